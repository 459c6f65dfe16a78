// sope simulate --mesh FILE [--object-pose rx,ry,rz,tx,ty,tz] [--units mm] [--rig RIG.yaml]
//                --out DIR
// sope simulate --board COLSxROWSxSQUARE_M --views N [--rig RIG.yaml] --out DIR
// sope simulate --table --mesh A --mesh B ... [--seed N] [--clutter K] [--no-backdrop] --out DIR
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include <opencv2/core.hpp>
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/pipeline_flags.h"
#include "core/error.h"
#include "core/mesh.h"
#include "core/object_size.h"
#include "core/rig_calibration.h"
#include "simulator/board_sequence.h"
#include "simulator/scene_builder.h"
#include "simulator/simulate_scan.h"
#include "simulator/table_scene.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

// Meshes outside the plausible diagonal range (core/object_size.h, as build-db) are in
// other units: rescale them.
constexpr double kDefaultObjectSize = kDefaultObjectDiagonal;
// Beyond this (metres) nothing of the scene can reach a bench-top rig's image.
constexpr double kMaxSceneDistance = 100.0;

// The sensor flags: bound to `sensor`; for --table, flags not given take
// TableSensorOptions' values (the hard tabletop defaults).
struct SensorFlags {
  SensorOptions sensor;
  std::vector<std::pair<CLI::Option*, double SensorOptions::*>> doubles;
  CLI::Option* supersample = nullptr;

  void Add(CLI::App& app) {
    auto add = [&](const char* name, double SensorOptions::*field, const char* help) {
      doubles.emplace_back(app.add_option(name, sensor.*field, help)->capture_default_str(), field);
    };
    add("--ambient", &SensorOptions::ambient, "Ambient light relative to the projector");
    add("--defocus", &SensorOptions::defocus_sigma_px, "Projector defocus sigma, projector px");
    add("--read-noise", &SensorOptions::read_noise, "Camera read noise sigma, grey levels");
    add("--shot-noise", &SensorOptions::shot_noise, "Shot noise gain (variance per grey level)");
    supersample = app.add_option("--supersample", sensor.supersample, "Samples per camera pixel side")
                      ->capture_default_str();
    app.add_option("--seed", sensor.seed, "Noise seed (--table: also the scene seed)")
        ->capture_default_str();
    add("--camera-gamma", &SensorOptions::gamma, "Camera response gamma");
    add("--projector-gamma", &SensorOptions::projector_gamma, "Projector response gamma");
    add("--projector-black-level", &SensorOptions::projector_black_level,
        "Light of a black projector pixel, fraction of white");
    add("--projector-saturation", &SensorOptions::projector_saturation,
        "Projector value (0..1] from which it emits full white");
  }
  SensorOptions TableOptions() const {
    SensorOptions options = TableSensorOptions(sensor.seed);
    for (const auto& [option, field] : doubles) {
      if (option->count() > 0) options.*field = sensor.*field;
    }
    if (supersample->count() > 0) options.supersample = sensor.supersample;
    return options;
  }
};

int RunTableSimulation(const std::vector<std::string>& meshes, double size, double mesh_unit,
                       const cli::TableFlags& flags, bool no_backdrop, const SensorOptions& sensor,
                       const RigCalibration& calibration, const PatternOptions& patterns,
                       bool allow_empty, const std::string& out) {
  SOPE_CHECK(!meshes.empty(), "--table needs at least one --mesh");
  TableSceneOptions options = flags.ToOptions();
  for (const std::string& spec : meshes) {
    TableObjectSpec object;
    object.spec = spec;
    object.size = size >= 0 ? size : kSizeAsDatabase;
    object.mesh_unit = mesh_unit;
    options.objects.push_back(object);
  }
  options.backdrop = !no_backdrop;
  options.seed = sensor.seed;
  TableScene table = MakeTableScene(options, calibration);
  VirtualRig rig(calibration, sensor);
  const SimulatedScan scan = SimulateScan(rig, table.scene, patterns);
  ComputeVisibleFractions(scan.ground_truth.object_id, calibration.camera, &table);
  const int lit = cv::countNonZero(scan.ground_truth.lit);
  SOPE_CHECK(lit > 0 || allow_empty, "no camera pixel sees the table lit by the projector");
  SimulatedScanExtras extras;
  extras.gt_pose_json = TableGroundTruthJson(table);
  extras.images.emplace_back("gt_objects.png",
                             DrawTableObjects(scan.ground_truth.object_id, calibration.camera, table));
  WriteSimulatedScan(out, scan, extras);
  std::string summary;
  for (const TableObjectTruth& truth : table.objects) {
    summary += fmt::format("{}{} {:.0f}%", summary.empty() ? "" : ", ", truth.model,
                           100 * truth.visible_fraction);
  }
  spdlog::info("table scene {} (camera {:.1f} deg down, {} objects: {}): {} frames -> {}",
               options.seed, table.camera_tilt_deg, table.objects.size(), summary,
               scan.frames.images.size(), out);
  return 0;
}

