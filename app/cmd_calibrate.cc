// sope calibrate --frames DIR [DIR...] --board COLSxROWSxSQUARE_M --out CAL.yaml
// sope calibrate --camera /dev/videoN|virtual --board ... [--record DIR] --out CAL.yaml
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <optional>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/live_rig.h"
#include "app/pipeline_flags.h"
#include "calibration/calibration_report.h"
#include "calibration/rig_calibrator.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/frame_set.h"
#include "pipeline/board_capture.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {
namespace fs = std::filesystem;

// Each argument is a frame set (has frames.json) or a directory whose immediate
// subdirectories are frame sets (what `sope simulate --board` writes), taken in name order.
std::vector<std::string> ExpandFrameSetDirectories(const std::vector<std::string>& arguments) {
  std::vector<std::string> directories;
  for (const std::string& argument : arguments) {
    std::error_code error;
    SOPE_CHECK(fs::is_directory(argument, error), "--frames {}: no such directory", argument);
    if (fs::exists(JoinPath(argument, FrameSetManifest::kFileName), error)) {
      directories.push_back(argument);
      continue;
    }
    std::vector<std::string> children;
    for (const fs::directory_entry& entry : fs::directory_iterator(argument, error)) {
      if (entry.is_directory(error) &&
          fs::exists(entry.path() / FrameSetManifest::kFileName, error)) {
        children.push_back(entry.path().string());
      }
    }
    SOPE_CHECK(!children.empty(),
               "--frames {}: neither a frame set ({} missing) nor a "
               "directory of frame sets",
               argument, FrameSetManifest::kFileName);
    std::sort(children.begin(), children.end());
    directories.insert(directories.end(), children.begin(), children.end());
  }
  return directories;
}

// Live capture (--camera, pipeline/board_capture.h): a real camera waits for Enter on stdin
// before each pose ("q" or end of input finishes); the virtual rig scripts
// `virtual_views` poses. Returns the view directories.
std::vector<std::string> CaptureLiveViews(const std::string& camera, const BoardSpec& board,
                                          const RigCalibration& sizes,
                                          const cli::LiveRigFlags& live_flags,
                                          const std::string& record, int virtual_views) {
  const cli::InterruptFlag interrupt;
  BoardCaptureOptions options;
  options.spec = camera;
  options.sizes = sizes;
  options.board = board;
  options.record_directory = record;
  options.virtual_views = virtual_views;
  options.rig = live_flags.RigOptions();
  options.session = live_flags.SessionOptions(interrupt.flag());
  const auto ready = [](int index, int captured) {
    std::fprintf(stderr, "pose %d: hold the board still in view, then Enter to capture "
                 "(q + Enter to finish, %d captured): ", index, captured);
    std::fflush(stderr);
    std::string line;
    if (!std::getline(std::cin, line) || line == "q" || line == "Q") {
      std::fputs("\n", stderr);
      return false;
    }
    return true;
  };
  std::optional<cli::Progress> progress;
  int pose = 0;
  return CaptureBoardViews(
      options, ready, [&](int index) { progress.reset(); pose = index; },
      [&](size_t done, size_t total) {
        if (!progress) progress.emplace(fmt::format("pose {}: capturing", pose), total);
        progress->Update(done);
      });
}

// Finds the board in every view, calibrates, and writes CAL.yaml with its report and
// residual plot beside it.
void CalibrateAndWrite(const BoardSpec& board, const CalibrationOptions& options,
                       const std::vector<std::string>& directories, const std::string& out) {
  RigCalibrator calibrator(board, options);
  {
    cli::Progress progress("finding the board", directories.size());
    for (size_t i = 0; i < directories.size(); ++i) {
      calibrator.AddFrameSet(LoadFrameSet(directories[i]), directories[i]);
      progress.Update(i + 1);
    }
  }
  const CalibrationSummary summary = calibrator.Calibrate();
  WriteCalibrationReport(CalibrationSidecarPath(out, ".report.json"), summary);
  WriteImageAtomic(CalibrationSidecarPath(out, ".residuals.png"), DrawResidualPlot(summary));
  WriteRigCalibration(out, summary.calibration);
  std::fputs(summary.BriefReport().c_str(), stdout);
  spdlog::info("calibration -> {} (+ {}, {})", out, CalibrationSidecarPath(out, ".report.json"),
               CalibrationSidecarPath(out, ".residuals.png"));
}

// --camera and the flags of a live (or scripted virtual) capture of the board views.
struct LiveBoardFlags {
  std::string camera, record, projector_size, camera_size;
  int views = 12;
  cli::LiveRigFlags rig;

  void Add(CLI::App& app, CLI::App* source, CLI::Option* frames_option) {
    source->add_option("--camera", camera,
                       "Capture live instead: /dev/videoN (V4L2 camera + projector window; "
                       "Enter on stdin captures a board pose, q finishes) or virtual (scripted "
                       "board poses on the virtual rig)")
        ->excludes(frames_option);
    app.add_option("--record", record,
                   "--camera: where the board views are recorded (DIR/view_NNN frame sets; "
                   "default CAL.views next to --out)");
    app.add_option("--projector", projector_size,
                   "--camera /dev/videoN: projector size WxH (one pattern pixel per projector "
                   "pixel)");
    app.add_option("--camera-size", camera_size, "--camera /dev/videoN: camera image size WxH");
    app.add_option("--views", views, "--camera virtual: scripted board poses")
        ->capture_default_str();
  }

