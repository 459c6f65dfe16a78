// The virtual rig as a live camera: it sees what the virtual display shows, on the
// simulated clock, with an injected transport delay that the rig session's latency
// measurement must recover, and with injected device faults.
#include "simulator/virtual_camera.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/core.hpp>

#include "capture/rig_session.h"
#include "core/error.h"
#include "simulator/primitives.h"
#include "simulator/scene_builder.h"
#include "tests/test_support.h"

namespace sope {
namespace {

using ::testing::HasSubstr;

using testing::SmallRig;

Scene WallScene() {
  Scene scene;
  scene.objects.push_back(MakeBackdrop(0.6, 1.5, 1.2));
  return scene;
}

using testing::ErrorOf;

cv::Mat Uniform(const VirtualDisplay& display, int level) {
  return cv::Mat(display.height(), display.width(), CV_8UC1, cv::Scalar(level));
}

TEST(VirtualCamera, SeesWhatTheDisplayShowsOnTheSimulatedClock) {
  VirtualCameraOptions options;
  options.frame_period = 0.04;
  VirtualLiveRig live = MakeVirtualLiveRig(SmallRig(), WallScene(), {}, options);
  Camera& camera = *live.camera;
  EXPECT_EQ(camera.width(), 320);
  EXPECT_EQ(camera.height(), 240);
  EXPECT_TRUE(camera.live());
  EXPECT_DOUBLE_EQ(camera.Now(), 0.0);
  live.display->Show(Uniform(*live.display, 255));
  const Frame lit = camera.Grab({});
  EXPECT_DOUBLE_EQ(lit.exposure_start, 0.0);
  EXPECT_DOUBLE_EQ(camera.Now(), 0.04) << "delivered one period after its exposure";
  GrabRequest request;
  request.not_before = 0.1;
  live.display->Show(Uniform(*live.display, 0));
  const Frame dark = camera.Grab(request);
  EXPECT_NEAR(dark.exposure_start, 0.12, 1e-12) << "the first frame starting at or after 0.1";
  EXPECT_EQ(dark.sequence, 3u);
  EXPECT_NEAR(camera.Now(), 0.16, 1e-12);
  const double lit_mean = cv::mean(lit.image)[0], dark_mean = cv::mean(dark.image)[0];
  EXPECT_GT(lit_mean, dark_mean + 50) << lit_mean << " vs " << dark_mean;
  EXPECT_EQ(live.camera->delivered(), 2u) << "frames nobody grabs are not rendered";
}

TEST(VirtualCamera, ShowsWhatWasOnTheDisplayDelayFramesBefore) {
  VirtualCameraOptions options;
  options.frame_period = 0.05;
  options.delay_frames = 2;
  VirtualLiveRig live = MakeVirtualLiveRig(SmallRig(), WallScene(), {}, options);
  live.display->Show(Uniform(*live.display, 255));  // at t = 0
  GrabRequest request;
  request.not_before = 0.0;
  const Frame first = live.camera->Grab(request);  // exposed at 0: shows t = −0.1, black
  request.not_before = 0.1;
  const Frame third = live.camera->Grab(request);  // exposed at 0.1: shows t = 0, white
  EXPECT_GT(cv::mean(third.image)[0], cv::mean(first.image)[0] + 50);
}

TEST(VirtualCamera, LatencyMeasurementRecoversAnInjectedDelayOfKFrames) {
  for (int k = 0; k <= 3; ++k) {
    VirtualCameraOptions options;
    options.delay_frames = k;
    options.readout_jitter = 0.8 * options.frame_period;  // vary the phase
    options.seed = 17 + k;
    VirtualLiveRig live = MakeVirtualLiveRig(SmallRig(), WallScene(), {}, options);
    RigSession session(*live.display, *live.camera);
    const LatencyMeasurement& measurement = session.MeasureLatency();
    SCOPED_TRACE(measurement.Summary());
    std::printf(
        "[virtual latency] injected %d frames: measured %.1f ms = %.2f frames "
        "(samples %.2f..%.2f frames)\n",
        k, 1e3 * measurement.latency, measurement.frames(),
        *std::min_element(measurement.samples.begin(), measurement.samples.end()) /
            options.frame_period,
        *std::max_element(measurement.samples.begin(), measurement.samples.end()) /
            options.frame_period);
    EXPECT_EQ(static_cast<int>(std::floor(measurement.frames())), k);
    for (double sample : measurement.samples) {
      EXPECT_GE(sample, k * options.frame_period - 1e-9);
    }
    EXPECT_GT(measurement.white_level, measurement.black_level + 50);
    EXPECT_GT(measurement.lit_fraction, 0.5) << "the projector lights most of the view";
  }
}

TEST(VirtualCamera, AStalledCameraTimesOutAndTimePasses) {
  VirtualCameraOptions options;
  options.stall_after = 2;
  VirtualLiveRig live = MakeVirtualLiveRig(SmallRig(), WallScene(), {}, options);
  live.camera->Grab({});
  live.camera->Grab({});
  const double before = live.camera->Now();
  GrabRequest request;
  request.timeout = 1.5;
  EXPECT_EQ(ErrorOf([&] { live.camera->Grab(request); }),
            "camera virtual: no frame within 1.50 s (timeout): the camera stopped delivering "
            "frames");
  EXPECT_NEAR(live.camera->Now(), before + 1.5, 1e-12);
  // A frame due after the timeout is a timeout too.
  VirtualLiveRig slow = MakeVirtualLiveRig(SmallRig(), WallScene(), {}, {});
  request.not_before = 10.0;
  request.timeout = 1.0;
  EXPECT_THAT(ErrorOf([&] { slow.camera->Grab(request); }), HasSubstr("no frame within 1.00 s"));
}

TEST(VirtualCamera, ADeviceLostMidStreamIsAClearError) {
  VirtualCameraOptions options;
  options.lose_device_after = 1;
  VirtualLiveRig live = MakeVirtualLiveRig(SmallRig(), WallScene(), {}, options);
  live.camera->Grab({});
  EXPECT_THAT(ErrorOf([&] { live.camera->Grab({}); }),
              HasSubstr("camera virtual disappeared or failed"));
}

TEST(VirtualCamera, RefusesADisplayOfAnotherSizeAndBadOptions) {
  SimulatedClock clock;
  VirtualRig rig(SmallRig());
  VirtualDisplay display(1024, 768, [&] { return clock.Now(); });
  EXPECT_THAT(ErrorOf([&] { VirtualCamera camera(rig, display, clock); }),
              HasSubstr("virtual display is 1024x768 but the virtual rig's projector is 256x192"));
  VirtualCameraOptions options;
  options.frame_period = 0;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "frame period 0");
  options = VirtualCameraOptions();
  options.readout_jitter = 1.0;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "readout jitter 1");
}

TEST(MakeDemoScene, AMugBeforeABackdrop) {
  const Scene scene = MakeDemoScene(0.6);
  ASSERT_EQ(scene.objects.size(), 2u);
  EXPECT_NEAR(scene.objects[1].cam_from_model.translation.z(), 0.75, 1e-9);
  EXPECT_GT(scene.objects[0].mesh.faces.size(), 100u);
}

}  // namespace
}  // namespace sope
