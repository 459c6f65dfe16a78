#include "simulator/procedural_objects.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <optional>
#include <utility>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "core/camera_model.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/units.h"
#include "simulator/scene_builder.h"
#include "simulator/virtual_rig.h"
#include "tests/test_support.h"

namespace sope {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

// Instances checked per class in the per-instance property tests.
constexpr int kSeedsPerClass = 20;

// Every edge used exactly once in each direction: closed, consistently oriented, each edge
// shared by exactly two faces.
bool IsWatertight(const TriangleMesh& mesh) {
  std::map<std::pair<int, int>, int> edges;
  for (const Eigen::Vector3i& f : mesh.faces) {
    for (int k = 0; k < 3; ++k) ++edges[{f[k], f[(k + 1) % 3]}];
  }
  for (const auto& [edge, count] : edges) {
    if (count != 1) return false;
    const auto reverse = edges.find({edge.second, edge.first});
    if (reverse == edges.end() || reverse->second != 1) return false;
  }
  return true;
}

// Divergence theorem; positive when the faces point outward.
double SignedVolume(const TriangleMesh& mesh) {
  double volume = 0.0;
  for (const Eigen::Vector3i& f : mesh.faces) {
    volume += mesh.vertices[f[0]].cast<double>().dot(
                  mesh.vertices[f[1]].cast<double>().cross(mesh.vertices[f[2]].cast<double>())) /
              6.0;
  }
  return volume;
}

// Distances along the ray origin + t·direction (t > 0) of every face it crosses, sorted
// (Möller & Trumbore 1997).
std::vector<double> RayHits(const TriangleMesh& mesh, const Vector3d& origin,
                            const Vector3d& direction) {
  std::vector<double> hits;
  for (const Eigen::Vector3i& f : mesh.faces) {
    const Vector3d a = mesh.vertices[f[0]].cast<double>();
    const Vector3d e1 = mesh.vertices[f[1]].cast<double>() - a;
    const Vector3d e2 = mesh.vertices[f[2]].cast<double>() - a;
    const Vector3d p = direction.cross(e2);
    const double det = e1.dot(p);
    if (std::abs(det) < 1e-18) continue;
    const Vector3d s = origin - a;
    const double u = s.dot(p) / det;
    if (u < 0 || u > 1) continue;
    const Vector3d q = s.cross(e1);
    const double v = direction.dot(q) / det;
    if (v < 0 || u + v > 1) continue;
    const double t = e2.dot(q) / det;
    if (t > 0) hits.push_back(t);
  }
  std::sort(hits.begin(), hits.end());
  return hits;
}

// Whether segments ab and cd cross (proper intersection or touching).
bool SegmentsIntersect(const Vector2d& a, const Vector2d& b, const Vector2d& c, const Vector2d& d) {
  const auto cross = [](const Vector2d& u, const Vector2d& v) {
    return u.x() * v.y() - u.y() * v.x();
  };
  const double d1 = cross(b - a, c - a), d2 = cross(b - a, d - a);
  const double d3 = cross(d - c, a - c), d4 = cross(d - c, b - c);
  return ((d1 > 0) != (d2 > 0)) && ((d3 > 0) != (d4 > 0)) && d1 != 0 && d2 != 0 && d3 != 0 &&
         d4 != 0;
}

bool IsSimplePolyline(const std::vector<Vector2d>& points) {
  for (size_t i = 0; i + 1 < points.size(); ++i) {
    for (size_t j = i + 2; j + 1 < points.size(); ++j) {
      if (SegmentsIntersect(points[i], points[i + 1], points[j], points[j + 1])) return false;
    }
  }
  return true;
}

struct Box3 {
  Vector3d lo, hi;
  Vector3d extent() const { return hi - lo; }
};
Box3 BoundsOf(const TriangleMesh& mesh) {
  Eigen::Vector3f lo, hi;
  mesh.Bounds(&lo, &hi);
  return {lo.cast<double>(), hi.cast<double>()};
}

std::string Name(ObjectClass cls, uint64_t seed) {
  return ToString(cls) + " seed " + std::to_string(seed);
}

// ------------------------------------------------------------------------------------
// Names and options.

TEST(ObjectClass, NamesRoundTripAndUnknownNamesThrow) {
  const std::vector<ObjectClass> classes = AllObjectClasses();
  EXPECT_EQ(classes.size(), 10u);
  for (ObjectClass cls : classes) EXPECT_EQ(ObjectClassFromString(ToString(cls)), cls);
  EXPECT_EQ(ToString(ObjectClass::kWineGlass), "wine_glass");
  try {
    ObjectClassFromString("teapot");
    FAIL() << "no exception";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("teapot"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("saucepan"), std::string::npos);
  }
}

TEST(ProceduralObjectOptions, InvalidValuesThrow) {
  ProceduralObjectOptions options;
  EXPECT_NO_THROW(options.Check());
  options.segments = 7;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "segments", "got 7");
  EXPECT_THROW_WITH_MESSAGE(MakeObject(ObjectClass::kMug, 0, options), Error, "segments", "got 7");
  options = {};
  options.profile_tolerance = 0.0;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "profile_tolerance", "got 0");
  options.profile_tolerance = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "profile_tolerance", "got nan");
}

