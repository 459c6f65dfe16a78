// Tabletop scenes on the virtual rig (issue 12, `sope simulate --table`): several objects
// resting on a table seen from above at a desk-rig angle, touching and hiding each other,
// optionally with unknown clutter and a backdrop (a wall behind the table), with the ground
// truth of every object.
//
// Resting poses. A rigid object on a plane rests on a face of its convex hull; the face is
// statically stable when the centre of mass projects (along the face normal) into the face
// polygon (e.g. Moll & Erdmann, "Manipulation of pose distributions", IJRR 2002; the
// quasi-static probability of landing on a face is the solid angle the face subtends at
// the centre of mass, Wiegley et al. 1996). The hull is qhull's (merged coplanar facets);
// the centre of mass is that of the solid (signed tetrahedra; the hull's when the mesh is
// not a closed positive solid). A stable face is drawn with probability ∝ its solid angle,
// the yaw about the table normal uniformly.
//
// Placement. Table frame: origin where the camera's optical axis meets the table, z up
// (towards the camera side), x along the camera's x axis. An object's footprint is the
// convex hull of its hull vertices projected on the table; footprints must not overlap
// (touching allowed, within kFootprintTolerance), which keeps the solids apart — their
// hulls lie inside disjoint vertical prisms. With allow_touching some objects are slid
// toward a neighbour until their footprints touch. Every object's hull must project
// inside the camera image and the projector image (with margins): what both see.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include "core/convex_hull.h"

#include "core/camera_model.h"
#include "core/mesh.h"
#include "core/rig_calibration.h"
#include "core/rigid3d.h"
#include "simulator/virtual_rig.h"

