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

}  // namespace sope
