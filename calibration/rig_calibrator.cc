#include "calibration/rig_calibrator.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <fmt/format.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/eigen.hpp>
#include <spdlog/spdlog.h>

#include "calibration/reprojection_error.h"
#include "core/error.h"
#include "core/statistics.h"
#include "decoder/phase_decoder.h"

namespace sope {
namespace internal {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kDegreesPerRadian = 180.0 / M_PI;

using PoseBlock = std::array<double, kPoseSize>;

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// b_from_a → [angle-axis, translation]. Eigen matrices are column-major, as Ceres' rotation
// helpers expect.
PoseBlock ToPoseBlock(const Rigid3d& b_from_a) {
  PoseBlock block;
  ceres::RotationMatrixToAngleAxis(b_from_a.rotation.data(), block.data());
  for (int i = 0; i < 3; ++i) block[3 + i] = b_from_a.translation[i];
  return block;
}

Rigid3d FromPoseBlock(const double* block) {
  Rigid3d b_from_a;
  ceres::AngleAxisToRotationMatrix(block, b_from_a.rotation.data());
  b_from_a.translation = Eigen::Vector3d(block[3], block[4], block[5]);
  return b_from_a;
}

Rigid3d FromRodrigues(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat rotation;
  cv::Rodrigues(rvec, rotation);
  Rigid3d pose;
  cv::cv2eigen(rotation, pose.rotation);
  cv::Mat translation;
  tvec.convertTo(translation, CV_64F);
  pose.translation = Eigen::Vector3d(translation.at<double>(0), translation.at<double>(1),
                                     translation.at<double>(2));
  return pose;
}

// Intrinsics and distortion of one device as Ceres parameter blocks.
struct DeviceBlocks {
  std::array<double, kIntrinsicsSize> intrinsics{};  // fx, fy, cx, cy
  std::array<double, kDistortionSize> distortion{};  // k1, k2, p1, p2, k3

  static DeviceBlocks FromOpenCv(const cv::Mat& matrix, const cv::Mat& distortion,
                                 const DistortionTerms& terms) {
    DeviceBlocks blocks;
    blocks.intrinsics = {matrix.at<double>(0, 0), matrix.at<double>(1, 1), matrix.at<double>(0, 2),
                         matrix.at<double>(1, 2)};
    for (int i = 0; i < kDistortionSize && i < static_cast<int>(distortion.total()); ++i) {
      blocks.distortion[i] = distortion.at<double>(i);
    }
    // Terms the options fix are exactly zero, whatever OpenCV did with them.
    for (int i : terms.FixedIndices()) blocks.distortion[i] = 0.0;
    return blocks;
  }

