// The rig session on a light synthetic camera that watches a VirtualDisplay with a
// transport delay (no rendering: the image is the pattern, dimmed, offset and with a
// little noise). Latency measurement, fresh frames, timeouts, a vanishing camera, and
// recordings that appear whole or not at all.
#include "capture/rig_session.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "capture/clock.h"
#include "capture/replay_camera.h"
#include "core/error.h"
#include "core/file_util.h"
#include "tests/test_support.h"

namespace sope {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

constexpr int kWidth = 64;
constexpr int kHeight = 48;
constexpr double kPeriod = 1.0 / 30.0;

// Frame n is exposed at n·T, delivered at (n + 1)·T + jitter, and shows
// 20 + 0.75 · (the pattern shown at n·T − delay·T) ± 1 grey level.
struct CameraFaults {
  int lose_after = -1;   // delivered frames before the device vanishes
  int stall_after = -1;  // delivered frames before no more arrive
  bool blind = false;    // does not see the projector
};

class PatternCamera : public Camera {
 public:
  using Faults = CameraFaults;

  PatternCamera(const VirtualDisplay& display, SimulatedClock& clock, int delay_frames,
                double jitter = 0.0, CameraFaults faults = CameraFaults())
      : display_(display), clock_(clock), delay_(delay_frames), jitter_(jitter), faults_(faults) {}

  Frame Grab(const GrabRequest& request) override {
    const double now = clock_.Now();
    int64_t n = std::max<int64_t>(next_, static_cast<int64_t>(std::floor(now / kPeriod)) - 4);
    if (std::isfinite(request.not_before)) {
      while (n * kPeriod < request.not_before) ++n;
    }
    const double delivery = (n + 1) * kPeriod + jitter_ * rng_.uniform(0.0, 1.0);
    const bool stalled = faults_.stall_after >= 0 && delivered_ >= faults_.stall_after;
    if (stalled || delivery > now + request.timeout) {
      clock_.AdvanceTo(now + request.timeout);
      SOPE_THROW("camera pattern: no frame within {:.2f} s (timeout)", request.timeout);
    }
    SOPE_CHECK(faults_.lose_after < 0 || delivered_ < faults_.lose_after,
               "camera pattern disappeared or failed");
    clock_.AdvanceTo(delivery);
    Frame frame;
    const cv::Mat pattern = display_.PatternAt(n * kPeriod - delay_ * kPeriod);
    cv::Mat noise(kHeight, kWidth, CV_32F);
    rng_.fill(noise, cv::RNG::UNIFORM, -1.0, 1.0);
    cv::Mat image;
    pattern.convertTo(image, CV_32F, faults_.blind ? 0.0 : 0.75, 20.0);
    cv::Mat(image + noise).convertTo(frame.image, CV_8U);
    frame.exposure_start = n * kPeriod;
    frame.sequence = static_cast<uint64_t>(n);
    next_ = n + 1;
    ++delivered_;
    return frame;
  }
  int width() const override { return kWidth; }
  int height() const override { return kHeight; }
  double Now() const override { return clock_.Now(); }
  double frame_period() const override { return kPeriod; }
  std::string name() const override { return "pattern"; }

  // The image this camera makes of `pattern` without noise.
  static cv::Mat Expected(const cv::Mat& pattern) {
    cv::Mat image;
    pattern.convertTo(image, CV_8U, 0.75, 20.0);
    return image;
  }

