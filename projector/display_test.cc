// Displays: the virtual display's bookkeeping, and the GLFW projector window read back
// pixel by pixel (run under xvfb-run by scripts/run-with-xvfb.sh; skipped without a
// display): every pattern of a sequence must come back byte for byte.
#include "projector/display.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

#include "core/error.h"
#include "projector/patterns.h"
#include "tests/test_support.h"

namespace sope {
namespace {

bool HaveDisplayServer() {
  const char* display = std::getenv("DISPLAY");
  return HaveGlfwDisplay() && display != nullptr && *display != '\0';
}

// Under scripts/run-with-xvfb.sh: a private 1024x768 screen that fullscreen tests may use.
bool OnPrivateXvfb() {
  const char* xvfb = std::getenv("SOPE_XVFB");
  return xvfb != nullptr && std::string(xvfb) == "1";
}

#define SOPE_REQUIRE_DISPLAY()                                                   \
  if (!HaveDisplayServer()) {                                                    \
    GTEST_SKIP() << "no X display (install xvfb: the test runs under xvfb-run)"; \
  }

// Number of pixels (over all three channels) where the read-back differs from `pattern`.
int CountDifferences(const cv::Mat& pattern, const cv::Mat& read_back_bgr) {
  cv::Mat expected_bgr;
  if (pattern.channels() == 1) {
    cv::cvtColor(pattern, expected_bgr, cv::COLOR_GRAY2BGR);
  } else {
    expected_bgr = pattern;
  }
  EXPECT_EQ(read_back_bgr.type(), CV_8UC3);
  EXPECT_EQ(read_back_bgr.size(), expected_bgr.size());
  if (read_back_bgr.size() != expected_bgr.size()) return -1;
  cv::Mat difference;
  cv::absdiff(expected_bgr, read_back_bgr, difference);
  return cv::countNonZero(difference.reshape(1));
}

// Shows every pattern of a Gray sequence (x and y, with inverses) plus random grey and
// colour images, reading each back after Show().
void ExpectExactReadBack(Display& display) {
  PatternOptions options;
  options.projector_width = display.width();
  options.projector_height = display.height();
  const std::vector<Pattern> patterns = GeneratePatterns(options);
  ASSERT_GT(patterns.size(), 20u);
  for (const Pattern& pattern : patterns) {
    display.Show(pattern.image);
    ASSERT_EQ(CountDifferences(pattern.image, display.ReadBack()), 0)
        << display.name() << ": " << pattern.info.file << " (" << ToString(pattern.info.role) << " "
        << ToString(pattern.info.axis) << " bit " << pattern.info.bit
        << (pattern.info.inverted ? " inverted" : "") << ")";
  }
  // Every grey level, and colour: values pass through unchanged (no dithering, no
  // filtering, no gamma), pixel for pixel (random texture: a one-pixel shift would show).
  cv::RNG rng(7);
  cv::Mat grey(display.height(), display.width(), CV_8UC1);
  rng.fill(grey, cv::RNG::UNIFORM, 0, 256);
  display.Show(grey);
  EXPECT_EQ(CountDifferences(grey, display.ReadBack()), 0) << "random grey";
  cv::Mat colour(display.height(), display.width(), CV_8UC3);
  rng.fill(colour, cv::RNG::UNIFORM, 0, 256);
  display.Show(colour);
  EXPECT_EQ(CountDifferences(colour, display.ReadBack()), 0) << "random colour";
  // A view into a larger image (non-contiguous rows).
  cv::Mat big(display.height() + 3, display.width() + 5, CV_8UC1);
  rng.fill(big, cv::RNG::UNIFORM, 0, 256);
  const cv::Mat view = big(cv::Rect(2, 1, display.width(), display.height()));
  display.Show(view);
  EXPECT_EQ(CountDifferences(view, display.ReadBack()), 0) << "non-contiguous pattern";
}

TEST(VirtualDisplay, RemembersWhatWasShownAndWhen) {
  double now = 0.0;
  VirtualDisplay display(
      8, 4, [&] { return now; }, 3);
  EXPECT_EQ(cv::countNonZero(display.Current()), 0) << "black before the first Show";
  std::vector<cv::Mat> shown;
  for (int i = 0; i < 5; ++i) {
    now = 1.0 + i;
    shown.push_back(cv::Mat(4, 8, CV_8UC1, cv::Scalar(10 * (i + 1))));
    display.Show(shown.back());
  }
  EXPECT_EQ(display.show_count(), 5u);
  EXPECT_EQ(display.Current().at<uint8_t>(0, 0), 50);
  EXPECT_EQ(display.PatternAt(5.5).at<uint8_t>(0, 0), 50);
  EXPECT_EQ(display.PatternAt(4.0).at<uint8_t>(0, 0), 40) << "shown exactly at t = 4";
  EXPECT_EQ(display.PatternAt(3.99).at<uint8_t>(0, 0), 30);
  // Older than the history (3 kept): the oldest kept pattern.
  EXPECT_EQ(display.PatternAt(0.5).at<uint8_t>(0, 0), 30);
  // The display keeps its own copy.
  shown.back().setTo(0);
  EXPECT_EQ(display.Current().at<uint8_t>(0, 0), 50);
  const cv::Mat read_back = display.ReadBack();
  EXPECT_EQ(read_back.type(), CV_8UC3);
  EXPECT_EQ(read_back.at<cv::Vec3b>(3, 7), cv::Vec3b(50, 50, 50));
}

TEST(VirtualDisplay, BlackBeforeTheFirstPatternInTime) {
  double now = 2.0;
  VirtualDisplay display(4, 4, [&] { return now; });
  display.Show(cv::Mat(4, 4, CV_8UC1, cv::Scalar(255)));
  EXPECT_EQ(display.PatternAt(1.0).at<uint8_t>(0, 0), 0);
  EXPECT_EQ(display.PatternAt(2.0).at<uint8_t>(0, 0), 255);
}

TEST(VirtualDisplay, RefusesPatternsOfAnotherSize) {
  VirtualDisplay display(1024, 768);
  try {
    display.Show(cv::Mat::zeros(600, 800, CV_8UC1));
    FAIL() << "expected sope::Error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("pattern is 800x600 but the projector is 1024x768"),
              std::string::npos)
        << e.what();
  }
  EXPECT_THROW_WITH_MESSAGE(display.Show(cv::Mat::zeros(768, 1024, CV_16UC1)), Error,
                            "virtual display", "got CV_16UC1");
}

TEST(DisplayOptions, Check) {
  DisplayOptions options;
  EXPECT_NO_THROW(options.Check());
  options.width = 0;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "projector size 0x768");
  options = DisplayOptions();
  options.monitor = -1;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "monitor index -1");
}

