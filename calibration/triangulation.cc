#include "calibration/triangulation.h"

#include <cmath>
#include <limits>

#include <Eigen/Dense>
#include <opencv2/core.hpp>

#include "core/error.h"

namespace sope {
namespace {

// A lens's distortion in locals (OpenCV order, 0 when absent), so that the per-pixel loops
// below are plain arithmetic the compiler vectorises.
struct Lens {
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0, k4 = 0, k5 = 0, k6 = 0;
  double fx = 1, fy = 1, cx = 0, cy = 0;
  explicit Lens(const CameraModel& model) {
    const auto coeff = [&](size_t i) {
      return i < model.distortion.size() ? model.distortion[i] : 0.0;
    };
    k1 = coeff(0), k2 = coeff(1), p1 = coeff(2), p2 = coeff(3);
    k3 = coeff(4), k4 = coeff(5), k5 = coeff(6), k6 = coeff(7);
    fx = model.fx(), fy = model.fy(), cx = model.cx(), cy = model.cy();
  }
  // Undistorted → distorted normalised coordinates (CameraModel::Distort).
  inline void Distort(double x, double y, double* xd, double* yd) const {
    const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
    const double radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6);
    *xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    *yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
  }
  // One Gauss–Newton step of Undistort towards the distorted target (tx, ty), with the
  // analytic Jacobian of CameraModel's DistortWithJacobian; returns the squared residual
  // before the step.
  inline double NewtonStep(double tx, double ty, double* x, double* y) const {
    const double u = *x, v = *y;
    const double r2 = u * u + v * v, r4 = r2 * r2, r6 = r4 * r2;
    const double num = 1.0 + k1 * r2 + k2 * r4 + k3 * r6;
    const double den = 1.0 + k4 * r2 + k5 * r4 + k6 * r6;
    const double radial = num / den;
    const double rx = u * radial + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u) - tx;
    const double ry = v * radial + p1 * (r2 + 2.0 * v * v) + 2.0 * p2 * u * v - ty;
    const double dnum = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4;
    const double dden = k4 + 2.0 * k5 * r2 + 3.0 * k6 * r4;
    const double dradial = (dnum * den - num * dden) / (den * den);
    const double j00 = radial + u * dradial * 2.0 * u + 2.0 * p1 * v + 6.0 * p2 * u;
    const double j01 = u * dradial * 2.0 * v + 2.0 * p1 * u + 2.0 * p2 * v;
    const double j10 = v * dradial * 2.0 * u + 2.0 * p1 * u + 2.0 * p2 * v;
    const double j11 = radial + v * dradial * 2.0 * v + 6.0 * p1 * v + 2.0 * p2 * u;
    const double det = j00 * j11 - j01 * j10;
    *x = u - (j11 * rx - j01 * ry) / det;
    *y = v - (j00 * ry - j10 * rx) / det;
    return rx * rx + ry * ry;
  }
};

// Undistorted normalised coordinates (CameraModel::CamFromImage) of the integer pixels
// (x0 + i, y0 + j), i < width, j < height, CV_32FC2 (pixels outside the image too: the
// projector's plane tables need rays a few pixels beyond its border).
//
// Rows are solved together: Gauss–Newton from the distorted point on the first row of each
// range, then warm-started from the row above (one pixel away: two steps reach 1e-14),
// then one more evaluation checks CameraModel::Undistort's tolerance; a pixel that misses
// it is solved by CameraModel::Undistort itself. Results equal the per-pixel solve to its
// 1e-14 tolerance.
cv::Mat UndistortedGrid(const CameraModel& model, int x0, int y0, int width, int height) {
  cv::Mat grid(height, width, CV_32FC2);
  const Lens lens(model);
  const bool distorted = model.HasDistortion();
  constexpr int kColdSteps = 12;
  constexpr int kWarmSteps = 2;
  constexpr double kTolerance = 1e-14;  // CameraModel::Undistort's
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    std::vector<double> target_x(width), estimate_x(width), estimate_y(width), residual(width);
    for (int i = 0; i < width; ++i) target_x[i] = ((x0 + i) - lens.cx) / lens.fx;
    double previous_target_y = 0.0;
    for (int j = rows.start; j < rows.end; ++j) {
      const double target_y = ((y0 + j) - lens.cy) / lens.fy;
      cv::Vec2f* row = grid.ptr<cv::Vec2f>(j);
      if (!distorted) {
        for (int i = 0; i < width; ++i) {
          row[i] = cv::Vec2f(static_cast<float>(target_x[i]), static_cast<float>(target_y));
        }
        continue;
      }
      const bool warm = j > rows.start;
      double* __restrict ex = estimate_x.data();
      double* __restrict ey = estimate_y.data();
      double* __restrict res = residual.data();
      const double* __restrict tx = target_x.data();
      if (warm) {
        const double shift = target_y - previous_target_y;
        for (int i = 0; i < width; ++i) ey[i] += shift;
      } else {
        for (int i = 0; i < width; ++i) {
          ex[i] = tx[i];
          ey[i] = target_y;
        }
      }
      const int steps = warm ? kWarmSteps : kColdSteps;
      for (int step = 0; step < steps; ++step) {
        for (int i = 0; i < width; ++i) lens.NewtonStep(tx[i], target_y, &ex[i], &ey[i]);
      }
      for (int i = 0; i < width; ++i) {
        double xd, yd;
        lens.Distort(ex[i], ey[i], &xd, &yd);
        res[i] = (xd - tx[i]) * (xd - tx[i]) + (yd - target_y) * (yd - target_y);
      }
      for (int i = 0; i < width; ++i) {
        if (!(res[i] < kTolerance * kTolerance)) {
          const Eigen::Vector2d exact = model.Undistort(Eigen::Vector2d(tx[i], target_y));
          ex[i] = exact.x();
          ey[i] = exact.y();
        }
        row[i] = cv::Vec2f(static_cast<float>(ex[i]), static_cast<float>(ey[i]));
      }
      previous_target_y = target_y;
    }
  });
  return grid;
}

