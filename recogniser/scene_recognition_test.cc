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
#include <functional>
#include <limits>
#include <memory>
#include <thread>
#include <tuple>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "calibration/scan.h"
#include "core/error.h"
#include "core/mesh.h"
#include "recogniser/convex_segmentation.h"
#include "recogniser/pose_metrics.h"
#include "recogniser/tools/database_builder.h"
#include "simulator/primitives.h"
#include "simulator/procedural_objects.h"
#include "simulator/simulate_scan.h"
#include "simulator/virtual_rig.h"
#include "tests/procedural_database.h"
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

// `mesh` turned by `world_from_model` (world z up) at table position (x, y), its lowest
// point on the table: cam_from_model.
Rigid3d LaidOnTable(const TableFrame& frame, const TriangleMesh& mesh,
                    const Eigen::Matrix3d& world_from_model, double x, double y) {
  double lowest = std::numeric_limits<double>::infinity();
  for (const Eigen::Vector3f& v : mesh.vertices) {
    lowest = std::min(lowest, (world_from_model * v.cast<double>()).z());
  }
  Rigid3d pose = frame.Pose(x, y, 0.0);
  pose.rotation = frame.cam_from_world * world_from_model;
  pose.translation += frame.cam_from_world * Eigen::Vector3d(0, 0, -lowest);
  return pose;
}

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

// A scene of the table top alone (objects are added to it).
Scene EmptyTable(const TableFrame& frame) {
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  return scene;
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

// The same hypotheses, objects (models, scores, points, poses) and unknown objects.
void ExpectSameScene(const SceneRecognitionResult& result,
                     const SceneRecognitionResult& expected) {
  EXPECT_EQ(result.hypotheses, expected.hypotheses);
  ASSERT_EQ(result.objects.size(), expected.objects.size()) << SceneBriefReport(result);
  for (size_t i = 0; i < result.objects.size(); ++i) {
    const Suggestion& a = result.objects[i].best();
    const Suggestion& b = expected.objects[i].best();
    EXPECT_EQ(a.model_name, b.model_name);
    EXPECT_EQ(a.score, b.score);
    EXPECT_EQ(result.objects[i].indices, expected.objects[i].indices);
    EXPECT_LT((a.cam_from_model.translation - b.cam_from_model.translation).norm(), 1e-12);
    EXPECT_LT((a.cam_from_model.rotation - b.cam_from_model.rotation).norm(), 1e-12);
  }
  ASSERT_EQ(result.unknown.size(), expected.unknown.size());
  for (size_t i = 0; i < result.unknown.size(); ++i) {
    EXPECT_EQ(result.unknown[i].indices, expected.unknown[i].indices);
  }
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

// Categories (DatabaseData::categories): the database holds mugs 0 and 3 and bowl 0; on
// the table stands mug 0 widened by 10% — another instance of the class, which fits no
// database mug at instance level (UnseenInstancesPassAtClassLevelAndClutterDoesNot). When
// the classes are categories (a models directory `sope objects` wrote: CATEGORY files) it
// must be found as a mug, accepted at class level. When the same models are a set of
// instances (a folder of a dataset's unlike objects: no CATEGORY file) no cluster may be
// taken for an unseen instance of their class: nothing is reported at class level (what
// is reported passed the instance-level tests: mug_0 on a part of the wider mug).
TEST(SceneRecognitionCategories, AnUnseenInstanceIsTakenForTheClassOnlyInACategory) {
  const TableFrame frame;
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  const Rigid3d mug_pose = frame.Pose(0.0, -0.02, 0.9);
  TriangleMesh mug = MakeObject(ObjectClass::kMug, 0);
  for (Eigen::Vector3f& v : mug.vertices) v.head<2>() *= 1.1f;
  scene.objects.push_back({mug, mug_pose, 0.8, {}});
  const PointCloud cloud = ScanScene(scene);
  const Eigen::Vector3d centre = mug_pose * MakePoseTruthModel(mug).center;
  for (const bool categories : {true, false}) {
    const testing::ScratchDir scratch;
    const std::unique_ptr<Database> db = testing::ProceduralDatabase(
        scratch, {{ObjectClass::kMug, {0, 3}}, {ObjectClass::kBowl, {0}}}, categories);
    for (int c = 0; c < static_cast<int>(db->classes().size()); ++c) {
      EXPECT_EQ(db->IsCategory(c), categories) << db->classes()[c];
    }
    const SceneRecognitionResult result = SceneRecogniser(*db).Recognise(cloud);
    std::printf("classes %s:\n%s\n", categories ? "categories" : "sets of instances",
                SceneBriefReport(result).c_str());
    const RecognisedObject* found = nullptr;
    for (const RecognisedObject& o : result.objects) {
      const Eigen::Vector3d c = o.best().cam_from_model * MakePoseTruthModel(mug).center;
      if ((c - centre).norm() < 0.05) found = &o;
      if (!categories) {
        EXPECT_FALSE(o.class_level) << o.best().model_name << " at class level";
      }
    }
    if (categories) {
      ASSERT_NE(found, nullptr) << "the wider mug was not found";
      EXPECT_EQ(found->best().class_name, "mug");
      EXPECT_TRUE(found->class_level);
    }
  }
}

// The last recognised object whose pose puts `mesh`'s centre within `max_distance` of
// `centre` (null: none).
const RecognisedObject* LastNear(const SceneRecognitionResult& result, const TriangleMesh& mesh,
                                 const Eigen::Vector3d& centre, double max_distance) {
  const Eigen::Vector3d mesh_centre = MakePoseTruthModel(mesh).center;
  const RecognisedObject* found = nullptr;
  for (const RecognisedObject& o : result.objects) {
    if ((o.best().cam_from_model * mesh_centre - centre).norm() < max_distance) found = &o;
  }
  return found;
}

// The last recognised object whose best suggestion is of class `name` (null: none).
const RecognisedObject* LastOfClass(const SceneRecognitionResult& result,
                                    const std::string& name) {
  const RecognisedObject* found = nullptr;
  for (const RecognisedObject& o : result.objects) {
    if (o.best().class_name == name) found = &o;
  }
  return found;
}

// Sibling hypotheses (SceneRecognitionOptions::sibling_hypotheses): the database holds
// procedural bowls 0, 1, 5 and 12 and mug 0; on the table stand two unseen bowls, 1192
// (12.4 cm wide, 5.3 cm high: bowl 1's size) and 1019 (16.7 × 7.6 cm: nearest bowl 12),
// and the mug. Each bowl must be found as a bowl with the database bowl nearest it in
// size, its centre within 5 mm along the table; the mug as the mug. (Without siblings the
// recogniser, posing its first-ranked model only, gives bowl 1192 as bowl_5, 8.7 mm off,
// which passes the instance-level tests; the comparison is printed.)
TEST(SceneRecognitionSiblings, UnseenBowlsArePosedWithTheDatabaseBowlNearestInSize) {
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kBowl, {0, 1, 5, 12}}, {ObjectClass::kMug, {0}}});

  const TableFrame frame;
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  struct Truth {
    TriangleMesh mesh;
    Rigid3d pose;
    std::string nearest;
  };
  const std::vector<Truth> bowls = {
      {MakeObject(ObjectClass::kBowl, 1192), frame.Pose(0.10, 0.06, 0.3), "bowl_1"},
      {MakeObject(ObjectClass::kBowl, 1019), frame.Pose(-0.05, -0.05, 1.1), "bowl_12"}};
  for (const Truth& t : bowls) scene.objects.push_back({t.mesh, t.pose, 0.8, {}});
  scene.objects.push_back(
      {MakeObject(ObjectClass::kMug, 0), frame.Pose(-0.17, 0.07, 0.8), 0.8, {}});
  const PointCloud cloud = ScanScene(scene);
  const SceneRecogniser recogniser(*db);
  // The recogniser alone poses the first-ranked model only (no other models screened,
  // no widening): its view-based ranking, blind to size, picks a bowl of the wrong size
  // for at least one of the two, which the siblings must correct.
  SceneRecognitionOptions options;
  options.recognition.screening.models = 1;
  options.recognition.refinement.candidates = 1;
  options.recognition.assembly.class_screen_classes = 0;
  options.recognition.widening.below_score = 0.0;
  options.max_scale = 0.0;  // siblings alone (a scaled bowl_5 fits bowl 1192 too)
  for (const int siblings : {0, options.sibling_hypotheses}) {
    options.sibling_hypotheses = siblings;
    const SceneRecognitionResult result = recogniser.Recognise(cloud, options);
    std::printf("sibling hypotheses %d:\n%s\n", siblings, SceneBriefReport(result).c_str());
    if (siblings == 0) continue;  // shown for comparison only
    EXPECT_NE(LastOfClass(result, "mug"), nullptr);
    for (const Truth& t : bowls) {
      const Eigen::Vector3d centre = t.pose * MakePoseTruthModel(t.mesh).center;
      const RecognisedObject* found = LastNear(result, t.mesh, centre, 0.05);
      ASSERT_NE(found, nullptr) << "the unseen bowl nearest " << t.nearest << " was not found";
      const PoseComparison error = ComparePoses(found->best().cam_from_model, t.pose, t.mesh);
      // The database bowl is another instance, of another height (bowl 12 is 1.1 cm lower
      // than bowl 1019): how high its centre sits is the instance's, not the pose's. The
      // centre is checked along the table.
      const Eigen::Vector3d up = frame.cam_from_world.col(2);
      const Eigen::Vector3d offset =
          found->best().cam_from_model * MakePoseTruthModel(t.mesh).center - centre;
      const double along_table = (offset - offset.dot(up) * up).norm();
      std::printf("%s: found as %s, rotation %.2f°, centre %.2f mm (%.2f mm along the table)\n",
                  t.nearest.c_str(), found->best().model_name.c_str(), error.rotation_error_deg,
                  1e3 * error.center_error_m, 1e3 * along_table);
      EXPECT_EQ(found->best().model_name, t.nearest);
      EXPECT_LT(along_table, 0.005);
    }
  }
}

// Two database mugs and two database glasses (procedural instances).
std::unique_ptr<Database> MugsAndGlasses(const testing::ScratchDir& scratch) {
  return testing::ProceduralDatabase(
      scratch, {{ObjectClass::kMug, {2, 8}}, {ObjectClass::kGlass, {12, 15}}});
}