TEST(GlfwDisplay, WindowedReadBackIsExact) {
  SOPE_REQUIRE_DISPLAY();
  DisplayOptions options;
  options.windowed = true;
  options.width = OnPrivateXvfb() ? 1024 : 800;  // the whole private screen
  options.height = OnPrivateXvfb() ? 768 : 600;
  const std::unique_ptr<Display> display = OpenGlfwDisplay(options);
  EXPECT_EQ(display->width(), options.width);
  EXPECT_EQ(display->height(), options.height);
  ExpectExactReadBack(*display);
}

TEST(GlfwDisplay, OddSizedWindowReadBackIsExact) {
  SOPE_REQUIRE_DISPLAY();
  DisplayOptions options;
  options.windowed = true;
  options.width = 333;  // rows not a multiple of 4 bytes
  options.height = 177;
  const std::unique_ptr<Display> display = OpenGlfwDisplay(options);
  ExpectExactReadBack(*display);
}

TEST(GlfwDisplay, FullscreenOnAMatchingMonitorIsExact) {
  SOPE_REQUIRE_DISPLAY();
  if (!OnPrivateXvfb()) GTEST_SKIP() << "fullscreen is only tested on the private Xvfb screen";
  const std::vector<MonitorInfo> monitors = ListMonitors();
  ASSERT_FALSE(monitors.empty());
  EXPECT_EQ(monitors[0].width, 1024);
  EXPECT_EQ(monitors[0].height, 768);
  DisplayOptions options;
  options.monitor = 0;
  options.width = 1024;
  options.height = 768;
  const std::unique_ptr<Display> display = OpenGlfwDisplay(options);
  ExpectExactReadBack(*display);
  // No input on Xvfb: WaitKey times out.
  EXPECT_EQ(display->WaitKey(0.01), DisplayKey::kNone);
}

