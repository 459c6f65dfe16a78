#include "core/frame_set.h"

#include <fstream>
#include <limits>

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

using testing::ErrorOf;

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
  // A number beyond double's range (nlohmann throws out_of_range, not parse_error: it
  // escaped as an internal error; found by frames_json_fuzz, 2026-12-05).
  EXPECT_NE(ErrorOf([] {
              ParseFrameSetManifest("{\"camera\": {\"width\": 888.38886E8887}}", "m.json");
            }).find("m.json: not valid JSON"),
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
  EXPECT_NE(ErrorOf([&] { parse(j); }), "(no error)");
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

// Phase frames of one group: `shifts` on `axis` at `period`, files named after them.
void AddPhaseGroup(PatternAxis axis, double period, const std::vector<double>& shifts,
                   FrameSetManifest* manifest) {
  for (double shift : shifts) {
    FrameInfo frame;
    frame.role = FrameRole::kPhase;
    frame.axis = axis;
    frame.period = period;
    frame.shift = shift;
    frame.file = fmt::format("phase_{}_{}_{}.png", ToString(axis), period,
                             manifest->frames.size());
    manifest->frames.push_back(frame);
  }
}

// A phase-only manifest for a 64×48 projector: x at periods 64 (absolute) and 8.
FrameSetManifest PhaseManifest() {
  FrameSetManifest manifest;
  manifest.camera_width = 8;
  manifest.camera_height = 6;
  manifest.projector_width = 64;
  manifest.projector_height = 48;
  AddPhaseGroup(PatternAxis::kX, 64.0, {0.0, 2.0944, 4.18879}, &manifest);
  AddPhaseGroup(PatternAxis::kX, 8.0, {0.0, 1.5707963, 3.14159265, 4.71238898}, &manifest);
  return manifest;
}

TEST(FrameSet, PhaseManifestRoundTripAndGroups) {
  const FrameSetManifest manifest = PhaseManifest();
  const FrameSetManifest parsed =
      ParseFrameSetManifest(SerializeFrameSetManifest(manifest), "test");
  ASSERT_EQ(parsed.frames.size(), 7u);
  EXPECT_EQ(parsed.frames[4].role, FrameRole::kPhase);
  EXPECT_EQ(parsed.frames[4].period, 8.0);
  EXPECT_EQ(parsed.frames[5].shift, 3.14159265);
  EXPECT_TRUE(parsed.HasPhase());
  EXPECT_TRUE(parsed.HasPhaseAxis(PatternAxis::kX));
  EXPECT_FALSE(parsed.HasPhaseAxis(PatternAxis::kY));
  EXPECT_FALSE(parsed.HasAxis(PatternAxis::kX));  // no code frames
  const std::vector<PhaseGroup> groups = parsed.PhaseGroups(PatternAxis::kX);
  ASSERT_EQ(groups.size(), 2u);
  EXPECT_EQ(groups[0].period, 64.0);
  EXPECT_TRUE(groups[0].absolute);
  EXPECT_EQ(groups[1].period, 8.0);
  EXPECT_FALSE(groups[1].absolute);
  EXPECT_EQ(groups[1].frames, (std::vector<size_t>{3, 4, 5, 6}));
}

TEST(FrameSet, DesignPhaseExampleParses) {
  // DESIGN.md: SLStudio's "2x3" codec for a 1824-wide projector.
  const std::string text = R"({ "format": "sope-frames/1",
    "camera": {"width": 1688, "height": 1352}, "projector": {"width": 1824, "height": 1140},
    "frames": [
      {"file": "f0.png", "role": "phase", "axis": "x", "period": 1824.0, "shift": 0.0},
      {"file": "f1.png", "role": "phase", "axis": "x", "period": 1824.0, "shift": 2.0944},
      {"file": "f2.png", "role": "phase", "axis": "x", "period": 1824.0, "shift": 4.18879},
      {"file": "f3.png", "role": "phase", "axis": "x", "period": 114.0, "shift": 0.0},
      {"file": "f4.png", "role": "phase", "axis": "x", "period": 114.0, "shift": 2.0944},
      {"file": "f5.png", "role": "phase", "axis": "x", "period": 114.0, "shift": 4.18879} ] })";
  const FrameSetManifest manifest = ParseFrameSetManifest(text, "design");
  ASSERT_EQ(manifest.PhaseGroups(PatternAxis::kX).size(), 2u);
  EXPECT_EQ(manifest.PhaseGroups(PatternAxis::kX)[1].period, 114.0);
}

