// Pose of a recognised object from a database view (thesis §4.7 "post-processing", which
// left ICP as future work): the database view fixes the direction from which the camera
// sees the model; what remains is the roll about the line of sight, the distance, and a
// refinement.
//
// Frames. `cam` is the query camera (origin at its centre, z forward). The *canonical*
// frame of a view is the camera turned about its centre (a virtual pan/tilt — the same
// rays) so that the view's centroid lies on its +z axis: cam_from_canonical is the
// smallest rotation taking e_z to the centroid's direction (CamFromCanonical). Two
// cameras at the same place seeing the object in different image positions and rolls
// have canonical frames that differ by a rotation about z only, so
//   canonical_query_from_model = Rz(α) · canonical_view_from_model     (α: the roll)
// up to the small change of perspective between the database distance and the query's.
//
// Steps for one database view (EstimatePose):
//  1. roll: circular cross-correlation of polar signatures of the two clouds in their
//     canonical image planes (per angle bin and ring: point count, depth relative to the
//     centroid, radial normal component — each channel zero-mean, unit-norm over the
//     angle), evaluated at every bin shift, the best `roll_hypotheses` local maxima
//     refined by parabolic interpolation;
//  2. translation: the view's centroid (model frame) onto the query's centroid;
//  3. ICP, point-to-plane (Chen & Medioni 1992) with a small point-to-point term for
//     stability along planes, from the view's stored cloud (model frame) to the query;
//     correspondences by projective association (the query is one depth view, so the
//     candidates for a point lie along nearby rays: a grid in normalised image
//     coordinates, as in KinectFusion, Newcombe et al. 2011) with normal compatibility
//     and a shrinking distance gate, Geman–McClure weights;
//  4. verification: visible model points classified against the query along their rays
//     (fit within the inlier distance, query surface seen *behind* the model point =
//     free-space violation, in front = occluded, nothing = empty) and the fraction of
//     query points explained by the model (points on faces seen nearly edge-on count
//     less); the score combines them (AlignmentScore).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/options.h"
#include "core/point_cloud.h"
#include "core/rigid3d.h"

namespace sope {

// Smallest rotation taking e_z to `direction` (any length > 0): cam_from_canonical for a
// centroid at `direction` (camera frame).
Eigen::Matrix3d CamFromCanonical(const Eigen::Vector3d& direction);

// Points of one depth view (sensor at the origin) indexed by their normalised image
// coordinates (x/z, y/z) on a grid of square cells: the candidate correspondences of a
// point are those in the cells around its projection.
class ProjectiveGrid {
 public:
  ProjectiveGrid() = default;
  // `cell` is the cell side in normalised image units (≈ point spacing / depth). Points
  // with z ≤ 0 or non-finite are ignored. `normals` empty or one per point.
  ProjectiveGrid(const std::vector<Eigen::Vector3f>& points,
                 const std::vector<Eigen::Vector3f>& normals, float cell);

  // Nearest point (3-D distance) to `point` among the cells within `window` cells of its
  // projection whose normal n satisfies n·normal ≥ min_cos (no test when `normal` is
  // zero or the grid has no normals), closer than √max_distance2. Returns its index in
  // the constructor's arrays or −1; *distance2 gets the squared distance.
  int Nearest(const Eigen::Vector3f& point, const Eigen::Vector3f& normal, float min_cos,
              int window, float max_distance2, float* distance2) const;
  // The point whose ray is closest (in the image) to `point`'s within `window` cells, or −1.
  int AlongRay(const Eigen::Vector3f& point, int window) const;

  bool empty() const { return x_.empty(); }
  float cell() const { return cell_; }
  // Point and normal by the constructor's index.
  const Eigen::Vector3f& point(int index) const { return points_[index]; }
  const Eigen::Vector3f& normal(int index) const { return normals_[index]; }
  bool has_normals() const { return !normals_.empty(); }

