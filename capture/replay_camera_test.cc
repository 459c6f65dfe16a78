// Replaying a recorded frame set as a camera, and the camera factory's specs.
#include "capture/replay_camera.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/frame_set.h"
#include "projector/patterns.h"
#include "tests/test_support.h"

namespace sope {
namespace {

using ::testing::HasSubstr;

using testing::ErrorOf;

// A small recorded set: frame i is filled with 10·i.
FrameSet SmallSet(PatternOptions* options_out = nullptr) {
  PatternOptions options;
  options.projector_width = 16;
  options.projector_height = 8;
  options.axes = PatternAxes::kX;
  FrameSet set;
  set.manifest = MakePatternManifest(options, 12, 10);
  for (size_t i = 0; i < set.manifest.frames.size(); ++i) {
    set.images.push_back(cv::Mat(10, 12, CV_8UC1, cv::Scalar(static_cast<double>(10 * i))));
  }
  if (options_out) *options_out = options;
  return set;
}

TEST(ReplayCamera, DeliversTheFramesInOrderAsIfLive) {
  PatternOptions options;
  FrameSet set = SmallSet(&options);
  const std::vector<Pattern> patterns = GeneratePatterns(options);
  ReplayCamera camera(set, "memory");
  EXPECT_FALSE(camera.live());
  EXPECT_EQ(camera.width(), 12);
  EXPECT_EQ(camera.height(), 10);
  EXPECT_EQ(camera.name(), "replay:memory");
  double last_start = -1.0;
  for (size_t i = 0; i < patterns.size(); ++i) {
    GrabRequest request;
    request.showing = &patterns[i].info;
    request.not_before = camera.Now() + 0.25 * (i % 3);
    const Frame frame = camera.Grab(request);
    EXPECT_EQ(frame.image.at<uint8_t>(0, 0), 10 * i);
    EXPECT_EQ(frame.sequence, i);
    EXPECT_GE(frame.exposure_start, request.not_before) << "fresh by the camera's clock";
    EXPECT_GT(frame.exposure_start, last_start);
    EXPECT_GE(camera.Now(), frame.exposure_start) << "time passed while grabbing";
    last_start = frame.exposure_start;
  }
  EXPECT_EQ(camera.delivered(), patterns.size());
  EXPECT_THAT(ErrorOf([&] { camera.Grab({}); }),
              HasSubstr("replay memory: exhausted — all " + std::to_string(patterns.size()) +
                        " recorded frames were delivered"));
}

TEST(ReplayCamera, RefusesAFrameRecordedWithAnotherPattern) {
  PatternOptions options;
  ReplayCamera camera(SmallSet(&options), "memory");
  const std::vector<Pattern> patterns = GeneratePatterns(options);
  GrabRequest request;
  request.showing = &patterns[0].info;  // white: matches frame 0
  camera.Grab(request);
  request.showing = &patterns[2].info;  // frame 1 is black
  EXPECT_EQ(ErrorOf([&] { camera.Grab(request); }),
            "replay memory: frame 1 (frame_01.png) does not match the pattern sequence: "
            "recorded black but the projector shows code x gray bit 3/4");
  FrameInfo inverted = patterns[2].info;
  inverted.inverted = true;
  std::string why;
  EXPECT_FALSE(SameFrameInfo(patterns[2].info, inverted, &why));
  EXPECT_EQ(why,
            "recorded code x gray bit 3/4 but the projector shows code x gray bit 3/4 inverted");
  EXPECT_TRUE(SameFrameInfo(patterns[2].info, patterns[2].info));
}

TEST(ReplayCamera, OpensARecordedDirectoryThroughTheFactory) {
  testing::ScratchDir scratch;
  WriteFrameSet(scratch.File("set"), SmallSet());
  const std::unique_ptr<Camera> camera = OpenCamera("replay:" + scratch.File("set"));
  EXPECT_FALSE(camera->live());
  EXPECT_EQ(camera->Grab({}).image.at<uint8_t>(0, 0), 0);
  EXPECT_EQ(camera->Grab({}).image.at<uint8_t>(0, 0), 10);
  EXPECT_THAT(ErrorOf([&] { OpenCamera("replay:" + scratch.File("missing")); }),
              HasSubstr("missing"));
}

TEST(OpenCamera, SpecsAndClearErrors) {
  EXPECT_EQ(ErrorOf([] { OpenCamera("webcam"); }),
            "camera 'webcam': expected /dev/videoN, replay:DIR or virtual");
  EXPECT_THAT(ErrorOf([] { OpenCamera("virtual"); }), HasSubstr("needs a virtual rig"));
  EXPECT_THAT(ErrorOf([] { OpenCamera("replay:"); }), HasSubstr("replay needs a directory"));
  const std::string absent = ErrorOf([] { OpenCamera("/dev/video99"); });
  if (HaveV4l2Camera()) {
    EXPECT_THAT(absent, HasSubstr("camera /dev/video99: no such device"));
  } else {
    EXPECT_THAT(absent, HasSubstr("no V4L2 backend"));
  }
  EXPECT_EQ(absent.find('\n'), std::string::npos);
  if (HaveV4l2Camera()) {
    // A device node that is not a camera.
    EXPECT_EQ(ErrorOf([] { OpenCamera("/dev/null"); }),
              "camera /dev/null: not a V4L2 video device");
  }
}

}  // namespace
}  // namespace sope