cv::Mat UndistortedGrid(const CameraModel& model) {
  return UndistortedGrid(model, 0, 0, model.width, model.height);
}

// Bilinear interpolation in a CV_32FC2 table at (x, y) ∈ [0, cols − 1] × [0, rows − 1] (the
// caller checks the range).
inline void Bilinear(const cv::Mat& table, double x, double y, double* out0, double* out1) {
  const int width = table.cols, height = table.rows;
  const int x0 = std::min(static_cast<int>(x), width - 2 < 0 ? 0 : width - 2);
  const int y0 = std::min(static_cast<int>(y), height - 2 < 0 ? 0 : height - 2);
  const int x1 = std::min(x0 + 1, width - 1), y1 = std::min(y0 + 1, height - 1);
  const double fx = x - x0, fy = y - y0;
  const cv::Vec2f* row0 = table.ptr<cv::Vec2f>(y0);
  const cv::Vec2f* row1 = table.ptr<cv::Vec2f>(y1);
  const cv::Vec2f a = row0[x0], b = row0[x1], c = row1[x0], d = row1[x1];
  *out0 = (1 - fy) * ((1 - fx) * a[0] + fx * b[0]) + fy * ((1 - fx) * c[0] + fx * d[0]);
  *out1 = (1 - fy) * ((1 - fx) * a[1] + fx * b[1]) + fy * ((1 - fx) * c[1] + fx * d[1]);
}

inline bool InTable(const cv::Mat& table, double x, double y) {
  return x >= 0 && y >= 0 && x <= table.cols - 1 && y <= table.rows - 1;
}

// Light planes of one projector axis from the ray grid `extended` (undistorted normalised
// coordinates of the projector pixels shifted by `margin`, `margin` pixels beyond every
// border): for columns, the chord through column c at rows r ± margin, n = a × b with
// a = (x_a, y_a, 1) etc., stored as (n_y, n_z) / n_x; for rows, the chord through row r at
// columns c ± margin, stored as (n_x, n_z) / n_y. CV_32FC2, [row][column].
cv::Mat PlaneTable(const cv::Mat& extended, int margin, int width, int height, bool columns) {
  cv::Mat planes(height, width, CV_32FC2);
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int r = rows.start; r < rows.end; ++r) {
      cv::Vec2f* out = planes.ptr<cv::Vec2f>(r);
      const cv::Vec2f* above = extended.ptr<cv::Vec2f>(r + margin - (columns ? margin : 0));
      const cv::Vec2f* below = extended.ptr<cv::Vec2f>(r + margin + (columns ? margin : 0));
      for (int c = 0; c < width; ++c) {
        const cv::Vec2f a = columns ? above[c + margin] : above[c];
        const cv::Vec2f b = columns ? below[c + margin] : below[c + 2 * margin];
        const double xa = a[0], ya = a[1], xb = b[0], yb = b[1];
        const double nx = ya - yb, ny = xb - xa, nz = xa * yb - ya * xb;
        out[c] = columns ? cv::Vec2f(static_cast<float>(ny / nx), static_cast<float>(nz / nx))
                         : cv::Vec2f(static_cast<float>(nx / ny), static_cast<float>(nz / ny));
      }
    }
  });
  return planes;
}

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

std::string ToString(TriangulationMethod method) {
  return method == TriangulationMethod::kMidpoint ? "midpoint" : "linear";
}

TriangulationMethod TriangulationMethodFromString(const std::string& text) {
  if (text == "midpoint") return TriangulationMethod::kMidpoint;
  if (text == "linear") return TriangulationMethod::kLinear;
  SOPE_THROW("unknown triangulation method '{}' (expected midpoint or linear)", text);
}

