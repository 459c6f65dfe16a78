// Tabletop recognition (issue 12) end to end on the virtual rig: procedural objects resting
// upright on a table plane seen 45° from above, plus an unknown clutter object (a torus,
// not in the database), scanned through the full pipeline (patterns rendered, decoded,
// triangulated); the table segmented, every cluster recognised, the scene verified. Checked
// against the ground truth: every known object found with the right model, centre within
// 5 mm, rotation modulo symmetry within 5°, resting on the plane; the torus not reported
// as a known object. Then the bad inputs: no plane, an empty table, NaN, a single point.
#include "recogniser/scene_recognition.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "calibration/scan.h"
#include "core/error.h"
#include "recogniser/pose_metrics.h"
#include "recogniser/tools/database_builder.h"
#include "simulator/primitives.h"
#include "simulator/procedural_objects.h"
#include "simulator/simulate_scan.h"
#include "simulator/virtual_rig.h"
#include "tests/test_support.h"

namespace sope {
namespace {

namespace fs = std::filesystem;

const std::vector<ObjectClass> kClasses = {ObjectClass::kMug, ObjectClass::kBottle,
                                           ObjectClass::kBox, ObjectClass::kBowl};

// Camera 45° down onto a table whose surface passes through (0, 0.02, 0.6) m (camera
// frame): world z up, world x = camera x.
struct TableFrame {
  Eigen::Matrix3d cam_from_world;
  Eigen::Vector3d origin_in_cam = Eigen::Vector3d(0, 0.02, 0.6);
  TableFrame() {
    const double tilt = 45.0 * M_PI / 180.0;
    const Eigen::Vector3d ex(1, 0, 0);
    const Eigen::Vector3d ez(0, -std::sin(tilt), -std::cos(tilt));
    cam_from_world.col(0) = ex;
    cam_from_world.col(1) = ez.cross(ex);
    cam_from_world.col(2) = ez;
  }
  // An upright object (model z up, its lowest point at z = 0) at table position (x, y),
  // turned by `yaw` about the vertical.
  Rigid3d Pose(double x, double y, double yaw) const {
    Rigid3d pose;
    pose.rotation = cam_from_world * Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).matrix();
    pose.translation = origin_in_cam + cam_from_world * Eigen::Vector3d(x, y, 0);
    return pose;
  }
};

SceneObject TableTop(const TableFrame& frame) {
  SceneObject table;
  // MakePlane's faces point to −z: turned over (about x) they face up, to the camera.
  table.mesh = MakePlane(0.7, 0.7, 4);
  table.cam_from_model = frame.Pose(0, 0, 0);
  table.cam_from_model.rotation =
      table.cam_from_model.rotation * Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).matrix();
  table.albedo = 0.6;
  return table;
}

PointCloud ScanScene(const Scene& scene) {
  const RigCalibration calibration = DefaultRigCalibration();
  VirtualRig rig(calibration);
  PatternOptions patterns;
  patterns.projector_width = calibration.projector.width;
  patterns.projector_height = calibration.projector.height;
  const SimulatedScan scan = SimulateScan(rig, scene, patterns);
  return ScanFrameSet(scan.frames, calibration).triangulation.cloud;
}

class SceneRecognitionTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir();
    const std::string models = scratch_->File("models");
    WriteProceduralModels(models, 1, 0);
    for (ObjectClass cls : AllObjectClasses()) {
      if (std::find(kClasses.begin(), kClasses.end(), cls) == kClasses.end()) {
        fs::remove_all(models + "/" + ToString(cls));
      }
    }
    DatabaseOptions options = DatabaseOptions::Preset("sope");
    options.views_per_model = 80;
    WriteDatabase(scratch_->File("table.sopedb"), BuildDatabase(models, options));
    db_ = Database::Open(scratch_->File("table.sopedb")).release();
  }
  static void TearDownTestSuite() {
    delete db_;
    delete scratch_;
  }
  static testing::ScratchDir* scratch_;
  static Database* db_;
};
testing::ScratchDir* SceneRecognitionTest::scratch_ = nullptr;
Database* SceneRecognitionTest::db_ = nullptr;

