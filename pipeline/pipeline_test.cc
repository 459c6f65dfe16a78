// The pipeline layer on the virtual rig: the scan-and-recognise controller over virtual
// scenes (ground truth), recorded frame sets and the live rig; a scan with nothing in the
// range band is a status, not an error; results.jsonl is appended, and on a full disk no
// scan leaves files without its results line.
#include "pipeline/scan_and_recognise.h"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <optional>
#include <cstring>
#include <sstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/mesh.h"
#include "decoder/decoder.h"
#include "pipeline/scan_source.h"
#include "pipeline/table_eval.h"
#include "recogniser/pose_metrics.h"
#include "recogniser/segmentation.h"
#include "recogniser/tools/database_builder.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"
#include "tests/procedural_database.h"
#include "tests/test_support.h"

namespace sope {
namespace {

namespace fs = std::filesystem;

// Three classes, one instance (seed 0) each, 40 views: a database for the loop, not for
// accuracy (scan_and_recognise_test measures that).
const std::vector<ObjectClass> kClasses = {ObjectClass::kMug, ObjectClass::kBottle,
                                           ObjectClass::kBowl};

template <typename F>
void ExpectErrorNaming(F&& f, const std::string& needle) {
  try {
    f();
    ADD_FAILURE() << "no error; expected one naming '" << needle << "'";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

class Pipeline : public ::testing::Test {
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
    options.views_per_model = 40;
    WriteDatabase(scratch_->File("db.sopedb"), BuildDatabase(models, options));
    db_ = Database::Open(scratch_->File("db.sopedb")).release();
  }
  static void TearDownTestSuite() {
    delete db_;
    delete scratch_;
  }
  // Scenes of the database's own instances (the true model frame is the database's).
  static VirtualSceneSourceOptions SceneSource(uint64_t seed) {
    VirtualSceneSourceOptions options;
    options.calibration = DefaultRigCalibration();
    options.scenes.classes = kClasses;
    options.scenes.instance_seed_base = 0;
    options.scenes.instance_count = 1;
    options.seed = seed;
    options.patterns.projector_width = options.calibration.projector.width;
    options.patterns.projector_height = options.calibration.projector.height;
    return options;
  }
  static testing::ScratchDir* scratch_;
  static Database* db_;
};
testing::ScratchDir* Pipeline::scratch_ = nullptr;
Database* Pipeline::db_ = nullptr;

TEST_F(Pipeline, ControllerScansVirtualScenesAndComparesWithTheTruth) {
  VirtualSceneSource source(SceneSource(5));
  ScanAndRecogniseOptions options;
  options.max_scans = 3;
  ScanAndRecogniseController controller(options, &source, *db_);
  std::vector<ScanReport> reports;
  const int done = controller.Run([&](const ScanReport& r) { reports.push_back(r); });
  ASSERT_EQ(done, 3);
  ASSERT_EQ(reports.size(), 3u);
  int correct = 0;
  for (int i = 0; i < 3; ++i) {
    const ScanReport& r = reports[i];
    EXPECT_EQ(r.index, i);
    EXPECT_EQ(r.status, ScanStatus::kRecognised) << r.message;
    ASSERT_TRUE(r.truth.has_value());
    // The scene's own band: every kept point nearer than the backdrop.
    EXPECT_GT(r.result.object.size(), 1000u);
    EXPECT_LT(r.result.object.size(), r.result.scan.triangulation.cloud.size());
    const nlohmann::json j = nlohmann::json::parse(r.json);
    EXPECT_EQ(j.at("status"), "recognised");
    EXPECT_EQ(j.at("scan").at("index"), i);
    EXPECT_EQ(j.at("ground_truth").at("class"), r.truth->class_name);
    EXPECT_EQ(j.at("ground_truth").at("class_correct").get<bool>(), r.class_correct);
    EXPECT_FALSE(j.contains("files"));  // no out_dir
    if (!r.class_correct) continue;
    ++correct;
    ASSERT_TRUE(r.pose_error.has_value());
    // The one comparison: the JSON carries exactly ComparePoses' numbers.
    const PoseComparison again = ComparePoses(r.result.recognition.best().cam_from_model,
                                              r.truth->cam_from_model, r.truth->mesh);
    EXPECT_EQ(j.at("ground_truth").at("adds_m").get<double>(), again.adds_m);
    EXPECT_EQ(j.at("ground_truth").at("rotation_error_deg").get<double>(),
              again.rotation_error_deg);
    // A right class on a database instance: ADD-S within 10% of the diameter.
    EXPECT_LT(r.pose_error->adds_over_diameter(), 0.10) << r.truth->class_name;
  }
  EXPECT_GE(correct, 2);
}

// The live loop decodes while capturing: every frame reaches the source's frame sink in
// order as it is grabbed, and an IncrementalDecoder fed from it gives the batch map.
TEST_F(Pipeline, FramesReachTheSinkAsCapturedAndDecodeAsTheBatch) {
  VirtualSceneSource source(SceneSource(7));
  std::unique_ptr<IncrementalDecoder> decoder;
  size_t calls = 0;
  source.SetFrameSink([&](const FrameSetManifest& manifest, size_t index, const cv::Mat& image) {
    EXPECT_EQ(index, calls);
    if (index == 0) decoder = std::make_unique<IncrementalDecoder>(manifest);
    ++calls;
    decoder->AddFrame(index, image);
  });
  const SourceScan scan = source.Next(0);
  ASSERT_EQ(calls, scan.frames.images.size());
  const CorrespondenceMap live = decoder->Finish();
  const CorrespondenceMap batch = Decode(scan.frames);
  ASSERT_GT(batch.CountValid(), 10000u);
  EXPECT_EQ(cv::norm(live.mask, batch.mask, cv::NORM_INF), 0.0);
  cv::Mat same_x, same_y;
  cv::compare(live.proj_x, batch.proj_x, same_x, cv::CMP_EQ);
  cv::compare(live.proj_y, batch.proj_y, same_y, cv::CMP_EQ);
  // Equal wherever decoded (NaN elsewhere compares unequal).
  EXPECT_EQ(cv::countNonZero(same_x & batch.mask), static_cast<int>(batch.CountValid()));
  EXPECT_EQ(cv::countNonZero(same_y & batch.mask), static_cast<int>(batch.CountValid()));
  source.SetFrameSink({});
}

TEST_F(Pipeline, NothingInTheBandIsAStatusAndTheRunGoesOn) {
  VirtualSceneSource source(SceneSource(1));
  ScanAndRecogniseOptions options;
  options.max_scans = 2;
  options.max_range = 0.2;  // the objects are ≥ 0.4 m away
  ScanAndRecogniseController controller(options, &source, *db_);
  std::vector<ScanReport> reports;
  EXPECT_EQ(controller.Run([&](const ScanReport& r) { reports.push_back(r); }), 2);
  ASSERT_EQ(reports.size(), 2u);
  for (const ScanReport& r : reports) {
    EXPECT_EQ(r.status, ScanStatus::kNothingInBand);
    EXPECT_NE(r.message.find("segmentation left 0 of"), std::string::npos) << r.message;
    EXPECT_EQ(r.message.find("--"), std::string::npos) << "names a flag: " << r.message;
    EXPECT_TRUE(r.result.recognition.empty());
    const nlohmann::json j = nlohmann::json::parse(r.json);
    EXPECT_EQ(j.at("status"), "nothing in band");
    EXPECT_TRUE(j.at("objects").is_array());
    EXPECT_TRUE(j.at("objects").empty());
    EXPECT_FALSE(j.contains("class"));
    EXPECT_FALSE(j.at("ground_truth").at("class_correct").get<bool>());
  }
  // For a single scan, seeing nothing is a failure when asked.
  options.max_scans = 1;
  options.fail_on_nothing_found = true;
  ScanAndRecogniseController strict(options, &source, *db_);
  ExpectErrorNaming([&] { strict.Run(); }, "segmentation left 0 of");
}

TEST_F(Pipeline, ResultsAreAppendedAndEveryLineHasItsFiles) {
  testing::ScratchDir scratch;
  const std::string out = scratch.File("out");
  fs::create_directories(out);
  WriteFileAtomic(out + "/results.jsonl", "{\"earlier\": true}\n");
  VirtualSceneSource source(SceneSource(2));
  ScanAndRecogniseOptions options;
  options.max_scans = 2;
  options.out_dir = out;
  ScanAndRecogniseController controller(options, &source, *db_);
  std::vector<std::string> lines_seen;
  controller.Run([&](const ScanReport& r) { lines_seen.push_back(r.json); });
  std::istringstream lines(ReadFileToString(out + "/results.jsonl", "results"));
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line, "{\"earlier\": true}");  // appended, not rewritten
  for (int i = 0; i < 2; ++i) {
    ASSERT_TRUE(std::getline(lines, line));
    EXPECT_EQ(line, lines_seen[i]);
    const nlohmann::json files = nlohmann::json::parse(line).at("files");
    for (const char* key : {"cloud", "object_cloud", "overlay"}) {
      EXPECT_TRUE(fs::is_regular_file(files.at(key).get<std::string>())) << key;
    }
  }
  EXPECT_FALSE(std::getline(lines, line));
}

TEST_F(Pipeline, AFullDiskLeavesNoCloudsWithoutTheirResultsLine) {
  // results.jsonl on a device that is always full (ENOSPC on every write): the scan's
  // clouds and overlay are written, the line is not, so they are removed again.
  testing::ScratchDir scratch;
  const std::string out = scratch.File("out");
  fs::create_directories(out);
  fs::create_symlink("/dev/full", out + "/results.jsonl");
  VirtualSceneSource source(SceneSource(3));
  ScanAndRecogniseOptions options;
  options.max_scans = 1;
  options.out_dir = out;
  ScanAndRecogniseController controller(options, &source, *db_);
  int reported = 0;
  ExpectErrorNaming([&] { controller.Run([&](const ScanReport&) { ++reported; }); },
                    "results.jsonl: " + std::string(std::strerror(ENOSPC)));
  EXPECT_EQ(reported, 0);
  for (const auto& entry : fs::directory_iterator(out)) {
    EXPECT_EQ(entry.path().filename().string(), "results.jsonl") << "left behind: "
                                                              << entry.path().string();
  }
}

// Tabletop matching: a bottle and a mug side by side, only the mug detected (exactly). The
// mug's detection lies within half the bottle's diameter of the bottle's centre too; the
// bottle comes first in the truth list, yet the detection goes to the mug (its own model
// first), and the bottle is a miss.
TEST_F(Pipeline, TableMatchingGivesADetectionToItsOwnModelFirst) {
  auto model_index = [](const std::string& name) {
    for (int m = 0; m < db_->num_models(); ++m) {
      if (db_->model(m).name == name) return m;
    }
    return -1;
  };
  const int mug = model_index("mug_0");
  ASSERT_GE(mug, 0);
  ScanTruth truth;
  ScanObjectTruth bottle{"bottle_0", "bottle", 0, true, MakeObject(ObjectClass::kBottle, 0), {}};
  bottle.cam_from_model.translation = Eigen::Vector3d(0.0, 0.0, 0.6);
  ScanObjectTruth cup{"mug_0", "mug", 0, true, MakeObject(ObjectClass::kMug, 0), {}};
  cup.cam_from_model.translation = Eigen::Vector3d(0.06, 0.0, 0.6);
  truth.objects = {bottle, cup};
  SceneRecognitionResult scene;
  RecognisedObject detected;
  Suggestion s;
  s.model = mug;
  s.model_name = "mug_0";
  s.class_name = "mug";
  s.cam_from_model = cup.cam_from_model;
  s.posed = true;
  detected.recognition.suggestions.push_back(s);
  scene.objects.push_back(detected);
  const double gap = (db_->model(mug).center - MakePoseTruthModel(bottle.mesh).center +
                      Eigen::Vector3d(0.06, 0.0, 0.0))
                         .norm();
  ASSERT_LT(gap, 0.5 * MakePoseTruthModel(bottle.mesh).diameter) << "the test needs them close";
  const std::vector<TableObjectMatch> matches = MatchTableObjects(scene, truth, *db_);
  ASSERT_EQ(matches.size(), 2u);
  EXPECT_EQ(matches[0].detection, -1);
  EXPECT_FALSE(matches[0].correct);
  EXPECT_EQ(matches[1].detection, 0);
  EXPECT_TRUE(matches[1].model_correct);
  EXPECT_TRUE(matches[1].correct);
}

TEST(AppendLine, CutsBackAFailedWrite) {
  testing::ScratchDir scratch;
  const std::string path = scratch.File("sub/results.jsonl");
  AppendLine(path, "one");
  AppendLine(path, "two");
  EXPECT_EQ(ReadFileToString(path, "results"), "one\ntwo\n");
  ExpectErrorNaming([] { AppendLine("/dev/full", "x"); }, "/dev/full");
  ExpectErrorNaming([&] { AppendLine(scratch.File("sub"), "x"); }, "sub");  // a directory
}

TEST_F(Pipeline, RecordedFrameSetsReplayThroughTheController) {
  // Record the built-in mug scene with the live-rig source, then scan it twice from disk.
  testing::ScratchDir scratch;
  LiveRigSourceOptions live;
  live.spec = "virtual";
  live.calibration = DefaultRigCalibration();
  live.patterns.projector_width = live.calibration.projector.width;
  live.patterns.projector_height = live.calibration.projector.height;
  live.record_directory = scratch.File("rec");
  {
    LiveRigSource source(live);
    EXPECT_EQ(source.size(), 1);
    const SourceScan scan = source.Next(0);
    ASSERT_TRUE(scan.truth.has_value());
    EXPECT_EQ(scan.truth->class_name, "mug");
    EXPECT_TRUE(fs::exists(scratch.File("rec/frames.json")));
  }
  FrameSetDirectorySource frames({scratch.File("rec"), scratch.File("rec")}, "");
  ScanAndRecogniseOptions options;
  options.max_scans = -1;  // as many as the source holds
  options.max_range = 0.72;  // the mug at 0.6 m, the backdrop at 0.75 m
  ScanAndRecogniseController controller(options, &frames, *db_);
  std::vector<ScanReport> reports;
  EXPECT_EQ(controller.Run([&](const ScanReport& r) { reports.push_back(r); }), 2);
  for (const ScanReport& r : reports) {
    EXPECT_EQ(r.source, scratch.File("rec"));
    ASSERT_EQ(r.status, ScanStatus::kRecognised) << r.message;
    EXPECT_EQ(r.result.recognition.best().class_name, "mug");
    EXPECT_FALSE(r.truth.has_value());  // a recording carries no ground truth
  }
  ExpectErrorNaming([&] { frames.Next(2); }, "frame set 2 of 2");
}

// Scene `index` of the procedural tabletop evaluation with `seed` (`sope eval --table
// --procedural --seed SEED`): every procedural class in the order of the default
// database's classes (by name), as the evaluation draws them, and one clutter object.
SourceScan EvaluationTableScene(uint64_t seed, int index) {
  VirtualTableSourceOptions source_options;
  source_options.calibration = DefaultRigCalibration();
  source_options.patterns.projector_width = source_options.calibration.projector.width;
  source_options.patterns.projector_height = source_options.calibration.projector.height;
  source_options.table.clutter = 1;
  source_options.seed = seed;
  source_options.classes = AllObjectClasses();
  std::sort(source_options.classes.begin(), source_options.classes.end(),
            [](ObjectClass a, ObjectClass b) { return ToString(a) < ToString(b); });
  VirtualTableSource source(source_options);
  return source.Next(index);
}

// Scene `index` of the procedural tabletop evaluation with `seed`, scanned: its cloud and the
// model centre (camera frame) of its object of `class_name` and `instance_seed`; nullopt
// when the scene holds no such object (it is not the scene a test describes).
struct ScannedTruthObject {
  PointCloud cloud;
  Eigen::Vector3d centre;
};
std::optional<ScannedTruthObject> ScanEvaluationObject(uint64_t seed, int index,
                                                       const std::string& class_name,
                                                       uint64_t instance_seed) {
  const SourceScan scan = EvaluationTableScene(seed, index);
  if (!scan.truth.has_value()) return std::nullopt;
  for (const ScanObjectTruth& o : scan.truth->objects) {
    if (o.class_name != class_name || o.instance_seed != instance_seed) continue;
    return ScannedTruthObject{ScanFrameSet(scan.frames, scan.calibration).triangulation.cloud,
                              o.cam_from_model * MakePoseTruthModel(o.mesh).center};
  }
  return std::nullopt;
}

// Whether `result` names an object `class_name` whose model centre lies within 3 cm of
// `centre` (camera frame).
bool NamedNear(const SceneRecognitionResult& result, const Database& db,
               const std::string& class_name, const Eigen::Vector3d& centre) {
  for (const RecognisedObject& o : result.objects) {
    const Eigen::Vector3d c = o.best().cam_from_model * db.model(o.best().model).center;
    if ((c - centre).norm() < 0.03 && o.best().class_name == class_name) return true;
  }
  return false;
}

// Joins across a gap the camera did not see through (SceneRecognitionOptions::join_gap),
// on scene 11 of the procedural tabletop evaluation with seed 601 (`sope eval --table
// --procedural --seed 601`): two unseen wine glasses (1165, 1914) lie on their sides by a
// box. Their stems are too thin to scan, so each comes out as two clusters, foot and bowl,
// several centimetres apart, and a bowl alone looks like a mug or a glass lying down. The
// database holds other instances: wine glasses 0, 3 and 12, mugs 2, 8 and 11, glasses 2,
// 12 and 15, cans 1 and 5, boxes 0 and 1. Without the joins (join_gap 0) glass 1914's bowl
// is taken for a mug and its foot is left unknown; joined (nothing seen through the gap)
// it must be found as a wine glass, its centre within 3 cm. (Glass 1165 is only printed:
// once found neither way, it is now found both ways — by later second looks, not joins.)
TEST(TableJoins, WineGlassesOnTheirSidesCutInTwoByTheirUnscannedStems) {
#if defined(__SANITIZE_ADDRESS__)
  // One scene's exact outcome: the sanitizer build's arithmetic gives another cloud (there
  // glass 1165 is found with and without the joins, 1914 with neither; no sanitizer error).
  GTEST_SKIP() << "depends on the Release build's exact cloud of this scene";
#endif
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kWineGlass, {0, 3, 12}},
                {ObjectClass::kMug, {2, 8, 11}},
                {ObjectClass::kGlass, {2, 12, 15}},
                {ObjectClass::kCan, {1, 5}},
                {ObjectClass::kBox, {0, 1}}});
  const SourceScan scan = EvaluationTableScene(601, 11);
  ASSERT_TRUE(scan.truth.has_value());
  const PointCloud cloud = ScanFrameSet(scan.frames, scan.calibration).triangulation.cloud;
  std::vector<const ScanObjectTruth*> glasses;
  for (const ScanObjectTruth& o : scan.truth->objects) {
    if (o.class_name == "wine_glass") glasses.push_back(&o);
  }
  ASSERT_EQ(glasses.size(), 2u) << "scene 11 of seed 601 is not the one described";

  const SceneRecogniser recogniser(*db);
  SceneRecognitionOptions options;
  for (const double gap : {0.0, options.join_gap}) {
    options.join_gap = gap;
    const SceneRecognitionResult result = recogniser.Recognise(cloud, options);
    std::printf("join gap %.2f m: %zu clusters\n%s\n", gap, result.segmentation.clusters.size(),
                SceneBriefReport(result).c_str());
    for (const ScanObjectTruth* glass : glasses) {
      const Eigen::Vector3d centre = glass->cam_from_model * MakePoseTruthModel(glass->mesh).center;
      const bool named = NamedNear(result, *db, "wine_glass", centre);
      std::printf("  wine glass %llu: %s\n", static_cast<unsigned long long>(glass->instance_seed),
                  named ? "found" : "not found");
      if (glass->instance_seed == 1914) {
        EXPECT_EQ(named, gap > 0);
      }
    }
  }
}

