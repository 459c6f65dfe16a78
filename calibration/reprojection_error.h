// Reprojection errors of the camera–projector bundle adjustment, templated for Ceres'
// automatic differentiation. The lens model is core/camera_model.cc's (OpenCV's) written
// once more as a template; reprojection_error_test.cc checks the two agree to 1e-9 px.
#pragma once

#include <ceres/rotation.h>

namespace sope {
namespace internal {

// Parameter block layouts.
constexpr int kIntrinsicsSize = 4;  // fx, fy, cx, cy (pixels)
constexpr int kDistortionSize = 5;  // k1, k2, p1, p2, k3 (OpenCV order)
constexpr int kPoseSize = 6;        // angle-axis (radians) then translation (metres)

// OpenCV's distortion of the undistorted normalised point (x, y) (z = 1 plane):
//   r² = x² + y²,  radial = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶),
//   x_d = x·radial + 2 p1 x y + p2 (r² + 2x²),  y_d = y·radial + p1 (r² + 2y²) + 2 p2 x y.
// `coefficients` holds kNumCoefficients ∈ {4, 5, 8} values in OpenCV order (k1, k2, p1, p2,
// k3, k4, k5, k6); missing ones are 0.
template <int kNumCoefficients, typename T>
void DistortOpenCv(const T* coefficients, const T& x, const T& y, T* distorted_x, T* distorted_y) {
  static_assert(kNumCoefficients == 4 || kNumCoefficients == 5 || kNumCoefficients == 8,
                "OpenCV distortion has 4, 5 or 8 coefficients");
  const T& k1 = coefficients[0];
  const T& k2 = coefficients[1];
  const T& p1 = coefficients[2];
  const T& p2 = coefficients[3];
  const T r2 = x * x + y * y;
  const T r4 = r2 * r2;
  const T r6 = r4 * r2;
  T numerator = T(1.0) + k1 * r2 + k2 * r4;
  if constexpr (kNumCoefficients >= 5) numerator += coefficients[4] * r6;
  T radial = numerator;
  if constexpr (kNumCoefficients == 8) {
    radial /= T(1.0) + coefficients[5] * r2 + coefficients[6] * r4 + coefficients[7] * r6;
  }
  *distorted_x = x * radial + T(2.0) * p1 * x * y + p2 * (r2 + T(2.0) * x * x);
  *distorted_y = y * radial + p1 * (r2 + T(2.0) * y * y) + T(2.0) * p2 * x * y;
}

// Pixel of a point in the device frame (z forward): intrinsics [fx, fy, cx, cy],
// distortion [k1, k2, p1, p2, k3]. As CameraModel::ImageFromCam.
template <typename T>
void ImageFromDevice(const T* intrinsics, const T* distortion, const T* point_in_device, T* pixel) {
  const T x = point_in_device[0] / point_in_device[2];
  const T y = point_in_device[1] / point_in_device[2];
  T distorted_x, distorted_y;
  DistortOpenCv<kDistortionSize>(distortion, x, y, &distorted_x, &distorted_y);
  pixel[0] = intrinsics[0] * distorted_x + intrinsics[2];
  pixel[1] = intrinsics[1] * distorted_y + intrinsics[3];
}

// b_from_a pose block [angle-axis, translation] applied to a point: X_b = R·X_a + t.
template <typename T>
void TransformPoint(const T* b_from_a, const T* point_in_a, T* point_in_b) {
  ceres::AngleAxisRotatePoint(b_from_a, point_in_a, point_in_b);
  point_in_b[0] += b_from_a[3];
  point_in_b[1] += b_from_a[4];
  point_in_b[2] += b_from_a[5];
}

// Camera residual of one board corner, pixels (predicted − observed):
//   x_cam = π_cam(cam_from_board · X_board).
// Blocks: camera intrinsics (4), camera distortion (5), cam_from_board (6).
struct CameraReprojectionError {
  CameraReprojectionError(const double* corner_in_board, const double* observed_px)
      : corner_in_board_{corner_in_board[0], corner_in_board[1], corner_in_board[2]},
        observed_px_{observed_px[0], observed_px[1]} {}

  template <typename T>
  bool operator()(const T* intrinsics, const T* distortion, const T* cam_from_board,
                  T* residual) const {
    const T corner[3] = {T(corner_in_board_[0]), T(corner_in_board_[1]), T(corner_in_board_[2])};
    T point_in_cam[3];
    TransformPoint(cam_from_board, corner, point_in_cam);
    T pixel[2];
    ImageFromDevice(intrinsics, distortion, point_in_cam, pixel);
    residual[0] = pixel[0] - T(observed_px_[0]);
    residual[1] = pixel[1] - T(observed_px_[1]);
    return true;
  }

 private:
  double corner_in_board_[3];
  double observed_px_[2];
};

// Projector residual of one board corner, projector pixels (predicted − observed):
//   x_proj = π_proj(proj_from_cam · cam_from_board · X_board).
// Blocks: projector intrinsics (4), projector distortion (5), proj_from_cam (6),
// cam_from_board (6).
struct ProjectorReprojectionError {
  ProjectorReprojectionError(const double* corner_in_board, const double* observed_px)
      : corner_in_board_{corner_in_board[0], corner_in_board[1], corner_in_board[2]},
        observed_px_{observed_px[0], observed_px[1]} {}

  template <typename T>
  bool operator()(const T* intrinsics, const T* distortion, const T* proj_from_cam,
                  const T* cam_from_board, T* residual) const {
    const T corner[3] = {T(corner_in_board_[0]), T(corner_in_board_[1]), T(corner_in_board_[2])};
    T point_in_cam[3], point_in_proj[3];
    TransformPoint(cam_from_board, corner, point_in_cam);
    TransformPoint(proj_from_cam, point_in_cam, point_in_proj);
    T pixel[2];
    ImageFromDevice(intrinsics, distortion, point_in_proj, pixel);
    residual[0] = pixel[0] - T(observed_px_[0]);
    residual[1] = pixel[1] - T(observed_px_[1]);
    return true;
  }

 private:
  double corner_in_board_[3];
  double observed_px_[2];
};

}  // namespace internal
}  // namespace sope
