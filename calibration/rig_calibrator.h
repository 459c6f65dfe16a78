// Camera–projector calibration from checkerboard views with structured light (DESIGN.md
// `sope calibrate`): the board's corners are found in the camera, carried into the
// projector through the decoded Gray-code correspondences by local homographies, and
// camera, projector and their relative pose are refined jointly with Ceres.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "calibration/board.h"
#include "calibration/projector_corners.h"
#include "core/frame_set.h"
#include "core/rig_calibration.h"
#include "core/rigid3d.h"
#include "decoder/decoder.h"

namespace sope {

// Which of OpenCV's distortion coefficients (k1, k2, p1, p2, k3) a device estimates; the
// others stay 0.
struct DistortionTerms {
  bool k1 = true;
  bool k2 = true;
  bool p1 = true;
  bool p2 = true;
  bool k3 = true;

  static DistortionTerms None() { return {false, false, false, false, false}; }
  // Indices into (k1, k2, p1, p2, k3) that stay fixed at 0.
  std::vector<int> FixedIndices() const;
  // "k1,k2,p1,p2,k3" (the estimated ones, OpenCV order) or "none".
  std::string ToString() const;
};
// Comma-separated names from {k1, k2, k3, p1, p2}, any order, or "none". Throws
// sope::Error naming an unknown term.
DistortionTerms DistortionTermsFromString(const std::string& text);

enum class RobustLoss { kNone, kHuber, kCauchy };
std::string ToString(RobustLoss loss);
RobustLoss RobustLossFromString(const std::string& text);  // "none", "huber", "cauchy"

struct CalibrationOptions {
  BoardDetectionOptions detection;
  DecoderOptions decoder;
  // Refine Gray-decoded coordinates to sub-pixel before the local homographies
  // (RefineGrayCodeSubpixel); without it the integer codes bias corners where camera and
  // projector pixels are nearly commensurate.
  bool subpixel_codes = true;
  LocalHomographyOptions local_homography;
  // Estimated distortion terms. Projectors usually have little distortion and k3 is poorly
  // observed from a few board poses across a projector's field.
  DistortionTerms camera_distortion;
  DistortionTerms projector_distortion = {true, true, true, true, false};
  // Robust loss on each corner's reprojection error and its scale, pixels (residuals
  // beyond it are down-weighted).
  RobustLoss loss = RobustLoss::kHuber;
  double loss_scale_px = 1.0;
  // A view is dropped (and the rest solved again) when its RMS reprojection error, both
  // devices together, exceeds max_view_rms_ratio × the median over the views AND
  // min_outlier_rms_px pixels.
  double max_view_rms_ratio = 3.0;
  double min_outlier_rms_px = 1.0;
  int max_drop_rounds = 3;
  // Views whose projector saw fewer than this fraction of the corners are left out of the
  // projector's initial (OpenCV) calibration; all their corners still enter the
  // adjustment.
  double min_projector_corner_fraction = 0.5;
  // Fewest usable views (board found) a calibration accepts.
  int min_views = 3;
  // Ceres: iteration limit and threads.
  int max_iterations = 200;
  int num_threads = 1;

  // Throws sope::Error naming an invalid value.
  void Check() const;
};

// The corners of one board view as measured in both devices.
struct BoardObservation {
  std::string name;
  // Entry i is board corner CornerIndex(i) in the camera, pixels: board.NumCorners()
  // entries in corner order when corner_indices is empty (the whole board), else one per
  // entry of corner_indices (a board partly in view, BoardDetection::indices).
  std::vector<Eigen::Vector2d> camera_corners;
  // Same size: the same corners in the projector, pixels; nullopt where the projector did
  // not see them well enough.
  std::vector<std::optional<Eigen::Vector2d>> projector_corners;
  std::vector<int> corner_indices;
  // Only part of the board was in view (its labelling then has a board frame of its own).
  bool partial = false;
  int NumProjectorCorners() const;
  int CornerIndex(size_t i) const {
    return corner_indices.empty() ? static_cast<int>(i) : corner_indices[i];
  }
};

struct DeviceSizes {
  int camera_width = 0;
  int camera_height = 0;
  int projector_width = 0;
  int projector_height = 0;
  bool operator==(const DeviceSizes& other) const;
};

struct CalibrationViewReport {
  std::string name;
  bool board_found = false;
  bool used = false;   // in the final adjustment
  bool partial = false;  // only part of the board in view (BoardDetection::partial)
  std::string status;  // "used", "board not found", "dropped: <reason>"
  int camera_corners = 0;
  int projector_corners = 0;
  // RMS reprojection errors in the final calibration, pixels (NaN when the board was not
  // found); for dropped views, of the calibration without them.
  double rms_camera_px = 0.0;
  double rms_projector_px = 0.0;
  double rms_px = 0.0;  // both devices together
  Rigid3d cam_from_board;
  // Residuals (predicted − observed) per corner, pixels.
  std::vector<Eigen::Vector2d> camera_residuals_px;
  std::vector<Eigen::Vector2d> projector_residuals_px;
};

struct CalibrationSummary {
  RigCalibration calibration;  // rms_* filled: final RMS over the used views, pixels
  BoardSpec board;
  // Every view given, in order: used, dropped or without a board.
  std::vector<CalibrationViewReport> views;
  int num_views_used = 0;
  int num_views_dropped = 0;
  int num_views_without_board = 0;
  int num_partial_views_used = 0;  // used views with the board partly in view
  int num_camera_corners = 0;     // in the used views
  int num_projector_corners = 0;  // in the used views
  // RMS of the initial OpenCV calibrations (each device on its own), pixels.
  double initial_rms_camera_px = 0.0;
  double initial_rms_projector_px = 0.0;
  // The last Ceres solve.
  std::string solver_termination;
  int solver_iterations = 0;
  double solver_initial_cost = 0.0;
  double solver_final_cost = 0.0;
  double detection_seconds = 0.0;  // board, decoding and projector corners, all views
  double solve_seconds = 0.0;      // initialisation and adjustment