namespace sope {

// Two footprints may overlap by this much (metres) and still count as touching.
constexpr double kFootprintTolerance = 1e-4;
// Most objects on one table.
constexpr int kMaxTableObjects = 16;

struct TableObjectSpec {
  // Mesh spec as LoadMeshSpec (simulator/scene_builder.h): a file or builtin:CLASS[:SEED].
  std::string spec;
  // Empty: derived from the spec (TableObjectNames).
  std::string model;
  std::string class_name;
  // Model frame; filled by MakeTableScene from `spec` when empty.
  TriangleMesh mesh;
  // Bounding-box diagonal to scale the mesh to, metres; 0 keeps its units (files in
  // metres); kSizeAsDatabase: the rule build-db applies (core/object_size.h: kept when the
  // diagonal is plausible in metres, else scaled to kDefaultObjectDiagonal; or scaled by
  // mesh_unit when that is given, as build-db --units).
  double size = 0.0;
  // With kSizeAsDatabase: metres per mesh file unit (SizeNormalisationOptions::mesh_unit of
  // the database); 0 guesses.
  double mesh_unit = 0.0;
};
constexpr double kSizeAsDatabase = -1.0;

// Model and class names a database built from the same meshes gives (build-db and the
// procedural models directory, simulator/procedural_objects.h WriteProceduralModels):
// "builtin:CLASS:SEED" → model CLASS_SEED, class CLASS ("builtin:CLASS" = seed 0); other
// builtins → model = class = the name; a file DIR/<class>/<class>_<k>.ext (a procedural
// models directory) → model <class>_<k>, class <class>; any other file → model = class =
// its stem (a flat models directory: "a flat file's class is its name").
void TableObjectNames(const std::string& spec, std::string* model, std::string* class_name);

struct TableSceneOptions {
  std::vector<TableObjectSpec> objects;  // the known objects, at least one
  // Unknown clutter objects (class "clutter", in no database): tori and lumpy stones
  // (an ellipsoid with random low-order bumps), 6–11 cm and 3–9 cm across.
  int clutter = 0;
  // A matte wall standing on the table's far edge, facing the camera.
  bool backdrop = true;
  // Angle between the optical axis and the table plane, degrees: uniform in [min, max].
  double camera_tilt_deg_min = 30.0;
  double camera_tilt_deg_max = 60.0;
  // Camera centre to the table point on the optical axis, metres.
  double table_distance = 0.75;
  // Table top: `table_size` metres square around the optical-axis point (the far half as
  // deep as the near half is free, the wall stands at the far edge).
  double table_size = 1.2;
  double table_albedo = 0.45;
  // Object albedo uniform in [min, max] (dark and bright objects), clutter alike.
  double albedo_min = 0.25;
  double albedo_max = 0.85;
  // Objects slid against a neighbour until they touch, probability per object.
  bool allow_touching = true;
  double touch_probability = 0.4;
  // Margin kept from the camera's and the projector's image border, pixels.
  double image_margin_px = 20.0;
  // Random placements tried per object; when one finds no place, the table is cleared and
  // placement starts again, at most `placement_restarts` times in all.
  int placement_attempts = 400;
  int placement_restarts = 8;
  uint64_t seed = 1;
  // Throws sope::Error naming the invalid value (no objects, tilt outside (0, 90], …).
  void Check() const;
};

struct TableObjectTruth {
  std::string spec;  // the mesh spec (empty for clutter and meshes given directly)
  std::string model, class_name;
  bool known = true;      // false for clutter
  int scene_index = -1;   // index in Scene::objects (gt_object_id = index + 1)
  Rigid3d cam_from_model;
  TriangleMesh mesh;      // model frame, metres (scaled)
  double scale = 1.0;     // applied to the spec's mesh
  Eigen::Vector3d center_of_mass_in_model = Eigen::Vector3d::Zero();
  // The resting face (hull facet) in the model frame: unit outward normal n and offset
  // with n·x + offset = 0 on the face.
  Eigen::Vector3d rest_normal_in_model = Eigen::Vector3d::UnitZ();
  double rest_offset = 0.0;
  // Solid-angle probability of the chosen face among all hull faces.
  double rest_probability = 0.0;
  // Filled by ComputeVisibleFractions: pixels (pixel centres) of the object in the full
  // scene, pixels when rendered alone, and their ratio in [0, 1].
  int visible_pixels = 0;
  int alone_pixels = 0;
  double visible_fraction = 0.0;
};

struct TableScene {
  // Known objects, clutter, then the table top and the backdrop (if any).
  Scene scene;
  // Table plane in the camera frame: n·x + d = 0, unit n towards the camera (d > 0).
  Eigen::Vector4d table_plane_in_cam = Eigen::Vector4d::Zero();
  Rigid3d cam_from_table;      // the table frame (see the top of this file)
  double camera_tilt_deg = 0;  // angle between optical axis and table plane, degrees
  int table_index = -1;        // Scene::objects index of the table top
  int backdrop_index = -1;     // … of the backdrop, −1 = none
  std::vector<TableObjectTruth> objects;  // known first (spec order), then clutter
  // Derived from the seed for the sensor noise of a capture.
  uint64_t seed = 1;
};

// Scene `options.seed` (deterministic) for the rig `calibration`. Throws sope::Error on
// invalid options, an unreadable mesh, or when the objects cannot all be placed ("cannot
// place 7 objects on the table: object 6 (…) does not fit …").
TableScene MakeTableScene(const TableSceneOptions& options, const RigCalibration& calibration);

// Visible fraction of every object: pixels with its gt object id in `object_id` (the full
// scene's GroundTruth::object_id, CV_32SC1) over the pixels it covers rendered alone with
// a DepthRenderer (both count pixel-centre ray hits), clamped to [0, 1].
void ComputeVisibleFractions(const cv::Mat& object_id, const CameraModel& camera,
                             TableScene* scene);
// The same, setting the scene on `rig` first (the rig then holds the scene).
void ComputeVisibleFractions(VirtualRig& rig, TableScene* scene);

// Sensor options for hard, realistic tabletop scans: camera and projector gamma, a
// projector black level, stronger defocus and blur, more noise and ambient light than
// SensorOptions' defaults (and the table is farther than the rig's reference distance, so
// it is dimmer).
SensorOptions TableSensorOptions(uint64_t seed = 1);

// A colour picture of the object ids (CV_8UC3): every object its own colour, table and
// backdrop grey, nothing black; each known object labelled with its model name.
cv::Mat DrawTableObjects(const cv::Mat& object_id, const CameraModel& camera,
                         const TableScene& scene);

// gt_pose.json of a table scene (`sope simulate --table`), pretty-printed:
//   {"format": "sope-gt-pose/1", "scene": "table", "units": …,
//    "table_plane": [nx, ny, nz, d] (camera frame, n·x + d = 0, n towards the camera),
//    "table": {"cam_from_table", "camera_tilt_deg", "gt_object_id"},
//    "backdrop": {"gt_object_id"} (when present),
//    "objects": [{"model", "class", "known", "cam_from_model" (rotation 3×3, translation m,
//                 as for single-object scans), "visible_fraction", "visible_pixels",
//                 "alone_pixels", "gt_object_id" (its value in gt_object_id.png), "mesh"
//                 (the spec), "scale", "albedo", "center_of_mass_in_model"}, …]}
// known objects first, then clutter.
std::string TableGroundTruthJson(const TableScene& scene);

namespace internal {

// The convex hull, centre of mass and resting faces live in core/convex_hull.h (the
// recogniser's plane prior uses them too).
using sope::ComputeConvexHull;
using sope::ConvexHull;
using sope::CenterOfMass;
using sope::ConvexHull2d;
using sope::HullFacet;
using sope::RestingFace;
using sope::StableFaces;

// 2-D convex polygons (counter-clockwise): penetration depth along the best separating
// axis (≤ 0: disjoint or touching, > 0: overlapping by that much).
double PolygonOverlap(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b);

}  // namespace internal
}  // namespace sope