// Size looks of two unexplained clusters joined (SceneRecognitionOptions::join_size_looks), on
// scene 10 of the procedural tabletop evaluation with seed 501: an unseen wine glass (1713)
// stands in full view, its stem too thin to scan, so its bowl floats 8 cm over its foot —
// two clusters, joined across the unseen gap. The database holds other instances: wine
// glasses 0, 2, 5, 7, 8, 9, 11 and 14, glasses 0, 4, 7, 9 and 13, bowls 1, 4, 5 and 10,
// plates 10 and 15, vase 8. The bowl alone is taken for a floating glass (dropped); the
// wine glass whose views the joined points resemble most fits them badly (another bowl
// shape). Without the joined clusters' size looks nothing names the glass; with them (a
// sibling or a scaled model nearer the joined points' size) it must be named a wine
// glass, its centre within 3 cm.
TEST(TableJoins, AStandingWineGlassWhoseBowlFloatsIsFoundBySizeLooks) {
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "depends on the Release build's exact cloud of this scene";
#endif
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kWineGlass, {0, 2, 5, 7, 8, 9, 11, 14}},
                {ObjectClass::kGlass, {0, 4, 7, 9, 13}},
                {ObjectClass::kBowl, {1, 4, 5, 10}},
                {ObjectClass::kPlate, {10, 15}},
                {ObjectClass::kVase, {8}}});
  const std::optional<ScannedTruthObject> glass =
      ScanEvaluationObject(501, 10, "wine_glass", 1713);
  ASSERT_TRUE(glass.has_value()) << "scene 10 of seed 501 is not the one described";
  const PointCloud& cloud = glass->cloud;
  const Eigen::Vector3d& centre = glass->centre;

  const SceneRecogniser recogniser(*db);
  SceneRecognitionOptions options;
  // The gap between bowl and foot: 3 (the evaluation's decode) or 4 (this one's) of 10
  // samples seen through, either side of join_max_seen 0.35; 0.45 joins them here too —
  // the test is about what the join is recognised as.
  options.join_max_seen = 0.45;
  for (const bool size_looks : {false, true}) {
    options.join_size_looks = size_looks;
    const SceneRecognitionResult result = recogniser.Recognise(cloud, options);
    std::printf("join size looks %s:\n%s\n", size_looks ? "on" : "off",
                SceneBriefReport(result).c_str());
    const bool named = NamedNear(result, *db, "wine_glass", centre);
    EXPECT_EQ(named, size_looks);
  }
}

