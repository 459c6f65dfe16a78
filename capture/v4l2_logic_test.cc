// The V4L2 backend's pure logic: format choice, buffer conversion, control plan,
// stale-frame policy and error messages — everything but the ioctls.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cerrno>
#include <map>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "capture/v4l2_internal.h"
#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace internal {
namespace {

using ::testing::HasSubstr;

using testing::ErrorOf;

// ---------------------------------------------------------------------------------------
// Formats.

TEST(FourCc, RoundTripsToText) {
  EXPECT_EQ(FourCcToString(kFourCcYuyv), "YUYV");
  EXPECT_EQ(FourCcToString(kFourCcGrey), "GREY");
  EXPECT_EQ(FourCcToString(kFourCcMjpeg), "MJPG");
  EXPECT_EQ(FourCcToString(FourCc('Y', '1', '6', ' ')), "Y16");
  EXPECT_EQ(FourCcToString(0x01020304), "????");
}

const std::vector<FormatOffer> kWebcam = {
    FormatOffer::Discrete(kFourCcYuyv, 640, 480),
    FormatOffer::Discrete(kFourCcYuyv, 1280, 720),
    FormatOffer::Discrete(kFourCcMjpeg, 640, 480),
    FormatOffer::Discrete(kFourCcMjpeg, 1280, 720),
    FormatOffer::Discrete(kFourCcMjpeg, 1920, 1080),
    FormatOffer::Discrete(FourCc('H', '2', '6', '4'), 3840, 2160),
};

TEST(ChooseFormat, LargestUsableSizeWhenNoneIsRequested) {
  const FormatChoice choice = ChooseFormat(kWebcam, 0, 0, PixelFormat::kAuto, "/dev/video0");
  EXPECT_EQ(choice.fourcc, kFourCcMjpeg) << "H264 is not usable; MJPEG has the largest size";
  EXPECT_EQ(choice.width, 1920);
  EXPECT_EQ(choice.height, 1080);
}

TEST(ChooseFormat, RawFormatsFirstAtTheRequestedSize) {
  FormatChoice choice = ChooseFormat(kWebcam, 1280, 720, PixelFormat::kAuto, "/dev/video0");
  EXPECT_EQ(choice.fourcc, kFourCcYuyv);
  EXPECT_EQ(choice.width, 1280);
  EXPECT_EQ(choice.height, 720);
  std::vector<FormatOffer> with_grey = kWebcam;
  with_grey.push_back(FormatOffer::Discrete(kFourCcGrey, 1280, 720));
  choice = ChooseFormat(with_grey, 1280, 720, PixelFormat::kAuto, "/dev/video0");
  EXPECT_EQ(choice.fourcc, kFourCcGrey);
  // Only MJPEG has 1920x1080.
  choice = ChooseFormat(kWebcam, 1920, 1080, PixelFormat::kAuto, "/dev/video0");
  EXPECT_EQ(choice.fourcc, kFourCcMjpeg);
}

TEST(ChooseFormat, AnExplicitFormatIsTheOnlyCandidate) {
  FormatChoice choice = ChooseFormat(kWebcam, 0, 0, PixelFormat::kYuyv, "/dev/video0");
  EXPECT_EQ(choice.fourcc, kFourCcYuyv);
  EXPECT_EQ(choice.width, 1280);
  choice = ChooseFormat(kWebcam, 640, 480, PixelFormat::kMjpeg, "/dev/video0");
  EXPECT_EQ(choice.fourcc, kFourCcMjpeg);
  EXPECT_THAT(ErrorOf([] { ChooseFormat(kWebcam, 1920, 1080, PixelFormat::kYuyv, "/dev/video0"); }),
              HasSubstr("cannot deliver 1920x1080 in yuyv"));
}

TEST(ChooseFormat, StepwiseRanges) {
  const std::vector<FormatOffer> offers = {{kFourCcGrey, 64, 2048, 16, 48, 1536, 8}};
  const FormatChoice choice = ChooseFormat(offers, 1024, 768, PixelFormat::kAuto, "/dev/video2");
  EXPECT_EQ(choice.fourcc, kFourCcGrey);
  EXPECT_EQ(choice.width, 1024);
  EXPECT_THROW_WITH_MESSAGE(ChooseFormat(offers, 1000, 768, PixelFormat::kAuto, "/dev/video2"),
                            Error, "/dev/video2", "1000x768")
      << "1000 is off the 16-pixel grid";
  const FormatChoice largest = ChooseFormat(offers, 0, 0, PixelFormat::kAuto, "/dev/video2");
  EXPECT_EQ(largest.width, 2048);
  EXPECT_EQ(largest.height, 1536);
}

TEST(ChooseFormat, ErrorsNameTheDeviceAndListTheOffers) {
  const std::string message =
      ErrorOf([] { ChooseFormat(kWebcam, 800, 600, PixelFormat::kAuto, "/dev/video3"); });
  EXPECT_EQ(message,
            "camera /dev/video3 cannot deliver 800x600 in GREY, YUYV or MJPEG; it offers: H264 "
            "3840x2160; MJPG 640x480, 1280x720, 1920x1080; YUYV 640x480, 1280x720");
  const std::vector<FormatOffer> h264_only = {
      FormatOffer::Discrete(FourCc('H', '2', '6', '4'), 1920, 1080)};
  EXPECT_THAT(ErrorOf([&] { ChooseFormat(h264_only, 0, 0, PixelFormat::kAuto, "/dev/video3"); }),
              HasSubstr("offers no GREY, YUYV or MJPEG format"));
}

// ---------------------------------------------------------------------------------------
// Conversions.

TEST(ConvertToGrey, GreyHonoursTheStride) {
  BufferLayout layout{kFourCcGrey, 5, 3, 8, 24};
  std::vector<uint8_t> data(24, 0xee);  // padding bytes must not leak into the image
  for (int y = 0; y < 3; ++y) {
    for (int x = 0; x < 5; ++x) data[y * 8 + x] = static_cast<uint8_t>(10 * y + x);
  }
  const cv::Mat grey = ConvertToGrey(layout, data.data(), data.size());
  ASSERT_EQ(grey.type(), CV_8UC1);
  ASSERT_EQ(grey.size(), cv::Size(5, 3));
  for (int y = 0; y < 3; ++y) {
    for (int x = 0; x < 5; ++x) EXPECT_EQ(grey.at<uint8_t>(y, x), 10 * y + x);
  }
  // The last row needs no padding: 8 + 8 + 5 bytes suffice, 20 do not.
  EXPECT_NO_THROW(ConvertToGrey(layout, data.data(), 21));
  EXPECT_THAT(ErrorOf([&] { ConvertToGrey(layout, data.data(), 20); }),
              HasSubstr("short frame: 20 bytes, a 5x3 GREY frame needs 21"));
}

TEST(ConvertToGrey, YuyvKeepsTheLumaBytes) {
  const int width = 6, height = 2;
  BufferLayout layout{kFourCcYuyv, width, height, 0, 0};
  std::vector<uint8_t> data(width * height * 2);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; x += 2) {
      uint8_t* macropixel = &data[(y * width + x) * 2];
      macropixel[0] = static_cast<uint8_t>(100 + 10 * y + x);  // Y0
      macropixel[1] = 90;                                      // U
      macropixel[2] = static_cast<uint8_t>(101 + 10 * y + x);  // Y1
      macropixel[3] = 160;                                     // V
    }
  }
  cv::Mat color;
  const cv::Mat grey = ConvertToGrey(layout, data.data(), data.size(), &color);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) EXPECT_EQ(grey.at<uint8_t>(y, x), 100 + 10 * y + x);
  }
  // Colour: OpenCV's YUYV conversion of the same bytes.
  cv::Mat expected;
  cv::cvtColor(cv::Mat(height, width, CV_8UC2, data.data()), expected, cv::COLOR_YUV2BGR_YUYV);
  ASSERT_EQ(color.type(), CV_8UC3);
  EXPECT_EQ(cv::norm(color, expected, cv::NORM_INF), 0.0);
  EXPECT_THROW_WITH_MESSAGE(ConvertToGrey(layout, data.data(), data.size() - 1), Error, "23 bytes",
                            "needs 24");
  BufferLayout odd{kFourCcYuyv, 5, 2, 0, 0};
  EXPECT_THROW_WITH_MESSAGE(ConvertToGrey(odd, data.data(), data.size()), Error, "even width",
                            "got 5");
}