 private:
  bool CellOf(const Eigen::Vector3f& point, int* cx, int* cy) const;
  float cell_ = 0.0f;
  float inv_cell_ = 0.0f;
  float u0_ = 0.0f, v0_ = 0.0f;  // normalised coordinates of the grid corner
  int width_ = 0, height_ = 0;
  std::vector<int> cell_start_;  // CSR: width·height + 1
  std::vector<int> order_;       // point index per slot
  // Per slot, structure of arrays (vector loads): position, normal (zero without normals).
  std::vector<float> x_, y_, z_, nx_, ny_, nz_;
  std::vector<Eigen::Vector3f> points_;   // by original index
  std::vector<Eigen::Vector3f> normals_;  // by original index
};

// The query as the pose stage sees it: canonical frame, grid, polar signature.
struct PoseQuery {
  Eigen::Matrix3d cam_from_canonical = Eigen::Matrix3d::Identity();
  // Pre-processed query points and normals (normals facing the sensor), canonical frame.
  std::vector<Eigen::Vector3f> points, normals;
  float centroid_depth = 0.0f;  // |centroid|, metres (the centroid is (0, 0, depth))
  float radius = 0.0f;          // normalisation radius, metres
  float spacing = 0.0f;         // point spacing, metres (the voxel leaf)
  ProjectiveGrid grid;
  std::vector<float> signature;  // PolarSignature of the points
  // Indices of an evenly spread subset of `points` used to measure coverage, in an order
  // whose every prefix is spread evenly too (van der Corput order of a strided sample).
  std::vector<int> coverage_sample;
};

struct PoseOptions {
  // Polar signature: angle bins (roll resolution 360°/bins before interpolation) and
  // radial ring edges as fractions of the normalisation radius.
  int angle_bins = 36;
  std::vector<float> ring_edges = {0.45f, 0.8f};
  // Roll hypotheses per view (distinct local maxima of the correlation, ≥ 1).
  int roll_hypotheses = 2;

  // ICP.
  int max_iterations = 25;
  // Correspondence gate, metres: starts at max(initial_gate_fraction · query radius,
  // final_gate) and shrinks geometrically to final_gate by gate_iterations.
  double initial_gate_fraction = 0.35;
  double final_gate = 0.008;
  int gate_iterations = 8;
  // Projective search window, cells either side: wide while the gate is wide.
  int initial_window = 2;
  int final_window = 1;
  // Normals of corresponding points must agree within this angle (cosine).
  double normal_min_cos = 0.5;
  // Weight of the point-to-point term relative to point-to-plane (keeps sliding along
  // planes in check).
  double point_to_point_weight = 0.05;
  // Stop when an update turns by less than this (radians) and moves less than this (m).
  double min_rotation_step = 2e-4;
  double min_translation_step = 2e-5;

  // Verification: a visible model point fits when a query point lies within
  // inlier_distance (metres, 3-D); a query point is explained when a model point lies
  // within inlier_distance of its tangent plane and coverage_lateral_factor · the view
  // cloud's spacing laterally.
  double inlier_distance = 0.006;
  double coverage_lateral_factor = 1.5;
  // Penalty weights of model points with nothing on their ray (empty) and of free-space
  // violations, relative to a fitting point.
  double empty_weight = 0.15;
  double violation_weight = 1.0;
  // Query points sampled for the coverage measure.
  int coverage_samples = 400;
  // Coverage weight of a query point: min(1, cos(incidence angle) / coverage_grazing_cos),
  // so faces seen within ≈ asin(coverage_grazing_cos) of edge-on count less (0.2: 11.5°,
  // about the spacing of a 300-view grid; such faces may be missing from the nearest
  // database view's cloud). 0 counts every point fully.
  double coverage_grazing_cos = 0.2;

