#include "recogniser/near_symmetry.h"

#include <cmath>
#include <vector>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

namespace sope {
namespace {

// A closed cylinder of `radius` and `height` about the z axis (base at z = 0), surface
// points about `spacing` apart; with `handle`, a 1 cm thick slab standing 3 cm off its side
// along +x (a mug's handle, seen as a block).
std::vector<Eigen::Vector3f> Cylinder(double radius, double height, bool handle, double spacing = 0.003) {
  std::vector<Eigen::Vector3f> points;
  const int around = static_cast<int>(std::ceil(2 * M_PI * radius / spacing));
  for (int a = 0; a < around; ++a) {
    const double t = 2 * M_PI * a / around;
    for (double z = 0; z <= height; z += spacing) {
      points.emplace_back(radius * std::cos(t), radius * std::sin(t), z);
    }
  }
  for (double x = -radius; x <= radius; x += spacing) {  // the two ends
    for (double y = -radius; y <= radius; y += spacing) {
      if (x * x + y * y > radius * radius) continue;
      points.emplace_back(x, y, 0.0);
      points.emplace_back(x, y, height);
    }
  }
  if (handle) {
    for (double x = radius; x <= radius + 0.03; x += spacing) {
      for (double z = 0.2 * height; z <= 0.8 * height; z += spacing) {
        for (const double y : {-0.005, 0.005}) points.emplace_back(x, y, z);
      }
    }
  }
  return points;
}

// `points` turned by `rotation` and moved by `shift`.
std::vector<Eigen::Vector3f> Moved(std::vector<Eigen::Vector3f> points, const Eigen::Matrix3d& rotation,
                                   const Eigen::Vector3d& shift) {
  for (Eigen::Vector3f& p : points) p = (rotation * p.cast<double>() + shift).cast<float>();
  return points;
}

TEST(NearSymmetryAxis, AMugBodyGivesItsAxisAndTheHandleItsAsymmetry) {
  // The cylinder's axis tilted and moved off the origin: the axis found must be it.
  const Eigen::Matrix3d rotation =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 0.5).normalized()).toRotationMatrix();
  const Eigen::Vector3d shift(0.02, -0.05, 0.6);
  const Eigen::Vector3d true_direction = rotation.col(2);
  const auto distance_to_true_axis = [&](const Eigen::Vector3d& p) {
    const Eigen::Vector3d d = p - shift;
    return (d - d.dot(true_direction) * true_direction).norm();
  };
  const NearSymmetryAxis mug = FindNearSymmetryAxis(Moved(Cylinder(0.04, 0.1, true), rotation, shift), 0.0045);
  ASSERT_TRUE(mug.found);
  EXPECT_GT(std::abs(mug.direction.dot(true_direction)), std::cos(2.0 * M_PI / 180));
  EXPECT_LT(distance_to_true_axis(mug.point), 0.002);
  // The handle is ~8% of the points; turned, most of them leave the surface.
  EXPECT_GT(mug.asymmetric_fraction, 0.03);
  EXPECT_LT(mug.asymmetric_fraction, 0.15);

  // Without the handle: the same axis, and turning moves (almost) nothing.
  const NearSymmetryAxis glass = FindNearSymmetryAxis(Moved(Cylinder(0.04, 0.1, false), rotation, shift), 0.0045);
  ASSERT_TRUE(glass.found);
  EXPECT_GT(std::abs(glass.direction.dot(true_direction)), std::cos(2.0 * M_PI / 180));
  EXPECT_LT(glass.asymmetric_fraction, 0.01);
}

TEST(NearSymmetryAxis, ABoxHasNone) {
  // A 12 × 7 × 4 cm box's faces, 3 mm apart: no circle holds its sides, and no turn by 60°
  // keeps it on itself.
  std::vector<Eigen::Vector3f> points;
  const Eigen::Vector3d size(0.12, 0.07, 0.04);
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    for (double a = 0; a <= size[u]; a += 0.003) {
      for (double b = 0; b <= size[v]; b += 0.003) {
        for (const double side : {0.0, size[axis]}) {
          Eigen::Vector3d p;
          p[axis] = side, p[u] = a, p[v] = b;
          points.push_back(p.cast<float>());
        }
      }
    }
  }
  const NearSymmetryAxis box = FindNearSymmetryAxis(points, 0.0045);
  EXPECT_FALSE(box.found) << "asymmetric fraction " << box.asymmetric_fraction;
  EXPECT_GT(box.asymmetric_fraction, 0.35);
}

}  // namespace
}  // namespace sope