TEST_F(SceneRecognitionTest, FindsEveryKnownObjectOnTheTableAndRejectsTheUnknownOne) {
  const TableFrame frame;
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  struct Truth {
    ObjectClass cls;
    TriangleMesh mesh;
    Rigid3d pose;
  };
  std::vector<Truth> truths = {
      {ObjectClass::kMug, MakeObject(ObjectClass::kMug, 0), frame.Pose(0.0, -0.05, -0.6)},
      {ObjectClass::kBottle, MakeObject(ObjectClass::kBottle, 0), frame.Pose(-0.14, 0.0, 2.0)},
      {ObjectClass::kBowl, MakeObject(ObjectClass::kBowl, 0), frame.Pose(0.12, 0.03, 0.4)}};
  for (const Truth& t : truths) scene.objects.push_back({t.mesh, t.pose, 0.8, {}});
  // The unknown clutter object: a torus lying flat (its centre 2 cm above the table).
  Rigid3d torus_pose = frame.Pose(0.0, 0.09, 0.0);
  torus_pose.translation += frame.cam_from_world * Eigen::Vector3d(0, 0, 0.02);
  scene.objects.push_back({MakeTorus(0.045, 0.02), torus_pose, 0.8, {}});

  const PointCloud cloud = ScanScene(scene);
  ASSERT_GT(cloud.size(), 10000u);
  const SceneRecogniser recogniser(*db_);
  const SceneRecognitionResult result = recogniser.Recognise(cloud);
  std::printf("%s\n", SceneBriefReport(result).c_str());

  // The plane: normal within 1° of the truth, height of its origin within 2 mm.
  ASSERT_TRUE(result.segmentation.plane.found);
  const Eigen::Vector3f up = (frame.cam_from_world.col(2)).cast<float>();
  EXPECT_GT(result.segmentation.plane.normal.dot(up), std::cos(1.0 * M_PI / 180.0));
  EXPECT_NEAR(result.segmentation.plane.Height(frame.origin_in_cam.cast<float>()), 0.0, 0.002);

  int found = 0;
  for (const Truth& t : truths) {
    const RecognisedObject* match = nullptr;
    const Eigen::Vector3d centre = t.pose * MakePoseTruthModel(t.mesh).center;
    double nearest_object = 0.05;  // a match lies within 5 cm
    for (const RecognisedObject& o : result.objects) {
      const double d = (o.best().cam_from_model * MakePoseTruthModel(t.mesh).center - centre).norm();
      if (d < nearest_object) {
        nearest_object = d;
        match = &o;
      }
    }
    if (!match) {
      ADD_FAILURE() << ToString(t.cls) << " not found";
      continue;
    }
    EXPECT_EQ(match->best().class_name, ToString(t.cls));
    if (match->best().class_name != ToString(t.cls)) continue;
    ++found;
    const PoseComparison error = ComparePoses(match->best().cam_from_model, t.pose, t.mesh);
    std::printf("%s: rotation %.2f°, centre %.2f mm, ADD-S %.2f mm, %zu points\n",
                ToString(t.cls).c_str(), error.rotation_error_deg, 1e3 * error.center_error_m,
                1e3 * error.adds_m, match->indices.size());
    EXPECT_LT(error.rotation_error_deg, 5.0) << ToString(t.cls);
    EXPECT_LT(error.center_error_m, 0.005) << ToString(t.cls);
    EXPECT_LT(error.adds_over_diameter(), 0.1) << ToString(t.cls);
    EXPECT_TRUE(match->verified);
    EXPECT_GT(match->visible_fraction, 0.3);
  }
  EXPECT_EQ(found, 3);
  // Only the three known objects are reported: the torus is not named as a model.
  EXPECT_EQ(result.objects.size(), 3u);
  ASSERT_GE(result.unknown.size(), 1u);
  const Eigen::Vector3f torus_centre = torus_pose.translation.cast<float>();
  double nearest = std::numeric_limits<double>::max();
  for (const UnknownObject& u : result.unknown) {
    nearest = std::min<double>(nearest, (u.centroid - torus_centre).norm());
  }
  EXPECT_LT(nearest, 0.04);

  const nlohmann::json j = nlohmann::json::parse(SceneRecognitionResultToJson(result));
  ASSERT_EQ(j["objects"].size(), 3u);
  EXPECT_EQ(j["class"], j["objects"][0]["class"]);  // top level = the best object
  for (const auto& o : j["objects"]) {
    EXPECT_TRUE(o.contains("points") && o.contains("visible_fraction") && o.contains("verified"));
    EXPECT_TRUE(o.contains("pose") && o.contains("candidates"));
  }
}

