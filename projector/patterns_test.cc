#include "projector/patterns.h"

#include <bitset>
#include <cmath>
#include <cstdint>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/structured_light.hpp>

#include "core/error.h"
#include "tests/opencv_graycode.h"
#include "tests/test_support.h"

namespace sope {
namespace {

TEST(GrayCode, BinaryFromGrayInvertsGrayFromBinary) {
  for (uint32_t value = 0; value < (1u << 17); ++value) {
    ASSERT_EQ(BinaryFromGray(GrayFromBinary(value)), value);
    ASSERT_EQ(GrayFromBinary(BinaryFromGray(value)), value);
  }
  std::mt19937 random(7);
  for (int i = 0; i < 100000; ++i) {
    const uint32_t value = random();
    ASSERT_EQ(BinaryFromGray(GrayFromBinary(value)), value) << value;
  }
}

TEST(GrayCode, NeighboursDifferInExactlyOneBit) {
  for (uint32_t value = 0; value + 1 < (1u << 16); ++value) {
    const uint32_t changed = GrayFromBinary(value) ^ GrayFromBinary(value + 1);
    ASSERT_EQ(std::bitset<32>(changed).count(), 1u) << value;
  }
}

TEST(GrayCode, PatternBitIsTheBitOfTheCodeWord) {
  EXPECT_EQ(GrayFromBinary(0b1011), 0b1110u);
  for (uint32_t coordinate = 0; coordinate < 2048; ++coordinate) {
    for (int bit = 0; bit < 11; ++bit) {
      ASSERT_EQ(PatternBit(PatternCode::kBinary, coordinate, bit), ((coordinate >> bit) & 1) == 1);
      ASSERT_EQ(PatternBit(PatternCode::kGray, coordinate, bit),
                (((coordinate ^ (coordinate >> 1)) >> bit) & 1) == 1);
    }
  }
}

TEST(BitsForSize, IsTheCeilingOfLog2) {
  EXPECT_EQ(BitsForSize(1), 1);  // a single column still needs one frame
  EXPECT_EQ(BitsForSize(2), 1);
  EXPECT_EQ(BitsForSize(3), 2);
  EXPECT_EQ(BitsForSize(700), 10);
  EXPECT_EQ(BitsForSize(800), 10);
  EXPECT_EQ(BitsForSize(1000), 10);
  EXPECT_EQ(BitsForSize(1024), 10);
  EXPECT_EQ(BitsForSize(1025), 11);
  EXPECT_EQ(BitsForSize(1280), 11);
}

TEST(PatternAxes, StringsRoundTrip) {
  for (PatternAxes axes : {PatternAxes::kX, PatternAxes::kY, PatternAxes::kXY}) {
    EXPECT_EQ(PatternAxesFromString(ToString(axes)), axes);
  }
  EXPECT_THROW_WITH_MESSAGE(PatternAxesFromString("z"), Error, "'z'");
}

TEST(PatternOptions, CheckNamesTheInvalidValue) {
  EXPECT_NO_THROW(PatternOptions().Check());
  PatternOptions options;
  options.projector_width = 0;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "projector size 0x768");
  options = PatternOptions();
  options.skip_low_bits = BitsForSize(options.projector_height);  // nothing left on y
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "skip_low_bits 10");
  options = PatternOptions();
  options.inverted = false;
  options.white_black = false;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "inverse frames or white/black references");
}

// The frames GeneratePatterns must produce, in display order.
std::vector<FrameInfo> ExpectedFrames(const PatternOptions& options) {
  std::vector<FrameInfo> frames;
  if (options.white_black) {
    frames.push_back({"", FrameRole::kWhite});
    frames.push_back({"", FrameRole::kBlack});
  }
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    if ((axis == PatternAxis::kX && options.axes == PatternAxes::kY) ||
        (axis == PatternAxis::kY && options.axes == PatternAxes::kX)) {
      continue;
    }
    const int bits =
        BitsForSize(axis == PatternAxis::kX ? options.projector_width : options.projector_height);
    for (int bit = bits - 1; bit >= options.skip_low_bits; --bit) {
      for (bool inverted : {false, true}) {
        if (!inverted || options.inverted) {
          frames.push_back({"", FrameRole::kCode, axis, options.code, bits, bit, inverted});
        }
      }
    }
  }
  return frames;
}

