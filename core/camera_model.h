// Pinhole lens with OpenCV's distortion model, shared by the camera and by the projector
// (an "inverse camera"). Pixel convention is OpenCV's: the centre of the top-left pixel is
// (0, 0); projector column c lights the projector pixel whose centre is x = c.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace sope {

// Largest camera/projector image sope accepts: a side of 16384 pixels and 32 Mpx in all
// (a frame set holds tens of such frames in memory; beyond this allocations fail).
constexpr int kMaxImageSide = 16384;
constexpr int64_t kMaxImagePixels = int64_t{1} << 25;

struct CameraModel {
  int width = 0;   // pixels
  int height = 0;  // pixels
  // Intrinsics in pixels: [fx 0 cx; 0 fy cy; 0 0 1].
  Eigen::Matrix3d matrix = Eigen::Matrix3d::Identity();
  // OpenCV order (k1, k2, p1, p2[, k3[, k4, k5, k6]]): 0, 4, 5 or 8 coefficients.
  std::vector<double> distortion;

  double fx() const { return matrix(0, 0); }
  double fy() const { return matrix(1, 1); }
  double cx() const { return matrix(0, 2); }
  double cy() const { return matrix(1, 2); }

  // Throws sope::Error naming the offending value when sizes (1..kMaxImageSide, at most
  // kMaxImagePixels), focal lengths, the matrix's bottom row (must be 0 0 1) or the
  // number of distortion coefficients are invalid.
  void Check() const;
  bool HasDistortion() const;

  // Normalised image plane (z = 1, undistorted) → distorted normalised coordinates.
  Eigen::Vector2d Distort(const Eigen::Vector2d& undistorted) const;
  // Inverse of Distort by Gauss–Newton with an analytic Jacobian (converges to 1e-12 in
  // a few iterations for realistic lenses, unlike cv::undistortPoints' fixed 5 steps).
  Eigen::Vector2d Undistort(const Eigen::Vector2d& distorted) const;

  // Point in the device frame (metres, z forward) → pixel. Points behind the device give
  // an undefined pixel; callers test z > 0.
  Eigen::Vector2d ImageFromCam(const Eigen::Vector3d& point_in_cam) const;
  // Pixel → point on the normalised plane z = 1 (undistorted): the ray through the pixel.
  Eigen::Vector2d CamFromImage(const Eigen::Vector2d& pixel) const;
  // Unit-length ray direction through a pixel, device frame.
  Eigen::Vector3d RayFromImage(const Eigen::Vector2d& pixel) const;
};

// Pinhole model from a field of view: fx = fy = width / (2·tan(hfov/2)), principal point at
// the image centre, no distortion. `horizontal_fov` in radians.
CameraModel MakePinhole(int width, int height, double horizontal_fov);

}  // namespace sope
