// Projector displays: where the stripe patterns are shown. A GLFW window on the projector
// (fullscreen, one pattern pixel per projector pixel) for real rigs, and a virtual display
// that only remembers what it shows, for the virtual rig. GLFW and GL headers stay in
// glfw_display.cc (STYLE.md §2).
#pragma once

#include <cstddef>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <opencv2/core/mat.hpp>
#include <string>
#include <vector>

namespace sope {

// Keys of the interactive pattern stepper (`sope project`).
enum class DisplayKey {
  kNone,      // no key within the timeout, or a display without input
  kNext,      // space, →, Enter, Page Down
  kPrevious,  // ←, Backspace, Page Up
  kQuit,      // q, Esc, or the window was closed
};

class Display {
 public:
  virtual ~Display() = default;

  // Shows `pattern` — CV_8UC1 (grey) or CV_8UC3 (BGR), exactly width() × height(): pattern
  // pixel (x, y) lights projector pixel (x, y), unscaled and unfiltered — and returns once
  // it has been handed to the screen (after the buffer swap; with vsync, after the swap
  // interval). Throws sope::Error naming the display on a wrong size or type.
  virtual void Show(const cv::Mat& pattern) = 0;
  // Projector resolution, pixels.
  virtual int width() const = 0;
  virtual int height() const = 0;
  // Waits up to `timeout_s` seconds for a key; kNone on timeout. Displays without input
  // return kNone at once.
  virtual DisplayKey WaitKey(double timeout_s) { return DisplayKey::kNone; }
  // What the display shows now, read back from it (CV_8UC3, BGR, width() × height()): the
  // GLFW window's pixels as the X server holds them, the virtual display's pattern. For
  // tests and diagnostics.
  virtual cv::Mat ReadBack() = 0;
  // For messages: "GLFW window on monitor 0 (HDMI-1)", "virtual display".
  virtual std::string name() const = 0;
};

struct DisplayOptions {
  // Monitor index as GLFW lists them (0 = primary); ignored when windowed.
  int monitor = 0;
  // A decorated window of width × height instead of fullscreen, for development.
  bool windowed = false;
  // Projector resolution = pattern size, pixels. Fullscreen requires the monitor's current
  // video mode to be exactly this size (no mode switch, no scaling).
  int width = 1024;
  int height = 768;
  // Wait for the vertical blank on each swap (no tearing: one pattern per refresh).
  bool vsync = true;
  std::string title = "sope projector";

  // Throws sope::Error naming the invalid value.
  void Check() const;
};

struct MonitorInfo {
  int index = 0;
  std::string name;
  int width = 0;  // current video mode, pixels
  int height = 0;
  int refresh_hz = 0;
};

// True when this build has the GLFW backend (SOPE_WITH_GLFW).
bool HaveGlfwDisplay();
// The connected monitors. Throws sope::Error when there is no display (GLFW cannot
// initialise: no $DISPLAY, no X server) or the build has no GLFW.
std::vector<MonitorInfo> ListMonitors();
// Opens the projector window (GLFW, OpenGL). Fullscreen on `options.monitor` — refused
// unless its current mode is exactly width × height — or windowed. Textures are uploaded
// at their own size and drawn with GL_NEAREST onto a framebuffer of the same size, so the
// mapping is exact; a framebuffer of another size (desktop scaling) is refused. One
// window per process. Throws sope::Error (one line naming the monitor or the value) when
// there is no display, no such monitor, the mode or framebuffer size differs, or the
// build has no GLFW.
std::unique_ptr<Display> OpenGlfwDisplay(const DisplayOptions& options);

// A display that shows nothing: it records the patterns and, when given a clock, when
// they were shown, so a virtual camera can see what was on the "screen" at any instant.
// Thread-safe.
class VirtualDisplay : public Display {
 public:
  // `clock` returns the current time, seconds, in the time base of the camera that
  // watches this display (nullptr: no timestamps, PatternAt() is the current pattern).
  // Before the first Show() the display is black. The last `history` patterns are kept.
  VirtualDisplay(int width, int height, std::function<double()> clock = nullptr,
                 size_t history = 16);

  void Show(const cv::Mat& pattern) override;
  int width() const override { return width_; }
  int height() const override { return height_; }
  cv::Mat ReadBack() override;
  std::string name() const override { return "virtual display"; }

  // The pattern shown last (CV_8UC1; a colour pattern is kept as grey).
  cv::Mat Current() const;
  // The pattern on screen at `time` (the last one shown at or before it; black before the
  // first, the oldest kept one before the history). Needs a clock.
  cv::Mat PatternAt(double time) const;
  // Number of Show() calls so far.
  size_t show_count() const;

 private:
  struct Shown {
    double time;
    cv::Mat pattern;
  };
  int width_, height_;
  std::function<double()> clock_;
  size_t history_;
  mutable std::mutex mutex_;
  std::deque<Shown> shown_;
  size_t show_count_ = 0;
  cv::Mat black_;
};

namespace internal {
// Throws sope::Error naming `display_name` unless `pattern` is CV_8UC1 or CV_8UC3 of
// exactly width × height.
void CheckPattern(const cv::Mat& pattern, int width, int height, const std::string& display_name);
}  // namespace internal

}  // namespace sope
