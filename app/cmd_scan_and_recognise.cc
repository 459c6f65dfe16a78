// sope scan-and-recognise [--virtual | --camera /dev/videoN|virtual|replay:DIR | --frames DIR...]
//                         [--db DB.sopedb] [--calibration CAL.yaml] [--out DIR]
//                         [--scans N | --continuous] [--json]
// Scan (show the patterns, grab the frames), decode + triangulate, cut the cloud down to the
// object with a range band, recognise it and estimate its pose — once per scan.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/live_rig.h"
#include "app/pipeline_flags.h"
#include "calibration/scan.h"
#include "capture/rig_session.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/frame_set.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rig_calibration.h"
#include "recogniser/crc32c.h"
#include "recogniser/database.h"
#include "recogniser/database_builder.h"
#include "recogniser/pose_metrics.h"
#include "recogniser/recogniser.h"
#include "recogniser/scan_recognition.h"
#include "simulator/procedural_objects.h"
#include "recogniser/bop.h"
#include "simulator/virtual_camera.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

namespace fs = std::filesystem;

// The default database of --virtual: every procedural class, kDefaultDbInstances instances
// (seeds kDefaultDbSeed …), kDefaultDbViews Fibonacci viewpoints each, the "sope" preset.
constexpr int kDefaultDbInstances = 2;
constexpr int kDefaultDbViews = 100;
constexpr uint64_t kDefaultDbSeed = 0;
// Unseen instances for the virtual scenes start here (the database holds seeds 0 and 1).
constexpr uint64_t kUnseenSeedBase = 1000;
// Delivery jitter of the virtual camera, as `sope scan --camera virtual` (live_rig.cc).
constexpr double kVirtualJitter = 0.5;

double NowMs() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

std::string CacheRoot() {
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg) {
    return JoinPath(xdg, "sope");
  }
  const char* home = std::getenv("HOME");
  SOPE_CHECK(home && *home, "no cache directory for the default database: neither "
             "XDG_CACHE_HOME nor HOME is set (give --db DB.sopedb)");
  return JoinPath(JoinPath(home, ".cache"), "sope");
}

// The default database for --virtual, built on first use and cached under
// CACHE/virtual-db-<key>/ (models/ and db.sopedb; the key names everything that decides
// the contents). Returns the database path.
std::string DefaultVirtualDatabase() {
  DatabaseOptions options = DatabaseOptions::Preset("sope");
  options.layout = ViewpointLayout::kFibonacci;
  options.views_per_model = kDefaultDbViews;
  // The key changes with the version, the file format and every build option (a checksum
  // of their JSON), so a stale cache is never used.
  const std::string options_json = DatabaseOptionsToJson(options);
  const std::string key = fmt::format(
      "v{}-f{}-{}x{}-s{}-{}views-{:08x}", SOPE_VERSION, kDatabaseFormatVersion,
      AllObjectClasses().size(), kDefaultDbInstances, kDefaultDbSeed, kDefaultDbViews,
      Crc32c(options_json.data(), options_json.size()));
  const std::string dir = JoinPath(CacheRoot(), "virtual-db-" + key);
  const std::string db_path = JoinPath(dir, "db.sopedb");
  if (fs::exists(db_path)) {
    spdlog::info("database: {} (cached)", db_path);
    return db_path;
  }
  spdlog::info("building the default database (once; cached in {}): {} classes x {} "
               "procedural instances x {} views",
               dir, AllObjectClasses().size(), kDefaultDbInstances, kDefaultDbViews);
  const std::string models = JoinPath(dir, "models");
  // The meshes stay in the cache: the database names them (the overlay draws them).
  WriteProceduralModels(models, kDefaultDbInstances, kDefaultDbSeed);
  BuildSummary summary;
  DatabaseData data;
  {
    const std::vector<ModelSource> sources = ListModels(models);
    cli::Progress progress("building the database", sources.size() * kDefaultDbViews);
    data = BuildDatabase(sources, options, [&](int done, int) { progress.Update(done); },
                         &summary);
  }
  WriteDatabase(db_path, data);  // atomic: a half-built cache never exists
  spdlog::info("{} -> {}", summary.BriefReport(), db_path);
  return db_path;
}

