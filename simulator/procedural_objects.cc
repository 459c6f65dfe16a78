#include "simulator/procedural_objects.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <utility>

#include <Eigen/Geometry>
#include <fmt/format.h>

#include "core/error.h"
#include "core/file_util.h"
#include "core/units.h"

namespace sope {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

// Spacing of the dense curve samples before simplification, metres.
constexpr double kDenseStep = 2.5e-4;
// Profile points closer than this are merged, metres.
constexpr double kWeldDistance = 1e-7;

constexpr std::array<ObjectClass, 10> kAllClasses = {
    ObjectClass::kMug,       ObjectClass::kBottle,  ObjectClass::kBowl,  ObjectClass::kBox,
    ObjectClass::kCan,       ObjectClass::kGlass,   ObjectClass::kPlate, ObjectClass::kVase,
    ObjectClass::kWineGlass, ObjectClass::kSaucepan};

// The SplitMix64 output finaliser: a bijective 64-bit mix.
uint64_t Mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

// SplitMix64 (Steele, Lea & Flood, OOPSLA 2014): a tiny generator whose output is fixed by
// its seed on every platform, unlike the std:: distributions.
class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed) {}
  uint64_t Next() { return Mix64(state_ += 0x9E3779B97F4A7C15ull); }
  // Uniform in [lo, hi).
  double Uniform(double lo, double hi) {
    return lo + (hi - lo) * static_cast<double>(Next() >> 11) * 0x1.0p-53;
  }
  // Uniform in {lo, …, hi}.
  int UniformInt(int lo, int hi) {
    return lo + static_cast<int>(Next() % static_cast<uint64_t>(hi - lo + 1));
  }
  bool Bernoulli(double p) { return Uniform(0.0, 1.0) < p; }

 private:
  uint64_t state_;
};

double Length(const std::vector<Vector2d>& points) {
  double length = 0.0;
  for (size_t i = 1; i < points.size(); ++i) length += (points[i] - points[i - 1]).norm();
  return length;
}

Vector2d StartDirection(const std::vector<Vector2d>& points) {
  for (size_t i = 1; i < points.size(); ++i) {
    const Vector2d d = points[i] - points[0];
    if (d.norm() > kWeldDistance) return d.normalized();
  }
  return Vector2d::Zero();
}

Vector2d EndDirection(const std::vector<Vector2d>& points) {
  for (size_t i = points.size() - 1; i-- > 0;) {
    const Vector2d d = points.back() - points[i];
    if (d.norm() > kWeldDistance) return d.normalized();
  }
  return Vector2d::Zero();
}

// The polyline with arc length `from_start` removed at its start and `from_end` at its end
// (their sum at most the length).
std::vector<Vector2d> Trim(const std::vector<Vector2d>& points, double from_start,
                           double from_end) {
  const double total = Length(points);
  const double begin = std::min(from_start, total), end = std::max(begin, total - from_end);
  std::vector<Vector2d> result;
  double s = 0.0;
  for (size_t i = 1; i < points.size(); ++i) {
    const double length = (points[i] - points[i - 1]).norm();
    const double s_next = s + length;
    const auto at = [&](double t) {
      return length > 0 ? Vector2d(points[i - 1] + (t - s) / length * (points[i] - points[i - 1]))
                        : points[i];
    };
    if (result.empty() && s_next >= begin) result.push_back(at(begin));
    if (!result.empty()) {
      if (s_next >= end) {
        result.push_back(at(end));
        return result;
      }
      result.push_back(points[i]);
    }
    s = s_next;
  }
  // Rounding left `end` just beyond the accumulated length.
  result.push_back(points.back());
  return result;
}

// Removes points closer than kWeldDistance to their predecessor.
std::vector<Vector2d> Deduplicate(const std::vector<Vector2d>& points) {
  std::vector<Vector2d> result;
  for (const Vector2d& p : points) {
    if (result.empty() || (p - result.back()).norm() > kWeldDistance) result.push_back(p);
  }
  return result;
}

// r of the polyline `wall` (traced upward) at height z, linear between samples.
double RadiusAtHeight(const std::vector<Vector2d>& wall, double z) {
  for (size_t i = 1; i < wall.size(); ++i) {
    const double z0 = wall[i - 1].y(), z1 = wall[i].y();
    if ((z0 <= z && z <= z1) || (z1 <= z && z <= z0)) {
      const double t = z1 != z0 ? (z - z0) / (z1 - z0) : 0.0;
      return wall[i - 1].x() + t * (wall[i].x() - wall[i - 1].x());
    }
  }
  SOPE_THROW("RadiusAtHeight: z = {} outside the wall", z);
}

Vector2d Lerp(const Vector2d& a, const Vector2d& b, double t) { return a + t * (b - a); }

std::vector<Vector3d> SampleCubicBezier(const Vector3d& p0, const Vector3d& p1, const Vector3d& p2,
                                        const Vector3d& p3, int samples) {
  std::vector<Vector3d> points;
  for (int i = 0; i <= samples; ++i) {
    const double t = static_cast<double>(i) / samples, u = 1.0 - t;
    points.push_back(u * u * u * p0 + 3 * u * u * t * p1 + 3 * u * t * t * p2 + t * t * t * p3);
  }
  return points;
}

// The outer wall `outer_wall` (traced upward from where the caller's profile ends), a lip
// rounded with half the wall thickness, the inner wall (the outer one offset inward by
// `thickness`) down to height `floor_z`, a rounded corner of `floor_round` and the floor
// to the axis: the cavity of an open vessel.
void AppendVesselWall(const std::vector<Vector2d>& outer_wall, double thickness, double floor_z,
                      double floor_round, internal::ProfileBuilder* builder) {
  std::vector<Vector2d> inner = internal::OffsetPolyline(outer_wall, thickness);
  std::reverse(inner.begin(), inner.end());
  SOPE_CHECK(inner.front().y() > floor_z, "vessel floor {} above the rim {}", floor_z,
             inner.front().y());
  std::vector<Vector2d> cavity_wall = {inner.front()};
  for (size_t i = 1; i < inner.size(); ++i) {
    if (inner[i].y() <= floor_z) {
      const Vector2d& a = inner[i - 1];
      const double t = (a.y() - floor_z) / (a.y() - inner[i].y());
      cavity_wall.push_back(Lerp(a, inner[i], t));
      break;
    }
    cavity_wall.push_back(inner[i]);
  }
  builder->PolylineTo(outer_wall)
      .Round(0.5 * thickness)
      .LineTo(cavity_wall.front())
      .Round(0.5 * thickness)
      .PolylineTo(cavity_wall)
      .Round(floor_round)
      .LineTo(Vector2d(0.0, cavity_wall.back().y()));
}

// ---------------------------------------------------------------------------------------
// The classes. Every length in metres; the ranges are the table in the header.