// Every pixel of a code frame shows PatternBit of its column (x) or row (y), negated for
// inverses; white and black are uniform.
void ExpectImageShowsItsBit(const Pattern& pattern, int width, int height) {
  const cv::Mat& image = pattern.image;
  ASSERT_EQ(image.type(), CV_8UC1);
  ASSERT_EQ(image.cols, width);
  ASSERT_EQ(image.rows, height);
  const FrameInfo& info = pattern.info;
  size_t wrong = 0;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      bool lit = info.role == FrameRole::kWhite;
      if (info.role == FrameRole::kCode) {
        const uint32_t coordinate = static_cast<uint32_t>(info.axis == PatternAxis::kX ? x : y);
        lit = PatternBit(info.code, coordinate, info.bit) != info.inverted;
      }
      wrong += image.at<uint8_t>(y, x) != (lit ? 255 : 0);
    }
  }
  EXPECT_EQ(wrong, 0u) << info.file;
}

struct SequenceCase {
  int width;
  int height;
  PatternAxes axes;
  PatternCode code;
  bool inverted;
  bool white_black;
  int skip_low_bits;

  PatternOptions Options() const {
    PatternOptions options;
    options.projector_width = width;
    options.projector_height = height;
    options.axes = axes;
    options.code = code;
    options.inverted = inverted;
    options.white_black = white_black;
    options.skip_low_bits = skip_low_bits;
    return options;
  }
};

class PatternSequence : public ::testing::TestWithParam<SequenceCase> {};

TEST_P(PatternSequence, CountsOrderImagesAndManifestAgree) {
  const SequenceCase& c = GetParam();
  const PatternOptions options = c.Options();
  const std::vector<Pattern> patterns = GeneratePatterns(options);
  const std::vector<FrameInfo> expected = ExpectedFrames(options);
  ASSERT_EQ(patterns.size(), expected.size());
  std::set<std::string> files;
  for (size_t i = 0; i < patterns.size(); ++i) {
    const FrameInfo& info = patterns[i].info;
    SCOPED_TRACE(fmt::format("frame {} ({})", i, info.file));
    EXPECT_EQ(info.role, expected[i].role);
    if (info.role == FrameRole::kCode) {
      EXPECT_EQ(info.axis, expected[i].axis);
      EXPECT_EQ(info.code, expected[i].code);
      EXPECT_EQ(info.bits, expected[i].bits);
      EXPECT_EQ(info.bit, expected[i].bit);
      EXPECT_EQ(info.inverted, expected[i].inverted);
    }
    EXPECT_TRUE(files.insert(info.file).second) << "duplicate file name";
    ExpectImageShowsItsBit(patterns[i], c.width, c.height);
  }
  // The manifest describes the same sequence and passes its own checks.
  const FrameSetManifest manifest = MakePatternManifest(options, 640, 480);
  ASSERT_EQ(manifest.frames.size(), patterns.size());
  for (size_t i = 0; i < patterns.size(); ++i) {
    EXPECT_EQ(manifest.frames[i].file, patterns[i].info.file);
    EXPECT_EQ(manifest.frames[i].role, patterns[i].info.role);
    EXPECT_EQ(manifest.frames[i].bit, patterns[i].info.bit);
  }
  EXPECT_NO_THROW(manifest.Check());
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    if (manifest.HasAxis(axis)) {
      EXPECT_EQ(manifest.AxisLowestBit(axis), c.skip_low_bits);
    }
  }
}

