// The V4L2 camera in two parts (STYLE.md §2; for the tests and the backend only):
//  - pure logic, testable without a device: format choice from what the device offers,
//    conversion of GREY/YUYV/MJPEG buffers to grey, the control plan (auto modes off,
//    manual exposure and gain), the stale-frame policy by timestamps, and errno → message;
//  - V4l2Device, the thin ioctl shell (v4l2_device.cc, the only file that includes
//    <linux/videodev2.h>), behind an interface so the streaming state machine
//    (MakeV4l2Camera) runs in tests on a fake device.
// V4L2 specifics are expressed here in our own types (fourcc codes, Control), never with
// the kernel header's.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <opencv2/core/mat.hpp>
#include <optional>
#include <string>
#include <vector>

#include "capture/camera.h"

namespace sope {
namespace internal {

// ---------------------------------------------------------------------------------------
// Pixel formats.

constexpr uint32_t FourCc(char a, char b, char c, char d) {
  return static_cast<uint32_t>(static_cast<uint8_t>(a)) |
         (static_cast<uint32_t>(static_cast<uint8_t>(b)) << 8) |
         (static_cast<uint32_t>(static_cast<uint8_t>(c)) << 16) |
         (static_cast<uint32_t>(static_cast<uint8_t>(d)) << 24);
}
constexpr uint32_t kFourCcGrey = FourCc('G', 'R', 'E', 'Y');
constexpr uint32_t kFourCcYuyv = FourCc('Y', 'U', 'Y', 'V');
constexpr uint32_t kFourCcMjpeg = FourCc('M', 'J', 'P', 'G');
// "YUYV"; non-printable bytes as '?'.
std::string FourCcToString(uint32_t fourcc);

// One pixel format at a set of sizes, as VIDIOC_ENUM_FMT / VIDIOC_ENUM_FRAMESIZES report
// it: a discrete size has min == max; a stepwise range has steps ≥ 1.
struct FormatOffer {
  uint32_t fourcc = 0;
  int min_width = 0, max_width = 0, step_width = 1;
  int min_height = 0, max_height = 0, step_height = 1;

  static FormatOffer Discrete(uint32_t fourcc, int width, int height) {
    return {fourcc, width, width, 1, height, height, 1};
  }
  bool Contains(int width, int height) const;
};

struct FormatChoice {
  uint32_t fourcc = 0;
  int width = 0;
  int height = 0;
};

// The format to negotiate. Only GREY, YUYV and MJPEG are usable. With a requested size
// (width, height > 0) the size must be offered exactly; otherwise the largest offered size
// is taken. Among formats with that size: `preference`, or for kAuto GREY, then YUYV,
// then MJPEG (raw first: JPEG artefacts blur stripe edges). Throws sope::Error naming
// `device` and listing what it offers when nothing fits.
FormatChoice ChooseFormat(const std::vector<FormatOffer>& offers, int width, int height,
                          PixelFormat preference, const std::string& device);

// The format the driver settled on (VIDIOC_S_FMT's answer).
struct BufferLayout {
  uint32_t fourcc = 0;
  int width = 0;
  int height = 0;
  int bytes_per_line = 0;  // 0: tightly packed
  size_t size_image = 0;   // bytes of a full frame (an upper bound for MJPEG)
};

// Grey image (CV_8UC1, layout size) from one captured buffer of `bytes_used` bytes; for
// GREY a copy, for YUYV the luma bytes (Y0 U Y1 V → Y0 Y1), for MJPEG cv::imdecode. With
// `color` non-null also the BGR image (empty for GREY). Throws sope::Error on a buffer
// shorter than a frame, or an undecodable or wrongly sized JPEG.
cv::Mat ConvertToGrey(const BufferLayout& layout, const uint8_t* data, size_t bytes_used,
                      cv::Mat* color = nullptr);

// ---------------------------------------------------------------------------------------
// Controls.

// The controls we set, by meaning (v4l2_device.cc maps them to V4L2_CID_*).
enum class Control {
  kExposureAuto,          // menu: 0 auto, 1 manual, 2 shutter priority, 3 aperture priority
  kExposureAutoPriority,  // bool: may auto exposure lower the frame rate
  kExposureAbsolute,      // int: exposure time in 100 µs units
  kAutoGain,              // bool
  kGain,                  // int, device units
  kAutoWhiteBalance,      // bool
};
std::string ToString(Control control);

// Values of V4L2_CID_EXPOSURE_AUTO's menu (enum v4l2_exposure_auto_type).
constexpr int64_t kExposureModeAuto = 0;
constexpr int64_t kExposureModeManual = 1;
constexpr int64_t kExposureModeShutterPriority = 2;
constexpr int64_t kExposureModeAperturePriority = 3;
// V4L2_CID_EXPOSURE_ABSOLUTE counts 100 µs.
constexpr double kExposureUnitSeconds = 100e-6;

// What VIDIOC_QUERYCTRL (+ VIDIOC_QUERYMENU) says about a control the device has.
struct ControlInfo {
  int64_t minimum = 0;
  int64_t maximum = 0;
  int64_t step = 1;
  int64_t default_value = 0;
  bool is_menu = false;
  std::vector<int64_t> menu_values;  // the valid entries of a menu control
  bool writable = true;              // false when read-only, disabled or grabbed
};

struct ControlSetting {
  Control control;
  int64_t value;
  std::string meaning;  // "manual exposure", "exposure 10.0 ms", "auto white balance off"
};

struct ControlPlan {
  std::vector<ControlSetting> settings;  // in this order (auto modes before values)
  std::vector<std::string> cannot_set;   // one entry per wish the device cannot grant
};

// What to set for `options`, given what the device has (`query` returns nullopt for a
// control it lacks). With options.manual: exposure mode manual (shutter priority when the
// menu has no manual mode), exposure priority off, auto gain off, auto white balance off.
// options.exposure > 0 → exposure time in 100 µs units, snapped to the control's step;
// options.gain ≥ 0 → gain. Values out of the control's range are not clamped: they go to
// cannot_set with the range, as do missing or read-only controls.
ControlPlan PlanControls(const CameraOptions& options,
                         const std::function<std::optional<ControlInfo>(Control)>& query);

// ---------------------------------------------------------------------------------------
// Timestamps and stale frames.

// Which instant V4L2 stamped (V4L2_BUF_FLAG_TSTAMP_SRC_*).
enum class TimestampSource { kEndOfFrame, kStartOfExposure };

struct DequeuedBuffer {
  int index = 0;
  size_t bytes_used = 0;
  double timestamp = 0.0;            // seconds
  bool timestamp_monotonic = false;  // V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC
  TimestampSource source = TimestampSource::kEndOfFrame;
  uint32_t sequence = 0;
  bool error = false;  // V4L2_BUF_FLAG_ERROR: the data may be corrupt
};

// Start of the exposure of a frame's first row, CLOCK_MONOTONIC seconds. Start-of-exposure
// stamps are taken as they are; end-of-frame stamps are moved back by the readout (≈ one
// frame period) and the exposure (the frame period when unknown, i.e. ≤ 0). Buffers not
// stamped on CLOCK_MONOTONIC fall back to the dequeue time (CLOCK_MONOTONIC) moved back
// likewise. Conservative: the result is never later than the true start, only earlier.
double ExposureStart(const DequeuedBuffer& buffer, double dequeue_time, double frame_period,
                     double exposure);
// A frame is stale when its exposure began before the request's `not_before`: it may
// still show the previous pattern.
inline bool IsStale(double exposure_start, double not_before) {
  return exposure_start < not_before;
}

// ---------------------------------------------------------------------------------------
// Errors.

// An ioctl/open/poll that failed: the operation ("VIDIOC_DQBUF", "open") and errno.
class DeviceError : public std::exception {
 public:
  DeviceError(std::string operation, int error_number);
  const char* what() const noexcept override { return what_.c_str(); }
  const std::string& operation() const { return operation_; }
  int error_number() const { return error_number_; }

