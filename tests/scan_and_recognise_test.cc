// Scan and recognise end to end without hardware (issue 5): the virtual rig's camera films
// what the virtual projector display shows, a RigSession captures the pattern sequence into
// a frame set, it is decoded and triangulated into a cloud, the range band cuts away the
// backdrop, and the recogniser names the object and estimates its pose — checked against
// the simulator's ground truth for objects of five classes in random poses. Then the
// `sope scan-and-recognise` command line: one virtual scan with --out and --json, the
// default (cached) database, and bad inputs.
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "calibration/scan.h"
#include "capture/rig_session.h"
#include "core/file_util.h"
#include "core/frame_set.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rig_calibration.h"
#include "core/statistics.h"
#include "recogniser/database.h"
#include "recogniser/pose_metrics.h"
#include "recogniser/recogniser.h"
#include "recogniser/tools/database_builder.h"
#include "recogniser/tools/scan_recognition.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_camera.h"
#include "tests/test_support.h"

namespace sope {
namespace {

namespace fs = std::filesystem;

// The database: two instances (seeds 0, 1) of five classes, 80 viewpoints each.
const std::vector<ObjectClass> kClasses = {ObjectClass::kMug, ObjectClass::kBottle,
                                           ObjectClass::kBowl, ObjectClass::kBox,
                                           ObjectClass::kVase};
constexpr int kInstances = 2;
constexpr int kViews = 80;

class ScanAndRecognise : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir();
    const std::string models = scratch_->File("models");
    WriteProceduralModels(models, kInstances, 0);
    for (ObjectClass cls : AllObjectClasses()) {
      if (std::find(kClasses.begin(), kClasses.end(), cls) == kClasses.end()) {
        fs::remove_all(models + "/" + ToString(cls));
      }
    }
    DatabaseOptions options = DatabaseOptions::Preset("sope");
    options.views_per_model = kViews;
    BuildSummary summary;
    WriteDatabase(db_path(), BuildDatabase(models, options, {}, &summary));
    std::printf("database: %s\n", summary.BriefReport().c_str());
    db_ = Database::Open(db_path()).release();
  }
  static void TearDownTestSuite() {
    delete db_;
    delete scratch_;
  }
  static std::string db_path() { return scratch_->File("db.sopedb"); }

  static testing::ScratchDir* scratch_;
  static Database* db_;
};
testing::ScratchDir* ScanAndRecognise::scratch_ = nullptr;
Database* ScanAndRecognise::db_ = nullptr;