internal::ObjectParts MakeMug(Rng* rng, const ProceduralObjectOptions& options) {
  const double height = rng->Uniform(0.080, 0.110);
  const double rim_radius = rng->Uniform(0.036, 0.047);
  const double base_radius = rim_radius * rng->Uniform(0.85, 1.05);
  const double bulge = rng->Uniform(0.0, 0.04);  // relative widening at mid-height
  const double wall = rng->Uniform(0.003, 0.005);
  const double floor_thickness = rng->Uniform(0.005, 0.009);
  const double recess = rng->Uniform(0.0005, 0.0015);  // underside inside the foot ring
  const double foot_width = rng->Uniform(0.004, 0.008);
  const double base_round = rng->Uniform(0.002, 0.005);

  const std::vector<Vector2d> outer_wall =
      internal::SampleCatmullRom({{base_radius, 0.0},
                                  {0.5 * (rim_radius + base_radius) * (1.0 + bulge), 0.5 * height},
                                  {rim_radius, height}},
                                 Vector2d::Zero(), Vector2d(0, 1));
  internal::ProfileBuilder builder({0.0, recess});
  builder.LineTo({base_radius - foot_width, recess})
      .Round(0.001)
      .LineTo({base_radius - foot_width + 0.001, 0.0})
      .Round(0.0005)
      .LineTo({base_radius, 0.0})
      .Round(base_round);
  AppendVesselWall(outer_wall, wall, floor_thickness, rng->Uniform(0.003, 0.008), &builder);

  // C-shaped handle in the plane y = 0: a cubic Bézier leaving the wall horizontally at
  // both ends, its ends inside the wall (half the wall thickness in).
  const double top_z = height - rng->Uniform(0.012, 0.020);
  const double span = std::min(height * rng->Uniform(0.50, 0.68), top_z - floor_thickness - 0.008);
  const double bottom_z = top_z - span;
  const double reach_top = rng->Uniform(0.025, 0.035);  // centre line beyond the body
  const double reach_bottom = reach_top * rng->Uniform(0.70, 1.0);
  const double half_thickness = rng->Uniform(0.0030, 0.0045);  // in the handle's plane
  const double half_width = rng->Uniform(0.0050, 0.0080);      // along y
  const double top_r = RadiusAtHeight(outer_wall, top_z);
  const double bottom_r = RadiusAtHeight(outer_wall, bottom_z);
  // A cubic Bézier reaches ¾ of its control points' offset at t = ½.
  const std::vector<Vector3d> path = SampleCubicBezier(
      {top_r - 0.5 * wall, 0, top_z}, {top_r + 4.0 / 3.0 * reach_top, 0, top_z},
      {bottom_r + 4.0 / 3.0 * reach_bottom, 0, bottom_z}, {bottom_r - 0.5 * wall, 0, bottom_z}, 48);
  internal::ObjectParts parts;
  parts.profile = builder.Build(options.profile_tolerance);
  parts.parts.push_back(internal::SweepTube(
      path, Vector3d::UnitY(),
      [&](double, double theta) {
        return Vector2d(half_thickness * std::cos(theta), half_width * std::sin(theta));
      },
      20));
  return parts;
}

internal::ObjectParts MakeBottle(Rng* rng, const ProceduralObjectOptions& options) {
  const double height = rng->Uniform(0.20, 0.32);
  const double body_radius = rng->Uniform(0.030, 0.045);
  const double neck_radius = rng->Uniform(0.011, 0.016);
  const double shoulder_z = height * rng->Uniform(0.50, 0.72);
  const bool has_cap = rng->Bernoulli(0.7);  // screw cap; otherwise a corked lip
  const double cap_height = rng->Uniform(0.014, 0.024);
  const double cap_radius = neck_radius + rng->Uniform(0.0015, 0.003);
  const double neck_top_z = has_cap ? height - cap_height : height - 0.003;
  const double neck_base_z = shoulder_z + (neck_top_z - shoulder_z) * rng->Uniform(0.35, 0.65);
  const Vector2d shoulder_knot(neck_radius + (body_radius - neck_radius) * rng->Uniform(0.35, 0.65),
                               shoulder_z + (neck_base_z - shoulder_z) * rng->Uniform(0.35, 0.60));
  const double punt = rng->Uniform(0.002, 0.015);  // the bottom's dome
  const double foot_width = rng->Uniform(0.004, 0.010);
  const double base_round = rng->Uniform(0.003, 0.008);
  const int grooves = rng->UniformInt(0, 3);
  const double groove_depth = rng->Uniform(0.0008, 0.0015);
  const double groove_half_width = rng->Uniform(0.002, 0.004);
  const double bead_z = neck_top_z - rng->Uniform(0.004, 0.008);
  const double bead = rng->Uniform(0.0008, 0.0015);  // ring below the cap or lip

  internal::ProfileBuilder builder({0.0, punt});
  builder
      .SplineTo({{0.5 * (body_radius - foot_width), 0.6 * punt}, {body_radius - foot_width, 0.0}},
                Vector2d(1, 0), Vector2d::Zero())
      .Round(0.002)
      .LineTo({body_radius, 0.0})
      .Round(base_round);
  // Grooves evenly over the lower body.
  const double groove_lo = 0.15 * height, groove_hi = shoulder_z - 0.02;
  for (int g = 0; g < grooves; ++g) {
    const double z = groove_lo + (groove_hi - groove_lo) * (g + 0.5) / grooves;
    builder.LineTo({body_radius, z - groove_half_width})
        .SplineTo({{body_radius - groove_depth, z}, {body_radius, z + groove_half_width}},
                  Vector2d(0, 1), Vector2d(0, 1));
  }
  builder.LineTo({body_radius, shoulder_z})
      .SplineTo({shoulder_knot, {neck_radius, neck_base_z}}, Vector2d(0, 1), Vector2d(0, 1))
      .LineTo({neck_radius, bead_z - 0.0015})
      .SplineTo({{neck_radius + bead, bead_z}, {neck_radius, bead_z + 0.0015}}, Vector2d(0, 1),
                Vector2d(0, 1));
  if (has_cap) {
    builder.LineTo({neck_radius, neck_top_z})
        .Round(0.0003)
        .LineTo({cap_radius, neck_top_z})
        .Round(0.0005)
        .LineTo({cap_radius, height})
        .Round(0.002)
        .LineTo({0.0, height});
  } else {
    builder.LineTo({neck_radius, neck_top_z})
        .Round(0.001)
        .LineTo({neck_radius + 0.0015, neck_top_z + 0.0005})
        .Round(0.001)
        .LineTo({neck_radius + 0.0015, height})
        .Round(0.001)
        .LineTo({0.0, height});
  }
  internal::ObjectParts parts;
  parts.profile = builder.Build(options.profile_tolerance);
  return parts;
}

