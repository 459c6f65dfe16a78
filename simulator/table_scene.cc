#include "simulator/table_scene.h"

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <filesystem>
#include <numeric>

#include <Eigen/Geometry>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/json.h"
#include "core/object_size.h"
#include "core/split_mix.h"
#include "simulator/primitives.h"
#include "simulator/procedural_objects.h"
#include "simulator/scene_builder.h"

namespace sope {
namespace {

constexpr double kDegree = M_PI / 180.0;
// Objects keep this far from the table's edges, metres.
constexpr double kTableEdgeMargin = 0.02;
// Hull points must be at least this far in front of camera and projector, metres.
constexpr double kMinDepth = 0.05;
// Bisection steps when sliding an object against a neighbour (2^-24 of the distance).
constexpr int kTouchSteps = 24;

// Rotation taking unit `from` to unit `to`.
Eigen::Matrix3d RotationBetween(const Eigen::Vector3d& from, const Eigen::Vector3d& to) {
  return Eigen::Quaterniond::FromTwoVectors(from, to).toRotationMatrix();
}

// Clutter: tori 6–11 cm and lumpy stones 3–9 cm across.
TriangleMesh MakeClutter(SplitMix* rng, std::string* model, int index) {
  if (rng->Uniform() < 0.4) {
    *model = fmt::format("clutter_torus_{}", index);
    const double major = rng->Uniform(0.022, 0.038);
    return MakeTorus(major, rng->Uniform(0.3, 0.45) * major, 64, 24);
  }
  *model = fmt::format("clutter_stone_{}", index);
  TriangleMesh stone = MakeSphere(1.0, 24, 48);
  const Eigen::Vector3d axes(rng->Uniform(0.025, 0.045), rng->Uniform(0.02, 0.04),
                             rng->Uniform(0.015, 0.03));
  struct Bump {
    Eigen::Vector3d direction;
    double frequency, phase, amplitude;
  };
  std::vector<Bump> bumps(4);
  for (Bump& bump : bumps) {
    bump.direction = Eigen::Vector3d(rng->Uniform(-1, 1), rng->Uniform(-1, 1), rng->Uniform(-1, 1))
                         .normalized();
    bump.frequency = rng->Uniform(1.0, 3.0);
    bump.phase = rng->Uniform(0, 2 * M_PI);
    bump.amplitude = rng->Uniform(0.03, 0.09);
  }
  for (Eigen::Vector3f& vertex : stone.vertices) {
    const Eigen::Vector3d u = vertex.cast<double>().normalized();
    double radius = 1.0;
    for (const Bump& bump : bumps) {
      radius += bump.amplitude * std::cos(bump.frequency * M_PI * u.dot(bump.direction) + bump.phase);
    }
    vertex = (radius * u.cwiseProduct(axes)).cast<float>();
  }
  return stone;
}

bool InImage(const CameraModel& device, const Eigen::Vector3d& point_in_device, double margin) {
  if (point_in_device.z() < kMinDepth) return false;
  const Eigen::Vector2d pixel = device.ImageFromCam(point_in_device);
  return pixel.x() >= margin && pixel.y() >= margin && pixel.x() <= device.width - 1 - margin &&
         pixel.y() <= device.height - 1 - margin;
}

// An object being placed: its hull in the model frame and its rest on the table.
struct Candidate {
  int input = -1;  // index in the truth list
  internal::ConvexHull hull;
  Eigen::Vector3d center_of_mass = Eigen::Vector3d::Zero();
  std::vector<internal::RestingFace> faces;
  double total_probability = 0.0;
  double radius = 0.0;  // of the hull about its centroid
};

struct Pose {
  Rigid3d table_from_model;
  std::vector<Eigen::Vector2d> footprint;  // table frame, counter-clockwise
  int face = -1;
};

// The rest on `face` with `yaw`, the footprint's centre at table point (x, y).
Pose RestPose(const Candidate& object, int face, double yaw, const Eigen::Vector2d& xy) {
  const internal::HullFacet& facet = object.hull.facets[object.faces[face].facet];
  const Eigen::Matrix3d rotation =
      Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
      RotationBetween(facet.normal, -Eigen::Vector3d::UnitZ());
  Pose pose;
  pose.face = face;
  std::vector<Eigen::Vector2d> projected;
  double lowest = std::numeric_limits<double>::infinity();
  for (const Eigen::Vector3d& vertex : object.hull.vertices) {
    const Eigen::Vector3d p = rotation * vertex;
    projected.push_back(p.head<2>());
    lowest = std::min(lowest, p.z());
  }
  pose.footprint = internal::ConvexHull2d(projected);
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();
  for (const Eigen::Vector2d& p : pose.footprint) centre += p;
  centre /= static_cast<double>(pose.footprint.size());
  const Eigen::Vector2d shift = xy - centre;
  for (Eigen::Vector2d& p : pose.footprint) p += shift;
  pose.table_from_model = Rigid3d(rotation, Eigen::Vector3d(shift.x(), shift.y(), -lowest));
  return pose;
}

}  // namespace

// ---------------------------------------------------------------------------------------
namespace internal {


double PolygonOverlap(const std::vector<Eigen::Vector2d>& a,
                      const std::vector<Eigen::Vector2d>& b) {
  // Separating axis theorem: the smallest interval overlap over every edge normal.
  double overlap = std::numeric_limits<double>::infinity();
  for (const std::vector<Eigen::Vector2d>* polygon : {&a, &b}) {
    const std::vector<Eigen::Vector2d>& p = *polygon;
    for (size_t i = 0; i < p.size(); ++i) {
      const Eigen::Vector2d edge = p[(i + 1) % p.size()] - p[i];
      if (edge.squaredNorm() <= 0) continue;
      const Eigen::Vector2d axis = Eigen::Vector2d(-edge.y(), edge.x()).normalized();
      double a_lo = std::numeric_limits<double>::infinity(), a_hi = -a_lo;
      double b_lo = a_lo, b_hi = -a_lo;
      for (const Eigen::Vector2d& q : a) {
        a_lo = std::min(a_lo, q.dot(axis));
        a_hi = std::max(a_hi, q.dot(axis));
      }
      for (const Eigen::Vector2d& q : b) {
        b_lo = std::min(b_lo, q.dot(axis));
        b_hi = std::max(b_hi, q.dot(axis));
      }
      overlap = std::min(overlap, std::min(a_hi, b_hi) - std::max(a_lo, b_lo));
    }
  }
  return overlap;
}

}  // namespace internal

// ---------------------------------------------------------------------------------------

void TableObjectNames(const std::string& spec, std::string* model, std::string* class_name) {
  const std::string prefix = "builtin:";
  if (spec.rfind(prefix, 0) == 0) {
    const std::string name = spec.substr(prefix.size());
    const size_t colon = name.find(':');
    const std::string base = name.substr(0, colon);
    bool procedural = false;
    for (ObjectClass cls : AllObjectClasses()) procedural |= ToString(cls) == base;
    if (!procedural || (colon == std::string::npos && base == "box")) {
      *model = *class_name = base;  // a primitive
      return;
    }
    *class_name = base;
    *model = base + "_" + (colon == std::string::npos ? std::string("0") : name.substr(colon + 1));
    return;
  }
  const std::filesystem::path path(spec);
  const std::string stem = path.stem().string();
  const std::string parent = path.parent_path().filename().string();
  *model = stem;
  *class_name =
      !parent.empty() && stem.size() > parent.size() + 1 && stem.rfind(parent + "_", 0) == 0
          ? parent
          : stem;
}

void TableSceneOptions::Check() const {
  SOPE_CHECK(!objects.empty(), "a table scene needs at least one object (--mesh)");
  SOPE_CHECK(clutter >= 0, "clutter must be ≥ 0 objects, got {}", clutter);
  const int total = static_cast<int>(objects.size()) + clutter;
  SOPE_CHECK(total <= kMaxTableObjects, "a table holds at most {} objects, got {} ({} + {} clutter)",
             kMaxTableObjects, total, objects.size(), clutter);
  SOPE_CHECK(std::isfinite(camera_tilt_deg_min) && std::isfinite(camera_tilt_deg_max) &&
                 camera_tilt_deg_min > 0 && camera_tilt_deg_max <= 90 &&
                 camera_tilt_deg_min <= camera_tilt_deg_max,
             "camera tilt range must lie in (0, 90]° with min ≤ max, got [{}, {}]",
             camera_tilt_deg_min, camera_tilt_deg_max);
  SOPE_CHECK(std::isfinite(table_distance) && table_distance > 0.1 && table_distance <= 10,
             "table distance must be in (0.1, 10] m, got {}", table_distance);
  SOPE_CHECK(std::isfinite(table_size) && table_size > 0.1 && table_size <= 20,
             "table size must be in (0.1, 20] m, got {}", table_size);
  SOPE_CHECK(table_albedo >= 0 && table_albedo <= 1, "table albedo must be in [0, 1], got {}",
             table_albedo);
  SOPE_CHECK(albedo_min >= 0 && albedo_max <= 1 && albedo_min <= albedo_max,
             "object albedo range must lie in [0, 1], got [{}, {}]", albedo_min, albedo_max);
  SOPE_CHECK(touch_probability >= 0 && touch_probability <= 1,
             "touch probability must be in [0, 1], got {}", touch_probability);
  SOPE_CHECK(std::isfinite(image_margin_px) && image_margin_px >= 0,
             "image margin must be ≥ 0 px, got {}", image_margin_px);
  SOPE_CHECK(placement_attempts >= 1, "placement attempts must be ≥ 1, got {}",
             placement_attempts);
  SOPE_CHECK(placement_restarts >= 1, "placement restarts must be ≥ 1, got {}",
             placement_restarts);
  for (const TableObjectSpec& object : objects) {
    SOPE_CHECK(!object.spec.empty() || !object.mesh.faces.empty(),
               "a table object needs a mesh spec or a mesh");
    SOPE_CHECK(object.size == kSizeAsDatabase ||
                   (std::isfinite(object.size) && object.size >= 0 && object.size <= 10),
               "object {}: size must be in [0, 10] m, got {}", object.spec, object.size);
    SOPE_CHECK(std::isfinite(object.mesh_unit) && object.mesh_unit >= 0 &&
                   object.mesh_unit <= 1000,
               "object {}: mesh unit must be in [0, 1000] m (0: guessed), got {}", object.spec,
               object.mesh_unit);
  }
}

TableScene MakeTableScene(const TableSceneOptions& options, const RigCalibration& calibration) {
  options.Check();
  calibration.camera.Check();
  calibration.projector.Check();
  SplitMix rng{options.seed * 0x9E3779B97F4A7C15ull + 0x7AB1E};
  TableScene out;
  out.seed = options.seed;

  // Camera and table: n = (0, −cos θ, −sin θ) (towards the camera, up in the image), the
  // table through the optical-axis point at table_distance.
  const double tilt = rng.Uniform(options.camera_tilt_deg_min, options.camera_tilt_deg_max);
  out.camera_tilt_deg = tilt;
  const double theta = tilt * kDegree;
  const Eigen::Vector3d x_axis = Eigen::Vector3d::UnitX();
  const Eigen::Vector3d z_axis(0, -std::cos(theta), -std::sin(theta));
  const Eigen::Vector3d y_axis = z_axis.cross(x_axis);
  Eigen::Matrix3d cam_from_table_rotation;
  cam_from_table_rotation << x_axis, y_axis, z_axis;
  out.cam_from_table =
      Rigid3d(cam_from_table_rotation, Eigen::Vector3d(0, 0, options.table_distance));
  out.table_plane_in_cam << z_axis, options.table_distance * std::sin(theta);
  const Rigid3d table_from_cam = out.cam_from_table.Inverse();
  const Rigid3d proj_from_table = calibration.proj_from_cam * out.cam_from_table;

  // The objects: meshes, names, hulls and stable faces.
  const int known = static_cast<int>(options.objects.size());
  const int total = known + options.clutter;
  std::vector<Candidate> candidates(total);
  out.objects.resize(total);
  for (int i = 0; i < total; ++i) {
    TableObjectTruth& truth = out.objects[i];
    if (i < known) {
      const TableObjectSpec& spec = options.objects[i];
      truth.mesh = spec.mesh.faces.empty() ? LoadMeshSpec(spec.spec) : spec.mesh;
      std::string model, class_name;
      TableObjectNames(spec.spec, &model, &class_name);
      truth.spec = spec.spec;
      truth.model = spec.model.empty() ? model : spec.model;
      truth.class_name = spec.class_name.empty() ? class_name : spec.class_name;
      if (truth.model.empty()) truth.model = fmt::format("object_{}", i + 1);
      if (truth.class_name.empty()) truth.class_name = truth.model;
      truth.mesh.Check();
      const double diagonal = truth.mesh.BoundingDiagonal();
      SOPE_CHECK(std::isfinite(diagonal) && diagonal > 0, "object {} ({}): the mesh has no extent",
                 i + 1, truth.model);
      const double scale = spec.size == kSizeAsDatabase ? MeshScale(diagonal, spec.mesh_unit)
                           : spec.size > 0             ? spec.size / diagonal
                                                       : 1.0;
      if (scale != 1.0) {
        truth.scale = scale;
        truth.mesh.Transform(truth.scale, Eigen::Vector3d::Zero());
      }
    } else {
      truth.known = false;
      truth.class_name = "clutter";
      truth.mesh = MakeClutter(&rng, &truth.model, i - known);
    }
    Candidate& candidate = candidates[i];
    candidate.input = i;
    std::vector<Eigen::Vector3d> points;
    points.reserve(truth.mesh.vertices.size());
    for (const Eigen::Vector3f& v : truth.mesh.vertices) points.push_back(v.cast<double>());
    try {
      candidate.hull = internal::ComputeConvexHull(points);
    } catch (const Error& e) {
      SOPE_THROW("object {} ({}): {}", i + 1, truth.model, e.what());
    }
    candidate.center_of_mass = internal::CenterOfMass(truth.mesh, candidate.hull);
    candidate.faces = internal::StableFaces(candidate.hull, candidate.center_of_mass);
    SOPE_CHECK(!candidate.faces.empty(), "object {} ({}): no stable resting face", i + 1,
               truth.model);
    for (const internal::RestingFace& face : candidate.faces) {
      candidate.total_probability += face.probability;
    }
    for (const Eigen::Vector3d& p : candidate.hull.vertices) {
      candidate.radius = std::max(candidate.radius, (p - candidate.hull.centroid).norm());
    }
    truth.center_of_mass_in_model = candidate.center_of_mass;
  }

  // Largest first: they are the hardest to fit.
  std::vector<int> order(total);
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return candidates[a].radius > candidates[b].radius; });

  const double half_width = options.table_size / 2;
  const double near_edge = -options.table_size / 2, far_edge = options.table_size / 3;
  const CameraModel& camera = calibration.camera;
  const CameraModel& projector = calibration.projector;
  auto valid = [&](const Candidate& object, const Pose& pose,
                   const std::vector<std::vector<Eigen::Vector2d>>& placed) {
    for (const Eigen::Vector2d& p : pose.footprint) {
      if (std::abs(p.x()) > half_width - kTableEdgeMargin ||
          p.y() < near_edge + kTableEdgeMargin || p.y() > far_edge - kTableEdgeMargin) {
        return false;
      }
    }
    for (const std::vector<Eigen::Vector2d>& other : placed) {
      if (internal::PolygonOverlap(pose.footprint, other) > kFootprintTolerance) return false;
    }
    const Rigid3d cam_from_model = out.cam_from_table * pose.table_from_model;
    const Rigid3d proj_from_model = proj_from_table * pose.table_from_model;
    for (const Eigen::Vector3d& vertex : object.hull.vertices) {
      if (!InImage(camera, cam_from_model * vertex, options.image_margin_px) ||
          !InImage(projector, proj_from_model * vertex, options.image_margin_px)) {
        return false;
      }
    }
    return true;
  };

  // Greedy placement, restarted from an empty table when an object finds no place.
  std::vector<Pose> poses(total);
  int failed = -1, failed_after = 0;
  for (int restart = 0; restart < options.placement_restarts; ++restart) {
    failed = -1;
    std::vector<std::vector<Eigen::Vector2d>> placed;
    std::vector<Eigen::Vector2d> placed_centres;
    for (int k = 0; k < total; ++k) {
      const Candidate& object = candidates[order[k]];
      bool found = false;
      for (int attempt = 0; attempt < options.placement_attempts && !found; ++attempt) {
        // A stable face by its probability, a yaw, and a table point seen by a random pixel.
        double pick = rng.Uniform() * object.total_probability;
        int face = 0;
        while (face + 1 < static_cast<int>(object.faces.size()) &&
               pick >= object.faces[face].probability) {
          pick -= object.faces[face].probability;
          ++face;
        }
        const double yaw = rng.Uniform(0, 2 * M_PI);
        const Eigen::Vector2d pixel(rng.Uniform(0.1, 0.9) * camera.width,
                                    rng.Uniform(0.1, 0.9) * camera.height);
        const Eigen::Vector3d ray = camera.RayFromImage(pixel);
        const double along = z_axis.dot(ray);
        if (along >= -1e-6) continue;  // the ray misses the table
        const Eigen::Vector3d hit_in_table =
            table_from_cam * Eigen::Vector3d(-out.table_plane_in_cam[3] / along * ray);
        Pose pose = RestPose(object, face, yaw, hit_in_table.head<2>());
        if (!valid(object, pose, placed)) continue;
        if (options.allow_touching && !placed.empty() && rng.Uniform() < options.touch_probability) {
          // Slide toward the nearest placed object until the footprints touch.
          const Eigen::Vector2d start = hit_in_table.head<2>();
          size_t nearest = 0;
          for (size_t j = 1; j < placed_centres.size(); ++j) {
            if ((placed_centres[j] - start).norm() < (placed_centres[nearest] - start).norm()) {
              nearest = j;
            }
          }
          const Eigen::Vector2d goal = placed_centres[nearest];
          double lo = 0.0, hi = 1.0;
          for (int step = 0; step < kTouchSteps; ++step) {
            const double mid = 0.5 * (lo + hi);
            const Pose moved = RestPose(object, face, yaw, start + mid * (goal - start));
            (valid(object, moved, placed) ? lo : hi) = mid;
          }
          pose = RestPose(object, face, yaw, start + lo * (goal - start));
        }
        poses[object.input] = pose;
        placed.push_back(pose.footprint);
        Eigen::Vector2d centre = Eigen::Vector2d::Zero();
        for (const Eigen::Vector2d& p : pose.footprint) centre += p;
        placed_centres.push_back(centre / static_cast<double>(pose.footprint.size()));
        found = true;
      }
      if (!found) {
        failed = object.input;
        failed_after = k;
        break;
      }
    }
    if (failed < 0) break;
  }
  if (failed >= 0) {
    SOPE_THROW(
        "cannot place {} objects on the table: object {} ({}, {:.0f} mm across) does not fit "
        "beside the {} placed in the area camera and projector both see ({} restarts of {} "
        "attempts per object)",
        total, failed + 1, out.objects[failed].model, 2e3 * candidates[failed].radius,
        failed_after, options.placement_restarts, options.placement_attempts);
  }

  // Scene objects: known, clutter, table, backdrop.
  for (int i = 0; i < total; ++i) {
    TableObjectTruth& truth = out.objects[i];
    const Candidate& object = candidates[i];
    const internal::HullFacet& facet = object.hull.facets[object.faces[poses[i].face].facet];
    truth.rest_normal_in_model = facet.normal;
    truth.rest_offset = facet.offset;
    truth.rest_probability = object.faces[poses[i].face].probability;
    truth.cam_from_model = out.cam_from_table * poses[i].table_from_model;
    truth.scene_index = static_cast<int>(out.scene.objects.size());
    SceneObject scene_object;
    scene_object.mesh = truth.mesh;
    scene_object.cam_from_model = truth.cam_from_model;
    scene_object.albedo = rng.Uniform(options.albedo_min, options.albedo_max);
    out.scene.objects.push_back(std::move(scene_object));
  }
  const float w = static_cast<float>(half_width);
  const float y0 = static_cast<float>(near_edge), y1 = static_cast<float>(far_edge);
  SceneObject table;
  table.mesh.vertices = {{-w, y0, 0}, {w, y0, 0}, {w, y1, 0}, {-w, y1, 0}};
  table.mesh.faces = {{0, 1, 2}, {0, 2, 3}};  // counter-clockwise seen from above
  table.cam_from_model = out.cam_from_table;
  table.albedo = options.table_albedo;
  out.table_index = static_cast<int>(out.scene.objects.size());
  out.scene.objects.push_back(std::move(table));
  if (options.backdrop) {
    SceneObject wall;
    const float h = static_cast<float>(options.table_size);
    wall.mesh.vertices = {{-w, y1, 0}, {w, y1, 0}, {w, y1, h}, {-w, y1, h}};
    wall.mesh.faces = {{0, 1, 2}, {0, 2, 3}};  // counter-clockwise seen from the camera side
    wall.cam_from_model = out.cam_from_table;
    wall.albedo = 0.6;
    out.backdrop_index = static_cast<int>(out.scene.objects.size());
    out.scene.objects.push_back(std::move(wall));
  }
  return out;
}