// Class evidence in the selection (SceneRecognitionOptions::class_weight): the database
// holds mugs 2 and 8 and glasses 12 and 15; on the table lies an unseen mug (1186) on its
// side, its handle turned up and to one side. The recogniser ranks the mug class first
// (0.83), but glass 15, a little wider, explains a few more of the body's points than the
// mug models do: by geometry alone (class_weight 0, printed for comparison) the mug is
// reported as a glass (and names the mug as its doubt). With the class evidence it must be a
// mug.
TEST(SceneRecognitionClassEvidence, AMugOnItsSideIsNotTakenForAWiderGlass) {
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = MugsAndGlasses(scratch);

  const TableFrame frame;
  Scene scene = EmptyTable(frame);
  // The mug's axis (model z) laid along the table, its handle (model +x) turned 60° up
  // from the table, the whole turned 0.5 rad about the vertical; its lowest point on the
  // table.
  const TriangleMesh mug = MakeObject(ObjectClass::kMug, 1186);
  const Eigen::Matrix3d lying = Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()).matrix() *
                                Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitX()).matrix() *
                                Eigen::AngleAxisd(M_PI / 3, Eigen::Vector3d::UnitZ()).matrix();
  const Rigid3d mug_pose = LaidOnTable(frame, mug, lying, 0.06, 0.02);
  scene.objects.push_back({mug, mug_pose, 0.8, {}});
  const PointCloud cloud = ScanScene(scene);
  const SceneRecogniser recogniser(*db);
  const auto found_near = [](const SceneRecognitionResult& result, const Eigen::Vector3d& centre,
                             const TriangleMesh& mesh) -> const RecognisedObject* {
    for (const RecognisedObject& o : result.objects) {
      const Eigen::Vector3d c = o.best().cam_from_model * MakePoseTruthModel(mesh).center;
      if ((c - centre).norm() < 0.04) return &o;
    }
    return nullptr;
  };
  const Eigen::Vector3d mug_centre = mug_pose * MakePoseTruthModel(mug).center;
  SceneRecognitionOptions options;
  for (const double weight : {0.0, options.class_weight}) {
    options.class_weight = weight;
    const SceneRecognitionResult result = recogniser.Recognise(cloud, options);
    std::printf("class weight %.2f:\n%s\n", weight, SceneBriefReport(result).c_str());
    // The doubt an object reports is about its own class: another class, named when it
    // comes near (the glass accepted by geometry alone doubts the mug ranked far above it).
    for (const RecognisedObject& o : result.objects) {
      EXPECT_NE(o.recognition.ambiguous_with, o.best().class_name);
      if (o.best().class_name == "glass") {
        EXPECT_EQ(o.recognition.ambiguous_with, "mug");
      }
    }
    if (weight == 0.0) continue;  // shown for comparison only
    const RecognisedObject* found_mug = found_near(result, mug_centre, mug);
    ASSERT_NE(found_mug, nullptr) << "the mug was not found";
    EXPECT_EQ(found_mug->best().class_name, "mug");
    // The handle leaves the wall along the model's +x axis in every procedural mug. Printed:
    // the database mug's handle, another shape than the unseen one's, explains few points.
    const Eigen::Vector3d true_handle = mug_pose.rotation.col(0);
    const Eigen::Vector3d found_handle = found_mug->best().cam_from_model.rotation.col(0);
    std::printf("mug found as %s, handle %.1f° off\n", found_mug->best().model_name.c_str(),
                std::acos(std::clamp(true_handle.dot(found_handle), -1.0, 1.0)) * 180 / M_PI);
  }
}

// Other-class looks from the poses the cut to top_k left out
// (RecognitionResult::other_class_poses): an unseen mug lying on its side, its handle up
// in full view (procedural tables, seed 901, scene 7). The recogniser's four suggestions
// are all glasses (a glass fits the body, verification 0.88); its class screening posed a
// mug too (0.59), but below the cut. The glass leaves the handle unexplained (16% of the
// cluster), and the looks of the mug class — posed from that mug, turned about its axis —
// must find it a mug. Before these poses were kept, the mug class had no pose to look
// from, and the mug was reported as a glass.
TEST(SceneRecognitionClassEvidence, AMugWithItsHandleUpIsFoundFromAPoseBelowTheCut) {
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kMug, {2, 8, 13}}, {ObjectClass::kGlass, {1, 5, 8, 12, 15}}});
  const TableFrame frame;
  Scene scene = EmptyTable(frame);
  const TriangleMesh mug = MakeObject(ObjectClass::kMug, 1258);
  Eigen::Matrix3d lying;  // world from model, as in that scene
  lying << -0.401894, -0.858735, -0.317891,  //
      0.146658, 0.282315, -0.948045,         //
      0.903865, -0.427635, 0.012480;
  lying = Eigen::Quaterniond(lying).normalized().toRotationMatrix();
  const Rigid3d mug_pose = LaidOnTable(frame, mug, lying, 0.0, 0.0);
  scene.objects.push_back({mug, mug_pose, 0.8, {}});
  const PointCloud cloud = ScanScene(scene);
  const SceneRecognitionResult result = SceneRecogniser(*db).Recognise(cloud);
  std::printf("%s\n", SceneBriefReport(result).c_str());
  const Eigen::Vector3d centre = mug_pose * MakePoseTruthModel(mug).center;
  const RecognisedObject* found = LastNear(result, mug, centre, 0.04);
  ASSERT_NE(found, nullptr) << "the mug was not found within 4 cm";
  EXPECT_EQ(found->best().class_name, "mug");
  const Eigen::Vector3d true_handle = mug_pose.rotation.col(0);
  const Eigen::Vector3d found_handle = found->best().cam_from_model.rotation.col(0);
  const double handle_deg =
      std::acos(std::clamp(true_handle.dot(found_handle), -1.0, 1.0)) * 180 / M_PI;
  std::printf("found as %s, handle %.1f° off\n", found->best().model_name.c_str(), handle_deg);
  EXPECT_LT(handle_deg, 30.0) << "a mug, but its handle is not where the scan shows it";
}

// A cluster the class its recognition ranks first explains (its accepted hypothesis leaves
// less than other_class_remainder unexplained) gets no other class's turns about that
// class's axis of near symmetry (SceneRecognitionOptions::roll_explained_clusters): a glass
// standing in full view, which the database's mugs also resemble, is a glass either way,
// and the mug beside it a mug; only the hypotheses that could at most tie are left out.
TEST(SceneRecognitionRolls, AClusterTheFirstClassExplainsGetsNoOtherClassTurns) {
  // Database instances, standing side by side.
  const TriangleMesh glass = MakeObject(ObjectClass::kGlass, 12);
  const TriangleMesh mug = MakeObject(ObjectClass::kMug, 2);
  const TableFrame frame;
  const Rigid3d glass_pose = frame.Pose(-0.06, 0.0, 0.3);
  const Rigid3d mug_pose = frame.Pose(0.08, 0.02, 2.2);
  Scene scene = EmptyTable(frame);
  scene.objects.push_back({glass, glass_pose, 0.8, {}});
  scene.objects.push_back({mug, mug_pose, 0.8, {}});
  const PointCloud cloud = ScanScene(scene);
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = MugsAndGlasses(scratch);
  const SceneRecogniser recogniser(*db);
  SceneRecognitionOptions everywhere;
  everywhere.roll_explained_clusters = true;
  const SceneRecognitionResult expected = recogniser.Recognise(cloud, everywhere);
  const SceneRecognitionResult result = recogniser.Recognise(cloud, SceneRecognitionOptions());
  std::printf("turns on every cluster (%d hypotheses):\n%s\nnot on explained ones (%d):\n%s\n",
              expected.hypotheses, SceneBriefReport(expected).c_str(), result.hypotheses,
              SceneBriefReport(result).c_str());
  // The turns of the mugs about their axis on the glass's cluster are the difference.
  EXPECT_LT(result.hypotheses, expected.hypotheses);
  ASSERT_EQ(result.objects.size(), 2u);
  ASSERT_EQ(expected.objects.size(), result.objects.size());
  for (size_t i = 0; i < result.objects.size(); ++i) {
    const Suggestion& a = result.objects[i].best();
    const Suggestion& b = expected.objects[i].best();
    EXPECT_EQ(a.model_name, b.model_name);
    EXPECT_NEAR(a.score, b.score, 1e-9);
    EXPECT_LT((a.cam_from_model.translation - b.cam_from_model.translation).norm(), 1e-9);
    EXPECT_LT((a.cam_from_model.rotation - b.cam_from_model.rotation).norm(), 1e-9);
  }
  for (const auto& [mesh, pose, name] :
       {std::make_tuple(&glass, &glass_pose, "glass"), std::make_tuple(&mug, &mug_pose, "mug")}) {
    const Eigen::Vector3d centre = *pose * MakePoseTruthModel(*mesh).center;
    const RecognisedObject* found = LastNear(result, *mesh, centre, 0.05);
    ASSERT_NE(found, nullptr) << name << " not found within 5 cm";
    EXPECT_EQ(found->best().class_name, name);
    const PoseComparison error = ComparePoses(found->best().cam_from_model, *pose, *mesh);
    std::printf("%s: ADD-S %.2f mm\n", name, 1e3 * error.adds_m);
    EXPECT_LT(error.adds_over_diameter(), 0.1) << name;
  }
}

// A wine glass lying on its side (an unseen instance): its stem, thin and seen from above,
// leaves its bowl and its foot apart in the segmentation, and the line between their
// nearest points passes over the stem, which the camera sees behind it — points of the
// two parts themselves, which tell nothing about a gap between two objects. The two parts
// must be joined and the whole found as a wine glass (procedural tables, seed 701, scene
// 6: a wine glass found as a mug from its bowl alone, the foot left unknown).
TEST(SceneRecognitionJoins, AWineGlassLyingOnItsSideIsJoinedAcrossItsStem) {
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kWineGlass, {2, 3, 4, 5}},
                {ObjectClass::kMug, {2, 3, 4, 5}},
                {ObjectClass::kCan, {2, 3, 4, 5}}});
  const TableFrame frame;
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  // The glass at rest on its bowl's rim and its foot's edge, as in that scene (world from
  // model, world z up; its lowest point on the table).
  const TriangleMesh glass = MakeObject(ObjectClass::kWineGlass, 1817);
  Eigen::Matrix3d lying;
  lying << 0.888850, -0.336699, 0.310772,  //
      0.311131, -0.054392, -0.948809,       //
      0.336367, 0.940040, 0.056411;
  lying = Eigen::Quaterniond(lying).normalized().toRotationMatrix();
  const Rigid3d pose = LaidOnTable(frame, glass, lying, 0.0, 0.02);
  scene.objects.push_back({glass, pose, 0.8, {}});
  const PointCloud cloud = ScanScene(scene);
  const SceneRecogniser recogniser(*db);
  const SceneRecognitionResult result = recogniser.Recognise(cloud);
  std::printf("%s\n", SceneBriefReport(result).c_str());
  EXPECT_GE(result.segmentation.clusters.size(), 2u)
      << "the scan no longer splits the glass: the test does not test the join";
  // The second looks side by side on two threads (the joins' and the parts' looks, every
  // cluster's size looks): the same answer.
  SceneRecognitionOptions two_threads;
  two_threads.recognition.threads = 2;
  ExpectSameScene(SceneRecogniser(*db).Recognise(cloud, two_threads), result);