internal::ObjectParts MakeBowl(Rng* rng, const ProceduralObjectOptions& options) {
  const double rim_radius = rng->Uniform(0.060, 0.100);
  const double height =
      rng->Uniform(std::max(0.050, 0.5 * rim_radius), std::min(0.090, 0.95 * rim_radius));
  const double foot_radius = rim_radius * rng->Uniform(0.35, 0.50);
  const double foot_height = rng->Uniform(0.004, 0.008);
  const double recess = foot_height * rng->Uniform(0.5, 0.9);
  const double wall = rng->Uniform(0.0035, 0.0055);
  const double exponent = rng->Uniform(2.0, 3.0);  // 2: elliptic; larger: boxier
  const double flare = rng->Uniform(0.0, 0.08);    // rim widening, relative

  // Outer wall: the superellipse (r/R₀)ⁿ + (d/D)ⁿ = 1 (d = depth below the rim), from the
  // foot ring to the rim, widened by (1 + flare·s²) at relative height s so that it ends
  // at rim_radius: r = R₀·sin(t)^(2/n), d = D·cos(t)^(2/n), t ∈ [t_foot, π/2].
  const double base_radius = rim_radius / (1.0 + flare);
  const double t_foot = std::asin(std::pow(foot_radius / base_radius, 0.5 * exponent));
  const double depth = (height - foot_height) / std::pow(std::cos(t_foot), 2.0 / exponent);
  std::vector<Vector2d> outer_wall;
  constexpr int kWallSamples = 400;
  for (int i = 0; i <= kWallSamples; ++i) {
    const double t = t_foot + (0.5 * kPi - t_foot) * i / kWallSamples;
    const double z = i == 0 ? foot_height
                            : height - depth * std::pow(std::max(std::cos(t), 0.0), 2.0 / exponent);
    const double s = (z - foot_height) / (height - foot_height);
    const double r =
        i == 0 ? foot_radius
               : base_radius * std::pow(std::sin(t), 2.0 / exponent) * (1.0 + flare * s * s);
    outer_wall.emplace_back(r, z);
  }
  internal::ProfileBuilder builder({0.0, recess});
  builder.LineTo({foot_radius - 0.004, recess})
      .Round(0.001)
      .LineTo({foot_radius - 0.003, 0.0})
      .Round(0.0005)
      .LineTo({foot_radius, 0.0})
      .Round(0.001)
      .LineTo({foot_radius, foot_height})
      .Round(0.002);
  AppendVesselWall(outer_wall, wall, foot_height + wall * rng->Uniform(1.0, 1.3),
                   rng->Uniform(0.010, 0.025), &builder);
  internal::ObjectParts parts;
  parts.profile = builder.Build(options.profile_tolerance);
  return parts;
}

internal::ObjectParts MakeBox(Rng* rng, const ProceduralObjectOptions&) {
  Vector3d size;
  const double kind = rng->Uniform(0.0, 1.0);
  if (kind < 0.45) {  // cereal box, standing
    size = {rng->Uniform(0.14, 0.23), rng->Uniform(0.045, 0.085), rng->Uniform(0.20, 0.33)};
  } else if (kind < 0.70) {  // shoe box, lying
    size = {rng->Uniform(0.28, 0.36), rng->Uniform(0.17, 0.22), rng->Uniform(0.095, 0.13)};
  } else {  // small carton (tea, toothpaste, spices)
    size = {rng->Uniform(0.08, 0.16), rng->Uniform(0.05, 0.10), rng->Uniform(0.04, 0.12)};
    if (size.y() > size.x()) std::swap(size.x(), size.y());
  }
  const double radius = rng->Bernoulli(0.25) ? 0.0005 : rng->Uniform(0.001, 0.006);
  TriangleMesh box = internal::MakeRoundedBox(size, radius, 3);
  box.Transform(1.0, Vector3d(0, 0, 0.5 * size.z()));
  internal::ObjectParts parts;
  parts.parts.push_back(std::move(box));
  return parts;
}

internal::ObjectParts MakeCan(Rng* rng, const ProceduralObjectOptions& options) {
  internal::ProfileBuilder builder({0.0, 0.0});
  if (rng->Bernoulli(0.6)) {
    // Beverage can: domed bottom on a standing ring, necked top with a seam ring around a
    // recessed lid.
    const double radius = rng->Uniform(0.0265, 0.0335);
    const double height = rng->Uniform(0.095, 0.170);
    const double dome = rng->Uniform(0.008, 0.012);
    const double ring_radius = radius * rng->Uniform(0.72, 0.80);
    const double wall_start_z = rng->Uniform(0.008, 0.013);
    const double neck_height = rng->Uniform(0.008, 0.014);
    const double seam_radius = radius * rng->Uniform(0.86, 0.90);
    const double seam_height = 0.003;
    const double lid_recess = rng->Uniform(0.003, 0.005);
    builder = internal::ProfileBuilder({0.0, dome});
    builder
        .SplineTo({{0.55 * ring_radius, 0.75 * dome}, {ring_radius, 0.0}}, Vector2d(1, 0),
                  Vector2d::Zero())
        .Round(0.0015)
        .SplineTo({{ring_radius + 0.6 * (radius - ring_radius), 0.35 * wall_start_z},
                   {radius, wall_start_z}},
                  Vector2d(1, 0.6), Vector2d(0, 1))
        .LineTo({radius, height - neck_height})
        .SplineTo({{radius + 0.6 * (seam_radius - radius), height - 0.45 * neck_height},
                   {seam_radius, height - seam_height}},
                  Vector2d(0, 1), Vector2d(0, 1))
        .LineTo({seam_radius, height})
        .Round(0.0006)
        .LineTo({seam_radius - 0.0022, height})
        .Round(0.0006)
        .LineTo({seam_radius - 0.0028, height - lid_recess})
        .Round(0.001)
        .LineTo({0.0, height - lid_recess});
  } else {
    // Food tin: seams at both ends standing out by `seam`, recessed ends, beads.
    const double radius = rng->Uniform(0.033, 0.050);
    const double height = rng->Uniform(0.070, 0.120);
    const double seam = 0.001, seam_height = 0.003;
    const double recess = rng->Uniform(0.0015, 0.003);
    const int beads = rng->Bernoulli(0.3) ? 0 : rng->UniformInt(2, 6);
    const double bead_depth = rng->Uniform(0.0006, 0.0012), bead_half_width = 0.002;
    builder = internal::ProfileBuilder({0.0, recess});
    builder.LineTo({radius - 0.0025, recess})
        .Round(0.001)
        .LineTo({radius - 0.0015, 0.0})
        .Round(0.0004)
        .LineTo({radius + seam, 0.0})
        .Round(0.0008)
        .LineTo({radius + seam, seam_height})
        .Round(0.0008)
        .LineTo({radius, seam_height + 0.001})
        .Round(0.001);
    const double bead_lo = seam_height + 0.008, bead_hi = height - seam_height - 0.008;
    for (int b = 0; b < beads; ++b) {
      const double z = bead_lo + (bead_hi - bead_lo) * (b + 0.5) / beads;
      builder.LineTo({radius, z - bead_half_width})
          .SplineTo({{radius - bead_depth, z}, {radius, z + bead_half_width}}, Vector2d(0, 1),
                    Vector2d(0, 1));
    }
    builder.LineTo({radius, height - seam_height - 0.001})
        .Round(0.001)
        .LineTo({radius + seam, height - seam_height})
        .Round(0.0008)
        .LineTo({radius + seam, height})
        .Round(0.0008)
        .LineTo({radius - 0.0015, height})
        .Round(0.0004)
        .LineTo({radius - 0.0025, height - recess})
        .Round(0.001)
        .LineTo({0.0, height - recess});
  }
  internal::ObjectParts parts;
  parts.profile = builder.Build(options.profile_tolerance);
  return parts;
}

internal::ObjectParts MakeGlass(Rng* rng, const ProceduralObjectOptions& options) {
  const double height = rng->Uniform(0.085, 0.150);
  const double rim_radius = rng->Uniform(0.032, 0.045);
  const double base_radius = rim_radius * rng->Uniform(0.65, 0.92);
  const double wall = rng->Uniform(0.002, 0.003);
  const double base_thickness = rng->Uniform(0.006, 0.014);
  const double recess = rng->Uniform(0.0005, 0.0015);
  const Vector2d middle(0.5 * (base_radius + rim_radius) + rng->Uniform(-0.001, 0.003),
                        0.5 * height);
  const std::vector<Vector2d> outer_wall = internal::SampleCatmullRom(
      {{base_radius, 0.0}, middle, {rim_radius, height}}, Vector2d::Zero(), Vector2d::Zero());
  internal::ProfileBuilder builder({0.0, recess});
  builder.LineTo({base_radius - 0.004, recess})
      .Round(0.001)
      .LineTo({base_radius - 0.002, 0.0})
      .Round(0.0005)
      .LineTo({base_radius, 0.0})
      .Round(rng->Uniform(0.0015, 0.003));
  AppendVesselWall(outer_wall, wall, base_thickness, rng->Uniform(0.002, 0.006), &builder);
  internal::ObjectParts parts;
  parts.profile = builder.Build(options.profile_tolerance);
  return parts;
}

