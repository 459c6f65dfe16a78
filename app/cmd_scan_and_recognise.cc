// sope scan-and-recognise [--virtual | --camera /dev/videoN|virtual|replay:DIR | --frames DIR...]
//                         [--db DB.sopedb] [--calibration CAL.yaml] [--out DIR]
//                         [--scans N | --continuous] [--json]
// Scan (show the patterns, grab the frames), decode + triangulate, cut the cloud down to the
// object with a range band, recognise it and estimate its pose — once per scan. Flags →
// options → the pipeline's controller (pipeline/scan_and_recognise.h).
#include <algorithm>
#include <cstdio>
#include <memory>
#include <optional>

#include <fmt/format.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/live_rig.h"
#include "app/pipeline_flags.h"
#include "core/error.h"
#include "pipeline/default_database.h"
#include "recogniser/bop.h"
#include "pipeline/scan_and_recognise.h"
#include "pipeline/scan_source.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

struct Flags {
  std::string camera, calibration_path, db_path, out_dir, object_spec, instances = "unseen";
  std::string bop_csv;
  std::vector<std::string> frames_dirs;
  bool use_virtual = false, continuous = false, json = false, no_backdrop = false;
  int scans = 0, top = 4;
  uint64_t seed = 1;
  double min_range = -1.0, max_range = -1.0;
  cli::DecoderFlags decoder;
  cli::TriangulationFlags triangulation;
  cli::PatternFlags patterns;
  cli::LiveRigFlags live;
  cli::LoggingFlags logging;
  cli::TableFlags table;
  CLI::Option* scans_option = nullptr;

  void Add(CLI::App& app);
  // Which source, and how many scans (−1: until Ctrl-C). Checks the flag combinations.
  bool from_frames() const { return !frames_dirs.empty(); }
  bool virtual_rig() const { return use_virtual || camera == "virtual"; }
  int MaxScans() const;
  ScanAndRecogniseOptions ControllerOptions(const std::atomic<bool>* cancel) const;
};

void Flags::Add(CLI::App& app) {
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
  const DefaultDatabaseOptions default_db;
  app.add_option("--db", db_path,
                 fmt::format("Database (.sopedb, from sope build-db); default for the virtual "
                             "rig: the cached procedural database (10 classes x {} instances x "
                             "{} views)",
                             default_db.instances, default_db.views));
  app.add_option("--calibration", calibration_path,
                 "Rig calibration YAML (--frames: default the one frames.json names; virtual: "
                 "default the virtual rig's true calibration)");
  app.add_option("--out", out_dir,
                 "Per scan: scan_NNNN.ply (the full cloud), scan_NNNN_object.ply (the "
                 "segmented cloud), scan_NNNN_overlay.png, and the JSON line appended to "
                 "results.jsonl");
  app.add_option("--bop-csv", bop_csv,
                 "Also write each scan's best estimate to a BOP challenge results CSV "
                 "(scene_id 1, im_id = scan index, obj_id = database model index + 1, t in mm, "
                 "time = frame to result in s), rewritten after every scan");
  scans_option = app.add_option("--scans", scans, "Number of scans (live sources; default 1, "
                                                  "or until Ctrl-C with --continuous)");
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
                   fmt::format("unseen (instances not in the database) or database (the "
                               "default database's own instances, seeds {}-{})",
                               default_db.seed, default_db.seed + default_db.instances - 1))
      ->capture_default_str();
  virtual_group->add_flag("--no-backdrop", no_backdrop,
                          "No backdrop behind the object (--table: no wall behind the table)");
  table.Add(app, true);
  decoder.Add(app);
  triangulation.Add(app);
  auto* live_group = app.add_option_group("live capture (--camera, --virtual)");
  patterns.Add(*live_group);
  live.Add(*live_group);
  logging.Add(app);
}

int Flags::MaxScans() const {
  SOPE_CHECK(!from_frames() || (!continuous && scans_option->count() == 0),
             "--scans/--continuous apply to live sources; --frames scans each set once");
  SOPE_CHECK(scans_option->count() == 0 || scans >= 1, "--scans must be ≥ 1, got {}", scans);
  if (from_frames()) return static_cast<int>(frames_dirs.size());
  if (scans_option->count() > 0) return scans;
  return continuous ? -1 : 1;
}

ScanAndRecogniseOptions Flags::ControllerOptions(const std::atomic<bool>* cancel) const {
  SOPE_CHECK(top >= 1, "--top must be ≥ 1, got {}", top);
  ScanAndRecogniseOptions options;
  options.scan.decoder = decoder.ToOptions();
  options.scan.triangulation = triangulation.ToOptions();
  options.scan.triangulation.num_threads = options.scan.decoder.num_threads;
  options.recognition.threads = std::max(1, options.scan.decoder.num_threads);
  options.recognition.top_k = top;
  options.tabletop = table.table;
  if (min_range >= 0) options.min_range = min_range;
  if (max_range >= 0) options.max_range = max_range;
  options.max_scans = MaxScans();
  options.fail_on_nothing_found = options.max_scans == 1;  // one scan that sees nothing fails
  options.out_dir = out_dir;
  options.cancel = cancel;
  options.Check();
  return options;
}