TEST(FrameSet, BadPhaseSetsGiveClearErrors) {
  using nlohmann::json;
  const json good = json::parse(SerializeFrameSetManifest(PhaseManifest()));
  auto parse = [](const json& j) { ParseFrameSetManifest(j.dump(), "m.json"); };
  ASSERT_EQ(ErrorOf([&] { parse(good); }), "(no error)");
  json j = good;
  j["frames"][1]["shift"] = 2.0 * 3.14159265358979323846;  // = shift 0 modulo 2π
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("phase group of period 64: 2 distinct shifts"),
            std::string::npos)
      << ErrorOf([&] { parse(j); });
  j = good;
  j["frames"].erase(2);  // two shifts left at period 64
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("at least 3 distinct shifts"), std::string::npos);
  j = good;
  j["frames"][3]["period"] = 0.0;
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("phase period 0 must be a positive"),
            std::string::npos);
  j = good;
  j["frames"][3]["period"] = -8.0;
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("phase period -8 must be a positive"),
            std::string::npos);
  j = good;
  j["frames"][3]["period"] = "eight";
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("'period' has the wrong type"), std::string::npos);
  j = good;
  j["frames"][3].erase("shift");
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("missing 'shift'"), std::string::npos);
  // Not finite (in-memory manifests; JSON cannot carry NaN).
  FrameSetManifest manifest = PhaseManifest();
  manifest.frames[3].period = std::numeric_limits<double>::infinity();
  EXPECT_NE(ErrorOf([&] { manifest.Check(); }).find("phase period inf"), std::string::npos);
  manifest = PhaseManifest();
  manifest.frames[3].shift = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(ErrorOf([&] { manifest.Check(); }).find("phase shift nan is not finite"),
            std::string::npos);
  // The absolute group removed: period 8 has nothing to unwrap it.
  j = good;
  for (int k = 0; k < 3; ++k) j["frames"].erase(0);
  EXPECT_NE(ErrorOf([&] { parse(j); })
                .find("phase group of period 8 px is finer than the projector (64 px) and has "
                      "no coarser group or Gray code"),
            std::string::npos)
      << ErrorOf([&] { parse(j); });
  // A y group with a coarsest period below the projector height.
  manifest = PhaseManifest();
  AddPhaseGroup(PatternAxis::kY, 47.5, {0.0, 2.0, 4.0}, &manifest);
  EXPECT_NE(ErrorOf([&] { manifest.Check(); }).find("axis y: the phase group of period 47.5"),
            std::string::npos);
}

TEST(FrameSet, GrayPlusPhaseMustFitTogether) {
  // Gray code bits 5..3 of a 64-pixel x axis: blocks of 8 px; phase at period 8 fits, and
  // at 16 fits with bit 3 as the complementary half-period bit.
  auto make = [](int lowest_bit, double period) {
    FrameSetManifest manifest;
    manifest.camera_width = 8;
    manifest.camera_height = 6;
    manifest.projector_width = 64;
    manifest.projector_height = 48;
    for (int bit = 5; bit >= lowest_bit; --bit) {
      for (bool inverted : {false, true}) {
        FrameInfo code;
        code.file = fmt::format("code_{}{}.png", bit, inverted ? "i" : "");
        code.axis = PatternAxis::kX;
        code.bits = 6;
        code.bit = bit;
        code.inverted = inverted;
        manifest.frames.push_back(code);
      }
    }
    AddPhaseGroup(PatternAxis::kX, period, {0.0, 2.0944, 4.18879}, &manifest);
    return manifest;
  };
  EXPECT_EQ(ErrorOf([&] { make(3, 8.0).Check(); }), "(no error)");
  EXPECT_EQ(ErrorOf([&] { make(3, 16.0).Check(); }), "(no error)");
  EXPECT_NE(ErrorOf([&] { make(3, 12.0).Check(); })
                .find("axis x: the Gray code's finest stripe is 8 px but the coarsest phase "
                      "period is 12 px"),
            std::string::npos)
      << ErrorOf([&] { make(3, 12.0).Check(); });
  EXPECT_NE(ErrorOf([&] { make(3, 32.0).Check(); }), "(no error)");
  EXPECT_NE(ErrorOf([&] { make(4, 8.0).Check(); }), "(no error)");
  FrameSetManifest binary = make(3, 8.0);
  for (FrameInfo& frame : binary.frames) frame.code = PatternCode::kBinary;
  EXPECT_NE(ErrorOf([&] { binary.Check(); }).find("combined with a Gray code only"),
            std::string::npos);
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

// Issue 13: nlohmann's get<int>() wrapped 4294967616 to 320, truncated 320.7 and saturated
// 1e30; only exact integers in range are accepted.
TEST(FrameSet, NonIntegerOrOutOfRangeNumbersAreRefused) {
  using nlohmann::json;
  const json good = json::parse(SerializeFrameSetManifest(SmallManifest()));
  auto parse = [](const json& j) { ParseFrameSetManifest(j.dump(), "m.json"); };
  for (const json& width : {json(4294967616ull), json(320.7), json(1e30), json(-4294967296ll)}) {
    json j = good;
    j["camera"]["width"] = width;
    const std::string error = ErrorOf([&] { parse(j); });
    SCOPED_TRACE(width.dump());
    EXPECT_NE(error.find("'width'"), std::string::npos) << error;
    EXPECT_TRUE(error.find("must be an integer") != std::string::npos ||
                error.find("out of range") != std::string::npos)
        << error;
  }
  json j = good;
  j["frames"][2]["bit"] = 0.5;
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("'bit' has the wrong type: must be an integer"), std::string::npos);
  j = good;
  j["camera"]["width"] = 320.0;  // a float, even a whole one, is not an integer in JSON
  EXPECT_NE(ErrorOf([&] { parse(j); }).find("must be an integer"), std::string::npos);
}

}  // namespace
}  // namespace sope