// ------------------------------------------------------------------------------------
// Building blocks against closed-form geometry.

TEST(Lathe, RectangleProfileIsAPrismWithExactVolume) {
  const double radius = 0.04, height = 0.1;
  const int segments = 48;
  const TriangleMesh mesh =
      internal::Lathe({{0, 0}, {radius, 0}, {radius, height}, {0, height}}, segments);
  EXPECT_NO_THROW(mesh.Check());
  EXPECT_TRUE(IsWatertight(mesh));
  EXPECT_EQ(mesh.vertices.size(), 2u * segments + 2u);
  const double polygon_area = 0.5 * segments * std::sin(2 * kPi / segments) * radius * radius;
  EXPECT_NEAR(SignedVolume(mesh), polygon_area * height, 1e-9);
}

TEST(Lathe, ClockwiseProfileGivesInwardFacesAndBadProfilesThrow) {
  // Reversed profile: same solid, faces inward (negative volume) — the orientation rule.
  const TriangleMesh reversed = internal::Lathe({{0, 0.1}, {0.04, 0.1}, {0.04, 0}, {0, 0}}, 32);
  EXPECT_LT(SignedVolume(reversed), 0.0);
  EXPECT_THROW_WITH_MESSAGE(internal::Lathe({{0.01, 0}, {0.04, 0}, {0, 0.1}}, 32), Error, "Lathe",
                            "r = 0.01");  // off axis
  EXPECT_THROW_WITH_MESSAGE(internal::Lathe({{0, 0}, {0, 0.05}, {0, 0.1}}, 32), Error, "Lathe",
                            "profile point 1");  // on axis
  EXPECT_THROW_WITH_MESSAGE(internal::Lathe({{0, 0}, {0.04, 0}, {0, 0.1}}, 2), Error, "Lathe",
                            "segments", "got 2");
}

TEST(Lathe, SemicircleProfileApproachesTheSphereVolume) {
  const double radius = 0.05;
  std::vector<Vector2d> profile;
  const int steps = 64;
  for (int i = 0; i <= steps; ++i) {
    const double angle = -0.5 * kPi + kPi * i / steps;
    profile.emplace_back(i == 0 || i == steps ? 0.0 : radius * std::cos(angle),
                         radius * std::sin(angle));
  }
  const TriangleMesh sphere = internal::Lathe(profile, 128);
  EXPECT_TRUE(IsWatertight(sphere));
  const double exact = 4.0 / 3.0 * kPi * std::pow(radius, 3);
  EXPECT_LT(SignedVolume(sphere), exact);
  EXPECT_NEAR(SignedVolume(sphere), exact, 0.002 * exact);
}