void TriangulationOptions::Check() const {
  SOPE_CHECK(min_depth >= 0 && max_depth > min_depth,
             "depth band [{}, {}] m is empty or negative", min_depth, max_depth);
  SOPE_CHECK(num_threads >= 1, "num_threads must be ≥ 1, got {}", num_threads);
}

Triangulator::Triangulator(const RigCalibration& calibration,
                           const TriangulationOptions& options)
    : calibration_(calibration), options_(options) {
  calibration_.Check();
  options_.Check();
  cam_from_proj_rotation_ = calibration_.proj_from_cam.rotation.transpose();
  projector_center_in_cam_ = -(cam_from_proj_rotation_ * calibration_.proj_from_cam.translation);
  camera_rays_ = UndistortedGrid(calibration_.camera);
  // The projector grid reaches kPlaneHalfSpanPx beyond the border, for the chords of the
  // plane tables; projector_rays_ is its interior (the same values).
  const CameraModel& projector = calibration_.projector;
  constexpr int kMargin = static_cast<int>(kPlaneHalfSpanPx);
  static_assert(kMargin == kPlaneHalfSpanPx, "the chord spans whole pixels");
  projector_rays_with_margin_ = UndistortedGrid(projector, -kMargin, -kMargin,
                                                projector.width + 2 * kMargin,
                                                projector.height + 2 * kMargin);
  const cv::Mat& extended = projector_rays_with_margin_;
  projector_rays_ = extended(cv::Rect(kMargin, kMargin, projector.width, projector.height));
  column_planes_ = PlaneTable(extended, kMargin, projector.width, projector.height, true);
  row_planes_ = PlaneTable(extended, kMargin, projector.width, projector.height, false);
}

size_t Triangulator::TableBytes() const {
  const auto bytes = [](const cv::Mat& m) { return m.total() * m.elemSize(); };
  return bytes(camera_rays_) + bytes(projector_rays_with_margin_) + bytes(column_planes_) +
         bytes(row_planes_);
}

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