  // Captures and records the board views; returns their frame-set directories.
  std::vector<std::string> Capture(const BoardSpec& board, const std::string& out) const {
    RigCalibration sizes = DefaultRigCalibration();  // the virtual rig's true calibration
    if (camera != "virtual") {
      SOPE_CHECK(!projector_size.empty() && !camera_size.empty(),
                 "--camera {} needs --projector WxH and --camera-size WxH", camera);
      cli::ParseSize(projector_size, "--projector", &sizes.projector.width,
                     &sizes.projector.height);
      cli::ParseSize(camera_size, "--camera-size", &sizes.camera.width, &sizes.camera.height);
    }
    SOPE_CHECK(views >= 3, "--views must be ≥ 3, got {}", views);
    const std::string record_dir = record.empty() ? CalibrationSidecarPath(out, ".views") : record;
    const std::vector<std::string> directories =
        CaptureLiveViews(camera, board, sizes, rig, record_dir, views);
    SOPE_CHECK(directories.size() >= 3,
               "{} board pose(s) captured; calibration needs at least 3 (better 10-20 in "
               "varied tilts)",
               directories.size());
    return directories;
  }
};

}  // namespace

int RunCalibrate(int argc, char** argv) {
  CLI::App app{
      "Calibrate a camera-projector rig from frame sets of a checkerboard in varied "
      "poses, each with white/black frames and Gray codes in x and y: board corners "
      "in the camera, in the projector by local homographies of the decoded "
      "correspondences (Moreno & Taubin 2012), refined jointly with Ceres. Writes "
      "CAL.yaml, CAL.report.json (per-view RMS, dropped views) and "
      "CAL.residuals.png.",
      "sope calibrate"};
  std::vector<std::string> frame_arguments;
  std::string board_text, out;
  std::string detector = "sb", camera_terms = "k1,k2,p1,p2,k3", projector_terms = "k1,k2,p1,p2";
  std::string loss = "huber";
  CalibrationOptions options;
  cli::DecoderFlags decoder_flags;
  cli::LoggingFlags logging;
  // Exactly one source: a usage error (exit 2) otherwise.
  CLI::App* source = app.add_option_group("source", "--frames or --camera");
  source->require_option(1);
  CLI::Option* frames_option =
      source->add_option("--frames", frame_arguments,
                     "Frame sets (directories with frames.json), or directories whose "
                     "subdirectories are frame sets (e.g. what `sope simulate --board` wrote)")
          ->expected(1, -1);
  LiveBoardFlags live;
  live.Add(app, source, frames_option);
  app.add_option("--board", board_text,
                 "Checkerboard COLSxROWSxSQUARE_M: COLS x ROWS = INNER corners (OpenCV "
                 "patternSize; a board of 10x7 squares is 9x6), square side in metres, "
                 "e.g. 9x6x0.025")
      ->required();
  app.add_option("--out", out, "Output calibration YAML")->required();
  app.add_option("--detector", detector,
                 "Camera corner detector: sb (findChessboardCornersSB) or classic "
                 "(findChessboardCorners + cornerSubPix)")
      ->capture_default_str();
  bool no_subpixel = false;
  app.add_flag("--no-subpixel", no_subpixel,
               "Use the integer Gray codes as decoded (no sub-pixel refinement from the "
               "stripe-edge contrasts before the local homographies)");
  bool whole_boards = false;
  app.add_flag("--whole-boards", whole_boards,
               "Use only views that show the whole board (by default a view whose board runs "
               "out of the image is used with its visible corners)");
  app.add_option("--min-partial-fraction", options.detection.min_partial_corner_fraction,
                 "A board partly out of the image is used when at least this fraction of its "
                 "corners is in view (and >= 3 along each side)")
      ->capture_default_str();
  app.add_option("--window-fraction", options.local_homography.window_fraction,
                 "Local homography half window, fraction of the square size in camera pixels")
      ->capture_default_str();
  app.add_option("--camera-distortion", camera_terms,
                 "Estimated camera distortion terms (subset of k1,k2,p1,p2,k3, or none)")
      ->capture_default_str();
  app.add_option("--projector-distortion", projector_terms,
                 "Estimated projector distortion terms (subset of k1,k2,p1,p2,k3, or none)")
      ->capture_default_str();
  app.add_option("--loss", loss, "Robust loss: none, huber or cauchy")->capture_default_str();
  app.add_option("--loss-scale", options.loss_scale_px, "Robust loss scale, pixels")
      ->capture_default_str();
  app.add_option("--max-view-rms-ratio", options.max_view_rms_ratio,
                 "Drop views whose RMS exceeds this many times the median (and "
                 "--min-outlier-rms)")
      ->capture_default_str();
  app.add_option("--min-outlier-rms", options.min_outlier_rms_px,
                 "Never drop views with an RMS below this, pixels")
      ->capture_default_str();
  // Board views decode per pixel (the corners' local homographies need no filled pixels).
  decoder_flags.consistency = false;
  decoder_flags.Add(app);
  live.rig.Add(*app.add_option_group("live capture (--camera)"));
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  const BoardSpec board = BoardSpecFromString(board_text);
  options.detection.detector = CornerDetectorFromString(detector);
  options.camera_distortion = DistortionTermsFromString(camera_terms);
  options.projector_distortion = DistortionTermsFromString(projector_terms);
  options.loss = RobustLossFromString(loss);
  options.subpixel_codes = !no_subpixel;
  options.detection.partial = !whole_boards;
  options.decoder = decoder_flags.ToOptions();
  options.num_threads = options.decoder.num_threads;
  options.Check();

  const std::vector<std::string> directories =
      live.camera.empty() ? ExpandFrameSetDirectories(frame_arguments) : live.Capture(board, out);
  CalibrateAndWrite(board, options, directories, out);
  return 0;
}

}  // namespace sope