  // Several lines in the spirit of ceres::Solver::Summary::BriefReport(): views used and
  // dropped, RMS per device, intrinsics, baseline and rotation (degrees).
  std::string BriefReport() const;
};

// Incremental calibration: add views one at a time (a live capture can show which were
// usable), then Calibrate(). Holds only the corner observations, not the frames.
class RigCalibrator {
 public:
  // Throws sope::Error on an invalid board or options.
  RigCalibrator(const BoardSpec& board, const CalibrationOptions& options = {});

  // Finds the board in the white frame (DetectBoard: the whole board or, unless
  // options.detection.partial is off, a part cut by the image border), decodes the frame set,
  // refines the codes to sub-pixel (RefineGrayCodeSubpixel, unless options say no) and
  // carries the corners into the projector (FindProjectorCorners). Returns the view's
  // observation, or nullopt when the board is not found — an expected failure, logged as
  // a warning naming the view, which is then listed as skipped in the summary. Throws
  // sope::Error (naming `name`, default the frame set's directory) when the set has no
  // white frame or not both x and y codes, or when its camera or projector size differs
  // from the views added before.
  std::optional<BoardObservation> AddFrameSet(const FrameSet& frames, std::string name = "");
  // Adds corners measured elsewhere (another detector, synthetic tests). Throws
  // sope::Error when the corner counts do not match the board (or corner_indices, which
  // must name board corners) or `sizes` differs from the views added before.
  void AddObservation(const BoardObservation& observation, const DeviceSizes& sizes);

  int NumViews() const { return static_cast<int>(views_.size()); }
  int NumUsableViews() const;
  const BoardSpec& board() const { return board_; }

  // Initial camera and projector calibrations (Zhang's method, cv::calibrateCamera; the
  // projector as an inverse camera from the board points and its corner coordinates,
  // Moreno & Taubin 2012), proj_from_cam from the per-view relative poses, then one
  // joint bundle adjustment (Ceres, Levenberg–Marquardt, Schur complement over the board
  // poses) of both devices' intrinsics and distortion, proj_from_cam and every
  // cam_from_board, minimising the reprojection errors in both devices under the robust
  // loss. Views that do not fit (CalibrationOptions::max_view_rms_ratio) are dropped and
  // the rest solved again. Throws sope::Error when no view found the board ("board
  // COLSxROWS not found in any view — check --board"), fewer than min_views views are
  // usable, or the projector saw the board in fewer than min_views views.
  CalibrationSummary Calibrate() const;

 private:
  struct View {
    std::string name;
    std::optional<BoardObservation> observation;
  };
  void CheckSizes(const DeviceSizes& sizes, const std::string& name);

  BoardSpec board_;
  CalibrationOptions options_;
  std::optional<DeviceSizes> sizes_;
  std::string first_view_name_;
  std::vector<View> views_;
  double detection_seconds_ = 0.0;
};

// One-shot: RigCalibrator(board, options), AddFrameSet for each set (named by its
// directory, or "view N" for in-memory sets), Calibrate().
CalibrationSummary CalibrateRig(const std::vector<FrameSet>& frame_sets, const BoardSpec& board,
                                const CalibrationOptions& options = {});

}  // namespace sope