// `simulate --board`: a calibration sequence, one frame set per board pose.
int RunBoardSimulation(const std::string& board_text, BoardSequenceOptions board_options,
                       const SensorOptions& sensor, const RigCalibration& calibration,
                       const PatternOptions& patterns, const std::string& out) {
  const BoardSpec board = BoardSpecFromString(board_text);
  board_options.patterns = patterns;
  board_options.Check();
  VirtualRig rig(calibration, sensor);
  cli::Progress progress("rendering board views", board_options.num_views);
  WriteBoardSequence(out, rig, board, board_options,
                     [&](int done, int) { progress.Update(done); });
  spdlog::info("rendered {} views of a {} board ({} frames each) -> {}", board_options.num_views,
               board.ToString(),
               MakePatternManifest(patterns, calibration.camera.width, calibration.camera.height)
                   .frames.size(),
               out);
  return 0;
}

// `simulate --mesh`: one object, optionally before a backdrop (empty: the flag was not given).
struct SingleObjectScene {
  std::string mesh_path;
  std::string pose_text;
  std::optional<double> size;
  double mesh_unit = 0.0;  // metres per mesh unit; 0 guesses (core/object_size.h)
  std::optional<double> backdrop;
};

int RunSingleObjectSimulation(const SingleObjectScene& object, const SensorOptions& sensor,
                              const RigCalibration& calibration, const PatternOptions& patterns,
                              bool allow_empty, const std::string& out) {
  const Rigid3d pose = cli::ParsePose(object.pose_text, "--object-pose");
  const double farthest_coordinate = pose.translation.cwiseAbs().maxCoeff();
  SOPE_CHECK(farthest_coordinate <= kMaxSceneDistance,
             "--object-pose '{}': a centre coordinate of {:.3g} m is beyond {} m", object.pose_text,
             farthest_coordinate, kMaxSceneDistance);
  SOPE_CHECK(!object.size ||
                 (std::isfinite(*object.size) && *object.size > 0.0 &&
                  *object.size <= kMaxSceneDistance),
             "--object-size must be in (0, {}] m, got {}", kMaxSceneDistance, *object.size);
  SOPE_CHECK(!object.backdrop ||
                 (std::isfinite(*object.backdrop) && *object.backdrop > 0.0 &&
                  *object.backdrop <= kMaxSceneDistance),
             "--backdrop must be a depth in (0, {}] m, got {}", kMaxSceneDistance,
             *object.backdrop);
  const TriangleMesh mesh = LoadMeshSpec(object.mesh_path);
  const double mesh_diagonal = mesh.BoundingDiagonal();
  SOPE_CHECK(std::isfinite(mesh_diagonal) && mesh_diagonal > 0.0,
             "mesh {}: its extent ({} units) is not a usable size", object.mesh_path,
             mesh_diagonal);
  Placement placement;
  placement.rotation = pose.rotation;
  placement.center_in_cam = pose.translation;
  if (object.size) {
    placement.size = *object.size;
  } else if (object.mesh_unit > 0.0) {
    placement.size = mesh_diagonal * object.mesh_unit;
  } else if (!IsPlausibleDiagonal(mesh_diagonal)) {
    placement.size = kDefaultObjectSize;
    spdlog::info("mesh diagonal is {:.3g} units: scaling it to {} m (use --units or "
                 "--object-size)",
                 mesh_diagonal, kDefaultObjectSize);
  }
  Scene scene;
  scene.objects.push_back(PlaceObject(mesh, placement));
  if (object.backdrop) {
    const double depth = *object.backdrop;
    scene.objects.push_back(MakeBackdrop(depth, 4 * depth, 3 * depth));
  }

  VirtualRig rig(calibration, sensor);
  const SimulatedScan scan = SimulateScan(rig, scene, patterns);
  const int lit = cv::countNonZero(scan.ground_truth.lit);
  SOPE_CHECK(lit > 0 || allow_empty,
             "no camera pixel sees the object lit by the projector (is it in front of both, "
             "within their fields of view? --allow-empty writes the empty frame set anyway)");
  WriteSimulatedScan(out, scan);
  spdlog::info("rendered {} frames ({}x{} camera, {}x{} projector), {} pixels lit -> {}",
               scan.frames.images.size(), calibration.camera.width, calibration.camera.height,
               calibration.projector.width, calibration.projector.height, lit, out);
  return 0;
}

}  // namespace