  // Every field but ring_edges (core/options.h).
  static const std::vector<OptionField<PoseOptions>>& Fields();
  void Check() const;
};

// Canonical frame, grid, signature and coverage sample of a pre-processed query cloud
// (camera frame, with normals; `centroid` and `radius` from Preprocess; `spacing` the
// voxel leaf, metres).
PoseQuery MakePoseQuery(const PointCloud& cloud_in_cam, const Eigen::Vector3f& centroid_in_cam,
                        float radius, float spacing, const PoseOptions& options);

// Polar signature (see the file comment) of points in a canonical frame (centroid on
// the z axis at `centroid_depth`), normalised by `radius`.
std::vector<float> PolarSignature(const std::vector<Eigen::Vector3f>& points,
                                  const std::vector<Eigen::Vector3f>& normals,
                                  float centroid_depth, float radius, const PoseOptions& options);

struct RollHypothesis {
  double roll = 0.0;         // α, radians: canonical_query = Rz(α) · canonical_view
  double correlation = 0.0;  // normalised correlation at α, in [−1, 1]
};
// Best roll hypotheses (descending correlation; distinct local maxima) between the query
// signature and a view signature.
std::vector<RollHypothesis> EstimateRoll(const std::vector<float>& query_signature,
                                         const std::vector<float>& view_signature,
                                         const PoseOptions& options);

struct IcpResult {
  Rigid3d canonical_from_model;  // the refined pose in the query's canonical frame
  int iterations = 0;
  bool converged = false;
  int correspondences = 0;  // in the last iteration
  double rms = 0.0;         // of the point-to-plane residuals of those, metres
};
// Point-to-plane ICP of `model_points` (model frame, with normals) onto the query,
// starting from `initial` (canonical_from_model). `iterations` ≤ 0 uses max_iterations;
// `initial_gate` > 0 (metres) replaces the starting correspondence gate (e.g. a narrow one
// when refining a pose that is already close).
IcpResult RefinePose(const std::vector<Eigen::Vector3f>& model_points,
                     const std::vector<Eigen::Vector3f>& model_normals, const PoseQuery& query,
                     const Rigid3d& initial, const PoseOptions& options, int iterations = 0,
                     double initial_gate = 0.0);

struct AlignmentScore {
  int visible = 0;     // model points facing the camera
  int fitting = 0;     // … with a query point within inlier_distance
  int violations = 0;  // … in front of the query surface seen along their ray
  int occluded = 0;    // … behind it
  int empty = 0;       // … with no query point on their ray
  double model_fit = 0.0;       // fitting / (fitting + w_v·violations + w_e·empty)
  // Fraction of the sampled query points explained, those on faces seen nearly edge-on
  // weighted down (PoseOptions::coverage_grazing_cos).
  double query_coverage = 0.0;
  double rms = 0.0;             // 3-D distance of the fitting points, metres
  // model_fit · query_coverage, in [0, 1]: how well model and query explain each other.
  double score = 0.0;
};
// `model_points` may be a prefix of a view cloud in farthest-point order (`model_spacing`
// is then the spacing of that prefix); `coverage_samples` > 0 uses only that many of the
// query's coverage sample.
AlignmentScore ScoreAlignment(const std::vector<Eigen::Vector3f>& model_points,
                              const std::vector<Eigen::Vector3f>& model_normals,
                              float model_spacing, const PoseQuery& query,
                              const Rigid3d& canonical_from_model, const PoseOptions& options,
                              int coverage_samples = 0);

// Polar signature of a database view (its stored cloud, model frame) in the view's
// canonical frame, and that frame: canonical_view_from_model.
std::vector<float> ViewSignature(const Rigid3d& view_cam_from_model,
                                 const Eigen::Vector3f& view_centroid_in_model, float view_radius,
                                 const std::vector<Eigen::Vector3f>& model_points,
                                 const std::vector<Eigen::Vector3f>& model_normals,
                                 const PoseOptions& options,
                                 Rigid3d* canonical_view_from_model = nullptr);

// Initial poses (canonical_query_from_model), one per roll hypothesis, for a database
// view given by its camera pose, centroid (model frame) and stored cloud.
struct PoseHypothesis {
  Rigid3d canonical_from_model;
  RollHypothesis roll;
};
std::vector<PoseHypothesis> InitialPoses(const Rigid3d& view_cam_from_model,
                                         const Eigen::Vector3f& view_centroid_in_model,
                                         float view_radius,
                                         const std::vector<Eigen::Vector3f>& model_points,
                                         const std::vector<Eigen::Vector3f>& model_normals,
                                         const PoseQuery& query, const PoseOptions& options);

}  // namespace sope
