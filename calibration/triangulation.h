// Triangulation of decoded correspondences into a point cloud in the camera frame.
#pragma once

#include <string>

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

// Triangulates every valid pixel of `map`. `white` (camera size, 8-bit grey or BGR, may
// be empty) colours the points. Throws sope::Error when the map and the calibration
// disagree in camera or projector size.
TriangulationResult Triangulate(const CorrespondenceMap& map,
                                const RigCalibration& calibration, const cv::Mat& white,
                                const TriangulationOptions& options = {});

}  // namespace sope
