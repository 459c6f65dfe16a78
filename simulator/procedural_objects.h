// Procedural household objects for class-level recognition: ten classes of everyday
// objects, each a family of instances drawn from randomly sampled shape parameters in
// real-world sizes, so a recogniser can be trained on some instances and tested on unseen
// ones (the recogniser issue: "procedural household objects ... many instances each").
//
// Construction. Round objects are surfaces of revolution: a 2-D profile (r, z) made of
// straight segments, centripetal Catmull–Rom splines through control points (Yuksel,
// Schaefer & Keyser, "Parameterization and applications of Catmull–Rom curves", CAD 2011:
// no cusps or self-intersections within a segment) and rounded corners, simplified to a
// chord tolerance (Douglas–Peucker) and lathed around the z axis. Open vessels (mug, bowl,
// glass, vase, wine glass, saucepan; the plate is built the same way) have real wall
// thickness: the profile runs up the outside, over a lip rounded with half the wall
// thickness, down the inside (the outer wall offset inward along its normal) to the floor,
// so a depth camera looking in sees the inner wall and floor. Handles are tubes swept along
// a cubic Bézier (the mug's C, the saucepan's handle leaving horizontally and bending up),
// capped at both ends, their ends buried in the wall. Boxes are cuboids with rounded edges
// (a box grown by a sphere of the bevel radius).
//
// Model frame, metres: the axis of revolution is +z, the object stands on the plane z = 0
// (its lowest point is at z = 0), the axis passes through x = y = 0, handles point to +x
// (and lie in the plane y = 0). Boxes are centred on x = y = 0 with their longer horizontal
// side along x. Faces are counter-clockwise seen from outside.
//
// Watertightness: every mesh is closed — each edge is shared by exactly two faces, once in
// each direction — and has positive signed volume. Mugs and saucepans are the union of two
// such closed components (body and handle) that interpenetrate where the handle enters the
// wall: fine for rendering and volume, not one 2-manifold solid. All other classes are a
// single closed 2-manifold.
//
// Classes and parameter ranges (uniform; millimetres here for readability, metres in the
// code; R = radius, D = diameter, H = height, w = wall thickness):
//
// | class      | shape                                   | main parameters                      |
// |------------|-----------------------------------------|--------------------------------------|
// | mug        | open, near-cylindrical body + C handle  | H 80–110, rim D 72–94, base D 0.85–  |
// |            | (elliptic section 6–9 × 10–16; its      | 1.05×rim, bulge 0–4%, w 3–5, floor   |
// |            | centre line 20–35 beyond the body)      | 5–9                                  |
// | bottle     | closed; body, S-shoulder, neck, cap or  | H 200–320, body D 60–90, neck D      |
// |            | lip bead, bottom punt, 0–3 grooves      | 22–32, shoulder at 0.50–0.72·H       |
// | bowl       | open, superellipse wall (exponent 2–3,  | rim D 120–200, H 50–90 (0.5–0.95·R), |
// |            | rim flare 0–8%) on a foot ring          | foot D 0.35–0.5×rim, w 3.5–5.5       |
// | box        | cuboid with rounded edges: cereal       | cereal 140–230 × 45–85 × 200–330,    |
// |            | (upright), shoe box (flat), small carton| shoe 280–360 × 170–220 × 95–130,     |
// |            |                                         | carton 80–160 × 50–100 × 40–120;     |
// |            |                                         | edge radius 0.5–6                    |
// | can        | closed; beverage (domed bottom, necked  | beverage D 53–67, H 95–170; tin D    |
// |            | top, recessed lid) or food tin (seams,  | 66–100, H 70–120                     |
// |            | beads)                                  |                                      |
// | glass      | open tapered tumbler, heavy base        | H 85–150, rim D 64–90, base D 0.65–  |
// |            |                                         | 0.92×rim, w 2–3, base 6–14           |
// | plate      | shallow, well + flange, foot ring       | D 180–280, H 15–30, w 3.5–6          |
// | vase       | open, curvy (base, belly, neck, flared  | H 150–300, belly D 80–160, neck D    |
// |            | lip), 30% fluted (6–12 lobes, 2–4%)     | 40–0.75×belly, w 3–5                 |
// | wine_glass | foot, stem, open tulip bowl             | H 150–230, bowl D 66–90, bowl H      |
// |            |                                         | 70–110, foot D 60–84, w 1.5–2.5      |
// | saucepan   | open cylinder + long straight handle    | D 140–220, H 70–130, handle 140–200  |
// |            | rising 5–20°                            | long, w 2–3.5                        |
//
// The bounding-box extents each class spans are in GetObjectClassInfo(); the classes differ
// in metric size and shape (open/closed, handle, neck, flat faces) although some overlap in
// size (a mug seen without its handle looks like a tumbler — as in the real world).
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"

