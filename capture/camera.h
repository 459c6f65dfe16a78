// Cameras: one interface for every frame source of a rig session — a V4L2 webcam, the
// replay of a recorded frame set, and the virtual rig's camera (simulator/virtual_camera.h,
// which lives above capture/ because it renders with the simulator). Device headers stay
// in the backends' .cc files (STYLE.md §2).
#pragma once

#include <cstdint>
#include <limits>
#include <memory>
#include <opencv2/core/mat.hpp>
#include <string>

#include "core/frame_set.h"

namespace sope {

struct Frame {
  // CV_8UC1 at the camera's size (CV_16UC1 when a 16-bit frame set is replayed).
  cv::Mat image;
  // CV_8UC3 (BGR) when the request asked for colour and the camera has it; else empty.
  cv::Mat color;
  // Start of the frame's exposure (the earliest row's, for rolling shutters), seconds on
  // the camera's clock (Camera::Now()). For V4L2 this is derived from the buffer timestamp
  // (CLOCK_MONOTONIC) the same way for every frame, so differences are exact up to a
  // constant offset that the latency measurement absorbs.
  double exposure_start = 0.0;
  // The camera's frame counter; gaps are frames dropped by the driver or as stale.
  uint64_t sequence = 0;
};

struct GrabRequest {
  // Return the first frame whose exposure started at or after this time (camera clock,
  // seconds); frames exposed earlier are stale — they may show the previous pattern — and
  // are dropped. −∞: the next frame, whatever it shows.
  double not_before = -std::numeric_limits<double>::infinity();
  // Give up when no such frame has arrived after this long, seconds → sope::Error.
  double timeout = 2.0;
  // Also deliver the frame in colour (Frame::color) when the camera can.
  bool want_color = false;
  // What the projector shows now, when known: a replay checks that its next frame was
  // recorded with the same pattern.
  const FrameInfo* showing = nullptr;
};

class Camera {
 public:
  virtual ~Camera() = default;

  // The next fresh frame (see GrabRequest). Throws sope::Error naming the camera on a
  // timeout, when the device disappears or fails, or when a replay is exhausted or does
  // not match `request.showing`.
  virtual Frame Grab(const GrabRequest& request) = 0;
  // Image size, pixels.
  virtual int width() const = 0;
  virtual int height() const = 0;
  // Now on the clock of Frame::exposure_start, seconds.
  virtual double Now() const = 0;
  // Nominal time between frames, seconds; 0 when unknown.
  virtual double frame_period() const = 0;
  // False when frames do not depend on what the projector shows (a replay): no latency can
  // be measured and none needs waiting for.
  virtual bool live() const { return true; }
  // "/dev/video0", "replay:DIR", "virtual".
  virtual std::string name() const = 0;
  // One line for logs: name, driver, format, frame rate, controls that could not be set.
  virtual std::string description() const { return name(); }
};

enum class PixelFormat { kAuto, kGrey, kYuyv, kMjpeg };
std::string ToString(PixelFormat format);
PixelFormat PixelFormatFromString(const std::string& text);  // auto, grey, yuyv, mjpeg

struct CameraOptions {
  // Requested image size, pixels; 0 × 0 = the largest the camera offers.
  int width = 0;
  int height = 0;
  // Pixel format on the wire; kAuto prefers uncompressed (GREY, then YUYV) at the chosen
  // size, MJPEG only when nothing raw has it. Frames are always delivered as grey.
  PixelFormat pixel_format = PixelFormat::kAuto;
  // Requested frame rate, frames per second; 0 = the driver's default.
  double fps = 0.0;
  // Turn auto-exposure, auto-gain, auto-white-balance and exposure priority off, so every
  // pattern is captured with the same photometric settings (the decoder compares frames).
  bool manual = true;
  // Manual exposure time, seconds (V4L2 counts 100 µs units); 0 = keep the current one.
  double exposure = 0.0;
  // Manual analogue gain in the device's own units; < 0 = keep the current one.
  double gain = -1.0;
  // Driver buffers for streaming (mmap); more buffers smooth over a slow consumer.
  int buffers = 4;

  // Throws sope::Error naming the invalid value.
  void Check() const;
};

// Opens a camera from a spec: "/dev/videoN" (V4L2), "replay:DIR" (a recorded frame set).
// "virtual" is made by the simulator (MakeVirtualLiveRig in simulator/virtual_camera.h)
// and refused here with a message saying so. Throws sope::Error: unknown spec, device
// absent, busy, not a capture device, format/size not available, or a build without V4L2.
std::unique_ptr<Camera> OpenCamera(const std::string& spec, const CameraOptions& options = {});

// True when this build has the V4L2 backend (SOPE_WITH_V4L2).
bool HaveV4l2Camera();

}  // namespace sope
