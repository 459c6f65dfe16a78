#include "simulator/primitives.h"

#include <cmath>
#include <map>
#include <utility>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "core/error.h"
#include "core/units.h"
#include "tests/test_support.h"

namespace sope {
namespace {


// Directed edge → number of faces using it.
std::map<std::pair<int, int>, int> DirectedEdges(const TriangleMesh& mesh) {
  std::map<std::pair<int, int>, int> edges;
  for (const Eigen::Vector3i& f : mesh.faces) {
    for (int k = 0; k < 3; ++k) ++edges[{f[k], f[(k + 1) % 3]}];
  }
  return edges;
}

// Every edge used once in each direction: closed, consistently oriented, manifold.
bool IsWatertight(const TriangleMesh& mesh) {
  const auto edges = DirectedEdges(mesh);
  for (const auto& [edge, count] : edges) {
    if (count != 1) return false;
    const auto reverse = edges.find({edge.second, edge.first});
    if (reverse == edges.end() || reverse->second != 1) return false;
  }
  return true;
}

// No directed edge twice: neighbouring faces agree on orientation.
bool IsConsistentlyOriented(const TriangleMesh& mesh) {
  for (const auto& [edge, count] : DirectedEdges(mesh)) {
    if (count != 1) return false;
  }
  return true;
}

// Signed volume by the divergence theorem; positive for outward faces.
double SignedVolume(const TriangleMesh& mesh) {
  double volume = 0.0;
  for (const Eigen::Vector3i& f : mesh.faces) {
    const Eigen::Vector3d a = mesh.vertices[f[0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[f[1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[f[2]].cast<double>();
    volume += a.dot(b.cross(c)) / 6.0;
  }
  return volume;
}

TEST(Primitives, PlaneFacesMinusZAndSpansItsSize) {
  const TriangleMesh plane = MakePlane(0.4, 0.3, 5);
  EXPECT_NO_THROW(plane.Check());
  EXPECT_EQ(plane.vertices.size(), 36u);
  EXPECT_EQ(plane.faces.size(), 50u);
  EXPECT_TRUE(IsConsistentlyOriented(plane));
  double area = 0.0;
  for (const Eigen::Vector3i& f : plane.faces) {
    const Eigen::Vector3d a = plane.vertices[f[0]].cast<double>();
    const Eigen::Vector3d normal =
        (plane.vertices[f[1]].cast<double>() - a).cross(plane.vertices[f[2]].cast<double>() - a);
    EXPECT_NEAR(normal.normalized().z(), -1.0, 1e-9);
    area += 0.5 * normal.norm();
  }
  EXPECT_NEAR(area, 0.12, 1e-7);
  Eigen::Vector3f lo, hi;
  plane.Bounds(&lo, &hi);
  EXPECT_NEAR(lo.x(), -0.2, 1e-7);
  EXPECT_NEAR(hi.x(), 0.2, 1e-7);
  EXPECT_NEAR(lo.y(), -0.15, 1e-7);
  EXPECT_NEAR(hi.y(), 0.15, 1e-7);
  EXPECT_EQ(lo.z(), 0.0f);
  EXPECT_EQ(hi.z(), 0.0f);
}

TEST(Primitives, SphereIsWatertightOutwardAndInscribed) {
  const double radius = 0.1;
  const int rings = 24, segments = 48;
  const TriangleMesh sphere = MakeSphere(radius, rings, segments);
  EXPECT_NO_THROW(sphere.Check());
  EXPECT_EQ(sphere.vertices.size(), static_cast<size_t>((rings - 1) * segments + 2));
  EXPECT_EQ(sphere.faces.size(), static_cast<size_t>(2 * (rings - 1) * segments));
  EXPECT_TRUE(IsWatertight(sphere));
  for (const Eigen::Vector3f& v : sphere.vertices) EXPECT_NEAR(v.norm(), radius, 1e-7);
  // Every face plane lies within the stated gap of the sphere.
  const double gap = SphereTessellationGap(radius, rings, segments);
  for (const Eigen::Vector3i& f : sphere.faces) {
    const Eigen::Vector3d a = sphere.vertices[f[0]].cast<double>();
    const Eigen::Vector3d normal = (sphere.vertices[f[1]].cast<double>() - a)
                                       .cross(sphere.vertices[f[2]].cast<double>() - a)
                                       .normalized();
    const double plane_distance = normal.dot(a);
    EXPECT_GT(plane_distance, 0.0);  // outward
    EXPECT_GE(plane_distance, radius - gap - 1e-7);
  }
  const double volume = SignedVolume(sphere);
  EXPECT_GT(volume, 0.0);
  EXPECT_LT(volume, 4.0 / 3.0 * kPi * std::pow(radius, 3));
  EXPECT_NEAR(volume, 4.0 / 3.0 * kPi * std::pow(radius, 3), 0.01 * volume);
}

TEST(Primitives, BoxIsWatertightWithExactVolume) {
  const TriangleMesh box = MakeBox(0.1, 0.2, 0.3);
  EXPECT_EQ(box.vertices.size(), 8u);
  EXPECT_EQ(box.faces.size(), 12u);
  EXPECT_TRUE(IsWatertight(box));
  EXPECT_NEAR(SignedVolume(box), 0.006, 1e-9);
  EXPECT_NEAR(box.SurfaceArea(), 2 * (0.02 + 0.03 + 0.06), 1e-7);  // float vertices
}

TEST(Primitives, CylinderCappedIsWatertightOpenIsNot) {
  const int segments = 40;
  const double radius = 0.05, height = 0.2;
  const TriangleMesh capped = MakeCylinder(radius, height, segments, true);
  EXPECT_TRUE(IsWatertight(capped));
  const double polygon_area = 0.5 * segments * std::sin(2 * kPi / segments) * radius * radius;
  EXPECT_NEAR(SignedVolume(capped), polygon_area * height, 1e-9);
  Eigen::Vector3f lo, hi;
  capped.Bounds(&lo, &hi);
  EXPECT_NEAR(lo.z(), -0.1, 1e-7);
  EXPECT_NEAR(hi.z(), 0.1, 1e-7);

  const TriangleMesh tube = MakeCylinder(radius, height, segments, false);
  EXPECT_FALSE(IsWatertight(tube));
  EXPECT_TRUE(IsConsistentlyOriented(tube));
  EXPECT_EQ(tube.faces.size(), static_cast<size_t>(2 * segments));
  // Outward side: every face normal points away from the axis.
  for (const Eigen::Vector3i& f : tube.faces) {
    const Eigen::Vector3d a = tube.vertices[f[0]].cast<double>();
    const Eigen::Vector3d normal =
        (tube.vertices[f[1]].cast<double>() - a).cross(tube.vertices[f[2]].cast<double>() - a);
    EXPECT_GT(normal.dot(Eigen::Vector3d(a.x(), a.y(), 0.0)), 0.0);
  }
}

TEST(Primitives, TorusIsWatertightWithNearAnalyticVolume) {
  const double major = 0.1, minor = 0.03;
  const TriangleMesh torus = MakeTorus(major, minor, 96, 48);
  EXPECT_TRUE(IsWatertight(torus));
  const double analytic = 2 * kPi * kPi * major * minor * minor;
  EXPECT_GT(SignedVolume(torus), 0.0);
  EXPECT_NEAR(SignedVolume(torus), analytic, 0.01 * analytic);
}

TEST(Primitives, InvalidParametersThrow) {
  EXPECT_THROW_WITH_MESSAGE(MakePlane(0.0, 1.0, 1), Error, "MakePlane", "got 0x1");
  EXPECT_THROW_WITH_MESSAGE(MakePlane(1.0, 1.0, 0), Error, "MakePlane", "subdivisions", "got 0");
  EXPECT_THROW_WITH_MESSAGE(MakeSphere(-1.0, 8, 8), Error, "MakeSphere", "radius", "got -1");
  EXPECT_THROW_WITH_MESSAGE(MakeSphere(1.0, 1, 8), Error, "MakeSphere", "got 1 and 8");
  EXPECT_THROW_WITH_MESSAGE(MakeSphere(1.0, 8, 2), Error, "MakeSphere", "got 8 and 2");
  EXPECT_THROW_WITH_MESSAGE(MakeBox(1.0, 0.0, 1.0), Error, "MakeBox", "got 1x0x1");
  EXPECT_THROW_WITH_MESSAGE(MakeCylinder(1.0, 1.0, 2), Error, "MakeCylinder", "segments", "got 2");
  EXPECT_THROW_WITH_MESSAGE(MakeTorus(0.1, 0.2), Error, "MakeTorus", "got 0.1 and 0.2");
  EXPECT_THROW_WITH_MESSAGE(MakeTorus(0.2, 0.1, 2, 8), Error, "MakeTorus", "segments",
                            "got 2 and 8");
}

}  // namespace
}  // namespace sope
