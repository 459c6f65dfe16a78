// A rigid transform b_from_a: X_b = rotation · X_a + translation (metres).
#pragma once

#include <algorithm>
#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace sope {

struct Rigid3d {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Rigid3d() = default;
  Rigid3d(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation)
      : rotation(rotation), translation(translation) {}

  Eigen::Vector3d operator*(const Eigen::Vector3d& point_in_a) const {
    return rotation * point_in_a + translation;
  }
  // c_from_b * b_from_a = c_from_a.
  Rigid3d operator*(const Rigid3d& b_from_a) const {
    return Rigid3d(rotation * b_from_a.rotation, rotation * b_from_a.translation + translation);
  }
  // a_from_b.
  Rigid3d Inverse() const {
    const Eigen::Matrix3d rotation_t = rotation.transpose();
    return Rigid3d(rotation_t, -(rotation_t * translation));
  }
  Eigen::Matrix4d ToMatrix() const {
    Eigen::Matrix4d matrix = Eigen::Matrix4d::Identity();
    matrix.topLeftCorner<3, 3>() = rotation;
    matrix.topRightCorner<3, 1>() = translation;
    return matrix;
  }
};

// Rotation from Euler angles in radians applied as R = Rz(rz)·Ry(ry)·Rx(rx) (extrinsic
// x, then y, then z) — the convention of the CLI's `--object-pose rx,ry,rz,tx,ty,tz`.
inline Eigen::Matrix3d RotationFromEulerXYZ(double rx, double ry, double rz) {
  return (Eigen::AngleAxisd(rz, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(ry, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(rx, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

// Angle of the rotation between two rotation matrices, radians in [0, π].
inline double RotationAngleBetween(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  const double cos_angle = std::clamp(((a.transpose() * b).trace() - 1.0) / 2.0, -1.0, 1.0);
  return std::acos(cos_angle);
}

}  // namespace sope