 private:
  const VirtualDisplay& display_;
  SimulatedClock& clock_;
  int delay_;
  double jitter_;
  Faults faults_;
  int64_t next_ = 0;
  int delivered_ = 0;
  cv::RNG rng_{12345};
};

struct Bench {
  explicit Bench(int delay_frames, double jitter = 0.0, CameraFaults faults = CameraFaults())
      : display(kWidth, kHeight, [this] { return clock.Now(); }),
        camera(display, clock, delay_frames, jitter, faults) {}
  SimulatedClock clock;
  VirtualDisplay display;
  PatternCamera camera;
};

std::vector<Pattern> Patterns() {
  PatternOptions options;
  options.projector_width = kWidth;
  options.projector_height = kHeight;
  return GeneratePatterns(options);
}

// Largest |frame − expected image of its pattern| over a capture.
double WorstMismatch(const FrameSet& frames, const std::vector<Pattern>& patterns) {
  double worst = 0.0;
  for (size_t i = 0; i < patterns.size(); ++i) {
    worst = std::max(worst, cv::norm(frames.images[i], PatternCamera::Expected(patterns[i].image),
                                     cv::NORM_INF));
  }
  return worst;
}

using testing::ErrorOf;

// Nothing at `path`, and no staging directory left beside it.
void ExpectNothingWritten(const std::string& path) {
  EXPECT_FALSE(fs::exists(path)) << path;
  for (const auto& entry : fs::directory_iterator(fs::path(path).parent_path())) {
    EXPECT_EQ(entry.path().filename().string().find(".tmp-"), std::string::npos)
        << "staging directory left behind: " << entry.path();
  }
}

TEST(RigSession, LatencyMeasurementRecoversAnInjectedDelayOfKFrames) {
  for (int k = 0; k <= 4; ++k) {
    Bench bench(k, /*jitter=*/0.9 * kPeriod);
    RigSession session(bench.display, bench.camera);
    const LatencyMeasurement& measurement = session.MeasureLatency();
    SCOPED_TRACE(measurement.Summary());
    EXPECT_EQ(static_cast<int>(std::floor(measurement.frames())), k);
    ASSERT_EQ(measurement.samples.size(), 6u);
    for (double sample : measurement.samples) {
      EXPECT_GE(sample, k * kPeriod - 1e-12) << "every sample bounds the latency from above";
      EXPECT_LT(sample, (k + 1) * kPeriod);
    }
    EXPECT_NEAR(measurement.black_level, 20.0, 1.0);
    EXPECT_NEAR(measurement.white_level, 20.0 + 0.75 * 255, 1.0);
    EXPECT_DOUBLE_EQ(measurement.lit_fraction, 1.0);
    std::printf("[latency] injected %d frames (%.1f ms): measured %.1f ms = %.2f frames\n", k,
                1e3 * k * kPeriod, 1e3 * measurement.latency, measurement.frames());
  }
}

TEST(RigSession, CapturesEveryPatternWithoutStaleFrames) {
  const std::vector<Pattern> patterns = Patterns();
  Bench bench(3, 0.5 * kPeriod);
  RigSession session(bench.display, bench.camera);
  size_t progress_calls = 0;
  const FrameSet frames = session.Capture(patterns, [&](size_t done, size_t total) {
    EXPECT_EQ(done, ++progress_calls);
    EXPECT_EQ(total, patterns.size());
  });
  EXPECT_EQ(progress_calls, patterns.size());
  ASSERT_EQ(frames.images.size(), patterns.size());
  EXPECT_EQ(frames.manifest.camera_width, kWidth);
  EXPECT_EQ(frames.manifest.projector_width, kWidth);
  EXPECT_NO_THROW(frames.manifest.Check());
  EXPECT_LE(WorstMismatch(frames, patterns), 1.0) << "each frame shows its own pattern";
  ASSERT_EQ(session.timings().size(), patterns.size());
  for (const FrameTiming& timing : session.timings()) {
    EXPECT_GE(timing.exposure_start, timing.shown + 3 * kPeriod);
  }
  // The projector is left dark.
  EXPECT_EQ(cv::countNonZero(bench.display.Current()), 0);
}

TEST(RigSession, WithoutWaitingForTheLatencyFramesAreStale) {
  // The negative control: the same rig with latency forced to 0 grabs frames that still
  // show the previous pattern.
  const std::vector<Pattern> patterns = Patterns();
  Bench bench(3);
  RigSessionOptions options;
  options.latency = 0.0;
  RigSession session(bench.display, bench.camera, options);
  EXPECT_GT(WorstMismatch(session.Capture(patterns), patterns), 100.0);
}

TEST(RigSession, AFrameThatNeverArrivesIsATimeoutAndLeavesNoRecording) {
  testing::ScratchDir scratch;
  PatternCamera::Faults faults;
  faults.stall_after = 20;  // during the scan, after the latency measurement
  Bench bench(1, 0.0, faults);
  RigSessionOptions options;
  options.grab_timeout = 0.5;
  RigSession session(bench.display, bench.camera, options);
  const std::string out = scratch.File("scan");
  EXPECT_THAT(ErrorOf([&] { session.Record(Patterns(), out); }), HasSubstr("no frame within"));
  ExpectNothingWritten(out);
}

TEST(RigSession, ACameraVanishingMidScanIsAClearErrorAndLeavesNoRecording) {
  testing::ScratchDir scratch;
  PatternCamera::Faults faults;
  faults.lose_after = 30;
  Bench bench(1, 0.0, faults);
  RigSession session(bench.display, bench.camera);
  const std::string out = scratch.File("scan");
  EXPECT_EQ(ErrorOf([&] { session.Record(Patterns(), out); }),
            "camera pattern disappeared or failed");
  ExpectNothingWritten(out);
}

TEST(RigSession, AnExceptionMidRecordingLeavesNoOutputDirectory) {
  testing::ScratchDir scratch;
  const std::string out = scratch.File("scan");
  Bench bench(2);
  RigSession session(bench.display, bench.camera);
  EXPECT_THROW_WITH_MESSAGE(session.Record(Patterns(), out, nullptr,
                                           [](size_t done, size_t) {
                                             if (done == 7) throw std::runtime_error("power cut");
                                           }),
                            std::runtime_error, "power cut");
  ExpectNothingWritten(out);
  // An existing recording at that path survives a failed re-recording untouched.
  Bench good(2);
  RigSession good_session(good.display, good.camera);
  good_session.Record(Patterns(), out);
  const FrameSet before = LoadFrameSet(out);
  std::atomic<bool> cancel{false};
  RigSessionOptions options;
  options.cancel = &cancel;
  Bench again(2);
  RigSession cancelled(again.display, again.camera, options);
  EXPECT_EQ(ErrorOf([&] {
              cancelled.Record(Patterns(), out, nullptr,
                               [&](size_t done, size_t) { cancel = done >= 5; });
            }),
            "interrupted");
  const FrameSet after = LoadFrameSet(out);
  ASSERT_EQ(after.images.size(), before.images.size());
  for (size_t i = 0; i < after.images.size(); ++i) {
    EXPECT_EQ(cv::norm(after.images[i], before.images[i], cv::NORM_INF), 0.0);
  }
}

TEST(RigSession, RecordingsReplayFrameForFrame) {
  testing::ScratchDir scratch;
  const std::string out = scratch.File("scan");
  const std::vector<Pattern> patterns = Patterns();
  Bench bench(2, 0.3 * kPeriod);
  RigSession session(bench.display, bench.camera);
  RigCalibration calibration;  // any valid calibration: it is only stored
  calibration.camera.width = calibration.projector.width = kWidth;
  calibration.camera.height = calibration.projector.height = kHeight;
  calibration.camera.matrix << 60, 0, 32, 0, 60, 24, 0, 0, 1;
  calibration.projector.matrix = calibration.camera.matrix;
  calibration.camera.distortion = calibration.projector.distortion = {0, 0, 0, 0, 0};
  calibration.proj_from_cam.translation = Eigen::Vector3d(-0.1, 0, 0);
  const FrameSet recorded = session.Record(patterns, out, &calibration);
  EXPECT_EQ(recorded.directory, out);
  EXPECT_TRUE(fs::exists(JoinPath(out, "calibration.yaml")));
  // capture.json: the latency and every frame's timing.
  const nlohmann::json log =
      nlohmann::json::parse(ReadFileToString(JoinPath(out, "capture.json"), "log"));
  EXPECT_EQ(log["format"], "sope-capture/1");
  EXPECT_NEAR(log["latency"].get<double>(), session.latency(), 1e-12);
  EXPECT_EQ(log["frames"].size(), patterns.size());
  const FrameSet loaded = LoadFrameSet(out);
  EXPECT_EQ(loaded.manifest.calibration, "calibration.yaml");
  ASSERT_EQ(loaded.images.size(), patterns.size());
  // The recording played back through a second session: identical frames, no latency.
  ReplayCamera replay(out);
  VirtualDisplay display(kWidth, kHeight);
  RigSession replay_session(display, replay);
  const FrameSet replayed = replay_session.Capture(patterns);
  EXPECT_DOUBLE_EQ(replay_session.latency(), 0.0);
  for (size_t i = 0; i < patterns.size(); ++i) {
    EXPECT_EQ(cv::norm(replayed.images[i], recorded.images[i], cv::NORM_INF), 0.0) << i;
  }
  // Replaying with another pattern sequence is refused.
  PatternOptions other;
  other.projector_width = kWidth;
  other.projector_height = kHeight;
  other.axes = PatternAxes::kY;
  ReplayCamera replay_again(out);
  RigSession mismatched(display, replay_again);
  EXPECT_THAT(ErrorOf([&] { mismatched.Capture(GeneratePatterns(other)); }),
              HasSubstr("does not match the pattern sequence"));
}

TEST(RigSession, ACameraThatDoesNotSeeTheProjectorIsAClearError) {
  PatternCamera::Faults faults;
  faults.blind = true;
  Bench bench(0, 0.0, faults);
  RigSession session(bench.display, bench.camera);
  EXPECT_THAT(ErrorOf([&] { session.MeasureLatency(); }),
              HasSubstr("camera pattern does not see the projector: only 0.000% of its pixels"));
}

TEST(RigSession, ALatencyBeyondTheMaximumIsAClearError) {
  Bench bench(20);  // 0.67 s
  RigSessionOptions options;
  options.max_latency = 0.3;
  RigSession session(bench.display, bench.camera, options);
  // The reference frames are taken max_latency after each change: with a longer latency
  // they show the previous level, so the camera seems not to see the projector at all.
  EXPECT_THAT(ErrorOf([&] { session.MeasureLatency(); }), HasSubstr("does not see the projector"));
}

TEST(RigSession, RefusesPatternsOfAnotherSizeThanTheDisplay) {
  Bench bench(0);
  RigSessionOptions options;
  options.latency = 0.05;
  RigSession session(bench.display, bench.camera, options);
  PatternOptions other;
  other.projector_width = 32;
  other.projector_height = 24;
  EXPECT_THAT(ErrorOf([&] { session.Capture(GeneratePatterns(other)); }),
              HasSubstr("patterns are 32x24 but the virtual display is 64x48"));
}

TEST(RigSessionOptions, Check) {
  RigSessionOptions options;
  EXPECT_NO_THROW(options.Check());
  options.settle = -1;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "settle time -1");
  options = RigSessionOptions();
  options.transition_fraction = 1.0;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "transition fraction 1");
  options = RigSessionOptions();
  options.latency_flashes = 0;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "latency flashes 0");
  options = RigSessionOptions();
  options.latency = 0.1;  // given: no measurement
  Bench bench(5);
  RigSession session(bench.display, bench.camera, options);
  EXPECT_DOUBLE_EQ(session.latency(), 0.1);
  EXPECT_EQ(bench.display.show_count(), 0u) << "no flashing when the latency is given";
}

}  // namespace
}  // namespace sope