  CameraModel ToModel(int width, int height) const {
    CameraModel model;
    model.width = width;
    model.height = height;
    model.matrix << intrinsics[0], 0.0, intrinsics[2], 0.0, intrinsics[1], intrinsics[3], 0.0, 0.0,
        1.0;
    model.distortion.assign(distortion.begin(), distortion.end());
    return model;
  }
};

// Everything the adjustment estimates. cam_from_board has one block per view given to
// Calibrate (usable or not; only the active ones are used).
struct RigState {
  DeviceBlocks camera;
  DeviceBlocks projector;
  PoseBlock proj_from_cam{};
  std::vector<PoseBlock> cam_from_board;
};

struct ViewResiduals {
  std::vector<Eigen::Vector2d> camera;     // predicted − observed, pixels
  std::vector<Eigen::Vector2d> projector;  // predicted − observed, pixels
  double SumSquaredCamera() const {
    double sum = 0.0;
    for (const Eigen::Vector2d& r : camera) sum += r.squaredNorm();
    return sum;
  }
  double SumSquaredProjector() const {
    double sum = 0.0;
    for (const Eigen::Vector2d& r : projector) sum += r.squaredNorm();
    return sum;
  }
  double RmsCamera() const {
    return camera.empty() ? kNaN : std::sqrt(SumSquaredCamera() / camera.size());
  }
  double RmsProjector() const {
    return projector.empty() ? kNaN : std::sqrt(SumSquaredProjector() / projector.size());
  }
  double Rms() const {
    const size_t count = camera.size() + projector.size();
    return count == 0 ? kNaN : std::sqrt((SumSquaredCamera() + SumSquaredProjector()) / count);
  }
};

// Residuals of one view with the same functors the adjustment uses.
ViewResiduals ComputeResiduals(const BoardSpec& board, const BoardObservation& observation,
                               const RigState& state, const PoseBlock& cam_from_board) {
  ViewResiduals residuals;
  for (size_t k = 0; k < observation.camera_corners.size(); ++k) {
    const Eigen::Vector3d corner = board.CornerInBoard(observation.CornerIndex(k));
    Eigen::Vector2d residual;
    CameraReprojectionError(corner.data(), observation.camera_corners[k].data())(
        state.camera.intrinsics.data(), state.camera.distortion.data(), cam_from_board.data(),
        residual.data());
    residuals.camera.push_back(residual);
    if (const auto& projector = observation.projector_corners[k]) {
      ProjectorReprojectionError(corner.data(), projector->data())(
          state.projector.intrinsics.data(), state.projector.distortion.data(),
          state.proj_from_cam.data(), cam_from_board.data(), residual.data());
      residuals.projector.push_back(residual);
    }
  }
  return residuals;
}

std::unique_ptr<ceres::LossFunction> MakeLoss(RobustLoss loss, double scale_px) {
  switch (loss) {
    case RobustLoss::kNone:
      return nullptr;
    case RobustLoss::kHuber:
      return std::make_unique<ceres::HuberLoss>(scale_px);
    case RobustLoss::kCauchy:
      return std::make_unique<ceres::CauchyLoss>(scale_px);
  }
  return nullptr;
}

void SetDistortionManifold(ceres::Problem* problem, double* distortion,
                           const DistortionTerms& terms) {
  const std::vector<int> fixed = terms.FixedIndices();
  if (fixed.size() == static_cast<size_t>(kDistortionSize)) {
    problem->SetParameterBlockConstant(distortion);
  } else if (!fixed.empty()) {
    problem->SetManifold(distortion, new ceres::SubsetManifold(kDistortionSize, fixed));
  }
}

// Bundle adjustment over the views `active` (indices into `observations`). With
// `poses_only`, the devices and proj_from_cam stay fixed and only the board poses move
// (used to re-fit dropped views to the final calibration).
ceres::Solver::Summary Adjust(const BoardSpec& board,
                              const std::vector<const BoardObservation*>& observations,
                              const std::vector<int>& active, const CalibrationOptions& options,
                              bool poses_only, RigState* state) {
  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  const std::unique_ptr<ceres::LossFunction> loss = MakeLoss(options.loss, options.loss_scale_px);
  bool any_projector = false;
  for (int v : active) {
    const BoardObservation& observation = *observations[v];
    double* pose = state->cam_from_board[v].data();
    for (size_t k = 0; k < observation.camera_corners.size(); ++k) {
      const Eigen::Vector3d corner = board.CornerInBoard(observation.CornerIndex(k));
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<CameraReprojectionError, 2, kIntrinsicsSize,
                                          kDistortionSize, kPoseSize>(
              new CameraReprojectionError(corner.data(), observation.camera_corners[k].data())),
          loss.get(), state->camera.intrinsics.data(), state->camera.distortion.data(), pose);
      if (const auto& projector = observation.projector_corners[k]) {
        problem.AddResidualBlock(
            new ceres::AutoDiffCostFunction<ProjectorReprojectionError, 2, kIntrinsicsSize,
                                            kDistortionSize, kPoseSize, kPoseSize>(
                new ProjectorReprojectionError(corner.data(), projector->data())),
            loss.get(), state->projector.intrinsics.data(), state->projector.distortion.data(),
            state->proj_from_cam.data(), pose);
        any_projector = true;
      }
    }
  }
  if (poses_only) {
    problem.SetParameterBlockConstant(state->camera.intrinsics.data());
    problem.SetParameterBlockConstant(state->camera.distortion.data());
    if (any_projector) {
      problem.SetParameterBlockConstant(state->projector.intrinsics.data());
      problem.SetParameterBlockConstant(state->projector.distortion.data());
      problem.SetParameterBlockConstant(state->proj_from_cam.data());
    }
  } else {
    SetDistortionManifold(&problem, state->camera.distortion.data(), options.camera_distortion);
    if (any_projector) {
      SetDistortionManifold(&problem, state->projector.distortion.data(),
                            options.projector_distortion);
    }
  }
  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::DENSE_SCHUR;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.num_threads = options.num_threads;
  solver_options.function_tolerance = 1e-12;
  solver_options.gradient_tolerance = 1e-12;
  solver_options.parameter_tolerance = 1e-12;
  solver_options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, &problem, &summary);
  return summary;
}

