// The exact per-point path of Triangulator (Intersect, TriangulateExact, TriangulatePixel):
// the reference the table path (triangulation.cc) is measured and tested against, and its
// fallback for the rare pixels off the tables. A translation unit of its own so that it is
// compiled with the project's default flags, not the table kernels' (triangulation.cc's
// 512-bit vectors would make the reference itself slower: the linear method's Eigen solve
// 75 → 93 ms in scan_bench), so the speed-ups in scan_bench compare against the same
// reference as before.
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

#include <Eigen/Dense>
#include <opencv2/core.hpp>

#include "calibration/triangulation.h"
#include "calibration/triangulation_rows.h"
#include "core/cv_threads.h"
#include "core/error.h"

namespace sope {
namespace {

// Colour of camera pixel (x, y) as RGB from a grey or BGR image.
Color3ub PixelColor(const cv::Mat& white, int x, int y) {
  if (white.type() == CV_8UC3) {
    const cv::Vec3b bgr = white.at<cv::Vec3b>(y, x);
    return Color3ub(bgr[2], bgr[1], bgr[0]);
  }
  if (white.type() == CV_16UC1) {
    const uint8_t grey = static_cast<uint8_t>(white.at<uint16_t>(y, x) >> 8);
    return Color3ub(grey, grey, grey);
  }
  const uint8_t grey = white.at<uint8_t>(y, x);
  return Color3ub(grey, grey, grey);
}

}  // namespace

Eigen::Vector2d Triangulator::CameraRay(int x, int y) const {
  const cv::Vec2f ray = camera_rays_.at<cv::Vec2f>(y, x);
  return Eigen::Vector2d(ray[0], ray[1]);
}

Eigen::Vector2d Triangulator::ProjectorRay(double proj_x, double proj_y) const {
  const int width = projector_rays_.cols, height = projector_rays_.rows;
  if (!(proj_x >= 0 && proj_y >= 0 && proj_x <= width - 1 && proj_y <= height - 1)) {
    return calibration_.projector.CamFromImage(Eigen::Vector2d(proj_x, proj_y));
  }
  // Bilinear interpolation in the table of undistorted pixel centres.
  const int x0 = std::min(static_cast<int>(proj_x), width - 2 < 0 ? 0 : width - 2);
  const int y0 = std::min(static_cast<int>(proj_y), height - 2 < 0 ? 0 : height - 2);
  const int x1 = std::min(x0 + 1, width - 1), y1 = std::min(y0 + 1, height - 1);
  const double fx = proj_x - x0, fy = proj_y - y0;
  const cv::Vec2f a = projector_rays_.at<cv::Vec2f>(y0, x0);
  const cv::Vec2f b = projector_rays_.at<cv::Vec2f>(y0, x1);
  const cv::Vec2f c = projector_rays_.at<cv::Vec2f>(y1, x0);
  const cv::Vec2f d = projector_rays_.at<cv::Vec2f>(y1, x1);
  Eigen::Vector2d ray;
  for (int k = 0; k < 2; ++k) {
    ray[k] = (1 - fy) * ((1 - fx) * a[k] + fx * b[k]) + fy * ((1 - fx) * c[k] + fx * d[k]);
  }
  return ray;
}

std::optional<Eigen::Vector3d> Triangulator::Intersect(const Eigen::Vector2d& camera_ray,
                                                       double proj_x, double proj_y) const {
  const Eigen::Vector3d camera_direction = camera_ray.homogeneous();
  const bool has_x = std::isfinite(proj_x), has_y = std::isfinite(proj_y);
  if (!has_x && !has_y) return std::nullopt;
  Eigen::Vector3d point_in_cam;
  if (has_x && has_y) {
    const Eigen::Vector3d projector_direction =
        cam_from_proj_rotation_ * ProjectorRay(proj_x, proj_y).homogeneous();
    if (options_.method == TriangulationMethod::kMidpoint) {
      // Closest approach of X = s·d_c and X = C_p + u·d_p; the midpoint of the segment.
      const Eigen::Vector3d& c = projector_center_in_cam_;
      const double a = camera_direction.dot(camera_direction);
      const double b = camera_direction.dot(projector_direction);
      const double e = projector_direction.dot(projector_direction);
      const double denominator = a * e - b * b;
      if (std::abs(denominator) < 1e-12 * a * e) return std::nullopt;
      const double dc = camera_direction.dot(c), dp = projector_direction.dot(c);
      const double s = (dc * e - b * dp) / denominator;
      const double u = (b * dc - a * dp) / denominator;
      point_in_cam = 0.5 * (s * camera_direction + (c + u * projector_direction));
    } else {
      // Linear least squares (thesis eq. 4.1): x_n·P3 − P1 = 0 etc. for both devices in
      // normalised coordinates, camera P = [I|0], projector P = [R|t]; solved for the
      // inhomogeneous point.
      const Eigen::Vector2d projector_ray = ProjectorRay(proj_x, proj_y);
      const Eigen::Matrix3d& r = calibration_.proj_from_cam.rotation;
      const Eigen::Vector3d& t = calibration_.proj_from_cam.translation;
      Eigen::Matrix<double, 4, 3> a;
      Eigen::Vector4d b;
      a.row(0) << -1, 0, camera_ray.x();
      a.row(1) << 0, -1, camera_ray.y();
      b(0) = 0;
      b(1) = 0;
      a.row(2) = projector_ray.x() * r.row(2) - r.row(0);
      a.row(3) = projector_ray.y() * r.row(2) - r.row(1);
      b(2) = t.x() - projector_ray.x() * t.z();
      b(3) = t.y() - projector_ray.y() * t.z();
      point_in_cam = (a.transpose() * a).ldlt().solve(a.transpose() * b);
    }
    if (options_.max_reprojection_px > 0) {
      const Eigen::Vector3d point_in_proj = calibration_.proj_from_cam * point_in_cam;
      if (point_in_proj.z() <= 0) return std::nullopt;
      const Eigen::Vector2d reprojected = calibration_.projector.ImageFromCam(point_in_proj);
      if ((reprojected - Eigen::Vector2d(proj_x, proj_y)).norm() > options_.max_reprojection_px) {
        return std::nullopt;
      }
    }
  } else {
    // Ray–plane: the camera ray meets the light plane of one projector column (row). With
    // lens distortion the "plane" is curved, so it is linearised around the row (column)
    // where the point lands and re-linearised until that stops moving.
    const CameraModel& projector = calibration_.projector;
    double other = has_x ? projector.cy() : projector.cx();
    constexpr int kMaxIterations = 5;
    constexpr double kHalfSpanPx = kPlaneHalfSpanPx;
    bool found = false;
    for (int iteration = 0; iteration < kMaxIterations; ++iteration) {
      Eigen::Vector3d ray_a, ray_b;
      if (has_x) {
        ray_a = ProjectorRay(proj_x, other - kHalfSpanPx).homogeneous();
        ray_b = ProjectorRay(proj_x, other + kHalfSpanPx).homogeneous();
      } else {
        ray_a = ProjectorRay(other - kHalfSpanPx, proj_y).homogeneous();
        ray_b = ProjectorRay(other + kHalfSpanPx, proj_y).homogeneous();
      }
      const Eigen::Vector3d normal_in_cam = cam_from_proj_rotation_ * ray_a.cross(ray_b);
      const double denominator = normal_in_cam.dot(camera_direction);
      if (std::abs(denominator) < 1e-12 * normal_in_cam.norm()) return std::nullopt;
      const double s = normal_in_cam.dot(projector_center_in_cam_) / denominator;
      point_in_cam = s * camera_direction;
      const Eigen::Vector3d point_in_proj = calibration_.proj_from_cam * point_in_cam;
      if (point_in_proj.z() <= 0) return std::nullopt;
      const Eigen::Vector2d landed = projector.ImageFromCam(point_in_proj);
      const double next = has_x ? landed.y() : landed.x();
      found = true;
      if (!std::isfinite(next)) return std::nullopt;
      if (std::abs(next - other) < 1e-3) break;
      other = next;
    }
    if (!found) return std::nullopt;
  }
  if (!(point_in_cam.z() >= options_.min_depth && point_in_cam.z() <= options_.max_depth)) {
    return std::nullopt;
  }
  return point_in_cam;
}

std::optional<Eigen::Vector3d> Triangulator::TriangulatePixel(
    const Eigen::Vector2d& camera_pixel, double proj_x, double proj_y) const {
  return Intersect(calibration_.camera.CamFromImage(camera_pixel), proj_x, proj_y);
}

void triangulation_rows::CheckInputs(const RigCalibration& calibration,
                                     const CorrespondenceMap& map, const cv::Mat& white) {
  const CameraModel& camera = calibration.camera;
  SOPE_CHECK(!map.mask.empty(), "correspondence map is empty");
  SOPE_CHECK(map.width() == camera.width && map.height() == camera.height,
             "correspondence map is {}x{} but the calibration's camera is {}x{}", map.width(),
             map.height(), camera.width, camera.height);
  SOPE_CHECK(map.projector_width == calibration.projector.width &&
                 map.projector_height == calibration.projector.height,
             "frames were coded for a {}x{} projector but the calibration's projector is {}x{}",
             map.projector_width, map.projector_height, calibration.projector.width,
             calibration.projector.height);
  SOPE_CHECK(white.empty() || (white.cols == camera.width && white.rows == camera.height),
             "white image is {}x{}, camera is {}x{}", white.cols, white.rows, camera.width,
             camera.height);
  SOPE_CHECK(white.empty() || white.type() == CV_8UC1 || white.type() == CV_8UC3 ||
                 white.type() == CV_16UC1,
             "white image must be 8-bit grey/BGR or 16-bit grey");
}

TriangulationResult Triangulator::TriangulateExact(const CorrespondenceMap& map,
                                                   const cv::Mat& white) const {
  triangulation_rows::CheckInputs(calibration_, map, white);
  const CameraModel& camera = calibration_.camera;
  const int height = camera.height, width = camera.width;
  TriangulationResult result;
  result.depth = cv::Mat(height, width, CV_32FC1,
                         cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  // Rows are triangulated independently (in parallel when asked) and concatenated in row
  // order, so the output is the same for any thread count.
  std::vector<PointCloud> row_clouds(height);
  std::vector<std::vector<cv::Point>> row_pixels(height);
  std::vector<size_t> row_rejected(height, 0);
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  auto triangulate_rows = [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      const uint8_t* mask = map.mask.ptr<uint8_t>(y);
      const float* proj_x = map.HasX() ? map.proj_x.ptr<float>(y) : nullptr;
      const float* proj_y = map.HasY() ? map.proj_y.ptr<float>(y) : nullptr;
      float* depth = result.depth.ptr<float>(y);
      for (int x = 0; x < width; ++x) {
        if (mask[x] == 0) continue;
        const std::optional<Eigen::Vector3d> point = Intersect(
            CameraRay(x, y), proj_x ? proj_x[x] : kNaN, proj_y ? proj_y[x] : kNaN);
        if (!point) {
          ++row_rejected[y];
          continue;
        }
        depth[x] = static_cast<float>(point->z());
        row_clouds[y].points.push_back(point->cast<float>());
        if (!white.empty()) row_clouds[y].colors.push_back(PixelColor(white, x, y));
        row_pixels[y].emplace_back(x, y);
      }
    }
  };
  if (options_.num_threads > 1) {
    const ScopedCvThreads threads(options_.num_threads);
    cv::parallel_for_(cv::Range(0, height), triangulate_rows);
  } else {
    triangulate_rows(cv::Range(0, height));
  }
  size_t total = 0;
  for (const PointCloud& row : row_clouds) total += row.size();
  result.cloud.points.reserve(total);
  if (!white.empty()) result.cloud.colors.reserve(total);
  result.pixels.reserve(total);
  for (int y = 0; y < height; ++y) {
    const PointCloud& row = row_clouds[y];
    result.cloud.points.insert(result.cloud.points.end(), row.points.begin(), row.points.end());
    result.cloud.colors.insert(result.cloud.colors.end(), row.colors.begin(), row.colors.end());
    result.pixels.insert(result.pixels.end(), row_pixels[y].begin(), row_pixels[y].end());
    result.rejected += row_rejected[y];
  }
  return result;
}

}  // namespace sope