 private:
  std::string operation_;
  int error_number_;
  std::string what_;
};

// One-line messages naming the device. `present_devices` lists /dev/video* for the
// "no such device" case.
std::string OpenErrorMessage(const std::string& device, int error_number,
                             const std::vector<std::string>& present_devices = {});
std::string DeviceErrorMessage(const std::string& device, const DeviceError& error);
// Whether errno from a streaming operation means the device is gone (unplugged, failed).
bool IsDeviceLost(int error_number);

// ---------------------------------------------------------------------------------------
// The device: one method per V4L2 operation we use. Methods throw DeviceError.

struct DeviceCapabilities {
  std::string driver, card, bus_info;
  bool video_capture = false;  // V4L2_CAP_VIDEO_CAPTURE (single-planar)
  bool streaming = false;      // V4L2_CAP_STREAMING
};

class V4l2Device {
 public:
  virtual ~V4l2Device() = default;
  virtual DeviceCapabilities QueryCapabilities() = 0;              // VIDIOC_QUERYCAP
  virtual std::vector<FormatOffer> EnumerateFormats() = 0;         // VIDIOC_ENUM_FMT/FRAMESIZES
  virtual BufferLayout SetFormat(const FormatChoice& format) = 0;  // VIDIOC_S_FMT
  // VIDIOC_S_PARM (fps > 0) / G_PARM: the frame period in effect, seconds; 0 if unknown.
  virtual double SetFrameRate(double fps) = 0;
  virtual std::optional<ControlInfo> QueryControl(Control control) = 0;  // VIDIOC_QUERYCTRL
  virtual void SetControl(Control control, int64_t value) = 0;           // VIDIOC_S_CTRL
  // VIDIOC_REQBUFS (memory mmap) + VIDIOC_QUERYBUF + mmap; returns the count granted.
  virtual int RequestBuffers(int count) = 0;
  virtual void QueueBuffer(int index) = 0;  // VIDIOC_QBUF
  virtual void StreamOn() = 0;              // VIDIOC_STREAMON
  virtual void StreamOff() = 0;             // VIDIOC_STREAMOFF
  // poll(): true when a buffer can be dequeued, false after `timeout` seconds.
  virtual bool WaitForFrame(double timeout) = 0;
  // VIDIOC_DQBUF (non-blocking): nullopt when none is ready (EAGAIN).
  virtual std::optional<DequeuedBuffer> DequeueBuffer() = 0;
  virtual const uint8_t* BufferData(int index) const = 0;
  virtual double Now() const = 0;  // CLOCK_MONOTONIC, seconds
};

// Opens a V4L2 device node (O_RDWR | O_NONBLOCK). Throws DeviceError("open", errno).
// Only with SOPE_WITH_V4L2.
std::unique_ptr<V4l2Device> OpenV4l2Device(const std::string& path);

// The streaming state machine on top of a device: query capabilities (refuse non-capture
// or non-streaming devices), negotiate the format, set the frame rate, apply the control
// plan (logging what could not be set), map buffers and stream. Grab() polls until a
// fresh frame (IsStale) arrives or the timeout passes, requeueing every buffer it takes.
// Throws sope::Error naming `path` for every failure.
std::unique_ptr<Camera> MakeV4l2Camera(std::unique_ptr<V4l2Device> device, const std::string& path,
                                       const CameraOptions& options);

}  // namespace internal
}  // namespace sope