TEST(ConvertToGrey, MjpegIsDecoded) {
  cv::Mat image(48, 64, CV_8UC1);
  for (int y = 0; y < image.rows; ++y) {
    for (int x = 0; x < image.cols; ++x) image.at<uint8_t>(y, x) = static_cast<uint8_t>(4 * x);
  }
  std::vector<uint8_t> jpeg;
  cv::Mat bgr;
  cv::cvtColor(image, bgr, cv::COLOR_GRAY2BGR);
  ASSERT_TRUE(cv::imencode(".jpg", bgr, jpeg, {cv::IMWRITE_JPEG_QUALITY, 100}));
  const BufferLayout layout{kFourCcMjpeg, 64, 48, 0, 64 * 48 * 2};
  cv::Mat color;
  const cv::Mat grey = ConvertToGrey(layout, jpeg.data(), jpeg.size(), &color);
  ASSERT_EQ(grey.type(), CV_8UC1);
  EXPECT_LE(cv::norm(grey, image, cv::NORM_INF), 3.0);
  EXPECT_EQ(color.type(), CV_8UC3);
  const BufferLayout wrong_size{kFourCcMjpeg, 640, 480, 0, 0};
  EXPECT_THAT(ErrorOf([&] { ConvertToGrey(wrong_size, jpeg.data(), jpeg.size()); }),
              HasSubstr("MJPEG frame is 64x48, expected 640x480"));
  std::vector<uint8_t> garbage(500, 0x55);
  EXPECT_THAT(ErrorOf([&] { ConvertToGrey(layout, garbage.data(), garbage.size()); }),
              HasSubstr("undecodable MJPEG frame"));
}