#if defined(__SANITIZE_ADDRESS__)
  // This scene sits where the outcome turns on which points the first verification
  // accepts: the sanitizer build's other floating-point code (its database views
  // included) accepts the bowl as a mug at class level before the join, and the line
  // between bowl and foot then sees the table. The path ran (memory checks); the outcome
  // is asserted in the optimised builds, which CI runs.
  std::printf("sanitizer build: outcome not asserted\n");
  return;
#endif
  const Eigen::Vector3d centre = pose * MakePoseTruthModel(glass).center;
  ASSERT_EQ(result.objects.size(), 1u);
  const RecognisedObject& found = result.objects.front();
  EXPECT_EQ(found.best().class_name, "wine_glass");
  const Eigen::Vector3d found_centre =
      found.best().cam_from_model * MakePoseTruthModel(MakeObject(ObjectClass::kWineGlass, 2)).center;
  std::printf("found as %s, centre %.1f mm off (the database instance's centre)\n",
              found.best().model_name.c_str(), 1e3 * (found_centre - centre).norm());
  // Another instance's centre: within 2 cm (the bowl alone, found as a mug, was 13 cm off).
  EXPECT_LT((found_centre - centre).norm(), 0.02);
}

// Size looks of a cluster joined with an accepted object's points
// (SceneRecognitionOptions::object_join_size_looks): an unseen mug (procedural 1000) stands
// with its handle to the side, and the scan loses the handle's roots (cut out of the cloud
// here: every point 0.5–9 mm outside the body on the handle's side, as a shadow or a
// grazing view cuts them), so its body and its handle are two clusters. The database holds
// mugs 2, 8 and 13 and glasses 1, 5, 8, 12 and 15. The body alone is a glass; joined with
// the handle the points rank the mug class first, but no database mug fits them as it is.
// With the size looks of that class on the joined points (its siblings, the scaled model,
// stood upright) the mug must be named, its centre within 3 cm; without them it is not.
TEST(SceneRecognitionJoins, AMugWhoseHandleIsCutOffItsBodyIsFoundBySizeLooksOnTheJoin) {
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kMug, {2, 8, 13}}, {ObjectClass::kGlass, {1, 5, 8, 12, 15}}});
  const TableFrame frame;
  Scene scene = EmptyTable(frame);
  const TriangleMesh mug = MakeObject(ObjectClass::kMug, 1000);
  const Rigid3d pose = frame.Pose(0.0, 0.0, 0.0);  // the handle (model x) to the right
  scene.objects.push_back({mug, pose, 0.8, {}});
  const PointCloud scanned = ScanScene(scene);
  // The body's outer radius: the vertices on the side away from the handle.
  double radius = 0.0;
  for (const Eigen::Vector3f& v : mug.vertices) {
    if (v.x() < 0) radius = std::max(radius, std::hypot(double{v.x()}, double{v.y()}));
  }
  const Rigid3d model_from_cam = pose.Inverse();
  PointCloud cloud;
  size_t cut = 0;
  for (const Eigen::Vector3f& p : scanned.points) {
    const Eigen::Vector3d m = model_from_cam * p.cast<double>();
    const double r = std::hypot(m.x(), m.y());
    const bool root = m.x() > 0 && std::abs(m.y()) < 0.015 && r > radius + 0.0005 &&
                      r < radius + 0.009;
    if (root) {
      ++cut;
    } else {
      cloud.points.push_back(p);
    }
  }
  std::printf("body radius %.1f mm; %zu points of the handle's roots cut\n", 1e3 * radius, cut);
  const Eigen::Vector3d centre = pose * MakePoseTruthModel(mug).center;
  const SceneRecogniser recogniser(*db);
  SceneRecognitionOptions options;
  for (const bool size_looks : {false, true}) {
    options.object_join_size_looks = size_looks;
    const SceneRecognitionResult result = recogniser.Recognise(cloud, options);
    std::printf("object join size looks %s:\n%s\n", size_looks ? "on" : "off",
                SceneBriefReport(result).c_str());
    EXPECT_GE(result.segmentation.clusters.size(), 2u)
        << "the handle is not a cluster of its own: the test does not test the join";
    bool named = false;
    for (const RecognisedObject& o : result.objects) {
      const Eigen::Vector3d c = o.best().cam_from_model * db->model(o.best().model).center;
      named |= o.best().class_name == "mug" && (c - centre).norm() < 0.03;
    }
    EXPECT_EQ(named, size_looks);
  }
}

// Scaled hypotheses (SceneRecognitionOptions::max_scale): the database holds two boxes
// (procedural 3 and 10) and a mug; on the table stands a box of other proportions — box 3
// 1.4× as deep and 0.8× as high — and the mug. The box must be found as a box whose scaled dimensions
// are the new box's (within 10%), its centre within 5 mm; the mug as the mug. (Without
// scaling the database box explains a part of the new one only: printed for comparison.)
// A wall at the far edge of the table, shorter than the backdrop test's extent (1.2 × the
// largest model's diameter): standing upright at the edge of the table seen, it is a
// backdrop too (IsBackdrop's far-edge rule); the mug in front of it is the one object.
TEST_F(SceneRecognitionTest, AShortWallAtTheTablesFarEdgeIsABackdrop) {
  const TableFrame frame;
  Scene scene;
  SceneObject table;
  table.mesh = MakePlane(0.5, 0.3, 4);  // far edge 15 cm behind the centre
  table.cam_from_model = frame.Pose(0, 0, 0);
  table.cam_from_model.rotation =
      table.cam_from_model.rotation * Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).matrix();
  table.albedo = 0.6;
  scene.objects.push_back(table);
  double max_diameter = 0.0;
  for (int m = 0; m < db_->num_models(); ++m) {
    max_diameter = std::max(max_diameter, db_->model(m).diameter);
  }
  const double width = 0.8 * max_diameter;
  SceneObject wall;
  wall.mesh = MakePlane(width, 0.06, 4);
  wall.cam_from_model = frame.Pose(0.0, 0.15, 0.0);
  wall.cam_from_model.rotation = wall.cam_from_model.rotation *
                                 Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitX()).matrix();
  wall.cam_from_model.translation += frame.cam_from_world * Eigen::Vector3d(0, 0, 0.03);
  wall.albedo = 0.5;
  scene.objects.push_back(wall);
  scene.objects.push_back(
      {MakeObject(ObjectClass::kMug, 0), frame.Pose(0.0, -0.04, 0.3), 0.8, {}});
  const PointCloud cloud = ScanScene(scene);

  const SceneRecogniser recogniser(*db_);
  const SceneRecognitionResult result = recogniser.Recognise(cloud);
  std::printf("wall %.0f mm wide (largest model %.0f mm):\n%s\n", 1e3 * width,
              1e3 * max_diameter, SceneBriefReport(result).c_str());
  ASSERT_EQ(result.background.size(), 1u);
  const Eigen::Vector3d away = frame.cam_from_world.col(1);  // world y
  const double behind =
      (result.background[0].centroid.cast<double>() - frame.origin_in_cam).dot(away);
  EXPECT_NEAR(behind, 0.15, 0.01);
  ASSERT_EQ(result.objects.size(), 1u);
  EXPECT_EQ(result.objects[0].best().class_name, "mug");
}

TEST(SceneRecognitionScaled, ABoxOfOtherProportionsIsFoundWithItsScale) {
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kBox, {3, 10}}, {ObjectClass::kMug, {0}}});
  const TriangleMesh box = MakeObject(ObjectClass::kBox, 3);
  const TriangleMesh other_box = MakeObject(ObjectClass::kBox, 10);

  const Eigen::Vector3f true_scale(1.0f, 1.4f, 0.8f);
  TriangleMesh unseen = box;
  for (Eigen::Vector3f& v : unseen.vertices) v = v.cwiseProduct(true_scale);
  const TableFrame frame;
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  const Rigid3d box_pose = frame.Pose(0.07, 0.02, 0.5);
  scene.objects.push_back({unseen, box_pose, 0.8, {}});
  scene.objects.push_back(
      {MakeObject(ObjectClass::kMug, 0), frame.Pose(-0.12, -0.03, 0.8), 0.8, {}});
  const PointCloud cloud = ScanScene(scene);
  const SceneRecogniser recogniser(*db);
  SceneRecognitionOptions options;
  for (const double max_scale : {0.0, options.max_scale}) {
    options.max_scale = max_scale;
    const SceneRecognitionResult result = recogniser.Recognise(cloud, options);
    std::printf("max scale %.1f:\n%s\n", max_scale, SceneBriefReport(result).c_str());
    if (max_scale == 0.0) continue;  // shown for comparison only
    const Eigen::Vector3d centre = box_pose * MakePoseTruthModel(unseen).center;
    const RecognisedObject* found = LastOfClass(result, "box");
    EXPECT_NE(LastOfClass(result, "mug"), nullptr);
    ASSERT_NE(found, nullptr) << "the box was not found";
    std::printf("box: scale (%.2f, %.2f, %.2f)\n", found->scale.x(), found->scale.y(),
                found->scale.z());
    // A box has several poses that put a scaled box where the new one is (lying on
    // another face, the scale permuted alike): its dimensions, largest first, must be the
    // new box's within 10%.
    const TriangleMesh& found_mesh = found->best().model_name == "box_3" ? box : other_box;
    Eigen::Vector3f low = found_mesh.vertices.front(), high = low;
    for (const Eigen::Vector3f& v : found_mesh.vertices) {
      low = low.cwiseMin(v);
      high = high.cwiseMax(v);
    }
    Eigen::Vector3f found_size = found->scale.cast<float>().cwiseProduct(high - low);
    Eigen::Vector3f true_size = Eigen::Vector3f::Zero();
    for (int a = 0; a < 3; ++a) {
      float lo = unseen.vertices.front()[a], hi = lo;
      for (const Eigen::Vector3f& v : unseen.vertices) {
        lo = std::min(lo, v[a]);
        hi = std::max(hi, v[a]);
      }
      true_size[a] = hi - lo;
    }
    std::sort(found_size.data(), found_size.data() + 3, std::greater<float>());
    std::sort(true_size.data(), true_size.data() + 3, std::greater<float>());
    for (int a = 0; a < 3; ++a) {
      EXPECT_NEAR(found_size[a] / true_size[a], 1.0, 0.1) << "dimension " << a;
    }
    // The database box at the reported pose has its centre where the scaled box's is (the
    // scale is about the model's centre).
    const Eigen::Vector3d found_centre =
        found->best().cam_from_model * MakePoseTruthModel(found_mesh).center;
    std::printf("box: centre %.2f mm off\n", 1e3 * (found_centre - centre).norm());
    EXPECT_LT((found_centre - centre).norm(), 0.005);
    const nlohmann::json j = nlohmann::json::parse(SceneRecognitionResultToJson(result));
    bool has_scale = false;
    for (const auto& o : j["objects"]) has_scale |= o["class"] == "box" && o.contains("scale");
    EXPECT_TRUE(has_scale);
  }
}