int RunSimulate(int argc, char** argv) {
  CLI::App app{"Render a structured-light frame set of a mesh on the virtual rig (OSMesa), "
               "with ground truth: gt_depth.exr, gt_proj_x/y.exr, gt_lit.png, gt_pose.json "
               "and the rig's calibration.yaml. With --board instead of --mesh: a checkerboard "
               "calibration sequence, DIR/view_000/... (one frame set per board pose), "
               "DIR/calibration_true.yaml and DIR/gt_board_poses.json.",
               "sope simulate"};
  std::vector<std::string> mesh_paths;
  std::string pose_text = "0,0,0,0,0,0.6", rig_path, out, units = "auto";
  double size = -1.0, backdrop = 0.0;
  SensorFlags sensor_flags;
  SensorOptions& sensor = sensor_flags.sensor;
  cli::TableFlags table_flags;
  bool no_backdrop = false;
  cli::PatternFlags pattern_flags;
  cli::LoggingFlags logging;
  std::string board_text;
  BoardSequenceOptions board_options;
  CLI::Option* mesh_option = app.add_option(
      "--mesh", mesh_paths,
      "Mesh file (OBJ, PLY, OFF, STL) or builtin:sphere|box|cylinder|torus|plane, "
      "builtin:CLASS[:SEED] for a procedural object; several with --table");
  app.add_option("--board", board_text,
                 "Render a calibration sequence of a printed checkerboard instead: "
                 "COLSxROWSxSQUARE_M, COLS x ROWS = INNER corners (OpenCV patternSize; a "
                 "board of 10x7 squares is 9x6), square side in metres, e.g. 9x6x0.025")
      ->excludes(mesh_option);
  app.add_option("--views", board_options.num_views, "--board: number of board poses")
      ->capture_default_str();
  app.add_option("--pose-seed", board_options.seed, "--board: seed of the random board poses")
      ->capture_default_str();
  app.add_option("--partial-views", board_options.partial_fraction,
                 "--board: fraction of the views whose board runs partly out of the camera "
                 "image (10-40% of its corners outside; 0 = every board in full view)")
      ->capture_default_str();
  app.add_option("--object-pose", pose_text,
                 "Object rotation (degrees, R = Rz*Ry*Rx) and bounding-box centre (metres) "
                 "in the camera frame: rx,ry,rz,tx,ty,tz")
      ->capture_default_str();
  CLI::Option* size_option = app.add_option(
      "--object-size", size,
      "Scale the mesh to this bounding-box diagonal, metres (default: keep metres when "
      "plausible, else 0.25)");
  cli::AddMeshUnitFlag(app, &units);
  CLI::Option* backdrop_option =
      app.add_option("--backdrop", backdrop, "Add a matte backdrop plane at this depth, metres");
  bool allow_empty = false;
  app.add_flag("--allow-empty", allow_empty,
               "Write the frame set even when no pixel sees the object lit (else an error)");
  app.add_option("--rig", rig_path, "Rig calibration YAML (default: the built-in desktop rig)");
  app.add_option("--out", out, "Output frame-set directory")->required();
  sensor_flags.Add(app);
  table_flags.Add(app, false);
  app.add_flag("--no-backdrop", no_backdrop, "--table: no wall behind the table");
  pattern_flags.Add(app);
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  const double mesh_unit = cli::ParseMeshUnit(units, "--units");
  SOPE_CHECK(mesh_unit == 0.0 || size_option->count() == 0,
             "--units and --object-size exclude each other (one sets the mesh's size)");
  const RigCalibration calibration =
      rig_path.empty() ? DefaultRigCalibration() : ReadRigCalibration(rig_path);
  const PatternOptions patterns =
      pattern_flags.ToOptions(calibration.projector.width, calibration.projector.height);
  if (!board_text.empty()) {
    SOPE_CHECK(!table_flags.table, "--board and --table exclude each other");
    return RunBoardSimulation(board_text, board_options, sensor, calibration, patterns, out);
  }
  if (table_flags.table) {
    SOPE_CHECK(backdrop_option->count() == 0,
               "--backdrop DEPTH is for single-object scenes (--table has a wall; --no-backdrop)");
    SOPE_CHECK(size_option->count() == 0 ||
                   (std::isfinite(size) && size > 0.0 && size <= kMaxPlausibleDiagonal),
               "--object-size must be in (0, {}] m for a table, got {}", kMaxPlausibleDiagonal,
               size);
    return RunTableSimulation(mesh_paths, size, mesh_unit, table_flags, no_backdrop,
                              sensor_flags.TableOptions(),
                              calibration, patterns, allow_empty, out);
  }
  SOPE_CHECK(!no_backdrop, "--no-backdrop is for --table (single objects: omit --backdrop)");
  SOPE_CHECK(mesh_paths.size() <= 1, "--mesh given {} times: several meshes need --table",
             mesh_paths.size());
  SOPE_CHECK(!mesh_paths.empty(), "one of --mesh or --board is required");
  SingleObjectScene object;
  object.mesh_path = mesh_paths[0];
  object.pose_text = pose_text;
  if (size_option->count() > 0) object.size = size;
  object.mesh_unit = mesh_unit;
  if (backdrop_option->count() > 0) object.backdrop = backdrop;
  return RunSingleObjectSimulation(object, sensor, calibration, patterns, allow_empty, out);
}

}  // namespace sope
