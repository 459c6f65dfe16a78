// The V4L2 camera's streaming state machine on a fake device: a sensor that exposes a
// frame every period and fills a queued buffer when it has one (like a driver, dropping
// the frame otherwise), on a fake clock. Negotiation, controls, stale-frame dropping,
// buffer recycling, timeouts and a device that disappears mid-stream.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cerrno>
#include <deque>
#include <map>
#include <opencv2/core.hpp>
#include <set>

#include "capture/v4l2_internal.h"
#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace internal {
namespace {

using ::testing::HasSubstr;

class FakeDevice : public V4l2Device {
 public:
  struct Config {
    DeviceCapabilities capabilities{"fakecam", "Fake Camera", "usb-0000:00:14.0-1", true, true};
    std::vector<FormatOffer> offers = {FormatOffer::Discrete(kFourCcYuyv, 64, 48),
                                       FormatOffer::Discrete(kFourCcYuyv, 32, 24),
                                       FormatOffer::Discrete(kFourCcGrey, 32, 24)};
    std::map<Control, ControlInfo> controls;
    std::set<Control> refused_controls;  // S_CTRL fails with EINVAL
    int refused_errno = EINVAL;
    double frame_period = 0.04;  // 25 fps
    double start_time = 100.0;   // CLOCK_MONOTONIC when streaming starts
    TimestampSource source = TimestampSource::kStartOfExposure;
    int granted_buffers = 4;
    // Faults (< 0: never): after this many frames are dequeued the device is gone; after
    // this many frames are exposed the sensor stops.
    int vanish_after_dequeues = -1;
    int stall_after_frames = -1;
    std::set<int> corrupt_frames;  // V4L2_BUF_FLAG_ERROR on these frame numbers
    bool change_format = false;    // S_FMT answers with another size
  };

  explicit FakeDevice(Config config) : config_(std::move(config)) {}

  DeviceCapabilities QueryCapabilities() override { return config_.capabilities; }
  std::vector<FormatOffer> EnumerateFormats() override { return config_.offers; }
  BufferLayout SetFormat(const FormatChoice& format) override {
    layout_ = {format.fourcc, format.width, format.height,
               format.width * (format.fourcc == kFourCcYuyv ? 2 : 1), 0};
    if (config_.change_format) layout_.width /= 2;
    layout_.size_image = static_cast<size_t>(layout_.bytes_per_line) * layout_.height;
    return layout_;
  }
  double SetFrameRate(double fps) override { return config_.frame_period; }
  std::optional<ControlInfo> QueryControl(Control control) override {
    const auto it = config_.controls.find(control);
    if (it == config_.controls.end()) return std::nullopt;
    return it->second;
  }
  void SetControl(Control control, int64_t value) override {
    if (config_.refused_controls.count(control)) {
      throw DeviceError("VIDIOC_S_CTRL " + ToString(control), config_.refused_errno);
    }
    set_controls[control] = value;
  }
  int RequestBuffers(int count) override {
    const int granted = std::min(count, config_.granted_buffers);
    buffers_.assign(granted, std::vector<uint8_t>(layout_.size_image));
    return granted;
  }
  void QueueBuffer(int index) override {
    if (index < 0 || index >= static_cast<int>(buffers_.size()) || queued_.count(index)) {
      throw DeviceError("VIDIOC_QBUF", EINVAL);  // a double queue is a bug in the camera
    }
    queued_.insert(index);
  }
  void StreamOn() override {
    streaming = true;
    next_frame_ = 0;
  }
  void StreamOff() override { streaming = false; }

  // Time runs frame by frame, so a buffer requeued now can take the next frame.
  bool WaitForFrame(double timeout) override {
    const double until = now_ + timeout;
    Produce(now_);
    while (done_.empty()) {
      const bool stalled =
          config_.stall_after_frames >= 0 && next_frame_ >= config_.stall_after_frames;
      const double arrival = FrameStart(next_frame_) + config_.frame_period;
      if (stalled || arrival > until) {
        now_ = until;
        return false;
      }
      now_ = arrival;
      Produce(now_);
    }
    return true;
  }

  std::optional<DequeuedBuffer> DequeueBuffer() override {
    if (config_.vanish_after_dequeues >= 0 && dequeued >= config_.vanish_after_dequeues) {
      throw DeviceError("VIDIOC_DQBUF", ENODEV);
    }
    if (done_.empty() || done_.front().arrival > now_) return std::nullopt;
    const Filled filled = done_.front();
    done_.pop_front();
    ++dequeued;
    return filled.buffer;
  }