// ---------------------------------------------------------------------------------------
// Controls.

// What a typical UVC webcam offers: exposure modes manual and aperture priority, exposure
// 0.3–204.7 ms, gain 0–255, white balance automatic, no auto gain.
std::map<Control, ControlInfo> UvcWebcamControls() {
  std::map<Control, ControlInfo> controls;
  ControlInfo mode;
  mode.is_menu = true;
  mode.minimum = 0;
  mode.maximum = 3;
  mode.menu_values = {1, 3};
  controls[Control::kExposureAuto] = mode;
  controls[Control::kExposureAutoPriority] = {0, 1, 1, 0, false, {}, true};
  controls[Control::kExposureAbsolute] = {3, 2047, 1, 250, false, {}, true};
  controls[Control::kGain] = {0, 255, 1, 64, false, {}, true};
  controls[Control::kAutoWhiteBalance] = {0, 1, 1, 1, false, {}, true};
  return controls;
}

std::function<std::optional<ControlInfo>(Control)> Query(
    const std::map<Control, ControlInfo>& controls) {
  return [controls](Control control) -> std::optional<ControlInfo> {
    const auto it = controls.find(control);
    if (it == controls.end()) return std::nullopt;
    return it->second;
  };
}

TEST(PlanControls, TurnsAutomaticsOffAndSetsExposureAndGain) {
  CameraOptions options;
  options.exposure = 0.010;
  options.gain = 32;
  const ControlPlan plan = PlanControls(options, Query(UvcWebcamControls()));
  ASSERT_EQ(plan.settings.size(), 5u);
  EXPECT_EQ(plan.settings[0].control, Control::kExposureAuto);
  EXPECT_EQ(plan.settings[0].value, kExposureModeManual);
  EXPECT_EQ(plan.settings[1].control, Control::kExposureAutoPriority);
  EXPECT_EQ(plan.settings[1].value, 0);
  EXPECT_EQ(plan.settings[2].control, Control::kAutoWhiteBalance);
  EXPECT_EQ(plan.settings[2].value, 0);
  EXPECT_EQ(plan.settings[3].control, Control::kExposureAbsolute);
  EXPECT_EQ(plan.settings[3].value, 100) << "10 ms in 100 µs units";
  EXPECT_EQ(plan.settings[3].meaning, "exposure 10.0 ms");
  EXPECT_EQ(plan.settings[4].control, Control::kGain);
  EXPECT_EQ(plan.settings[4].value, 32);
  // The webcam has no auto gain control: reported, not fatal.
  ASSERT_EQ(plan.cannot_set.size(), 1u);
  EXPECT_EQ(plan.cannot_set[0], "auto gain off (not supported)");
}