// Revolution looks (SceneRecognitionOptions::upright_max_tilt_deg), on scene 2 of the
// procedural tabletop evaluation with seed 601: an unseen wine glass (1003) stands in full
// view, bowl and stem clustered apart. The database's 16 wine glasses (plates 1, 9, 10 and
// 12, cans 3, 5, 7 and 12, bottles 3 and 10 beside them), posed on its views, fit the bowl
// leaning or floating: stems and bowls cross free space (violations 37–58% in the
// evaluation). Stood upright on the axis the bowl's normals meet, and scaled to its height
// and radius profile, a database wine glass must name it within 3 cm; without those looks
// nothing names it. (With 7 of the wine glasses only, a sibling names it either way.)
TEST(TableRevolution, AStandingWineGlassTheSearchTiltsIsFoundStoodUpright) {
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "depends on the Release build's exact cloud of this scene";
#endif
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kWineGlass,
                 {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15}},
                {ObjectClass::kPlate, {1, 9, 10, 12}},
                {ObjectClass::kCan, {3, 5, 7, 12}},
                {ObjectClass::kBottle, {3, 10}}});
  const std::optional<ScannedTruthObject> glass =
      ScanEvaluationObject(601, 2, "wine_glass", 1003);
  ASSERT_TRUE(glass.has_value()) << "scene 2 of seed 601 is not the one described";
  const PointCloud& cloud = glass->cloud;
  const Eigen::Vector3d& centre = glass->centre;

  const SceneRecogniser recogniser(*db);
  SceneRecognitionOptions options;
  const double tilt = options.upright_max_tilt_deg;
  for (const bool looks : {false, true}) {
    options.upright_max_tilt_deg = looks ? tilt : 0.0;
    const SceneRecognitionResult result = recogniser.Recognise(cloud, options);
    std::printf("revolution looks %s:\n%s\n", looks ? "on" : "off",
                SceneBriefReport(result).c_str());
    EXPECT_EQ(NamedNear(result, *db, "wine_glass", centre), looks);
  }
}

