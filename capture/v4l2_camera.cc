// The V4L2 camera's streaming state machine, on the V4l2Device interface (v4l2_internal.h)
// so that tests run it on a fake device. The ioctls themselves are in v4l2_device.cc.
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

#include "capture/v4l2_internal.h"
#include "core/error.h"

namespace sope {
namespace internal {
namespace {

// Consecutive corrupt frames (V4L2_BUF_FLAG_ERROR, undecodable JPEG) before giving up.
constexpr int kMaxConsecutiveCorruptFrames = 10;

class V4l2Camera : public Camera {
 public:
  V4l2Camera(std::unique_ptr<V4l2Device> device, const std::string& path,
             const CameraOptions& options)
      : device_(std::move(device)), path_(path), options_(options) {
    try {
      Start();
    } catch (const DeviceError& error) {
      Stop();
      throw Error(DeviceErrorMessage(path_, error));
    } catch (...) {
      Stop();
      throw;
    }
  }

  ~V4l2Camera() override { Stop(); }

  Frame Grab(const GrabRequest& request) override {
    try {
      return GrabFrame(request);
    } catch (const DeviceError& error) {
      streaming_ = false;  // a lost device cannot be stopped cleanly
      throw Error(DeviceErrorMessage(path_, error));
    }
  }

  int width() const override { return layout_.width; }
  int height() const override { return layout_.height; }
  double Now() const override { return device_->Now(); }
  double frame_period() const override { return frame_period_; }
  std::string name() const override { return path_; }
  std::string description() const override { return description_; }

 private:
  void Start() {
    options_.Check();
    const DeviceCapabilities caps = device_->QueryCapabilities();
    SOPE_CHECK(caps.video_capture,
               "camera {} ({}, {}) is not a video capture device (a metadata or output node? "
               "webcams often have two /dev/video nodes: try the other)",
               path_, caps.card, caps.driver);
    SOPE_CHECK(caps.streaming, "camera {} ({}, {}) cannot stream (no V4L2 streaming I/O)", path_,
               caps.card, caps.driver);
    const FormatChoice choice = ChooseFormat(device_->EnumerateFormats(), options_.width,
                                             options_.height, options_.pixel_format, path_);
    layout_ = device_->SetFormat(choice);
    SOPE_CHECK(layout_.fourcc == choice.fourcc && layout_.width == choice.width &&
                   layout_.height == choice.height,
               "camera {}: asked for {} {}x{}, the driver set {} {}x{}", path_,
               FourCcToString(choice.fourcc), choice.width, choice.height,
               FourCcToString(layout_.fourcc), layout_.width, layout_.height);
    frame_period_ = device_->SetFrameRate(options_.fps);
    if (options_.fps > 0.0 && frame_period_ > 0.0 &&
        std::abs(1.0 / frame_period_ - options_.fps) > 0.05 * options_.fps) {
      cannot_set_.push_back(
          fmt::format("{:g} fps (runs at {:.3g} fps)", options_.fps, 1.0 / frame_period_));
    }
    ApplyControls();
    const int granted = device_->RequestBuffers(options_.buffers);
    SOPE_CHECK(granted >= 2, "camera {}: the driver granted {} buffers, streaming needs 2", path_,
               granted);
    buffer_count_ = granted;
    for (int i = 0; i < buffer_count_; ++i) device_->QueueBuffer(i);
    device_->StreamOn();
    streaming_ = true;
    description_ = fmt::format("{} ({}, {}): {} {}x{}, {}", path_, caps.card, caps.driver,
                               FourCcToString(layout_.fourcc), layout_.width, layout_.height,
                               frame_period_ > 0.0 ? fmt::format("{:.3g} fps", 1.0 / frame_period_)
                                                   : std::string("frame rate unknown"));
    if (!cannot_set_.empty()) {
      description_ += fmt::format("; could not set: {}", fmt::join(cannot_set_, "; "));
      spdlog::warn("camera {}: could not set: {}", path_, fmt::join(cannot_set_, "; "));
    }
    spdlog::debug("{}", description_);
  }