TEST(CatmullRom, PassesThroughKnotsAndHonoursEndTangents) {
  const std::vector<Vector2d> knots = {{0, 0}, {0.01, 0.02}, {0.03, 0.025}, {0.05, 0.0}};
  const std::vector<Vector2d> curve =
      internal::SampleCatmullRom(knots, Vector2d(0, 1), Vector2d(0, -1));
  for (const Vector2d& knot : knots) {
    double nearest = 1.0;
    for (const Vector2d& p : curve) nearest = std::min(nearest, (p - knot).norm());
    EXPECT_LT(nearest, 1e-12);
  }
  for (size_t i = 1; i < curve.size(); ++i) {
    EXPECT_LE((curve[i] - curve[i - 1]).norm(), 3e-4);  // dense: ≤ 0.25 mm nominal
  }
  // Start and end directions within 15° of the requested ones.
  const Vector2d start = (curve[1] - curve[0]).normalized();
  const Vector2d end = (curve.back() - curve[curve.size() - 2]).normalized();
  EXPECT_GT(start.dot(Vector2d(0, 1)), std::cos(15.0 * kPi / 180.0));
  EXPECT_GT(end.dot(Vector2d(0, -1)), std::cos(15.0 * kPi / 180.0));
  // Collinear knots with tangents along the line stay on the line.
  for (const Vector2d& p : internal::SampleCatmullRom({{0.03, 0}, {0.03, 0.02}, {0.03, 0.1}},
                                                      Vector2d(0, 1), Vector2d(0, 1))) {
    EXPECT_NEAR(p.x(), 0.03, 1e-12);
  }
}

TEST(OffsetPolyline, ArcOffsetStaysAtTheDistance) {
  // A quarter circle of radius 0.05 traced counter-clockwise: its left is the centre.
  std::vector<Vector2d> arc;
  for (int i = 0; i <= 200; ++i) {
    const double angle = 0.5 * kPi * i / 200;
    arc.emplace_back(0.05 * std::cos(angle), 0.05 * std::sin(angle));
  }
  for (const Vector2d& p : internal::OffsetPolyline(arc, 0.004)) {
    EXPECT_NEAR(p.norm(), 0.046, 1e-6);
  }
}

TEST(SimplifyPolyline, RemovedPointsStayWithinTolerance) {
  std::vector<Vector2d> curve;
  for (int i = 0; i <= 1000; ++i) {
    const double x = 0.1 * i / 1000;
    curve.emplace_back(x, 0.01 * std::sin(60 * x));
  }
  const double tolerance = 5e-5;
  const std::vector<Vector2d> simple = internal::SimplifyPolyline(curve, tolerance);
  EXPECT_LT(simple.size(), curve.size() / 5);
  EXPECT_EQ(simple.front(), curve.front());
  EXPECT_EQ(simple.back(), curve.back());
  for (const Vector2d& p : curve) {
    double nearest = 1.0;
    for (size_t i = 0; i + 1 < simple.size(); ++i) {
      const Vector2d d = simple[i + 1] - simple[i];
      const double t = std::clamp((p - simple[i]).dot(d) / d.squaredNorm(), 0.0, 1.0);
      nearest = std::min(nearest, (simple[i] + t * d - p).norm());
    }
    EXPECT_LE(nearest, tolerance + 1e-12);
  }
}