int OpenCvFlags(const DistortionTerms& terms) {
  int flags = 0;
  if (!terms.k1) flags |= cv::CALIB_FIX_K1;
  if (!terms.k2) flags |= cv::CALIB_FIX_K2;
  if (!terms.k3) flags |= cv::CALIB_FIX_K3;
  if (!terms.p1 || !terms.p2) flags |= cv::CALIB_ZERO_TANGENT_DIST;
  return flags;
}

// Zhang's calibration of one device from board views; `corners[v][i]` observes board
// corner `indices[v][i]`. Returns the RMS reprojection error and fills the device blocks
// and the device_from_board poses.
double CalibrateDevice(const BoardSpec& board,
                       const std::vector<std::vector<Eigen::Vector2d>>& corners,
                       const std::vector<std::vector<int>>& indices, int width, int height,
                       const DistortionTerms& terms, DeviceBlocks* blocks,
                       std::vector<Rigid3d>* device_from_board) {
  std::vector<std::vector<cv::Point3f>> object_points(corners.size());
  std::vector<std::vector<cv::Point2f>> image_points(corners.size());
  for (size_t v = 0; v < corners.size(); ++v) {
    for (size_t i = 0; i < corners[v].size(); ++i) {
      const Eigen::Vector3d corner = board.CornerInBoard(indices[v][i]);
      object_points[v].emplace_back(static_cast<float>(corner.x()), static_cast<float>(corner.y()),
                                    0.0f);
      image_points[v].emplace_back(static_cast<float>(corners[v][i].x()),
                                   static_cast<float>(corners[v][i].y()));
    }
  }
  cv::Mat matrix, distortion;
  std::vector<cv::Mat> rvecs, tvecs;
  const double rms = cv::calibrateCamera(
      object_points, image_points, cv::Size(width, height), matrix, distortion, rvecs, tvecs,
      OpenCvFlags(terms),
      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
  *blocks = DeviceBlocks::FromOpenCv(matrix, distortion, terms);
  device_from_board->clear();
  for (size_t v = 0; v < rvecs.size(); ++v) {
    device_from_board->push_back(FromRodrigues(rvecs[v], tvecs[v]));
  }
  return rms;
}

// Mean of rotations (quaternions aligned to the first, summed, normalised) and the
// component-wise median of translations: a robust enough start for the adjustment.
Rigid3d AveragePose(const std::vector<Rigid3d>& poses) {
  Eigen::Vector4d sum = Eigen::Vector4d::Zero();
  const Eigen::Quaterniond first(poses.front().rotation);
  std::array<std::vector<double>, 3> translations;
  for (const Rigid3d& pose : poses) {
    Eigen::Quaterniond q(pose.rotation);
    if (q.coeffs().dot(first.coeffs()) < 0) q.coeffs() *= -1.0;
    sum += q.coeffs();
    for (int i = 0; i < 3; ++i) translations[i].push_back(pose.translation[i]);
  }
  Rigid3d mean;
  mean.rotation = Eigen::Quaterniond(sum.normalized()).toRotationMatrix();
  for (int i = 0; i < 3; ++i) {
    std::vector<double>& values = translations[i];
    std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
    mean.translation[i] = values[values.size() / 2];
  }
  return mean;
}

std::string FormatDevice(const char* label, const CameraModel& model, double rms, int corners) {
  std::string distortion;
  const char* names[] = {"k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"};
  for (size_t i = 0; i < model.distortion.size() && i < 8; ++i) {
    distortion += fmt::format(" {} {:.5f}", names[i], model.distortion[i]);
  }
  return fmt::format(
      "  {:<14}{}x{}  fx {:.2f}  fy {:.2f}  cx {:.2f}  cy {:.2f} px;{}\n"
      "  {:<14}RMS {:.3f} px over {} corners\n",
      label, model.width, model.height, model.fx(), model.fy(), model.cx(), model.cy(), distortion,
      "", rms, corners);
}

}  // namespace
}  // namespace internal