  const uint8_t* BufferData(int index) const override { return buffers_.at(index).data(); }
  double Now() const override { return now_; }

  // Exposure start of frame n.
  double FrameStart(int n) const { return config_.start_time + n * config_.frame_period; }
  // The grey level every pixel of frame n has.
  static uint8_t Level(int n) { return static_cast<uint8_t>(n % 256); }
  int queued_count() const { return static_cast<int>(queued_.size()); }
  // Buffers the driver holds: queued, or filled and waiting to be dequeued. Equal to the
  // buffer count unless the camera lost one.
  int held_by_driver() const { return static_cast<int>(queued_.size() + done_.size()); }
  int buffer_count() const { return static_cast<int>(buffers_.size()); }
  void Advance(double seconds) {
    now_ += seconds;
    Produce(now_);
  }

  std::map<Control, int64_t> set_controls;
  bool streaming = false;
  int dequeued = 0;
  int dropped_by_driver = 0;

 private:
  struct Filled {
    DequeuedBuffer buffer;
    double arrival;
  };

  // The sensor: every frame completes one period after its exposure started; it lands in
  // a queued buffer or is dropped.
  void Produce(double until) {
    if (!streaming) return;
    while (true) {
      if (config_.stall_after_frames >= 0 && next_frame_ >= config_.stall_after_frames) return;
      const double arrival = FrameStart(next_frame_) + config_.frame_period;
      if (arrival > until) return;
      const int n = next_frame_++;
      if (queued_.empty()) {
        ++dropped_by_driver;
        continue;
      }
      const int index = *queued_.begin();
      queued_.erase(queued_.begin());
      std::vector<uint8_t>& data = buffers_[index];
      for (size_t i = 0; i < data.size(); ++i) {
        // YUYV: luma on even bytes, neutral chroma on odd ones.
        data[i] = layout_.fourcc == kFourCcYuyv && i % 2 ? 128 : Level(n);
      }
      DequeuedBuffer buffer;
      buffer.index = index;
      buffer.bytes_used = data.size();
      buffer.timestamp_monotonic = true;
      buffer.source = config_.source;
      buffer.timestamp = config_.source == TimestampSource::kStartOfExposure
                             ? FrameStart(n)
                             : FrameStart(n) + config_.frame_period;
      buffer.sequence = static_cast<uint32_t>(n);
      buffer.error = config_.corrupt_frames.count(n) > 0;
      done_.push_back({buffer, arrival});
    }
  }