TEST_F(ScanAndRecognise, VirtualRigLoopRecognisesClassAndPose) {
  const RigCalibration calibration = DefaultRigCalibration();
  // Scenes: the database's own instances (so the true model frame is the recognised
  // model's and the pose error is well defined), a uniformly random rotation, 0.5–0.62 m
  // (farther for the large ones), before a backdrop the range band removes.
  RecognitionSceneOptions scene_options;
  scene_options.classes = kClasses;
  scene_options.instance_seed_base = 0;
  scene_options.instance_count = kInstances;
  constexpr int kScenes = 8;
  VirtualCameraOptions camera;
  camera.delay_frames = 2;
  camera.readout_jitter = 0.5 * camera.frame_period;
  RecognitionScene scene = MakeRecognitionScene(1, calibration.camera, scene_options);
  VirtualLiveRig live = MakeVirtualLiveRig(calibration, scene.scene, {}, camera);
  RigSession session(*live.display, *live.camera);
  PatternOptions patterns;
  patterns.projector_width = calibration.projector.width;
  patterns.projector_height = calibration.projector.height;
  const std::vector<Pattern> sequence = GeneratePatterns(patterns);
  const Triangulator triangulator(calibration);
  const Recogniser recogniser(*db_);

  int correct = 0;
  std::vector<std::string> classes_seen;
  std::vector<double> rotation_errors, center_errors, adds_fractions;
  for (int k = 0; k < kScenes; ++k) {
    if (k > 0) {
      scene = MakeRecognitionScene(1 + k, calibration.camera, scene_options);
      live.rig->SetScene(scene.scene);
    }
    const FrameSet frames = session.Capture(sequence);
    const ScanRecognition result = RecogniseFrameSet(frames, triangulator, DecoderOptions(),
                                                     scene.segmentation, recogniser, {});
    // The segmentation kept the object only: every kept point is closer than the backdrop.
    ASSERT_GT(result.object.size(), 5000u);
    for (const Eigen::Vector3f& p : result.object.points) {
      ASSERT_LT(p.norm(), scene.backdrop_distance - 0.05);
    }
    ASSERT_FALSE(result.recognition.empty());
    const Suggestion& best = result.recognition.best();
    const std::string truth_class = ToString(scene.object_class);
    classes_seen.push_back(truth_class);
    std::printf("scene %d: %s, %zu object points -> %s (%s) score %.2f", k,
                scene.Description().c_str(), result.object.size(), best.class_name.c_str(),
                best.model_name.c_str(), best.score);
    if (best.class_name != truth_class) {
      std::printf("  WRONG CLASS\n");
      continue;
    }
    ++correct;
    // Rotation modulo the symmetry, bounding-box centre, ADD-S (recogniser/pose_metrics.h).
    const PoseComparison error =
        ComparePoses(best.cam_from_model, scene.cam_from_model, scene.mesh);
    const double rotation_error = error.rotation_error_deg;
    const double center_error = error.center_error_m;
    const double diameter = error.diameter_m;
    const double adds = error.adds_m;
    std::printf("; rotation error %.2f° (mod symmetry), centre %.2f mm, ADD-S %.2f mm (%.2f%% "
                "of %.0f mm)\n",
                rotation_error, 1e3 * center_error, 1e3 * adds, 100 * adds / diameter,
                1e3 * diameter);
    rotation_errors.push_back(rotation_error);
    center_errors.push_back(center_error);
    adds_fractions.push_back(adds / diameter);
    // A correct pose: ADD-S within 10% of the diameter (Hinterstoisser et al.'s criterion)
    // and the object's centre within 1 cm.
    EXPECT_LT(adds / diameter, 0.10) << scene.Description();
    EXPECT_LT(center_error, 0.010) << scene.Description();
  }
  std::printf("%d scenes: class correct %d; median rotation error %.2f°, median centre error "
              "%.2f mm, median ADD-S %.2f%% of the diameter\n",
              kScenes, correct, Median(rotation_errors), 1e3 * Median(center_errors),
              100 * Median(adds_fractions));
  std::sort(classes_seen.begin(), classes_seen.end());
  EXPECT_GE(std::unique(classes_seen.begin(), classes_seen.end()) - classes_seen.begin(), 3)
      << "at least three classes scanned";
  // One miss allowed: a mug whose handle is hidden is a vase-like cylinder from that side.
  EXPECT_GE(correct, kScenes - 1);
  EXPECT_LT(Median(rotation_errors), 3.0);
  EXPECT_LT(Median(center_errors), 0.002);
}

TEST(ScanRecognitionScene, SegmentationBandSeparatesObjectAndBackdrop) {
  const CameraModel camera = DefaultRigCalibration().camera;
  for (uint64_t seed = 0; seed < 40; ++seed) {
    const RecognitionScene scene = MakeRecognitionScene(seed, camera);
    ASSERT_EQ(scene.scene.objects.size(), 2u);
    // Every vertex of the object inside the band, the backdrop beyond it.
    double farthest = 0.0;
    for (const Eigen::Vector3f& v : scene.mesh.vertices) {
      farthest = std::max(farthest, (scene.cam_from_model * v.cast<double>()).norm());
    }
    EXPECT_LT(farthest, scene.segmentation.max_range) << scene.Description();
    EXPECT_GT(scene.backdrop_distance, scene.segmentation.max_range + 0.05);
    EXPECT_GE(scene.instance_seed, 1000u);  // unseen instances by default
  }
  // Deterministic.
  const RecognitionScene a = MakeRecognitionScene(7, camera), b = MakeRecognitionScene(7, camera);
  EXPECT_EQ(a.instance_seed, b.instance_seed);
  EXPECT_TRUE(a.cam_from_model.rotation.isApprox(b.cam_from_model.rotation));
}

// ---------------------------------------------------------------------------------------
// The command line.

using SopeRun = testing::CommandRun;
using testing::Quote;

// Runs `prefix sope arguments` through the shell.
SopeRun Sope(const std::string& arguments, const testing::ScratchDir& scratch,
             const std::string& prefix = "") {
  return testing::RunCommand(SOPE_BINARY, arguments, scratch, prefix);
}

