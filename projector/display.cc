#include "projector/display.h"

#include <algorithm>
#include <opencv2/imgproc.hpp>

#include "core/error.h"

namespace sope {

namespace internal {

void CheckPattern(const cv::Mat& pattern, int width, int height, const std::string& display_name) {
  SOPE_CHECK(pattern.type() == CV_8UC1 || pattern.type() == CV_8UC3,
             "{}: patterns must be 8-bit grey or BGR images, got {}", display_name,
             cv::typeToString(pattern.type()));
  SOPE_CHECK(pattern.cols == width && pattern.rows == height,
             "{}: pattern is {}x{} but the projector is {}x{} (one pattern pixel per projector "
             "pixel; generate the patterns for this projector size)",
             display_name, pattern.cols, pattern.rows, width, height);
}

}  // namespace internal

void DisplayOptions::Check() const {
  SOPE_CHECK(width > 0 && height > 0 && width <= 16384 && height <= 16384,
             "projector size {}x{} must be in 1..16384", width, height);
  SOPE_CHECK(monitor >= 0, "monitor index {} must be >= 0", monitor);
}

VirtualDisplay::VirtualDisplay(int width, int height, std::function<double()> clock, size_t history)
    : width_(width),
      height_(height),
      clock_(std::move(clock)),
      history_(std::max<size_t>(history, 1)) {
  SOPE_CHECK(width > 0 && height > 0, "virtual display size {}x{} must be positive", width, height);
  black_ = cv::Mat::zeros(height, width, CV_8UC1);
}

void VirtualDisplay::Show(const cv::Mat& pattern) {
  internal::CheckPattern(pattern, width_, height_, name());
  Shown shown;
  shown.time = clock_ ? clock_() : 0.0;
  if (pattern.channels() == 3) {
    cv::cvtColor(pattern, shown.pattern, cv::COLOR_BGR2GRAY);
  } else {
    shown.pattern = pattern.clone();
  }
  std::lock_guard<std::mutex> lock(mutex_);
  shown_.push_back(std::move(shown));
  while (shown_.size() > history_) shown_.pop_front();
  ++show_count_;
}

cv::Mat VirtualDisplay::Current() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return shown_.empty() ? black_ : shown_.back().pattern;
}

cv::Mat VirtualDisplay::PatternAt(double time) const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (shown_.empty()) return black_;
  if (!clock_) return shown_.back().pattern;
  // Before the oldest kept entry: black if nothing was ever dropped, else the oldest kept.
  if (time < shown_.front().time)
    return show_count_ > shown_.size() ? shown_.front().pattern : black_;
  auto it = std::upper_bound(shown_.begin(), shown_.end(), time,
                             [](double t, const Shown& shown) { return t < shown.time; });
  return std::prev(it)->pattern;
}

size_t VirtualDisplay::show_count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return show_count_;
}

cv::Mat VirtualDisplay::ReadBack() {
  cv::Mat bgr;
  cv::cvtColor(Current(), bgr, cv::COLOR_GRAY2BGR);
  return bgr;
}

#ifndef SOPE_WITH_GLFW
bool HaveGlfwDisplay() { return false; }
std::vector<MonitorInfo> ListMonitors() {
  SOPE_THROW("no projector window: this build has no GLFW (configure with -DSOPE_WITH_GLFW=ON)");
}
std::unique_ptr<Display> OpenGlfwDisplay(const DisplayOptions&) {
  SOPE_THROW("no projector window: this build has no GLFW (configure with -DSOPE_WITH_GLFW=ON)");
}
#endif

}  // namespace sope