TEST(PlanControls, ReportsWhatTheDeviceCannotGrant) {
  std::map<Control, ControlInfo> controls = UvcWebcamControls();
  controls[Control::kAutoWhiteBalance].writable = false;
  CameraOptions options;
  options.exposure = 0.5;  // 5000 units > 2047
  options.gain = 300;
  const ControlPlan plan = PlanControls(options, Query(controls));
  std::string all;
  for (const std::string& entry : plan.cannot_set) all += entry + "|";
  EXPECT_THAT(all, HasSubstr("auto white balance off (read-only or inactive)"));
  EXPECT_THAT(all, HasSubstr("exposure 500.0 ms (out of range 0.3..204.7 ms)"));
  EXPECT_THAT(all, HasSubstr("gain 300 (out of range 0..255)"));
  EXPECT_THAT(all, HasSubstr("auto gain off (not supported)"));
  for (const ControlSetting& setting : plan.settings) {
    EXPECT_NE(setting.control, Control::kExposureAbsolute) << "never clamped silently";
    EXPECT_NE(setting.control, Control::kGain);
  }
}

TEST(PlanControls, ShutterPriorityWhenTheMenuHasNoManualMode) {
  std::map<Control, ControlInfo> controls = UvcWebcamControls();
  controls[Control::kExposureAuto].menu_values = {0, 2};
  ControlPlan plan = PlanControls(CameraOptions(), Query(controls));
  ASSERT_FALSE(plan.settings.empty());
  EXPECT_EQ(plan.settings[0].value, kExposureModeShutterPriority);
  controls[Control::kExposureAuto].menu_values = {0, 3};  // auto modes only
  plan = PlanControls(CameraOptions(), Query(controls));
  EXPECT_EQ(plan.cannot_set.front(), "manual exposure (not in the menu: 0, 3)");
}

TEST(PlanControls, ExposureSnapsToTheControlsStep) {
  std::map<Control, ControlInfo> controls = UvcWebcamControls();
  controls[Control::kExposureAbsolute] = {5, 2005, 10, 105, false, {}, true};
  CameraOptions options;
  options.manual = false;
  options.exposure = 0.0123;  // 123 units → 125 on the grid 5, 15, …
  const ControlPlan plan = PlanControls(options, Query(controls));
  ASSERT_EQ(plan.settings.size(), 1u) << "manual = false sets no automatics";
  EXPECT_EQ(plan.settings[0].value, 125);
}

TEST(PlanControls, NothingToDoWithoutWishes) {
  CameraOptions options;
  options.manual = false;
  const ControlPlan plan = PlanControls(options, Query({}));
  EXPECT_TRUE(plan.settings.empty());
  EXPECT_TRUE(plan.cannot_set.empty());
}

// ---------------------------------------------------------------------------------------
// Timestamps.

TEST(ExposureStart, StartOfExposureStampsAreTakenAsTheyAre) {
  DequeuedBuffer buffer;
  buffer.timestamp = 1000.5;
  buffer.timestamp_monotonic = true;
  buffer.source = TimestampSource::kStartOfExposure;
  EXPECT_DOUBLE_EQ(ExposureStart(buffer, 1001.0, 1.0 / 30, 0.01), 1000.5);
}

TEST(ExposureStart, EndOfFrameStampsMoveBackByReadoutAndExposure) {
  DequeuedBuffer buffer;
  buffer.timestamp = 1000.5;
  buffer.timestamp_monotonic = true;
  buffer.source = TimestampSource::kEndOfFrame;
  EXPECT_DOUBLE_EQ(ExposureStart(buffer, 1001.0, 0.04, 0.01), 1000.5 - 0.04 - 0.01);
  // Unknown exposure: assume a whole frame period; unknown period: 30 fps.
  EXPECT_DOUBLE_EQ(ExposureStart(buffer, 1001.0, 0.04, 0.0), 1000.5 - 0.08);
  EXPECT_DOUBLE_EQ(ExposureStart(buffer, 1001.0, 0.0, 0.0), 1000.5 - 2.0 / 30);
}

