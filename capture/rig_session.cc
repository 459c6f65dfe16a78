#include "capture/rig_session.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/file_util.h"

namespace sope {
namespace {

constexpr const char* kCalibrationFile = "calibration.yaml";
constexpr const char* kCaptureLogFile = "capture.json";

double Median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

}  // namespace

void RigSessionOptions::Check() const {
  SOPE_CHECK(std::isfinite(latency) && latency <= 10.0,
             "latency {} s must be <= 10 (negative: measure it)", latency);
  SOPE_CHECK(settle >= 0.0 && settle <= 10.0, "settle time {} s must be in 0..10", settle);
  SOPE_CHECK(latency_flashes >= 1 && latency_flashes <= 100, "latency flashes {} must be in 1..100",
             latency_flashes);
  SOPE_CHECK(max_latency > 0.0 && max_latency <= 10.0, "maximum latency {} s must be in (0, 10]",
             max_latency);
  SOPE_CHECK(min_flash_contrast > 0.0, "minimum flash contrast {} must be positive",
             min_flash_contrast);
  SOPE_CHECK(min_lit_fraction > 0.0 && min_lit_fraction <= 1.0,
             "minimum lit fraction {} must be in (0, 1]", min_lit_fraction);
  SOPE_CHECK(transition_fraction > 0.0 && transition_fraction < 1.0,
             "transition fraction {} must be in (0, 1)", transition_fraction);
  SOPE_CHECK(grab_timeout > 0.0, "grab timeout {} s must be positive", grab_timeout);
}

std::string LatencyMeasurement::Summary() const {
  if (samples.empty()) return fmt::format("latency {:.1f} ms (not measured)", 1e3 * latency);
  const auto [lowest, highest] = std::minmax_element(samples.begin(), samples.end());
  return fmt::format(
      "latency {:.1f} ms ({:.2f} frames; {} transitions {:.1f}–{:.1f} ms), black {:.0f} / white "
      "{:.0f} grey levels on {:.0f}% of the image",
      1e3 * latency, frames(), samples.size(), 1e3 * *lowest, 1e3 * *highest, black_level,
      white_level, 100 * lit_fraction);
}

FrameSetManifest ManifestForPatterns(const std::vector<Pattern>& patterns, int camera_width,
                                     int camera_height) {
  SOPE_CHECK(!patterns.empty(), "no patterns to capture");
  FrameSetManifest manifest;
  manifest.camera_width = camera_width;
  manifest.camera_height = camera_height;
  manifest.projector_width = patterns.front().image.cols;
  manifest.projector_height = patterns.front().image.rows;
  for (const Pattern& pattern : patterns) {
    SOPE_CHECK(pattern.image.cols == manifest.projector_width &&
                   pattern.image.rows == manifest.projector_height,
               "pattern {} is {}x{}, the first was {}x{}", pattern.info.file, pattern.image.cols,
               pattern.image.rows, manifest.projector_width, manifest.projector_height);
    manifest.frames.push_back(pattern.info);
  }
  return manifest;
}

RigSession::RigSession(Display& display, Camera& camera, const RigSessionOptions& options)
    : display_(display), camera_(camera), options_(options) {
  options_.Check();
  if (options_.latency >= 0.0) {
    measurement_.latency = options_.latency;
    measurement_.frame_period = camera_.frame_period();
    have_latency_ = true;
  }
}

void RigSession::CheckCancelled() const {
  SOPE_CHECK(!options_.cancel || !options_.cancel->load(), "interrupted");
}

Frame RigSession::ShowAndGrab(const cv::Mat& image, const FrameInfo* info, double wait,
                              double* shown) {
  CheckCancelled();
  display_.Show(image);
  *shown = camera_.Now();
  GrabRequest request;
  request.not_before = *shown + wait;
  request.timeout = wait + options_.grab_timeout;
  request.showing = info;
  Frame frame = camera_.Grab(request);
  SOPE_CHECK(frame.image.cols == camera_.width() && frame.image.rows == camera_.height(),
             "camera {} delivered a {}x{} frame, expected {}x{}", camera_.name(), frame.image.cols,
             frame.image.rows, camera_.width(), camera_.height());
  return frame;
}

const LatencyMeasurement& RigSession::MeasureLatency() {
  LatencyMeasurement measurement;
  measurement.frame_period = camera_.frame_period();
  if (!camera_.live()) {
    measurement_ = measurement;
    have_latency_ = true;
    return measurement_;
  }
  const cv::Mat black = cv::Mat::zeros(display_.height(), display_.width(), CV_8UC1);
  const cv::Mat white(display_.height(), display_.width(), CV_8UC1, cv::Scalar(255));
  // Reference frames, each well after its pattern reached the sensor.
  double shown = 0.0;
  cv::Mat black_frame, white_frame;
  ShowAndGrab(black, nullptr, options_.max_latency, &shown).image.convertTo(black_frame, CV_32F);
  ShowAndGrab(white, nullptr, options_.max_latency, &shown).image.convertTo(white_frame, CV_32F);
  const cv::Mat lit = (white_frame - black_frame) >= options_.min_flash_contrast;
  const int lit_pixels = cv::countNonZero(lit);
  measurement.lit_fraction = static_cast<double>(lit_pixels) / lit.total();
  measurement.black_level = cv::mean(black_frame, lit)[0];
  measurement.white_level = cv::mean(white_frame, lit)[0];
  SOPE_CHECK(measurement.lit_fraction >= options_.min_lit_fraction,
             "camera {} does not see the projector: only {:.3f}% of its pixels get ≥ {} grey "
             "levels brighter when the projector turns from black to white (projector on and "
             "in view? exposure too short or saturated?)",
             camera_.name(), 100 * measurement.lit_fraction, options_.min_flash_contrast);

  bool showing_white = true;
  for (int flash = 0; flash < options_.latency_flashes; ++flash) {
    const double old_level = showing_white ? measurement.white_level : measurement.black_level;
    const double new_level = showing_white ? measurement.black_level : measurement.white_level;
    const double threshold = old_level + options_.transition_fraction * (new_level - old_level);
    showing_white = !showing_white;
    CheckCancelled();
    display_.Show(showing_white ? white : black);
    const double t_show = camera_.Now();
    GrabRequest request;
    request.not_before = t_show;  // frames exposed earlier cannot show the transition
    while (true) {
      request.timeout =
          std::max(t_show + options_.max_latency - camera_.Now(), 0.0) + options_.grab_timeout;
      const Frame frame = camera_.Grab(request);
      const double level = cv::mean(frame.image, lit)[0];
      const bool arrived = new_level > old_level ? level >= threshold : level <= threshold;
      const double delay = frame.exposure_start - t_show;
      if (arrived) {
        measurement.samples.push_back(delay);
        break;
      }
      SOPE_CHECK(delay <= options_.max_latency,
                 "camera {}: the projector turned {} but no frame exposed within {:.2f} s "
                 "shows it (mean level {:.0f}, expected {:.0f})",
                 camera_.name(), showing_white ? "white" : "black", options_.max_latency, level,
                 new_level);
      request.not_before = std::nextafter(frame.exposure_start, HUGE_VAL);
    }
  }
  measurement.latency = Median(measurement.samples);
  measurement_ = measurement;
  have_latency_ = true;
  spdlog::info("camera {}: {}", camera_.name(), measurement_.Summary());
  return measurement_;
}

double RigSession::latency() {
  if (!have_latency_) MeasureLatency();
  return measurement_.latency;
}

FrameSet RigSession::CaptureInto(const std::vector<Pattern>& patterns, const std::string& staging,
                                 const Progress& progress) {
  FrameSet frames;
  frames.manifest = ManifestForPatterns(patterns, camera_.width(), camera_.height());
  SOPE_CHECK(frames.manifest.projector_width == display_.width() &&
                 frames.manifest.projector_height == display_.height(),
             "patterns are {}x{} but the {} is {}x{}", frames.manifest.projector_width,
             frames.manifest.projector_height, display_.name(), display_.width(),
             display_.height());
  const double wait = latency() + options_.settle;
  timings_.clear();
  for (size_t i = 0; i < patterns.size(); ++i) {
    FrameTiming timing;
    const Frame frame = ShowAndGrab(patterns[i].image, &patterns[i].info, wait, &timing.shown);
    timing.exposure_start = frame.exposure_start;
    timing.sequence = frame.sequence;
    timings_.push_back(timing);
    frames.images.push_back(frame.image);
    if (frame_sink_) frame_sink_(frames.manifest, i, frames.images.back());
    if (!staging.empty()) WriteImageAtomic(JoinPath(staging, patterns[i].info.file), frame.image);
    if (progress) progress(i + 1, patterns.size());
  }
  // Leave the projector dark between scans.
  display_.Show(cv::Mat::zeros(display_.height(), display_.width(), CV_8UC1));
  frames.Check();
  return frames;
}

FrameSet RigSession::Capture(const std::vector<Pattern>& patterns, const Progress& progress) {
  return CaptureInto(patterns, "", progress);
}

FrameSet RigSession::Record(const std::vector<Pattern>& patterns, const std::string& directory,
                            const RigCalibration* calibration, const Progress& progress) {
  StagedDirectory staged(directory, FrameSetManifest::kFileName);
  FrameSet frames = CaptureInto(patterns, staged.path(), progress);
  if (calibration) {
    frames.manifest.calibration = kCalibrationFile;
    WriteRigCalibration(JoinPath(staged.path(), kCalibrationFile), *calibration);
  }
  nlohmann::json log;
  log["format"] = "sope-capture/1";
  log["units"] = "seconds on the camera clock";
  log["camera"] = camera_.description();
  log["display"] = display_.name();
  log["latency"] = measurement_.latency;
  log["latency_samples"] = measurement_.samples;
  log["settle"] = options_.settle;
  log["frame_period"] = camera_.frame_period();
  nlohmann::json timing_list = nlohmann::json::array();
  for (size_t i = 0; i < timings_.size(); ++i) {
    timing_list.push_back({{"file", frames.manifest.frames[i].file},
                           {"shown", timings_[i].shown},
                           {"exposure_start", timings_[i].exposure_start},
                           {"sequence", timings_[i].sequence}});
  }
  log["frames"] = timing_list;
  WriteFileAtomic(JoinPath(staged.path(), kCaptureLogFile), log.dump(2) + "\n");
  WriteFileAtomic(JoinPath(staged.path(), FrameSetManifest::kFileName),
                  SerializeFrameSetManifest(frames.manifest));
  staged.Commit();
  frames.directory = directory;
  return frames;
}

}  // namespace sope