// ---- options ------------------------------------------------------------------------

std::vector<int> DistortionTerms::FixedIndices() const {
  std::vector<int> fixed;
  const bool estimated[internal::kDistortionSize] = {k1, k2, p1, p2, k3};
  for (int i = 0; i < internal::kDistortionSize; ++i) {
    if (!estimated[i]) fixed.push_back(i);
  }
  return fixed;
}

std::string DistortionTerms::ToString() const {
  std::string text;
  const std::pair<bool, const char*> terms[] = {
      {k1, "k1"}, {k2, "k2"}, {p1, "p1"}, {p2, "p2"}, {k3, "k3"}};
  for (const auto& [on, name] : terms) {
    if (!on) continue;
    if (!text.empty()) text += ",";
    text += name;
  }
  return text.empty() ? "none" : text;
}

DistortionTerms DistortionTermsFromString(const std::string& text) {
  DistortionTerms terms = DistortionTerms::None();
  if (text == "none") return terms;
  std::stringstream stream(text);
  std::string item;
  bool any = false;
  while (std::getline(stream, item, ',')) {
    if (item == "k1")
      terms.k1 = true;
    else if (item == "k2")
      terms.k2 = true;
    else if (item == "k3")
      terms.k3 = true;
    else if (item == "p1")
      terms.p1 = true;
    else if (item == "p2")
      terms.p2 = true;
    else
      SOPE_THROW(
          "distortion terms '{}': unknown term '{}' (known: k1, k2, p1, p2, k3, or "
          "none)",
          text, item);
    any = true;
  }
  SOPE_CHECK(any, "distortion terms '{}': expected e.g. k1,k2,p1,p2,k3 or none", text);
  return terms;
}

std::string ToString(RobustLoss loss) {
  switch (loss) {
    case RobustLoss::kNone:
      return "none";
    case RobustLoss::kHuber:
      return "huber";
    case RobustLoss::kCauchy:
      return "cauchy";
  }
  return "?";
}

RobustLoss RobustLossFromString(const std::string& text) {
  if (text == "none") return RobustLoss::kNone;
  if (text == "huber") return RobustLoss::kHuber;
  if (text == "cauchy") return RobustLoss::kCauchy;
  SOPE_THROW("unknown robust loss '{}' (known: none, huber, cauchy)", text);
}

void CalibrationOptions::Check() const {
  detection.Check();
  decoder.Check();
  local_homography.Check();
  SOPE_CHECK(std::isfinite(loss_scale_px) && loss_scale_px > 0,
             "loss_scale_px must be > 0 pixels, got {}", loss_scale_px);
  SOPE_CHECK(max_view_rms_ratio > 1.0, "max_view_rms_ratio must be > 1, got {}",
             max_view_rms_ratio);
  SOPE_CHECK(min_outlier_rms_px >= 0, "min_outlier_rms_px must be >= 0, got {}",
             min_outlier_rms_px);
  SOPE_CHECK(max_drop_rounds >= 0, "max_drop_rounds must be >= 0, got {}", max_drop_rounds);
  SOPE_CHECK(min_projector_corner_fraction > 0 && min_projector_corner_fraction <= 1,
             "min_projector_corner_fraction must be in (0, 1], got {}",
             min_projector_corner_fraction);
  SOPE_CHECK(min_views >= 3, "min_views must be >= 3 (Zhang's method), got {}", min_views);
  SOPE_CHECK(max_iterations >= 1, "max_iterations must be >= 1, got {}", max_iterations);
  SOPE_CHECK(num_threads >= 1, "num_threads must be >= 1, got {}", num_threads);
}