// The virtual scenes: the database's procedural classes (or --object), unseen instances
// or the default database's own.
RecognitionSceneOptions SceneOptions(const Flags& flags, const Database& db) {
  RecognitionSceneOptions scenes;
  scenes.backdrop = !flags.no_backdrop;
  if (!flags.object_spec.empty()) {
    RestrictScenesToObject(flags.object_spec, &scenes);
  } else {
    scenes.classes = ProceduralClassesIn(db);
    // Tables of --mesh objects need no procedural class.
    SOPE_CHECK(!scenes.classes.empty() || (flags.table.table && !flags.table.meshes.empty()),
               "--virtual: the database {} holds no procedural class (mug, bottle, ...) to put "
               "in front of the virtual rig (or give --table --mesh FILE ...)", db.path());
  }
  if (flags.object_spec.find(':') == std::string::npos) {
    const DefaultDatabaseOptions defaults;
    scenes.instance_seed_base =
        flags.instances == "database" ? defaults.seed : kUnseenInstanceSeedBase;
    if (flags.instances == "database") scenes.instance_count = defaults.instances;
  }
  return scenes;
}

std::unique_ptr<ScanSource> MakeSource(const Flags& flags, const Database& db,
                                       const std::atomic<bool>* cancel) {
  if (flags.from_frames()) {
    return std::make_unique<FrameSetDirectorySource>(flags.frames_dirs, flags.calibration_path);
  }
  SOPE_CHECK(!flags.calibration_path.empty() || flags.virtual_rig(),
             "--camera {} needs --calibration CAL.yaml", flags.camera);
  const RigCalibration calibration = flags.calibration_path.empty()
                                         ? DefaultRigCalibration()
                                         : ReadRigCalibration(flags.calibration_path);
  const PatternOptions patterns =
      flags.patterns.ToOptions(calibration.projector.width, calibration.projector.height);
  SOPE_CHECK(flags.table.table || flags.table.meshes.empty(), "--mesh needs --table");
  SOPE_CHECK(flags.table.meshes.empty() || flags.table.objects == 0,
             "--objects and --mesh exclude each other (--mesh sets the objects)");
  if (flags.use_virtual && flags.table.table) {
    const RecognitionSceneOptions scenes = SceneOptions(flags, db);
    VirtualTableSourceOptions options;
    options.calibration = calibration;
    options.table = flags.table.ToOptions();
    // --mesh objects scaled and named as the database scaled (build-db --units) and named
    // them (the truth's class is the database's).
    for (TableObjectSpec& object : options.table.objects) {
      object.mesh_unit = db.options().size.mesh_unit;
      NameAsInDatabase(db, &object);
    }
    options.table.backdrop = !flags.no_backdrop;
    options.objects = flags.table.objects;
    options.classes = scenes.classes;
    options.instance_seed_base = scenes.instance_seed_base;
    options.instance_count = scenes.instance_count;
    options.seed = flags.seed;
    options.sensor = TableSensorOptions(flags.seed);
    options.patterns = patterns;
    options.rig = flags.live.RigOptions();
    options.session = flags.live.SessionOptions(cancel);
    return std::make_unique<VirtualTableSource>(options);
  }
  if (flags.use_virtual) {
    VirtualSceneSourceOptions options;
    options.calibration = calibration;
    options.scenes = SceneOptions(flags, db);
    options.seed = flags.seed;
    options.patterns = patterns;
    options.rig = flags.live.RigOptions();
    options.session = flags.live.SessionOptions(cancel);
    return std::make_unique<VirtualSceneSource>(options);
  }
  LiveRigSourceOptions options;
  options.spec = flags.camera;
  options.calibration = calibration;
  if (!flags.calibration_path.empty()) options.calibration_source = flags.calibration_path;
  options.patterns = patterns;
  options.rig = flags.live.RigOptions();
  options.session = flags.live.SessionOptions(cancel);
  return std::make_unique<LiveRigSource>(options);
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
  Flags flags;
  flags.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  flags.logging.Apply();
  if (!flags.from_frames() && flags.camera.empty()) flags.use_virtual = true;
  SOPE_CHECK(flags.instances == "unseen" || flags.instances == "database",
             "--instances must be unseen or database, got '{}'", flags.instances);
  ScanAndRecogniseOptions options = flags.ControllerOptions(nullptr);  // checked early

  if (flags.db_path.empty()) {
    SOPE_CHECK(flags.virtual_rig(), "--db DB.sopedb is required (a default database exists "
               "only for the virtual rig)");
    std::optional<cli::Progress> progress;
    flags.db_path = EnsureDefaultDatabase({}, [&](int done, int total) {
      if (!progress) progress.emplace("building the database", total);
      progress->Update(done);
    });
  } else {
    SOPE_CHECK(flags.instances == "unseen", "--instances database needs the default database "
               "(no --db)");
  }
  const std::unique_ptr<Database> db = Database::Open(flags.db_path);
  // Ctrl-C from here on ends the run between frames (during the database build it kills:
  // the build is staged, nothing half-built stays in the cache).
  const cli::InterruptFlag interrupt;
  options.cancel = interrupt.flag();
  const std::unique_ptr<ScanSource> source = MakeSource(flags, *db, interrupt.flag());
  ScanAndRecogniseController controller(options, source.get(), *db);
  std::optional<cli::Progress> progress;
  std::vector<BopEstimate> bop_estimates;
  controller.Run(
      [&](const ScanReport& report) {
        progress.reset();
        const RecognitionResult& recognition = report.result.recognition;
        if (!flags.bop_csv.empty() && !recognition.empty()) {
          const Suggestion& best = recognition.best();
          bop_estimates.push_back({1, report.index, best.model + 1, best.score,
                                   best.cam_from_model, report.result.timing.total / 1000.0});
          WriteBopCsv(flags.bop_csv, bop_estimates);
        }
        std::printf("%s\n", flags.json ? report.json.c_str() : ScanReportToText(report).c_str());
        std::fflush(stdout);
      },
      [&](size_t done, size_t total) {
        if (!progress) progress.emplace("capturing", total);
        progress->Update(done);
      });
  return 0;
}

}  // namespace sope