// Decoding the projector's own images (camera = projector) returns every coordinate:
// the bits, read most significant first from the frames, Gray → binary, give x (or y).
TEST_P(PatternSequence, FramesDecodeToEveryProjectorCoordinate) {
  const SequenceCase& c = GetParam();
  const PatternOptions options = c.Options();
  const std::vector<Pattern> patterns = GeneratePatterns(options);
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    const int size = axis == PatternAxis::kX ? c.width : c.height;
    std::vector<uint32_t> word(size, 0);
    bool coded = false;
    for (const Pattern& pattern : patterns) {  // most significant bit first
      if (pattern.info.role != FrameRole::kCode || pattern.info.axis != axis ||
          pattern.info.inverted) {
        continue;
      }
      coded = true;
      for (int i = 0; i < size; ++i) {
        const uint8_t level = axis == PatternAxis::kX ? pattern.image.at<uint8_t>(0, i)
                                                      : pattern.image.at<uint8_t>(i, 0);
        word[i] = (word[i] << 1) | (level == 255 ? 1u : 0u);
      }
    }
    if (!coded) continue;
    for (int i = 0; i < size; ++i) {
      const uint32_t block = c.code == PatternCode::kGray ? BinaryFromGray(word[i]) : word[i];
      ASSERT_EQ(block, static_cast<uint32_t>(i) >> c.skip_low_bits) << ToString(axis) << " " << i;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(
    Layouts, PatternSequence,
    ::testing::Values(SequenceCase{1000, 700, PatternAxes::kXY, PatternCode::kGray, true, true, 0},
                      SequenceCase{1280, 800, PatternAxes::kXY, PatternCode::kGray, true, true, 0},
                      SequenceCase{1280, 800, PatternAxes::kX, PatternCode::kBinary, false, true,
                                   0},
                      SequenceCase{300, 200, PatternAxes::kY, PatternCode::kGray, true, false, 0},
                      SequenceCase{300, 200, PatternAxes::kXY, PatternCode::kGray, true, true, 3},
                      SequenceCase{1, 1, PatternAxes::kXY, PatternCode::kGray, true, true, 0},
                      SequenceCase{17, 9, PatternAxes::kXY, PatternCode::kBinary, true, true, 1}));

// ---------------------------------------------------------------------------------------
// OpenCV's cv::structured_light::GrayCodePattern. generate() returns only the pattern
// images: for each column bit from the most significant, the pattern then its inverse,
// then the row bits likewise (2·(⌈log2 width⌉ + ⌈log2 height⌉) images, CV_8UC1, white =
// bit 1 of the Gray code). The white and black references come separately from
// getImagesForShadowMasks(blackImage, whiteImage) — black first in the argument list —
// and OpenCV's capture sample projects them after the patterns: white, then black.
// MakeOpenCvGrayCodeManifest describes exactly that capture order.
// ---------------------------------------------------------------------------------------
class OpenCvGrayCode : public ::testing::TestWithParam<cv::Size> {};

TEST_P(OpenCvGrayCode, ManifestMatchesGenerateImageForImage) {
  const cv::Size projector = GetParam();
  const testing::OpenCvGrayCodeSequence opencv = testing::GenerateOpenCvGrayCode(projector);
  const cv::Mat& white = opencv.white;
  const cv::Mat& black = opencv.black;
  const size_t num_patterns = testing::MakeOpenCvGrayCode(projector)->getNumberOfPatternImages();
  ASSERT_EQ(opencv.patterns.size(), num_patterns);
  const size_t expected_patterns =
      2 * static_cast<size_t>(BitsForSize(projector.width) + BitsForSize(projector.height));
  ASSERT_EQ(num_patterns, expected_patterns);

  std::vector<std::string> files;
  for (size_t i = 0; i < num_patterns + 2; ++i) files.push_back(fmt::format("im{}.png", i + 1));
  const FrameSetManifest manifest =
      MakeOpenCvGrayCodeManifest(projector.width, projector.height, 640, 480, files);
  ASSERT_EQ(manifest.frames.size(), num_patterns + 2);
  // OpenCV's captures in capture order: the patterns, white, black.
  const std::vector<cv::Mat> opencv_sequence = opencv.CaptureOrder();
  for (size_t i = 0; i < opencv_sequence.size(); ++i) {
    const FrameInfo& frame = manifest.frames[i];
    SCOPED_TRACE(fmt::format("image {} ({}, {} bit {}{})", i, ToString(frame.role),
                             ToString(frame.axis), frame.bit, frame.inverted ? " inverted" : ""));
    EXPECT_EQ(frame.file, files[i]);
    cv::Mat theirs = opencv_sequence[i];
    if (theirs.channels() == 3) cv::extractChannel(theirs, theirs, 0);
    const cv::Mat ours = RenderPattern(frame, projector.width, projector.height);
    ASSERT_EQ(theirs.size(), ours.size());
    ASSERT_EQ(theirs.type(), CV_8UC1);
    EXPECT_EQ(cv::norm(ours, theirs, cv::NORM_INF), 0.0);
  }
  EXPECT_EQ(manifest.frames[num_patterns].role, FrameRole::kWhite);
  EXPECT_EQ(manifest.frames[num_patterns + 1].role, FrameRole::kBlack);
  EXPECT_EQ(cv::countNonZero(white != 255), 0);
  EXPECT_EQ(cv::countNonZero(black), 0);
  // A list of the wrong length is refused.
  files.pop_back();
  EXPECT_THROW_WITH_MESSAGE(
      MakeOpenCvGrayCodeManifest(projector.width, projector.height, 640, 480, files), Error,
      "got " + std::to_string(files.size()));
}

// OpenCV's own decoder reads our rendered frames back to every projector pixel, so the
// polarity (bright = bit 1) and bit order agree with OpenCV's decoding as well.
TEST_P(OpenCvGrayCode, GetProjPixelDecodesOurFrames) {
  const cv::Size projector = GetParam();
  // Every pixel of small projectors, every third column and row of large ones.
  const int stride = projector.area() > 100000 ? 3 : 1;
  const cv::Ptr<cv::structured_light::GrayCodePattern> opencv =
      testing::MakeOpenCvGrayCode(projector);
  std::vector<std::string> files;
  for (size_t i = 0; i < opencv->getNumberOfPatternImages() + 2; ++i) {
    files.push_back(fmt::format("{}.png", i));
  }
  const FrameSetManifest manifest = MakeOpenCvGrayCodeManifest(
      projector.width, projector.height, projector.width, projector.height, files);
  std::vector<cv::Mat> images;
  for (size_t i = 0; i < opencv->getNumberOfPatternImages(); ++i) {
    images.push_back(RenderPattern(manifest.frames[i], projector.width, projector.height));
  }
  size_t wrong = 0;
  for (int y = 0; y < projector.height; y += stride) {
    for (int x = 0; x < projector.width; x += stride) {
      cv::Point decoded;
      const bool error = opencv->getProjPixel(images, x, y, decoded);
      wrong += error || decoded != cv::Point(x, y);
    }
  }
  EXPECT_EQ(wrong, 0u);
}

INSTANTIATE_TEST_SUITE_P(Sizes, OpenCvGrayCode,
                         ::testing::Values(cv::Size(1280, 800), cv::Size(512, 384),
                                           cv::Size(1000, 700), cv::Size(300, 200),
                                           cv::Size(17, 9)),
                         [](const ::testing::TestParamInfo<cv::Size>& info) {
                           return fmt::format("{}x{}", info.param.width, info.param.height);
                         });

}  // namespace
}  // namespace sope