// Other classes' looks (SceneRecognitionOptions::other_class_remainder), on scene 7 of the
// procedural tabletop evaluation with seed 901: an unseen mug (1258) lies on its side in
// full view, its handle up. The database holds the 16 mugs and 16 glasses of the
// default database: a glass fits its body better than the mugs the recogniser poses, and
// the class evidence points to the glass; the handle is left unexplained. With the looks,
// a sibling mug turned to put its handle where it was seen explains the handle too, and
// the mug must be named within 3 cm; without them it is not. (With 4 mugs and 4 glasses
// only, a mug names it either way.)
TEST(TableOtherClasses, AMugTakenForAGlassIsFoundByTurningASiblingsHandle) {
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "depends on the Release build's exact cloud of this scene";
#endif
  const testing::ScratchDir scratch;
  const std::unique_ptr<Database> db = testing::ProceduralDatabase(
      scratch, {{ObjectClass::kMug, {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15}},
                {ObjectClass::kGlass, {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15}}});
  const std::optional<ScannedTruthObject> mug = ScanEvaluationObject(901, 7, "mug", 1258);
  ASSERT_TRUE(mug.has_value()) << "scene 7 of seed 901 is not the one described";

  const SceneRecogniser recogniser(*db);
  SceneRecognitionOptions options;
  const double remainder = options.other_class_remainder;
  for (const bool looks : {false, true}) {
    options.other_class_remainder = looks ? remainder : 0.0;
    const SceneRecognitionResult result = recogniser.Recognise(mug->cloud, options);
    std::printf("other classes' looks %s:\n%s\n", looks ? "on" : "off",
                SceneBriefReport(result).c_str());
    EXPECT_EQ(NamedNear(result, *db, "mug", mug->centre), looks);
  }
}