// What the virtual rig really showed, for the JSON "ground_truth" and the report.
struct Truth {
  std::string class_name;
  uint64_t instance_seed = 0;
  TriangleMesh mesh;
  Rigid3d cam_from_model;
};

nlohmann::json PoseJson(const Rigid3d& pose) {
  nlohmann::json rotation = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) {
    rotation.push_back({pose.rotation(r, 0), pose.rotation(r, 1), pose.rotation(r, 2)});
  }
  return {{"rotation", rotation},
          {"translation", {pose.translation.x(), pose.translation.y(), pose.translation.z()}}};
}

// Ground truth and, for the right class, the pose errors: rotation modulo the true
// object's symmetry, the error of its bounding-box centre, and ADD-S of the true mesh
// under the estimated vs the true pose.
nlohmann::json TruthJson(const Truth& truth, const RecognitionResult& result, std::string* brief) {
  nlohmann::json j = {{"class", truth.class_name},
                      {"instance_seed", truth.instance_seed},
                      {"pose", PoseJson(truth.cam_from_model)}};
  const bool correct = !result.empty() && result.best().class_name == truth.class_name;
  j["class_correct"] = correct;
  *brief = fmt::format("truth {} (instance {})", truth.class_name, truth.instance_seed);
  if (!correct) return j;
  const Rigid3d& estimate = result.best().cam_from_model;
  const ModelSymmetry symmetry = DetectSymmetry(truth.mesh);
  const double rotation_error =
      SymmetricRotationErrorDeg(estimate.rotation, truth.cam_from_model.rotation, symmetry);
  Eigen::Vector3f lo, hi;
  truth.mesh.Bounds(&lo, &hi);
  const Eigen::Vector3d center = (0.5 * (lo + hi)).cast<double>();
  const double center_error = (estimate * center - truth.cam_from_model * center).norm();
  const double adds = AverageDistanceSymmetric(SampleSurface(truth.mesh, 10000), estimate,
                                               truth.cam_from_model);
  j["rotation_error_deg"] = rotation_error;
  j["center_error_m"] = center_error;
  j["adds_m"] = adds;
  j["diameter_m"] = truth.mesh.BoundingDiagonal();
  *brief += fmt::format(": rotation error {:.1f}° (mod symmetry), centre {:.1f} mm, ADD-S "
                        "{:.1f} mm",
                        rotation_error, 1e3 * center_error, 1e3 * adds);
  return j;
}

// The camera's white frame (or the first frame) for the overlay.
cv::Mat WhiteImage(const FrameSet& frames) {
  if (!frames.white_color.empty()) return frames.white_color;
  const std::optional<size_t> white = frames.manifest.Find(FrameRole::kWhite);
  return frames.images.at(white ? *white : 0);
}

cv::Mat Overlay(const FrameSet& frames, const RigCalibration& calibration, const Database& db,
                const RecognitionResult& result) {
  const cv::Mat white = WhiteImage(frames);
  if (result.empty()) return DrawRecognitionOverlay(white, calibration.camera,
                                                    std::vector<Eigen::Vector3f>{}, Rigid3d(),
                                                    "no suggestion");
  const Suggestion& best = result.best();
  const std::string label =
      fmt::format("{} {} {:.2f}", best.class_name, best.model_name, best.score);
  const ModelRecord& model = db.model(best.model);
  try {
    TriangleMesh mesh = ReadMesh(model.source_path);
    mesh.Transform(model.scale, Eigen::Vector3d::Zero());
    return DrawRecognitionOverlay(white, calibration.camera, mesh, best.cam_from_model, label);
  } catch (const Error& e) {
    spdlog::warn("overlay: {} — drawing the database view's points instead", e.what());
    return DrawRecognitionOverlay(white, calibration.camera, db.ViewCloud(best.view).points,
                                  best.cam_from_model, label);
  }
}