void ComputeVisibleFractions(const cv::Mat& object_id, const CameraModel& camera,
                             TableScene* scene) {
  SOPE_CHECK(object_id.type() == CV_32SC1 && object_id.cols == camera.width &&
                 object_id.rows == camera.height,
             "visible fractions: the object-id image must be CV_32SC1 of the camera's size "
             "{}x{}", camera.width, camera.height);
  std::vector<int> counts(scene->scene.objects.size() + 1, 0);
  for (int y = 0; y < object_id.rows; ++y) {
    const int32_t* row = object_id.ptr<int32_t>(y);
    for (int x = 0; x < object_id.cols; ++x) {
      if (row[x] >= 0 && row[x] < static_cast<int>(counts.size())) ++counts[row[x]];
    }
  }
  DepthRenderer renderer(camera);
  for (TableObjectTruth& truth : scene->objects) {
    renderer.SetMesh(truth.mesh);
    truth.alone_pixels = static_cast<int>(renderer.Render(truth.cam_from_model).size());
    truth.visible_pixels = counts.at(truth.scene_index);
    truth.visible_fraction =
        truth.alone_pixels > 0
            ? std::min(1.0, static_cast<double>(truth.visible_pixels) / truth.alone_pixels)
            : 0.0;
  }
}

void ComputeVisibleFractions(VirtualRig& rig, TableScene* scene) {
  rig.SetScene(scene->scene);
  ComputeVisibleFractions(rig.ground_truth().object_id, rig.calibration().camera, scene);
}

