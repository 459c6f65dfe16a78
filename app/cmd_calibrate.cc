// sope calibrate --frames DIR [DIR...] --board COLSxROWSxSQUARE_M --out CAL.yaml
#include <algorithm>
#include <filesystem>

#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/pipeline_flags.h"
#include "calibration/calibration_report.h"
#include "calibration/rig_calibrator.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/frame_set.h"

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
  app.add_option("--frames", frame_arguments,
                 "Frame sets (directories with frames.json), or directories whose "
                 "subdirectories are frame sets (e.g. what `sope simulate --board` wrote)")
      ->required()
      ->expected(1, -1);
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
  decoder_flags.Add(app);
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  const BoardSpec board = BoardSpecFromString(board_text);
  options.detection.detector = CornerDetectorFromString(detector);
  options.camera_distortion = DistortionTermsFromString(camera_terms);
  options.projector_distortion = DistortionTermsFromString(projector_terms);
  options.loss = RobustLossFromString(loss);
  options.subpixel_codes = !no_subpixel;
  options.decoder = decoder_flags.ToOptions();
  options.num_threads = options.decoder.num_threads;
  options.Check();

  const std::vector<std::string> directories = ExpandFrameSetDirectories(frame_arguments);
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
  return 0;
}

}  // namespace sope