// Joins with remainders (SceneRecognitionOptions::join_remainders), on scene 14 of the
// tabletop evaluation of the classic meshes with seed 301 (`sope eval --table --db
// classic.sopedb --seed 301`; ../shared/data/meshes/classic, skipped when absent): spot lies
// on its back beside cheburashka. Its body touches cheburashka and is clustered with it; a
// shadow cuts its legs off into a cluster of their own. Once cheburashka is found, the
// body is the unexplained remainder of that cluster (43%): joined with the legs it must be
// named spot within 3 cm; without those joins the legs are joined with the whole cluster
// only, and nothing names spot.
TEST(TableJoins, AnObjectTouchingAnotherIsJoinedWithItsPartByItsRemainder) {
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "depends on the Release build's exact cloud of this scene";
#endif
  const std::optional<std::string> data = testing::SharedDataDir();
  if (!data) GTEST_SKIP() << "../shared/data not found";
  const std::string classic = JoinPath(*data, "meshes/classic");
  if (!std::filesystem::is_directory(classic)) GTEST_SKIP() << classic << " not found";
  const testing::ScratchDir scratch;
  const std::string models = scratch.File("models");
  std::filesystem::create_directories(models);
  for (const char* name : {"cheburashka", "spot", "teapot", "cow", "homer"}) {
    std::filesystem::copy_file(JoinPath(classic, std::string(name) + ".obj"),
                               JoinPath(models, std::string(name) + ".obj"));
  }
  DatabaseOptions db_options = DatabaseOptions::Preset("sope");
  db_options.views_per_model = 80;
  WriteDatabase(scratch.File("classic.sopedb"), BuildDatabase(models, db_options));
  const std::unique_ptr<Database> db = Database::Open(scratch.File("classic.sopedb"));

  // The scene as the evaluation draws it: its objects in its order, seed 301 + 14.
  VirtualTableSourceOptions source_options;
  source_options.calibration = DefaultRigCalibration();
  source_options.patterns.projector_width = source_options.calibration.projector.width;
  source_options.patterns.projector_height = source_options.calibration.projector.height;
  source_options.table.clutter = 1;
  source_options.seed = 301 + 14;
  for (const char* name : {"cheburashka", "spot", "teapot"}) {
    TableObjectSpec spec;
    spec.spec = JoinPath(models, std::string(name) + ".obj");
    spec.size = kSizeAsDatabase;
    spec.mesh_unit = db->options().size.mesh_unit;
    source_options.table.objects.push_back(spec);
  }
  VirtualTableSource source(source_options);
  const SourceScan scan = source.Next(0);
  ASSERT_TRUE(scan.truth.has_value());
  std::optional<Eigen::Vector3d> centre;
  for (const ScanObjectTruth& o : scan.truth->objects) {
    if (o.class_name == "spot") centre = o.cam_from_model * MakePoseTruthModel(o.mesh).center;
  }
  ASSERT_TRUE(centre.has_value());
  const PointCloud cloud = ScanFrameSet(scan.frames, scan.calibration).triangulation.cloud;

  const SceneRecogniser recogniser(*db);
  SceneRecognitionOptions options;
  for (const bool remainders : {false, true}) {
    options.join_remainders = remainders;
    const SceneRecognitionResult result = recogniser.Recognise(cloud, options);
    std::printf("joins with remainders %s:\n%s\n", remainders ? "on" : "off",
                SceneBriefReport(result).c_str());
    EXPECT_EQ(NamedNear(result, *db, "spot", *centre), remainders);
  }
}

