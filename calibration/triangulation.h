// Triangulation of decoded correspondences into a point cloud in the camera frame.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include <opencv2/core/mat.hpp>

#include "core/point_cloud.h"
#include "core/rig_calibration.h"
#include "decoder/decoder.h"

namespace sope {

enum class TriangulationMethod {
  // Midpoint of the closest approach of the camera and projector rays (thesis §4).
  kMidpoint,
  // Linear least squares on the projection equations of both devices (thesis eq. 4.1).
  kLinear,
};
std::string ToString(TriangulationMethod method);
TriangulationMethod TriangulationMethodFromString(const std::string& text);

struct TriangulationOptions {
  // Used when both axes are decoded; with one axis the camera ray meets the projector's
  // light plane (exact, iterated for projector lens distortion).
  TriangulationMethod method = TriangulationMethod::kMidpoint;
  // Keep points with camera-frame depth z in [min_depth, max_depth], metres.
  double min_depth = 0.01;
  double max_depth = 20.0;
  // Reject points whose camera and projector rays miss each other by more than this many
  // projector pixels when reprojected (two-axis methods only); ≤ 0 disables.
  double max_reprojection_px = 2.0;
  // Threads; 1 = single-threaded.
  int num_threads = 1;

  void Check() const;
};

struct TriangulationResult {
  PointCloud cloud;  // camera frame, metres; coloured when a white image was given
  // z per camera pixel (CV_32FC1), NaN where no point.
  cv::Mat depth;
  // Camera pixel (x, y) of each cloud point, same order (for overlays and evaluation).
  std::vector<cv::Point> pixels;
  size_t rejected = 0;  // decoded pixels rejected by depth or reprojection tests
};

// Camera pixels a triangulation is restricted to (the live loop asks only for the object:
// its segmented region or a band of rows). Both parts are optional and combine (∧).
struct TriangulationRegion {
  // Camera pixels; empty (the default) = the whole image. Clipped to the image.
  cv::Rect roi;
  // CV_8UC1 of the camera size, non-zero = triangulate; empty = every pixel.
  cv::Mat mask;
};

// Triangulates decoded maps for one calibration: the cache object a live loop keeps per
// calibration and reuses across scans.
//
// Construction precomputes, in float (compact: 8 bytes per entry):
//  - the undistorted normalised ray (x/z, y/z) of every camera pixel;
//  - a grid of undistorted normalised coordinates of every integer projector pixel,
//    bilinearly interpolated for sub-pixel (phase-shift) or block-centre coordinates —
//    the projector ray of the two-axis methods;
//  - per projector axis, the light plane through each integer (column, row) — the chord of
//    the curved (distorted) column surface through the rows ±kPlaneHalfSpanPx around it,
//    as the normal n / n_dominant (two floats), also bilinearly interpolated.
// Each point is then closed-form arithmetic in double (midpoint, the 3×3 normal equations
// of the linear method, or ray–plane: the chord through the projector row (column) that
// the same camera column's points of the two camera rows above predict — kept when the
// point lands within 0.1 px of it, as ~95% do — else two plane-table steps, from the
// projector's centre row and then from where that point lands, and the chord there; with
// a mild lens the last step takes the plane table's plane instead of the chord, see
// kPlaneTableMaxDeviationPx), run over the valid pixels of a row as branch-free loops the
// compiler vectorises. Coordinates outside the tables (and other rare cases) go through the
// exact per-point path, so results are those of TriangulateExact within float rounding
// (calibration_test checks 1e-6 m of depth).
class Triangulator {
 public:
  // Throws sope::Error on an invalid calibration or options.
  explicit Triangulator(const RigCalibration& calibration,
                        const TriangulationOptions& options = {});

  // Triangulates every valid pixel of `map` (inside `region` when given; with one axis
  // coded a region's points can differ from the whole image's in the last bits, within
  // 1e-6 m: ray–plane predicts from the rows above). `white` (camera size, 8-bit grey or
  // BGR, may be empty) colours the points. Throws sope::Error when the
  // map and the calibration disagree in camera or projector size, or the region's mask is
  // not CV_8UC1 of the camera size.
  TriangulationResult Triangulate(const CorrespondenceMap& map, const cv::Mat& white) const;
  TriangulationResult Triangulate(const CorrespondenceMap& map, const cv::Mat& white,
                                  const TriangulationRegion& region) const;