internal::ObjectParts MakePlate(Rng* rng, const ProceduralObjectOptions& options) {
  const double radius = rng->Uniform(0.090, 0.140);
  const double height = rng->Uniform(0.015, 0.030);
  const double thickness = rng->Uniform(0.0035, 0.006);
  const double foot_radius = radius * rng->Uniform(0.35, 0.45);
  const double foot_height = rng->Uniform(0.002, 0.004);
  const double well_radius = radius * rng->Uniform(0.55, 0.70);
  const double recess = foot_height * rng->Uniform(0.3, 0.8);
  // The underside rises by `rise` from the foot ring to the rim edge; the top surface is
  // its offset by the thickness, so the rim top lands at about `height`.
  const double rise = height - thickness - foot_height;
  const std::vector<Vector2d> underside = internal::SampleCatmullRom(
      {{foot_radius, foot_height},
       {well_radius, foot_height + rise * rng->Uniform(0.05, 0.15)},
       {well_radius + 0.4 * (radius - well_radius), foot_height + rise * rng->Uniform(0.7, 0.8)},
       {radius, foot_height + rise}},
      Vector2d(1, 0), Vector2d(1, rng->Uniform(0.1, 0.3)));
  internal::ProfileBuilder builder({0.0, recess});
  builder.LineTo({foot_radius - 0.004, recess})
      .Round(0.001)
      .LineTo({foot_radius - 0.003, 0.0})
      .Round(0.0005)
      .LineTo({foot_radius, 0.0})
      .Round(0.0008)
      .LineTo({foot_radius, foot_height})
      .Round(0.0015);
  AppendVesselWall(underside, thickness, foot_height + thickness + 1e-4, 0.01, &builder);
  internal::ObjectParts parts;
  parts.profile = builder.Build(options.profile_tolerance);
  return parts;
}

internal::ObjectParts MakeVase(Rng* rng, const ProceduralObjectOptions& options) {
  const double height = rng->Uniform(0.15, 0.30);
  const double belly_radius = rng->Uniform(0.040, 0.080);
  const double belly_z = height * rng->Uniform(0.25, 0.55);
  const double base_radius = belly_radius * rng->Uniform(0.55, 0.90);
  const double neck_radius = std::max(0.020, belly_radius * rng->Uniform(0.35, 0.75));
  const double neck_z = height * rng->Uniform(0.72, 0.88);
  const double lip_radius = neck_radius * rng->Uniform(1.0, 1.45);
  const double wall = rng->Uniform(0.003, 0.005);
  const double floor_thickness = rng->Uniform(0.008, 0.015);
  const double recess = rng->Uniform(0.0005, 0.002);
  const bool fluted = rng->Bernoulli(0.3);
  const int lobes = 2 * rng->UniformInt(3, 6);
  const double flute_amplitude = rng->Uniform(0.02, 0.04);

  const std::vector<Vector2d> outer_wall = internal::SampleCatmullRom(
      {{base_radius, 0.0}, {belly_radius, belly_z}, {neck_radius, neck_z}, {lip_radius, height}},
      Vector2d(rng->Uniform(0.2, 1.0), 1), Vector2d(rng->Uniform(0.0, 0.6), 1));
  internal::ProfileBuilder builder({0.0, recess});
  builder.LineTo({base_radius - 0.005, recess})
      .Round(0.001)
      .LineTo({base_radius - 0.003, 0.0})
      .Round(0.0005)
      .LineTo({base_radius, 0.0})
      .Round(rng->Uniform(0.002, 0.005));
  AppendVesselWall(outer_wall, wall, floor_thickness, rng->Uniform(0.004, 0.012), &builder);
  internal::ObjectParts parts;
  parts.profile = builder.Build(options.profile_tolerance);
  if (fluted) {
    parts.radial_scale = [lobes, flute_amplitude](double, double phi) {
      return 1.0 + flute_amplitude * std::cos(lobes * phi);
    };
  }
  return parts;
}

internal::ObjectParts MakeWineGlass(Rng* rng, const ProceduralObjectOptions& options) {
  const double foot_radius = rng->Uniform(0.030, 0.042);
  const double foot_edge = rng->Uniform(0.002, 0.004);   // thickness at the rim of the foot
  const double foot_top_z = rng->Uniform(0.006, 0.012);  // where the stem starts
  const double foot_lift = rng->Uniform(0.001, 0.004);   // underside cone at the centre
  const double stem_radius = rng->Uniform(0.0035, 0.0055);
  const double stem_base_radius = stem_radius * rng->Uniform(1.0, 1.3);
  const double bowl_height = rng->Uniform(0.070, 0.110);
  const double height = rng->Uniform(std::max(0.150, bowl_height + foot_top_z + 0.045), 0.230);
  const double stem_top_z = height - bowl_height;
  const double bowl_radius = rng->Uniform(0.033, 0.045);
  const double bowl_widest_z = stem_top_z + bowl_height * rng->Uniform(0.35, 0.55);
  const double rim_radius = bowl_radius * rng->Uniform(0.75, 1.0);
  const double wall = rng->Uniform(0.0015, 0.0025);
  const double bowl_floor_z = stem_top_z + rng->Uniform(0.004, 0.010);

  const std::vector<Vector2d> bowl =
      internal::SampleCatmullRom({{stem_radius, stem_top_z},
                                  {0.7 * bowl_radius, stem_top_z + 0.15 * bowl_height},
                                  {bowl_radius, bowl_widest_z},
                                  {rim_radius, height}},
                                 Vector2d(1, 0.35), Vector2d::Zero());
  internal::ProfileBuilder builder({0.0, foot_lift});
  builder.LineTo({foot_radius, 0.0})
      .Round(0.5 * foot_edge)
      .LineTo({foot_radius, foot_edge})
      .Round(0.5 * foot_edge)
      .SplineTo(
          {{0.5 * (foot_radius + stem_base_radius), foot_edge + 0.3 * (foot_top_z - foot_edge)},
           {stem_base_radius, foot_top_z}},
          Vector2d(-1, 0.05), Vector2d(0, 1))
      .LineTo({stem_radius, stem_top_z})
      .Round(rng->Uniform(0.004, 0.008));
  AppendVesselWall(bowl, wall, bowl_floor_z, 0.004, &builder);
  internal::ObjectParts parts;
  parts.profile = builder.Build(options.profile_tolerance);
  return parts;
}