  Config config_;
  BufferLayout layout_;
  std::vector<std::vector<uint8_t>> buffers_;
  std::set<int> queued_;
  std::deque<Filled> done_;
  int next_frame_ = 0;
  double now_ = 100.0;
};

// The camera and a view of its fake device (owned by the camera).
struct Rig {
  FakeDevice* device;
  std::unique_ptr<Camera> camera;
};

Rig Open(FakeDevice::Config config, CameraOptions options = {}) {
  auto device = std::make_unique<FakeDevice>(std::move(config));
  FakeDevice* view = device.get();
  if (options.width == 0) {
    options.width = 64;
    options.height = 48;
  }
  return {view, MakeV4l2Camera(std::move(device), "/dev/video7", options)};
}

using testing::ErrorOf;

TEST(V4l2Camera, NegotiatesTheFormatAndStreams) {
  Rig rig = Open({});
  EXPECT_EQ(rig.camera->width(), 64);
  EXPECT_EQ(rig.camera->height(), 48);
  EXPECT_DOUBLE_EQ(rig.camera->frame_period(), 0.04);
  EXPECT_TRUE(rig.device->streaming);
  EXPECT_EQ(rig.device->queued_count(), 4) << "every buffer queued before streaming";
  EXPECT_EQ(rig.camera->name(), "/dev/video7");
  EXPECT_THAT(rig.camera->description(),
              HasSubstr("/dev/video7 (Fake Camera, fakecam): YUYV 64x48, 25 fps"));
  const Frame frame = rig.camera->Grab({});
  ASSERT_EQ(frame.image.type(), CV_8UC1);
  ASSERT_EQ(frame.image.size(), cv::Size(64, 48));
  EXPECT_EQ(frame.sequence, 0u);
  EXPECT_DOUBLE_EQ(frame.exposure_start, rig.device->FrameStart(0));
  EXPECT_EQ(frame.image.at<uint8_t>(47, 63), FakeDevice::Level(0)) << "luma of YUYV";
  rig.camera.reset();
}

TEST(V4l2Camera, DropsFramesExposedBeforeTheRequest) {
  Rig rig = Open({});
  rig.camera->Grab({});
  // Time passes (the projector changes pattern); the buffers fill with stale frames.
  rig.device->Advance(0.5);
  const double request_time = rig.camera->Now();
  GrabRequest request;
  request.not_before = request_time + 0.05;  // latency + settle
  const Frame frame = rig.camera->Grab(request);
  EXPECT_GE(frame.exposure_start, request.not_before);
  EXPECT_LT(frame.exposure_start, request.not_before + 0.04) << "the first fresh frame";
  const int n = static_cast<int>(frame.sequence);
  EXPECT_DOUBLE_EQ(frame.exposure_start, rig.device->FrameStart(n));
  EXPECT_EQ(frame.image.at<uint8_t>(0, 0), FakeDevice::Level(n)) << "the image of that frame";
  EXPECT_GT(rig.device->dequeued, 2) << "stale frames were dequeued and dropped";
  EXPECT_EQ(rig.device->held_by_driver(), rig.device->buffer_count())
      << "every buffer taken was given back (none lost to the stale path)";
}

TEST(V4l2Camera, RecyclesBuffersOverALongSession) {
  Rig rig = Open({});
  GrabRequest request;
  uint64_t last_sequence = 0;
  for (int i = 0; i < 200; ++i) {
    request.not_before = rig.camera->Now() + 0.01 * (i % 7);
    const Frame frame = rig.camera->Grab(request);
    EXPECT_GE(frame.exposure_start, request.not_before);
    if (i > 0) {
      EXPECT_GT(frame.sequence, last_sequence);
    }
    last_sequence = frame.sequence;
    ASSERT_EQ(rig.device->held_by_driver(), rig.device->buffer_count()) << "grab " << i;
  }
}

TEST(V4l2Camera, EndOfFrameTimestampsAreMovedBackConservatively) {
  FakeDevice::Config config;
  config.source = TimestampSource::kEndOfFrame;
  CameraOptions options;
  options.width = 64;
  options.height = 48;
  options.exposure = 0.01;
  config.controls[Control::kExposureAbsolute] = {1, 5000, 1, 100, false, {}, true};
  Rig rig = Open(config, options);
  const Frame frame = rig.camera->Grab({});
  // Stamped at the frame's end (start + period); moved back by period + exposure.
  EXPECT_NEAR(frame.exposure_start, rig.device->FrameStart(0) - 0.01, 1e-9);
  // Such a frame is stale for a request at its true start: the policy errs early, never
  // late, so a frame counted as fresh really started after the request.
  GrabRequest request;
  request.not_before = rig.device->FrameStart(3);
  const Frame fresh = rig.camera->Grab(request);
  EXPECT_GE(rig.device->FrameStart(static_cast<int>(fresh.sequence)), request.not_before);
}

TEST(V4l2Camera, AFrameThatNeverArrivesIsATimeout) {
  FakeDevice::Config config;
  config.stall_after_frames = 3;
  Rig rig = Open(config);
  for (int i = 0; i < 3; ++i) rig.camera->Grab({});
  const double before = rig.camera->Now();
  GrabRequest request;
  request.timeout = 0.5;
  EXPECT_EQ(ErrorOf([&] { rig.camera->Grab(request); }),
            "camera /dev/video7: no frame within 0.50 s (timeout): the camera stopped "
            "delivering frames");
  EXPECT_NEAR(rig.camera->Now() - before, 0.5, 1e-9) << "it waited the whole timeout";
}

TEST(V4l2Camera, OnlyStaleFramesUntilTheDeadlineIsATimeoutSayingSo) {
  Rig rig = Open({});
  GrabRequest request;
  request.not_before = rig.camera->Now() + 10.0;  // nothing that late within the timeout
  request.timeout = 0.3;
  EXPECT_THAT(ErrorOf([&] { rig.camera->Grab(request); }),
              HasSubstr("no frame within 0.30 s (timeout) — "));
  EXPECT_THAT(ErrorOf([&] { rig.camera->Grab(request); }), HasSubstr("stale"));
}

TEST(V4l2Camera, ADeviceThatDisappearsMidStreamIsAClearError) {
  FakeDevice::Config config;
  config.vanish_after_dequeues = 5;
  Rig rig = Open(config);
  for (int i = 0; i < 5; ++i) rig.camera->Grab({});
  EXPECT_EQ(ErrorOf([&] { rig.camera->Grab({}); }),
            "camera /dev/video7 disappeared or failed (VIDIOC_DQBUF: No such device): "
            "unplugged?");
  EXPECT_THAT(ErrorOf([&] { rig.camera->Grab({}); }), HasSubstr("is not streaming"))
      << "later grabs fail at once";
}

TEST(V4l2Camera, CorruptFramesAreSkipped) {
  FakeDevice::Config config;
  config.corrupt_frames = {0, 1, 2};
  Rig rig = Open(config);
  const Frame frame = rig.camera->Grab({});
  EXPECT_EQ(frame.sequence, 3u);
  EXPECT_EQ(rig.device->held_by_driver(), rig.device->buffer_count());
  // Endless corruption is an error, not a hang.
  config.corrupt_frames.clear();
  for (int n = 0; n < 100; ++n) config.corrupt_frames.insert(n);
  Rig broken = Open(config);
  EXPECT_THAT(ErrorOf([&] { broken.camera->Grab({}); }), HasSubstr("corrupt frames in a row"));
}

TEST(V4l2Camera, RefusesDevicesThatCannotCaptureOrStream) {
  FakeDevice::Config config;
  config.capabilities.video_capture = false;
  EXPECT_THAT(ErrorOf([&] { Open(config); }),
              HasSubstr("camera /dev/video7 (Fake Camera, fakecam) is not a video capture device"));
  config = FakeDevice::Config();
  config.capabilities.streaming = false;
  EXPECT_THAT(ErrorOf([&] { Open(config); }), HasSubstr("cannot stream"));
}

TEST(V4l2Camera, RefusesASizeTheCameraCannotDeliver) {
  CameraOptions options;
  options.width = 1920;
  options.height = 1080;
  EXPECT_EQ(ErrorOf([&] { Open({}, options); }),
            "camera /dev/video7 cannot deliver 1920x1080 in GREY, YUYV or MJPEG; it offers: "
            "GREY 32x24; YUYV 64x48, 32x24");
  FakeDevice::Config config;
  config.change_format = true;
  EXPECT_THAT(ErrorOf([&] { Open(config); }),
              HasSubstr("asked for YUYV 64x48, the driver set YUYV 32x48"));
  options.width = 32;
  options.height = 24;
  EXPECT_EQ(Open({}, options).camera->description().find("GREY 32x24") != std::string::npos, true)
      << "raw grey preferred at the requested size";
}

TEST(V4l2Camera, AppliesTheControlPlanAndReportsWhatFailed) {
  FakeDevice::Config config;
  ControlInfo mode;
  mode.is_menu = true;
  mode.maximum = 3;
  mode.menu_values = {1, 3};
  config.controls[Control::kExposureAuto] = mode;
  config.controls[Control::kExposureAbsolute] = {3, 2047, 1, 250, false, {}, true};
  config.controls[Control::kAutoWhiteBalance] = {0, 1, 1, 1, false, {}, true};
  config.controls[Control::kGain] = {0, 255, 1, 64, false, {}, true};
  config.refused_controls = {Control::kAutoWhiteBalance};
  CameraOptions options;
  options.width = 64;
  options.height = 48;
  options.exposure = 0.02;
  options.gain = 10;
  Rig rig = Open(config, options);
  EXPECT_EQ(rig.device->set_controls[Control::kExposureAuto], kExposureModeManual);
  EXPECT_EQ(rig.device->set_controls[Control::kExposureAbsolute], 200);
  EXPECT_EQ(rig.device->set_controls[Control::kGain], 10);
  const std::string description = rig.camera->description();
  EXPECT_THAT(description, HasSubstr("could not set: "));
  EXPECT_THAT(description,
              HasSubstr("exposure priority off (constant frame rate) (not supported)"));
  EXPECT_THAT(description, HasSubstr("auto gain off (not supported)"));
  EXPECT_THAT(
      description,
      HasSubstr("auto white balance off (VIDIOC_S_CTRL auto white balance: Invalid argument)"));
  // A device lost while setting controls is fatal, not a warning.
  config.refused_errno = ENODEV;
  EXPECT_THAT(ErrorOf([&] { Open(config, options); }), HasSubstr("disappeared or failed"));
}

TEST(V4l2Camera, TooFewBuffersIsAnError) {
  FakeDevice::Config config;
  config.granted_buffers = 1;
  EXPECT_THAT(ErrorOf([&] { Open(config); }), HasSubstr("granted 1 buffers, streaming needs 2"));
}

}  // namespace
}  // namespace internal
}  // namespace sope