std::string TableGroundTruthJson(const TableScene& scene) {
  nlohmann::json objects = nlohmann::json::array();
  for (const TableObjectTruth& truth : scene.objects) {
    objects.push_back({{"model", truth.model},
                       {"class", truth.class_name},
                       {"known", truth.known},
                       {"cam_from_model", Rigid3dToJson(truth.cam_from_model)},
                       {"visible_fraction", JsonNumber(truth.visible_fraction)},
                       {"visible_pixels", truth.visible_pixels},
                       {"alone_pixels", truth.alone_pixels},
                       {"gt_object_id", truth.scene_index + 1},
                       {"mesh", truth.spec},
                       {"scale", JsonNumber(truth.scale)},
                       {"albedo", JsonNumber(scene.scene.objects.at(truth.scene_index).albedo)},
                       {"center_of_mass_in_model", Vector3dToJson(truth.center_of_mass_in_model)}});
  }
  const Eigen::Vector4d& plane = scene.table_plane_in_cam;
  nlohmann::json j = {
      {"format", "sope-gt-pose/1"},
      {"scene", "table"},
      {"units", "metres; rotation maps model to camera; table_plane n·x + d = 0 in the camera "
                "frame, n towards the camera"},
      {"table_plane", {JsonNumber(plane[0]), JsonNumber(plane[1]), JsonNumber(plane[2]),
                       JsonNumber(plane[3])}},
      {"table", {{"cam_from_table", Rigid3dToJson(scene.cam_from_table)},
                 {"camera_tilt_deg", JsonNumber(scene.camera_tilt_deg)},
                 {"gt_object_id", scene.table_index + 1}}},
      {"objects", objects}};
  if (scene.backdrop_index >= 0) j["backdrop"] = {{"gt_object_id", scene.backdrop_index + 1}};
  return j.dump(2) + "\n";
}

