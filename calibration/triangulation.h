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

// Triangulates decoded maps for one calibration. Construction precomputes the undistorted
// ray of every camera pixel and a table of undistorted projector pixel centres (bilinearly
// interpolated for sub-pixel or block-centre coordinates), so repeated scans with the same
// rig cost only the ray intersections.
class Triangulator {
 public:
  // Throws sope::Error on an invalid calibration or options.
  explicit Triangulator(const RigCalibration& calibration,
                        const TriangulationOptions& options = {});

  // Triangulates every valid pixel of `map`. `white` (camera size, 8-bit grey or BGR, may
  // be empty) colours the points. Throws sope::Error when the map and the calibration
  // disagree in camera or projector size.
  TriangulationResult Triangulate(const CorrespondenceMap& map, const cv::Mat& white) const;

  // The 3D point (camera frame) for one camera pixel and its projector coordinates; NaN
  // projector coordinates mark an axis that is not coded. nullopt when the rays are
  // parallel, the point is behind a device, or a rejection test fails.
  std::optional<Eigen::Vector3d> TriangulatePixel(const Eigen::Vector2d& camera_pixel,
                                                  double proj_x, double proj_y) const;

  const RigCalibration& calibration() const { return calibration_; }

 private:
  Eigen::Vector2d CameraRay(int x, int y) const;
  Eigen::Vector2d ProjectorRay(double proj_x, double proj_y) const;
  std::optional<Eigen::Vector3d> Intersect(const Eigen::Vector2d& camera_ray, double proj_x,
                                           double proj_y) const;

  RigCalibration calibration_;
  TriangulationOptions options_;
  Eigen::Vector3d projector_center_in_cam_;
  Eigen::Matrix3d cam_from_proj_rotation_;
  // Undistorted normalised coordinates, CV_32FC2: camera per camera pixel, projector per
  // integer projector pixel.
  cv::Mat camera_rays_;
  cv::Mat projector_rays_;
};

// One-shot convenience: Triangulator(calibration, options).Triangulate(map, white).
TriangulationResult Triangulate(const CorrespondenceMap& map,
                                const RigCalibration& calibration, const cv::Mat& white,
                                const TriangulationOptions& options = {});

}  // namespace sope