TEST(ProfileBuilder, RoundedSquareCornerIsTangentAndNearTheCircle) {
  const double radius = 0.004;
  internal::ProfileBuilder builder({0, 0});
  builder.LineTo({0.02, 0}).Round(radius).LineTo({0.02, 0.02});
  const std::vector<Vector2d> profile = builder.Build(1e-6);
  // The rounding starts and ends `radius` from the corner (t = ρ·tan 45°).
  bool starts_at_tangent_point = false, ends_at_tangent_point = false;
  double closest_to_corner = 1.0;
  for (const Vector2d& p : profile) {
    starts_at_tangent_point |= (p - Vector2d(0.02 - radius, 0)).norm() < 1e-9;
    ends_at_tangent_point |= (p - Vector2d(0.02, radius)).norm() < 1e-9;
    closest_to_corner = std::min(closest_to_corner, (p - Vector2d(0.02, 0)).norm());
    EXPECT_LE(p.x(), 0.02 + 1e-12);
    EXPECT_GE(p.y(), -1e-12);
  }
  EXPECT_TRUE(starts_at_tangent_point);
  EXPECT_TRUE(ends_at_tangent_point);
  // A circular fillet passes (√2 − 1)·ρ from the corner; the quadratic Bézier ρ·√2/4.
  EXPECT_NEAR(closest_to_corner, std::sqrt(2.0) / 4.0 * radius, 1e-5);
  EXPECT_THROW_WITH_MESSAGE(internal::ProfileBuilder({0, 0}).Round(0.001), Error, "Round",
                            "no piece before the joint");
  EXPECT_THROW_WITH_MESSAGE(internal::ProfileBuilder({0, 0}).PolylineTo({{0.01, 0}, {0.02, 0}}),
                            Error, "PolylineTo", "starts at (0.01, 0)");
}

TEST(SweepTube, StraightCircularTubeIsAPrism) {
  const double radius = 0.006, length = 0.1;
  const int segments = 24;
  const TriangleMesh tube = internal::SweepTube(
      {{0, 0, 0}, {0.05, 0, 0}, {length, 0, 0}}, Vector3d::UnitY(),
      [&](double, double theta) {
        return Vector2d(radius * std::cos(theta), radius * std::sin(theta));
      },
      segments);
  EXPECT_TRUE(IsWatertight(tube));
  const double polygon_area = 0.5 * segments * std::sin(2 * kPi / segments) * radius * radius;
  EXPECT_NEAR(SignedVolume(tube), polygon_area * length, 1e-10);
}

TEST(RoundedBox, SizeVolumeAndWatertightness) {
  const Vector3d size(0.2, 0.1, 0.05);
  const double radius = 0.005;
  const TriangleMesh box = internal::MakeRoundedBox(size, radius, 4);
  EXPECT_TRUE(IsWatertight(box));
  const Box3 bounds = BoundsOf(box);
  EXPECT_LT((bounds.extent() - size).norm(), 1e-7);
  // Minkowski sum of the inner box (a, b, c) and a ball: abc + 2r(ab + bc + ca)
  // + πr²(a + b + c) + 4/3·πr³. The facets cut inside the round parts only: with 8 equal
  // facets per quarter circle the edges' quarter discs (πr²/4) become polygons of area
  // 4r²·sin(π/16); what remains is the corners' deficit, a few % of 4/3·πr³ = 5.2e-7 m³.
  const Vector3d inner = size - Vector3d::Constant(2 * radius);
  const double a = inner.x(), b = inner.y(), c = inner.z();
  const double exact = a * b * c + 2 * radius * (a * b + b * c + c * a) +
                       kPi * radius * radius * (a + b + c) + 4.0 / 3.0 * kPi * std::pow(radius, 3);
  const double polygonal_edges =
      exact - 4.0 * (a + b + c) * radius * radius * (kPi / 4.0 - 4.0 * std::sin(kPi / 16.0));
  const double volume = SignedVolume(box);
  EXPECT_LT(volume, polygonal_edges);
  EXPECT_NEAR(volume, polygonal_edges, 3e-8);
  EXPECT_THROW_WITH_MESSAGE(internal::MakeRoundedBox(size, 0.0, 3), Error, "MakeRoundedBox",
                            "radius 0 for 0.2x0.1x0.05");
  EXPECT_THROW_WITH_MESSAGE(internal::MakeRoundedBox(size, 0.03, 3), Error, "MakeRoundedBox",
                            "radius 0.03 for 0.2x0.1x0.05");
}

// ------------------------------------------------------------------------------------
// Every class, many instances.