TEST_F(SceneRecognitionTest, UnseenInstancesPassAtClassLevelAndClutterDoesNot) {
  // The scene verification's class-level acceptance on ground truth: instances the
  // database does not hold — a wider mug and bowl — and a torus, scanned on the table.
  // Hypotheses: the database's mug_0 and bowl_0 at the unseen instances' true poses, and
  // mug_0 put down on the torus. With the recogniser's class
  // evidence (probability 0.9) both unseen instances pass; mug_0 on the torus does not,
  // even with class probability 1 (clutter often gets a confident class: the geometry
  // keeps it out). Without class evidence, whatever passes must pass at instance level.
  const TableFrame frame;
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  const Rigid3d mug_pose = frame.Pose(0.0, -0.05, 0.9);
  const Rigid3d bowl_pose = frame.Pose(0.13, 0.03, 0.0);
  const Rigid3d on_torus = frame.Pose(0.0, 0.09, 0.0);
  // Other instances of the classes: the database's own, widened by 10% (a wider mug and
  // bowl of the same heights; their surfaces 3–7 mm off the database models').
  auto widened = [](TriangleMesh mesh) {
    for (Eigen::Vector3f& v : mesh.vertices) v.head<2>() *= 1.1f;
    return mesh;
  };
  scene.objects.push_back({widened(MakeObject(ObjectClass::kMug, 0)), mug_pose, 0.8, {}});
  scene.objects.push_back({widened(MakeObject(ObjectClass::kBowl, 0)), bowl_pose, 0.8, {}});
  Rigid3d torus_pose = on_torus;
  torus_pose.translation += frame.cam_from_world * Eigen::Vector3d(0, 0, 0.02);
  scene.objects.push_back({MakeTorus(0.045, 0.02), torus_pose, 0.8, {}});
  const PointCloud cloud = ScanScene(scene);

  const TableSegmentationOptions segmentation;
  const TableSegmentation seg = SegmentTable(cloud, segmentation);
  ASSERT_TRUE(seg.plane.found);
  ASSERT_EQ(seg.clusters.size(), 3u);
  PointCloud above;
  for (const ObjectCluster& c : seg.clusters) {
    above.points.insert(above.points.end(), c.cloud.points.begin(), c.cloud.points.end());
  }
  auto model_index = [](const std::string& name) {
    for (int m = 0; m < db_->num_models(); ++m) {
      if (db_->model(m).name == name) return m;
    }
    return -1;
  };
  const SceneRecogniser recogniser(*db_);
  const int mug = model_index("mug_0"), bowl = model_index("bowl_0");
  ASSERT_GE(mug, 0);
  ASSERT_GE(bowl, 0);
  const PointCloud& mug_surface = recogniser.ModelSurface(mug, 0.003);
  const PointCloud& bowl_surface = recogniser.ModelSurface(bowl, 0.003);
  const float cut = static_cast<float>(segmentation.min_height + segmentation.plane_distance);
  const TablePlane plane = seg.plane;
  const auto ignore = [&plane, cut](const Eigen::Vector3f& p) { return plane.Height(p) < cut; };
  const SceneVerificationOptions options;
  for (const double class_probability : {0.9, 0.0}) {
    const std::vector<SceneHypothesis> hypotheses = {
        {&mug_surface, mug_pose, 0.0, class_probability},
        {&bowl_surface, bowl_pose, 0.0, class_probability},
        {&mug_surface, on_torus, 0.0, 1.0}};
    const std::vector<HypothesisEvidence> evidence =
        VerifyHypotheses(above, cloud, hypotheses, options, ignore);
    const char* names[] = {"mug_0 on the wider mug", "bowl_0 on the wider bowl",
                           "mug_0 on the torus"};
    for (size_t h = 0; h < evidence.size(); ++h) {
      const HypothesisEvidence& e = evidence[h];
      std::printf("class p %.1f, %s: fit %.2f, local %.2f, violations %.2f, %s%s\n",
                  class_probability, names[h], e.model_fit, e.local_explained,
                  e.violation_fraction, e.accepted ? "accepted" : "rejected",
                  e.class_level ? " (class level)" : "");
    }
    EXPECT_FALSE(evidence[2].passes) << "the torus named as a mug";
    EXPECT_FALSE(evidence[2].accepted);
    if (class_probability > 0) {
      EXPECT_TRUE(evidence[0].accepted && evidence[0].class_level);
      EXPECT_TRUE(evidence[1].accepted && evidence[1].class_level);
    } else {
      // They fit no database model exactly: rejected without class evidence.
      for (const HypothesisEvidence& e : evidence) EXPECT_FALSE(e.class_level || e.accepted);
    }
  }
}