int BoardObservation::NumProjectorCorners() const {
  return static_cast<int>(std::count_if(projector_corners.begin(), projector_corners.end(),
                                        [](const auto& corner) { return corner.has_value(); }));
}

bool DeviceSizes::operator==(const DeviceSizes& other) const {
  return camera_width == other.camera_width && camera_height == other.camera_height &&
         projector_width == other.projector_width && projector_height == other.projector_height;
}

// ---- summary ------------------------------------------------------------------------

std::string CalibrationSummary::BriefReport() const {
  const int given = static_cast<int>(views.size());
  std::string report = fmt::format(
      "Rig calibration, board {} (inner corners x square, m)\n"
      "  {:<14}{} given: {} used, {} dropped, {} without the board{}\n",
      board.ToString(), "views", given, num_views_used, num_views_dropped, num_views_without_board,
      num_partial_views_used > 0
          ? fmt::format("; {} used with the board partly in view", num_partial_views_used)
          : "");
  report += internal::FormatDevice("camera", calibration.camera, calibration.rms_camera_px,
                                   num_camera_corners);
  report += internal::FormatDevice("projector", calibration.projector, calibration.rms_projector_px,
                                   num_projector_corners);
  const Eigen::Vector3d& t = calibration.proj_from_cam.translation;
  const double angle =
      RotationAngleBetween(calibration.proj_from_cam.rotation, Eigen::Matrix3d::Identity());
  report += fmt::format(
      "  {:<14}baseline {:.4f} m, rotation {:.3f} deg, t = [{:.4f}, {:.4f}, {:.4f}] m\n",
      "proj_from_cam", calibration.BaselineLength(), angle * internal::kDegreesPerRadian, t.x(),
      t.y(), t.z());
  report += fmt::format(
      "  {:<14}camera {:.3f} px, projector {:.3f} px, both {:.3f} px "
      "(initial OpenCV: {:.3f}, {:.3f})\n",
      "RMS", calibration.rms_camera_px, calibration.rms_projector_px, calibration.rms_stereo_px,
      initial_rms_camera_px, initial_rms_projector_px);
  report +=
      fmt::format("  {:<14}{}, {} iterations, cost {:.6g} -> {:.6g}\n", "Ceres", solver_termination,
                  solver_iterations, solver_initial_cost, solver_final_cost);
  report += fmt::format("  {:<14}detection {:.2f} s, solve {:.2f} s\n", "time", detection_seconds,
                        solve_seconds);
  for (const CalibrationViewReport& view : views) {
    if (!view.used) report += fmt::format("  {:<14}{}: {}\n", "skipped", view.name, view.status);
  }
  return report;
}

// ---- calibrator ---------------------------------------------------------------------

RigCalibrator::RigCalibrator(const BoardSpec& board, const CalibrationOptions& options)
    : board_(board), options_(options) {
  board_.Check();
  options_.Check();
}

int RigCalibrator::NumUsableViews() const {
  return static_cast<int>(std::count_if(views_.begin(), views_.end(),
                                        [](const View& v) { return v.observation.has_value(); }));
}

void RigCalibrator::CheckSizes(const DeviceSizes& sizes, const std::string& name) {
  if (!sizes_) {
    sizes_ = sizes;
    first_view_name_ = name;
    return;
  }
  SOPE_CHECK(sizes == *sizes_,
             "view {} has a {}x{} camera and a {}x{} projector but view {} has {}x{} and "
             "{}x{}: all views must come from one rig",
             name, sizes.camera_width, sizes.camera_height, sizes.projector_width,
             sizes.projector_height, first_view_name_, sizes_->camera_width, sizes_->camera_height,
             sizes_->projector_width, sizes_->projector_height);
}

