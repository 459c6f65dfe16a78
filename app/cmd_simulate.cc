// sope simulate --mesh FILE [--object-pose rx,ry,rz,tx,ty,tz] [--rig RIG.yaml] --out DIR
// sope simulate --board COLSxROWSxSQUARE_M --views N [--rig RIG.yaml] --out DIR
#include <cmath>

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
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

// Meshes outside the plausible diagonal range (core/object_size.h, as build-db) are in
// other units: rescale them.
constexpr double kDefaultObjectSize = kDefaultObjectDiagonal;
// Beyond this (metres) nothing of the scene can reach a bench-top rig's image.
constexpr double kMaxSceneDistance = 100.0;

}  // namespace

int RunSimulate(int argc, char** argv) {
  CLI::App app{"Render a structured-light frame set of a mesh on the virtual rig (OSMesa), "
               "with ground truth: gt_depth.exr, gt_proj_x/y.exr, gt_lit.png, gt_pose.json "
               "and the rig's calibration.yaml. With --board instead of --mesh: a checkerboard "
               "calibration sequence, DIR/view_000/... (one frame set per board pose), "
               "DIR/calibration_true.yaml and DIR/gt_board_poses.json.",
               "sope simulate"};
  std::string mesh_path, pose_text = "0,0,0,0,0,0.6", rig_path, out;
  double size = -1.0, backdrop = 0.0;
  SensorOptions sensor;
  cli::PatternFlags pattern_flags;
  cli::LoggingFlags logging;
  std::string board_text;
  BoardSequenceOptions board_options;
  CLI::Option* mesh_option = app.add_option(
      "--mesh", mesh_path,
      "Mesh file (OBJ, PLY, OFF, STL) or builtin:sphere|box|cylinder|torus|plane");
  app.add_option("--board", board_text,
                 "Render a calibration sequence of a printed checkerboard instead: "
                 "COLSxROWSxSQUARE_M, COLS x ROWS = INNER corners (OpenCV patternSize; a "
                 "board of 10x7 squares is 9x6), square side in metres, e.g. 9x6x0.025")
      ->excludes(mesh_option);
  app.add_option("--views", board_options.num_views, "--board: number of board poses")
      ->capture_default_str();
  app.add_option("--pose-seed", board_options.seed, "--board: seed of the random board poses")
      ->capture_default_str();
  app.add_option("--object-pose", pose_text,
                 "Object rotation (degrees, R = Rz*Ry*Rx) and bounding-box centre (metres) "
                 "in the camera frame: rx,ry,rz,tx,ty,tz")
      ->capture_default_str();
  CLI::Option* size_option = app.add_option(
      "--object-size", size,
      "Scale the mesh to this bounding-box diagonal, metres (default: keep metres when "
      "plausible, else 0.25)");
  CLI::Option* backdrop_option =
      app.add_option("--backdrop", backdrop, "Add a matte backdrop plane at this depth, metres");
  bool allow_empty = false;
  app.add_flag("--allow-empty", allow_empty,
               "Write the frame set even when no pixel sees the object lit (else an error)");
  app.add_option("--rig", rig_path, "Rig calibration YAML (default: the built-in desktop rig)");
  app.add_option("--out", out, "Output frame-set directory")->required();
  app.add_option("--ambient", sensor.ambient, "Ambient light relative to the projector")
      ->capture_default_str();
  app.add_option("--defocus", sensor.defocus_sigma_px, "Projector defocus sigma, projector px")
      ->capture_default_str();
  app.add_option("--read-noise", sensor.read_noise, "Camera read noise sigma, grey levels")
      ->capture_default_str();
  app.add_option("--shot-noise", sensor.shot_noise, "Shot noise gain (variance per grey level)")
      ->capture_default_str();
  app.add_option("--supersample", sensor.supersample, "Samples per camera pixel side")
      ->capture_default_str();
  app.add_option("--seed", sensor.seed, "Noise seed")->capture_default_str();
  app.add_option("--camera-gamma", sensor.gamma, "Camera response gamma")->capture_default_str();
  app.add_option("--projector-gamma", sensor.projector_gamma, "Projector response gamma")
      ->capture_default_str();
  app.add_option("--projector-black-level", sensor.projector_black_level,
                 "Light of a black projector pixel, fraction of white")
      ->capture_default_str();
  app.add_option("--projector-saturation", sensor.projector_saturation,
                 "Projector value (0..1] from which it emits full white")
      ->capture_default_str();
  pattern_flags.Add(app);
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  const RigCalibration calibration =
      rig_path.empty() ? DefaultRigCalibration() : ReadRigCalibration(rig_path);
  const PatternOptions patterns =
      pattern_flags.ToOptions(calibration.projector.width, calibration.projector.height);
  if (!board_text.empty()) {
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
  SOPE_CHECK(!mesh_path.empty(), "one of --mesh or --board is required");
  const Rigid3d pose = cli::ParsePose(pose_text, "--object-pose");
  const double farthest_coordinate = pose.translation.cwiseAbs().maxCoeff();
  SOPE_CHECK(farthest_coordinate <= kMaxSceneDistance,
             "--object-pose '{}': a centre coordinate of {:.3g} m is beyond {} m", pose_text,
             farthest_coordinate, kMaxSceneDistance);
  SOPE_CHECK(size_option->count() == 0 ||
                 (std::isfinite(size) && size > 0.0 && size <= kMaxSceneDistance),
             "--object-size must be in (0, {}] m, got {}", kMaxSceneDistance, size);
  SOPE_CHECK(backdrop_option->count() == 0 ||
                 (std::isfinite(backdrop) && backdrop > 0.0 && backdrop <= kMaxSceneDistance),
             "--backdrop must be a depth in (0, {}] m, got {}", kMaxSceneDistance, backdrop);
  const TriangleMesh mesh = LoadMeshSpec(mesh_path);
  const double mesh_diagonal = mesh.BoundingDiagonal();
  SOPE_CHECK(std::isfinite(mesh_diagonal) && mesh_diagonal > 0.0,
             "mesh {}: its extent ({} units) is not a usable size", mesh_path, mesh_diagonal);
  Placement placement;
  placement.rotation = pose.rotation;
  placement.center_in_cam = pose.translation;
  if (size >= 0) {
    placement.size = size;
  } else {
    const double diagonal = mesh.BoundingDiagonal();
    if (!IsPlausibleDiagonal(diagonal)) {
      placement.size = kDefaultObjectSize;
      spdlog::info("mesh diagonal is {:.3g} units: scaling it to {} m (use --object-size)",
                   diagonal, kDefaultObjectSize);
    }
  }
  Scene scene;
  scene.objects.push_back(PlaceObject(mesh, placement));
  if (backdrop > 0) scene.objects.push_back(MakeBackdrop(backdrop, 4 * backdrop, 3 * backdrop));

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

}  // namespace sope