TEST(ProceduralObjects, EveryInstanceIsValidClosedOutwardAndWithinItsClassRange) {
  for (ObjectClass cls : AllObjectClasses()) {
    const ObjectClassInfo& info = GetObjectClassInfo(cls);
    for (uint64_t seed = 0; seed < kSeedsPerClass; ++seed) {
      SCOPED_TRACE(Name(cls, seed));
      const TriangleMesh mesh = MakeObject(cls, seed);
      ASSERT_NO_THROW(mesh.Check());
      EXPECT_TRUE(IsWatertight(mesh));
      EXPECT_GT(SignedVolume(mesh), 0.0);
      // Each component (body, handle) on its own is closed and outward too.
      const internal::ObjectParts parts = internal::MakeObjectParts(cls, seed, {});
      for (const TriangleMesh& part : parts.parts) {
        EXPECT_TRUE(IsWatertight(part));
        EXPECT_GT(SignedVolume(part), 0.0);
      }
      // A generic ray crosses a closed surface an even number of times.
      const std::vector<double> hits =
          RayHits(mesh, Vector3d(0.00131, 0.00077, 1.0), Vector3d(0.013, 0.007, -1).normalized());
      EXPECT_EQ(hits.size() % 2, 0u);
      EXPECT_GE(hits.size(), 2u);

      const Box3 bounds = BoundsOf(mesh);
      EXPECT_NEAR(bounds.lo.z(), 0.0, 1e-6);  // stands on z = 0
      const Vector3d extent = bounds.extent();
      for (int axis = 0; axis < 3; ++axis) {
        EXPECT_GE(extent[axis], info.min_extent[axis]) << "axis " << axis;
        EXPECT_LE(extent[axis], info.max_extent[axis]) << "axis " << axis;
      }
      // Centred on the axis; only handles (toward +x) break the symmetry.
      EXPECT_NEAR(bounds.lo.y() + bounds.hi.y(), 0.0, 1e-5);
      if (!info.has_handle) {
        EXPECT_NEAR(bounds.lo.x() + bounds.hi.x(), 0.0, 1e-5);
      }
    }
  }
}

TEST(ProceduralObjects, ProfilesAreSimpleCurvesOffTheAxis) {
  for (ObjectClass cls : AllObjectClasses()) {
    for (uint64_t seed = 0; seed < kSeedsPerClass; ++seed) {
      SCOPED_TRACE(Name(cls, seed));
      const internal::ObjectParts parts = internal::MakeObjectParts(cls, seed, {});
      if (cls == ObjectClass::kBox) {
        EXPECT_TRUE(parts.profile.empty());
        continue;
      }
      ASSERT_GE(parts.profile.size(), 4u);
      EXPECT_EQ(parts.profile.front().x(), 0.0);
      EXPECT_EQ(parts.profile.back().x(), 0.0);
      for (size_t i = 1; i + 1 < parts.profile.size(); ++i) {
        EXPECT_GT(parts.profile[i].x(), 1e-5);
      }
      EXPECT_TRUE(IsSimplePolyline(parts.profile));
    }
  }
}

TEST(ProceduralObjects, DeterministicPerSeedAndDifferentAcrossSeeds) {
  for (ObjectClass cls : AllObjectClasses()) {
    SCOPED_TRACE(ToString(cls));
    const TriangleMesh a = MakeObject(cls, 7), b = MakeObject(cls, 7), c = MakeObject(cls, 8);
    ASSERT_EQ(a.vertices.size(), b.vertices.size());
    ASSERT_EQ(a.faces.size(), b.faces.size());
    EXPECT_TRUE(a.vertices == b.vertices);
    EXPECT_TRUE(a.faces == b.faces);
    EXPECT_FALSE(a.vertices == c.vertices);
    EXPECT_GT((BoundsOf(a).extent() - BoundsOf(c).extent()).norm(), 1e-4);
  }
  // Seeds give different instances across classes too (no shared stream).
  EXPECT_FALSE(MakeObject(ObjectClass::kGlass, 3).vertices ==
               MakeObject(ObjectClass::kMug, 3).vertices);
}