std::optional<BoardObservation> RigCalibrator::AddFrameSet(const FrameSet& frames,
                                                           std::string name) {
  if (name.empty()) {
    name = frames.directory.empty() ? fmt::format("view {}", views_.size()) : frames.directory;
  }
  const FrameSetManifest& manifest = frames.manifest;
  // Code frames or phase groups (or both) on each axis.
  const auto coded = [&](PatternAxis axis) {
    return manifest.HasAxis(axis) || manifest.HasPhaseAxis(axis);
  };
  SOPE_CHECK(coded(PatternAxis::kX) && coded(PatternAxis::kY),
             "view {}: calibration needs both x and y codes, the frame set codes only {}", name,
             coded(PatternAxis::kX) ? "x" : coded(PatternAxis::kY) ? "y" : "neither");
  const std::optional<size_t> white = manifest.Find(FrameRole::kWhite);
  SOPE_CHECK(white.has_value() || manifest.HasPhase(),
             "view {}: the frame set has no white frame (needed to find the board) and no "
             "phase frames to synthesise one from",
             name);
  CheckSizes({manifest.camera_width, manifest.camera_height, manifest.projector_width,
              manifest.projector_height},
             name);
  const auto start = std::chrono::steady_clock::now();
  View view;
  view.name = name;
  // Without a white frame the board is found in the phase texture (mean + amplitude of the
  // finest group: what a white frame would show).
  const cv::Mat board_image = white ? frames.Image(*white) : SynthesizePhaseTexture(frames);
  const std::optional<BoardDetection> detection =
      DetectBoard(board_image, board_, options_.detection);
  if (!detection) {
    spdlog::warn("view {}: board {} not found in the {}; view skipped", name,
                 board_.PatternSizeString(), white ? "white frame" : "phase texture");
    views_.push_back(view);
    detection_seconds_ += internal::SecondsSince(start);
    return std::nullopt;
  }
  DecoderOptions decoder = options_.decoder;
  decoder.gray_subpixel = options_.subpixel_codes ? GraySubpixel::kEdges : GraySubpixel::kOff;
  const CorrespondenceMap map = Decode(frames, decoder);
  BoardObservation observation;
  observation.name = name;
  observation.camera_corners = detection->corners;
  if (detection->partial) {
    observation.corner_indices = detection->indices;
    observation.partial = true;
  }
  // The visible grid as a board of its own: the neighbours of each corner.
  observation.projector_corners = FindProjectorCorners(
      map, detection->GridSpec(board_), detection->corners, options_.local_homography);
  spdlog::debug("view {}: {} corners{}, {} seen by the projector", name,
                detection->corners.size(),
                detection->partial ? fmt::format(" ({}x{} of the board in view)",
                                                 detection->grid_cols, detection->grid_rows)
                                   : "",
                observation.NumProjectorCorners());
  view.observation = observation;
  views_.push_back(view);
  detection_seconds_ += internal::SecondsSince(start);
  return observation;
}

void RigCalibrator::AddObservation(const BoardObservation& observation, const DeviceSizes& sizes) {
  const int expected = observation.corner_indices.empty()
                           ? board_.NumCorners()
                           : static_cast<int>(observation.corner_indices.size());
  for (int index : observation.corner_indices) {
    SOPE_CHECK(index >= 0 && index < board_.NumCorners(),
               "view {}: corner index {} is not a corner of a {} board ({} corners)",
               observation.name, index, board_.PatternSizeString(), board_.NumCorners());
  }
  SOPE_CHECK(static_cast<int>(observation.camera_corners.size()) == expected &&
                 observation.projector_corners.size() == observation.camera_corners.size(),
             "view {}: {} camera and {} projector corners for a {} board ({} corners)",
             observation.name, observation.camera_corners.size(),
             observation.projector_corners.size(), board_.PatternSizeString(), board_.NumCorners());
  CheckSizes(sizes, observation.name);
  views_.push_back(View{observation.name, observation});
}