// Tabletop scans (ScanTableFrameSet): the code consistency fills only near what stands on
// the table, growing from the pixels whose points stand on it — on scene 0 of the
// procedural evaluation with seed 301, the points standing on the table are those of the
// whole-image consistency within 0.5%, while most of its fills (those on the table plane)
// are not made: 19.2k of its 73.5k (30.2k when the fills grew from every decoded pixel
// near the objects, before 2026-12-07; standing points 271,794 and 271,796 of 271,796); a
// plain map decoded beforehand (the live loop's way) gives the same cloud, and without
// consistency the scan is the usual one.
TEST(TableScan, FillsOnlyNearWhatStandsOnTheTable) {
  const SourceScan scan = EvaluationTableScene(301, 0);
  // The source gives no range band from the scene's truth (a live rig has none): the
  // tabletop path runs with the default band.
  EXPECT_FALSE(scan.band.has_value());
  const ScanOptions scan_options;
  const Triangulator triangulator(scan.calibration, scan_options.triangulation);
  const DecoderOptions& options = scan_options.decoder;
  const TableSegmentationOptions segmentation;
  const ScanResult whole = ScanFrameSet(scan.frames, triangulator, options);
  const ScanResult table = ScanTableFrameSet(scan.frames, triangulator, options, segmentation);
  CorrespondenceMap plain = Decode(scan.frames, PlainTableDecoderOptions(options));
  const double plain_valid = static_cast<double>(plain.CountValid());
  const double whole_fills = static_cast<double>(whole.correspondences.CountValid()) - plain_valid;
  const double table_fills = static_cast<double>(table.correspondences.CountValid()) - plain_valid;

  const TablePlane plane = FindTablePlane(whole.triangulation.cloud, segmentation);
  ASSERT_TRUE(plane.found);
  const auto standing = [&](const PointCloud& cloud) {
    int count = 0;
    for (const Eigen::Vector3f& p : cloud.points) {
      const float h = plane.Height(p);
      count += h > segmentation.min_height && h <= segmentation.max_height;
    }
    return count;
  };
  const int whole_standing = standing(whole.triangulation.cloud);
  const int table_standing = standing(table.triangulation.cloud);
  std::printf("fills: whole image %.0f, tabletop %.0f; points standing on the table %d / %d\n",
              whole_fills, table_fills, whole_standing, table_standing);
  ASSERT_GT(whole_fills, 10000.0);
  EXPECT_LT(table_fills, 0.3 * whole_fills);
  EXPECT_GT(whole_standing, 20000);
  EXPECT_NEAR(table_standing, whole_standing, 0.005 * whole_standing);

  const ScanResult given =
      ScanTableFrameSet(scan.frames, triangulator, options, segmentation, &plain, 0.0);
  ASSERT_EQ(given.triangulation.cloud.size(), table.triangulation.cloud.size());
  EXPECT_TRUE(given.triangulation.cloud.points == table.triangulation.cloud.points);

  DecoderOptions no_consistency = options;
  no_consistency.consistency.enabled = false;
  const ScanResult usual = ScanFrameSet(scan.frames, triangulator, no_consistency);
  const ScanResult same = ScanTableFrameSet(scan.frames, triangulator, no_consistency, segmentation);
  ASSERT_EQ(usual.triangulation.cloud.size(), same.triangulation.cloud.size());
  EXPECT_TRUE(usual.triangulation.cloud.points == same.triangulation.cloud.points);
}

