// Global descriptors of a pre-processed partial view, coarse to fine (thesis §4.3):
//  - shape distributions of primitive features estimated with a Gaussian KDE (bandwidth
//    1/(2√2) on normalised data, thesis §4.3.1): radial distance R, radial direction R̂,
//    normal N̂, radial–normal alignment A = |⟨R̂, N̂⟩|, tangent-plane distance D = R·A;
//  - a Bézier patch of order (m, n) fitted to the cloud; its control points (and the
//    spanning vectors of the initial plane) as a descriptor (thesis §4.3.2);
//  - the Viewpoint Feature Histogram (PCL VFH, 308 bins) as the fine descriptor, and
//    optionally CVFH / OUR-CVFH (PCL) — improvements over the thesis where they pay;
//  - metric size (sope addition: a structured-light scan is metric, so object size is a
//    strong cue the thesis's unit-ball normalisation throws away).
// The coarse vector is what the binary codes compress; the fine vector ranks the
// candidates the coarse search flags.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/enum_strings.h"
#include "recogniser/preprocess.h"

namespace sope {

enum class FineDescriptor { kVfh, kCvfh, kOurCvfh };
// Default weight of the control-net smoothness penalty of the Bézier patch fit.
constexpr double kDefaultBezierSmoothing = 0.1;
template <>
struct EnumTable<FineDescriptor> {
  static constexpr const char* kWhat = "fine descriptor";
  static constexpr EnumName<FineDescriptor> kNames[] = {{FineDescriptor::kVfh, "vfh"},
                                                       {FineDescriptor::kCvfh, "cvfh"},
                                                       {FineDescriptor::kOurCvfh, "ourcvfh"}};
};
std::string ToString(FineDescriptor descriptor);
FineDescriptor FineDescriptorFromString(const std::string& text);  // vfh|cvfh|ourcvfh

struct FeatureOptions {
  // Shape distributions: KDE bandwidth on unit-ball data and evaluation points per
  // 1-D distribution.
  double kde_bandwidth = 0.35355339059327373;  // 1 / (2√2)
  int kde_samples = 16;
  // Include the per-component distributions of R̂ and N̂ in the camera axes (thesis).
  // They change with the roll about the viewing axis; when false only the roll-invariant
  // components along the viewing axis (R̂_z, N̂_z) are used.
  bool direction_components_xyz = false;
  // Bézier patch order (m, n) and fitting iterations; order 0 disables the patch.
  int bezier_order_u = 3;
  int bezier_order_v = 3;
  int bezier_iterations = 10;
  // Weight of the control-net smoothness penalty of the patch fit (FitBezierPatch),
  // dimensionless, per point and control point. With 0.1 the nets of two views 5° apart of
  // one object are ≥ 2× closer than those of any two of five classes (features_test.cc);
  // with 0.001 control points over sparsely covered corners swing by up to ±1 and a mug's
  // 5° change exceeds most differences between classes.
  double bezier_smoothing = kDefaultBezierSmoothing;
  // Append metric size features (log radius, sorted principal extents in metres).
  bool metric_size = true;
  FineDescriptor fine = FineDescriptor::kVfh;