TEST(ProceduralObjects, ExtentRangesAreCoveredNotJustBounded) {
  // Over 200 instances the extents spread over most of the documented range: the table
  // describes the real variety, not a loose envelope.
  for (ObjectClass cls : AllObjectClasses()) {
    SCOPED_TRACE(ToString(cls));
    const ObjectClassInfo& info = GetObjectClassInfo(cls);
    Vector3d lo = Vector3d::Constant(1e9), hi = Vector3d::Constant(-1e9);
    for (uint64_t seed = 1000; seed < 1200; ++seed) {
      const Vector3d extent = BoundsOf(MakeObject(cls, seed, {16, 2e-4})).extent();
      lo = lo.cwiseMin(extent);
      hi = hi.cwiseMax(extent);
    }
    for (int axis = 0; axis < 3; ++axis) {
      const double range = info.max_extent[axis] - info.min_extent[axis];
      EXPECT_GE(lo[axis], info.min_extent[axis]) << "axis " << axis;
      EXPECT_LE(hi[axis], info.max_extent[axis]) << "axis " << axis;
      EXPECT_GT(hi[axis] - lo[axis], 0.6 * range) << "axis " << axis;
    }
  }
}

TEST(ProceduralObjects, VesselsAreHollowWithRealWallsAndFloors) {
  for (ObjectClass cls : AllObjectClasses()) {
    const ObjectClassInfo& info = GetObjectClassInfo(cls);
    for (uint64_t seed = 0; seed < kSeedsPerClass; ++seed) {
      SCOPED_TRACE(Name(cls, seed));
      const TriangleMesh mesh = MakeObject(cls, seed);
      const Box3 bounds = BoundsOf(mesh);
      const double height = bounds.hi.z();
      // Down the axis from above (slightly off it, to miss the pole vertex).
      const Vector3d above(0.0003, 0.0002, height + 0.1), down(0, 0, -1);
      const std::vector<double> from_above = RayHits(mesh, above, down);
      ASSERT_GE(from_above.size(), 2u);
      const double first_z = above.z() - from_above.front();
      if (cls == ObjectClass::kPlate) {
        // A shallow dish: its well lies on the foot ring (2–4 mm) plus the thickness
        // (3.5–6 mm), below the rim.
        EXPECT_GT(first_z, 0.0055);
        EXPECT_LT(first_z, 0.0101);
        EXPECT_GT(height - first_z, 0.004);
        continue;
      }
      if (!info.open_vessel) {
        // Closed objects: the first surface is near the top (a can's lid is recessed ≤ 5
        // mm, a bottle cap is the top).
        EXPECT_GT(first_z, height - 0.006);
        continue;
      }
      // The inner floor: well above z = 0 and well below the rim.
      EXPECT_GT(first_z, 0.003);
      EXPECT_GT(height - first_z, 0.03) << "cavity depth";
      // Up the axis from below: the underside. The floor between is solid, 1.5–20 mm
      // thick (a wine glass is solid from the foot through the stem).
      const std::vector<double> from_below =
          RayHits(mesh, Vector3d(0.0003, 0.0002, -0.1), Vector3d(0, 0, 1));
      ASSERT_GE(from_below.size(), 2u);
      const double underside_z = -0.1 + from_below.front();
      EXPECT_NEAR(from_above.size(), 2u, 0u) << "only the floor on the axis";
      if (cls != ObjectClass::kWineGlass) {
        EXPECT_GT(first_z - underside_z, 0.0015);
        EXPECT_LT(first_z - underside_z, 0.020);
      } else {
        // The bowl (70–110 mm, its floor 4–10 mm up) sits on foot and stem (≥ 45 mm).
        EXPECT_GT(first_z, 0.045);
        EXPECT_GT(height - first_z, 0.059);
      }
      // Across the wall, halfway up the cavity, from the side opposite the handle: the
      // ray crosses outer and inner wall surface, then the far wall.
      const double z = 0.5 * (first_z + height);
      const std::vector<double> across =
          RayHits(mesh, Vector3d(bounds.lo.x() - 0.1, 0.0004, z), Vector3d(1, 0, 0));
      ASSERT_GE(across.size(), 4u);
      const double thickness = across[1] - across[0];
      EXPECT_GT(thickness, 0.0014);
      EXPECT_LT(thickness, 0.015);
    }
  }
}