internal::ObjectParts MakeSaucepan(Rng* rng, const ProceduralObjectOptions& options) {
  const double radius = rng->Uniform(0.070, 0.110);
  const double height = rng->Uniform(0.070, 0.130);
  const double rim_radius = radius * rng->Uniform(1.0, 1.06);
  const double flare = rng->Uniform(0.0, 0.003);  // rolled-out rim
  const double wall = rng->Uniform(0.002, 0.0035);
  const double base_thickness = rng->Uniform(0.004, 0.007);
  const double recess = rng->Uniform(0.0005, 0.0015);
  const std::vector<Vector2d> outer_wall = internal::SampleCatmullRom(
      {{radius, 0.0}, {rim_radius, height - 0.008}, {rim_radius + flare, height}}, Vector2d::Zero(),
      Vector2d::Zero());
  internal::ProfileBuilder builder({0.0, recess});
  builder.LineTo({radius - 0.025, recess})
      .Round(0.002)
      .LineTo({radius - 0.022, 0.0})
      .Round(0.001)
      .LineTo({radius, 0.0})
      .Round(rng->Uniform(0.006, 0.012));
  AppendVesselWall(outer_wall, wall, base_thickness, rng->Uniform(0.004, 0.010), &builder);

  // Handle: leaves the wall horizontally, bends up to `angle`, widens toward its end.
  const double handle_z = height - rng->Uniform(0.010, 0.025);
  const double length = rng->Uniform(0.14, 0.20);
  const double angle = rng->Uniform(5.0, 20.0) * kPi / 180.0;
  const double half_thickness = rng->Uniform(0.004, 0.006);  // vertical
  const double half_width = rng->Uniform(0.008, 0.012);      // along y
  const double widening = rng->Uniform(1.0, 1.4);            // at the end
  const Vector3d start(RadiusAtHeight(outer_wall, handle_z) - 0.4 * wall, 0.0, handle_z);
  const Vector3d direction(std::cos(angle), 0.0, std::sin(angle));
  const Vector3d end = start + length * direction;
  const std::vector<Vector3d> path = SampleCubicBezier(start, start + Vector3d(length / 3, 0, 0),
                                                       end - length / 3 * direction, end, 32);
  internal::ObjectParts parts;
  parts.profile = builder.Build(options.profile_tolerance);
  parts.parts.push_back(internal::SweepTube(
      path, Vector3d::UnitY(),
      [&](double s, double theta) {
        // Superellipse |u/a|⁴ + |v/b|⁴ = 1: a rounded rectangle.
        const double c = std::cos(theta), n = std::sin(theta);
        const double scale = 1.0 + (widening - 1.0) * s;
        return Vector2d(half_thickness * std::copysign(std::sqrt(std::abs(c)), c),
                        scale * half_width * std::copysign(std::sqrt(std::abs(n)), n));
      },
      24));
  return parts;
}

}  // namespace

// ---------------------------------------------------------------------------------------

std::string ToString(ObjectClass cls) {
  switch (cls) {
    case ObjectClass::kMug:
      return "mug";
    case ObjectClass::kBottle:
      return "bottle";
    case ObjectClass::kBowl:
      return "bowl";
    case ObjectClass::kBox:
      return "box";
    case ObjectClass::kCan:
      return "can";
    case ObjectClass::kGlass:
      return "glass";
    case ObjectClass::kPlate:
      return "plate";
    case ObjectClass::kVase:
      return "vase";
    case ObjectClass::kWineGlass:
      return "wine_glass";
    case ObjectClass::kSaucepan:
      return "saucepan";
  }
  SOPE_THROW("invalid ObjectClass {}", static_cast<int>(cls));
}

ObjectClass ObjectClassFromString(const std::string& text) {
  std::string known;
  for (ObjectClass cls : kAllClasses) {
    if (text == ToString(cls)) return cls;
    known += (known.empty() ? "" : ", ") + ToString(cls);
  }
  SOPE_THROW("unknown object class '{}' (known: {})", text, known);
}

std::vector<ObjectClass> AllObjectClasses() {
  return std::vector<ObjectClass>(kAllClasses.begin(), kAllClasses.end());
}

const ObjectClassInfo& GetObjectClassInfo(ObjectClass cls) {
  // Extents (x, y, z), metres: the parameter ranges' extremes (measured over 3000 seeds
  // per class: splines may bulge a little past their knots, rounded lips trim a little)
  // plus 1–2 mm.
  static const std::map<ObjectClass, ObjectClassInfo> kInfo = [] {
    const auto info = [](bool open_vessel, bool has_handle, Vector3d min_extent,
                         Vector3d max_extent) {
      ObjectClassInfo result;
      result.open_vessel = open_vessel;
      result.has_handle = has_handle;
      result.min_extent = min_extent;
      result.max_extent = max_extent;
      return result;
    };
    std::map<ObjectClass, ObjectClassInfo> table;
    table[ObjectClass::kMug] = info(true, true, {0.094, 0.070, 0.079}, {0.136, 0.101, 0.111});
    table[ObjectClass::kBottle] = info(false, false, {0.059, 0.059, 0.199}, {0.091, 0.091, 0.321});
    table[ObjectClass::kBowl] = info(true, false, {0.117, 0.117, 0.049}, {0.201, 0.201, 0.092});
    table[ObjectClass::kBox] = info(false, false, {0.079, 0.044, 0.039}, {0.361, 0.221, 0.331});
    table[ObjectClass::kCan] = info(false, false, {0.052, 0.052, 0.069}, {0.103, 0.103, 0.171});
    table[ObjectClass::kGlass] = info(true, false, {0.062, 0.062, 0.084}, {0.094, 0.094, 0.151});
    table[ObjectClass::kPlate] = info(false, false, {0.177, 0.177, 0.013}, {0.281, 0.281, 0.031});
    table[ObjectClass::kVase] = info(true, false, {0.075, 0.075, 0.148}, {0.185, 0.185, 0.302});
    table[ObjectClass::kWineGlass] =
        info(true, false, {0.064, 0.064, 0.148}, {0.096, 0.096, 0.231});
    table[ObjectClass::kSaucepan] = info(true, true, {0.275, 0.140, 0.069}, {0.433, 0.241, 0.189});
    return table;
  }();
  const auto it = kInfo.find(cls);
  SOPE_CHECK(it != kInfo.end(), "invalid ObjectClass {}", static_cast<int>(cls));
  return it->second;
}

void ProceduralObjectOptions::Check() const {
  SOPE_CHECK(segments >= 8, "procedural objects: segments must be >= 8, got {}", segments);
  SOPE_CHECK(profile_tolerance > 0 && std::isfinite(profile_tolerance),
             "procedural objects: profile_tolerance must be > 0 metres, got {}", profile_tolerance);
}

TriangleMesh MakeObject(ObjectClass cls, uint64_t seed, const ProceduralObjectOptions& options) {
  const internal::ObjectParts parts = internal::MakeObjectParts(cls, seed, options);
  TriangleMesh mesh;
  if (!parts.profile.empty()) {
    mesh = internal::Lathe(parts.profile, options.segments, parts.radial_scale);
  }
  for (const TriangleMesh& part : parts.parts) internal::AppendMesh(part, &mesh);
  return mesh;
}

namespace {

// True when `dir` holds only what WriteProceduralModels writes (<class>/<class>_<k>.obj):
// an earlier models directory, safe to replace.
bool IsProceduralModelsDirectory(const std::string& dir) {
  namespace fs = std::filesystem;
  std::error_code error;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir, error)) {
    const std::string name = entry.path().filename().string();
    if (!entry.is_directory() ||
        std::none_of(kAllClasses.begin(), kAllClasses.end(),
                     [&](ObjectClass cls) { return ToString(cls) == name; })) {
      return false;
    }
    for (const fs::directory_entry& file : fs::directory_iterator(entry.path(), error)) {
      const std::string stem = file.path().stem().string();
      if (file.is_regular_file() && file.path().filename() == kCategoryMarker) continue;
      if (!file.is_regular_file() || file.path().extension() != ".obj" ||
          stem.rfind(name + "_", 0) != 0 || stem.size() == name.size() + 1 ||
          stem.find_first_not_of("0123456789", name.size() + 1) != std::string::npos) {
        return false;
      }
    }
  }
  return !error;
}

}  // namespace

