#include "calibration/calibration_report.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/json.h"
#include "core/plots.h"

namespace sope {
namespace internal {
namespace {

nlohmann::json DeviceJson(const CameraModel& model, double rms) {
  return {{"width", model.width},
          {"height", model.height},
          {"fx", model.fx()},
          {"fy", model.fy()},
          {"cx", model.cx()},
          {"cy", model.cy()},
          {"distortion", model.distortion},
          {"rms_px", JsonNumber(rms)}};
}

// Last path component, for short labels.
std::string ShortName(const std::string& name) {
  std::string trimmed = name;
  while (trimmed.size() > 1 && trimmed.back() == '/') trimmed.pop_back();
  const size_t slash = trimmed.rfind('/');
  return slash == std::string::npos ? trimmed : trimmed.substr(slash + 1);
}

const cv::Scalar kCameraColour(190, 110, 30);     // blue
const cv::Scalar kProjectorColour(20, 140, 240);  // orange
const cv::Scalar kInk(40, 40, 40);
const cv::Scalar kGrid(215, 215, 215);
const cv::Scalar kDropped(30, 30, 220);  // red

void Text(cv::Mat* image, const std::string& text, cv::Point at, double scale = 0.45,
          const cv::Scalar& colour = kInk, int thickness = 1) {
  cv::putText(*image, HersheyText(text), at, cv::FONT_HERSHEY_SIMPLEX, scale, colour, thickness, cv::LINE_AA);
}

// A "nice" axis maximum ≥ value: 1, 2 or 5 × 10^k.
double NiceCeil(double value) {
  if (!(value > 0)) return 1.0;
  const double power = std::pow(10.0, std::floor(std::log10(value)));
  for (double step : {1.0, 2.0, 5.0, 10.0}) {
    if (step * power >= value) return step * power;
  }
  return 10.0 * power;
}

cv::Scalar ViewColour(size_t index, size_t count) {
  cv::Mat hsv(
      1, 1, CV_8UC3,
      cv::Scalar(static_cast<double>(150.0 * index / std::max<size_t>(count, 1)), 220, 200));
  cv::Mat bgr;
  cv::cvtColor(hsv, bgr, cv::COLOR_HSV2BGR);
  const cv::Vec3b c = bgr.at<cv::Vec3b>(0, 0);
  return cv::Scalar(c[0], c[1], c[2]);
}

void DrawScatter(cv::Mat* image, const cv::Rect& area, const CalibrationSummary& summary,
                 bool projector) {
  cv::rectangle(*image, area, kInk, 1);
  // The scale follows the used views; residuals of dropped views beyond it sit on the
  // border, in their direction.
  std::vector<double> norms;
  for (const CalibrationViewReport& view : summary.views) {
    if (!view.used) continue;
    for (const Eigen::Vector2d& r :
         projector ? view.projector_residuals_px : view.camera_residuals_px) {
      norms.push_back(r.norm());
    }
  }
  double range = 1.0;
  if (!norms.empty()) {
    std::sort(norms.begin(), norms.end());
    range = NiceCeil(std::max(1.1 * norms[static_cast<size_t>(0.99 * (norms.size() - 1))], 0.1));
  }
  const cv::Point centre(area.x + area.width / 2, area.y + area.height / 2);
  const double pixels_per_unit = 0.5 * std::min(area.width, area.height) / range;
  cv::line(*image, {area.x, centre.y}, {area.x + area.width, centre.y}, kGrid, 1);
  cv::line(*image, {centre.x, area.y}, {centre.x, area.y + area.height}, kGrid, 1);
  for (double ring : {0.25, 0.5, 1.0}) {
    const int radius = static_cast<int>(ring * range * pixels_per_unit);
    cv::circle(*image, centre, radius, kGrid, 1, cv::LINE_AA);
    Text(image, fmt::format("{:g}", ring * range), {centre.x + radius + 2, centre.y - 3}, 0.38,
         cv::Scalar(150, 150, 150));
  }
  for (size_t v = 0; v < summary.views.size(); ++v) {
    const CalibrationViewReport& view = summary.views[v];
    const cv::Scalar colour = view.used ? ViewColour(v, summary.views.size()) : kDropped;
    for (Eigen::Vector2d r : projector ? view.projector_residuals_px : view.camera_residuals_px) {
      if (r.norm() > range) r *= range / r.norm();
      const cv::Point p(centre.x + static_cast<int>(std::lround(r.x() * pixels_per_unit)),
                        centre.y + static_cast<int>(std::lround(r.y() * pixels_per_unit)));
      if (view.used) {
        cv::circle(*image, p, 2, colour, cv::FILLED, cv::LINE_AA);
      } else {
        cv::drawMarker(*image, p, colour, cv::MARKER_CROSS, 5, 1);
      }
    }
  }
  Text(image,
       fmt::format(
           "{} residuals (predicted - observed), px; RMS {:.3f} px",
           projector ? "projector" : "camera",
           projector ? summary.calibration.rms_projector_px : summary.calibration.rms_camera_px),
       {area.x, area.y - 8}, 0.5);
}

}  // namespace
}  // namespace internal

std::string CalibrationReportJson(const CalibrationSummary& summary) {
  nlohmann::json views = nlohmann::json::array();
  for (const CalibrationViewReport& view : summary.views) {
    nlohmann::json entry = {{"name", view.name},
                            {"status", view.status},
                            {"board_found", view.board_found},
                            {"used", view.used},
                            {"partial", view.partial},
                            {"camera_corners", view.camera_corners},
                            {"projector_corners", view.projector_corners},
                            {"rms_camera_px", JsonNumber(view.rms_camera_px)},
                            {"rms_projector_px", JsonNumber(view.rms_projector_px)},
                            {"rms_px", JsonNumber(view.rms_px)}};
    if (view.board_found) entry["cam_from_board"] = Rigid3dToJson(view.cam_from_board);
    views.push_back(entry);
  }
  const RigCalibration& calibration = summary.calibration;
  const nlohmann::json root = {
      {"format", "sope-calibration-report/1"},
      {"units", "pixels; metres; cam_from_board maps board to camera (X_cam = R X_board + t)"},
      {"board",
       {{"cols", summary.board.cols},
        {"rows", summary.board.rows},
        {"square_size_m", summary.board.square_size}}},
      {"views_given", summary.views.size()},
      {"views_used", summary.num_views_used},
      {"views_dropped", summary.num_views_dropped},
      {"views_without_board", summary.num_views_without_board},
      {"views_partial_used", summary.num_partial_views_used},
      {"camera", internal::DeviceJson(calibration.camera, calibration.rms_camera_px)},
      {"projector", internal::DeviceJson(calibration.projector, calibration.rms_projector_px)},
      {"proj_from_cam", Rigid3dToJson(calibration.proj_from_cam)},
      {"baseline_m", calibration.BaselineLength()},
      {"rms_camera_px", JsonNumber(calibration.rms_camera_px)},
      {"rms_projector_px", JsonNumber(calibration.rms_projector_px)},
      {"rms_stereo_px", JsonNumber(calibration.rms_stereo_px)},
      {"initial_rms_camera_px", JsonNumber(summary.initial_rms_camera_px)},
      {"initial_rms_projector_px", JsonNumber(summary.initial_rms_projector_px)},
      {"solver",
       {{"termination", summary.solver_termination},
        {"iterations", summary.solver_iterations},
        {"initial_cost", summary.solver_initial_cost},
        {"final_cost", summary.solver_final_cost}}},
      {"detection_seconds", summary.detection_seconds},
      {"solve_seconds", summary.solve_seconds},
      {"views", views}};
  return root.dump(2) + "\n";
}

void WriteCalibrationReport(const std::string& path, const CalibrationSummary& summary) {
  WriteFileAtomic(path, CalibrationReportJson(summary));
}

cv::Mat DrawResidualPlot(const CalibrationSummary& summary) {
  using namespace internal;
  constexpr int kWidth = 1200, kHeight = 960;
  cv::Mat image(kHeight, kWidth, CV_8UC3, cv::Scalar(255, 255, 255));

  // Bars: per-view RMS of each device.
  const cv::Rect bars(70, 50, kWidth - 100, 300);
  Text(&image,
       fmt::format("Per-view RMS reprojection error, px   (board {}, {} of {} views used)",
                   summary.board.ToString(), summary.num_views_used, summary.views.size()),
       {bars.x, 24}, 0.6);
  // The scale follows the used views; bars of dropped views beyond it are cut at the top
  // and carry their value.
  double largest = 0.0;
  std::vector<double> used_rms;
  for (const CalibrationViewReport& view : summary.views) {
    if (!view.used) continue;
    for (double rms : {view.rms_camera_px, view.rms_projector_px}) {
      if (std::isfinite(rms)) largest = std::max(largest, rms);
    }
    if (std::isfinite(view.rms_px)) used_rms.push_back(view.rms_px);
  }
  const double top = NiceCeil(std::max(1.15 * largest, 0.05));
  const auto y_of = [&](double value) {
    return bars.y + bars.height -
           static_cast<int>(std::lround(std::min(value, top) / top * bars.height));
  };
  for (int tick = 0; tick <= 5; ++tick) {
    const double value = top * tick / 5.0;
    cv::line(image, {bars.x, y_of(value)}, {bars.x + bars.width, y_of(value)}, kGrid, 1);
    Text(&image, fmt::format("{:.3g}", value), {8, y_of(value) + 4}, 0.4);
  }
  std::string median_label;
  int median_y = 0;
  if (!used_rms.empty()) {
    std::sort(used_rms.begin(), used_rms.end());
    const double median = used_rms[used_rms.size() / 2];
    cv::line(image, {bars.x, y_of(median)}, {bars.x + bars.width, y_of(median)},
             cv::Scalar(120, 120, 120), 1, cv::LINE_AA);
    median_label = fmt::format("median view RMS (both devices) {:.3f}", median);
    median_y = y_of(median);
  }
  const int count = std::max<int>(1, static_cast<int>(summary.views.size()));
  const double slot = static_cast<double>(bars.width) / count;
  const int bar_width = std::max(1, static_cast<int>(slot * 0.35));
  // Names when they fit, else view numbers (every k-th); the report JSON has the names.
  const bool names_fit = slot >= 90;
  const int label_every = names_fit ? 1 : std::max(1, static_cast<int>(std::ceil(28.0 / slot)));
  for (int v = 0; v < static_cast<int>(summary.views.size()); ++v) {
    const CalibrationViewReport& view = summary.views[v];
    const int x = bars.x + static_cast<int>(slot * v + slot * 0.15);
    if (v % label_every == 0) {
      std::string label = names_fit ? ShortName(view.name) : std::to_string(v);
      if (label.size() > 12) label = label.substr(label.size() - 12);
      Text(&image, label, {x, bars.y + bars.height + 16}, 0.35);
    }
    if (!view.board_found) {
      cv::drawMarker(image, {x + bar_width, bars.y + bars.height - 6}, cv::Scalar(150, 150, 150),
                     cv::MARKER_TILTED_CROSS, 8, 1);
      continue;
    }
    const std::pair<double, cv::Scalar> values[] = {{view.rms_camera_px, kCameraColour},
                                                    {view.rms_projector_px, kProjectorColour}};
    for (int d = 0; d < 2; ++d) {
      if (!std::isfinite(values[d].first)) continue;
      const cv::Rect bar(x + d * bar_width, y_of(values[d].first), bar_width,
                         bars.y + bars.height - y_of(values[d].first));
      cv::rectangle(image, bar, values[d].second, cv::FILLED);
      if (!view.used) cv::rectangle(image, bar, kDropped, 2);
    }
    if (!view.used) {
      const std::string value = fmt::format("{:.3g}", view.rms_px);
      const int text_x = std::min(x, bars.x + bars.width - 8 * static_cast<int>(value.size()));
      Text(&image, value, {text_x, bars.y - 4}, 0.4, kDropped);
    }
  }
  if (!median_label.empty()) {  // on a white box, over the bars
    int baseline = 0;
    const cv::Size size =
        cv::getTextSize(HersheyText(median_label), cv::FONT_HERSHEY_SIMPLEX, 0.4, 1, &baseline);
    const cv::Point at(bars.x + bars.width - size.width - 12, median_y - 5);
    cv::rectangle(image,
                  cv::Rect(at.x - 3, at.y - size.height - 3, size.width + 6, size.height + 6),
                  cv::Scalar(255, 255, 255), cv::FILLED);
    Text(&image, median_label, at, 0.4, cv::Scalar(110, 110, 110));
  }
  cv::rectangle(image, bars, kInk, 1);
  cv::rectangle(image, cv::Rect(bars.x + 10, bars.y + 8, 12, 12), kCameraColour, cv::FILLED);
  Text(&image, "camera", {bars.x + 26, bars.y + 19}, 0.45);
  cv::rectangle(image, cv::Rect(bars.x + 100, bars.y + 8, 12, 12), kProjectorColour, cv::FILLED);
  Text(&image, "projector", {bars.x + 116, bars.y + 19}, 0.45);
  if (summary.num_views_dropped > 0) {
    cv::rectangle(image, cv::Rect(bars.x + 205, bars.y + 8, 12, 12), kDropped, 2);
    Text(&image, "dropped (RMS in red)", {bars.x + 221, bars.y + 19}, 0.45);
  }
  if (summary.num_views_without_board > 0) {
    cv::drawMarker(image, {bars.x + 410, bars.y + 14}, cv::Scalar(150, 150, 150),
                   cv::MARKER_TILTED_CROSS, 8, 1);
    Text(&image, "board not found", {bars.x + 420, bars.y + 19}, 0.45);
  }

  // Scatter plots of the residual vectors.
  const int side = 520;
  DrawScatter(&image, cv::Rect(40, 420, side, side), summary, false);
  DrawScatter(&image, cv::Rect(kWidth - side - 40, 420, side, side), summary, true);
  return image;
}

std::string CalibrationSidecarPath(const std::string& calibration_path, const std::string& suffix) {
  const size_t slash = calibration_path.rfind('/');
  const size_t dot = calibration_path.rfind('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash) ||
      dot == (slash == std::string::npos ? 0 : slash + 1)) {
    return calibration_path + suffix;
  }
  return calibration_path.substr(0, dot) + suffix;
}

}  // namespace sope