namespace sope {

enum class ObjectClass {
  kMug,
  kBottle,
  kBowl,
  kBox,
  kCan,
  kGlass,
  kPlate,
  kVase,
  kWineGlass,
  kSaucepan,
};

// "mug", "bottle", "bowl", "box", "can", "glass", "plate", "vase", "wine_glass", "saucepan".
std::string ToString(ObjectClass cls);
// Inverse of ToString; throws sope::Error naming `text` and listing the known names.
ObjectClass ObjectClassFromString(const std::string& text);
// Every class, in enum order.
std::vector<ObjectClass> AllObjectClasses();

// What every instance of a class shares.
struct ObjectClassInfo {
  // A cavity open at the top: a ray down the axis from above ends on an inner floor well
  // above z = 0 (mug, bowl, glass, vase, wine_glass, saucepan).
  bool open_vessel = false;
  // A handle on the +x side beyond the body (mug, saucepan).
  bool has_handle = false;
  // Bounding-box size (x, y, z extents) of every instance lies in
  // [min_extent, max_extent] componentwise, metres.
  Eigen::Vector3d min_extent = Eigen::Vector3d::Zero();
  Eigen::Vector3d max_extent = Eigen::Vector3d::Zero();
};
const ObjectClassInfo& GetObjectClassInfo(ObjectClass cls);

struct ProceduralObjectOptions {
  // Lathe segments around the axis of revolution (≥ 8). 64 keeps the polygon within
  // r·(1 − cos(π/64)) ≈ 0.12% of the radius of the true circle (0.17 mm on a 28 cm plate).
  int segments = 64;
  // Largest distance between a profile curve and its polyline, metres (> 0).
  double profile_tolerance = 5e-5;
  // Throws sope::Error naming the invalid value.
  void Check() const;
};

// Instance `seed` of `cls`: its shape parameters are drawn from the ranges above by a
// SplitMix64 generator seeded from (cls, seed), so they are the same on every platform
// (no std:: distributions) and the same seed gives the identical mesh in every run;
// different seeds give different instances. Model frame and units as described at the top
// of this file. Throws sope::Error on invalid options.
TriangleMesh MakeObject(ObjectClass cls, uint64_t seed,
                        const ProceduralObjectOptions& options = {});

// Writes a models directory for `sope build-db --models DIR` (DESIGN.md):
// `dir/<class>/<class>_<k>.obj` for every class and k = 0 … instances_per_class − 1, where
// model k is MakeObject(cls, seed + k) — so directories written with seeds s and
// s' ≥ s + instances_per_class hold disjoint instances (training vs unseen test objects) —
// and `dir/<class>/CATEGORY` (kCategoryMarker, core/mesh.h: each class is a category).
// The directory is written as a whole (StagedDirectory): a full disk or a signal leaves
// nothing partial. An existing `dir` is replaced only when empty or itself a procedural
// models directory (only <class>/<class>_<k>.obj and CATEGORY files); anything else is
// refused, so no file sope did not write is deleted. Returns the paths written. Throws
// sope::Error unless 1 ≤ instances_per_class ≤ kMaxInstancesPerClass and `dir` is
// non-empty, or when a file cannot be written.
constexpr int kMaxInstancesPerClass = 1000;
std::vector<std::string> WriteProceduralModels(const std::string& dir, int instances_per_class,
                                               uint64_t seed,
                                               const ProceduralObjectOptions& options = {});
// The same for chosen instances: per class the given instance seeds, each written as
// <class>/<class>_<seed>.obj (the model names CLASS_SEED).
std::vector<std::string> WriteProceduralModels(
    const std::string& dir,
    const std::vector<std::pair<ObjectClass, std::vector<uint64_t>>>& instances,
    const ProceduralObjectOptions& options = {});

namespace internal {
// Building blocks, exposed for the tests.

// A profile curve in the half plane (r ≥ 0, z) built from pieces joined end to end, each
// joint optionally rounded. Lengths in metres.
class ProfileBuilder {
 public:
  explicit ProfileBuilder(const Eigen::Vector2d& start);