// Unseen instances left where the recogniser posed them
// (SceneRecognitionOptions::keep_unsnapped_from): the database holds cans 0 and 3, glass 0
// and mug 0; on the table lie an unseen can 30% wider than can 3 (its axis along the
// table) and stands mug 0. The can fitted to its upper side does not reach the table by
// its lowest point; snapped down, it leaves the scan. Kept where it was posed, it must be
// found as a can, its axis within 10° of the truth's, the mug as the mug; reported with
// snap 0 (not moved). Without (keep_unsnapped_from 0) the result is printed for
// comparison.
TEST(SceneRecognitionUnsnapped, ALyingCanWiderThanTheDatabaseCansIsFound) {
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kCan, {0, 3}}, {ObjectClass::kGlass, {0}}, {ObjectClass::kMug, {0}}});
  TriangleMesh can = MakeObject(ObjectClass::kCan, 3);
  float radius = 0.0f;
  for (Eigen::Vector3f& v : can.vertices) {
    v.x() *= 1.3f;
    v.y() *= 1.3f;
    radius = std::max(radius, v.head<2>().norm());
  }
  const TableFrame frame;
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  // On its side: the model's axis (z) turned onto the table's x axis, lifted by its radius.
  Rigid3d lying;
  lying.rotation = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).matrix();
  lying.translation = Eigen::Vector3d(0, 0, radius);
  const Rigid3d can_pose = frame.Pose(0.02, 0.03, 0.4) * lying;
  scene.objects.push_back({can, can_pose, 0.8, {}});
  scene.objects.push_back(
      {MakeObject(ObjectClass::kMug, 0), frame.Pose(-0.13, -0.04, 0.8), 0.8, {}});
  const PointCloud cloud = ScanScene(scene);
  const SceneRecogniser recogniser(*db);
  SceneRecognitionOptions options;
  const double keep = options.keep_unsnapped_from;
  for (const double keep_from : {0.0, keep}) {
    options.keep_unsnapped_from = keep_from;
    const SceneRecognitionResult result = recogniser.Recognise(cloud, options);
    std::printf("keep unsnapped from %.3f:\n%s\n", keep_from, SceneBriefReport(result).c_str());
    if (keep_from == 0.0) continue;  // shown for comparison only
    const RecognisedObject* found = LastOfClass(result, "can");
    EXPECT_NE(LastOfClass(result, "mug"), nullptr);
    ASSERT_NE(found, nullptr) << "the can was not found";
    const Eigen::Vector3d true_axis = can_pose.rotation.col(2);
    const Eigen::Vector3d found_axis = found->best().cam_from_model.rotation.col(2);
    const double angle = std::acos(std::min(1.0, std::abs(true_axis.dot(found_axis))));
    std::printf("can: %s, axis %.1f° off, snap %.4f m\n", found->best().model_name.c_str(),
                angle * 180 / M_PI, found->snap_m);
    EXPECT_LT(angle, 10.0 * M_PI / 180);
    EXPECT_EQ(found->snap_m, 0.0);
  }
  options.keep_unsnapped_from = -1;
  testing::ExpectThrowsWithMessage<Error>([&] { recogniser.Recognise(cloud, options); },
                                          {"keep unsnapped from"});
}

// The plane prior's resting faces (SceneRecogniser::RestingNormals, from the hull of the
// model's surface sample): every procedural object stands on its flat base (the model's
// z = 0 plane, outward normal −z), so that face must be among them; a box also rests on
// its four sides and its top.
TEST_F(SceneRecognitionTest, ModelsRestOnTheirBase) {
  const SceneRecogniser recogniser(*db_);
  const SceneRecognitionOptions options;
  for (int m = 0; m < db_->num_models(); ++m) {
    const std::vector<Eigen::Vector3d>& normals = recogniser.RestingNormals(m, options.model_leaf);
    double best = -1.0;
    for (const Eigen::Vector3d& n : normals) {
      best = std::max(best, n.dot(-Eigen::Vector3d::UnitZ()));
    }
    EXPECT_GT(best, std::cos(2.0 * M_PI / 180.0))
        << db_->model(m).name << ": no resting face within 2° of its base (" << normals.size()
        << " faces)";
    if (db_->model(m).class_name == "box") {
      EXPECT_EQ(normals.size(), 6u) << db_->model(m).name;
    }
    // Built once: the same vector on the second call.
    EXPECT_EQ(&normals, &recogniser.RestingNormals(m, options.model_leaf));
  }
}

// A mug and a box standing apart on the table (the threads tests' scene).
Scene MugAndBoxOnTable(const TableFrame& frame) {
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  scene.objects.push_back({MakeObject(ObjectClass::kMug, 0), frame.Pose(0.08, 0.03, 0.7), 0.8, {}});
  scene.objects.push_back({MakeObject(ObjectClass::kBox, 0), frame.Pose(-0.1, -0.04, 0.3), 0.8, {}});
  return scene;
}

// SceneRecogniser::WarmUp on another thread while a scene is recognised (as the
// scan-and-recognise loop warms up during its first capture): the same objects, models and
// poses as a recogniser whose caches the recognition built itself, and afterwards every
// model's caches built, equal to those built cold.
TEST_F(SceneRecognitionTest, WarmingUpOnAnotherThreadChangesNoResult) {
  const TableFrame frame;
  const PointCloud cloud = ScanScene(MugAndBoxOnTable(frame));
  const SceneRecognitionOptions options;
  const SceneRecogniser cold(*db_);
  const SceneRecognitionResult expected = cold.Recognise(cloud, options);
  ASSERT_EQ(expected.objects.size(), 2u) << SceneBriefReport(expected);

  const SceneRecogniser warmed(*db_);
  std::thread warm_up([&] { warmed.WarmUp(options); });
  const SceneRecognitionResult result = warmed.Recognise(cloud, options);
  warm_up.join();
  ASSERT_EQ(result.objects.size(), expected.objects.size());
  for (size_t i = 0; i < result.objects.size(); ++i) {
    const Suggestion& a = result.objects[i].best();
    const Suggestion& b = expected.objects[i].best();
    EXPECT_EQ(a.model_name, b.model_name);
    EXPECT_LT((a.cam_from_model.translation - b.cam_from_model.translation).norm(), 1e-9);
    EXPECT_LT((a.cam_from_model.rotation - b.cam_from_model.rotation).norm(), 1e-9);
  }
  for (int m = 0; m < db_->num_models(); ++m) {
    const NearSymmetryAxis& axis = warmed.SymmetryAxis(m, options.model_leaf);
    const NearSymmetryAxis& built_cold = cold.SymmetryAxis(m, options.model_leaf);
    EXPECT_EQ(axis.found, built_cold.found) << db_->model(m).name;
    EXPECT_EQ(axis.direction, built_cold.direction) << db_->model(m).name;
    EXPECT_EQ(warmed.RestingNormals(m, options.model_leaf),
              cold.RestingNormals(m, options.model_leaf))
        << db_->model(m).name;
  }
}