void ExpectOneLineError(const SopeRun& run, const std::string& needle) {
  EXPECT_NE(run.exit_code, 0);
  EXPECT_EQ(std::count(run.err.begin(), run.err.end(), '\n'), 1) << run.err;
  EXPECT_EQ(run.err.rfind("sope scan-and-recognise: error: ", 0), 0u) << run.err;
  EXPECT_NE(run.err.find(needle), std::string::npos) << "expected '" << needle << "' in: "
                                                     << run.err;
}

// The documented fields of one result line (DESIGN.md "Recognition result" + the scan's).
void ExpectResultFields(const nlohmann::json& j) {
  for (const char* key : {"class", "model", "score", "view", "pose", "refined", "timing_ms",
                          "candidates", "scan", "ground_truth"}) {
    EXPECT_TRUE(j.contains(key)) << key << " in " << j.dump();
  }
  EXPECT_TRUE(j.at("view").contains("theta_deg"));
  EXPECT_TRUE(j.at("view").contains("phi_deg"));
  ASSERT_EQ(j.at("pose").at("rotation").size(), 3u);
  for (const auto& row : j.at("pose").at("rotation")) EXPECT_EQ(row.size(), 3u);
  EXPECT_EQ(j.at("pose").at("translation").size(), 3u);
  for (const char* stage : {"capture", "decode", "triangulate", "segment", "recognise",
                            "frame_to_result", "preprocess", "features", "coarse", "fine",
                            "pose"}) {
    EXPECT_TRUE(j.at("timing_ms").contains(stage)) << stage;
  }
  EXPECT_GT(j.at("scan").at("object_points").get<int>(), 1000);
  EXPECT_GT(j.at("scan").at("points").get<int>(), j.at("scan").at("object_points").get<int>())
      << "the backdrop was cut away";
  EXPECT_TRUE(j.at("ground_truth").contains("class"));
  EXPECT_TRUE(j.at("ground_truth").contains("class_correct"));
}

// The command-line tests need a database, not accuracy: three classes, one instance (seed 0)
// each, 40 views (a couple of seconds to build).
const std::vector<ObjectClass> kCliClasses = {ObjectClass::kMug, ObjectClass::kBottle,
                                              ObjectClass::kBowl};

class ScanAndRecogniseCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir();
    const std::string models = scratch_->File("models");
    WriteProceduralModels(models, 1, 0);
    for (ObjectClass cls : AllObjectClasses()) {
      if (std::find(kCliClasses.begin(), kCliClasses.end(), cls) == kCliClasses.end()) {
        fs::remove_all(models + "/" + ToString(cls));
      }
    }
    DatabaseOptions options = DatabaseOptions::Preset("sope");
    options.views_per_model = 40;
    WriteDatabase(db_path(), BuildDatabase(models, options));
  }
  static void TearDownTestSuite() { delete scratch_; }
  static std::string db_path() { return scratch_->File("db.sopedb"); }
  static testing::ScratchDir* scratch_;
};
testing::ScratchDir* ScanAndRecogniseCli::scratch_ = nullptr;