  void Check() const;
  // The thesis's configuration, reproducible as a preset: KDE of R, R̂ (xyz), N̂ (xyz),
  // A, D; Bézier (3, 3); VFH; no metric size.
  static FeatureOptions ThesisPreset();
};

struct ViewFeatures {
  Eigen::VectorXf coarse;  // concatenated blocks (CoarseLayout), for hashing
  Eigen::VectorXf fine;    // VFH (308) or the first CVFH/OUR-CVFH histogram
};

// Names and sizes of the blocks of the coarse vector for given options, in order
// (e.g. {"kde_R", 16}, {"kde_A", 16}, …, {"bezier", 48}, {"size", 4}) — for weighting
// and reports. The blocks:
//  - "kde_R", "kde_A", "kde_D": KDEs over [0, 1] of R = ‖p‖, A = |⟨R̂, N̂⟩|, D = R·A on the
//    normalised view (kde_samples values each, summing to 1);
//  - "kde_Rx", "kde_Ry", "kde_Rz", "kde_Nx", "kde_Ny", "kde_Nz" with
//    direction_components_xyz, else only "kde_Rz", "kde_Nz": KDEs over [−1, 1] of the camera-
//    axis components of R̂ and N̂;
//  - "bezier" (3·(m+1)(n+1)): the fitted control points (row-major in u) in the patch's
//    frame (axis_u, axis_v, axis_u × axis_v) relative to its origin, normalised units —
//    invariant to rotations of the view — with their part antisymmetric under the PCA
//    sign flip weighted by tanh(skewness / 0.1), so the block stays continuous where the
//    sign choice flips; "bezier_axes": the spanning vectors axis_u, axis_v in camera axes
//    (6 values) with direction_components_xyz, else |z| of each (2, roll-invariant like
//    R̂_z, N̂_z, and sign-invariant);
//  - "size" (metric_size): ln(radius / 1 m), then the extents of the view along its three
//    principal axes (1st–99th percentile range, metres), largest first.
// With direction_components_xyz false every block is invariant to a roll of the view
// about the camera's optical axis (up to resampling by the voxel grid).
std::vector<std::pair<std::string, int>> CoarseLayout(const FeatureOptions& options);
int CoarseDimension(const FeatureOptions& options);
int FineDimension(const FeatureOptions& options);

// Computes both vectors from a pre-processed cloud (normals required). Deterministic: the
// same input gives bit-identical output. The patch is fitted to at most 768 points of the
// view (an even stride subsample) with the sensor as the viewpoint (see FitBezierPatch).
// The fine histogram is PCL's (pcl::VFHEstimation on the metric cloud with the viewpoint at
// the sensor origin, normalised bins: bins 0–134 are the three angle histograms, each
// summing to 100·n/(n − 1), bins 135–179 the distance component, zero with PCL's defaults,
// 180–307 the viewpoint histogram summing to 100). The centroid is passed to PCL explicitly:
// PCL 1.13's own one makes the viewpoint histogram depend on the distance to the sensor
// (features.cc, FineHistogram). CVFH / OUR-CVFH (PCL) return one histogram per smooth
// region, of which the first is kept (PCL's region order: the seed order of its Euclidean
// clustering), with PCL's tolerances (3 leaves of 5 mm) scaled to 3× the cloud's median
// point spacing. OUR-CVFH prints a PCL warning on stderr for views with ambiguous axes.
// Throws sope::Error on invalid options, fewer than 10 points, missing or non-unit
// normals, non-finite points, or a metric cloud that does not match the normalised one.
ViewFeatures ComputeFeatures(const PreprocessedCloud& cloud, const FeatureOptions& options);

// Building blocks, exposed for tests and for the fine stage.
// Gaussian KDE of `values` evaluated at `samples` evenly spaced points over [lo, hi]
// (lo and hi included), normalised to sum 1 (all zero when every value lies more than ~8
// bandwidths outside [lo, hi]). Exact Gaussian sums when values are few; otherwise linear
// binning onto a grid of bandwidth/32 (Wand & Jones 1995) and exact sums over the bins —
// relative error ≈ 1e-4. Throws sope::Error on an empty or non-finite input, lo ≥ hi,
// samples outside [2, 1024] or bandwidth ≤ 0.
Eigen::VectorXf KernelDensity(const std::vector<float>& values, float lo, float hi, int samples,
                              float bandwidth);

struct BezierPatch {
  int order_u = 0, order_v = 0;
  Eigen::Vector3f origin;                // plane origin (centroid)
  Eigen::Vector3f axis_u, axis_v;        // spanning vectors of the initial plane
  std::vector<Eigen::Vector3f> control;  // (order_u + 1)·(order_v + 1), row-major in u:
                                         // k_ij at i·(order_v + 1) + j
  double rms_residual = 0.0;             // RMS point-to-surface distance at the end
};
// Fits a Bézier surface of order (m, n) to `points` (thesis §4.3.2, eq. 4.4–4.5): control
// points evenly spaced on the plane of the two largest covariance eigenvectors over the
// extent of the projected points, then `iterations` rounds of (a) linear least squares for
// the control points given the foot points (u_k, v_k), with a small penalty on the second
// differences of the control net along u and v, weighted by `smoothing` per point and
// control point (zero for a plane or any evenly spaced affine net), so that control points
// over empty parts of the parameter square stay determined, and (b) one Gauss–Newton step
// per point on its foot point from the previous (u, v), clamped to [0, 1]², kept when it
// gets closer. The default smoothing favours stable descriptors over fidelity: on a random
// bicubic surface it leaves an RMS residual of ≈ 0.02 (patch 1 × 0.6) where 1e-7 gives
// 3e-4 (features_test.cc).
// The PCA signs are made deterministic: axis_u has a positive third moment of the points
// along it (skewness), the plane normal axis_u × axis_v faces `viewpoint` (the overload
// without one uses a positive third moment along the normal too), axis_v completes the
// right-handed frame. Orders in [1, 8], ≥ 3 finite points, iterations ≥ 0, smoothing ≥ 0;
// throws sope::Error otherwise.
BezierPatch FitBezierPatch(const std::vector<Eigen::Vector3f>& points, int order_u, int order_v,
                           int iterations);
BezierPatch FitBezierPatch(const std::vector<Eigen::Vector3f>& points, int order_u, int order_v,
                           int iterations, const Eigen::Vector3f& viewpoint,
                           double smoothing = kDefaultBezierSmoothing);
// p(u, v) = Σ_ij B_i^m(u) B_j^n(v) k_ij (eq. 4.4).
Eigen::Vector3f EvaluateBezier(const BezierPatch& patch, float u, float v);

namespace internal {
// Principal axes of `points` (columns, by decreasing variance), their centroid and the
// variances along them (of the covariance normalised by the count). At least one point.
// The Bezier frame's PCA; also the scene recogniser's (model axes, backdrop planes).
void PrincipalAxes(const std::vector<Eigen::Vector3f>& points, Eigen::Vector3d* centroid,
                   Eigen::Matrix3d* axes, Eigen::Vector3d* variances);
}  // namespace internal

}  // namespace sope