// With two threads (recognition.threads) the independent work of a scene runs side by side
// (the clusters' first looks, the hypotheses' own verification evidence, the rolled turns,
// joins and splits), each piece on one thread and added in order: the same hypotheses,
// objects, models, poses, scores and unknowns as one thread (a mug, a box and a bottle on
// the table: several clusters).
TEST_F(SceneRecognitionTest, RecognisingClustersSideBySideChangesNoResult) {
  const TableFrame frame;
  Scene scene = MugAndBoxOnTable(frame);
  scene.objects.push_back(
      {MakeObject(ObjectClass::kBottle, 0), frame.Pose(0.02, 0.12, 1.9), 0.8, {}});
  const PointCloud cloud = ScanScene(scene);
  SceneRecognitionOptions one_thread;
  SceneRecognitionOptions two_threads;
  two_threads.recognition.threads = 2;
  const SceneRecogniser recogniser(*db_);
  const SceneRecognitionResult expected = recogniser.Recognise(cloud, one_thread);
  ASSERT_GE(expected.segmentation.clusters.size(), 2u) << SceneBriefReport(expected);
  ASSERT_GE(expected.objects.size(), 2u) << SceneBriefReport(expected);
  ExpectSameScene(SceneRecogniser(*db_).Recognise(cloud, two_threads), expected);
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

// Two objects touching (a mug's side pressed 3 mm into a bowl's rim): one Euclidean
// cluster. The recognition of the whole cluster mixes both; the scene recogniser splits it
// along the concave seam (or recognises its remainder) and must find both, with their
// poses, and report nothing unknown of either.
TEST_F(SceneRecognitionTest, TouchingObjectsInOneClusterAreBothFound) {
  const TableFrame frame;
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  const TriangleMesh bowl = MakeObject(ObjectClass::kBowl, 0);
  const TriangleMesh mug = MakeObject(ObjectClass::kMug, 0);
  // Model bounds (x: along the table at yaw 0; z: up) — a procedural object's origin is
  // not necessarily on its base.
  auto bounds = [](const TriangleMesh& mesh) {
    Eigen::Vector3f low = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
    Eigen::Vector3f high = -low;
    for (const Eigen::Vector3f& v : mesh.vertices) {
      low = low.cwiseMin(v);
      high = high.cwiseMax(v);
    }
    return std::make_pair(low, high);
  };
  const auto [bowl_low, bowl_high] = bounds(bowl);
  const auto [mug_low, mug_high] = bounds(mug);
  // Each resting on the table, the mug right of the bowl (its handle, at +x for yaw 0,
  // pointing away), its side 3 mm inside the bowl's rim.
  auto resting = [&frame](double x, float low_z) {
    Rigid3d pose = frame.Pose(x, 0.0, 0.0);
    pose.translation -= frame.cam_from_world.col(2) * static_cast<double>(low_z);
    return pose;
  };
  const double bowl_x = -0.04 - 0.5 * (bowl_low.x() + bowl_high.x());
  const double mug_x = bowl_x + bowl_high.x() - mug_low.x() - 0.003;
  const Rigid3d bowl_pose = resting(bowl_x, bowl_low.z());
  const Rigid3d mug_pose = resting(mug_x, mug_low.z());
  scene.objects.push_back({bowl, bowl_pose, 0.8, {}});
  scene.objects.push_back({mug, mug_pose, 0.8, {}});
  const PointCloud cloud = ScanScene(scene);

  const SceneRecogniser recogniser(*db_);
  const SceneRecognitionResult result = recogniser.Recognise(cloud);
  std::printf("%s\n", SceneBriefReport(result).c_str());
  // The largest cluster holds both (table x is camera x): it reaches past the bowl's centre
  // on the left and past the mug's on the right. (The mug's handle may be a cluster of its
  // own: the projector's shadow cuts it off.)
  ASSERT_FALSE(result.segmentation.clusters.empty());
  float low_x = std::numeric_limits<float>::max(), high_x = -low_x;
  for (const Eigen::Vector3f& p : result.segmentation.clusters[0].cloud.points) {
    low_x = std::min(low_x, p.x());
    high_x = std::max(high_x, p.x());
  }
  ASSERT_LT(low_x, bowl_pose.translation.x()) << "the two objects should touch";
  ASSERT_GT(high_x, mug_pose.translation.x()) << "the two objects should touch";
  struct Truth {
    ObjectClass cls;
    const TriangleMesh* mesh;
    Rigid3d pose;
  };
  for (const Truth& t : {Truth{ObjectClass::kBowl, &bowl, bowl_pose},
                         Truth{ObjectClass::kMug, &mug, mug_pose}}) {
    const RecognisedObject* match = nullptr;
    for (const RecognisedObject& o : result.objects) {
      if (o.best().class_name == ToString(t.cls)) match = &o;
    }
    if (!match) {
      ADD_FAILURE() << ToString(t.cls) << " not found";
      continue;
    }
    const PoseComparison error = ComparePoses(match->best().cam_from_model, t.pose, *t.mesh);
    std::printf("%s: rotation %.2f°, centre %.2f mm, ADD-S %.2f mm\n", ToString(t.cls).c_str(),
                error.rotation_error_deg, 1e3 * error.center_error_m, 1e3 * error.adds_m);
    EXPECT_LT(error.center_error_m, 0.005) << ToString(t.cls);
    EXPECT_LT(error.adds_over_diameter(), 0.1) << ToString(t.cls);
  }
  EXPECT_EQ(result.objects.size(), 2u);
  EXPECT_TRUE(result.unknown.empty());
}

// YCB meshes of ../shared/data posed on a table as in a scene of `sope eval --table`: a
// database of them (300 views), the scene (the table n·p + offset = 0 under the first
// object, camera frame) and its scan through the virtual rig.
struct YcbTruth {
  std::string name;
  Eigen::Matrix3d rotation;
  Eigen::Vector3d translation;
  TriangleMesh mesh;  // as the database scaled it
  Rigid3d pose() const {
    Rigid3d p;
    p.rotation = rotation;
    p.translation = translation;
    return p;
  }
};

class YcbTableScene {
 public:
  YcbTableScene(const std::string& data, const Eigen::Vector3d& normal, double offset,
                std::vector<YcbTruth> truths)
      : truths_(std::move(truths)) {
    std::vector<ModelSource> models;
    for (const YcbTruth& t : truths_) {
      models.push_back({data + "/meshes/ycb/" + t.name + ".obj", t.name, t.name});
    }
    DatabaseOptions db_options = DatabaseOptions::Preset("sope");
    db_options.views_per_model = 300;
    WriteDatabase(scratch_.File("ycb.sopedb"), BuildDatabase(models, db_options));
    db_ = Database::Open(scratch_.File("ycb.sopedb"));
    Scene scene;
    SceneObject table;
    table.mesh = MakePlane(0.7, 0.7, 4);  // faces −z: model −z turned to the camera (normal)
    const Eigen::Vector3d ex = Eigen::Vector3d::UnitX().cross(normal).cross(normal).normalized();
    table.cam_from_model.rotation.col(2) = -normal;
    table.cam_from_model.rotation.col(0) = ex;
    table.cam_from_model.rotation.col(1) = (-normal).cross(ex);
    const Eigen::Vector3d centre = truths_[0].translation;
    table.cam_from_model.translation = centre - (normal.dot(centre) + offset) * normal;
    table.albedo = 0.45;
    scene.objects.push_back(table);
    for (YcbTruth& t : truths_) {
      t.mesh = ReadMesh(data + "/meshes/ycb/" + t.name + ".obj");
      const double scale = SizeNormalisationScale(t.mesh, db_options.size);
      for (Eigen::Vector3f& v : t.mesh.vertices) v *= static_cast<float>(scale);
      scene.objects.push_back({t.mesh, t.pose(), 0.6, {}});
    }
    cloud_ = ScanScene(scene);
  }
  const Database& db() const { return *db_; }
  const PointCloud& cloud() const { return cloud_; }
  const YcbTruth& truth(size_t i) const { return truths_[i]; }
  // Whether `result` holds truth i's model posed within ADD-S < 10% of its diameter.
  bool Found(const SceneRecognitionResult& result, size_t i) const {
    const YcbTruth& t = truths_[i];
    for (const RecognisedObject& o : result.objects) {
      if (o.best().model_name != t.name) continue;
      const PoseComparison error = ComparePoses(o.best().cam_from_model, t.pose(), t.mesh);
      std::printf("%s: rotation %.2f°, centre %.2f mm, ADD-S / diameter %.3f\n", t.name.c_str(),
                  error.rotation_error_deg, 1e3 * error.center_error_m,
                  error.adds_over_diameter());
      if (error.adds_over_diameter() < 0.1) return true;
    }
    return false;
  }

 private:
  testing::ScratchDir scratch_;
  std::vector<YcbTruth> truths_;
  std::unique_ptr<Database> db_;
  PointCloud cloud_;
};

// A banana against a cracker box (YCB meshes of ../shared/data, posed as in scene 16 of
// `sope eval --table --db <the 10 YCB meshes, 300 views> --scenes 20`): one Euclidean
// cluster; its recognition finds the box, which leaves 26% of the cluster unexplained —
// below remainder_fraction (0.3), and that remainder mixes the banana with the box's own
// unexplained edge (a second connected part). Without remainder parts the banana is
// missed; with them its part (~21% of the cluster) is recognised alone and both objects
// are found, posed within ADD-S < 10% of their diameters.
TEST(SceneRecognitionRemainderParts, ABananaAgainstACrackerBoxIsFoundInItsPart) {
  SOPE_REQUIRE_SHARED_DATA(data);
  Eigen::Matrix3d box_rotation, banana_rotation;
  box_rotation << -0.01236171, -0.87690154, -0.48051105, -0.57803111, -0.38585221, 0.71902581,
      -0.81592109, 0.28663873, -0.50210658;
  banana_rotation << -0.86182785, -0.4986549, -0.09271483, 0.41228892, -0.79522001, 0.44457055,
      -0.29541597, 0.34491799, 0.89093263;
  const YcbTableScene scene(
      data, Eigen::Vector3d(-1.3413e-05, -0.58480066, -0.81117702), 0.60836941,
      {{"CrackerBox", box_rotation, Eigen::Vector3d(0.04689677, -0.05893065, 0.78527749), {}},
       {"Banana", banana_rotation, Eigen::Vector3d(-0.12972022, -0.01599493, 0.72182799), {}}});
  const SceneRecogniser recogniser(scene.db());
  SceneRecognitionOptions without_parts;
  without_parts.remainder_part_fraction = 0.0;
  const SceneRecognitionResult before = recogniser.Recognise(scene.cloud(), without_parts);
  std::printf("without remainder parts:\n%s\n", SceneBriefReport(before).c_str());
  ASSERT_EQ(before.segmentation.clusters.size(), 1u) << "the two objects should touch";
  EXPECT_TRUE(scene.Found(before, 0));
  EXPECT_FALSE(scene.Found(before, 1)) << "the case no longer needs the remainder parts";

  const SceneRecognitionResult result = recogniser.Recognise(scene.cloud());
  std::printf("with them:\n%s\n", SceneBriefReport(result).c_str());
  EXPECT_TRUE(scene.Found(result, 0));
  EXPECT_TRUE(scene.Found(result, 1));
  EXPECT_EQ(result.objects.size(), 2u);
}

// A banana lying between a can on its side and a mustard bottle (YCB meshes of
// ../shared/data posed as in scene 11 of `sope eval --table --db <the 10 YCB meshes, 300
// views> --scenes 20 --seed 1`), touching both. The banana's recognised pose (from the
// remainder of the can's cluster) is turned ~13° about its long axis, so its far end sinks
// 3 cm into the table; snapped up onto the table it fits 2–7% of its points and is
// rejected. Its refit on a resting face (SceneRecognitionOptions::rest_refit_from: turned
// onto each of the stable faces nearest its pose — the right one 96° away —, refined on the
// remainder with the table as a constraint) is found.
TEST(SceneRecognitionRestRefit, ABananaBetweenACanAndABottleIsFoundOnItsRestingFace) {
  SOPE_REQUIRE_SHARED_DATA(data);
  Eigen::Matrix3d banana, can, bottle;
  banana << -0.99322857, -0.11443145, -0.02006115, 0.07545507, -0.76669743, 0.63755908,
      -0.08833765, 0.63172818, 0.77014023;
  can << -0.12518006, -0.01863731, -0.99195897, 0.75333576, -0.65240158, -0.08280948,
      -0.64561226, -0.75764426, 0.09570782;
  bottle << 0.89696545, 0.44206454, 0.00565007, 0.28493506, -0.56827779, -0.77192769,
      -0.33803105, 0.69400237, -0.63568523;
  const YcbTableScene scene(
      data, Eigen::Vector3d(-9.53477e-06, -0.76869887, -0.63961089), 0.47969934,
      {{"Banana", banana, Eigen::Vector3d(0.09965754, 0.04100260, 0.65036867), {}},
       {"MasterChefCan", can, Eigen::Vector3d(-0.08672031, 0.03190169, 0.65640099), {}},
       {"MustardBottle", bottle, Eigen::Vector3d(0.13648362, 0.04192064, 0.56859749), {}}});
  const SceneRecogniser recogniser(scene.db());
  SceneRecognitionOptions without_refit;
  without_refit.rest_refit_from = 0.0;
  const SceneRecognitionResult before = recogniser.Recognise(scene.cloud(), without_refit);
  std::printf("without the refit:\n%s\n", SceneBriefReport(before).c_str());
  EXPECT_FALSE(scene.Found(before, 0)) << "the case no longer needs the refit";

  const SceneRecognitionResult result = recogniser.Recognise(scene.cloud());
  std::printf("with it:\n%s\n", SceneBriefReport(result).c_str());
  for (size_t i = 0; i < 3; ++i) EXPECT_TRUE(scene.Found(result, i)) << scene.truth(i).name;
  EXPECT_EQ(result.objects.size(), 3u);
}

// A wall behind the table (a vertical plane 70 × 30 cm standing on the table's far part)
// rises above the table like an object: it is a backdrop, left out of recognition, not an
// unknown object, and the object in front of it is still found.
TEST_F(SceneRecognitionTest, AWallBehindTheTableIsABackdropNotAnObject) {
  const TableFrame frame;
  Scene scene;
  scene.objects.push_back(TableTop(frame));
  SceneObject wall;
  wall.mesh = MakePlane(0.7, 0.3, 4);
  // MakePlane faces −z; turned by −90° about x its face looks along world −y (to the
  // camera), its centre 15 cm up, 12 cm behind the table's centre.
  wall.cam_from_model = frame.Pose(0.0, 0.12, 0.0);
  wall.cam_from_model.rotation =
      wall.cam_from_model.rotation * Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitX()).matrix();
  wall.cam_from_model.translation += frame.cam_from_world * Eigen::Vector3d(0, 0, 0.15);
  wall.albedo = 0.5;
  scene.objects.push_back(wall);
  const Rigid3d mug_pose = frame.Pose(0.0, -0.06, 0.3);
  scene.objects.push_back({MakeObject(ObjectClass::kMug, 0), mug_pose, 0.8, {}});
  const PointCloud cloud = ScanScene(scene);

  const SceneRecogniser recogniser(*db_);
  const SceneRecognitionResult result = recogniser.Recognise(cloud);
  std::printf("%s\n", SceneBriefReport(result).c_str());
  ASSERT_EQ(result.background.size(), 1u);
  // The backdrop cluster lies on the wall: its centroid 12 cm behind the table centre.
  const Eigen::Vector3d wall_normal = frame.cam_from_world.col(1);  // world y, away
  const double behind =
      (result.background[0].centroid.cast<double>() - frame.origin_in_cam).dot(wall_normal);
  EXPECT_NEAR(behind, 0.12, 0.01);
  ASSERT_EQ(result.objects.size(), 1u);
  EXPECT_EQ(result.objects[0].best().class_name, "mug");
  EXPECT_TRUE(result.unknown.empty());
  const nlohmann::json j = nlohmann::json::parse(SceneRecognitionResultToJson(result));
  EXPECT_EQ(j["background"].size(), 1u);

  // Without the backdrop test the wall is a cluster to recognise (and, here, unknown).
  SceneRecognitionOptions no_backdrop;
  no_backdrop.backdrop_planar_fraction = 0.0;
  const SceneRecognitionResult plain = recogniser.Recognise(cloud, no_backdrop);
  EXPECT_TRUE(plain.background.empty());
  EXPECT_EQ(plain.segmentation.clusters.size(), result.segmentation.clusters.size() + 1);
}