namespace {
// One model file to write: <class>/<class>_<index>.obj holding instance `seed`.
struct ModelFile {
  ObjectClass object_class;
  uint64_t index, seed;
};
std::vector<std::string> WriteModelFiles(const std::string& dir, const std::vector<ModelFile>& files,
                                         const ProceduralObjectOptions& options) {
  SOPE_CHECK(!dir.empty(), "WriteProceduralModels: empty directory name");
  options.Check();
  // Staged as a whole: a full disk or a signal leaves no partial models directory.
  StagedDirectory staged(dir, &IsProceduralModelsDirectory);
  std::vector<std::string> paths;
  for (const ModelFile& f : files) {
    const std::string name = ToString(f.object_class);
    const std::string file = JoinPath(name, fmt::format("{}_{}.obj", name, f.index));
    WriteMesh(JoinPath(staged.path(), file), MakeObject(f.object_class, f.seed, options));
    paths.push_back(JoinPath(dir, file));
    // Each class's instances are alike objects: a category (kCategoryMarker).
    const std::string marker = JoinPath(JoinPath(staged.path(), name), kCategoryMarker);
    if (!std::filesystem::exists(marker)) {
      WriteFileAtomic(marker, fmt::format("{}: procedural instances of one class (sope "
                                          "objects); unseen instances are recognised as {}\n",
                                          name, name));
    }
  }
  staged.Commit();
  return paths;
}
}  // namespace

std::vector<std::string> WriteProceduralModels(const std::string& dir, int instances_per_class,
                                               uint64_t seed,
                                               const ProceduralObjectOptions& options) {
  SOPE_CHECK(instances_per_class >= 1 && instances_per_class <= kMaxInstancesPerClass,
             "WriteProceduralModels: instances per class must be in [1, {}], got {}",
             kMaxInstancesPerClass, instances_per_class);
  SOPE_CHECK(seed <= std::numeric_limits<uint64_t>::max() - instances_per_class,
             "WriteProceduralModels: seed {} + {} instances overflows", seed,
             instances_per_class);
  std::vector<ModelFile> files;
  for (ObjectClass cls : kAllClasses) {
    for (int k = 0; k < instances_per_class; ++k) {
      files.push_back({cls, static_cast<uint64_t>(k), seed + static_cast<uint64_t>(k)});
    }
  }
  return WriteModelFiles(dir, files, options);
}

std::vector<std::string> WriteProceduralModels(
    const std::string& dir,
    const std::vector<std::pair<ObjectClass, std::vector<uint64_t>>>& instances,
    const ProceduralObjectOptions& options) {
  std::vector<ModelFile> files;
  for (const auto& [object_class, seeds] : instances) {
    for (const uint64_t seed : seeds) files.push_back({object_class, seed, seed});
  }
  return WriteModelFiles(dir, files, options);
}

// ---------------------------------------------------------------------------------------