// `sope eval --table` on a database of meshes in other units than metres (millimetres):
// each scene shows a mesh scaled as build-db scaled it, so the database's model lies on the
// table at its size and is found there (before, the command refused such a database, and
// the scenes would have kept the file's units: objects a thousand times too large).
// A mug and a bottle written in millimetres into `models`; their paths.
std::vector<std::string> WriteMillimetreModels(const std::string& models) {
  fs::create_directories(models);
  std::vector<std::string> meshes;
  for (const auto& [cls, seed] : {std::pair{ObjectClass::kMug, 3}, {ObjectClass::kBottle, 5}}) {
    TriangleMesh mesh = MakeObject(cls, seed);
    mesh.Transform(1000.0, Eigen::Vector3d::Zero());  // millimetres
    meshes.push_back(models + "/" + ToString(cls) + ".obj");
    WriteMesh(meshes.back(), mesh);
  }
  return meshes;
}

// `sope eval --table` of the meshes on 2 scenes of both: every object found, of the right
// model, posed within ADD-S < 10% of the (scaled) diameter.
TableEvalSummary ExpectBothFoundOnTwoTables(const Database& db,
                                            const std::vector<std::string>& meshes,
                                            const std::string& out_dir = "") {
  TableEvalOptions options;
  options.meshes = meshes;
  options.scenes = 2;
  options.min_objects = options.max_objects = 2;
  options.clutter = 0;
  const TableEvalSummary summary = RunTableEvaluation(db, options, out_dir);
  std::printf("%s", summary.Markdown().c_str());
  EXPECT_EQ(summary.known, 4);
  EXPECT_EQ(summary.correct, 4);
  EXPECT_EQ(summary.detections, 4);
  return summary;
}

TEST(TableEvaluation, MeshesInMillimetresAreScaledAsTheDatabaseScaledThem) {
  const testing::ScratchDir scratch;
  const std::vector<std::string> meshes = WriteMillimetreModels(scratch.File("models"));
  DatabaseOptions db_options = DatabaseOptions::Preset("sope");
  db_options.views_per_model = 60;
  WriteDatabase(scratch.File("mm.sopedb"), BuildDatabase(scratch.File("models"), db_options));
  const std::unique_ptr<Database> db = Database::Open(scratch.File("mm.sopedb"));
  for (const ModelRecord& model : db->models()) {
    EXPECT_LT(model.scale, 0.01) << model.name << ": the database should have scaled it";
    EXPECT_NE(model.scale, 0.001) << model.name << ": guessed, not given";
  }
  ExpectBothFoundOnTwoTables(*db, meshes);
}