TEST_F(SceneRecognitionTest, EmptyTableAndNoPlaneAreEmptyResults) {
  const TableFrame frame;
  Scene table;
  table.objects.push_back(TableTop(frame));
  const PointCloud empty_table = ScanScene(table);
  const SceneRecogniser recogniser(*db_);
  const SceneRecognitionResult on_table = recogniser.Recognise(empty_table);
  EXPECT_TRUE(on_table.segmentation.plane.found);
  EXPECT_TRUE(on_table.objects.empty());
  EXPECT_TRUE(on_table.unknown.empty());
  EXPECT_EQ(nlohmann::json::parse(SceneRecognitionResultToJson(on_table))["objects"].size(), 0u);

  // No plane: points spread through a box (no plane holds 15% of them).
  PointCloud scattered;
  uint64_t state = 7;
  auto uniform = [&state] {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<float>((state >> 11) * 0x1.0p-53);
  };
  for (int i = 0; i < 5000; ++i) {
    scattered.points.emplace_back(uniform() * 0.3f - 0.15f, uniform() * 0.3f - 0.15f,
                                  0.5f + uniform() * 0.3f);
  }
  const SceneRecognitionResult no_plane = recogniser.Recognise(scattered);
  EXPECT_FALSE(no_plane.segmentation.plane.found);
  EXPECT_TRUE(no_plane.objects.empty());
  EXPECT_NE(no_plane.segmentation.message.find("no plane"), std::string::npos);
  const nlohmann::json j = nlohmann::json::parse(SceneRecognitionResultToJson(no_plane));
  EXPECT_EQ(j["objects"].size(), 0u);
  EXPECT_FALSE(j["recognised"].get<bool>());
}

TEST(TableSegmentation, RefusesNanAndSinglePointClouds) {
  PointCloud nan_cloud;
  for (int i = 0; i < 100; ++i) nan_cloud.points.emplace_back(0.01f * i, 0.0f, 0.6f);
  nan_cloud.points[17].x() = std::numeric_limits<float>::quiet_NaN();
  testing::ExpectThrowsWithMessage<Error>([&] { SegmentTable(nan_cloud); }, {"1 non-finite point"});
  PointCloud single;
  single.points.emplace_back(0.0f, 0.0f, 0.6f);
  testing::ExpectThrowsWithMessage<Error>([&] { SegmentTable(single); }, {"has 1 point"});
}