CalibrationSummary RigCalibrator::Calibrate() const {
  using namespace internal;
  SOPE_CHECK(!views_.empty(), "no views to calibrate from");
  const int usable = NumUsableViews();
  const int given = NumViews();
  SOPE_CHECK(usable > 0,
             "board {} not found in any view — check --board (COLSxROWS counts "
             "inner corners)",
             board_.PatternSizeString());
  SOPE_CHECK(usable >= options_.min_views,
             "only {} usable view{} (board found in {} of {}); calibration needs at least {}",
             usable, usable == 1 ? "" : "s", usable, given, options_.min_views);
  const auto start = std::chrono::steady_clock::now();
  const DeviceSizes& sizes = *sizes_;

  // Usable views: their observations, in order.
  std::vector<const BoardObservation*> observations;
  std::vector<int> view_of;  // observation index → index into views_
  for (int v = 0; v < given; ++v) {
    if (views_[v].observation) {
      observations.push_back(&*views_[v].observation);
      view_of.push_back(v);
    }
  }
  const int count = static_cast<int>(observations.size());

  // Camera: Zhang's method on every usable view.
  CalibrationSummary summary;
  summary.board = board_;
  RigState state;
  std::vector<Rigid3d> cam_from_board;
  {
    std::vector<std::vector<Eigen::Vector2d>> corners;
    std::vector<std::vector<int>> indices;
    for (const BoardObservation* observation : observations) {
      corners.push_back(observation->camera_corners);
      indices.emplace_back();
      for (size_t k = 0; k < observation->camera_corners.size(); ++k) {
        indices.back().push_back(observation->CornerIndex(k));
      }
    }
    summary.initial_rms_camera_px =
        CalibrateDevice(board_, corners, indices, sizes.camera_width, sizes.camera_height,
                        options_.camera_distortion, &state.camera, &cam_from_board);
  }
  for (const Rigid3d& pose : cam_from_board) state.cam_from_board.push_back(ToPoseBlock(pose));

  // Projector as an inverse camera on the views where it saw most corners.
  {
    std::vector<std::vector<Eigen::Vector2d>> corners;
    std::vector<std::vector<int>> indices;
    std::vector<int> projector_views;
    const int min_corners = std::max(
        6,
        static_cast<int>(std::ceil(options_.min_projector_corner_fraction * board_.NumCorners())));
    for (int i = 0; i < count; ++i) {
      const BoardObservation& observation = *observations[i];
      if (observation.NumProjectorCorners() < min_corners) continue;
      corners.emplace_back();
      indices.emplace_back();
      for (size_t k = 0; k < observation.projector_corners.size(); ++k) {
        if (!observation.projector_corners[k]) continue;
        corners.back().push_back(*observation.projector_corners[k]);
        indices.back().push_back(observation.CornerIndex(k));
      }
      projector_views.push_back(i);
    }
    SOPE_CHECK(static_cast<int>(projector_views.size()) >= options_.min_views,
               "the projector saw at least {} of the {} board corners in only {} of {} views; "
               "calibration needs at least {} (are the x and y codes decodable on the board?)",
               min_corners, board_.NumCorners(), projector_views.size(), count, options_.min_views);
    std::vector<Rigid3d> proj_from_board;
    summary.initial_rms_projector_px =
        CalibrateDevice(board_, corners, indices, sizes.projector_width, sizes.projector_height,
                        options_.projector_distortion, &state.projector, &proj_from_board);
    std::vector<Rigid3d> proj_from_cam;
    for (size_t j = 0; j < projector_views.size(); ++j) {
      proj_from_cam.push_back(proj_from_board[j] * cam_from_board[projector_views[j]].Inverse());
    }
    state.proj_from_cam = ToPoseBlock(AveragePose(proj_from_cam));
  }

  // Joint adjustment; drop views that do not fit and solve again.
  std::vector<int> active(count);
  for (int i = 0; i < count; ++i) active[i] = i;
  std::vector<std::string> drop_reason(count);
  ceres::Solver::Summary solver_summary;
  for (int round = 0;; ++round) {
    solver_summary = Adjust(board_, observations, active, options_, false, &state);
    spdlog::debug("calibration round {}: {}", round, solver_summary.BriefReport());
    if (round == options_.max_drop_rounds) break;
    std::vector<double> rms(count, kNaN);
    std::vector<double> active_rms;
    for (int i : active) {
      rms[i] = ComputeResiduals(board_, *observations[i], state, state.cam_from_board[i]).Rms();
      active_rms.push_back(rms[i]);
    }
    const double median = Median(active_rms);
    std::vector<int> kept;
    for (int i : active) {
      if (rms[i] > options_.max_view_rms_ratio * median && rms[i] > options_.min_outlier_rms_px) {
        drop_reason[i] = fmt::format("dropped: RMS {:.3f} px > {:g} x the median {:.3f} px", rms[i],
                                     options_.max_view_rms_ratio, median);
        spdlog::warn("view {}: {}", observations[i]->name, drop_reason[i]);
      } else {
        kept.push_back(i);
      }
    }
    if (kept.size() == active.size()) break;
    SOPE_CHECK(static_cast<int>(kept.size()) >= options_.min_views,
               "only {} of {} views fit a common calibration (the others have reprojection "
               "errors far above the median); calibration needs at least {}",
               kept.size(), count, options_.min_views);
    active = kept;
  }
  // Dropped views: their board pose re-fitted to the final calibration, for the report.
  for (int i = 0; i < count; ++i) {
    if (!drop_reason[i].empty()) Adjust(board_, observations, {i}, options_, true, &state);
  }

  // Results.
  RigCalibration& calibration = summary.calibration;
  calibration.camera = state.camera.ToModel(sizes.camera_width, sizes.camera_height);
  calibration.projector = state.projector.ToModel(sizes.projector_width, sizes.projector_height);
  calibration.proj_from_cam = FromPoseBlock(state.proj_from_cam.data());
  double camera_sum = 0.0, projector_sum = 0.0;
  summary.views.resize(given);
  for (int v = 0; v < given; ++v) {
    summary.views[v].name = views_[v].name;
    summary.views[v].status = "board not found";
    summary.views[v].rms_camera_px = summary.views[v].rms_projector_px = summary.views[v].rms_px =
        kNaN;
  }
  for (int i = 0; i < count; ++i) {
    CalibrationViewReport& report = summary.views[view_of[i]];
    const ViewResiduals residuals =
        ComputeResiduals(board_, *observations[i], state, state.cam_from_board[i]);
    report.board_found = true;
    report.partial = observations[i]->partial;
    report.used = drop_reason[i].empty();
    report.status = report.used ? "used" : drop_reason[i];
    report.camera_corners = static_cast<int>(residuals.camera.size());
    report.projector_corners = static_cast<int>(residuals.projector.size());
    report.rms_camera_px = residuals.RmsCamera();
    report.rms_projector_px = residuals.RmsProjector();
    report.rms_px = residuals.Rms();
    report.cam_from_board = FromPoseBlock(state.cam_from_board[i].data());
    report.camera_residuals_px = residuals.camera;
    report.projector_residuals_px = residuals.projector;
    if (report.used) {
      ++summary.num_views_used;
      if (report.partial) ++summary.num_partial_views_used;
      summary.num_camera_corners += report.camera_corners;
      summary.num_projector_corners += report.projector_corners;
      camera_sum += residuals.SumSquaredCamera();
      projector_sum += residuals.SumSquaredProjector();
    } else {
      ++summary.num_views_dropped;
    }
  }
  summary.num_views_without_board = given - count;
  calibration.rms_camera_px = std::sqrt(camera_sum / std::max(summary.num_camera_corners, 1));
  calibration.rms_projector_px =
      std::sqrt(projector_sum / std::max(summary.num_projector_corners, 1));
  calibration.rms_stereo_px =
      std::sqrt((camera_sum + projector_sum) /
                std::max(summary.num_camera_corners + summary.num_projector_corners, 1));
  summary.solver_termination = ceres::TerminationTypeToString(solver_summary.termination_type);
  summary.solver_iterations = static_cast<int>(solver_summary.iterations.size());
  summary.solver_initial_cost = solver_summary.initial_cost;
  summary.solver_final_cost = solver_summary.final_cost;
  summary.detection_seconds = detection_seconds_;
  summary.solve_seconds = SecondsSince(start);
  SOPE_CHECK(solver_summary.IsSolutionUsable(), "bundle adjustment failed: {}",
             solver_summary.message);
  calibration.Check();
  return summary;
}

CalibrationSummary CalibrateRig(const std::vector<FrameSet>& frame_sets, const BoardSpec& board,
                                const CalibrationOptions& options) {
  RigCalibrator calibrator(board, options);
  for (const FrameSet& frames : frame_sets) calibrator.AddFrameSet(frames);
  return calibrator.Calibrate();
}

}  // namespace sope