// Visible surface of spheres seen from the origin: the first hit of each ray of a
// 2 mm × 2 mm grid at depth 0.6 m.
PointCloud SeenSpheres(const std::vector<Eigen::Vector3f>& centres, float radius) {
  PointCloud cloud;
  for (float x = -0.15f; x <= 0.15f; x += 0.002f) {
    for (float y = -0.1f; y <= 0.1f; y += 0.002f) {
      const Eigen::Vector3f ray = Eigen::Vector3f(x, y, 0.6f).normalized();
      float nearest = std::numeric_limits<float>::max();
      for (const Eigen::Vector3f& c : centres) {
        const float b = ray.dot(c);
        const float disc = b * b - (c.squaredNorm() - radius * radius);
        if (disc >= 0.0f) nearest = std::min(nearest, b - std::sqrt(disc));
      }
      if (nearest < std::numeric_limits<float>::max()) cloud.points.push_back(nearest * ray);
    }
  }
  return cloud;
}

TEST(ConvexSegmentation, SplitsTouchingSpheresAtTheirSeamAndKeepsOneWhole) {
  const float radius = 0.04f;
  const std::vector<Eigen::Vector3f> centres = {{-0.0401f, 0.0f, 0.6f}, {0.0401f, 0.0f, 0.6f}};
  const PointCloud two = SeenSpheres(centres, radius);
  const std::vector<std::vector<int>> segments = ConvexSegments(two);
  ASSERT_GE(segments.size(), 2u);
  // The two largest segments: one sphere each (by the side of x = 0 they lie on), nearly
  // pure, together nearly all the points.
  size_t covered = 0;
  for (int k = 0; k < 2; ++k) {
    int left = 0;
    for (const int i : segments[k]) left += two.points[i].x() < 0.0f;
    const double purity =
        std::max(left, static_cast<int>(segments[k].size()) - left) / double(segments[k].size());
    EXPECT_GT(purity, 0.97) << "segment " << k;
    covered += segments[k].size();
  }
  EXPECT_GT(covered, 0.9 * two.size());
  auto mostly_left = [&two](const std::vector<int>& segment) {
    int left = 0;
    for (const int i : segment) left += two.points[i].x() < 0.0f;
    return 2 * left > static_cast<int>(segment.size());
  };
  EXPECT_NE(mostly_left(segments[0]), mostly_left(segments[1]));

  const PointCloud one = SeenSpheres({centres[0]}, radius);
  const std::vector<std::vector<int>> whole = ConvexSegments(one);
  ASSERT_GE(whole.size(), 1u);
  EXPECT_GT(whole[0].size(), 0.9 * one.size());

  PointCloud bad = one;
  bad.points[5].y() = std::numeric_limits<float>::quiet_NaN();
  testing::ExpectThrowsWithMessage<Error>([&] { ConvexSegments(bad); }, {"non-finite"});
  ConvexSegmentationOptions wrong;
  wrong.seed_resolution = wrong.voxel_resolution;
  testing::ExpectThrowsWithMessage<Error>([&] { ConvexSegments(one, wrong); },
                                          {"seed resolution"});
}

// Two "objects" of flat strips (segments), 2 mm apart within each: A, three strips side
// by side (seams 6 cm long), and B, two strips, touching A only at one corner. The weakest
// seam separates A from B exactly; too large a minimum, or one segment, gives no split.
TEST(ConvexSegmentation, WeakestSeamSplitsTwoObjectsOfSeveralSegments) {
  PointCloud points;
  std::vector<std::vector<int>> segments;
  // A strip of w × 6 cm at (x0, y0), depth z, as one segment.
  const auto strip = [&](float x0, float y0, float w) {
    segments.emplace_back();
    for (float x = x0; x < x0 + w - 1e-6f; x += 0.002f) {
      for (float y = y0; y < y0 + 0.06f - 1e-6f; y += 0.002f) {
        segments.back().push_back(static_cast<int>(points.size()));
        points.points.emplace_back(x, y, 0.7f);
      }
    }
  };
  strip(0.0f, 0.0f, 0.03f);    // A: the largest segment first
  strip(0.03f, 0.0f, 0.02f);   // A
  strip(0.05f, 0.06f, 0.02f);  // B, touching A's strip 1 at its corner only
  strip(-0.02f, 0.0f, 0.02f);  // A
  strip(0.07f, 0.06f, 0.02f);  // B
  const SeamSplit seam = WeakestSeamSplit(points, segments, 0.004, 200);
  ASSERT_NE(seam.segments[0], 0u);
  EXPECT_EQ(seam.segments[0], 0b01011u);  // A: segments 0, 1, 3 (segment 0 always in part 0)
  EXPECT_EQ(seam.segments[1], 0b10100u);  // B: segments 2, 4
  std::vector<int> a, b;
  for (const int s : {0, 1, 3}) a.insert(a.end(), segments[s].begin(), segments[s].end());
  for (const int s : {2, 4}) b.insert(b.end(), segments[s].begin(), segments[s].end());
  std::sort(a.begin(), a.end());
  std::sort(b.begin(), b.end());
  EXPECT_EQ(seam.parts[0], a);
  EXPECT_EQ(seam.parts[1], b);
  EXPECT_GT(seam.contact, 0.0);
  // The corner contact is a few cell pairs; A's own seams (6 cm each) many more.
  EXPECT_LT(seam.contact, 20.0);

  // B holds 600 points: a minimum above that leaves only splits inside A, by a long seam
  // (still a split); above half the points, none.
  const SeamSplit larger = WeakestSeamSplit(points, segments, 0.004, 700);
  EXPECT_NE(larger.segments[0], 0u);
  EXPECT_GT(larger.contact, seam.contact);
  const SeamSplit none = WeakestSeamSplit(points, segments, 0.004, 1 + points.size() / 2);
  EXPECT_EQ(none.segments[0], 0u);
  EXPECT_TRUE(none.parts[0].empty() && none.parts[1].empty());
  const SeamSplit single = WeakestSeamSplit(points, {segments[0]}, 0.004, 10);
  EXPECT_EQ(single.segments[0], 0u);
  testing::ExpectThrowsWithMessage<Error>(
      [&] { WeakestSeamSplit(points, segments, 0.0, 10); }, {"cell must be > 0"});
  SceneRecognitionOptions options;
  options.seam_split_fraction = 0.6;  // both sides cannot hold more than half
  testing::ExpectThrowsWithMessage<Error>([&] { options.Check(); }, {"seam split fraction"});
}

