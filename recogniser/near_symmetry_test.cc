#include "recogniser/near_symmetry.h"

#include <cmath>
#include <optional>
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

// The side of a standing surface a camera at `camera` sees: the points (and their outward
// normals) of `points`/`normals` facing it, handed over in a frame turned by `turn`
// (cam_from_points = turn) with a little deterministic noise on the normals (±3°).
struct SeenSurface {
  std::vector<Eigen::Vector3f> points, normals;
};
SeenSurface SeenFrom(const std::vector<Eigen::Vector3f>& points,
                     const std::vector<Eigen::Vector3f>& normals, const Eigen::Vector3d& camera,
                     const Eigen::Matrix3d& turn) {
  SeenSurface seen;
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d p = points[i].cast<double>();
    Eigen::Vector3d n = normals[i].cast<double>();
    if (n.dot(camera - p) <= 0) continue;
    const double wobble = 0.05 * std::sin(12.9898 * static_cast<double>(i));
    n = (n + wobble * n.unitOrthogonal()).normalized();
    seen.points.push_back((turn.transpose() * p).cast<float>());
    seen.normals.push_back((turn.transpose() * n).cast<float>());
  }
  return seen;
}

// The table is z = 0 (up +z, offset 0) in the frame the camera's results are given in; the
// points are handed over turned, so the frame change is exercised too.
const Eigen::Vector3d kUp = Eigen::Vector3d::UnitZ();
const Eigen::Vector3d kCamera(0.1, -0.5, 0.4);  // ~40° down onto the objects
const Eigen::Matrix3d kTurn =
    Eigen::AngleAxisd(0.9, Eigen::Vector3d(0.3, -1, 0.4).normalized()).toRotationMatrix();

TEST(StandingAxis, AStandingCylinderSeenFromOneSideGivesItsAxis) {
  // A mug-sized cylinder standing at (0.03, 0.02) on the table, its wall and top seen from
  // the camera (about half of the wall): the axis must be found within 1 mm — and with a
  // handle standing off the wall, within 2 mm.
  const Eigen::Vector3d foot(0.03, 0.02, 0.0);
  for (const bool handle : {false, true}) {
    const std::vector<Eigen::Vector3f> body = Cylinder(0.04, 0.1, handle);
    std::vector<Eigen::Vector3f> points, normals;
    for (const Eigen::Vector3f& q : body) {
      const Eigen::Vector3d p = q.cast<double>();
      Eigen::Vector3d n;
      if (p.z() <= 1e-9) continue;  // the base rests on the table
      if (p.z() >= 0.1 - 1e-9) {
        n = kUp;
      } else if (p.head<2>().norm() > 0.04 + 1e-6) {
        n = Eigen::Vector3d(0, p.y() > 0 ? 1 : -1, 0);  // the handle's faces
      } else {
        n = Eigen::Vector3d(p.x(), p.y(), 0).normalized();
      }
      points.push_back((p + foot).cast<float>());
      normals.push_back(n.cast<float>());
    }
    const SeenSurface seen = SeenFrom(points, normals, kCamera, kTurn);
    const std::optional<Eigen::Vector3d> axis =
        StandingAxisPoint(seen.points, seen.normals, kTurn, kUp, 0.0);
    ASSERT_TRUE(axis.has_value()) << (handle ? "with" : "without") << " the handle";
    EXPECT_NEAR(axis->z(), 0.0, 1e-9) << "the point returned lies on the table";
    EXPECT_LT((axis->head<2>() - foot.head<2>()).norm(), handle ? 0.002 : 0.001)
        << (handle ? "with" : "without") << " the handle: " << axis->transpose();
  }
}

TEST(StandingAxis, AStandingBoxGivesTheCrossingOfItsSidesAndOneFaceNone) {
  // A 12 × 7 cm box 10 cm tall standing at (−0.02, 0.05): its two sides the camera sees
  // cross at its centre line.
  const Eigen::Vector3d centre(-0.02, 0.05, 0.0), half(0.06, 0.035, 0.05);
  std::vector<Eigen::Vector3f> points, normals;
  for (int axis = 0; axis < 2; ++axis) {
    const int other = 1 - axis;
    for (const double side : {-1.0, 1.0}) {
      for (double a = -half[other]; a <= half[other]; a += 0.003) {
        for (double z = 0.003; z <= 0.1; z += 0.003) {
          Eigen::Vector3d p = centre, n = Eigen::Vector3d::Zero();
          p[axis] += side * half[axis];
          p[other] += a;
          p.z() = z;
          n[axis] = side;
          points.push_back(p.cast<float>());
          normals.push_back(n.cast<float>());
        }
      }
    }
  }
  const SeenSurface seen = SeenFrom(points, normals, kCamera, kTurn);
  const std::optional<Eigen::Vector3d> axis =
      StandingAxisPoint(seen.points, seen.normals, kTurn, kUp, 0.0);
  ASSERT_TRUE(axis.has_value());
  EXPECT_LT((axis->head<2>() - centre.head<2>()).norm(), 0.002) << axis->transpose();

  // One face alone: its lines are parallel, no point is pinned.
  SeenSurface face;
  for (size_t i = 0; i < seen.points.size(); ++i) {
    const Eigen::Vector3d n = kTurn * seen.normals[i].cast<double>();
    if (n.y() < -0.9) {
      face.points.push_back(seen.points[i]);
      face.normals.push_back(seen.normals[i]);
    }
  }
  ASSERT_GT(face.points.size(), 100u);
  EXPECT_FALSE(StandingAxisPoint(face.points, face.normals, kTurn, kUp, 0.0).has_value());
}

}  // namespace
}  // namespace sope