namespace internal {

ProfileBuilder::ProfileBuilder(const Vector2d& start) : current_(start) {}

ProfileBuilder& ProfileBuilder::LineTo(const Vector2d& end) { return PolylineTo({current_, end}); }

ProfileBuilder& ProfileBuilder::SplineTo(const std::vector<Vector2d>& knots,
                                         const Vector2d& start_tangent,
                                         const Vector2d& end_tangent) {
  SOPE_CHECK(!knots.empty(), "ProfileBuilder::SplineTo: no knots");
  std::vector<Vector2d> all = {current_};
  all.insert(all.end(), knots.begin(), knots.end());
  return PolylineTo(SampleCatmullRom(all, start_tangent, end_tangent));
}

ProfileBuilder& ProfileBuilder::PolylineTo(const std::vector<Vector2d>& points) {
  SOPE_CHECK(points.size() >= 2, "ProfileBuilder::PolylineTo: need >= 2 points, got {}",
             points.size());
  SOPE_CHECK((points.front() - current_).norm() < 1e-6,
             "ProfileBuilder::PolylineTo: starts at ({}, {}), not at the current point ({}, {})",
             points.front().x(), points.front().y(), current_.x(), current_.y());
  std::vector<Vector2d> piece = points;
  piece.front() = current_;
  pieces_.push_back(std::move(piece));
  round_radius_.push_back(0.0);
  current_ = points.back();
  return *this;
}

ProfileBuilder& ProfileBuilder::Round(double radius) {
  SOPE_CHECK(!pieces_.empty(), "ProfileBuilder::Round: no piece before the joint");
  SOPE_CHECK(radius >= 0, "ProfileBuilder::Round: radius must be >= 0, got {}", radius);
  round_radius_.back() = radius;
  return *this;
}

std::vector<Vector2d> ProfileBuilder::Build(double tolerance) const {
  SOPE_CHECK(!pieces_.empty(), "ProfileBuilder::Build: empty profile");
  const size_t n = pieces_.size();
  // Trim lengths at each rounded joint j (end of piece j, start of piece j + 1).
  std::vector<double> trim_start(n, 0.0), trim_end(n, 0.0);
  for (size_t j = 0; j + 1 < n; ++j) {
    if (round_radius_[j] <= 0) continue;
    const Vector2d in = EndDirection(pieces_[j]), out = StartDirection(pieces_[j + 1]);
    const double turn = std::acos(std::clamp(in.dot(out), -1.0, 1.0));
    if (turn < 1e-3) continue;
    const double max_turn = 170.0 * kPi / 180.0;
    const double t = std::min({round_radius_[j] * std::tan(0.5 * std::min(turn, max_turn)),
                               0.5 * Length(pieces_[j]), 0.5 * Length(pieces_[j + 1])});
    trim_end[j] = t;
    trim_start[j + 1] = t;
  }
  std::vector<Vector2d> points;
  constexpr int kRoundSamples = 16;
  for (size_t j = 0; j < n; ++j) {
    const std::vector<Vector2d> piece = Trim(pieces_[j], trim_start[j], trim_end[j]);
    if (j > 0 && trim_start[j] > 0) {
      // Quadratic Bézier from the trimmed end of the previous piece over the corner.
      const Vector2d a = points.back(), corner = pieces_[j].front(), b = piece.front();
      for (int i = 1; i < kRoundSamples; ++i) {
        const double t = static_cast<double>(i) / kRoundSamples, u = 1.0 - t;
        points.push_back(u * u * a + 2 * u * t * corner + t * t * b);
      }
    }
    points.insert(points.end(), piece.begin(), piece.end());
  }
  return SimplifyPolyline(Deduplicate(points), tolerance);
}

std::vector<Vector2d> SampleCatmullRom(const std::vector<Vector2d>& knots,
                                       const Vector2d& start_tangent, const Vector2d& end_tangent) {
  SOPE_CHECK(knots.size() >= 2, "SampleCatmullRom: need >= 2 knots, got {}", knots.size());
  // Phantom end knots: reflections, or placed so that the uniform Catmull–Rom tangent
  // (P₂ − P₀)/2 at the end equals the requested direction times the chord.
  std::vector<Vector2d> p;
  const size_t k = knots.size();
  const double first_chord = (knots[1] - knots[0]).norm();
  const double last_chord = (knots[k - 1] - knots[k - 2]).norm();
  p.push_back(start_tangent.norm() > 0
                  ? Vector2d(knots[1] - 2.0 * first_chord * start_tangent.normalized())
                  : Vector2d(2.0 * knots[0] - knots[1]));
  p.insert(p.end(), knots.begin(), knots.end());
  p.push_back(end_tangent.norm() > 0
                  ? Vector2d(knots[k - 2] + 2.0 * last_chord * end_tangent.normalized())
                  : Vector2d(2.0 * knots[k - 1] - knots[k - 2]));
  // Centripetal parameterisation t_{i+1} = t_i + |P_{i+1} − P_i|^½, evaluated with the
  // Barry–Goldman pyramid.
  const auto knot_step = [](const Vector2d& a, const Vector2d& b) {
    return std::max(std::sqrt((b - a).norm()), 1e-9);
  };
  std::vector<Vector2d> samples = {knots.front()};
  for (size_t i = 1; i + 2 < p.size(); ++i) {
    const Vector2d &p0 = p[i - 1], &p1 = p[i], &p2 = p[i + 1], &p3 = p[i + 2];
    const double t0 = 0.0, t1 = t0 + knot_step(p0, p1), t2 = t1 + knot_step(p1, p2),
                 t3 = t2 + knot_step(p2, p3);
    const int steps =
        std::clamp(static_cast<int>(std::ceil((p2 - p1).norm() / kDenseStep)), 4, 4000);
    for (int s = 1; s <= steps; ++s) {
      const double t = t1 + (t2 - t1) * s / steps;
      const Vector2d a1 = ((t1 - t) * p0 + (t - t0) * p1) / (t1 - t0);
      const Vector2d a2 = ((t2 - t) * p1 + (t - t1) * p2) / (t2 - t1);
      const Vector2d a3 = ((t3 - t) * p2 + (t - t2) * p3) / (t3 - t2);
      const Vector2d b1 = ((t2 - t) * a1 + (t - t0) * a2) / (t2 - t0);
      const Vector2d b2 = ((t3 - t) * a2 + (t - t1) * a3) / (t3 - t1);
      samples.push_back(((t2 - t) * b1 + (t - t1) * b2) / (t2 - t1));
    }
    samples.back() = p2;
  }
  return samples;
}

std::vector<Vector2d> OffsetPolyline(const std::vector<Vector2d>& points, double distance) {
  const std::vector<Vector2d> clean = Deduplicate(points);
  SOPE_CHECK(clean.size() >= 2, "OffsetPolyline: need >= 2 distinct points");
  std::vector<Vector2d> normals;  // left unit normal of each segment
  for (size_t i = 0; i + 1 < clean.size(); ++i) {
    const Vector2d d = (clean[i + 1] - clean[i]).normalized();
    normals.emplace_back(-d.y(), d.x());
  }
  std::vector<Vector2d> result;
  for (size_t i = 0; i < clean.size(); ++i) {
    Vector2d offset;
    if (i == 0) {
      offset = distance * normals.front();
    } else if (i + 1 == clean.size()) {
      offset = distance * normals.back();
    } else {
      const Vector2d miter = (normals[i - 1] + normals[i]).normalized();
      offset = distance / std::max(miter.dot(normals[i]), 0.5) * miter;
    }
    result.push_back(clean[i] + offset);
  }
  return result;
}

std::vector<Vector2d> SimplifyPolyline(const std::vector<Vector2d>& points, double tolerance) {
  if (points.size() <= 2) return points;
  std::vector<bool> keep(points.size(), false);
  keep.front() = keep.back() = true;
  std::vector<std::pair<size_t, size_t>> stack = {{0, points.size() - 1}};
  while (!stack.empty()) {
    const auto [first, last] = stack.back();
    stack.pop_back();
    const Vector2d a = points[first], chord = points[last] - a;
    const double chord_length = chord.norm();
    double worst = -1.0;
    size_t worst_index = first;
    for (size_t i = first + 1; i < last; ++i) {
      const Vector2d v = points[i] - a;
      const double distance = chord_length > 0
                                  ? std::abs(chord.x() * v.y() - chord.y() * v.x()) / chord_length
                                  : v.norm();
      if (distance > worst) {
        worst = distance;
        worst_index = i;
      }
    }
    if (worst > tolerance) {
      keep[worst_index] = true;
      stack.emplace_back(first, worst_index);
      stack.emplace_back(worst_index, last);
    }
  }
  std::vector<Vector2d> result;
  for (size_t i = 0; i < points.size(); ++i) {
    if (keep[i]) result.push_back(points[i]);
  }
  return result;
}

TriangleMesh Lathe(const std::vector<Vector2d>& profile, int segments,
                   const std::function<double(double z, double phi)>& radial_scale) {
  SOPE_CHECK(segments >= 3, "Lathe: segments must be >= 3, got {}", segments);
  SOPE_CHECK(profile.size() >= 3, "Lathe: need >= 3 profile points, got {}", profile.size());
  SOPE_CHECK(profile.front().x() == 0.0 && profile.back().x() == 0.0,
             "Lathe: the profile must start and end on the axis (r = 0), got r = {} and {}",
             profile.front().x(), profile.back().x());
  const int rings = static_cast<int>(profile.size()) - 2;
  for (int i = 1; i <= rings; ++i) {
    SOPE_CHECK(profile[i].x() > 1e-7 && profile[i].allFinite(),
               "Lathe: profile point {} (r = {}) must lie off the axis", i, profile[i].x());
  }
  TriangleMesh mesh;
  const auto add = [&mesh](double x, double y, double z) {
    mesh.vertices.emplace_back(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
  };
  add(0.0, 0.0, profile.front().y());
  for (int i = 1; i <= rings; ++i) {
    for (int j = 0; j < segments; ++j) {
      const double phi = 2.0 * kPi * j / segments;
      const double r = profile[i].x() * (radial_scale ? radial_scale(profile[i].y(), phi) : 1.0);
      add(r * std::cos(phi), r * std::sin(phi), profile[i].y());
    }
  }
  add(0.0, 0.0, profile.back().y());
  const int first_pole = 0, last_pole = static_cast<int>(mesh.vertices.size()) - 1;
  const auto ring = [segments](int i, int j) { return 1 + (i - 1) * segments + j % segments; };
  // Moving along the profile direction d with φ increasing, the face normal φ̂ × d points
  // to the right of d in the (r, z) plane: outward when the material is on the left.
  for (int j = 0; j < segments; ++j) {
    mesh.faces.emplace_back(first_pole, ring(1, j + 1), ring(1, j));
    for (int i = 1; i < rings; ++i) {
      mesh.faces.emplace_back(ring(i, j), ring(i, j + 1), ring(i + 1, j + 1));
      mesh.faces.emplace_back(ring(i, j), ring(i + 1, j + 1), ring(i + 1, j));
    }
    mesh.faces.emplace_back(ring(rings, j), ring(rings, j + 1), last_pole);
  }
  return mesh;
}

TriangleMesh SweepTube(const std::vector<Vector3d>& path, const Vector3d& binormal,
                       const std::function<Vector2d(double s, double theta)>& section,
                       int section_segments) {
  SOPE_CHECK(path.size() >= 2, "SweepTube: need >= 2 path points, got {}", path.size());
  SOPE_CHECK(section_segments >= 3, "SweepTube: section_segments must be >= 3, got {}",
             section_segments);
  const int n = static_cast<int>(path.size()), m = section_segments;
  std::vector<double> arc(n, 0.0);
  for (int i = 1; i < n; ++i) arc[i] = arc[i - 1] + (path[i] - path[i - 1]).norm();
  SOPE_CHECK(arc.back() > 0, "SweepTube: path has zero length");
  TriangleMesh mesh;
  for (int i = 0; i < n; ++i) {
    const Vector3d tangent = (path[std::min(i + 1, n - 1)] - path[std::max(i - 1, 0)]).normalized();
    // (normal, binormal, tangent) is right-handed: the section runs counter-clockwise
    // about the tangent.
    const Vector3d normal = binormal.cross(tangent).normalized();
    for (int j = 0; j < m; ++j) {
      const Vector2d uv = section(arc[i] / arc.back(), 2.0 * kPi * j / m);
      mesh.vertices.push_back((path[i] + uv.x() * normal + uv.y() * binormal).cast<float>());
    }
  }
  const int start_center = static_cast<int>(mesh.vertices.size());
  mesh.vertices.push_back(path.front().cast<float>());
  mesh.vertices.push_back(path.back().cast<float>());
  const int end_center = start_center + 1;
  const auto index = [m](int i, int j) { return i * m + j % m; };
  for (int j = 0; j < m; ++j) {
    for (int i = 0; i + 1 < n; ++i) {
      mesh.faces.emplace_back(index(i, j), index(i, j + 1), index(i + 1, j + 1));
      mesh.faces.emplace_back(index(i, j), index(i + 1, j + 1), index(i + 1, j));
    }
    mesh.faces.emplace_back(start_center, index(0, j + 1), index(0, j));
    mesh.faces.emplace_back(end_center, index(n - 1, j), index(n - 1, j + 1));
  }
  return mesh;
}

TriangleMesh MakeRoundedBox(const Vector3d& size, double radius, int bevel_segments) {
  SOPE_CHECK(radius > 0 && 2.0 * radius < size.minCoeff(),
             "MakeRoundedBox: need 0 < radius < half the smallest size, got radius {} for "
             "{}x{}x{}",
             radius, size.x(), size.y(), size.z());
  SOPE_CHECK(bevel_segments >= 1, "MakeRoundedBox: bevel_segments must be >= 1, got {}",
             bevel_segments);
  const Vector3d inner = 0.5 * size - Vector3d::Constant(radius);  // half extents
  // Grid coordinates along each axis on the outer box: within a bevel zone at
  // inner + radius·tan(β), β uniform in [0, 45°], so facets span equal angles.
  std::array<std::vector<double>, 3> coords;
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<double>& c = coords[axis];
    for (int k = bevel_segments; k >= 0; --k) {
      c.push_back(-(inner[axis] + radius * std::tan(0.25 * kPi * k / bevel_segments)));
    }
    for (int k = 0; k <= bevel_segments; ++k) {
      c.push_back(inner[axis] + radius * std::tan(0.25 * kPi * k / bevel_segments));
    }
  }
  TriangleMesh mesh;
  std::map<std::array<int, 3>, int> vertex_of_grid_point;  // welds the faces' shared edges
  const auto vertex = [&](const std::array<int, 3>& grid) {
    const auto it = vertex_of_grid_point.find(grid);
    if (it != vertex_of_grid_point.end()) return it->second;
    const Vector3d p(coords[0][grid[0]], coords[1][grid[1]], coords[2][grid[2]]);
    const Vector3d clamped = p.cwiseMax(-inner).cwiseMin(inner);
    const Vector3d q = clamped + radius * (p - clamped).normalized();
    mesh.vertices.push_back(q.cast<float>());
    const int index = static_cast<int>(mesh.vertices.size()) - 1;
    vertex_of_grid_point.emplace(grid, index);
    return index;
  };
  for (int axis = 0; axis < 3; ++axis) {
    const int u_axis = (axis + 1) % 3, v_axis = (axis + 2) % 3;  // u × v = +axis
    const int nu = static_cast<int>(coords[u_axis].size());
    const int nv = static_cast<int>(coords[v_axis].size());
    for (const int side : {0, static_cast<int>(coords[axis].size()) - 1}) {
      const bool positive = side != 0;
      for (int i = 0; i + 1 < nu; ++i) {
        for (int j = 0; j + 1 < nv; ++j) {
          std::array<int, 3> g00, g10, g11, g01;
          g00[axis] = g10[axis] = g11[axis] = g01[axis] = side;
          g00[u_axis] = g01[u_axis] = i;
          g10[u_axis] = g11[u_axis] = i + 1;
          g00[v_axis] = g10[v_axis] = j;
          g01[v_axis] = g11[v_axis] = j + 1;
          const int a = vertex(g00), b = vertex(g10), c = vertex(g11), d = vertex(g01);
          if (positive) {
            mesh.faces.emplace_back(a, b, c);
            mesh.faces.emplace_back(a, c, d);
          } else {
            mesh.faces.emplace_back(a, c, b);
            mesh.faces.emplace_back(a, d, c);
          }
        }
      }
    }
  }
  return mesh;
}

void AppendMesh(const TriangleMesh& part, TriangleMesh* mesh) {
  const int offset = static_cast<int>(mesh->vertices.size());
  mesh->vertices.insert(mesh->vertices.end(), part.vertices.begin(), part.vertices.end());
  for (const Eigen::Vector3i& f : part.faces) {
    mesh->faces.push_back(f + Eigen::Vector3i::Constant(offset));
  }
}

ObjectParts MakeObjectParts(ObjectClass cls, uint64_t seed,
                            const ProceduralObjectOptions& options) {
  options.Check();
  // One stream per (class, seed). The start state is mixed: SplitMix64 advances its state
  // by a constant, so raw seeds s and s + k would give the same stream shifted by k draws
  // (correlated instances).
  Rng rng(Mix64(Mix64(seed) ^ ((static_cast<uint64_t>(cls) + 1) * 0xD1B54A32D192ED03ull)));
  ObjectParts parts;
  switch (cls) {
    case ObjectClass::kMug:
      parts = MakeMug(&rng, options);
      break;
    case ObjectClass::kBottle:
      parts = MakeBottle(&rng, options);
      break;
    case ObjectClass::kBowl:
      parts = MakeBowl(&rng, options);
      break;
    case ObjectClass::kBox:
      parts = MakeBox(&rng, options);
      break;
    case ObjectClass::kCan:
      parts = MakeCan(&rng, options);
      break;
    case ObjectClass::kGlass:
      parts = MakeGlass(&rng, options);
      break;
    case ObjectClass::kPlate:
      parts = MakePlate(&rng, options);
      break;
    case ObjectClass::kVase:
      parts = MakeVase(&rng, options);
      break;
    case ObjectClass::kWineGlass:
      parts = MakeWineGlass(&rng, options);
      break;
    case ObjectClass::kSaucepan:
      parts = MakeSaucepan(&rng, options);
      break;
    default:
      SOPE_THROW("invalid ObjectClass {}", static_cast<int>(cls));
  }
  // Stand exactly on z = 0: simplification may leave the lowest profile point a few µm up.
  double lowest = std::numeric_limits<double>::infinity();
  for (const Vector2d& p : parts.profile) lowest = std::min(lowest, p.y());
  for (const TriangleMesh& part : parts.parts) {
    for (const Eigen::Vector3f& v : part.vertices) lowest = std::min(lowest, double{v.z()});
  }
  for (Vector2d& p : parts.profile) p.y() -= lowest;
  for (TriangleMesh& part : parts.parts) part.Transform(1.0, Vector3d(0, 0, -lowest));
  return parts;
}

}  // namespace internal
}  // namespace sope