TEST_F(ScanAndRecogniseCli, VirtualScanWritesCloudOverlayAndJson) {
  testing::ScratchDir scratch;
  const std::string out = scratch.File("out");
  const SopeRun run = Sope("scan-and-recognise --virtual --db " + db_path() +
                               " --scans 1 --seed 3 --json --out " + Quote(out),
                           scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  ASSERT_EQ(std::count(run.out.begin(), run.out.end(), '\n'), 1) << run.out;
  const nlohmann::json j = nlohmann::json::parse(run.out);
  ExpectResultFields(j);
  // The database has mugs, bottles and bowls only: the scene is one of them (an unseen
  // instance).
  EXPECT_NE(std::find(kCliClasses.begin(), kCliClasses.end(),
                      ObjectClassFromString(j.at("ground_truth").at("class"))),
            kCliClasses.end());
  EXPECT_GE(j.at("ground_truth").at("instance_seed").get<uint64_t>(), 1000u);
  // results.jsonl holds the same line; the files exist and load.
  EXPECT_EQ(ReadFileToString(out + "/results.jsonl", "results"), run.out);
  const cv::Mat overlay = ReadImage(out + "/scan_0000_overlay.png");
  EXPECT_EQ(overlay.cols, 1280);
  EXPECT_EQ(overlay.rows, 720);
  EXPECT_EQ(overlay.channels(), 3);
  const PointCloud cloud = ReadPointCloud(out + "/scan_0000.ply");
  const PointCloud object = ReadPointCloud(out + "/scan_0000_object.ply");
  EXPECT_EQ(static_cast<int>(cloud.size()), j.at("scan").at("points").get<int>());
  EXPECT_EQ(static_cast<int>(object.size()), j.at("scan").at("object_points").get<int>());
  for (const auto& entry : fs::directory_iterator(out)) {
    EXPECT_EQ(entry.path().filename().string().find(".tmp"), std::string::npos) << entry.path();
  }

  // Another scan appends its line (and prints a human-readable one).
  const SopeRun more = Sope("scan-and-recognise --virtual --db " + db_path() +
                                " --scans 1 --seed 10 --quiet --out " + Quote(out),
                            scratch);
  ASSERT_EQ(more.exit_code, 0) << more.err;
  EXPECT_EQ(std::count(more.out.begin(), more.out.end(), '\n'), 1) << more.out;
  EXPECT_EQ(more.out.rfind("scan 0: ", 0), 0u) << more.out;
  const std::string lines = ReadFileToString(out + "/results.jsonl", "results");
  EXPECT_EQ(std::count(lines.begin(), lines.end(), '\n'), 2);
}

TEST_F(ScanAndRecogniseCli, ReplaysRecordedFrameSets) {
  testing::ScratchDir scratch;
  // A recording of the built-in mug scene, then scan-and-recognise on it twice (two --frames).
  const SopeRun record = Sope("scan --camera virtual --record " + scratch.File("rec") + " --out " +
                                  scratch.File("c.ply") + " --quiet",
                              scratch);
  ASSERT_EQ(record.exit_code, 0) << record.err;
  const SopeRun run = Sope("scan-and-recognise --frames " + scratch.File("rec") + " " +
                               scratch.File("rec") + " --db " + db_path() +
                               " --max-range 0.72 --json",
                           scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  std::istringstream lines(run.out);
  std::string line;
  int count = 0;
  while (std::getline(lines, line)) {
    const nlohmann::json j = nlohmann::json::parse(line);
    // The demo scene is the mug of seed 0, a database model, 0.6 m away before a backdrop
    // at 0.75 m; the band [0.05, 0.72] m keeps the mug.
    EXPECT_EQ(j.at("class"), "mug") << line;
    EXPECT_FALSE(j.contains("ground_truth"));
    EXPECT_EQ(j.at("scan").at("source"), scratch.File("rec"));
    ++count;
  }
  EXPECT_EQ(count, 2);
}

// Issue 10: phase-shift sequences through scan-and-recognise — a recording of the built-in
// mug scene in three periods on both axes (ray–ray), replayed, and the virtual rig scanning
// with Gray + phase on x alone (ray–plane).
TEST_F(ScanAndRecogniseCli, PhaseShiftSequencesRecordedAndVirtual) {
  testing::ScratchDir scratch;
  const SopeRun record = Sope("scan --camera virtual --code phase --periods 1024,128,16 "
                              "--record " + scratch.File("rec") + " --out " +
                                  scratch.File("c.ply") + " --quiet",
                              scratch);
  ASSERT_EQ(record.exit_code, 0) << record.err;
  const FrameSetManifest manifest = ReadFrameSetManifest(scratch.File("rec"));
  ASSERT_FALSE(manifest.frames.empty());
  const auto phase_frames =
      std::count_if(manifest.frames.begin(), manifest.frames.end(),
                    [](const FrameInfo& f) { return f.role == FrameRole::kPhase; });
  EXPECT_EQ(phase_frames, 2 * 3 * 4);  // x and y, three periods, four steps
  for (const FrameInfo& frame : manifest.frames) EXPECT_NE(frame.role, FrameRole::kCode);
  const SopeRun replay = Sope("scan-and-recognise --frames " + scratch.File("rec") + " --db " +
                                  db_path() + " --max-range 0.72 --json",
                              scratch);
  ASSERT_EQ(replay.exit_code, 0) << replay.err;
  const nlohmann::json j = nlohmann::json::parse(replay.out);
  EXPECT_EQ(j.at("class"), "mug") << replay.out;  // the demo scene's mug, a database model
  EXPECT_GT(j.at("scan").at("object_points").get<int>(), 5000);

  const SopeRun virtual_scan = Sope("scan-and-recognise --virtual --db " + db_path() +
                                        " --scans 1 --seed 3 --code gray+phase --period 16 "
                                        "--axes x --json",
                                    scratch);
  ASSERT_EQ(virtual_scan.exit_code, 0) << virtual_scan.err;
  const nlohmann::json v = nlohmann::json::parse(virtual_scan.out);
  ExpectResultFields(v);  // with the ground truth of the virtual scene
  EXPECT_GT(v.at("scan").at("object_points").get<int>(), 5000);
}

TEST_F(ScanAndRecogniseCli, BadInputsAreOneClearLine) {
  testing::ScratchDir scratch;
  WriteRigCalibration(scratch.File("rig.yaml"), DefaultRigCalibration());
  ExpectOneLineError(Sope("scan-and-recognise --camera /dev/video99 --calibration " +
                              scratch.File("rig.yaml") + " --db " + db_path(),
                          scratch),
                     "camera /dev/video99: no such device");
  ExpectOneLineError(Sope("scan-and-recognise --camera /dev/video99 --db " + db_path(), scratch),
                     "--camera /dev/video99 needs --calibration");
  ExpectOneLineError(Sope("scan-and-recognise --camera /dev/video99", scratch),
                     "--db DB.sopedb is required");
  ExpectOneLineError(
      Sope("scan-and-recognise --virtual --db " + scratch.File("missing.sopedb"), scratch),
      "missing.sopedb");
  WriteFileAtomic(scratch.File("bad.sopedb"), "not a database");
  ExpectOneLineError(Sope("scan-and-recognise --db " + scratch.File("bad.sopedb"), scratch),
                     "bad.sopedb");
  ExpectOneLineError(
      Sope("scan-and-recognise --frames " + scratch.File("none") + " --db " + db_path(), scratch),
      "none");
  ExpectOneLineError(Sope("scan-and-recognise --frames " + scratch.File("none") + " --scans 2 --db " +
                              db_path(),
                          scratch),
                     "--scans/--continuous apply to live sources");
  ExpectOneLineError(Sope("scan-and-recognise --virtual --object teapot --db " + db_path(), scratch),
                     "teapot");
  // A range band with nothing in it: the scan runs, the segmentation says what is left.
  ExpectOneLineError(Sope("scan-and-recognise --virtual --quiet --max-range 0.2 --db " + db_path(),
                          scratch),
                     "segmentation left 0 of");
  // No cache directory for the default database.
  ExpectOneLineError(Sope("scan-and-recognise --virtual", scratch, "env -u HOME -u XDG_CACHE_HOME"),
                     "no cache directory");
  EXPECT_FALSE(fs::exists(scratch.File("out")));
}

// A database of mesh files in a folder of their own (build-db: the folder is their class,
// "kitchen"), none of them a procedural class: `--virtual --table --mesh FILE ...` puts
// those files on the table (before, the command refused a database without procedural
// classes), and the ground truth names each object as the database names its model.
TEST(ScanAndRecogniseMeshTable, ObjectsOfAMeshDatabaseAreNamedAsInIt) {
  testing::ScratchDir scratch;
  const std::string kitchen = scratch.File("models/kitchen");
  fs::create_directories(kitchen);
  WriteMesh(kitchen + "/cup.obj", MakeObject(ObjectClass::kMug, 3));
  WriteMesh(kitchen + "/flask.obj", MakeObject(ObjectClass::kBottle, 5));
  DatabaseOptions options = DatabaseOptions::Preset("sope");
  options.views_per_model = 60;
  WriteDatabase(scratch.File("db.sopedb"), BuildDatabase(scratch.File("models"), options));
  const SopeRun run = Sope("scan-and-recognise --virtual --table --mesh " +
                               Quote(kitchen + "/cup.obj") + " --mesh " +
                               Quote(kitchen + "/flask.obj") + " --db " +
                               Quote(scratch.File("db.sopedb")) + " --scans 1 --json --quiet",
                           scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const nlohmann::json j = nlohmann::json::parse(run.out);
  const nlohmann::json& truth = j.at("ground_truth").at("objects");
  ASSERT_EQ(truth.size(), 2u) << j.dump();
  for (const nlohmann::json& object : truth) {
    EXPECT_EQ(object.at("class"), "kitchen") << object.dump();
    EXPECT_TRUE(object.at("correct").get<bool>()) << object.dump();
  }
}

TEST(ScanAndRecogniseDefaultDb, IsBuiltOnceAndCached) {
  // The first --virtual run without --db builds the default database (10 classes × 16
  // instances × 100 views) into $XDG_CACHE_HOME/sope; the second finds it there.
  testing::ScratchDir scratch;
  const std::string env = "env XDG_CACHE_HOME=" + Quote(scratch.File("cache"));
  const SopeRun first = Sope("scan-and-recognise --scans 1 --json", scratch, env);
  ASSERT_EQ(first.exit_code, 0) << first.err;
  EXPECT_NE(first.err.find("building the default database"), std::string::npos) << first.err;
  ExpectResultFields(nlohmann::json::parse(first.out));
  const SopeRun second = Sope("scan-and-recognise --scans 1 --seed 2", scratch, env);
  ASSERT_EQ(second.exit_code, 0) << second.err;
  EXPECT_NE(second.err.find("(cached)"), std::string::npos) << second.err;
  EXPECT_EQ(second.err.find("building"), std::string::npos) << second.err;
  std::printf("first run (builds the database):\n%s\n", first.err.c_str());
}

// `sope calibrate --camera virtual`: the virtual rig has no board to hold up, so the command
// scripts the board poses; each is captured live through the rig session, recorded, and
// calibrated as with --frames. Checked against the virtual rig's true calibration.
TEST(LiveCalibrateCli, VirtualScriptedBoardRecoversTheRig) {
  testing::ScratchDir scratch;
  const SopeRun run = Sope("calibrate --camera virtual --board 9x6x0.025 --views 5 --quiet --out " +
                               scratch.File("cal.yaml"),
                           scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  for (int k = 0; k < 5; ++k) {
    EXPECT_TRUE(fs::exists(scratch.File("cal.views/view_00" + std::to_string(k) + "/frames.json")));
  }
  const RigCalibration truth = ReadRigCalibration(scratch.File("cal.views/calibration_true.yaml"));
  const RigCalibration estimate = ReadRigCalibration(scratch.File("cal.yaml"));
  // Five views of a 9x6 board: focal lengths within 0.5%, principal points within 5 px, the
  // baseline within 1% (the --frames calibration test has the precise figures).
  EXPECT_NEAR(estimate.camera.fx(), truth.camera.fx(), 0.005 * truth.camera.fx());
  EXPECT_NEAR(estimate.projector.fx(), truth.projector.fx(), 0.005 * truth.projector.fx());
  EXPECT_NEAR(estimate.camera.cx(), truth.camera.cx(), 5.0);
  EXPECT_NEAR(estimate.camera.cy(), truth.camera.cy(), 5.0);
  const double baseline = truth.proj_from_cam.translation.norm();
  EXPECT_NEAR(estimate.proj_from_cam.translation.norm(), baseline, 0.01 * baseline);
  std::printf("[live calibrate, 5 scripted views] fx %.2f (true %.2f), projector fx %.2f (true "
              "%.2f), baseline %.4f m (true %.4f)\n",
              estimate.camera.fx(), truth.camera.fx(), estimate.projector.fx(),
              truth.projector.fx(), estimate.proj_from_cam.translation.norm(), baseline);
}

TEST(LiveCalibrateCli, BadLiveInputsAreOneClearLine) {
  testing::ScratchDir scratch;
  const auto expect = [](const SopeRun& run, const std::string& needle) {
    EXPECT_NE(run.exit_code, 0);
    EXPECT_EQ(std::count(run.err.begin(), run.err.end(), '\n'), 1) << run.err;
    EXPECT_EQ(run.err.rfind("sope calibrate: error: ", 0), 0u) << run.err;
    EXPECT_NE(run.err.find(needle), std::string::npos) << run.err;
  };
  const std::string out = " --board 9x6x0.025 --out " + scratch.File("cal.yaml");
  expect(Sope("calibrate --camera /dev/video99" + out, scratch), "needs --projector WxH");
  expect(Sope("calibrate --camera /dev/video99 --projector 1024x768 --camera-size 1280x720" + out,
              scratch),
         "camera /dev/video99: no such device");
  const SopeRun no_source = Sope("calibrate" + out, scratch);  // a usage error, as CLI11's
  EXPECT_EQ(no_source.exit_code, 2) << no_source.err;
  EXPECT_FALSE(fs::exists(scratch.File("cal.yaml")));
}

}  // namespace
}  // namespace sope