TEST(ProceduralObjects, NearVerticalWallsHaveTheSampledThickness) {
  // Mugs, tumblers and saucepans have near-vertical walls: the horizontal thickness at
  // mid-height is the sampled wall thickness (ranges in the header) within 10%.
  const std::map<ObjectClass, std::pair<double, double>> wall = {
      {ObjectClass::kMug, {0.003, 0.005}},
      {ObjectClass::kGlass, {0.002, 0.003}},
      {ObjectClass::kSaucepan, {0.002, 0.0035}}};
  for (const auto& [cls, range] : wall) {
    for (uint64_t seed = 0; seed < kSeedsPerClass; ++seed) {
      SCOPED_TRACE(Name(cls, seed));
      const TriangleMesh mesh = MakeObject(cls, seed);
      const Box3 bounds = BoundsOf(mesh);
      const std::vector<double> across = RayHits(
          mesh, Vector3d(bounds.lo.x() - 0.1, 0.0004, 0.5 * bounds.hi.z()), Vector3d(1, 0, 0));
      ASSERT_GE(across.size(), 2u);
      EXPECT_GE(across[1] - across[0], 0.98 * range.first);
      EXPECT_LE(across[1] - across[0], 1.10 * range.second);
    }
  }
}

TEST(ProceduralObjects, HandlesStickOutAndStayOutOfTheCavity) {
  for (ObjectClass cls : {ObjectClass::kMug, ObjectClass::kSaucepan}) {
    for (uint64_t seed = 0; seed < kSeedsPerClass; ++seed) {
      SCOPED_TRACE(Name(cls, seed));
      const internal::ObjectParts parts = internal::MakeObjectParts(cls, seed, {});
      ASSERT_EQ(parts.parts.size(), 1u);
      const TriangleMesh body = internal::Lathe(parts.profile, 64);
      const Box3 body_bounds = BoundsOf(body), all = BoundsOf(MakeObject(cls, seed));
      const double body_radius = body_bounds.hi.x();
      // Beyond the body on +x only: mug handles by ≥ 2 cm, saucepan handles by ≥ 12 cm.
      EXPECT_GT(all.hi.x() - body_radius, cls == ObjectClass::kMug ? 0.02 : 0.12);
      EXPECT_NEAR(all.lo.x(), body_bounds.lo.x(), 1e-7);
      // No handle vertex inside the cavity: from the axis at the vertex height toward it,
      // the body's inner wall comes first.
      const TriangleMesh& handle = parts.parts.front();
      int checked = 0;
      for (size_t i = 0; i < handle.vertices.size(); i += 7) {
        const Vector3d v = handle.vertices[i].cast<double>();
        const double radial = std::hypot(v.x(), v.y());
        const std::vector<double> hits =
            RayHits(body, Vector3d(0, 0, v.z()), Vector3d(v.x() / radial, v.y() / radial, 0));
        if (hits.empty()) continue;  // above the body (a saucepan handle's end)
        EXPECT_GT(radial, hits.front()) << "handle vertex " << i << " inside the cavity";
        ++checked;
      }
      EXPECT_GT(checked, 5);
    }
  }
}

