#include "calibration/projector_corners.h"

#include <algorithm>
#include <cmath>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "decoder/gray_refine.h"
#include "projector/patterns.h"

namespace sope {
CorrespondenceMap RefineGrayCodeSubpixel(const FrameSet& frames, const CorrespondenceMap& map) {
  SOPE_CHECK(
      map.width() == frames.manifest.camera_width && map.height() == frames.manifest.camera_height,
      "RefineGrayCodeSubpixel: the map is {}x{} but the frames are {}x{}", map.width(),
      map.height(), frames.manifest.camera_width, frames.manifest.camera_height);
  CorrespondenceMap refined = map;
  if (map.HasX()) refined.proj_x = map.proj_x.clone();
  if (map.HasY()) refined.proj_y = map.proj_y.clone();
  RefineGraySubpixel(frames, &refined);
  return refined;
}

void LocalHomographyOptions::Check() const {
  SOPE_CHECK(std::isfinite(window_fraction) && window_fraction > 0 && window_fraction <= 2.0,
             "local homography window_fraction must be in (0, 2], got {}", window_fraction);
  SOPE_CHECK(min_half_window_px >= 2 && max_half_window_px >= min_half_window_px,
             "local homography half window bounds must satisfy 2 <= min <= max, got [{}, {}]",
             min_half_window_px, max_half_window_px);
  SOPE_CHECK(min_decoded_fraction > 0 && min_decoded_fraction <= 1,
             "min_decoded_fraction must be in (0, 1], got {}", min_decoded_fraction);
  SOPE_CHECK(std::isfinite(ransac_threshold_px) && ransac_threshold_px > 0,
             "ransac_threshold_px must be > 0, got {}", ransac_threshold_px);
  SOPE_CHECK(min_inlier_fraction > 0 && min_inlier_fraction <= 1,
             "min_inlier_fraction must be in (0, 1], got {}", min_inlier_fraction);
  SOPE_CHECK(std::isfinite(edge_band_px) && edge_band_px >= 0, "edge_band_px must be >= 0, got {}",
             edge_band_px);
}

std::optional<Eigen::Vector2d> ProjectorPointFromLocalHomography(
    const CorrespondenceMap& map, const Eigen::Vector2d& camera_point, int half_window_px,
    const LocalHomographyOptions& options, const std::vector<Eigen::Vector2d>& edge_directions) {
  SOPE_CHECK(map.HasX() && map.HasY(),
             "local homographies need both projector axes decoded (x and y codes)");
  SOPE_CHECK(half_window_px >= 1, "half_window_px must be >= 1, got {}", half_window_px);
  if (!camera_point.allFinite()) return std::nullopt;
  const int cx = static_cast<int>(std::lround(camera_point.x()));
  const int cy = static_cast<int>(std::lround(camera_point.y()));
  const int x0 = cx - half_window_px, x1 = cx + half_window_px;
  const int y0 = cy - half_window_px, y1 = cy + half_window_px;
  if (x0 < 0 || y0 < 0 || x1 >= map.proj_x.cols || y1 >= map.proj_x.rows) return std::nullopt;

  // Unit normals of the edges: a pixel at offset d is in a band when |n·d| < band.
  std::vector<Eigen::Vector2d> edge_normals;
  if (options.edge_band_px > 0) {
    for (const Eigen::Vector2d& direction : edge_directions) {
      if (direction.norm() > 0)
        edge_normals.emplace_back(-direction.y() / direction.norm(),
                                  direction.x() / direction.norm());
    }
  }
  const auto in_edge_band = [&](double dx, double dy) {
    for (const Eigen::Vector2d& normal : edge_normals) {
      if (std::abs(normal.x() * dx + normal.y() * dy) < options.edge_band_px) return true;
    }
    return false;
  };
  // Camera pixels relative to the corner (conditioning), projector relative to the first.
  std::vector<cv::Point2f> camera, projector;
  int window_pixels = 0;
  for (int y = y0; y <= y1; ++y) {
    const float* row_x = map.proj_x.ptr<float>(y);
    const float* row_y = map.proj_y.ptr<float>(y);
    for (int x = x0; x <= x1; ++x) {
      if (in_edge_band(x - camera_point.x(), y - camera_point.y())) continue;
      ++window_pixels;
      if (!std::isfinite(row_x[x]) || !std::isfinite(row_y[x])) continue;
      camera.emplace_back(static_cast<float>(x - camera_point.x()),
                          static_cast<float>(y - camera_point.y()));
      projector.emplace_back(row_x[x], row_y[x]);
    }
  }
  if (camera.size() < options.min_decoded_fraction * window_pixels || camera.size() < 8) {
    return std::nullopt;
  }
  const cv::Point2f origin = projector.front();
  for (cv::Point2f& p : projector) p -= origin;
  std::vector<uchar> inliers;
  constexpr int kMaxRansacIterations = 2000;
  constexpr double kRansacConfidence = 0.999;
  const cv::Mat homography =
      cv::findHomography(camera, projector, cv::RANSAC, options.ransac_threshold_px, inliers,
                         kMaxRansacIterations, kRansacConfidence);
  if (homography.empty()) return std::nullopt;
  const auto inlier_count = std::count(inliers.begin(), inliers.end(), uchar(1));
  if (inlier_count < options.min_inlier_fraction * camera.size()) return std::nullopt;
  // The corner is the origin of the camera coordinates: H·(0, 0, 1)ᵀ.
  const double w = homography.at<double>(2, 2);
  if (!(std::abs(w) > 1e-12)) return std::nullopt;
  const Eigen::Vector2d point(homography.at<double>(0, 2) / w + origin.x,
                              homography.at<double>(1, 2) / w + origin.y);
  if (!point.allFinite()) return std::nullopt;
  return point;
}

std::vector<std::optional<Eigen::Vector2d>> FindProjectorCorners(
    const CorrespondenceMap& map, const BoardSpec& board,
    const std::vector<Eigen::Vector2d>& camera_corners, const LocalHomographyOptions& options) {
  board.Check();
  options.Check();
  SOPE_CHECK(static_cast<int>(camera_corners.size()) == board.NumCorners(),
             "FindProjectorCorners: {} camera corners for a {} board ({} corners)",
             camera_corners.size(), board.PatternSizeString(), board.NumCorners());
  SOPE_CHECK(map.HasX() && map.HasY(),
             "local homographies need both projector axes decoded (x and y codes)");
  std::vector<std::optional<Eigen::Vector2d>> result(camera_corners.size());
  for (int r = 0; r < board.rows; ++r) {
    for (int c = 0; c < board.cols; ++c) {
      const int k = r * board.cols + c;
      // Neighbours along the row and the column: the local square size and the directions
      // of the printed edges through the corner.
      const auto at = [&](int cc, int rr) {
        return camera_corners[std::clamp(rr, 0, board.rows - 1) * board.cols +
                              std::clamp(cc, 0, board.cols - 1)];
      };
      const Eigen::Vector2d along_row = at(c + 1, r) - at(c - 1, r);
      const Eigen::Vector2d along_column = at(c, r + 1) - at(c, r - 1);
      const double row_steps = std::min(c + 1, board.cols - 1) - std::max(c - 1, 0);
      const double column_steps = std::min(r + 1, board.rows - 1) - std::max(r - 1, 0);
      const double spacing =
          0.5 * (along_row.norm() / row_steps + along_column.norm() / column_steps);
      const int half = std::clamp(static_cast<int>(std::lround(options.window_fraction * spacing)),
                                  options.min_half_window_px, options.max_half_window_px);
      result[k] = ProjectorPointFromLocalHomography(map, camera_corners[k], half, options,
                                                    {along_row, along_column});
    }
  }
  return result;
}

}  // namespace sope