namespace sope {
namespace {

constexpr double kTwoPiTest = 6.283185307179586476925286766559;

TEST(PhasePatterns, SequenceAndManifestFollowTheContract) {
  PatternOptions options;
  options.projector_width = 1024;
  options.projector_height = 768;
  options.family = PatternFamily::kPhase;
  options.periods = {1024, 64, 8};
  options.steps = 4;
  const std::vector<Pattern> patterns = GeneratePatterns(options);
  // white, black, then 3 groups × 4 shifts per axis.
  ASSERT_EQ(patterns.size(), 2u + 2u * 12u);
  const FrameSetManifest manifest = MakePatternManifest(options, 320, 240);
  ASSERT_EQ(manifest.frames.size(), patterns.size());
  const std::vector<PhaseGroup> x = manifest.PhaseGroups(PatternAxis::kX);
  const std::vector<PhaseGroup> y = manifest.PhaseGroups(PatternAxis::kY);
  ASSERT_EQ(x.size(), 3u);
  ASSERT_EQ(y.size(), 3u);
  EXPECT_EQ(x[0].period, 1024.0);
  EXPECT_TRUE(x[0].absolute);
  EXPECT_TRUE(y[0].absolute);  // 1024 ≥ 768
  EXPECT_EQ(x[2].period, 8.0);
  ASSERT_EQ(x[2].shifts.size(), 4u);
  EXPECT_NEAR(x[2].shifts[1], kTwoPiTest / 4, 1e-12);
  // Every sinusoid is the contract's I(u) = ½(1 + cos(2πu/period − shift)), 8-bit.
  for (const Pattern& pattern : patterns) {
    if (pattern.info.role != FrameRole::kPhase) continue;
    ASSERT_EQ(pattern.image.type(), CV_8UC1);
    const bool is_x = pattern.info.axis == PatternAxis::kX;
    for (int u : {0, 1, 5, 37, 500, 767}) {
      const double expected =
          255.0 * 0.5 * (1.0 + std::cos(kTwoPiTest * u / pattern.info.period - pattern.info.shift));
      const int value = is_x ? pattern.image.at<uint8_t>(13, u) : pattern.image.at<uint8_t>(u, 13);
      EXPECT_LE(std::abs(value - expected), 0.5 + 1e-9) << pattern.info.file << " u " << u;
    }
  }
}

TEST(PhasePatterns, AutomaticPeriodsAndGrayPlusPhase) {
  PatternOptions options;
  options.projector_width = 1280;
  options.projector_height = 800;
  options.family = PatternFamily::kPhase;
  options.axes = PatternAxes::kX;
  options.white_black = false;
  EXPECT_EQ(PhasePeriodsFor(options, 1280), (std::vector<double>{1280, 160, 20}));
  EXPECT_EQ(MakePatternManifest(options, 64, 48).frames.size(), 12u);

  options.family = PatternFamily::kGrayPhase;
  options.period = 16;
  options.steps = 4;
  options.axes = PatternAxes::kXY;
  options.white_black = true;
  const FrameSetManifest manifest = MakePatternManifest(options, 64, 48);
  // Gray bits 10..3 (x, 11 bits) and 9..3 (y, 10 bits) with inverses, one group per axis.
  EXPECT_EQ(manifest.AxisLowestBit(PatternAxis::kX), 3);
  EXPECT_EQ(manifest.AxisBits(PatternAxis::kX), 11);
  EXPECT_EQ(manifest.PhaseGroups(PatternAxis::kY).size(), 1u);
  EXPECT_EQ(manifest.frames.size(), 2u + 2u * (8 + 7) + 2u * 4);
  options.complementary_bit = false;
  EXPECT_EQ(MakePatternManifest(options, 64, 48).AxisLowestBit(PatternAxis::kX), 4);
}

TEST(PhasePatterns, PrecompensationInvertsTheResponse) {
  PatternOptions options;
  options.projector_width = 64;
  options.projector_height = 8;
  options.axes = PatternAxes::kX;
  options.family = PatternFamily::kPhase;
  options.periods = {64};
  options.steps = 3;
  options.precompensate = ProjectorResponse::Gamma(2.2, 1025);
  for (const Pattern& pattern : GeneratePatterns(options)) {
    if (pattern.info.role != FrameRole::kPhase) continue;
    for (int u = 0; u < 64; ++u) {
      const double shown = std::pow(pattern.image.at<uint8_t>(0, u) / 255.0, 2.2);
      const double wanted =
          0.5 * (1.0 + std::cos(kTwoPiTest * u / pattern.info.period - pattern.info.shift));
      // One 8-bit step at the steepest part of v^2.2 is 2.2/255 of the range.
      EXPECT_NEAR(shown, wanted, 0.01) << u;
    }
  }
}

TEST(PhasePatterns, InvalidOptionsNameTheValue) {
  PatternOptions options;
  options.family = PatternFamily::kPhase;
  options.periods = {1024, 0};
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "phase period 0");
  options.periods = {512, 64};  // coarsest below the 1024 px width
  try {
    options.Check();
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("coarsest phase period 512"), std::string::npos);
  }
  options.periods = {1024};
  options.steps = 2;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "phase steps 2");
  options.steps = 4;
  options.family = PatternFamily::kGrayPhase;
  options.period = 12;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "gray+phase period 12");
  PatternCode code = PatternCode::kBinary;
  EXPECT_EQ(PatternFamilyFromString("gray+phase", &code), PatternFamily::kGrayPhase);
  EXPECT_EQ(code, PatternCode::kGray);
  EXPECT_THROW_WITH_MESSAGE(PatternFamilyFromString("sine", &code), Error,
                            "unknown pattern code 'sine'");
}

// The one-line description reports print (sope eval's scanned protocols).
TEST(DescribePatterns, NamesTheFamilyAxesAndPeriods) {
  PatternOptions options;
  EXPECT_EQ(DescribePatterns(options), "Gray code, axes xy, inverses");
  options.inverted = false;
  options.skip_low_bits = 2;
  EXPECT_EQ(DescribePatterns(options), "Gray code, axes xy, 2 low bits skipped");
  options.family = PatternFamily::kPhase;
  EXPECT_EQ(DescribePatterns(options),
            "phase shift, axes xy, periods 1024/128/16 px (x), 768/96/12 px (y), 4 steps");
  options.periods = {1024, 64, 8};
  options.axes = PatternAxes::kX;
  options.steps = 3;
  EXPECT_EQ(DescribePatterns(options), "phase shift, axes x, periods 1024/64/8 px, 3 steps");
  options.family = PatternFamily::kGrayPhase;
  options.precompensate = ProjectorResponse::Gamma(2.2);
  EXPECT_EQ(DescribePatterns(options),
            "Gray code + phase shift at 16 px, axes x, 3 steps, pre-distorted for the projector "
            "response");
}

}  // namespace
}  // namespace sope
