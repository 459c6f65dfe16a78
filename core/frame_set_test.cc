#include "core/frame_set.h"

#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "tests/test_support.h"

namespace sope {
namespace {

// A 2-bit x-only set with inverses and references on a 4-pixel-wide projector.
FrameSetManifest SmallManifest() {
  FrameSetManifest manifest;
  manifest.camera_width = 8;
  manifest.camera_height = 6;
  manifest.projector_width = 4;
  manifest.projector_height = 3;
  FrameInfo white, black;
  white.file = "white.png";
  white.role = FrameRole::kWhite;
  black.file = "black.png";
  black.role = FrameRole::kBlack;
  manifest.frames = {white, black};
  for (int bit = 1; bit >= 0; --bit) {
    for (bool inverted : {false, true}) {
      FrameInfo code;
      code.file = "code_" + std::to_string(bit) + (inverted ? "i" : "") + ".png";
      code.axis = PatternAxis::kX;
      code.bits = 2;
      code.bit = bit;
      code.inverted = inverted;
      manifest.frames.push_back(code);
    }
  }
  return manifest;
}

FrameSet SmallSet() {
  FrameSet set;
  set.manifest = SmallManifest();
  for (size_t i = 0; i < set.manifest.frames.size(); ++i) {
    set.images.push_back(cv::Mat(6, 8, CV_8UC1, cv::Scalar(static_cast<int>(20 * i))));
  }
  return set;
}

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(FrameSet, ManifestRoundTrip) {
  const FrameSetManifest manifest = SmallManifest();
  const FrameSetManifest parsed =
      ParseFrameSetManifest(SerializeFrameSetManifest(manifest), "test");
  ASSERT_EQ(parsed.frames.size(), manifest.frames.size());
  EXPECT_EQ(parsed.camera_width, 8);
  EXPECT_EQ(parsed.projector_height, 3);
  EXPECT_EQ(parsed.frames[3].bit, 1);
  EXPECT_TRUE(parsed.frames[3].inverted);
  EXPECT_EQ(parsed.AxisBits(PatternAxis::kX), 2);
  EXPECT_EQ(parsed.AxisBits(PatternAxis::kY), 0);
  EXPECT_EQ(parsed.FindCode(PatternAxis::kX, 0, true), std::optional<size_t>(5));
}

TEST(FrameSet, DesignExampleParses) {
  const std::string text = R"({ "format": "sope-frames/1",
    "camera": {"width": 1688, "height": 1352}, "projector": {"width": 1824, "height": 1140},
    "frames": [ {"file": "frame_00.png", "role": "white"}, {"file": "frame_01.png", "role": "black"},
      {"file": "frame_02.png", "role": "code", "axis": "x", "code": "gray", "bits": 11, "bit": 10, "inverted": false} ],
    "calibration": "calibration.yaml" })";
  const FrameSetManifest manifest = ParseFrameSetManifest(text, "design");
  EXPECT_EQ(manifest.calibration, "calibration.yaml");
  EXPECT_EQ(manifest.AxisLowestBit(PatternAxis::kX), 10);
}

TEST(FrameSet, MalformedManifestsGiveClearErrors) {
  using nlohmann::json;
  const json good = json::parse(SerializeFrameSetManifest(SmallManifest()));
  auto parse = [](const json& j) { ParseFrameSetManifest(j.dump(), "m.json"); };
  EXPECT_NE(ErrorOf([] { ParseFrameSetManifest("{not json", "m.json"); }).find("not valid JSON"),
            std::string::npos);
  json j = good;
  j["format"] = "sope-frames/9";
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("unsupported format"), std::string::npos);
  j = good;
  j.erase("camera");
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("'camera'"), std::string::npos);
  j = good;
  j["frames"][2]["bit"] = 2;  // bit ≥ bits
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("bit 2"), std::string::npos);
  j = good;
  j["frames"][2]["axis"] = "z";
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("unknown pattern axis"), std::string::npos);
  j = good;
  j["frames"][3]["file"] = "code_1.png";  // listed twice
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("listed twice"), std::string::npos);
  j = good;
  j["frames"].erase(2);  // bit 1 pattern missing, its inverse orphaned
  EXPECT_FALSE(ErrorOf([&] { parse(j); }).empty());
  j = good;
  j["projector"]["width"] = 5;  // 2 bits cannot code 5 columns
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("cannot code"), std::string::npos);
  j = good;
  j["frames"][2]["bits"] = "two";
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("wrong type"), std::string::npos);
  j = good;
  json frames = json::array();  // no inverses and no white frame: undecodable
  for (const auto& frame : good["frames"]) {
    if (frame["role"] == "code" && !frame["inverted"].get<bool>()) frames.push_back(frame);
    if (frame["role"] == "black") frames.push_back(frame);
  }
  j["frames"] = frames;
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("need both a white and a black"), std::string::npos);
}

TEST(FrameSet, WriteLoadRoundTrip) {
  testing::ScratchDir scratch;
  const FrameSet set = SmallSet();
  WriteFrameSet(scratch.File("set"), set);
  const FrameSet loaded = LoadFrameSet(scratch.File("set"));
  ASSERT_EQ(loaded.images.size(), set.images.size());
  for (size_t i = 0; i < set.images.size(); ++i) {
    EXPECT_EQ(cv::norm(loaded.images[i], set.images[i], cv::NORM_INF), 0.0);
  }
}

TEST(FrameSet, ColourFramesAreConvertedAndWhiteColourKept) {
  testing::ScratchDir scratch;
  FrameSet set = SmallSet();
  WriteFrameSet(scratch.File("set"), set);
  WriteImageAtomic(scratch.File("set/white.png"), cv::Mat(6, 8, CV_8UC3, cv::Scalar(10, 20, 30)));
  const FrameSet loaded = LoadFrameSet(scratch.File("set"));
  EXPECT_EQ(loaded.images[0].type(), CV_8UC1);
  ASSERT_EQ(loaded.white_color.type(), CV_8UC3);
  EXPECT_EQ(loaded.white_color.at<cv::Vec3b>(0, 0), cv::Vec3b(10, 20, 30));
}

TEST(FrameSet, BadFramesGiveClearErrors) {
  testing::ScratchDir scratch;
  const FrameSet set = SmallSet();
  WriteFrameSet(scratch.File("set"), set);
  // Missing frame.
  std::filesystem::remove(scratch.File("set/code_0.png"));
  EXPECT_NE(ErrorOf([&] { LoadFrameSet(scratch.File("set")); }).find("code_0.png"),
            std::string::npos);
  // Corrupt frame.
  std::ofstream(scratch.File("set/code_0.png")) << "garbage";
  EXPECT_NE(ErrorOf([&] { LoadFrameSet(scratch.File("set")); }).find("cannot decode"),
            std::string::npos);
  // Mismatched size.
  WriteImageAtomic(scratch.File("set/code_0.png"), cv::Mat(5, 8, CV_8UC1, cv::Scalar(0)));
  EXPECT_NE(ErrorOf([&] { LoadFrameSet(scratch.File("set")); }).find("does not match"),
            std::string::npos);
  // No manifest.
  EXPECT_NE(ErrorOf([&] { LoadFrameSet(scratch.path()); }).find("frames.json"),
            std::string::npos);
}

TEST(FrameSet, CheckRejectsMixedBitDepths) {
  FrameSet set = SmallSet();
  set.images[1] = cv::Mat(6, 8, CV_16UC1, cv::Scalar(0));
  EXPECT_THROW_WITH_MESSAGE(set.Check(), Error, "black.png", "bit depth");
}

}  // namespace
}  // namespace sope