  // A straight segment from the current point to `end`.
  ProfileBuilder& LineTo(const Eigen::Vector2d& end);
  // A centripetal Catmull–Rom spline from the current point through `knots` (the last is
  // the end). `start_tangent` / `end_tangent` (any length; zero = free, from the reflected
  // neighbouring knot) set the directions at the two ends.
  ProfileBuilder& SplineTo(const std::vector<Eigen::Vector2d>& knots,
                           const Eigen::Vector2d& start_tangent = Eigen::Vector2d::Zero(),
                           const Eigen::Vector2d& end_tangent = Eigen::Vector2d::Zero());
  // A dense polyline whose first point is (within 1 µm) the current point.
  ProfileBuilder& PolylineTo(const std::vector<Eigen::Vector2d>& points);
  // Rounds the joint at the current point (between the last piece and the next one) with a
  // fillet of about `radius` (a quadratic Bézier tangent to both pieces at distance
  // radius·tan(turn/2) from the corner, at most half of either piece's length).
  ProfileBuilder& Round(double radius);

  const Eigen::Vector2d& current() const { return current_; }
  // The polyline with the joints rounded, simplified to `tolerance`, consecutive
  // duplicates removed.
  std::vector<Eigen::Vector2d> Build(double tolerance) const;

 private:
  Eigen::Vector2d current_;
  std::vector<std::vector<Eigen::Vector2d>> pieces_;
  std::vector<double> round_radius_;  // per piece: fillet at its end joint, 0 = sharp
};

// Dense samples (spacing about 0.25 mm) of a centripetal Catmull–Rom spline through `knots`
// (≥ 2), end tangents as in ProfileBuilder::SplineTo.
std::vector<Eigen::Vector2d> SampleCatmullRom(const std::vector<Eigen::Vector2d>& knots,
                                              const Eigen::Vector2d& start_tangent,
                                              const Eigen::Vector2d& end_tangent);

// The polyline moved by `distance` to its left (rotating the direction of travel by +90°;
// for a wall traced upward at r > 0 that is toward the axis), mitred at the vertices.
std::vector<Eigen::Vector2d> OffsetPolyline(const std::vector<Eigen::Vector2d>& points,
                                            double distance);

// Douglas–Peucker simplification keeping both ends; every removed point is within
// `tolerance` of the result.
std::vector<Eigen::Vector2d> SimplifyPolyline(const std::vector<Eigen::Vector2d>& points,
                                              double tolerance);

// Surface of revolution of `profile` (r, z) about the z axis with `segments` segments:
// the first and last points must lie on the axis (r = 0; they become poles) and all others
// off it, and the profile must run counter-clockwise in the (r, z) half plane (the
// material on its left, e.g. up the outside, down the inside) for outward faces. Closed and
// watertight. `radial_scale(z, phi)` (optional) multiplies every radius, e.g. for flutes.
TriangleMesh Lathe(const std::vector<Eigen::Vector2d>& profile, int segments,
                   const std::function<double(double z, double phi)>& radial_scale = {});

// Tube along the polyline `path` (≥ 2 points) whose section at path parameter s ∈ [0, 1]
// (by arc length) is the closed curve section(s, theta), theta ∈ [0, 2π), given in the
// local frame (normal, binormal) — binormal = `binormal` (unit, perpendicular to the path,
// which must be planar), normal = binormal × tangent. Capped at both ends; closed,
// watertight and oriented outward.
TriangleMesh SweepTube(const std::vector<Eigen::Vector3d>& path, const Eigen::Vector3d& binormal,
                       const std::function<Eigen::Vector2d(double s, double theta)>& section,
                       int section_segments);

// Cuboid with full edge lengths size (x, y, z) centred at the origin, its edges and corners
// rounded with `radius` (0 < radius < half the smallest size): each face grid is extended
// over its half of the neighbouring edges, the points mapped onto the rounded surface
// (q = clamp(p, inner box) + radius·unit(p − clamp(p, inner box)) for p on the outer
// box), `bevel_segments` (≥ 1) facets on each face's side of an edge, so 2·bevel_segments
// per quarter circle. Closed and watertight.
TriangleMesh MakeRoundedBox(const Eigen::Vector3d& size, double radius, int bevel_segments);

// Appends `part`'s vertices and faces to `mesh`.
void AppendMesh(const TriangleMesh& part, TriangleMesh* mesh);

// An instance before assembly: MakeObject() = Lathe(profile, segments, radial_scale)
// (when the profile is not empty) plus every mesh in `parts`.
struct ObjectParts {
  std::vector<Eigen::Vector2d> profile;                      // (r, z), metres; empty for boxes
  std::function<double(double z, double phi)> radial_scale;  // empty = 1
  std::vector<TriangleMesh> parts;                           // handles; the box
};
ObjectParts MakeObjectParts(ObjectClass cls, uint64_t seed, const ProceduralObjectOptions& options);

}  // namespace internal
}  // namespace sope