  // The reference: the per-point exact path (Eigen solves; ray–plane re-linearised until
  // the landed row moves < 1e-3 px). Same contract as Triangulate; ~10× slower.
  TriangulationResult TriangulateExact(const CorrespondenceMap& map, const cv::Mat& white) const;

  // The 3D point (camera frame) for one camera pixel and its projector coordinates; NaN
  // projector coordinates mark an axis that is not coded. nullopt when the rays are
  // parallel, the point is behind a device, or a rejection test fails.
  std::optional<Eigen::Vector3d> TriangulatePixel(const Eigen::Vector2d& camera_pixel,
                                                  double proj_x, double proj_y) const;

  const RigCalibration& calibration() const { return calibration_; }
  const TriangulationOptions& options() const { return options_; }
  // Bytes held by the precomputed tables.
  size_t TableBytes() const;

  // Half the span of the chord that linearises a curved light plane, projector pixels.
  static constexpr double kPlaneHalfSpanPx = 8.0;
  // Ray–plane's last step (the predicted one, or the last of those from the centre) takes
  // the plane table's plane instead of building the chord from the ray grid when, over the
  // table (measured at set-up), the two meet the projector ray at most this far apart
  // along the coded axis: about the ray grid's own float rounding, a thousandth of a
  // decoder's sub-pixel precision. Mild lenses (~2e-5 px) take it, a strongly distorted
  // wide-angle projector (~3e-4 px) keeps the chords.
  static constexpr double kPlaneTableMaxDeviationPx = 5e-5;
  // The plane table's largest deviation from the chord, projector pixels (columns: x-coded
  // maps; rows: y-coded).
  double PlaneTableDeviation(bool columns) const {
    return columns ? column_plane_deviation_px_ : row_plane_deviation_px_;
  }

  // Working arrays of the fast path (defined in triangulation.cc).
  struct RowScratch;

 private:
  Eigen::Vector2d CameraRay(int x, int y) const;
  Eigen::Vector2d ProjectorRay(double proj_x, double proj_y) const;
  std::optional<Eigen::Vector3d> Intersect(const Eigen::Vector2d& camera_ray, double proj_x,
                                           double proj_y) const;
  // Fast path over the candidate pixels of camera row y (mask ∧ region) into `scratch`.
  void TriangulateRow(const CorrespondenceMap& map, const uint8_t* region_row, int x_begin,
                      int x_end, int y, RowScratch* scratch) const;

  RigCalibration calibration_;
  TriangulationOptions options_;
  Eigen::Vector3d projector_center_in_cam_;
  Eigen::Matrix3d cam_from_proj_rotation_;
  // Undistorted normalised coordinates, CV_32FC2: camera per camera pixel, projector per
  // integer projector pixel.
  cv::Mat camera_rays_;
  cv::Mat projector_rays_;
  // The projector grid with kPlaneHalfSpanPx more pixels on every side (projector pixel
  // (c, r) at (c + kPlaneHalfSpanPx, r + kPlaneHalfSpanPx)); projector_rays_ is its interior.
  cv::Mat projector_rays_with_margin_;
  // Light planes, CV_32FC2 of the projector size (row-major: [row][column]):
  // column_planes_ for x-coded maps, (n_y, n_z) / n_x of the chord through column c at
  // rows r ± kPlaneHalfSpanPx; row_planes_ for y-coded maps, (n_x, n_z) / n_y of the
  // chord through row r at columns c ± kPlaneHalfSpanPx. Normals in the projector frame.
  cv::Mat column_planes_;
  cv::Mat row_planes_;
  // The tables can be interpolated in (a projector of at least 2×2 pixels).
  bool fast_tables_ = false;
  double column_plane_deviation_px_ = 0.0, row_plane_deviation_px_ = 0.0;
};

// One-shot convenience: Triangulator(calibration, options).Triangulate(map, white) (the
// table set-up dominates; keep a Triangulator when scanning repeatedly).
TriangulationResult Triangulate(const CorrespondenceMap& map,
                                const RigCalibration& calibration, const cv::Mat& white,
                                const TriangulationOptions& options = {});

}  // namespace sope