TEST(ProceduralObjects, DepthCameraLookingIntoAMugSeesItsFloor) {
  // End to end with the renderer: a camera 0.5 m above a mug looking straight down sees
  // the inner floor at the image centre, at the depth the ray caster finds.
  const TriangleMesh mug = MakeObject(ObjectClass::kMug, 4);
  const double floor_z = 0.5 - RayHits(mug, Vector3d(0, 0, 0.5), Vector3d(0, 0, -1)).front();
  const CameraModel camera = MakePinhole(640, 480, 50.0 * kPi / 180.0);
  DepthRenderer renderer(camera);
  renderer.SetMesh(mug);
  // Camera at z = 0.5 above the origin looking down −z (x right, y down, z forward).
  Eigen::Matrix3d cam_from_model_rotation;
  cam_from_model_rotation << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  renderer.Render(Rigid3d(cam_from_model_rotation, Vector3d(0, 0, 0.5)));
  const float depth = renderer.depth().at<float>(240, 320);
  ASSERT_FALSE(std::isnan(depth));
  EXPECT_NEAR(depth, 0.5 - floor_z, 5e-4);
  EXPECT_GT(floor_z, 0.004);
}

// ------------------------------------------------------------------------------------
// Files and builtins.

TEST(WriteProceduralModels, WritesTheModelsTreeReadableBack) {
  testing::ScratchDir scratch;
  const std::string dir = scratch.File("models");
  const std::vector<std::string> paths = WriteProceduralModels(dir, 2, 40);
  EXPECT_EQ(paths.size(), 2u * AllObjectClasses().size());
  for (ObjectClass cls : AllObjectClasses()) {
    for (int k = 0; k < 2; ++k) {
      const std::string name = ToString(cls);
      const std::string path = dir + "/" + name + "/" + name + "_" + std::to_string(k) + ".obj";
      SCOPED_TRACE(path);
      ASSERT_TRUE(std::filesystem::is_regular_file(path));
      EXPECT_NE(std::find(paths.begin(), paths.end(), path), paths.end());
      const TriangleMesh read = ReadMesh(path);
      const TriangleMesh made = MakeObject(cls, 40 + k);
      EXPECT_TRUE(read.faces == made.faces);
      EXPECT_TRUE(read.vertices == made.vertices);  // OBJ floats round-trip exactly
    }
  }
  // Only the class folders, each a category (kCategoryMarker), no temporary files left
  // behind.
  int entries = 0;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(dir)) {
    entries += entry.is_regular_file() ? 1 : 0;
  }
  for (ObjectClass cls : AllObjectClasses()) {
    EXPECT_TRUE(std::filesystem::is_regular_file(dir + "/" + ToString(cls) + "/" +
                                                 kCategoryMarker));
  }
  EXPECT_EQ(entries, static_cast<int>(paths.size() + AllObjectClasses().size()));
  // A procedural models directory (its markers included) is replaced when written again.
  EXPECT_EQ(WriteProceduralModels(dir, 1, 40).size(), AllObjectClasses().size());
  EXPECT_THROW_WITH_MESSAGE(WriteProceduralModels(dir, 0, 0), Error, "instances per class",
                            "got 0");
  EXPECT_THROW_WITH_MESSAGE(WriteProceduralModels("", 1, 0), Error, "empty directory name");
}

TEST(LoadMeshSpec, BuiltinObjectClassesAndSeeds) {
  const TriangleMesh mug = LoadMeshSpec("builtin:mug");
  EXPECT_TRUE(mug.vertices == MakeObject(ObjectClass::kMug, 0).vertices);
  EXPECT_TRUE(LoadMeshSpec("builtin:wine_glass:12").vertices ==
              MakeObject(ObjectClass::kWineGlass, 12).vertices);
  // "box" stays the primitive box; the procedural box needs its seed.
  EXPECT_EQ(LoadMeshSpec("builtin:box").vertices.size(), 8u);
  EXPECT_TRUE(LoadMeshSpec("builtin:box:0").vertices == MakeObject(ObjectClass::kBox, 0).vertices);
  EXPECT_THROW_WITH_MESSAGE(LoadMeshSpec("builtin:mug:x"), Error, "'mug:x'", "seed 'x'");
  EXPECT_THROW_WITH_MESSAGE(LoadMeshSpec("builtin:mug:-1"), Error, "'mug:-1'", "seed '-1'");
  EXPECT_THROW_WITH_MESSAGE(LoadMeshSpec("builtin:teapot"), Error, "'teapot'");
}

}  // namespace
}  // namespace sope