SensorOptions TableSensorOptions(uint64_t seed) {
  SensorOptions options;
  options.ambient = 0.12;            // a lit room
  options.gamma = 2.2;               // camera response
  options.projector_gamma = 2.2;     // an uncompensated projector
  options.projector_black_level = 0.03;
  options.projector_saturation = 0.97;
  options.defocus_sigma_px = 1.0;    // the table is beyond the focus distance
  options.camera_blur_sigma_px = 0.5;
  options.read_noise = 1.5;
  options.shot_noise = 0.4;
  options.seed = seed;
  return options;
}

cv::Mat DrawTableObjects(const cv::Mat& object_id, const CameraModel& camera,
                         const TableScene& scene) {
  SOPE_CHECK(object_id.type() == CV_32SC1 && object_id.cols == camera.width &&
                 object_id.rows == camera.height,
             "object picture: the object-id image must be CV_32SC1 of the camera's size");
  cv::Mat out(object_id.size(), CV_8UC3, cv::Scalar(0, 0, 0));
  std::vector<cv::Vec3b> colours(scene.scene.objects.size() + 1, cv::Vec3b(110, 110, 110));
  if (scene.backdrop_index >= 0) colours[scene.backdrop_index] = cv::Vec3b(70, 70, 70);
  for (size_t i = 0; i < scene.objects.size(); ++i) {
    // Hues spread by the golden angle.
    cv::Mat hsv(1, 1, CV_8UC3, cv::Scalar(std::fmod(i * 137.508, 180.0), 200, 255));
    cv::Mat bgr;
    cv::cvtColor(hsv, bgr, cv::COLOR_HSV2BGR);
    colours[scene.objects[i].scene_index] = bgr.at<cv::Vec3b>(0, 0);
  }
  for (int y = 0; y < object_id.rows; ++y) {
    const int32_t* ids = object_id.ptr<int32_t>(y);
    cv::Vec3b* row = out.ptr<cv::Vec3b>(y);
    for (int x = 0; x < object_id.cols; ++x) {
      if (ids[x] >= 0 && ids[x] < static_cast<int>(colours.size())) row[x] = colours[ids[x]];
    }
  }
  for (const TableObjectTruth& truth : scene.objects) {
    const Eigen::Vector3d centre = truth.cam_from_model * truth.center_of_mass_in_model;
    if (centre.z() <= 0) continue;
    const Eigen::Vector2d pixel = camera.ImageFromCam(centre);
    const std::string label = truth.known ? truth.model : "unknown";
    cv::putText(out, label, cv::Point(static_cast<int>(pixel.x()) - 30, static_cast<int>(pixel.y())),
                cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 3, cv::LINE_AA);
    cv::putText(out, label, cv::Point(static_cast<int>(pixel.x()) - 30, static_cast<int>(pixel.y())),
                cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  }
  return out;
}

}  // namespace sope