namespace {

void CheckInputs(const RigCalibration& calibration, const CorrespondenceMap& map,
                 const cv::Mat& white) {
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

}  // namespace

TriangulationResult Triangulator::TriangulateExact(const CorrespondenceMap& map,
                                                   const cv::Mat& white) const {
  CheckInputs(calibration_, map, white);
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
    const int previous = cv::getNumThreads();
    cv::setNumThreads(options_.num_threads);
    cv::parallel_for_(cv::Range(0, height), triangulate_rows);
    cv::setNumThreads(previous);
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

// Per-thread working arrays of the fast path: one camera row's candidate pixels as
// structure-of-arrays, so the geometry loops have no branches and vectorise.
struct Triangulator::RowScratch {
  // Candidates: column, camera ray (x/z, y/z), projector coordinates.
  std::vector<int> xs;
  std::vector<double> ray_x, ray_y, proj_x, proj_y;
  // Two-axis: the projector ray; one axis: the plane (two normal components).
  std::vector<double> aux0, aux1;
  // One axis: camera ray in the projector frame, third normal component, the row (column)
  // a step linearises at and where its point lands, the step's depth.
  std::vector<double> q_x, q_y, q_z, aux2, landed, next, depth;
  std::vector<double> point_x, point_y, point_z;
  // 1 accepted, 0 rejected; exact_[i] 1: left to the exact per-point path.
  std::vector<uint8_t> ok, exact, done, valid;
  // Output of the rows this scratch has seen.
  std::vector<Eigen::Vector3f> points;
  std::vector<Color3ub> colors;
  std::vector<cv::Point> pixels;
  size_t rejected = 0;

  void Resize(size_t n) {
    for (std::vector<double>* v : {&ray_x, &ray_y, &proj_x, &proj_y, &aux0, &aux1, &q_x, &q_y,
                                   &q_z, &aux2, &landed, &next, &depth, &point_x, &point_y,
                                   &point_z}) {
      if (v->size() < n) v->resize(n);
    }
    for (std::vector<uint8_t>* v : {&ok, &exact, &done, &valid}) {
      if (v->size() < n) v->resize(n);
    }
  }
};

namespace {

// A projected row (column) further than this from the one the ray–plane's second step
// linearised at leaves the pixel to the exact path, which iterates on. Closer, the chord's
// error is second order in the distance (the plane's curvature times its square): well
// below 1e-6 m of depth for real lenses (calibration_test).
constexpr double kRayPlaneMaxRowShiftPx = 1.0;
// Ray–plane steps: the plane at the projector's centre row (column), then at the rows
// (columns) where the previous step's point lands; the plane tables (interpolated
// normals) for all but the last, which takes the exact path's chord from the ray grid.
constexpr int kRayPlaneSteps = 3;

}  // namespace

// The per-point geometry as kernels over structure-of-arrays: free functions with
// __restrict arrays and their constants copied into locals, so GCC vectorises them
// (inside the member function, it did not).
struct Pose {
  // proj_from_cam: X_proj = r·X_cam + t (row-major), and r⁻¹ = rᵀ.
  double r[9];
  double t[3];
  double center_in_cam[3];  // −rᵀ·t
};

// Midpoint of the closest approach of X = s·d_c and X = C_p + u·d_p, d_c = (x, y, 1) the
// camera ray, d_p = rᵀ·(x_p, y_p, 1) the projector ray: X = ½(s·d_c + C_p + u·d_p).
void MidpointKernel(int n, const Pose& pose, const double* __restrict ray_x,
                    const double* __restrict ray_y, const double* __restrict proj_ray_x,
                    const double* __restrict proj_ray_y, double* __restrict px,
                    double* __restrict py, double* __restrict pz, uint8_t* __restrict ok) {
  const double q00 = pose.r[0], q01 = pose.r[3], q02 = pose.r[6];
  const double q10 = pose.r[1], q11 = pose.r[4], q12 = pose.r[7];
  const double q20 = pose.r[2], q21 = pose.r[5], q22 = pose.r[8];
  const double c0 = pose.center_in_cam[0], c1 = pose.center_in_cam[1],
               c2 = pose.center_in_cam[2];
  for (int i = 0; i < n; ++i) {
    const double dcx = ray_x[i], dcy = ray_y[i];
    const double ux = proj_ray_x[i], uy = proj_ray_y[i];
    const double dpx = q00 * ux + q01 * uy + q02;
    const double dpy = q10 * ux + q11 * uy + q12;
    const double dpz = q20 * ux + q21 * uy + q22;
    const double a = dcx * dcx + dcy * dcy + 1.0;
    const double b = dcx * dpx + dcy * dpy + dpz;
    const double e = dpx * dpx + dpy * dpy + dpz * dpz;
    const double denominator = a * e - b * b;
    const double dc = dcx * c0 + dcy * c1 + c2;
    const double dp = dpx * c0 + dpy * c1 + dpz * c2;
    const double s = (dc * e - b * dp) / denominator;
    const double u = (b * dc - a * dp) / denominator;
    px[i] = 0.5 * (s * dcx + (c0 + u * dpx));
    py[i] = 0.5 * (s * dcy + (c1 + u * dpy));
    pz[i] = 0.5 * (s + (c2 + u * dpz));
    ok[i] = std::abs(denominator) >= 1e-12 * a * e;
  }
}

// Linear least squares (thesis eq. 4.1) in normalised coordinates, camera P = [I|0],
// projector P = [r|t]: rows (−1, 0, x_c), (0, −1, y_c), x_p·r₃ − r₁, y_p·r₃ − r₂ with
// b = (0, 0, t_x − x_p·t_z, t_y − y_p·t_z); the 3×3 normal equations AᵀA·X = Aᵀb solved
// by Cramer's rule.
void LinearKernel(int n, const Pose& pose, const double* __restrict ray_x,
                  const double* __restrict ray_y, const double* __restrict proj_ray_x,
                  const double* __restrict proj_ray_y, double* __restrict px,
                  double* __restrict py, double* __restrict pz, uint8_t* __restrict ok) {
  const double r00 = pose.r[0], r01 = pose.r[1], r02 = pose.r[2];
  const double r10 = pose.r[3], r11 = pose.r[4], r12 = pose.r[5];
  const double r20 = pose.r[6], r21 = pose.r[7], r22 = pose.r[8];
  const double tx = pose.t[0], ty = pose.t[1], tz = pose.t[2];
  for (int i = 0; i < n; ++i) {
    const double dcx = ray_x[i], dcy = ray_y[i];
    const double ux = proj_ray_x[i], uy = proj_ray_y[i];
    const double a20 = ux * r20 - r00, a21 = ux * r21 - r01, a22 = ux * r22 - r02;
    const double a30 = uy * r20 - r10, a31 = uy * r21 - r11, a32 = uy * r22 - r12;
    const double b2 = tx - ux * tz, b3 = ty - uy * tz;
    const double n00 = 1.0 + a20 * a20 + a30 * a30;
    const double n01 = a20 * a21 + a30 * a31;
    const double n02 = -dcx + a20 * a22 + a30 * a32;
    const double n11 = 1.0 + a21 * a21 + a31 * a31;
    const double n12 = -dcy + a21 * a22 + a31 * a32;
    const double n22 = dcx * dcx + dcy * dcy + a22 * a22 + a32 * a32;
    const double g0 = a20 * b2 + a30 * b3, g1 = a21 * b2 + a31 * b3, g2 = a22 * b2 + a32 * b3;
    const double m00 = n11 * n22 - n12 * n12, m01 = n02 * n12 - n01 * n22,
                 m02 = n01 * n12 - n02 * n11;
    const double m11 = n00 * n22 - n02 * n02, m12 = n01 * n02 - n00 * n12,
                 m22 = n00 * n11 - n01 * n01;
    const double det = n00 * m00 + n01 * m01 + n02 * m02;
    px[i] = (m00 * g0 + m01 * g1 + m02 * g2) / det;
    py[i] = (m01 * g0 + m11 * g1 + m12 * g2) / det;
    pz[i] = (m02 * g0 + m12 * g1 + m22 * g2) / det;
    ok[i] = 1;
  }
}

// ok ∧= the point is in front of the projector and reprojects within `max_px` of the
// decoded projector coordinates (not tested when NaN, as the exact path).
void ReprojectionKernel(int n, const Pose& pose, const Lens& lens_in, double max_px,
                        const double* __restrict px, const double* __restrict py,
                        const double* __restrict pz, const double* __restrict proj_x,
                        const double* __restrict proj_y, uint8_t* __restrict ok) {
  const Lens lens = lens_in;
  const double r00 = pose.r[0], r01 = pose.r[1], r02 = pose.r[2];
  const double r10 = pose.r[3], r11 = pose.r[4], r12 = pose.r[5];
  const double r20 = pose.r[6], r21 = pose.r[7], r22 = pose.r[8];
  const double tx = pose.t[0], ty = pose.t[1], tz = pose.t[2];
  for (int i = 0; i < n; ++i) {
    const double x = px[i], y = py[i], z = pz[i];
    const double xp = r00 * x + r01 * y + r02 * z + tx;
    const double yp = r10 * x + r11 * y + r12 * z + ty;
    const double zp = r20 * x + r21 * y + r22 * z + tz;
    double xd, yd;
    lens.Distort(xp / zp, yp / zp, &xd, &yd);
    const double ex = lens.fx * xd + lens.cx - proj_x[i];
    const double ey = lens.fy * yd + lens.cy - proj_y[i];
    const bool keep = (zp > 0) & !(std::sqrt(ex * ex + ey * ey) > max_px);
    ok[i] = ok[i] & keep;
  }
}

// ok ∧= min_depth ≤ z ≤ max_depth.
void DepthBandKernel(int n, double min_depth, double max_depth, const double* __restrict pz,
                     uint8_t* __restrict ok) {
  for (int i = 0; i < n; ++i) ok[i] = ok[i] & (pz[i] >= min_depth) & (pz[i] <= max_depth);
}

// q = r·(x, y, 1): the camera ray in the projector frame.
void RotateRaysKernel(int n, const Pose& pose, const double* __restrict ray_x,
                      const double* __restrict ray_y, double* __restrict qx,
                      double* __restrict qy, double* __restrict qz) {
  const double r00 = pose.r[0], r01 = pose.r[1], r02 = pose.r[2];
  const double r10 = pose.r[3], r11 = pose.r[4], r12 = pose.r[5];
  const double r20 = pose.r[6], r21 = pose.r[7], r22 = pose.r[8];
  for (int i = 0; i < n; ++i) {
    const double x = ray_x[i], y = ray_y[i];
    qx[i] = r00 * x + r01 * y + r02;
    qy[i] = r10 * x + r11 * y + r12;
    qz[i] = r20 * x + r21 * y + r22;
  }
}

// One ray–plane intersection per pixel: X_proj = s·q + t on the plane n·X_proj = 0, so
// s = −n·t / n·q; `next` the projector row (`columns`) or column where X lands, `valid`
// whether the step counts (plane not parallel to the ray, point in front of the
// projector, landing finite).
void RayPlaneKernel(int n, const Pose& pose, const Lens& lens_in, bool columns,
                    const double* __restrict qx, const double* __restrict qy,
                    const double* __restrict qz, const double* __restrict nx_in,
                    const double* __restrict ny_in, const double* __restrict nz_in,
                    double* __restrict depth, double* __restrict next,
                    uint8_t* __restrict valid) {
  const Lens lens = lens_in;
  const double tx = pose.t[0], ty = pose.t[1], tz = pose.t[2];
  const double scale = columns ? lens.fy : lens.fx, offset = columns ? lens.cy : lens.cx;
  const double pick_y = columns ? 1.0 : 0.0;
  for (int i = 0; i < n; ++i) {
    const double nx = nx_in[i], ny = ny_in[i], nz = nz_in[i];
    const double denominator = nx * qx[i] + ny * qy[i] + nz * qz[i];
    const double s = -(nx * tx + ny * ty + nz * tz) / denominator;
    const double xp = s * qx[i] + tx, yp = s * qy[i] + ty, zp = s * qz[i] + tz;
    double xd, yd;
    lens.Distort(xp / zp, yp / zp, &xd, &yd);
    const double landed = scale * (pick_y * yd + (1.0 - pick_y) * xd) + offset;
    depth[i] = s;
    next[i] = landed;
    valid[i] = (std::abs(denominator) >= 1e-12 * std::sqrt(nx * nx + ny * ny + nz * nz)) &
               (zp > 0) & (std::abs(landed) <= std::numeric_limits<double>::max());
  }
}

void Triangulator::TriangulateRow(const CorrespondenceMap& map, const uint8_t* region_row,
                                  int x_begin, int x_end, int y, RowScratch* scratch) const {
  RowScratch& w = *scratch;
  const uint8_t* mask = map.mask.ptr<uint8_t>(y);
  const float* map_x = map.HasX() ? map.proj_x.ptr<float>(y) : nullptr;
  const float* map_y = map.HasY() ? map.proj_y.ptr<float>(y) : nullptr;
  const cv::Vec2f* rays = camera_rays_.ptr<cv::Vec2f>(y);
  w.xs.clear();
  for (int x = x_begin; x < x_end; ++x) {
    if (mask[x] != 0 && (region_row == nullptr || region_row[x] != 0)) w.xs.push_back(x);
  }
  const int n = static_cast<int>(w.xs.size());
  if (n == 0) return;
  w.Resize(n);
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  for (int i = 0; i < n; ++i) {
    const int x = w.xs[i];
    w.ray_x[i] = rays[x][0];
    w.ray_y[i] = rays[x][1];
    w.proj_x[i] = map_x ? map_x[x] : kNaN;
    w.proj_y[i] = map_y ? map_y[x] : kNaN;
  }
  double* __restrict ray_x = w.ray_x.data();
  double* __restrict ray_y = w.ray_y.data();
  double* __restrict proj_x = w.proj_x.data();
  double* __restrict proj_y = w.proj_y.data();
  double* __restrict aux0 = w.aux0.data();
  double* __restrict aux1 = w.aux1.data();
  double* __restrict px = w.point_x.data();
  double* __restrict py = w.point_y.data();
  double* __restrict pz = w.point_z.data();
  uint8_t* __restrict ok = w.ok.data();
  uint8_t* __restrict exact = w.exact.data();

  Pose pose;
  for (int k = 0; k < 9; ++k) pose.r[k] = calibration_.proj_from_cam.rotation(k / 3, k % 3);
  for (int k = 0; k < 3; ++k) {
    pose.t[k] = calibration_.proj_from_cam.translation[k];
    pose.center_in_cam[k] = projector_center_in_cam_[k];
  }
  const Lens lens(calibration_.projector);

  if (map_x != nullptr && map_y != nullptr) {
    // Projector rays: bilinear in the grid (ProjectorRay's arithmetic); coordinates off
    // the grid (or not finite) go to the exact path.
    for (int i = 0; i < n; ++i) {
      const bool inside = InTable(projector_rays_, proj_x[i], proj_y[i]);
      exact[i] = !inside;
      if (inside) {
        Bilinear(projector_rays_, proj_x[i], proj_y[i], &aux0[i], &aux1[i]);
      } else {
        aux0[i] = aux1[i] = 0.0;
      }
    }
    if (options_.method == TriangulationMethod::kMidpoint) {
      MidpointKernel(n, pose, ray_x, ray_y, aux0, aux1, px, py, pz, ok);
    } else {
      LinearKernel(n, pose, ray_x, ray_y, aux0, aux1, px, py, pz, ok);
    }
    if (options_.max_reprojection_px > 0) {
      ReprojectionKernel(n, pose, lens, options_.max_reprojection_px, px, py, pz, proj_x,
                         proj_y, ok);
    }
    DepthBandKernel(n, options_.min_depth, options_.max_depth, pz, ok);
    return;
  }

  // Ray–plane: the camera ray X_proj = s·q + t (q = r·d_c) meets the plane n·X_proj = 0
  // of the coded column (row). Step 1 takes the plane at the projector's centre row
  // (column), each further step the plane at the row (column) where the previous step's
  // point lands — the exact path's re-linearisation; the plane tables (interpolated
  // normals) for all but the final step, which takes the exact path's chord.
  const bool columns = map_x != nullptr;
  const cv::Mat& planes = columns ? column_planes_ : row_planes_;
  const double* coded = columns ? proj_x : proj_y;
  const double start = columns ? lens.cy : lens.cx;
  double* __restrict qx = w.q_x.data();
  double* __restrict qy = w.q_y.data();
  double* __restrict qz = w.q_z.data();
  double* __restrict landed = w.landed.data();
  double* __restrict next = w.next.data();
  double* __restrict depth = w.depth.data();
  double* __restrict nzs = w.aux2.data();
  uint8_t* __restrict done = w.done.data();
  uint8_t* __restrict valid = w.valid.data();
  RotateRaysKernel(n, pose, ray_x, ray_y, qx, qy, qz);
  // The plane normal (projector frame) into (aux0, aux1, nzs): from the plane table
  // (dominant component 1), or for the final step the chord n = a × b of the rays at
  // other ± kPlaneHalfSpanPx, bilinear in the ray grid (with its margin) as the exact
  // path takes it. False when the coordinates are off the tables.
  const auto lookup = [&](int i, double other, bool chord) {
    const double u = columns ? coded[i] : other, v = columns ? other : coded[i];
    if (!chord) {
      const bool inside = InTable(planes, u, v);
      double first = 0.0, second = 0.0;
      if (inside) Bilinear(planes, u, v, &first, &second);
      aux0[i] = columns ? 1.0 : first;
      aux1[i] = columns ? first : 1.0;
      nzs[i] = second;
      return inside;
    }
    const cv::Mat& grid = projector_rays_with_margin_;
    const double ua = (columns ? u : u - kPlaneHalfSpanPx) + kPlaneHalfSpanPx;
    const double va = (columns ? v - kPlaneHalfSpanPx : v) + kPlaneHalfSpanPx;
    const double ub = (columns ? u : u + kPlaneHalfSpanPx) + kPlaneHalfSpanPx;
    const double vb = (columns ? v + kPlaneHalfSpanPx : v) + kPlaneHalfSpanPx;
    const bool inside = InTable(grid, ua, va) && InTable(grid, ub, vb);
    double xa = 0.0, ya = 0.0, xb = 0.0, yb = 0.0;
    if (inside) {
      Bilinear(grid, ua, va, &xa, &ya);
      Bilinear(grid, ub, vb, &xb, &yb);
    }
    aux0[i] = ya - yb;
    aux1[i] = xb - xa;
    nzs[i] = xa * yb - ya * xb;
    return inside;
  };
  // `landed` holds the row (column) each step linearises at; `done` marks pixels whose
  // iteration stopped there (the exact path's |next − other| < 1e-3 px).
  for (int i = 0; i < n; ++i) {
    exact[i] = !lookup(i, start, /*chord=*/false);
    landed[i] = start;
    done[i] = 0;
    ok[i] = 1;
  }
  for (int step = 0; step + 1 < kRayPlaneSteps; ++step) {
    RayPlaneKernel(n, pose, lens, columns, qx, qy, qz, aux0, aux1, nzs, depth, next, valid);
    const bool last_table_step = step + 2 == kRayPlaneSteps;
    for (int i = 0; i < n; ++i) {
      const bool active = (ok[i] != 0) & (done[i] == 0) & (exact[i] == 0);
      // An invalid step rejects, as the exact path's iteration would.
      ok[i] = ok[i] & (!active | (valid[i] != 0));
      const bool moved = !(std::abs(next[i] - landed[i]) < 1e-3);
      done[i] = done[i] | (active & (valid[i] != 0) & !moved);
      landed[i] = (active & (valid[i] != 0) & moved) ? next[i] : landed[i];
    }
    for (int i = 0; i < n; ++i) {
      if (ok[i] != 0 && exact[i] == 0 && (done[i] == 0 || last_table_step) &&
          !lookup(i, landed[i], /*chord=*/last_table_step)) {
        exact[i] = 1;
      }
    }
  }
  // The final step with the chord at the row (column) the iteration stopped at; a row
  // (column) still moving more than kRayPlaneMaxRowShiftPx after it is left to the exact
  // path (the chord's error is second order in that shift).
  RayPlaneKernel(n, pose, lens, columns, qx, qy, qz, aux0, aux1, nzs, depth, next, valid);
  for (int i = 0; i < n; ++i) {
    const bool active = (ok[i] != 0) & (exact[i] == 0);
    ok[i] = ok[i] & (!active | (valid[i] != 0));
    exact[i] = exact[i] | (active & (valid[i] != 0) & (done[i] == 0) &
                           !(std::abs(next[i] - landed[i]) < kRayPlaneMaxRowShiftPx));
    const double s = depth[i];
    px[i] = s * ray_x[i];
    py[i] = s * ray_y[i];
    pz[i] = s;
  }
  DepthBandKernel(n, options_.min_depth, options_.max_depth, pz, ok);
}

TriangulationResult Triangulator::Triangulate(const CorrespondenceMap& map,
                                              const cv::Mat& white) const {
  return Triangulate(map, white, TriangulationRegion());
}

TriangulationResult Triangulator::Triangulate(const CorrespondenceMap& map, const cv::Mat& white,
                                              const TriangulationRegion& region) const {
  CheckInputs(calibration_, map, white);
  const CameraModel& camera = calibration_.camera;
  const int height = camera.height, width = camera.width;
  SOPE_CHECK(region.mask.empty() || (region.mask.type() == CV_8UC1 &&
                                     region.mask.cols == width && region.mask.rows == height),
             "triangulation region mask must be CV_8UC1 {}x{} (the camera size)", width, height);
  const cv::Rect image(0, 0, width, height);
  const cv::Rect roi = region.roi.empty() ? image : (region.roi & image);
  TriangulationResult result;
  result.depth = cv::Mat(height, width, CV_32FC1,
                         cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  if (roi.empty()) return result;

  // Rows are split into contiguous blocks, each triangulated into its own scratch (in
  // parallel when asked) and concatenated in row order: the output is the same for any
  // thread count.
  const int num_blocks = options_.num_threads > 1 ? std::min(roi.height, 4 * options_.num_threads)
                                                  : 1;
  std::vector<RowScratch> blocks(num_blocks);
  if (num_blocks == 1) {
    // One block writes straight into its output: reserve the upper bound once.
    const size_t candidates = static_cast<size_t>(cv::countNonZero(map.mask(roi)));
    blocks[0].points.reserve(candidates);
    blocks[0].pixels.reserve(candidates);
    if (!white.empty()) blocks[0].colors.reserve(candidates);
  }
  const auto run_blocks = [&](const cv::Range& range) {
    for (int b = range.start; b < range.end; ++b) {
      RowScratch& w = blocks[b];
      const int y_begin = roi.y + static_cast<int>(static_cast<int64_t>(roi.height) * b / num_blocks);
      const int y_end =
          roi.y + static_cast<int>(static_cast<int64_t>(roi.height) * (b + 1) / num_blocks);
      for (int y = y_begin; y < y_end; ++y) {
        const uint8_t* region_row = region.mask.empty() ? nullptr : region.mask.ptr<uint8_t>(y);
        TriangulateRow(map, region_row, roi.x, roi.x + roi.width, y, &w);
        float* depth = result.depth.ptr<float>(y);
        const float* map_x = map.HasX() ? map.proj_x.ptr<float>(y) : nullptr;
        const float* map_y = map.HasY() ? map.proj_y.ptr<float>(y) : nullptr;
        const int n = static_cast<int>(w.xs.size());
        for (int i = 0; i < n; ++i) {
          const int x = w.xs[i];
          Eigen::Vector3d point(w.point_x[i], w.point_y[i], w.point_z[i]);
          if (w.exact[i] != 0) {
            const float kNaN = std::numeric_limits<float>::quiet_NaN();
            const std::optional<Eigen::Vector3d> exact_point = Intersect(
                CameraRay(x, y), map_x ? map_x[x] : kNaN, map_y ? map_y[x] : kNaN);
            if (!exact_point) {
              ++w.rejected;
              continue;
            }
            point = *exact_point;
          } else if (w.ok[i] == 0) {
            ++w.rejected;
            continue;
          }
          depth[x] = static_cast<float>(point.z());
          w.points.push_back(point.cast<float>());
          if (!white.empty()) w.colors.push_back(PixelColor(white, x, y));
          w.pixels.emplace_back(x, y);
        }
      }
    }
  };
  if (num_blocks > 1) {
    const int previous = cv::getNumThreads();
    cv::setNumThreads(options_.num_threads);
    cv::parallel_for_(cv::Range(0, num_blocks), run_blocks);
    cv::setNumThreads(previous);
  } else {
    run_blocks(cv::Range(0, 1));
  }
  if (num_blocks == 1) {
    result.cloud.points = std::move(blocks[0].points);
    result.cloud.colors = std::move(blocks[0].colors);
    result.pixels = std::move(blocks[0].pixels);
    result.rejected = blocks[0].rejected;
    return result;
  }
  size_t total = 0;
  for (const RowScratch& block : blocks) total += block.points.size();
  result.cloud.points.reserve(total);
  if (!white.empty()) result.cloud.colors.reserve(total);
  result.pixels.reserve(total);
  for (const RowScratch& block : blocks) {
    result.cloud.points.insert(result.cloud.points.end(), block.points.begin(),
                               block.points.end());
    result.cloud.colors.insert(result.cloud.colors.end(), block.colors.begin(),
                               block.colors.end());
    result.pixels.insert(result.pixels.end(), block.pixels.begin(), block.pixels.end());
    result.rejected += block.rejected;
  }
  return result;
}

TriangulationResult Triangulate(const CorrespondenceMap& map,
                                const RigCalibration& calibration, const cv::Mat& white,
                                const TriangulationOptions& options) {
  return Triangulator(calibration, options).Triangulate(map, white);
}

}  // namespace sope