// A square facing the camera, `size` metres wide, centred at (x, 0, z), sampled every
// 2 mm, normals towards the camera.
PointCloud Square(float x, float z, float size) {
  PointCloud square;
  for (float u = -size / 2; u <= size / 2 + 1e-6f; u += 0.002f) {
    for (float v = -size / 2; v <= size / 2 + 1e-6f; v += 0.002f) {
      square.points.emplace_back(x + u, v, z);
      square.normals.emplace_back(0.0f, 0.0f, -1.0f);
    }
  }
  return square;
}

// The second look of the scene verification: hypothesis B's bounding box reaches over the
// points of A (its model has a part hidden behind A). Judged alone, A's points in B's box
// count against B (local explained ≈ 0.5 < 0.55); once A is accepted they are A's, and B
// passes. Without second looks, B stays rejected.
TEST(SceneVerification, PointsAnAcceptedHypothesisExplainsNoLongerCountAgainstAnother) {
  const PointCloud a = Square(-0.03f, 0.6f, 0.04f);
  const PointCloud b_seen = Square(0.03f, 0.6f, 0.04f);
  PointCloud scene = a;
  scene.points.insert(scene.points.end(), b_seen.points.begin(), b_seen.points.end());
  PointCloud b_model = b_seen;  // … and a part 2 cm behind A, hidden by it
  const PointCloud hidden = Square(-0.03f, 0.62f, 0.04f);
  b_model.points.insert(b_model.points.end(), hidden.points.begin(), hidden.points.end());
  b_model.normals.insert(b_model.normals.end(), hidden.normals.begin(), hidden.normals.end());
  const std::vector<SceneHypothesis> hypotheses = {{&a, Rigid3d(), 0.0, 0.0},
                                                   {&b_model, Rigid3d(), 0.0, 0.0}};
  SceneVerificationOptions options;
  options.relook_rounds = 0;
  const std::vector<HypothesisEvidence> once = VerifyHypotheses(scene, scene, hypotheses, options);
  EXPECT_TRUE(once[0].accepted);
  EXPECT_NEAR(once[1].model_fit, 1.0, 0.02);  // its hidden part is occluded, not missing
  EXPECT_LT(once[1].local_explained, options.min_local_explained);
  EXPECT_FALSE(once[1].accepted);
  options.relook_rounds = 2;
  const std::vector<HypothesisEvidence> twice = VerifyHypotheses(scene, scene, hypotheses, options);
  EXPECT_TRUE(twice[0].accepted);
  EXPECT_TRUE(twice[1].accepted);
  EXPECT_NEAR(twice[1].local_explained, 1.0, 0.02);
  EXPECT_EQ(twice[1].duplicates, 0);

  // With a cache, hypothesis by hypothesis: the same evidence as all at once.
  VerificationCache cache;
  const std::vector<SceneHypothesis> first = {hypotheses[0]};
  const std::vector<HypothesisEvidence> alone =
      VerifyHypotheses(scene, scene, first, options, {}, &cache);
  ASSERT_EQ(alone.size(), 1u);
  EXPECT_TRUE(alone[0].accepted);
  const std::vector<HypothesisEvidence> cached =
      VerifyHypotheses(scene, scene, hypotheses, options, {}, &cache);
  ASSERT_EQ(cached.size(), twice.size());
  for (size_t h = 0; h < cached.size(); ++h) {
    EXPECT_EQ(cached[h].accepted, twice[h].accepted) << h;
    EXPECT_EQ(cached[h].explained, twice[h].explained) << h;
    EXPECT_EQ(cached[h].model_fit, twice[h].model_fit) << h;
    EXPECT_EQ(cached[h].local_explained, twice[h].local_explained) << h;
  }
  testing::ExpectThrowsWithMessage<Error>(
      [&] { VerifyHypotheses(scene, scene, first, options, {}, &cache); }, {"cache holds 2"});
}

// A hypothesis almost wholly hidden (SceneVerificationOptions::min_visible_fraction): a
// 12 cm square model 0.6 m away behind an 8 cm square 0.4 m away, of which only a 1 cm
// patch beside the occluder's shadow is seen. Its fit and explained fraction count only
// what is not occluded or on an empty ray, so it passes them on its 36 points (fit and
// local explained 1, no violation); only 1% of its camera-facing surface is seen, below
// the 5% a detection must show: rejected, and the reason says so. With the rule off it
// is accepted.
TEST(SceneVerification, AHypothesisAlmostWhollyHiddenIsRejected) {
  PointCloud scene = Square(0.0f, 0.4f, 0.08f);
  const PointCloud patch = Square(0.075f, 0.6f, 0.01f);
  scene.points.insert(scene.points.end(), patch.points.begin(), patch.points.end());
  const PointCloud model = Square(0.02f, 0.6f, 0.12f);
  const std::vector<SceneHypothesis> hypotheses = {{&model, Rigid3d(), 0.0, 0.0}};
  SceneVerificationOptions options;
  const std::vector<HypothesisEvidence> evidence =
      VerifyHypotheses(scene, scene, hypotheses, options);
  ASSERT_EQ(evidence.size(), 1u);
  const HypothesisEvidence& e = evidence[0];
  std::printf("fit %.2f, local %.2f, violations %.2f, visible fraction %.3f, %s\n",
              e.model_fit, e.local_explained, e.violation_fraction, e.visible_fraction,
              RejectionReason(e, options).c_str());
  EXPECT_GE(e.model_fit, options.min_model_fit);
  EXPECT_GE(e.local_explained, options.min_local_explained);
  EXPECT_LE(e.violation_fraction, options.max_violation_fraction);
  EXPECT_LT(e.visible_fraction, 0.02);
  EXPECT_FALSE(e.passes || e.accepted);
  EXPECT_NE(RejectionReason(e, options).find("visible fraction"), std::string::npos);
  options.min_visible_fraction = 0.0;
  EXPECT_TRUE(VerifyHypotheses(scene, scene, hypotheses, options)[0].accepted);
}

// The surface of a cube `size` metres wide centred at (x, 0, z), sampled every 2 mm,
// outward normals.
PointCloud Cube(float x, float z, float size) {
  PointCloud cube;
  const float h = size / 2;
  for (int axis = 0; axis < 3; ++axis) {
    for (const float side : {-1.0f, 1.0f}) {
      for (float u = -h; u <= h + 1e-6f; u += 0.002f) {
        for (float v = -h; v <= h + 1e-6f; v += 0.002f) {
          Eigen::Vector3f p, n = Eigen::Vector3f::Zero();
          p[axis] = side * h;
          p[(axis + 1) % 3] = u;
          p[(axis + 2) % 3] = v;
          n[axis] = side;
          cube.points.push_back(p + Eigen::Vector3f(x, 0.0f, z));
          cube.normals.push_back(n);
        }
      }
    }
  }
  return cube;
}

// Two solid objects cannot fill the same space: cubes A and B, 4 cm wide, B turned 30°
// about the line of sight, their centres `gap` apart, each explaining its face of the scene
// (the selection's gain test off: here each is accepted whatever it duplicates). At 1.5 cm
// each cube holds well over max_mutual_overlap of the other's surface sample inside its
// hull: only one is accepted. At 5 cm (1 cm apart at the nearest) both are accepted. (A single
// flat face pressed into another object puts at most a sixth of a cube's surface inside
// it: below the default 0.15.)
TEST(SceneVerification, AHypothesisFillingAnAcceptedOnesSpaceIsLeftOut) {
  const PointCloud cube = Cube(0.0f, 0.0f, 0.04f);
  const PointCloud face = Square(0.0f, -0.02f, 0.04f);
  for (const float gap : {0.015f, 0.05f}) {
    const Rigid3d cam_from_a(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.0, 0.0, 0.6));
    const Rigid3d cam_from_b(Eigen::AngleAxisd(M_PI / 6, Eigen::Vector3d::UnitZ()).matrix(),
                             Eigen::Vector3d(gap, 0.0, 0.6));
    PointCloud scene;
    for (const Eigen::Vector3f& p : face.points) {
      scene.points.push_back((cam_from_a * p.cast<double>()).cast<float>());
    }
    for (const Eigen::Vector3f& p : face.points) {
      const Eigen::Vector3f q = (cam_from_b * p.cast<double>()).cast<float>();
      if (std::abs(q.x()) > 0.0201f || std::abs(q.y()) > 0.0201f) scene.points.push_back(q);
    }
    const std::vector<SceneHypothesis> hypotheses = {{&cube, cam_from_a, 0.0, 0.0},
                                                     {&cube, cam_from_b, 0.0, 0.0}};
    SceneVerificationOptions options;
    options.min_gain_fraction = 0.0;
    options.duplicate_weight = 0.0;
    options.exchange_rounds = 0;
    options.max_mutual_overlap = 0.0;
    const std::vector<HypothesisEvidence> without =
        VerifyHypotheses(scene, scene, hypotheses, options);
    EXPECT_TRUE(without[0].accepted) << gap;
    EXPECT_TRUE(without[1].accepted) << gap;
    options.max_mutual_overlap = SceneVerificationOptions().max_mutual_overlap;
    const std::vector<HypothesisEvidence> with =
        VerifyHypotheses(scene, scene, hypotheses, options);
    if (gap > 0.04f) {
      EXPECT_TRUE(with[0].accepted && with[1].accepted) << gap;
    } else {
      // The one of larger gain is accepted, the other left out.
      EXPECT_EQ(with[0].accepted + with[1].accepted, 1) << gap;
      EXPECT_EQ(with[0].overlapping + with[1].overlapping, 1) << gap;
      EXPECT_NE(with[0].accepted, with[0].overlapping) << gap;
    }
  }
}

