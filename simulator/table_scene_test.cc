#include "simulator/table_scene.h"

#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/object_size.h"
#include "simulator/primitives.h"

namespace sope {
namespace {

using internal::ConvexHull;
using internal::ComputeConvexHull;

TableObjectSpec Spec(const std::string& spec) {
  TableObjectSpec object;
  object.spec = spec;
  return object;
}

std::vector<Eigen::Vector3d> Vertices(const TriangleMesh& mesh) {
  std::vector<Eigen::Vector3d> points;
  for (const Eigen::Vector3f& v : mesh.vertices) points.push_back(v.cast<double>());
  return points;
}

TableSceneOptions FourObjects(uint64_t seed) {
  TableSceneOptions options;
  for (const char* spec : {"builtin:mug:1", "builtin:bottle:2", "builtin:can:3", "builtin:bowl:4"}) {
    options.objects.push_back(Spec(spec));
  }
  options.clutter = 1;
  options.seed = seed;
  return options;
}

double PlaneDistance(const Eigen::Vector4d& plane, const Eigen::Vector3d& point) {
  return plane.head<3>().dot(point) + plane[3];
}

TEST(TableScene, CubeFacesAreEquallyLikely) {
  const ConvexHull hull = ComputeConvexHull(Vertices(MakeBox(0.1, 0.1, 0.1)));
  ASSERT_EQ(hull.facets.size(), 6u);  // coplanar triangles merged
  EXPECT_NEAR(hull.volume, 1e-3, 1e-9);
  const std::vector<internal::RestingFace> faces =
      internal::StableFaces(hull, Eigen::Vector3d::Zero());
  ASSERT_EQ(faces.size(), 6u);
  for (const internal::RestingFace& face : faces) {
    EXPECT_NEAR(face.probability, 1.0 / 6.0, 1e-9);
    EXPECT_NEAR(face.stability_margin, 0.05, 1e-9);
  }
}

TEST(TableScene, LeaningPrismDoesNotStandOnItsBase) {
  // Base [0, 0.02]² at z = 0, top shifted by 0.1 m in x at z = 0.1: the centre of mass
  // (x = 0.06) is beyond the base.
  std::vector<Eigen::Vector3d> points;
  for (double z : {0.0, 0.1}) {
    for (double x : {0.0, 0.02}) {
      for (double y : {0.0, 0.02}) points.emplace_back(x + z, y, z);
    }
  }
  const ConvexHull hull = ComputeConvexHull(points);
  EXPECT_NEAR(hull.centroid.x(), 0.06, 1e-9);
  const std::vector<internal::RestingFace> faces = internal::StableFaces(hull, hull.centroid);
  ASSERT_FALSE(faces.empty());
  double total = 0.0;
  for (const internal::RestingFace& face : faces) {
    total += face.probability;
    EXPECT_GT(hull.facets[face.facet].normal.z(), -0.99) << "the base is not a rest";
  }
  EXPECT_LT(total, 1.0);
}

TEST(TableScene, PolygonOverlapSeparatesTouchesAndOverlaps) {
  const std::vector<Eigen::Vector2d> square = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  auto shifted = [&](double dx) {
    std::vector<Eigen::Vector2d> out = square;
    for (Eigen::Vector2d& p : out) p.x() += dx;
    return out;
  };
  EXPECT_NEAR(internal::PolygonOverlap(square, shifted(1.5)), -0.5, 1e-12);
  EXPECT_NEAR(internal::PolygonOverlap(square, shifted(1.0)), 0.0, 1e-12);
  EXPECT_NEAR(internal::PolygonOverlap(square, shifted(0.75)), 0.25, 1e-12);
}

TEST(TableScene, NamesMatchTheDatabaseBuilder) {
  std::string model, cls;
  TableObjectNames("builtin:mug:17", &model, &cls);
  EXPECT_EQ(model, "mug_17");
  EXPECT_EQ(cls, "mug");
  TableObjectNames("builtin:bottle", &model, &cls);
  EXPECT_EQ(model, "bottle_0");
  EXPECT_EQ(cls, "bottle");
  TableObjectNames("builtin:torus", &model, &cls);
  EXPECT_EQ(model, "torus");
  EXPECT_EQ(cls, "torus");
  TableObjectNames("/data/meshes/ycb/Banana.obj", &model, &cls);
  EXPECT_EQ(model, "Banana");
  EXPECT_EQ(cls, "Banana");
  TableObjectNames("models/mug/mug_3.obj", &model, &cls);
  EXPECT_EQ(model, "mug_3");
  EXPECT_EQ(cls, "mug");
}

// Every object's lowest point lies on the table (1 mm), nothing below it (1 µm), its
// resting face is flat on the table (0.1°) and the centre of mass lies over the support
// polygon (the mesh vertices within 1 mm of the table).
TEST(TableScene, ObjectsRestStablyOnTheTable) {
  const RigCalibration calibration = DefaultRigCalibration();
  for (uint64_t seed : {1, 2, 3, 4, 5, 6}) {
    const TableScene scene = MakeTableScene(FourObjects(seed), calibration);
    ASSERT_EQ(scene.objects.size(), 5u);
    EXPECT_FALSE(scene.objects.back().known);
    EXPECT_NEAR(scene.table_plane_in_cam.head<3>().norm(), 1.0, 1e-12);
    EXPECT_GT(scene.table_plane_in_cam[3], 0.0);  // the camera is above the table
    const Rigid3d table_from_cam = scene.cam_from_table.Inverse();
    for (const TableObjectTruth& truth : scene.objects) {
      SCOPED_TRACE(fmt::format("seed {} object {}", seed, truth.model));
      double lowest = std::numeric_limits<double>::infinity();
      for (const Eigen::Vector3f& v : truth.mesh.vertices) {
        lowest = std::min(lowest, PlaneDistance(scene.table_plane_in_cam,
                                                truth.cam_from_model * v.cast<double>()));
      }
      EXPECT_GE(lowest, -1e-6);
      EXPECT_LE(lowest, 1e-3);
      const Eigen::Vector3d down_in_cam = truth.cam_from_model.rotation * truth.rest_normal_in_model;
      EXPECT_GT(-down_in_cam.dot(scene.table_plane_in_cam.head<3>()), std::cos(0.1 * M_PI / 180));
      std::vector<Eigen::Vector2d> contact;
      for (const Eigen::Vector3f& v : truth.mesh.vertices) {
        const Eigen::Vector3d in_table =
            table_from_cam * (truth.cam_from_model * v.cast<double>());
        if (in_table.z() <= 1e-3) contact.push_back(in_table.head<2>());
      }
      const std::vector<Eigen::Vector2d> support = internal::ConvexHull2d(contact);
      ASSERT_GE(support.size(), 3u);
      const Eigen::Vector2d com =
          (table_from_cam * (truth.cam_from_model * truth.center_of_mass_in_model)).head<2>();
      // Inside every counter-clockwise edge.
      for (size_t i = 0; i < support.size(); ++i) {
        const Eigen::Vector2d a = support[i], b = support[(i + 1) % support.size()];
        const Eigen::Vector2d edge = b - a;
        EXPECT_GE(edge.x() * (com.y() - a.y()) - edge.y() * (com.x() - a.x()), 0.0);
      }
    }
  }
}

// No surface point of one object (vertices and face centroids) is inside another's
// convex hull by more than 0.5 mm; every hull vertex projects into camera and projector.
TEST(TableScene, ObjectsDoNotInterpenetrateAndAreSeenByBoth) {
  const RigCalibration calibration = DefaultRigCalibration();
  int touching_pairs = 0;
  for (uint64_t seed : {1, 2, 3, 4, 5, 6, 7, 8}) {
    const TableScene scene = MakeTableScene(FourObjects(seed), calibration);
    std::vector<ConvexHull> hulls;
    for (const TableObjectTruth& truth : scene.objects) {
      hulls.push_back(ComputeConvexHull(Vertices(truth.mesh)));
      for (const Eigen::Vector3d& v : hulls.back().vertices) {
        const Eigen::Vector3d in_cam = truth.cam_from_model * v;
        const Eigen::Vector3d in_proj = calibration.proj_from_cam * in_cam;
        const Eigen::Vector2d pixel = calibration.camera.ImageFromCam(in_cam);
        const Eigen::Vector2d proj_pixel = calibration.projector.ImageFromCam(in_proj);
        EXPECT_TRUE(in_cam.z() > 0 && pixel.x() >= 0 && pixel.y() >= 0 &&
                    pixel.x() < calibration.camera.width && pixel.y() < calibration.camera.height);
        EXPECT_TRUE(in_proj.z() > 0 && proj_pixel.x() >= 0 && proj_pixel.y() >= 0 &&
                    proj_pixel.x() < calibration.projector.width &&
                    proj_pixel.y() < calibration.projector.height);
      }
    }
    for (size_t i = 0; i < scene.objects.size(); ++i) {
      const TableObjectTruth& a = scene.objects[i];
      std::vector<Eigen::Vector3d> surface = Vertices(a.mesh);
      for (const Eigen::Vector3i& f : a.mesh.faces) {
        surface.push_back((a.mesh.vertices[f[0]] + a.mesh.vertices[f[1]] + a.mesh.vertices[f[2]])
                              .cast<double>() / 3.0);
      }
      for (size_t j = 0; j < scene.objects.size(); ++j) {
        if (i == j) continue;
        const TableObjectTruth& b = scene.objects[j];
        const Rigid3d b_from_a = b.cam_from_model.Inverse() * a.cam_from_model;
        double closest = std::numeric_limits<double>::infinity();
        for (const Eigen::Vector3d& p : surface) closest = std::min(closest, hulls[j].Distance(b_from_a * p));
        EXPECT_GE(closest, -5e-4) << "seed " << seed << ": " << a.model << " inside " << b.model;
        if (i < j && closest < 2e-3) ++touching_pairs;
      }
    }
  }
  EXPECT_GT(touching_pairs, 0) << "allow_touching never made two objects touch";
}

TEST(TableScene, DeterministicBySeedAndTiltInRange) {
  const RigCalibration calibration = DefaultRigCalibration();
  const TableScene a = MakeTableScene(FourObjects(11), calibration);
  const TableScene b = MakeTableScene(FourObjects(11), calibration);
  const TableScene c = MakeTableScene(FourObjects(12), calibration);
  ASSERT_EQ(a.objects.size(), b.objects.size());
  for (size_t i = 0; i < a.objects.size(); ++i) {
    EXPECT_EQ(a.objects[i].model, b.objects[i].model);
    EXPECT_EQ(a.objects[i].cam_from_model.ToMatrix(), b.objects[i].cam_from_model.ToMatrix());
    EXPECT_EQ(a.scene.objects[i].albedo, b.scene.objects[i].albedo);
  }
  EXPECT_GT((a.objects[0].cam_from_model.translation - c.objects[0].cam_from_model.translation)
                .norm(), 1e-4);
  TableSceneOptions options = FourObjects(1);
  double lo = 90, hi = 0;
  for (uint64_t seed = 1; seed <= 20; ++seed) {
    options.seed = seed;
    const TableScene scene = MakeTableScene(options, calibration);
    // Angle between the optical axis (0, 0, 1) and the plane: asin(|n·z|).
    const double tilt = std::asin(std::abs(scene.table_plane_in_cam[2])) * 180 / M_PI;
    EXPECT_GE(tilt, 30.0);
    EXPECT_LE(tilt, 60.0);
    EXPECT_NEAR(tilt, scene.camera_tilt_deg, 1e-9);
    // The optical axis meets the table at the table distance.
    EXPECT_NEAR(-scene.table_plane_in_cam[3] / scene.table_plane_in_cam[2], 0.75, 1e-9);
    lo = std::min(lo, tilt);
    hi = std::max(hi, tilt);
  }
  EXPECT_GT(hi - lo, 10.0) << "tilts are not spread over the range";
}

// Visible fractions against the rig's ground truth: the counts are those of gt object
// ids, and an object rendered alone by the rig covers the DepthRenderer's pixel count
// (within 0.5%).
TEST(TableScene, VisibleFractionsMatchObjectIds) {
  const RigCalibration calibration = DefaultRigCalibration();
  TableSceneOptions options = FourObjects(3);
  options.objects.push_back(Spec("builtin:box:5"));
  TableScene scene = MakeTableScene(options, calibration);
  SensorOptions sensor;
  sensor.supersample = 1;
  VirtualRig rig(calibration, sensor);
  ComputeVisibleFractions(rig, &scene);
  const cv::Mat& ids = rig.ground_truth().object_id;
  for (const TableObjectTruth& truth : scene.objects) {
    SCOPED_TRACE(truth.model);
    EXPECT_EQ(truth.visible_pixels, cv::countNonZero(ids == truth.scene_index));
    EXPECT_GT(truth.alone_pixels, 100);
    EXPECT_GE(truth.visible_fraction, 0.0);
    EXPECT_LE(truth.visible_fraction, 1.0);
    EXPECT_NEAR(truth.visible_fraction,
                std::min(1.0, static_cast<double>(truth.visible_pixels) / truth.alone_pixels), 1e-12);
  }
  // Two objects alone on the rig.
  for (int i : {0, 1}) {
    const TableObjectTruth& truth = scene.objects[i];
    Scene alone;
    alone.objects.push_back(scene.scene.objects[truth.scene_index]);
    rig.SetScene(alone);
    const int count = cv::countNonZero(rig.ground_truth().object_id == 0);
    EXPECT_NEAR(count, truth.alone_pixels, 0.005 * truth.alone_pixels) << truth.model;
  }
}

TEST(TableScene, SizesMeshesLikeTheDatabaseBuilder) {
  TableSceneOptions options;
  TableObjectSpec large;  // a 2 m cube: not plausibly metres
  large.mesh = MakeBox(2, 2, 2);
  large.model = "large";
  large.size = kSizeAsDatabase;
  TableObjectSpec kept = Spec("builtin:mug:2");
  kept.size = kSizeAsDatabase;
  TableObjectSpec resized = Spec("builtin:can:2");
  resized.size = 0.2;
  options.objects = {large, kept, resized};
  const TableScene scene = MakeTableScene(options, DefaultRigCalibration());
  EXPECT_NEAR(scene.objects[0].scale, kDefaultObjectDiagonal / std::sqrt(12.0), 1e-6);
  EXPECT_NEAR(scene.objects[0].mesh.BoundingDiagonal(), kDefaultObjectDiagonal, 1e-6);
  EXPECT_EQ(scene.objects[0].model, "large");
  EXPECT_EQ(scene.objects[1].scale, 1.0);
  EXPECT_NEAR(scene.objects[2].mesh.BoundingDiagonal(), 0.2, 1e-6);

  // With the database's mesh unit (build-db --units) every mesh is scaled by it: a 150 mm
  // box (90 x 120 x 30) is 0.153 m across, not the guess's 0.25 m; a mesh plausible in
  // metres is scaled too.
  TableObjectSpec millimetres;
  millimetres.mesh = MakeBox(90, 120, 30);
  millimetres.model = "mm";
  millimetres.size = kSizeAsDatabase;
  millimetres.mesh_unit = 0.001;
  TableObjectSpec decimetres;
  decimetres.mesh = MakeBox(0.3, 0.4, 0.1);  // ~0.5 units: plausible as metres
  decimetres.model = "dm";
  decimetres.size = kSizeAsDatabase;
  decimetres.mesh_unit = 0.1;
  options.objects = {millimetres, decimetres};
  const TableScene given = MakeTableScene(options, DefaultRigCalibration());
  EXPECT_EQ(given.objects[0].scale, 0.001);
  EXPECT_NEAR(given.objects[0].mesh.BoundingDiagonal(), std::hypot(0.09, 0.12, 0.03), 1e-6);
  EXPECT_EQ(given.objects[1].scale, 0.1);
  options.objects[0].mesh_unit = -1;
  EXPECT_THROW(MakeTableScene(options, DefaultRigCalibration()), Error);
}

TEST(TableScene, BadInputGetsOneClearError) {
  const RigCalibration calibration = DefaultRigCalibration();
  TableSceneOptions none;
  try {
    MakeTableScene(none, calibration);
    ADD_FAILURE() << "no objects accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("at least one object"), std::string::npos) << e.what();
  }
  TableSceneOptions crowded;
  for (int k = 0; k < 12; ++k) crowded.objects.push_back(Spec(fmt::format("builtin:box:{}", 100 + k)));
  crowded.placement_attempts = 100;
  try {
    MakeTableScene(crowded, calibration);
    ADD_FAILURE() << "12 boxes fitted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot place 12 objects"), std::string::npos)
        << e.what();
  }
  TableSceneOptions tilt = FourObjects(1);
  tilt.camera_tilt_deg_max = 95;
  EXPECT_THROW(MakeTableScene(tilt, calibration), Error);
  TableSceneOptions missing = FourObjects(1);
  missing.objects[0].spec = "/nonexistent/mesh.obj";
  EXPECT_THROW(MakeTableScene(missing, calibration), Error);
}

}  // namespace
}  // namespace sope