TEST(TableSegmentation, SplitsSeparateBlocksOnAPlane) {
  // A 40 × 40 cm plane at z = 0.6 m (2 mm grid) with two 4 cm cubes' tops 3 cm above it,
  // 10 cm apart: two clusters, each with the cube's points.
  PointCloud cloud;
  for (int i = 0; i < 200; ++i) {
    for (int k = 0; k < 200; ++k) cloud.points.emplace_back(-0.2f + 0.002f * i, -0.2f + 0.002f * k, 0.6f);
  }
  const size_t plane_points = cloud.size();
  for (const float cx : {-0.05f, 0.05f}) {
    for (int i = 0; i < 20; ++i) {
      for (int k = 0; k < 20; ++k) cloud.points.emplace_back(cx + 0.002f * i, 0.002f * k, 0.57f);
    }
  }
  const TableSegmentation seg = SegmentTable(cloud);
  ASSERT_TRUE(seg.plane.found);
  EXPECT_NEAR(std::abs(seg.plane.normal.z()), 1.0, 1e-4);
  EXPECT_GT(seg.plane.normal.dot(-Eigen::Vector3f(0, 0, 0.6f)), 0.0f);  // faces the camera
  EXPECT_NEAR(seg.plane.Height(Eigen::Vector3f(0, 0, 0.57f)), 0.03, 1e-4);
  ASSERT_EQ(seg.clusters.size(), 2u);
  for (const ObjectCluster& c : seg.clusters) {
    EXPECT_EQ(c.indices.size(), 400u);
    for (const int i : c.indices) EXPECT_GE(static_cast<size_t>(i), plane_points);
  }
}

TEST(TableSegmentation, GridClustersEqualPclEuclideanClusters) {
  // A plane at z = 0.6 m and six blobs of random points above it: four far apart (1 cm
  // gaps, > 7.5 mm tolerance: separate objects), two touching (a 2 mm gap: one cluster).
  // The hash-grid clustering must give exactly PCL's clusters, and both the true groups.
  PointCloud cloud;
  for (int i = 0; i < 150; ++i) {
    for (int k = 0; k < 150; ++k) cloud.points.emplace_back(-0.15f + 0.002f * i, -0.15f + 0.002f * k, 0.6f);
  }
  uint64_t state = 11;
  auto uniform = [&state] {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<float>((state >> 11) * 0x1.0p-53);
  };
  struct Blob {
    float x, y, size;
    int group;
  };
  const std::vector<Blob> blobs = {{-0.12f, -0.12f, 0.04f, 0}, {-0.07f, -0.12f, 0.03f, 1},
                                   {0.05f, 0.05f, 0.05f, 2},   {0.102f, 0.05f, 0.03f, 2},
                                   {-0.1f, 0.06f, 0.02f, 3},   {0.06f, -0.1f, 0.035f, 4}};
  std::vector<int> group_of(cloud.size(), -1);
  for (const Blob& b : blobs) {
    for (int n = 0; n < 1500; ++n) {
      cloud.points.emplace_back(b.x + b.size * uniform(), b.y + b.size * uniform(),
                                0.59f - b.size * uniform());
      group_of.push_back(b.group);
    }
  }
  TableSegmentationOptions grid_options;
  TableSegmentationOptions pcl_options;
  pcl_options.clustering = TableSegmentationOptions::Clustering::kPclKdTree;
  const TableSegmentation grid = SegmentTable(cloud, grid_options);
  const TableSegmentation pcl = SegmentTable(cloud, pcl_options);
  ASSERT_EQ(grid.clusters.size(), 5u);
  ASSERT_EQ(pcl.clusters.size(), grid.clusters.size());
  for (size_t c = 0; c < grid.clusters.size(); ++c) {
    EXPECT_EQ(grid.clusters[c].indices, pcl.clusters[c].indices) << "cluster " << c;
    // One true group per cluster, and all of the points above the plane (blobs start 1 cm
    // above it) of that group.
    const int group = group_of[grid.clusters[c].indices.front()];
    ASSERT_GE(group, 0);
    for (const int i : grid.clusters[c].indices) EXPECT_EQ(group_of[i], group);
    const size_t expected = group == 2 ? 3000u : 1500u;
    EXPECT_EQ(grid.clusters[c].indices.size(), expected) << "group " << group;
  }
}

}  // namespace
}  // namespace sope