// The exchanges after the greedy selection: hypothesis W explains both squares A and B at
// once but also puts a patch in front of A where the camera saw A (free-space violations).
// Its gain (882 points less 121 violations) beats A's or B's alone (441 each), so the
// greedy selection accepts it first and A and B then only duplicate it; the selection
// without W — A and B, 882 points, no violation — gains more, and the exchange finds it.
TEST(SceneVerification, ExchangesReplaceAHypothesisThatBlocksTwoBetterOnes) {
  const PointCloud a = Square(-0.03f, 0.6f, 0.04f);
  const PointCloud b = Square(0.03f, 0.6f, 0.04f);
  PointCloud scene = a;
  scene.points.insert(scene.points.end(), b.points.begin(), b.points.end());
  scene.normals.insert(scene.normals.end(), b.normals.begin(), b.normals.end());
  PointCloud w = scene;
  const PointCloud patch = Square(-0.03f, 0.59f, 0.02f);  // 1 cm in front of A's centre
  w.points.insert(w.points.end(), patch.points.begin(), patch.points.end());
  w.normals.insert(w.normals.end(), patch.normals.begin(), patch.normals.end());
  const std::vector<SceneHypothesis> hypotheses = {
      {&a, Rigid3d(), 0.0, 0.0}, {&b, Rigid3d(), 0.0, 0.0}, {&w, Rigid3d(), 0.0, 0.0}};
  SceneVerificationOptions options;
  options.exchange_rounds = 0;
  const std::vector<HypothesisEvidence> greedy =
      VerifyHypotheses(scene, scene, hypotheses, options);
  ASSERT_TRUE(greedy[2].passes);
  EXPECT_EQ(greedy[2].violations, static_cast<int>(patch.size()));
  EXPECT_TRUE(greedy[2].accepted);
  EXPECT_FALSE(greedy[0].accepted);
  EXPECT_FALSE(greedy[1].accepted);
  options.exchange_rounds = 4;
  const std::vector<HypothesisEvidence> exchanged =
      VerifyHypotheses(scene, scene, hypotheses, options);
  EXPECT_TRUE(exchanged[0].accepted);
  EXPECT_TRUE(exchanged[1].accepted);
  EXPECT_FALSE(exchanged[2].accepted);
  EXPECT_EQ(exchanged[0].duplicates + exchanged[1].duplicates, 0);
  // W's points are all explained by A and B now.
  EXPECT_EQ(exchanged[2].duplicates, static_cast<int>(exchanged[2].explained.size()));
  options.exchange_rounds = -1;
  testing::ExpectThrowsWithMessage<Error>(
      [&] { VerifyHypotheses(scene, scene, hypotheses, options); }, {"exchange rounds"});
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

TEST(TableSegmentation, TheTableIsThePlaneBeneathABigBoxTop) {
  // Seen straight down from 0.6 m: a 40 × 40 cm table (2 mm grid) with a 30 × 30 cm box
  // 10 cm high on it and a 4 cm cube's top 3 cm above the table beside it. The box top
  // holds more points than the table left in view (9 of 16 parts), so RANSAC finds it
  // first; the table is the parallel plane below, and the box and the cube stand on it.
  PointCloud cloud;
  const auto on_box = [](float x, float y) { return x >= -0.2f && x < 0.1f && y >= -0.2f && y < 0.1f; };
  for (int i = 0; i < 200; ++i) {
    for (int k = 0; k < 200; ++k) {
      const float x = -0.2f + 0.002f * i, y = -0.2f + 0.002f * k;
      cloud.points.emplace_back(x, y, on_box(x, y) ? 0.5f : 0.6f);
    }
  }
  const size_t box_top_points = 150 * 150;
  for (int i = 0; i < 50; ++i) {  // the box's two visible sides (vertical, 2 mm grid)
    for (int k = 0; k < 150; ++k) {
      const float z = 0.5f + 0.002f * i, along = -0.2f + 0.002f * k;
      cloud.points.emplace_back(0.1f, along, z);
      cloud.points.emplace_back(along, 0.1f, z);
    }
  }
  const size_t cube_first = cloud.size();
  for (int i = 0; i < 20; ++i) {
    for (int k = 0; k < 20; ++k) cloud.points.emplace_back(0.15f + 0.002f * i, 0.15f + 0.002f * k, 0.57f);
  }
  const TableSegmentation seg = SegmentTable(cloud);
  ASSERT_TRUE(seg.plane.found) << seg.message;
  EXPECT_NEAR(std::abs(seg.plane.normal.z()), 1.0, 1e-4);
  // The table, not the box top 10 cm above it (the box's sides within plane_distance of the
  // table pull the fit by ~0.2 mm).
  EXPECT_NEAR(seg.plane.offset, 0.6, 1e-3);
  EXPECT_LT(static_cast<size_t>(seg.plane.inliers), box_top_points);
  ASSERT_EQ(seg.clusters.size(), 2u);
  EXPECT_GT(seg.clusters[0].indices.size(), box_top_points);  // the box: top and sides
  EXPECT_EQ(seg.clusters[1].indices.size(), 400u);            // the cube
  EXPECT_EQ(static_cast<size_t>(seg.clusters[1].indices.front()), cube_first);
}

TEST(TableSegmentation, TheTableIsThePlaneBeneathABigBoxFace) {
  // Seen 45° down (TableFrame): a box 30 cm wide and 30 cm high close to the camera, its
  // front face turned to it, hides most of the table (procedural tables, seed 1101, scene
  // 1): in view are a strip of table in front of it and beside it, a 4 cm cube's top on the
  // strip, and the box's top. The front face holds the most points, so RANSAC finds it
  // first; the table, the box top and the cube then lie below it. The table is the plane
  // under them (the box top's parallel plane below), and the box and the cube stand on it.
  const TableFrame frame;
  PointCloud cloud;
  const auto add = [&](double x, double y, double z) {
    cloud.points.push_back(
        (frame.origin_in_cam + frame.cam_from_world * Eigen::Vector3d(x, y, z)).cast<float>());
  };
  for (int i = 0; i < 200; ++i) {  // the table (2 mm grid), in front of and beside the box
    for (int k = 0; k < 110; ++k) {
      const double x = -0.2 + 0.002 * i, y = -0.17 + 0.002 * k;
      if (y >= -0.05 && std::abs(x) <= 0.15) continue;  // under the box
      if (x > 0.08 && x < 0.12 && y > -0.14 && y < -0.10) continue;  // under the cube
      add(x, y, 0.0);
    }
  }
  const size_t table_points = cloud.size();
  for (int i = 0; i <= 150; ++i) {  // the box: front face (y = −0.05) and top (z = 0.3)
    for (int k = 1; k <= 150; ++k) add(-0.15 + 0.002 * i, -0.05, 0.002 * k);
    for (int k = 1; k <= 50; ++k) add(-0.15 + 0.002 * i, -0.05 + 0.002 * k, 0.3);
  }
  const size_t cube_first = cloud.size();
  for (int i = 0; i < 20; ++i) {
    for (int k = 0; k < 20; ++k) add(0.08 + 0.002 * i, -0.14 + 0.002 * k, 0.04);
  }
  ASSERT_GT(151u * 150u, table_points) << "the front face must outnumber the table";
  const TableSegmentation seg = SegmentTable(cloud);
  ASSERT_TRUE(seg.plane.found) << seg.message;
  const Eigen::Vector3f up = (frame.cam_from_world * Eigen::Vector3d::UnitZ()).cast<float>();
  EXPECT_GT(seg.plane.normal.dot(up), std::cos(1.0 * M_PI / 180.0));
  EXPECT_NEAR(seg.plane.offset, -up.cast<double>().dot(frame.origin_in_cam), 1e-3);
  ASSERT_EQ(seg.clusters.size(), 2u) << seg.message;
  // The box (but for its face's lowest rows, within min_height of the table).
  EXPECT_GT(seg.clusters[0].indices.size(), 0.95 * (cube_first - table_points));
  EXPECT_LE(seg.clusters[0].indices.size(), cube_first - table_points);
  EXPECT_EQ(seg.clusters[1].indices.size(), 400u);                       // the cube
  EXPECT_EQ(static_cast<size_t>(seg.clusters[1].indices.front()), cube_first);
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

TEST(TableSegmentation, GridClustersEqualTheComponentsOfEveryPairWithinTheTolerance) {
  // 3000 random points in a 6 cm cube with a 4 mm tolerance (many cells, many points per
  // cell, chains across cell faces, edges and corners; negative coordinates too): the
  // components must be exactly those of the brute-force graph of all pairs within the
  // tolerance, in the order of their first point.
  std::vector<Eigen::Vector3f> points;
  uint64_t state = 7;
  auto uniform = [&state] {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<float>((state >> 11) * 0x1.0p-53);
  };
  for (int i = 0; i < 3000; ++i) {
    points.emplace_back(-0.03f + 0.06f * uniform(), -0.03f + 0.06f * uniform(),
                        0.5f + 0.06f * uniform());
  }
  const double tolerance = 0.004;
  std::vector<int> parent(points.size());
  for (size_t i = 0; i < parent.size(); ++i) parent[i] = static_cast<int>(i);
  const std::function<int(int)> root = [&](int i) {
    return parent[i] == i ? i : parent[i] = root(parent[i]);
  };
  const float tolerance2 = static_cast<float>(tolerance * tolerance);
  for (size_t i = 0; i < points.size(); ++i) {
    for (size_t j = i + 1; j < points.size(); ++j) {
      if ((points[j] - points[i]).squaredNorm() > tolerance2) continue;
      const int a = root(static_cast<int>(i)), b = root(static_cast<int>(j));
      parent[std::max(a, b)] = std::min(a, b);
    }
  }
  std::vector<std::vector<int>> expected;
  std::vector<int> component_of_root(points.size(), -1);
  for (size_t i = 0; i < points.size(); ++i) {
    const int r = root(static_cast<int>(i));
    if (component_of_root[r] < 0) {
      component_of_root[r] = static_cast<int>(expected.size());
      expected.emplace_back();
    }
    expected[component_of_root[r]].push_back(static_cast<int>(i));
  }
  // Neither one blob nor dust: the test exercises joins and separations alike.
  ASSERT_GT(expected.size(), 20u);
  ASSERT_LT(expected.size(), points.size() / 2);
  EXPECT_EQ(GridEuclideanClusters(points, tolerance), expected);
}

}  // namespace
}  // namespace sope