TEST(GlfwDisplay, RefusesAMonitorWhoseModeDiffersFromThePatterns) {
  SOPE_REQUIRE_DISPLAY();
  if (!OnPrivateXvfb()) GTEST_SKIP() << "needs the private Xvfb screen";
  DisplayOptions options;
  options.width = 800;
  options.height = 600;
  try {
    OpenGlfwDisplay(options);
    FAIL() << "expected sope::Error";
  } catch (const Error& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("runs at 1024x768 but the patterns are 800x600"), std::string::npos)
        << message;
    EXPECT_NE(message.find("--windowed"), std::string::npos) << message;
  }
  // The refused window was cleaned up: another one opens.
  options.windowed = true;
  EXPECT_NO_THROW(OpenGlfwDisplay(options));
}

TEST(GlfwDisplay, RefusesAMissingMonitorListingTheConnectedOnes) {
  SOPE_REQUIRE_DISPLAY();
  DisplayOptions options;
  options.monitor = 7;
  try {
    OpenGlfwDisplay(options);
    FAIL() << "expected sope::Error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no monitor 7: connected monitors: 0: "),
              std::string::npos)
        << e.what();
  }
}

TEST(GlfwDisplay, OneWindowPerProcess) {
  SOPE_REQUIRE_DISPLAY();
  DisplayOptions options;
  options.windowed = true;
  options.width = 64;
  options.height = 48;
  const std::unique_ptr<Display> first = OpenGlfwDisplay(options);
  EXPECT_THROW_WITH_MESSAGE(OpenGlfwDisplay(options), Error, "already open");
  first->Show(cv::Mat(48, 64, CV_8UC1, cv::Scalar(99)));
  EXPECT_EQ(CountDifferences(cv::Mat(48, 64, CV_8UC1, cv::Scalar(99)), first->ReadBack()), 0);
}

TEST(GlfwDisplay, NoDisplayIsOneClearError) {
  if (!HaveGlfwDisplay()) GTEST_SKIP() << "built without GLFW";
  const char* saved = std::getenv("DISPLAY");
  const std::string saved_display = saved ? saved : "";
  ::unsetenv("DISPLAY");
  ::unsetenv("WAYLAND_DISPLAY");
  DisplayOptions options;
  options.windowed = true;
  try {
    OpenGlfwDisplay(options);
    ADD_FAILURE() << "expected sope::Error";
  } catch (const Error& e) {
    const std::string message = e.what();
    EXPECT_EQ(message.rfind("no display: ", 0), 0u) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  }
  EXPECT_THROW_WITH_MESSAGE(ListMonitors(), Error, "$DISPLAY is not set");
  // An X server that is not there.
  ::setenv("DISPLAY", ":4999", 1);
  try {
    OpenGlfwDisplay(options);
    ADD_FAILURE() << "expected sope::Error";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()).rfind("no display: GLFW cannot initialise", 0), 0u) << e.what();
  }
  if (saved) ::setenv("DISPLAY", saved_display.c_str(), 1);
}

}  // namespace
}  // namespace sope