// Classes of the database that are procedural classes (the virtual scenes draw from these).
std::vector<ObjectClass> ProceduralClassesIn(const Database& db) {
  std::vector<ObjectClass> classes;
  for (const std::string& name : db.classes()) {
    for (ObjectClass cls : AllObjectClasses()) {
      if (ToString(cls) == name) classes.push_back(cls);
    }
  }
  return classes;
}

}  // namespace

int RunScanAndRecognise(int argc, char** argv) {
  CLI::App app{"Scan the object in front of the rig, recognise it and estimate its pose, once or "
               "continuously: capture the pattern sequence (or replay recorded frame sets), "
               "decode and triangulate, keep the points in a range band (the object, not the "
               "backdrop), recognise against a database. Without a source the virtual rig "
               "scans procedural household objects (unseen instances) in random poses before "
               "a backdrop, against a default database built on first use and cached in "
               "$XDG_CACHE_HOME/sope (or ~/.cache/sope).",
               "sope scan-and-recognise"};
  std::string camera, calibration_path, db_path, out_dir, object_spec, instances = "unseen";
  std::vector<std::string> frames_dirs;
  bool use_virtual = false, continuous = false, json = false, no_backdrop = false;
  int scans = 0, top = 4;
  uint64_t seed = 1;
  double min_range = -1.0, max_range = -1.0;
  cli::DecoderFlags decoder_flags;
  cli::TriangulationFlags triangulation_flags;
  cli::PatternFlags pattern_flags;
  cli::LiveRigFlags live_flags;
  cli::LoggingFlags logging;
  CLI::Option* virtual_option = app.add_flag(
      "--virtual", use_virtual,
      "Scan on the virtual rig: a procedural object in a random pose before a backdrop, a new "
      "one every scan (the default when no source is given)");
  CLI::Option* camera_option =
      app.add_option("--camera", camera,
                     "Capture live: /dev/videoN (V4L2 camera + projector window), virtual (the "
                     "virtual rig's built-in mug scene) or replay:DIR")
          ->excludes(virtual_option);
  app.add_option("--frames", frames_dirs, "Recorded frame sets, one scan each")
      ->excludes(virtual_option)
      ->excludes(camera_option);
  app.add_option("--db", db_path,
                 "Database (.sopedb, from sope build-db); default for the virtual rig: the "
                 "cached procedural database (10 classes x 2 instances x 100 views)");
  app.add_option("--calibration", calibration_path,
                 "Rig calibration YAML (--frames: default the one frames.json names; virtual: "
                 "default the virtual rig's true calibration)");
  app.add_option("--out", out_dir,
                 "Per scan: scan_NNNN.ply (the full cloud), scan_NNNN_object.ply (the "
                 "segmented cloud), scan_NNNN_overlay.png, and the JSON line appended to "
                 "results.jsonl");
  std::string bop_csv;
  std::vector<BopEstimate> bop_estimates;
  app.add_option("--bop-csv", bop_csv,
                 "Also write each scan's best estimate to a BOP challenge results CSV "
                 "(scene_id 1, im_id = scan index, obj_id = database model index + 1, t in mm, "
                 "time = frame to result in s), rewritten after every scan");
  CLI::Option* scans_option =
      app.add_option("--scans", scans, "Number of scans (live sources; default 1, or until "
                                       "Ctrl-C with --continuous)");
  app.add_flag("--continuous", continuous, "Scan again and again until Ctrl-C (or --scans N)");
  app.add_flag("--json", json, "Print one JSON object per scan (DESIGN.md recognition result "
                               "+ scan timings, and the ground truth on the virtual rig)");
  app.add_option("--top", top, "Number of suggestions")->capture_default_str();
  app.add_option("--min-range", min_range,
                 "Segmentation: keep points at least this far from the camera, metres "
                 "(default 0.05)");
  app.add_option("--max-range", max_range,
                 "Segmentation: keep points at most this far from the camera, metres (default: "
                 "--virtual: just before the scene's backdrop; --camera virtual 0.7; else 2)");
  auto* virtual_group = app.add_option_group("virtual scenes (--virtual)");
  virtual_group->add_option("--seed", seed, "Scene seed (scan i uses seed + i)")
      ->capture_default_str();
  virtual_group->add_option("--object", object_spec,
                            "Always this class (mug, bottle, ...; CLASS:SEED for one instance)");
  virtual_group
      ->add_option("--instances", instances,
                   "unseen (instances not in the database) or database (the default "
                   "database's own instances, seeds 0-1)")
      ->capture_default_str();
  virtual_group->add_flag("--no-backdrop", no_backdrop, "No backdrop behind the object");
  decoder_flags.Add(app);
  triangulation_flags.Add(app);
  auto* live_group = app.add_option_group("live capture (--camera, --virtual)");
  pattern_flags.Add(*live_group);
  live_flags.Add(*live_group);
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  // The source.
  const bool from_frames = !frames_dirs.empty();
  if (!from_frames && camera.empty()) use_virtual = true;
  SOPE_CHECK(!from_frames || (!continuous && scans_option->count() == 0),
             "--scans/--continuous apply to live sources; --frames scans each set once");
  SOPE_CHECK(scans_option->count() == 0 || scans >= 1, "--scans must be ≥ 1, got {}", scans);
  SOPE_CHECK(instances == "unseen" || instances == "database",
             "--instances must be unseen or database, got '{}'", instances);
  SOPE_CHECK(top >= 1, "--top must be ≥ 1, got {}", top);
  const bool virtual_rig = use_virtual || camera == "virtual";
  const int max_scans = from_frames ? static_cast<int>(frames_dirs.size())
                        : scans_option->count() > 0 ? scans
                        : continuous              ? -1
                                                  : 1;

  ScanOptions scan_options;
  scan_options.decoder = decoder_flags.ToOptions();
  scan_options.triangulation = triangulation_flags.ToOptions();
  scan_options.triangulation.num_threads = scan_options.decoder.num_threads;
  scan_options.Check();
  RecognitionOptions recognition_options;
  recognition_options.top_k = top;
  recognition_options.Check();

  // The database.
  if (db_path.empty()) {
    SOPE_CHECK(virtual_rig, "--db DB.sopedb is required (a default database exists only for "
               "the virtual rig)");
    db_path = DefaultVirtualDatabase();
  } else {
    SOPE_CHECK(instances == "unseen", "--instances database needs the default database (no "
               "--db)");
  }
  const std::unique_ptr<Database> db = Database::Open(db_path);
  const Recogniser recogniser(*db);

  // The rig.
  RigCalibration calibration;
  if (!from_frames) {
    SOPE_CHECK(!calibration_path.empty() || virtual_rig, "--camera {} needs --calibration "
               "CAL.yaml", camera);
    calibration = calibration_path.empty() ? DefaultRigCalibration()
                                           : ReadRigCalibration(calibration_path);
  }
  RecognitionSceneOptions scene_options;
  if (use_virtual) {
    scene_options.backdrop = !no_backdrop;
    if (!object_spec.empty()) {
      const size_t colon = object_spec.find(':');
      scene_options.classes = {ObjectClassFromString(object_spec.substr(0, colon))};
      if (colon != std::string::npos) {
        try {
          scene_options.instance_seed_base = std::stoull(object_spec.substr(colon + 1));
        } catch (const std::exception&) {
          throw Error(fmt::format("--object {}: the seed must be a number", object_spec));
        }
        scene_options.instance_count = 1;
      }
    } else {
      scene_options.classes = ProceduralClassesIn(*db);
      SOPE_CHECK(!scene_options.classes.empty(), "--virtual: the database {} holds no "
                 "procedural class (mug, bottle, ...) to put in front of the virtual rig",
                 db_path);
    }
    if (object_spec.find(':') == std::string::npos) {
      if (instances == "database") {
        scene_options.instance_seed_base = kDefaultDbSeed;
        scene_options.instance_count = kDefaultDbInstances;
      } else {
        scene_options.instance_seed_base = kUnseenSeedBase;
      }
    }
  }

  const cli::InterruptFlag interrupt;
  std::optional<cli::LiveRig> live;
  VirtualLiveRig virtual_live;
  std::unique_ptr<RigSession> session;
  std::vector<Pattern> sequence;
  std::optional<RecognitionScene> scene;
  std::string source = from_frames ? "frames" : use_virtual ? "virtual" : camera;
  if (!from_frames) {
    sequence = GeneratePatterns(
        pattern_flags.ToOptions(calibration.projector.width, calibration.projector.height));
    const RigSessionOptions session_options = live_flags.SessionOptions(interrupt.flag());
    if (use_virtual) {
      VirtualCameraOptions camera_options;
      camera_options.delay_frames = live_flags.virtual_delay_frames;
      camera_options.readout_jitter = kVirtualJitter * camera_options.frame_period;
      scene = MakeRecognitionScene(seed, calibration.camera, scene_options);
      virtual_live = MakeVirtualLiveRig(calibration, scene->scene, {}, camera_options);
      spdlog::info("virtual rig: {}; procedural objects before a backdrop",
                   virtual_live.camera->description());
      session = std::make_unique<RigSession>(*virtual_live.display, *virtual_live.camera,
                                             session_options);
    } else {
      live.emplace(cli::OpenLiveRig(camera, calibration, live_flags));
      session = std::make_unique<RigSession>(live->GetDisplay(), live->GetCamera(),
                                             session_options);
    }
  }

  std::unique_ptr<Triangulator> triangulator;  // per calibration (undistortion tables)
  int done = 0;
  for (int index = 0; max_scans < 0 || index < max_scans; ++index) {
    if (interrupt.flag()->load()) break;
    // 1. Capture (or load) the frame set.
    std::optional<Truth> truth;
    FrameSet frames;
    double capture_ms = 0.0;
    const double capture_start = NowMs();
    if (from_frames) {
      frames = LoadFrameSet(frames_dirs[index]);
      calibration = ResolveCalibration(frames, calibration_path);
      source = frames_dirs[index];
    } else {
      if (use_virtual) {
        if (index > 0) {
          scene = MakeRecognitionScene(seed + index, calibration.camera, scene_options);
          virtual_live.rig->SetScene(scene->scene);
        }
        spdlog::info("scan {}: virtual scene {}: {} at {:.2f} m", index, seed + index,
                     scene->Description(), scene->cam_from_model.translation.norm());
        truth = Truth{ToString(scene->object_class), scene->instance_seed, scene->mesh,
                      scene->cam_from_model};
      } else if (camera == "virtual") {
        const Scene demo = MakeDemoScene();
        truth = Truth{"mug", 0, demo.objects[0].mesh, demo.objects[0].cam_from_model};
      }
      try {
        cli::Progress progress(fmt::format("scan {}: capturing", index), sequence.size());
        frames = session->Capture(sequence, [&](size_t n, size_t) { progress.Update(n); });
      } catch (const Error&) {
        if (interrupt.flag()->load() && max_scans != 1 && done > 0) break;  // Ctrl-C ends it
        throw;
      }
    }
    capture_ms = NowMs() - capture_start;
    CheckCalibrationMatchesFrames(calibration, frames.manifest,
                                  calibration_path.empty() ? "the calibration" : calibration_path);

    // 2. Decode, triangulate, segment, recognise.
    ObjectSegmentationOptions segmentation;
    if (scene) segmentation = scene->segmentation;
    // The built-in scene of --camera virtual: the backdrop is 0.15 m behind the mug's centre.
    if (camera == "virtual") segmentation.max_range = kDefaultWorkingDistance + 0.1;
    if (min_range >= 0) segmentation.min_range = min_range;
    if (max_range >= 0) segmentation.max_range = max_range;
    if (!triangulator || from_frames) {
      triangulator = std::make_unique<Triangulator>(calibration, scan_options.triangulation);
    }
    const ScanRecognition result = RecogniseFrameSet(frames, *triangulator, scan_options.decoder,
                                                     segmentation, recogniser,
                                                     recognition_options);
    const RecognitionResult& recognition = result.recognition;

    // 3. Report and outputs.
    nlohmann::json j = nlohmann::json::parse(RecognitionResultToJson(recognition));
    nlohmann::json& timing = j["timing_ms"];
    timing["capture"] = capture_ms;
    timing["decode"] = result.timing.decode;
    timing["triangulate"] = result.timing.triangulate;
    timing["segment"] = result.timing.segment;
    timing["recognise"] = result.timing.recognise;
    timing["frame_to_result"] = result.timing.total;
    j["scan"] = {{"index", index},
                 {"source", source},
                 {"points", result.scan.triangulation.cloud.size()},
                 {"object_points", result.object.size()},
                 {"range_band_m", {segmentation.min_range, segmentation.max_range}}};
    std::string truth_brief;
    if (truth) j["ground_truth"] = TruthJson(*truth, recognition, &truth_brief);
    if (!out_dir.empty()) {
      const std::string stem = fmt::format("scan_{:04d}", index);
      const std::string cloud_path = JoinPath(out_dir, stem + ".ply");
      const std::string object_path = JoinPath(out_dir, stem + "_object.ply");
      const std::string overlay_path = JoinPath(out_dir, stem + "_overlay.png");
      WritePointCloud(cloud_path, result.scan.triangulation.cloud);
      WritePointCloud(object_path, result.object);
      WriteImageAtomic(overlay_path, Overlay(frames, calibration, *db, recognition));
      j["files"] = {{"cloud", cloud_path}, {"object_cloud", object_path},
                    {"overlay", overlay_path}};
      const std::string results_path = JoinPath(out_dir, "results.jsonl");
      std::string results = fs::exists(results_path)
                                ? ReadFileToString(results_path, "results file")
                                : std::string();
      WriteFileAtomic(results_path, results + j.dump() + "\n");
    }
    if (!bop_csv.empty() && !recognition.empty()) {
      const Suggestion& best = recognition.best();
      bop_estimates.push_back({1, index, best.model + 1, best.score, best.cam_from_model,
                               result.timing.total / 1000.0});
      WriteBopCsv(bop_csv, bop_estimates);
    }
    if (json) {
      std::printf("%s\n", j.dump().c_str());
    } else if (recognition.empty()) {
      std::printf("scan %d: no suggestion%s%s\n", index, truth ? "; " : "", truth_brief.c_str());
    } else {
      const Suggestion& best = recognition.best();
      std::printf("scan %d: %s (%s), score %.2f, %zu object points; frame to result %.0f ms "
                  "(decode %.0f, triangulate %.0f, segment %.0f, recognise %.0f)%s%s\n",
                  index, best.class_name.c_str(), best.model_name.c_str(), best.score,
                  result.object.size(), result.timing.total, result.timing.decode,
                  result.timing.triangulate, result.timing.segment, result.timing.recognise,
                  truth ? "; " : "", truth_brief.c_str());
    }
    std::fflush(stdout);
    ++done;
  }
  if (!out_dir.empty()) spdlog::info("{} scan(s) -> {}", done, out_dir);
  if (interrupt.flag()->load()) spdlog::info("stopped after {} scan(s) (interrupted)", done);
  return 0;
}

}  // namespace sope