// The same meshes with their unit given (build-db --units mm): the database's models have
// the objects' real size, the evaluation's scenes show them at that size (scaled by the
// unit the database records, not by the guess: with the guess the scenes' objects would be
// 0.25 m across against models of ~0.1–0.2 m, and not found).
TEST(TableEvaluation, MeshesOfAGivenUnitKeepTheirRealSize) {
  const testing::ScratchDir scratch;
  const std::vector<std::string> meshes = WriteMillimetreModels(scratch.File("models"));
  DatabaseOptions db_options = DatabaseOptions::Preset("sope");
  db_options.views_per_model = 60;
  db_options.size.mesh_unit = 0.001;
  WriteDatabase(scratch.File("mm.sopedb"), BuildDatabase(scratch.File("models"), db_options));
  const std::unique_ptr<Database> db = Database::Open(scratch.File("mm.sopedb"));
  EXPECT_EQ(db->options().size.mesh_unit, 0.001);
  for (const ModelRecord& model : db->models()) {
    const TriangleMesh original =
        MakeObject(model.class_name == "mug" ? ObjectClass::kMug : ObjectClass::kBottle,
                   model.class_name == "mug" ? 3 : 5);
    EXPECT_EQ(model.scale, 0.001) << model.name;
    // The model's diameter is the procedural object's own (metres), within the builder's
    // vertex-sampled estimate.
    EXPECT_NEAR(model.diameter, original.BoundingDiagonal(), 0.25 * original.BoundingDiagonal())
        << model.name;
  }
  ExpectBothFoundOnTwoTables(*db, meshes);
}

// A database built from DIR/<group>/<model>.obj calls every model's class <group> (build-db:
// the class is the folder); the scenes `sope eval --table` draws from its models' files name
// each object as the database names its model. Before, an object's class came from its
// file's name alone ("mug", against the database's "household"): no detection counted as
// right, recall 0% on a database of ../shared/data/meshes (folders ycb/ and classic/).
TEST(TableEvaluation, ObjectsAreNamedAsTheDatabaseNamesTheirModels) {
  const testing::ScratchDir scratch;
  const std::string group = scratch.File("models/household");
  fs::create_directories(group);
  for (const auto& [cls, seed] : {std::pair{ObjectClass::kMug, 3}, {ObjectClass::kBottle, 5}}) {
    WriteMesh(group + "/" + ToString(cls) + ".obj", MakeObject(cls, seed));
  }
  DatabaseOptions db_options = DatabaseOptions::Preset("sope");
  db_options.views_per_model = 60;
  WriteDatabase(scratch.File("grouped.sopedb"), BuildDatabase(scratch.File("models"), db_options));
  const std::unique_ptr<Database> db = Database::Open(scratch.File("grouped.sopedb"));
  std::vector<std::string> meshes;
  for (const ModelRecord& model : db->models()) {
    EXPECT_EQ(model.class_name, "household") << model.name;
    meshes.push_back(model.source_path);
  }
  TableObjectSpec spec;
  spec.spec = meshes.front();
  NameAsInDatabase(*db, &spec);
  EXPECT_EQ(spec.class_name, "household");
  EXPECT_EQ(spec.model, db->model(0).name);
  // `sope eval --table` with its default pool (every model file of the database).
  const TableEvalSummary summary =
      ExpectBothFoundOnTwoTables(*db, meshes, scratch.File("eval"));
  // The per-class figures and the confusion (rows true, columns detected) say the same.
  ASSERT_EQ(summary.per_class.size(), 1u);
  EXPECT_EQ(summary.per_class.at("household").known, 4);
  EXPECT_EQ(summary.per_class.at("household").correct, 4);
  EXPECT_EQ(summary.per_class.at("household").class_correct, 4);
  ASSERT_EQ(summary.confusion.size(), 1u);
  EXPECT_EQ(summary.confusion.begin()->first,
            std::make_pair(std::string("household"), std::string("household")));
  EXPECT_EQ(summary.confusion.begin()->second, 4);
  const cv::Mat confusion = ReadImage(scratch.File("eval/confusion.png"));
  EXPECT_GT(confusion.cols, 100);
  const nlohmann::json report =
      nlohmann::json::parse(ReadFileToString(scratch.File("eval/report.json"), "report"));
  EXPECT_EQ(report.at("per_class").at("household").at("correct"), 4);
  EXPECT_EQ(report.at("confusion").size(), 1u);
}

TEST(PipelineOptions, BadValuesAreNamed) {
  ScanAndRecogniseOptions options;
  options.max_scans = 0;
  ExpectErrorNaming([&] { options.Check(); }, "number of scans");
  options.max_scans = 1;
  options.min_range = 0.5;
  options.max_range = 0.4;
  ExpectErrorNaming([&] { options.Check(); }, "near end (0.5 m)");
  RecognitionSceneOptions scenes;
  ExpectErrorNaming([&] { RestrictScenesToObject("teapot", &scenes); }, "teapot");
  ExpectErrorNaming([&] { RestrictScenesToObject("mug:12x", &scenes); }, "mug:12x");
  RestrictScenesToObject("bottle:7", &scenes);
  ASSERT_EQ(scenes.classes.size(), 1u);
  EXPECT_EQ(scenes.classes[0], ObjectClass::kBottle);
  EXPECT_EQ(scenes.instance_seed_base, 7u);
  EXPECT_EQ(scenes.instance_count, 1);
}

}  // namespace
}  // namespace sope
