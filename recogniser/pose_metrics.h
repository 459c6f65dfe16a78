// Pose-error measures for evaluation: rotation and translation error, ADD and ADD-S
// (Hinterstoisser et al. 2012), and rotation error modulo the object's own symmetries,
// which are detected from the model surface (a can is the same after any turn about its
// axis, so the raw rotation error of a correct pose can be anything).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"
#include "core/rigid3d.h"

namespace sope {

// Points spread evenly over the mesh surface (area-weighted, deterministic for a seed).
std::vector<Eigen::Vector3f> SampleSurface(const TriangleMesh& mesh, int count, uint64_t seed = 1);

// Angle of R_a⁻¹·R_b, degrees.
double RotationErrorDeg(const Eigen::Matrix3d& rotation_a, const Eigen::Matrix3d& rotation_b);

// ADD: mean distance between the model points under the two poses, metres.
double AverageDistance(const std::vector<Eigen::Vector3f>& model_points,
                       const Rigid3d& cam_from_model_a, const Rigid3d& cam_from_model_b);
// ADD-S: mean distance from each model point under pose a to the closest model point
// under pose b, metres (for symmetric objects). Exact nearest neighbours (kd-tree).
double AverageDistanceSymmetric(const std::vector<Eigen::Vector3f>& model_points,
                                const Rigid3d& cam_from_model_a, const Rigid3d& cam_from_model_b);

// The rotations (model frame) that map the model surface onto itself: the mean distance
// from turned surface samples to the nearest of a dense sample of the surface exceeds
// that of unturned samples (the sampling floor) by less than `tolerance_fraction` of the
// bounding diagonal. Candidates are turns about its principal
// axes (2, 3, 4, 6-fold and continuous, tested at 10° steps) and half-turns about the
// axes perpendicular to them. Always contains the identity.
struct ModelSymmetry {
  std::vector<Eigen::Matrix3d> rotations;  // model_from_model
  // Set when the model is (numerically) a body of revolution: any turn about this axis
  // (model frame, unit) is a symmetry; `rotations` then holds the discrete part only.
  bool continuous = false;
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();
};
ModelSymmetry DetectSymmetry(const TriangleMesh& mesh, double tolerance_fraction = 0.005);

// Rotation error modulo the symmetry: min over symmetries S of the angle between
// R_estimate and R_truth·S (continuous: the angle between the mapped axes, combined with
// the discrete part), degrees.
double SymmetricRotationErrorDeg(const Eigen::Matrix3d& rotation_estimate,
                                 const Eigen::Matrix3d& rotation_truth,
                                 const ModelSymmetry& symmetry);

// ---------------------------------------------------------------------------------------
// The comparison of an estimated pose with the ground truth — the one definition the
// evaluation, `sope scan-and-recognise` (results "ground_truth"), the tests and the
// benches share.

// What the comparison needs of the true object, computed once per mesh (the symmetry
// detection is the expensive part): surface samples for ADD-S, the bounding-box centre,
// the bounding-box diagonal ("diameter") and the symmetries.
struct PoseTruthModel {
  std::vector<Eigen::Vector3f> samples;
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  double diameter = 0.0;
  ModelSymmetry symmetry;
};
struct PoseTruthModelOptions {
  int samples = 10000;   // surface samples for ADD-S
  uint64_t seed = 1;     // their seed
  void Check() const;
};
// `mesh` in its model frame (the frame both poses map from), metres.
PoseTruthModel MakePoseTruthModel(const TriangleMesh& mesh,
                                  const PoseTruthModelOptions& options = {});

struct PoseComparison {
  double rotation_error_deg = 0.0;  // modulo the object's symmetry
  double center_error_m = 0.0;      // of the bounding-box centre
  double adds_m = 0.0;              // ADD-S of the true model under the two poses
  double diameter_m = 0.0;          // bounding-box diagonal of the true model
  double adds_over_diameter() const { return adds_m / diameter_m; }
};
// `estimate` and `truth` are cam_from_model of the same model frame.
PoseComparison ComparePoses(const Rigid3d& estimate, const Rigid3d& truth,
                            const PoseTruthModel& model);
// The same, building the truth model of `mesh` (default options) first.
PoseComparison ComparePoses(const Rigid3d& estimate, const Rigid3d& truth,
                            const TriangleMesh& mesh);

}  // namespace sope