TEST(ExposureStart, NonMonotonicStampsFallBackToTheDequeueTime) {
  DequeuedBuffer buffer;
  buffer.timestamp = 5.0;  // some other clock
  buffer.timestamp_monotonic = false;
  buffer.source = TimestampSource::kStartOfExposure;
  EXPECT_DOUBLE_EQ(ExposureStart(buffer, 1001.0, 0.04, 0.01), 1001.0 - 0.05);
}

TEST(StaleFramePolicy, FramesExposedBeforeTheRequestAreStale) {
  EXPECT_TRUE(IsStale(9.99, 10.0));
  EXPECT_FALSE(IsStale(10.0, 10.0)) << "exposure starting exactly at the request is fresh";
  EXPECT_FALSE(IsStale(10.01, 10.0));
  EXPECT_FALSE(IsStale(-1e9, -std::numeric_limits<double>::infinity()));
}

// ---------------------------------------------------------------------------------------
// Errors.

TEST(ErrorMessages, OpenFailures) {
  EXPECT_EQ(OpenErrorMessage("/dev/video99", ENOENT),
            "camera /dev/video99: no such device (no /dev/video* devices present: is a camera "
            "plugged in?)");
  EXPECT_EQ(OpenErrorMessage("/dev/video99", ENOENT, {"/dev/video0", "/dev/video1"}),
            "camera /dev/video99: no such device (present: /dev/video0, /dev/video1)");
  EXPECT_EQ(OpenErrorMessage("/dev/video0", EBUSY),
            "camera /dev/video0: busy — another program is using it");
  EXPECT_THAT(OpenErrorMessage("/dev/video0", EACCES), HasSubstr("permission denied"));
  EXPECT_THAT(OpenErrorMessage("/dev/video0", ENODEV), HasSubstr("device not present"));
  EXPECT_THAT(OpenErrorMessage("/dev/video0", EMFILE), HasSubstr("cannot open: "));
}

TEST(ErrorMessages, StreamingFailures) {
  EXPECT_EQ(DeviceErrorMessage("/dev/video0", DeviceError("VIDIOC_DQBUF", ENODEV)),
            "camera /dev/video0 disappeared or failed (VIDIOC_DQBUF: No such device): "
            "unplugged?");
  EXPECT_THAT(DeviceErrorMessage("/dev/video0", DeviceError("poll", EIO)),
              HasSubstr("disappeared or failed"));
  EXPECT_EQ(DeviceErrorMessage("/dev/video0", DeviceError("VIDIOC_REQBUFS", EBUSY)),
            "camera /dev/video0: busy — another program is streaming from it (VIDIOC_REQBUFS)");
  EXPECT_EQ(DeviceErrorMessage("/dev/null", DeviceError("VIDIOC_QUERYCAP", ENOTTY)),
            "camera /dev/null: not a V4L2 video device");
  EXPECT_EQ(DeviceErrorMessage("/dev/video0", DeviceError("open", EBUSY)),
            OpenErrorMessage("/dev/video0", EBUSY));
  EXPECT_THAT(DeviceErrorMessage("/dev/video0", DeviceError("VIDIOC_S_FMT", EINVAL)),
              HasSubstr("VIDIOC_S_FMT failed: Invalid argument"));
  EXPECT_TRUE(IsDeviceLost(ENODEV));
  EXPECT_FALSE(IsDeviceLost(EINVAL));
}

TEST(CameraOptions, Check) {
  CameraOptions options;
  EXPECT_NO_THROW(options.Check());
  options.width = 640;  // without a height
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "640x0");
  options = CameraOptions();
  options.buffers = 1;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "buffers 1");
  options = CameraOptions();
  options.exposure = -1;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "exposure -1");
  EXPECT_EQ(PixelFormatFromString("MJPG"), PixelFormat::kMjpeg);
  EXPECT_EQ(PixelFormatFromString("gray"), PixelFormat::kGrey);
  EXPECT_THROW_WITH_MESSAGE(PixelFormatFromString("h264"), Error, "'h264'");
}

}  // namespace
}  // namespace internal
}  // namespace sope