  void ApplyControls() {
    const ControlPlan plan =
        PlanControls(options_, [this](Control control) { return device_->QueryControl(control); });
    cannot_set_ = plan.cannot_set;
    for (const ControlSetting& setting : plan.settings) {
      try {
        device_->SetControl(setting.control, setting.value);
        if (setting.control == Control::kExposureAbsolute) {
          exposure_ = setting.value * kExposureUnitSeconds;
        }
      } catch (const DeviceError& error) {
        if (IsDeviceLost(error.error_number())) throw;
        cannot_set_.push_back(fmt::format("{} ({})", setting.meaning, error.what()));
      }
    }
  }

  void Stop() {
    if (streaming_) {
      try {
        device_->StreamOff();
      } catch (const DeviceError& error) {
        spdlog::debug("camera {}: {}", path_, error.what());
      }
      streaming_ = false;
    }
  }

  Frame GrabFrame(const GrabRequest& request) {
    SOPE_CHECK(streaming_, "camera {} is not streaming (it failed earlier)", path_);
    SOPE_CHECK(request.timeout > 0.0, "grab timeout {} s must be positive", request.timeout);
    const double deadline = device_->Now() + request.timeout;
    int stale = 0, corrupt = 0, consecutive_corrupt = 0;
    double last_stale_start = -1.0;
    while (true) {
      const double remaining = deadline - device_->Now();
      if (remaining <= 0.0) {
        SOPE_THROW("camera {}: no frame within {:.2f} s (timeout){}", path_, request.timeout,
                   stale + corrupt == 0
                       ? std::string(": the camera stopped delivering frames")
                       : fmt::format(" — {} stale and {} corrupt frames dropped", stale, corrupt));
      }
      if (!device_->WaitForFrame(remaining)) continue;
      const std::optional<DequeuedBuffer> buffer = device_->DequeueBuffer();
      if (!buffer) continue;
      const double dequeue_time = device_->Now();
      // Every buffer taken goes back to the driver before the next step.
      if (buffer->error) {
        device_->QueueBuffer(buffer->index);
        ++corrupt;
        SOPE_CHECK(++consecutive_corrupt < kMaxConsecutiveCorruptFrames,
                   "camera {}: {} corrupt frames in a row", path_, consecutive_corrupt);
        continue;
      }
      const double start = ExposureStart(*buffer, dequeue_time, frame_period_, exposure_);
      if (IsStale(start, request.not_before)) {
        device_->QueueBuffer(buffer->index);
        ++stale;
        last_stale_start = start;
        continue;
      }
      Frame frame;
      try {
        frame.image = ConvertToGrey(layout_, device_->BufferData(buffer->index), buffer->bytes_used,
                                    request.want_color ? &frame.color : nullptr);
      } catch (const Error& error) {
        device_->QueueBuffer(buffer->index);
        ++corrupt;
        spdlog::debug("camera {}: dropped frame {}: {}", path_, buffer->sequence, error.what());
        SOPE_CHECK(++consecutive_corrupt < kMaxConsecutiveCorruptFrames,
                   "camera {}: {} undecodable frames in a row (last: {})", path_,
                   consecutive_corrupt, error.what());
        continue;
      }
      device_->QueueBuffer(buffer->index);
      frame.exposure_start = start;
      frame.sequence = buffer->sequence;
      consecutive_corrupt = 0;
      if (stale > 0) {
        spdlog::trace(
            "camera {}: dropped {} stale frames (last exposed {:.4f} s before the "
            "request)",
            path_, stale, request.not_before - last_stale_start);
      }
      return frame;
    }
  }

  std::unique_ptr<V4l2Device> device_;
  std::string path_;
  CameraOptions options_;
  BufferLayout layout_;
  double frame_period_ = 0.0;
  double exposure_ = 0.0;  // manual exposure set, seconds; 0 = unknown
  int buffer_count_ = 0;
  bool streaming_ = false;
  std::vector<std::string> cannot_set_;
  std::string description_;
};

}  // namespace

std::unique_ptr<Camera> MakeV4l2Camera(std::unique_ptr<V4l2Device> device, const std::string& path,
                                       const CameraOptions& options) {
  return std::make_unique<V4l2Camera>(std::move(device), path, options);
}

}  // namespace internal
}  // namespace sope
