#include "core/camera_model.h"

#include <cmath>

#include <Eigen/Dense>

#include "core/error.h"

namespace sope {
namespace {

// Coefficient i of the OpenCV vector, 0 when absent.
double Coeff(const std::vector<double>& d, size_t i) { return i < d.size() ? d[i] : 0.0; }

// Distortion and its 2×2 Jacobian with respect to the undistorted point.
void DistortWithJacobian(const std::vector<double>& d, const Eigen::Vector2d& p,
                         Eigen::Vector2d* distorted, Eigen::Matrix2d* jacobian) {
  const double k1 = Coeff(d, 0), k2 = Coeff(d, 1), p1 = Coeff(d, 2), p2 = Coeff(d, 3);
  const double k3 = Coeff(d, 4), k4 = Coeff(d, 5), k5 = Coeff(d, 6), k6 = Coeff(d, 7);
  const double x = p.x(), y = p.y();
  const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
  const double num = 1.0 + k1 * r2 + k2 * r4 + k3 * r6;
  const double den = 1.0 + k4 * r2 + k5 * r4 + k6 * r6;
  const double radial = num / den;
  (*distorted) << x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
      y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
  if (jacobian != nullptr) {
    const double dnum_dr2 = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4;
    const double dden_dr2 = k4 + 2.0 * k5 * r2 + 3.0 * k6 * r4;
    const double dradial_dr2 = (dnum_dr2 * den - num * dden_dr2) / (den * den);
    const double dradial_dx = dradial_dr2 * 2.0 * x;
    const double dradial_dy = dradial_dr2 * 2.0 * y;
    (*jacobian)(0, 0) = radial + x * dradial_dx + 2.0 * p1 * y + 6.0 * p2 * x;
    (*jacobian)(0, 1) = x * dradial_dy + 2.0 * p1 * x + 2.0 * p2 * y;
    (*jacobian)(1, 0) = y * dradial_dx + 2.0 * p1 * x + 2.0 * p2 * y;
    (*jacobian)(1, 1) = radial + y * dradial_dy + 6.0 * p1 * y + 2.0 * p2 * x;
  }
}

}  // namespace

void CameraModel::Check() const {
  SOPE_CHECK(width > 0 && height > 0, "invalid image size {}x{}", width, height);
  SOPE_CHECK(width <= kMaxImageSide && height <= kMaxImageSide &&
                 static_cast<int64_t>(width) * height <= kMaxImagePixels,
             "image size {}x{} is beyond the limit ({} pixels a side, {} Mpx in all)", width,
             height, kMaxImageSide, kMaxImagePixels >> 20);
  SOPE_CHECK(matrix(2, 0) == 0.0 && matrix(2, 1) == 0.0 && matrix(2, 2) == 1.0,
             "camera matrix bottom row must be 0 0 1, got {} {} {}", matrix(2, 0), matrix(2, 1),
             matrix(2, 2));
  SOPE_CHECK(matrix(1, 0) == 0.0 && std::isfinite(matrix(0, 1)),
             "camera matrix must have the form [fx s cx; 0 fy cy; 0 0 1] (element (1,0) is {}, "
             "skew {})", matrix(1, 0), matrix(0, 1));
  SOPE_CHECK(std::isfinite(fx()) && std::isfinite(fy()) && fx() > 0 && fy() > 0,
             "invalid focal lengths fx={} fy={}", fx(), fy());
  SOPE_CHECK(std::isfinite(cx()) && std::isfinite(cy()), "invalid principal point ({}, {})",
             cx(), cy());
  SOPE_CHECK(distortion.empty() || distortion.size() == 4 || distortion.size() == 5 ||
                 distortion.size() == 8,
             "distortion must have 0, 4, 5 or 8 coefficients, got {}", distortion.size());
  for (double c : distortion) {
    SOPE_CHECK(std::isfinite(c), "distortion coefficient is not finite");
  }
}

bool CameraModel::HasDistortion() const {
  for (double c : distortion) {
    if (c != 0.0) return true;
  }
  return false;
}

Eigen::Vector2d CameraModel::Distort(const Eigen::Vector2d& undistorted) const {
  if (!HasDistortion()) return undistorted;
  Eigen::Vector2d distorted;
  DistortWithJacobian(distortion, undistorted, &distorted, nullptr);
  return distorted;
}

Eigen::Vector2d CameraModel::Undistort(const Eigen::Vector2d& distorted) const {
  if (!HasDistortion()) return distorted;
  Eigen::Vector2d estimate = distorted;
  constexpr int kMaxIterations = 20;
  constexpr double kTolerance = 1e-14;
  for (int i = 0; i < kMaxIterations; ++i) {
    Eigen::Vector2d predicted;
    Eigen::Matrix2d jacobian;
    DistortWithJacobian(distortion, estimate, &predicted, &jacobian);
    const Eigen::Vector2d residual = predicted - distorted;
    if (residual.squaredNorm() < kTolerance * kTolerance) break;
    estimate -= jacobian.partialPivLu().solve(residual);
  }
  return estimate;
}

Eigen::Vector2d CameraModel::ImageFromCam(const Eigen::Vector3d& point_in_cam) const {
  const Eigen::Vector2d distorted =
      Distort(Eigen::Vector2d(point_in_cam.x() / point_in_cam.z(),
                              point_in_cam.y() / point_in_cam.z()));
  return Eigen::Vector2d(fx() * distorted.x() + cx(), fy() * distorted.y() + cy());
}

Eigen::Vector2d CameraModel::CamFromImage(const Eigen::Vector2d& pixel) const {
  return Undistort(Eigen::Vector2d((pixel.x() - cx()) / fx(), (pixel.y() - cy()) / fy()));
}

Eigen::Vector3d CameraModel::RayFromImage(const Eigen::Vector2d& pixel) const {
  return CamFromImage(pixel).homogeneous().normalized();
}

CameraModel MakePinhole(int width, int height, double horizontal_fov) {
  CameraModel model;
  model.width = width;
  model.height = height;
  const double focal = width / (2.0 * std::tan(horizontal_fov / 2.0));
  model.matrix << focal, 0, (width - 1) / 2.0, 0, focal, (height - 1) / 2.0, 0, 0, 1;
  return model;
}

}  // namespace sope
