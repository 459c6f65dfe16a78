#include "decoder/decoder.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <numeric>
#include <random>
#include <utility>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "decoder/decoder_internal.h"
#include "decoder/speckle_filter.h"
#include "projector/patterns.h"
#include "tests/test_support.h"

namespace sope {
namespace {

// ---------------------------------------------------------------------------------------
// A synthetic capture: the projector's patterns seen by a camera through a known affine
// map (the "scene"), with optics blur, a spatially varying albedo, ambient light, sensor
// noise, a cast shadow and optionally an interreflection (global light) term. The true
// projector coordinate of every camera pixel is known exactly.
// ---------------------------------------------------------------------------------------
struct SceneOptions {
  PatternOptions patterns;
  int camera_width = 400;
  int camera_height = 300;
  // Projector (x, y) of camera pixel (u, v), pixel centres at integers (OpenCV):
  // x = a0·u + a1·v + a2, y = a3·u + a4·v + a5.
  std::array<double, 6> proj_from_cam{0.7, 0.03, -12.0, -0.02, 0.65, 4.0};
  // Render code patterns this wide/high instead of the projector size (> projector size
  // fakes stripes whose codes lie beyond the projector).
  int pattern_width = 0;
  int pattern_height = 0;
  double blur_sigma_px = 0.7;        // camera pixels
  double gain = 190.0;               // grey levels of a fully lit pixel of albedo 1
  double ambient = 12.0;             // grey levels everywhere, projector off
  double noise_sigma = 1.5;          // grey levels
  cv::Rect shadow{40, 200, 60, 50};  // camera pixels no projector light reaches
  // Interreflection: a pixel in a vertical band around the image centre also receives
  // global_strength × (its horizontally mirrored pixel's direct light, blurred by
  // kGlobalBlurPx) — a concave corner reflecting the opposite wall.
  double global_strength = 0.0;
  bool sixteen_bit = false;
  uint64_t seed = 7;
};

constexpr double kGlobalBlurPx = 20.0;
constexpr double kGlobalBandFraction = 0.12;  // Gaussian σ of the band, × camera width

struct SyntheticCapture {
  FrameSet frame_set;
  cv::Mat true_x, true_y;  // CV_64FC1 continuous projector coordinates
  cv::Mat in_shadow;       // CV_8UC1, 255 inside the shadow rectangle
};

cv::Mat Albedo(const SceneOptions& scene) {
  cv::Mat albedo(scene.camera_height, scene.camera_width, CV_32FC1);
  for (int v = 0; v < albedo.rows; ++v) {
    for (int u = 0; u < albedo.cols; ++u) {
      albedo.at<float>(v, u) = static_cast<float>(0.45 + 0.5 * u / albedo.cols);
    }
  }
  return albedo;
}

SyntheticCapture RenderScene(const SceneOptions& scene) {
  SyntheticCapture capture;
  const cv::Size camera(scene.camera_width, scene.camera_height);
  capture.frame_set.manifest =
      MakePatternManifest(scene.patterns, scene.camera_width, scene.camera_height);
  const int pattern_width =
      scene.pattern_width > 0 ? scene.pattern_width : scene.patterns.projector_width;
  const int pattern_height =
      scene.pattern_height > 0 ? scene.pattern_height : scene.patterns.projector_height;
  const cv::Mat albedo = Albedo(scene);
  cv::Mat band(camera, CV_32FC1);
  for (int u = 0; u < camera.width; ++u) {
    const double t = (u - camera.width / 2.0) / (kGlobalBandFraction * camera.width);
    band.col(u).setTo(scene.global_strength * std::exp(-t * t));
  }
  cv::RNG rng(scene.seed);
  for (const FrameInfo& frame : capture.frame_set.manifest.frames) {
    cv::Mat pattern;
    RenderPattern(frame, pattern_width, pattern_height).convertTo(pattern, CV_32F, 1.0 / 255);
    cv::Mat direct;
    cv::warpAffine(pattern, direct, cv::Matx23d(scene.proj_from_cam.data()), camera,
                   cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT, 0.0);
    direct(scene.shadow).setTo(0.0);
    cv::Mat irradiance = direct.clone();
    if (scene.global_strength > 0.0) {
      cv::Mat mirrored, global;
      cv::flip(direct, mirrored, 1);
      cv::GaussianBlur(mirrored, global, cv::Size(), kGlobalBlurPx);
      irradiance += global.mul(band);
    }
    if (scene.blur_sigma_px > 0.0) {
      cv::GaussianBlur(irradiance, irradiance, cv::Size(), scene.blur_sigma_px);
    }
    cv::Mat noise(camera, CV_32FC1);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, scene.noise_sigma);
    cv::Mat grey = scene.ambient + scene.gain * albedo.mul(irradiance) + noise;
    cv::Mat image;
    if (scene.sixteen_bit) {
      grey.convertTo(image, CV_16U, 257.0);
    } else {
      grey.convertTo(image, CV_8U);
    }
    capture.frame_set.images.push_back(image);
  }
  capture.true_x.create(camera, CV_64FC1);
  capture.true_y.create(camera, CV_64FC1);
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      const std::array<double, 6>& a = scene.proj_from_cam;
      capture.true_x.at<double>(v, u) = a[0] * u + a[1] * v + a[2];
      capture.true_y.at<double>(v, u) = a[3] * u + a[4] * v + a[5];
    }
  }
  capture.in_shadow = cv::Mat::zeros(camera, CV_8UC1);
  capture.in_shadow(scene.shadow).setTo(255);
  return capture;
}

// Decoding quality against the truth. A pixel is "lit" when it sees the projector at least
// one projector pixel inside its border and at least kShadowClearance camera pixels from
// the shadow and kBorderClearance from the image border (where the synthetic blur
// reflects the image); "interior" when it is also at least kEdgeClearance projector pixels from
// every boundary between coded blocks (there the optics blur leaves the deciding bit's
// |pattern − inverse| near 0 and the pixel is rightly left undecided); "dark" when it is
// well inside the shadow or well off the projector.
constexpr int kShadowClearance = 3;
constexpr int kBorderClearance = 3;
constexpr double kEdgeClearance = 0.15;

struct Score {
  size_t lit = 0;
  size_t correct = 0;  // valid, every coded axis within step/2 + 1 of the truth
  size_t exact = 0;    // valid, every coded axis equal to the ideal decoded value
  size_t wrong = 0;    // valid but not correct
  size_t interior = 0;
  size_t interior_exact = 0;
  size_t interior_wrong = 0;
  size_t dark = 0;
  size_t dark_valid = 0;
  double CorrectRate() const { return static_cast<double>(correct) / lit; }
  double ExactRate() const { return static_cast<double>(exact) / lit; }
  double WrongRate() const { return static_cast<double>(wrong) / lit; }
  double InteriorExactRate() const { return static_cast<double>(interior_exact) / interior; }
};

std::ostream& operator<<(std::ostream& os, const Score& s) {
  return os << "lit " << s.lit << ": correct " << s.CorrectRate() << ", exact " << s.ExactRate()
            << ", wrong " << s.WrongRate() << " (" << s.wrong << "); interior " << s.interior
            << ": exact " << s.InteriorExactRate() << ", wrong " << s.interior_wrong << "; dark "
            << s.dark << ": valid " << s.dark_valid;
}

// Ideal decoded value: the centre of the step-wide block holding the lit projector pixel.
double IdealValue(double truth, float step, int projector_size) {
  const double pixel = std::round(truth);
  const double start = std::floor(pixel / step) * step;
  const double end = std::min<double>(start + step, projector_size);
  return 0.5 * (start + end - 1.0);
}

// Distance from `truth` to the nearest boundary between step-wide blocks (at k·step − ½).
double DistanceToBlockEdge(double truth, float step) {
  const double offset = std::fmod(truth + 0.5, step);
  return std::min(offset, step - offset);
}

Score Evaluate(const CorrespondenceMap& map, const SyntheticCapture& capture,
               const cv::Mat& region = cv::Mat()) {
  cv::Mat near_shadow;
  cv::dilate(capture.in_shadow, near_shadow, cv::Mat(), cv::Point(-1, -1), kShadowClearance);
  cv::Mat deep_shadow;
  cv::erode(capture.in_shadow, deep_shadow, cv::Mat(), cv::Point(-1, -1), kShadowClearance);
  const int sizes[2] = {map.projector_width, map.projector_height};
  Score score;
  for (int v = 0; v < map.height(); ++v) {
    for (int u = 0; u < map.width(); ++u) {
      if (!region.empty() && region.at<uint8_t>(v, u) == 0) continue;
      bool inside = true, far_outside = false, interior = true, correct = true, exact = true;
      for (int axis = 0; axis < 2; ++axis) {
        // The projector lights its whole image whichever axes are coded.
        const double truth = (axis == 0 ? capture.true_x : capture.true_y).at<double>(v, u);
        inside = inside && truth >= 1.0 && truth <= sizes[axis] - 2.0;
        far_outside = far_outside || truth < -2.0 || truth > sizes[axis] + 1.0;
        const cv::Mat& decoded = axis == 0 ? map.proj_x : map.proj_y;
        if (decoded.empty()) continue;
        const float step = axis == 0 ? map.step_x : map.step_y;
        interior = interior && DistanceToBlockEdge(truth, step) >= kEdgeClearance;
        const float value = decoded.at<float>(v, u);
        correct = correct && std::abs(value - truth) <= step / 2.0 + 1.0;
        exact = exact && value == IdealValue(truth, step, sizes[axis]);
      }
      const bool valid = map.mask.at<uint8_t>(v, u) != 0;
      if (far_outside || deep_shadow.at<uint8_t>(v, u) != 0) {
        ++score.dark;
        score.dark_valid += valid;
      } else if (inside && near_shadow.at<uint8_t>(v, u) == 0 && u >= kBorderClearance &&
                 v >= kBorderClearance && u < map.width() - kBorderClearance &&
                 v < map.height() - kBorderClearance) {
        ++score.lit;
        score.correct += valid && correct;
        score.exact += valid && exact;
        score.wrong += valid && !correct;
        score.interior += interior;
        score.interior_exact += interior && valid && exact;
        score.interior_wrong += interior && valid && !correct;
      }
    }
  }
  return score;
}

// Every output is consistent with the mask: coordinates NaN exactly where invalid,
// confidence in (0, 1] where valid and 0 elsewhere.
void ExpectConsistentMap(const CorrespondenceMap& map) {
  ASSERT_EQ(map.mask.type(), CV_8UC1);
  ASSERT_EQ(map.confidence.type(), CV_32FC1);
  size_t inconsistent = 0;
  for (int v = 0; v < map.height(); ++v) {
    for (int u = 0; u < map.width(); ++u) {
      const bool valid = map.mask.at<uint8_t>(v, u) == 255;
      const float confidence = map.confidence.at<float>(v, u);
      bool ok = map.mask.at<uint8_t>(v, u) == 0 || valid;
      ok = ok && (valid ? confidence > 0.0f && confidence <= 1.0f : confidence == 0.0f);
      for (const cv::Mat* coordinate : {&map.proj_x, &map.proj_y}) {
        if (!coordinate->empty()) ok = ok && std::isnan(coordinate->at<float>(v, u)) != valid;
      }
      inconsistent += !ok;
    }
  }
  EXPECT_EQ(inconsistent, 0u);
}

// ---------------------------------------------------------------------------------------
// Options, enums, tables, robust rules.
// ---------------------------------------------------------------------------------------
TEST(DecoderOptions, DefaultsAreValidAndBadValuesAreNamed) {
  EXPECT_NO_THROW(DecoderOptions().Check());
  const auto expect_invalid = [](auto mutate, const std::string& name) {
    DecoderOptions options;
    mutate(options);
    try {
      options.Check();
      ADD_FAILURE() << name << " accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  };
  expect_invalid([](DecoderOptions& o) { o.min_contrast = -1; }, "min_contrast");
  expect_invalid([](DecoderOptions& o) { o.min_contrast = std::nan(""); }, "min_contrast");
  expect_invalid([](DecoderOptions& o) { o.min_bit_contrast = 300; }, "min_bit_contrast");
  expect_invalid([](DecoderOptions& o) { o.robust_margin = -0.1; }, "robust_margin");
  expect_invalid([](DecoderOptions& o) { o.robust_black_level = 1.0; }, "robust_black_level");
  expect_invalid([](DecoderOptions& o) { o.num_threads = 0; }, "num_threads");
}

TEST(BitDecision, StringsRoundTrip) {
  for (BitDecision mode : {BitDecision::kAuto, BitDecision::kThreshold, BitDecision::kRobust}) {
    EXPECT_EQ(BitDecisionFromString(ToString(mode)), mode);
  }
  EXPECT_EQ(ToString(BitDecision::kRobust), "robust");
  EXPECT_THROW_WITH_MESSAGE(BitDecisionFromString("Robust"), Error, "'Robust'");
}

TEST(CoordinateLut, GrayAndBinaryDecodeEveryProjectorPixel) {
  for (PatternCode code : {PatternCode::kGray, PatternCode::kBinary}) {
    const int size = 1000;  // 10 bits, codes 1000..1023 lie beyond the projector
    const std::vector<float> lut = internal::MakeCoordinateLut(code, 10, 0, size);
    ASSERT_EQ(lut.size(), 1024u);
    for (uint32_t x = 0; x < 1024; ++x) {
      const uint32_t word = code == PatternCode::kGray ? GrayFromBinary(x) : x;
      if (x < static_cast<uint32_t>(size)) {
        EXPECT_EQ(lut[word], static_cast<float>(x)) << ToString(code) << " " << x;
      } else {
        EXPECT_TRUE(std::isnan(lut[word])) << ToString(code) << " " << x;
      }
    }
  }
}

TEST(CoordinateLut, OmittedLowBitsGiveBlockCentres) {
  // 1001 columns, 10 bits, bits 0..2 omitted: blocks of 8, the last one (1000) partial.
  const std::vector<float> lut = internal::MakeCoordinateLut(PatternCode::kGray, 10, 3, 1001);
  ASSERT_EQ(lut.size(), 128u);
  for (uint32_t block = 0; block < 128; ++block) {
    const float value = lut[GrayFromBinary(block)];
    if (block < 125) {
      EXPECT_EQ(value, block * 8 + 3.5f) << block;
    } else if (block == 125) {
      EXPECT_EQ(value, 1000.0f);  // only column 1000 of the block is on the projector
    } else {
      EXPECT_TRUE(std::isnan(value)) << block;
    }
  }
  // The top bits of a Gray code decode to the top bits of the coordinate.
  for (uint32_t x = 0; x < 1001; ++x) {
    EXPECT_EQ(lut[GrayFromBinary(x) >> 3], (x / 8) * 8 + (x / 8 == 125 ? 0.0f : 3.5f)) << x;
  }
}

TEST(RobustBit, DirectGlobalSeparation) {
  // b = 0: L_d = max − min, L_g = 2 min.
  internal::DirectGlobal split = internal::SeparateDirectGlobal(200.0f, 30.0f, 0.0f);
  EXPECT_FLOAT_EQ(split.direct, 170.0f);
  EXPECT_FLOAT_EQ(split.global, 60.0f);
  // b = 0.1: a pixel with L_d = 100, L_g = 40 shows max = L_d + L_g/2 + b·L_g/2 and
  // min = b·L_d + L_g/2·(1 + b)... (Moreno & Taubin eq. 7): recover both.
  const float b = 0.1f, direct = 100.0f, global = 40.0f;
  const float max_level = direct + 0.5f * global + b * 0.5f * global;
  const float min_level = b * direct + 0.5f * global + b * 0.5f * global;
  split = internal::SeparateDirectGlobal(max_level, min_level, b);
  EXPECT_NEAR(split.direct, direct, 1e-3);
  EXPECT_NEAR(split.global, global, 1e-3);
}

TEST(RobustBit, MorenoTaubinRules) {
  const float min_direct = 5.0f, margin = 0.1f;
  // Returns 0, 1, or −1 for unknown.
  const auto classify = [&](float pattern, float inverse, float direct, float global) {
    const internal::RobustBounds<float> bounds =
        internal::RobustBoundsOf({direct, global}, min_direct, margin);
    const uint8_t outcome = internal::ClassifyRobustBit(pattern, inverse, bounds);
    return (outcome & internal::kRobustUnknown) ? -1 : (outcome & internal::kRobustValue);
  };
  // Too little direct light: unknown whatever p, p̄ say.
  EXPECT_EQ(classify(200, 10, 4, 0), -1);
  // Direct dominates (L_d = 120 > L_g + e = 55): the pair decides, a tie does not.
  EXPECT_EQ(classify(150, 40, 120, 50), 1);
  EXPECT_EQ(classify(40, 150, 120, 50), 0);
  EXPECT_EQ(classify(90, 90, 120, 50), -1);
  // Global dominates (L_d = 60, L_g + e = 110): an unlit pixel lifted above its inverse
  // by interreflection is not believed (p = 95 > p̄ = 60 but p is not > L_g + e) …
  EXPECT_EQ(classify(95, 60, 60, 100), -1);
  // … but a clearly lit one (p > L_g + e, p̄ < L_d − e) is 1, and the mirror case 0.
  EXPECT_EQ(classify(160, 20, 60, 100), 1);
  EXPECT_EQ(classify(20, 160, 60, 100), 0);
  // Integer bounds (⌈L_d − e⌉, ⌊L_g + e⌋) classify integer levels exactly as the float ones.
  for (int pattern = 0; pattern <= 255; pattern += 3) {
    for (int inverse = 0; inverse <= 255; inverse += 5) {
      for (const auto& [direct, global] : {std::pair{60.3f, 100.7f}, std::pair{120.5f, 40.2f}}) {
        const internal::RobustBounds<float> bounds =
            internal::RobustBoundsOf({direct, global}, min_direct, margin);
        const uint8_t expected = internal::ClassifyRobustBit<float>(
            static_cast<float>(pattern), static_cast<float>(inverse), bounds);
        const uint8_t actual = internal::ClassifyRobustBit<int>(
            pattern, inverse, static_cast<int>(std::ceil(bounds.direct_minus_slack)),
            static_cast<int>(std::floor(bounds.global_plus_slack)), bounds.direct_dominates,
            bounds.too_dark);
        const bool unknown = expected & internal::kRobustUnknown;
        EXPECT_EQ(actual & internal::kRobustUnknown, expected & internal::kRobustUnknown);
        if (!unknown) {
          EXPECT_EQ(actual, expected) << pattern << " " << inverse;
        }
      }
    }
  }
}

// ---------------------------------------------------------------------------------------
// Synthetic captures.
// ---------------------------------------------------------------------------------------
// Measured on this scene (400×300 camera, 0.7 projector pixels per camera pixel, blur
// σ 0.7 px, noise σ 1.5): Gray codes decode 93.5 % (inverse) / 86 % (threshold) of the lit
// pixels, all exactly; the rest lie within ~0.05 projector pixels of a stripe edge where
// |pattern − inverse| < min_bit_contrast. Binary codes lose more (finer stripes, several
// bits flipping at once) and err, rarely, right at transitions. Limits leave ~3 % slack.
struct DecodeCase {
  std::string name;
  PatternAxes axes = PatternAxes::kXY;
  PatternCode code = PatternCode::kGray;
  bool inverted = true;
  bool sixteen_bit = false;
  BitDecision decision = BitDecision::kAuto;
  double min_correct = 0.90;           // of the lit pixels
  double min_interior_exact = 0.9999;  // of the pixels ≥ kEdgeClearance from stripe edges
  double max_wrong = 1e-5;             // of the lit pixels: valid but wrong
};

DecodeCase Case(std::string name, PatternAxes axes, PatternCode code, bool inverted,
                bool sixteen_bit = false, BitDecision decision = BitDecision::kAuto) {
  DecodeCase c{std::move(name), axes, code, inverted, sixteen_bit, decision};
  const bool threshold = !inverted || decision == BitDecision::kThreshold;
  if (code == PatternCode::kBinary) {
    c.min_correct = threshold ? 0.52 : 0.72;
    c.min_interior_exact = threshold ? 0.86 : 0.96;
    c.max_wrong = 5e-4;
  } else if (threshold) {
    c.min_correct = 0.82;
  }
  return c;
}

class SyntheticCodes : public ::testing::TestWithParam<DecodeCase> {};

TEST_P(SyntheticCodes, DecodesLitPixelsExactlyAndDarkPixelsNever) {
  const DecodeCase& c = GetParam();
  SceneOptions scene;
  scene.patterns.projector_width = 300;  // 9 bits, not a power of two
  scene.patterns.projector_height = 200;
  scene.patterns.axes = c.axes;
  scene.patterns.code = c.code;
  scene.patterns.inverted = c.inverted;
  scene.sixteen_bit = c.sixteen_bit;
  const SyntheticCapture capture = RenderScene(scene);
  DecoderOptions options;
  options.bit_decision = c.decision;
  const CorrespondenceMap map = Decode(capture.frame_set, options);

  EXPECT_EQ(map.HasX(), c.axes != PatternAxes::kY);
  EXPECT_EQ(map.HasY(), c.axes != PatternAxes::kX);
  EXPECT_EQ(map.projector_width, 300);
  EXPECT_EQ(map.projector_height, 200);
  EXPECT_EQ(map.step_x, 1.0f);
  EXPECT_EQ(map.step_y, 1.0f);
  ExpectConsistentMap(map);
  const Score score = Evaluate(map, capture);
  SCOPED_TRACE(::testing::Message() << score);
  ASSERT_GT(score.lit, 100000u);
  EXPECT_GE(score.CorrectRate(), c.min_correct);
  EXPECT_GE(score.InteriorExactRate(), c.min_interior_exact);
  EXPECT_EQ(score.interior_wrong, 0u);
  EXPECT_LE(score.WrongRate(), c.max_wrong);
  EXPECT_GT(score.dark, 5000u);
  EXPECT_EQ(score.dark_valid, 0u);  // shadow and off-projector pixels never decode
}

INSTANTIATE_TEST_SUITE_P(
    Codes, SyntheticCodes,
    ::testing::Values(
        Case("gray_xy_inverse_8bit", PatternAxes::kXY, PatternCode::kGray, true),
        Case("gray_xy_threshold_8bit", PatternAxes::kXY, PatternCode::kGray, false),
        Case("binary_xy_inverse_8bit", PatternAxes::kXY, PatternCode::kBinary, true),
        Case("binary_xy_threshold_8bit", PatternAxes::kXY, PatternCode::kBinary, false),
        Case("gray_x_inverse_8bit", PatternAxes::kX, PatternCode::kGray, true),
        Case("gray_y_threshold_8bit", PatternAxes::kY, PatternCode::kGray, false),
        Case("gray_xy_inverse_16bit", PatternAxes::kXY, PatternCode::kGray, true, true),
        Case("gray_xy_threshold_16bit", PatternAxes::kXY, PatternCode::kGray, false, true),
        Case("gray_xy_forced_threshold_8bit", PatternAxes::kXY, PatternCode::kGray, true, false,
             BitDecision::kThreshold),
        Case("gray_xy_robust_8bit", PatternAxes::kXY, PatternCode::kGray, true, false,
             BitDecision::kRobust),
        Case("gray_xy_robust_16bit", PatternAxes::kXY, PatternCode::kGray, true, true,
             BitDecision::kRobust)),
    [](const ::testing::TestParamInfo<DecodeCase>& info) { return info.param.name; });

TEST(SyntheticDecode, OmittedLowBitsDecodeToBlockCentres) {
  for (bool inverted : {true, false}) {
    SCOPED_TRACE(inverted ? "with inverses" : "against the threshold");
    SceneOptions scene;
    scene.patterns.projector_width = 300;
    scene.patterns.projector_height = 200;
    scene.patterns.inverted = inverted;
    scene.patterns.skip_low_bits = 2;
    const SyntheticCapture capture = RenderScene(scene);
    const CorrespondenceMap map = Decode(capture.frame_set);
    EXPECT_EQ(map.step_x, 4.0f);
    EXPECT_EQ(map.step_y, 4.0f);
    ExpectConsistentMap(map);
    const Score score = Evaluate(map, capture);
    SCOPED_TRACE(::testing::Message() << score);
    EXPECT_GE(score.CorrectRate(), 0.95);  // blocks of 4 have 4× fewer edges
    EXPECT_GE(score.InteriorExactRate(), 0.9999);
    EXPECT_EQ(score.wrong, 0u);
    // Every value is a block centre 4k + 1.5 (300 and 200 are multiples of 4), or a
    // boundary 4k + 3.5 between two blocks where the pixel straddles them.
    size_t off_grid = 0;
    for (const cv::Mat* coordinate : {&map.proj_x, &map.proj_y}) {
      for (int v = 0; v < coordinate->rows; ++v) {
        for (int u = 0; u < coordinate->cols; ++u) {
          const float value = coordinate->at<float>(v, u);
          if (!std::isnan(value)) off_grid += std::fmod(value - 1.5f, 2.0f) != 0.0f;
        }
      }
    }
    EXPECT_EQ(off_grid, 0u);
  }
}

TEST(SyntheticDecode, LowContrastBitsAreInvalidNotGuessed) {
  SceneOptions scene;
  scene.patterns.projector_width = 300;
  scene.patterns.projector_height = 200;
  scene.noise_sigma = 0.0;
  SyntheticCapture capture = RenderScene(scene);
  const FrameSetManifest& manifest = capture.frame_set.manifest;
  // In `flat`, bit 4 of x shows the same level in the pattern and its inverse except for a
  // ±1 grey-level wobble (below min_bit_contrast = 3): undecidable.
  const cv::Rect flat(250, 40, 80, 60);
  const size_t pattern = *manifest.FindCode(PatternAxis::kX, 4, false);
  const size_t inverse = *manifest.FindCode(PatternAxis::kX, 4, true);
  cv::Mat& p = capture.frame_set.images[pattern];
  cv::Mat& q = capture.frame_set.images[inverse];
  for (int v = flat.y; v < flat.br().y; ++v) {
    for (int u = flat.x; u < flat.br().x; ++u) {
      const int mid = (p.at<uint8_t>(v, u) + q.at<uint8_t>(v, u)) / 2;
      p.at<uint8_t>(v, u) = static_cast<uint8_t>(mid + ((u + v) % 2));
      q.at<uint8_t>(v, u) = static_cast<uint8_t>(mid);
    }
  }
  // In `dim`, white − black is below min_contrast = 10: treated as shadow.
  const cv::Rect dim(150, 60, 50, 50);
  const cv::Mat black = capture.frame_set.images[*manifest.Find(FrameRole::kBlack)];
  for (cv::Mat& image : capture.frame_set.images) {
    cv::Mat region = image(dim);
    cv::Mat dimmed = black(dim) + (region - black(dim)) * (8.0 / 255.0);
    dimmed.copyTo(region);
  }
  const CorrespondenceMap map = Decode(capture.frame_set);
  // In `flat` a pixel may only decode where the undecidable bit is the one that changes
  // between its two neighbouring columns (it sits on that bit's stripe boundary): then its
  // coordinate is the boundary, within a pixel of the truth. Nowhere else is it guessed.
  size_t flat_valid = 0, flat_off = 0;
  for (int v = flat.y; v < flat.br().y; ++v) {
    for (int u = flat.x; u < flat.br().x; ++u) {
      if (map.mask.at<uint8_t>(v, u) == 0) continue;
      ++flat_valid;
      flat_off += std::abs(map.proj_x.at<float>(v, u) - capture.true_x.at<double>(v, u)) > 1.0;
    }
  }
  EXPECT_EQ(flat_off, 0u);
  EXPECT_LT(flat_valid, static_cast<size_t>(flat.area() / 10));
  EXPECT_EQ(cv::countNonZero(map.mask(dim)), 0);
  cv::Mat region(map.mask.size(), CV_8UC1, cv::Scalar(255));
  region(flat).setTo(0);
  region(dim).setTo(0);
  const Score score = Evaluate(map, capture, region);
  SCOPED_TRACE(::testing::Message() << score);
  EXPECT_GE(score.CorrectRate(), 0.90);  // the rest of the image is unaffected
  EXPECT_GE(score.InteriorExactRate(), 0.9999);
  EXPECT_EQ(score.wrong, 0u);
  // With min_bit_contrast = 0 the flat bit is guessed (pattern > inverse on odd pixels),
  // so the same pixels decode, and about half of them wrongly: the check is what keeps
  // them out.
  DecoderOptions guessing;
  guessing.min_bit_contrast = 0.0;
  const CorrespondenceMap guessed = Decode(capture.frame_set, guessing);
  EXPECT_GT(cv::countNonZero(guessed.mask(flat)), flat.area() * 9 / 10);
}

// A camera row whose pixel i sees projector columns i and i + 1 half and half: exactly the
// bit that changes between them is undecidable (pattern = inverse), every other bit is
// clear. Gray codes decode each such pixel to the boundary i + ½; binary codes, which flip
// several bits at some boundaries, leave all straddling pixels invalid rather than guess.
TEST(SyntheticDecode, StraddlingPixelsResolveToTheGrayBoundary) {
  constexpr int kColumns = 64;
  for (PatternCode code : {PatternCode::kGray, PatternCode::kBinary}) {
    PatternOptions patterns;
    patterns.projector_width = kColumns;
    patterns.projector_height = 1;
    patterns.axes = PatternAxes::kX;
    patterns.code = code;
    FrameSet set;
    set.manifest = MakePatternManifest(patterns, kColumns - 1, 1);
    for (const Pattern& pattern : GeneratePatterns(patterns)) {
      cv::Mat row(1, kColumns - 1, CV_8UC1);
      for (int i = 0; i < kColumns - 1; ++i) {
        // 20 + 200 · (mean of the two columns' light): levels 20, 120 or 220.
        const int lit = pattern.image.at<uint8_t>(0, i) / 255 + pattern.image.at<uint8_t>(0, i + 1) / 255;
        row.at<uint8_t>(0, i) = static_cast<uint8_t>(20 + 100 * lit);
      }
      set.images.push_back(row);
    }
    DecoderOptions options;
    options.min_consistent_neighbours = 0;  // a single row: the per-pixel rule alone
    const CorrespondenceMap map = Decode(set, options);
    for (int i = 0; i < kColumns - 1; ++i) {
      const bool valid = map.mask.at<uint8_t>(0, i) != 0;
      if (code == PatternCode::kGray) {
        ASSERT_TRUE(valid) << "pixel " << i;
        EXPECT_EQ(map.proj_x.at<float>(0, i), i + 0.5f) << "pixel " << i;
        EXPECT_GT(map.confidence.at<float>(0, i), 0.0f);
        EXPECT_LE(map.confidence.at<float>(0, i), 0.5f);  // halved at a boundary
      } else {
        EXPECT_FALSE(valid) << "binary pixel " << i << " decoded to "
                            << map.proj_x.at<float>(0, i);
      }
    }
  }
}

// The speckle filter removes isolated decodes (noise that passes every threshold) and
// keeps surfaces, which decode in patches.
TEST(SyntheticDecode, SpeckleFilterRemovesIsolatedDecodesOnly) {
  SceneOptions scene;
  scene.patterns.projector_width = 300;
  scene.patterns.projector_height = 200;
  SyntheticCapture capture = RenderScene(scene);
  // Copy one lit pixel's values into a single pixel of the dark (deep shadow) region: it
  // decodes there, alone among undecodable neighbours.
  cv::Point lit(-1, -1), dark(-1, -1);
  for (int v = 2; v < capture.in_shadow.rows - 2 && (lit.x < 0 || dark.x < 0); ++v) {
    for (int u = 2; u < capture.in_shadow.cols - 2; ++u) {
      const cv::Rect around(u - 2, v - 2, 5, 5);
      if (dark.x < 0 && cv::countNonZero(capture.in_shadow(around)) == 25) dark = {u, v};
      if (lit.x < 0 && cv::countNonZero(capture.in_shadow(around)) == 0 && u > 100) lit = {u, v};
    }
  }
  ASSERT_GE(lit.x, 0);
  ASSERT_GE(dark.x, 0);
  for (cv::Mat& image : capture.frame_set.images) image.at<uint8_t>(dark) = image.at<uint8_t>(lit);
  DecoderOptions unfiltered;
  unfiltered.min_consistent_neighbours = 0;
  const CorrespondenceMap raw = Decode(capture.frame_set, unfiltered);
  const CorrespondenceMap filtered = Decode(capture.frame_set);
  EXPECT_NE(raw.mask.at<uint8_t>(dark), 0);       // the planted pixel decodes …
  EXPECT_EQ(filtered.mask.at<uint8_t>(dark), 0);  // … and the filter removes it
  EXPECT_NE(filtered.mask.at<uint8_t>(lit), 0);
  // On the lit surface the filter removes (almost) nothing.
  const Score before = Evaluate(raw, capture), after = Evaluate(filtered, capture);
  EXPECT_GE(after.CorrectRate(), before.CorrectRate() - 0.002);
  ExpectConsistentMap(filtered);
}

// Restores the SIMD kernels when a test that switched them off ends.
struct PortableKernels {
  ~PortableKernels() { internal::SetPortableKernelsForTesting(false); }
};

// A random map of `size` with invalid pixels (NaN) and coordinates near the tolerance.
CorrespondenceMap RandomMap(cv::Size size, bool two_axes, std::mt19937* random) {
  std::uniform_real_distribution<float> jitter(-1.6f, 1.6f);
  std::bernoulli_distribution invalid(0.2);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  CorrespondenceMap map;
  map.projector_width = 100;
  map.projector_height = 100;
  map.mask = cv::Mat(size, CV_8UC1);
  map.confidence = cv::Mat(size, CV_32FC1, cv::Scalar(0.5));
  map.proj_x = cv::Mat(size, CV_32FC1);
  if (two_axes) map.proj_y = cv::Mat(size, CV_32FC1);
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const bool bad = invalid(*random);
      map.mask.at<uint8_t>(y, x) = bad ? 0 : 255;
      map.proj_x.at<float>(y, x) = bad ? nan : 10.0f + 0.5f * x + jitter(*random);
      if (two_axes) map.proj_y.at<float>(y, x) = bad ? nan : 20.0f + jitter(*random);
    }
  }
  return map;
}

CorrespondenceMap DeepCopy(const CorrespondenceMap& map) {
  CorrespondenceMap copy = map;
  copy.mask = map.mask.clone();
  copy.confidence = map.confidence.clone();
  copy.proj_x = map.proj_x.clone();
  copy.proj_y = map.proj_y.clone();
  return copy;
}

void ExpectSameMaps(const CorrespondenceMap& a, const CorrespondenceMap& b);

// The banded filter (each decoding worker filters its own rows as it goes, the rows
// between the workers' ranges at the end) gives RemoveSpeckles' map: ranges that start and
// end mid-row, on row boundaries, shorter than a row, and one worker with every pixel;
// rows announced a few pixels at a time, as chunks are decoded.
TEST(SpeckleFilter, BandsGiveTheWholeImageFilter) {
  std::mt19937 random(11);
  for (const cv::Size size : {cv::Size(37, 23), cv::Size(150, 9), cv::Size(5, 40)}) {
    const CorrespondenceMap original = RandomMap(size, true, &random);
    CorrespondenceMap expected = DeepCopy(original);
    internal::RemoveSpeckles(2, 1.0f, &expected);
    const size_t total = static_cast<size_t>(size.area());
    const size_t cols = static_cast<size_t>(size.width);
    std::vector<std::vector<size_t>> splits = {
        {0, total}, {0, total / 2, total}, {0, cols, 3 * cols, total},
        {0, cols + 3, cols + 5, 4 * cols - 1, total}, {0, 1, 2 * cols, 2 * cols + 2, total}};
    std::vector<size_t> random_cuts = {0, total};
    std::uniform_int_distribution<size_t> cut(1, total - 1);
    for (int i = 0; i < 5; ++i) random_cuts.push_back(cut(random));
    std::sort(random_cuts.begin(), random_cuts.end());
    random_cuts.erase(std::unique(random_cuts.begin(), random_cuts.end()), random_cuts.end());
    splits.push_back(random_cuts);
    for (const std::vector<size_t>& split : splits) {
      CorrespondenceMap map = DeepCopy(original);
      std::vector<std::pair<size_t, size_t>> ranges;
      for (size_t w = 0; w + 1 < split.size(); ++w) ranges.emplace_back(split[w], split[w + 1]);
      internal::BandedSpeckleFilter filter(2, 1.0f, &map, ranges);
      // Workers in reverse order (any order must do), each in steps of 7 pixels.
      for (size_t w = ranges.size(); w-- > 0;) {
        for (size_t end = ranges[w].first; end < ranges[w].second;) {
          end = std::min(end + 7, ranges[w].second);
          filter.PixelsDecoded(w, end);
        }
      }
      filter.Finish();
      SCOPED_TRACE(::testing::Message() << size << " split into " << ranges.size());
      ExpectSameMaps(map, expected);
    }
  }
}

// The speckle filter against the rule written out per pixel: a valid pixel stays when at
// least min_neighbours of its 8 neighbours (inside the image) are within the tolerance on
// every coded axis, judged on the unfiltered map. Random maps with invalid pixels (NaN),
// coordinates near the tolerance, one and two coded axes, and thin images (borders only).
TEST(SpeckleFilter, MatchesTheRuleOnRandomMaps) {
  std::mt19937 random(7);
  constexpr float kTolerance = 1.0f;
  const PortableKernels restore;
  for (const cv::Size size : {cv::Size(1, 1), cv::Size(1, 9), cv::Size(9, 1), cv::Size(2, 2),
                              cv::Size(13, 7), cv::Size(64, 5), cv::Size(147, 4)}) {
    for (const auto& [two_axes, portable] : {std::pair{false, false}, std::pair{true, false},
                                            std::pair{false, true}, std::pair{true, true}}) {
      internal::SetPortableKernelsForTesting(portable);
      for (int min_neighbours = 1; min_neighbours <= 8; ++min_neighbours) {
        CorrespondenceMap map = RandomMap(size, two_axes, &random);
        const CorrespondenceMap before = DeepCopy(map);  // the filter writes in place
        internal::RemoveSpeckles(min_neighbours, kTolerance, &map);
        for (int y = 0; y < size.height; ++y) {
          for (int x = 0; x < size.width; ++x) {
            const auto agrees = [&](int nx, int ny) {
              const auto near = [&](const cv::Mat& image) {
                if (image.empty()) return true;
                const float d = image.at<float>(ny, nx) - image.at<float>(y, x);
                return d <= kTolerance && d >= -kTolerance;
              };
              return near(before.proj_x) && near(before.proj_y);
            };
            int count = 0;
            for (int dy = -1; dy <= 1; ++dy) {
              for (int dx = -1; dx <= 1; ++dx) {
                const int nx = x + dx, ny = y + dy;
                if ((dx != 0 || dy != 0) && nx >= 0 && ny >= 0 && nx < size.width &&
                    ny < size.height) {
                  count += agrees(nx, ny);
                }
              }
            }
            const bool valid = before.mask.at<uint8_t>(y, x) != 0;
            const bool kept = valid && count >= min_neighbours;
            SCOPED_TRACE(::testing::Message() << size << " two axes " << two_axes << " min "
                                            << min_neighbours << " portable " << portable
                                            << " at " << x << "," << y);
            ASSERT_EQ(map.mask.at<uint8_t>(y, x) != 0, kept);
            if (valid && !kept) {
              EXPECT_TRUE(std::isnan(map.proj_x.at<float>(y, x)));
              EXPECT_EQ(map.confidence.at<float>(y, x), 0.0f);
            } else if (valid) {
              EXPECT_EQ(map.proj_x.at<float>(y, x), before.proj_x.at<float>(y, x));
            }
          }
        }
      }
    }
  }
}

TEST(SyntheticDecode, CodesBeyondTheProjectorAreInvalid) {
  // The patterns of a 512-column projector, declared as a 300-column one: camera pixels
  // that see columns ≥ 300 decode to codes beyond the projector.
  SceneOptions scene;
  scene.patterns.projector_width = 300;
  scene.patterns.projector_height = 200;
  scene.patterns.axes = PatternAxes::kX;
  scene.pattern_width = 512;
  scene.proj_from_cam = {1.0, 0.0, 0.0, 0.0, 0.6, 0.0};  // columns 0..399
  scene.shadow = cv::Rect(0, 0, 1, 1);
  const SyntheticCapture capture = RenderScene(scene);
  const CorrespondenceMap map = Decode(capture.frame_set);
  EXPECT_EQ(cv::countNonZero(map.mask.colRange(301, 400)), 0);
  EXPECT_GT(cv::countNonZero(map.mask.colRange(1, 299)), 298 * 300 * 99 / 100);
  double max_x = 0.0;
  cv::minMaxIdx(map.proj_x, nullptr, &max_x, nullptr, nullptr, map.mask);
  EXPECT_EQ(max_x, 299.0);
}

TEST(SyntheticDecode, RobustModeNeverTrustsInterreflections) {
  SceneOptions scene;
  scene.patterns.projector_width = 300;
  scene.patterns.projector_height = 200;
  scene.global_strength = 1.8;
  scene.gain = 80.0;  // lit + reflected light stays below saturation (linear model)
  const SyntheticCapture capture = RenderScene(scene);
  // Where the interreflection is strong: |u − centre| < 1.2 σ of the band (strength
  // > 1.8 · e^(−1.44) ≈ 0.43 of the direct light).
  cv::Mat band = cv::Mat::zeros(capture.in_shadow.size(), CV_8UC1);
  const int half_width = static_cast<int>(1.2 * kGlobalBandFraction * scene.camera_width);
  band.colRange(scene.camera_width / 2 - half_width, scene.camera_width / 2 + half_width)
      .setTo(255);
  cv::Mat outside_band = 255 - band;
  DecoderOptions options;
  const CorrespondenceMap inverse_map = Decode(capture.frame_set, options);
  const Score inverse = Evaluate(inverse_map, capture, band);
  const Score inverse_outside = Evaluate(inverse_map, capture, outside_band);
  options.bit_decision = BitDecision::kThreshold;
  const Score threshold = Evaluate(Decode(capture.frame_set, options), capture, band);
  options.bit_decision = BitDecision::kRobust;
  const CorrespondenceMap robust_map = Decode(capture.frame_set, options);
  ExpectConsistentMap(robust_map);
  const Score robust = Evaluate(robust_map, capture, band);
  const Score robust_outside = Evaluate(robust_map, capture, outside_band);
  std::cout << "interreflection band: inverse " << inverse << "\n  threshold " << threshold
            << "\n  robust " << robust << "\noutside the band: inverse " << inverse_outside
            << "\n  robust " << robust_outside << "\n";
  // The case is hard: plain decisions decode many band pixels to wrong coordinates.
  EXPECT_GE(inverse.WrongRate(), 0.10);
  EXPECT_GE(threshold.WrongRate(), 0.05);
  // Robust decisions leave them invalid instead: (almost) never wrong …
  EXPECT_LE(robust.WrongRate(), 0.001);
  EXPECT_LE(robust_outside.WrongRate(), 0.001);
  // … and away from the interreflection decode about as much as plain decisions.
  EXPECT_GE(robust_outside.CorrectRate(), inverse_outside.CorrectRate() - 0.05);
}

// Room light (the black frame's level, here 70 of the lit pixels' ~170 grey levels) is in
// every frame alike and is not the projector's global light: robust decisions take it out
// before splitting direct from global light, and decode about as much as plain decisions,
// never wrongly. (Counted as global light, it made every bit undecidable: nothing decoded.)
TEST(SyntheticDecode, RobustModeDecodesUnderRoomLight) {
  SceneOptions scene;
  scene.patterns.projector_width = 300;
  scene.patterns.projector_height = 200;
  scene.ambient = 70.0;
  scene.gain = 100.0;  // ambient + lit stays below saturation
  const SyntheticCapture capture = RenderScene(scene);
  const cv::Mat everywhere(capture.in_shadow.size(), CV_8UC1, cv::Scalar(255));
  DecoderOptions options;
  const Score plain = Evaluate(Decode(capture.frame_set, options), capture, everywhere);
  options.bit_decision = BitDecision::kRobust;
  const CorrespondenceMap robust_map = Decode(capture.frame_set, options);
  ExpectConsistentMap(robust_map);
  const Score robust = Evaluate(robust_map, capture, everywhere);
  std::cout << "room light: plain " << plain << "\n  robust " << robust << "\n";
  EXPECT_GE(plain.CorrectRate(), 0.6);
  EXPECT_GE(robust.CorrectRate(), plain.CorrectRate() - 0.05);
  EXPECT_LE(robust.WrongRate(), 0.001);
}

TEST(SyntheticDecode, ThreadsGiveIdenticalResults) {
  SceneOptions scene;
  scene.camera_width = 517;  // not a multiple of the chunk size
  scene.camera_height = 301;
  scene.patterns.projector_width = 300;
  scene.patterns.projector_height = 200;
  const SyntheticCapture capture = RenderScene(scene);
  for (BitDecision mode : {BitDecision::kAuto, BitDecision::kThreshold, BitDecision::kRobust}) {
    DecoderOptions options;
    options.bit_decision = mode;
    const CorrespondenceMap single = Decode(capture.frame_set, options);
    for (int threads : {2, 3, 7}) {
      options.num_threads = threads;
      const CorrespondenceMap multi = Decode(capture.frame_set, options);
      SCOPED_TRACE(ToString(mode) + " threads " + std::to_string(threads));
      for (const auto& [a, b] :
           {std::pair{&single.proj_x, &multi.proj_x}, std::pair{&single.proj_y, &multi.proj_y},
            std::pair{&single.mask, &multi.mask},
            std::pair{&single.confidence, &multi.confidence}}) {
        ASSERT_EQ(a->size(), b->size());
        EXPECT_EQ(std::memcmp(a->data, b->data, a->total() * a->elemSize()), 0);
      }
    }
  }
}

void ExpectSameMaps(const CorrespondenceMap& a, const CorrespondenceMap& b) {
  EXPECT_EQ(a.projector_width, b.projector_width);
  EXPECT_EQ(a.projector_height, b.projector_height);
  EXPECT_EQ(a.step_x, b.step_x);
  EXPECT_EQ(a.step_y, b.step_y);
  for (const auto& [x, y] : {std::pair{&a.proj_x, &b.proj_x}, std::pair{&a.proj_y, &b.proj_y},
                             std::pair{&a.mask, &b.mask},
                             std::pair{&a.confidence, &b.confidence}}) {
    ASSERT_EQ(x->size(), y->size());
    ASSERT_EQ(x->type(), y->type());
    if (x->empty()) continue;
    EXPECT_EQ(std::memcmp(x->data, y->data, x->total() * x->elemSize()), 0);
  }
}

// The SIMD kernels (AVX-512 builds: the coordinate pass, the speckle filter's pair tests
// and counts) give the portable loops' maps bit for bit: noisy, blurred scenes whose
// stripe edges leave weak bits (boundary pixels), with a relative bit threshold, with
// threads, and camera widths that leave tails for the portable loops.
TEST(SyntheticDecode, SimdKernelsGiveThePortableLoopsMaps) {
  const PortableKernels restore;
  for (const int width : {400, 517}) {
    SceneOptions scene;
    scene.camera_width = width;
    scene.camera_height = 301;
    scene.patterns.projector_width = 300;
    scene.patterns.projector_height = 200;
    scene.blur_sigma_px = 1.2;
    scene.noise_sigma = 3.0;
    SyntheticCapture capture = RenderScene(scene);
    // Speckles: a lit pixel's values planted at isolated pixels of the shadow.
    for (cv::Mat& image : capture.frame_set.images) {
      for (int k = 0; k < 8; ++k) {
        image.at<uint8_t>(205 + 5 * k, 45 + 6 * k) = image.at<uint8_t>(100, 200 + k);
      }
    }
    for (const auto& [relative, threads] : {std::pair{0.0, 1}, std::pair{0.2, 1}, std::pair{0.0, 2}}) {
      DecoderOptions options;
      options.min_relative_bit_contrast = relative;
      options.num_threads = threads;
      internal::SetPortableKernelsForTesting(true);
      const CorrespondenceMap portable = Decode(capture.frame_set, options);
      internal::SetPortableKernelsForTesting(false);
      const CorrespondenceMap simd = Decode(capture.frame_set, options);
      SCOPED_TRACE(::testing::Message() << "width " << width << " relative " << relative
                                        << " threads " << threads);
      ExpectSameMaps(simd, portable);
      // The scene exercises every branch: decoded pixels, boundary pixels (confidence
      // halved, ≤ 0.5, at a half-integer coordinate) and speckles.
      EXPECT_GT(cv::countNonZero(portable.mask), scene.camera_width * scene.camera_height / 2);
      int boundary = 0;
      for (int y = 0; y < portable.mask.rows; ++y) {
        for (int x = 0; x < portable.mask.cols; ++x) {
          const float u = portable.proj_x.at<float>(y, x);
          boundary += portable.mask.at<uint8_t>(y, x) != 0 && u != std::floor(u);
        }
      }
      EXPECT_GT(boundary, 100);
      options.min_consistent_neighbours = 0;
      EXPECT_GT(cv::countNonZero(Decode(capture.frame_set, options).mask),
                cv::countNonZero(simd.mask));
    }
  }
}

// Frames fed one at a time (in order, reversed, shuffled) give the batch decode's map,
// byte for byte, for the per-frame path (inverses, with and without white/black, with a
// relative bit threshold, x only) and for the sets it hands to the batch decoder.
TEST(IncrementalDecode, GivesTheBatchMapInAnyArrivalOrder) {
  struct Variant {
    std::string name;
    bool white_black;
    PatternAxes axes;
    BitDecision mode;
    double relative;
    bool sixteen_bit;
    bool scan_defaults = false;  // sub-pixel edges and code consistency
    int threads = 1;
    // 300 × 200: 9 and 8 bits. 1500 × 1000: 11 and 10 bits, so the batch decoder's bit
    // passes take them in groups of 4, 2 and 1 (AccumulateInverseBitGroups), the
    // incremental one bit at a time.
    bool wide_projector = false;
  };
  const std::vector<Variant> variants = {
      {"inverses", true, PatternAxes::kXY, BitDecision::kAuto, 0.0, false},
      {"relative threshold", true, PatternAxes::kXY, BitDecision::kAuto, 0.2, false},
      {"no white/black", false, PatternAxes::kXY, BitDecision::kAuto, 0.0, false},
      {"x only", true, PatternAxes::kX, BitDecision::kAuto, 0.0, false},
      {"threshold (batch)", true, PatternAxes::kXY, BitDecision::kThreshold, 0.0, false},
      {"robust (batch)", true, PatternAxes::kXY, BitDecision::kRobust, 0.0, false},
      {"16-bit (batch)", true, PatternAxes::kXY, BitDecision::kAuto, 0.0, true},
      {"scan defaults", true, PatternAxes::kXY, BitDecision::kAuto, 0.0, false, true},
      {"scan defaults, no white/black", false, PatternAxes::kXY, BitDecision::kAuto, 0.0, false,
       true},
      {"scan defaults, x only", true, PatternAxes::kX, BitDecision::kAuto, 0.0, false, true},
      {"scan defaults, 16-bit (batch)", true, PatternAxes::kXY, BitDecision::kAuto, 0.0, true,
       true},
      {"2 threads", true, PatternAxes::kXY, BitDecision::kAuto, 0.0, false, false, 2},
      {"scan defaults, 2 threads", true, PatternAxes::kXY, BitDecision::kAuto, 0.0, false, true,
       2},
      {"11 and 10 bits", true, PatternAxes::kXY, BitDecision::kAuto, 0.0, false, false, 1, true},
      {"11 and 10 bits, relative threshold", true, PatternAxes::kXY, BitDecision::kAuto, 0.2,
       false, false, 1, true},
      {"11 and 10 bits, no white/black", false, PatternAxes::kXY, BitDecision::kAuto, 0.0, false,
       false, 1, true},
  };
  for (const Variant& variant : variants) {
    SCOPED_TRACE(variant.name);
    SceneOptions scene;
    scene.camera_width = 517;  // not a multiple of the chunk size
    scene.camera_height = 301;
    scene.patterns.projector_width = variant.wide_projector ? 1500 : 300;
    scene.patterns.projector_height = variant.wide_projector ? 1000 : 200;
    scene.patterns.white_black = variant.white_black;
    scene.patterns.axes = variant.axes;
    scene.sixteen_bit = variant.sixteen_bit;
    const SyntheticCapture capture = RenderScene(scene);
    DecoderOptions options;
    options.bit_decision = variant.mode;
    options.min_relative_bit_contrast = variant.relative;
    if (variant.scan_defaults) {
      options.gray_subpixel = GraySubpixel::kEdges;
      options.consistency.enabled = true;
    }
    options.num_threads = variant.threads;
    const CorrespondenceMap batch = Decode(capture.frame_set, options);
    ASSERT_GT(batch.CountValid(), 10000u);
    const size_t count = capture.frame_set.images.size();
    std::vector<size_t> order(count);
    std::iota(order.begin(), order.end(), 0);
    IncrementalDecoder decoder(capture.frame_set.manifest, options);
    for (int arrangement = 0; arrangement < 3; ++arrangement) {
      if (arrangement == 1) std::reverse(order.begin(), order.end());
      if (arrangement == 2) std::shuffle(order.begin(), order.end(), std::mt19937(3));
      decoder.Reset();
      for (size_t index : order) {
        // Not finished before the last frame: a clear error, nothing decoded.
        if (decoder.FramesAdded() + 1 == count) {
          EXPECT_THROW_WITH_MESSAGE(decoder.Finish(), Error, "has not been added");
        }
        decoder.AddFrame(index, capture.frame_set.images[index]);
      }
      EXPECT_EQ(decoder.FramesAdded(), count);
      CorrespondenceMap incremental;
      decoder.Finish(&incremental);
      ExpectSameMaps(batch, incremental);
    }
  }
}

// RefineGraySubpixel's stripe-edge formula, one pixel at a time as its header states it:
// the reference for the row-wise kernel (per-row bit differences, the edge bits found
// with float exponents, gathered).
cv::Mat ReferenceGrayRefinement(const FrameSet& frames, PatternAxis axis, const cv::Mat& decoded,
                                float step) {
  const FrameSetManifest& manifest = frames.manifest;
  const int lowest = manifest.AxisLowestBit(axis);
  const int size = axis == PatternAxis::kX ? manifest.projector_width : manifest.projector_height;
  const int blocks = (size + (1 << lowest) - 1) >> lowest;
  const auto white = manifest.Find(FrameRole::kWhite), black = manifest.Find(FrameRole::kBlack);
  const auto grey = [&](size_t index, int x, int y) -> double {
    const cv::Mat& image = frames.Image(index);
    return image.depth() == CV_16U ? image.at<uint16_t>(y, x) : image.at<uint8_t>(y, x);
  };
  // Bit `bit`'s difference at (x, y), positive when the pixel sees 1; NaN: no frames.
  const auto difference = [&](int bit, int x, int y) -> double {
    const auto pattern = manifest.FindCode(axis, bit, false);
    if (!pattern) return std::numeric_limits<double>::quiet_NaN();
    if (const auto inverse = manifest.FindCode(axis, bit, true)) {
      return grey(*pattern, x, y) - grey(*inverse, x, y);
    }
    if (!white || !black) return std::numeric_limits<double>::quiet_NaN();
    return 2.0 * (grey(*pattern, x, y) - 0.5 * (grey(*white, x, y) + grey(*black, x, y)));
  };
  cv::Mat refined = decoded.clone();
  for (int y = 0; y < decoded.rows; ++y) {
    for (int x = 0; x < decoded.cols; ++x) {
      const float value = decoded.at<float>(y, x);
      if (!std::isfinite(value)) continue;
      const float position = (value - 0.5f * (step - 1.0f)) / step;
      const int block = static_cast<int>(std::lround(position));
      if (std::abs(position - block) > 1e-4f || block < 1 || block + 1 >= blocks) continue;
      const uint32_t gray = GrayFromBinary(block);
      int lower_bit = 0, upper_bit = 0;  // the bits that flip from block − 1 and to block + 1
      while (((GrayFromBinary(block - 1) ^ gray) >> lower_bit) != 1u) ++lower_bit;
      while (((GrayFromBinary(block + 1) ^ gray) >> upper_bit) != 1u) ++upper_bit;
      const double lower_sign = ((gray >> lower_bit) & 1u) ? 1.0 : -1.0;
      const double upper_sign = ((gray >> upper_bit) & 1u) ? 1.0 : -1.0;
      const float lower = static_cast<float>(lower_sign * difference(lower_bit + lowest, x, y));
      const float upper = static_cast<float>(upper_sign * difference(upper_bit + lowest, x, y));
      if (!(lower >= 0.0f) || !(upper >= 0.0f) || lower + upper <= 0.0f) continue;
      refined.at<float>(y, x) = value + 0.5f * step * (lower - upper) / (lower + upper);
    }
  }
  return refined;
}

// The sub-pixel edges give the reference's coordinates exactly: with inverses, against the
// threshold (no inverses), 16-bit frames, omitted low bits.
TEST(GraySubpixelEdges, MatchThePerPixelFormula) {
  struct Variant {
    std::string name;
    bool inverted;
    bool sixteen_bit;
    int skip_low_bits;
  };
  for (const Variant& variant : {Variant{"inverses", true, false, 0},
                                 Variant{"threshold", false, false, 0},
                                 Variant{"16-bit", true, true, 0},
                                 Variant{"omitted low bits", true, false, 2}}) {
    SCOPED_TRACE(variant.name);
    SceneOptions scene;
    scene.camera_width = 517;
    scene.patterns.projector_width = 300;
    scene.patterns.projector_height = 200;
    scene.patterns.inverted = variant.inverted;
    scene.patterns.skip_low_bits = variant.skip_low_bits;
    scene.sixteen_bit = variant.sixteen_bit;
    const SyntheticCapture capture = RenderScene(scene);
    const CorrespondenceMap centres = Decode(capture.frame_set);
    ASSERT_GT(centres.CountValid(), 50000u);
    DecoderOptions options;
    options.gray_subpixel = GraySubpixel::kEdges;
    const CorrespondenceMap edges = Decode(capture.frame_set, options);
    for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
      const bool x_axis = axis == PatternAxis::kX;
      const cv::Mat& decoded = x_axis ? centres.proj_x : centres.proj_y;
      const cv::Mat& refined = x_axis ? edges.proj_x : edges.proj_y;
      const cv::Mat expected = ReferenceGrayRefinement(capture.frame_set, axis, decoded,
                                                       x_axis ? centres.step_x : centres.step_y);
      EXPECT_EQ(std::memcmp(refined.data, expected.data, expected.total() * sizeof(float)), 0);
      // Most decoded pixels moved off their block centres.
      EXPECT_GT(cv::countNonZero(refined != decoded), static_cast<int>(centres.CountValid() / 2));
    }
  }
}

TEST(IncrementalDecode, BadFramesAreClearErrors) {
  const SyntheticCapture capture = RenderScene(SceneOptions());
  IncrementalDecoder decoder(capture.frame_set.manifest);
  const size_t count = capture.frame_set.images.size();
  EXPECT_THROW_WITH_MESSAGE(decoder.AddFrame(count, capture.frame_set.images[0]), Error,
                            "out of range");
  EXPECT_THROW_WITH_MESSAGE(decoder.AddFrame(0, cv::Mat(10, 10, CV_8UC1)), Error, "10x10",
                            "400x300");
  EXPECT_THROW_WITH_MESSAGE(decoder.AddFrame(0, cv::Mat(300, 400, CV_32FC1)), Error,
                            "8- or 16-bit");
  decoder.AddFrame(0, capture.frame_set.images[0]);
  EXPECT_THROW_WITH_MESSAGE(decoder.AddFrame(0, capture.frame_set.images[0]), Error,
                            "already added");
  cv::Mat sixteen;
  capture.frame_set.images[1].convertTo(sixteen, CV_16U, 257.0);
  EXPECT_THROW_WITH_MESSAGE(decoder.AddFrame(1, sixteen), Error, "same bit depth");
  DecoderOptions bad;
  bad.min_contrast = -1.0;
  EXPECT_THROW_WITH_MESSAGE(IncrementalDecoder(capture.frame_set.manifest, bad), Error,
                            "min_contrast");
}

TEST(SyntheticDecode, WithoutWhiteAndBlackFramesInversesSuffice) {
  SceneOptions scene;
  scene.patterns.projector_width = 300;
  scene.patterns.projector_height = 200;
  scene.patterns.white_black = false;
  const SyntheticCapture capture = RenderScene(scene);
  const CorrespondenceMap map = Decode(capture.frame_set);
  ExpectConsistentMap(map);
  const Score score = Evaluate(map, capture);
  SCOPED_TRACE(::testing::Message() << score);
  EXPECT_GE(score.CorrectRate(), 0.90);
  EXPECT_GE(score.InteriorExactRate(), 0.9999);
  EXPECT_EQ(score.wrong, 0u);
  EXPECT_EQ(score.dark_valid, 0u);
}

TEST(SyntheticDecode, ConfidenceReflectsTheWeakestBit) {
  SceneOptions scene;
  scene.patterns.projector_width = 300;
  scene.patterns.projector_height = 200;
  scene.noise_sigma = 0.0;
  scene.blur_sigma_px = 0.0;
  scene.proj_from_cam = {0.25, 0.0, 0.0, 0.0, 0.25, 0.0};  // 4 camera px each
  for (bool inverted : {true, false}) {
    scene.patterns.inverted = inverted;
    const SyntheticCapture capture = RenderScene(scene);
    const CorrespondenceMap map = Decode(capture.frame_set);
    // Pixels at projector pixel centres see ideal stripes: |p − p̄| equals
    // white − black (confidence 1), |p − threshold| half of it (0.5), up to quantisation.
    const float ideal = inverted ? 1.0f : 0.5f;
    size_t checked = 0, off = 0;
    for (int v = 0; v < map.height(); ++v) {
      for (int u = 0; u < map.width(); ++u) {
        if (u % 4 != 0 || v % 4 != 0 || !map.mask.at<uint8_t>(v, u)) continue;
        ++checked;
        off += std::abs(map.confidence.at<float>(v, u) - ideal) > 0.02f;
      }
    }
    EXPECT_GT(checked, 1000u);
    EXPECT_EQ(off, 0u) << (inverted ? "inverse" : "threshold");
  }
}

TEST(SyntheticDecode, DecodingIntoAMapReusesItsImagesUnlessShared) {
  SceneOptions scene;
  scene.patterns.projector_width = 300;
  scene.patterns.projector_height = 200;
  const SyntheticCapture capture = RenderScene(scene);
  const CorrespondenceMap fresh = Decode(capture.frame_set);
  CorrespondenceMap map;
  Decode(capture.frame_set, DecoderOptions(), &map);
  const uchar* proj_x = map.proj_x.data;
  const uchar* mask = map.mask.data;
  Decode(capture.frame_set, DecoderOptions(), &map);
  EXPECT_EQ(map.proj_x.data, proj_x);  // reused
  EXPECT_EQ(map.mask.data, mask);
  EXPECT_EQ(std::memcmp(map.proj_x.data, fresh.proj_x.data, fresh.proj_x.total() * 4), 0);
  EXPECT_EQ(std::memcmp(map.mask.data, fresh.mask.data, fresh.mask.total()), 0);
  // A caller still holding the old mask keeps it: the map gets new memory.
  const cv::Mat held = map.mask;
  DecoderOptions strict;
  strict.min_bit_contrast = 40.0;
  Decode(capture.frame_set, strict, &map);
  EXPECT_NE(map.mask.data, held.data);
  EXPECT_EQ(cv::countNonZero(held), cv::countNonZero(fresh.mask));
  EXPECT_LT(map.CountValid(), fresh.CountValid());
  // An x-only set leaves no stale y map behind.
  SceneOptions x_only = scene;
  x_only.patterns.axes = PatternAxes::kX;
  Decode(RenderScene(x_only).frame_set, DecoderOptions(), &map);
  EXPECT_TRUE(map.HasX());
  EXPECT_FALSE(map.HasY());
  EXPECT_THROW_WITH_MESSAGE(Decode(capture.frame_set, DecoderOptions(), nullptr), Error,
                            "no output map");
}

// ---------------------------------------------------------------------------------------
// Files and bad inputs.
// ---------------------------------------------------------------------------------------
SyntheticCapture SmallCapture(PatternAxes axes = PatternAxes::kXY) {
  SceneOptions scene;
  scene.camera_width = 160;
  scene.camera_height = 120;
  scene.patterns.projector_width = 100;
  scene.patterns.projector_height = 80;
  scene.patterns.axes = axes;
  scene.patterns.skip_low_bits = 1;
  scene.shadow = cv::Rect(10, 10, 30, 30);
  return RenderScene(scene);
}

bool SameBytes(const cv::Mat& a, const cv::Mat& b) {
  return a.type() == b.type() && a.size() == b.size() && a.isContinuous() && b.isContinuous() &&
         std::memcmp(a.data, b.data, a.total() * a.elemSize()) == 0;
}

TEST(CorrespondenceMapFiles, WriteReadRoundTripIsExact) {
  for (PatternAxes axes : {PatternAxes::kXY, PatternAxes::kY}) {
    const CorrespondenceMap map = Decode(SmallCapture(axes).frame_set);
    ASSERT_GT(map.CountValid(), 1000u);
    testing::ScratchDir scratch;
    const std::string directory = scratch.File("maps/nested");
    WriteCorrespondenceMap(directory, map);
    const CorrespondenceMap read = ReadCorrespondenceMap(directory);
    EXPECT_EQ(read.projector_width, map.projector_width);
    EXPECT_EQ(read.projector_height, map.projector_height);
    EXPECT_EQ(read.step_x, map.step_x);
    EXPECT_EQ(read.step_y, map.step_y);
    EXPECT_EQ(read.HasX(), map.HasX());
    EXPECT_EQ(read.HasY(), map.HasY());
    if (map.HasX()) {
      EXPECT_TRUE(SameBytes(read.proj_x, map.proj_x));
    }
    EXPECT_TRUE(SameBytes(read.proj_y, map.proj_y));
    EXPECT_TRUE(SameBytes(read.mask, map.mask));
    EXPECT_TRUE(SameBytes(read.confidence, map.confidence));
    EXPECT_EQ(read.CountValid(), map.CountValid());
    // The colourised views: black exactly where invalid.
    const cv::Mat colour = ReadImage(JoinPath(directory, "proj_y.png"));
    ASSERT_EQ(colour.type(), CV_8UC3);
    cv::Mat grey;
    cv::cvtColor(colour, grey, cv::COLOR_BGR2GRAY);
    EXPECT_EQ(cv::countNonZero((grey == 0) != (map.mask == 0)), 0);
    EXPECT_TRUE(std::filesystem::exists(JoinPath(directory, "confidence.png")));
    EXPECT_EQ(std::filesystem::exists(JoinPath(directory, "proj_x.png")), map.HasX());
  }
}

TEST(CorrespondenceMapFiles, BadDirectoriesAreRefused) {
  const CorrespondenceMap map = Decode(SmallCapture().frame_set);
  testing::ScratchDir scratch;
  EXPECT_THROW_WITH_MESSAGE(ReadCorrespondenceMap(scratch.File("missing")), Error,
                            "missing/correspondence.json", "no such file");
  WriteCorrespondenceMap(scratch.path(), map);
  // A missing image.
  std::filesystem::remove(scratch.File("proj_x.exr"));
  EXPECT_THROW_WITH_MESSAGE(ReadCorrespondenceMap(scratch.path()), Error, "proj_x.exr",
                            "no such file");
  // An image of the wrong size.
  WriteCorrespondenceMap(scratch.path(), map);
  WriteImageAtomic(scratch.File("mask.png"), cv::Mat::zeros(10, 10, CV_8UC1));
  EXPECT_THROW_WITH_MESSAGE(ReadCorrespondenceMap(scratch.path()), Error,
                            "proj_x is CV_32FC1 160x120", "mask size 10x10");
  // Corrupt JSON and a wrong format tag.
  WriteCorrespondenceMap(scratch.path(), map);
  WriteFileAtomic(scratch.File("correspondence.json"), "{ \"format\": ");
  EXPECT_THROW_WITH_MESSAGE(ReadCorrespondenceMap(scratch.path()), Error, "correspondence.json",
                            "not valid JSON");
  WriteFileAtomic(scratch.File("correspondence.json"), "{ \"format\": \"other/1\" }");
  EXPECT_THROW_WITH_MESSAGE(ReadCorrespondenceMap(scratch.path()), Error, "correspondence.json",
                            "'other/1'");
  // Writing an inconsistent map.
  CorrespondenceMap broken = map;
  broken.confidence = cv::Mat();
  EXPECT_THROW_WITH_MESSAGE(WriteCorrespondenceMap(scratch.File("broken"), broken), Error,
                            "confidence", "0x0");
}

TEST(ColorizeCoordinate, HueFollowsTheCoordinateAndInvalidIsBlack) {
  cv::Mat coordinate(1, 4, CV_32FC1);
  coordinate.at<float>(0, 0) = 0.0f;
  coordinate.at<float>(0, 1) = 99.0f;
  coordinate.at<float>(0, 2) = std::numeric_limits<float>::quiet_NaN();
  coordinate.at<float>(0, 3) = 36.0f;  // hue 300 · 36 / 99 ≈ 109° (green)
  const cv::Mat colour = ColorizeCoordinate(coordinate, 100);
  ASSERT_EQ(colour.type(), CV_8UC3);
  EXPECT_EQ(colour.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 255));    // red
  EXPECT_EQ(colour.at<cv::Vec3b>(0, 1), cv::Vec3b(255, 0, 255));  // magenta
  EXPECT_EQ(colour.at<cv::Vec3b>(0, 2), cv::Vec3b(0, 0, 0));
  const cv::Vec3b green = colour.at<cv::Vec3b>(0, 3);
  EXPECT_EQ(green[1], 255);
  EXPECT_LT(green[0], 64);
  EXPECT_LT(green[2], 64);
  EXPECT_THROW_WITH_MESSAGE(ColorizeCoordinate(cv::Mat::zeros(2, 2, CV_8UC1), 100), Error,
                            "CV_32FC1", "got CV_8UC1");
  EXPECT_THROW_WITH_MESSAGE(ColorizeCoordinate(coordinate, 0), Error, "invalid projector size 0");
}

TEST(DecodeErrors, InvalidOptionsAndUndecodableSetsThrow) {
  SyntheticCapture capture = SmallCapture();
  DecoderOptions bad;
  bad.min_contrast = -3;
  EXPECT_THROW_WITH_MESSAGE(Decode(capture.frame_set, bad), Error, "min_contrast -3");
  bad = DecoderOptions();
  bad.consistency.enabled = true;
  bad.consistency.max_average_radius = -1;
  EXPECT_THROW_WITH_MESSAGE(Decode(capture.frame_set, bad), Error, "max_average_radius -1");

  // Inverses but no white/black: auto and robust decode, threshold cannot.
  SceneOptions scene;
  scene.camera_width = 160;
  scene.camera_height = 120;
  scene.shadow = cv::Rect(10, 10, 30, 30);
  scene.patterns.projector_width = 100;
  scene.patterns.projector_height = 80;
  scene.patterns.white_black = false;
  const SyntheticCapture no_references = RenderScene(scene);
  DecoderOptions threshold;
  threshold.bit_decision = BitDecision::kThreshold;
  EXPECT_NO_THROW(Decode(no_references.frame_set));
  EXPECT_THROW_WITH_MESSAGE(Decode(no_references.frame_set, threshold), Error, "threshold decoding",
                            "white and a black frame");

  // No inverses: robust decoding refuses with a message that says why.
  scene.patterns.white_black = true;
  scene.patterns.inverted = false;
  SyntheticCapture no_inverses = RenderScene(scene);
  DecoderOptions robust;
  robust.bit_decision = BitDecision::kRobust;
  try {
    Decode(no_inverses.frame_set, robust);
    ADD_FAILURE() << "robust decoding without inverses accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("inverse"), std::string::npos) << e.what();
  }

  // Neither inverses nor white/black: nothing to decide a bit against.
  FrameSet& set = no_inverses.frame_set;
  const size_t white = *set.manifest.Find(FrameRole::kWhite);
  set.manifest.frames.erase(set.manifest.frames.begin() + white);
  set.images.erase(set.images.begin() + white);
  EXPECT_THROW_WITH_MESSAGE(Decode(set), Error, "without inverses", "white and a black frame");

  // Images that do not match the manifest.
  SyntheticCapture wrong_size = SmallCapture();
  cv::resize(wrong_size.frame_set.images[3], wrong_size.frame_set.images[3], cv::Size(80, 60));
  EXPECT_THROW_WITH_MESSAGE(Decode(wrong_size.frame_set), Error, "frame_03.png", "80x60",
                            "160x120");
}

TEST(DecodeInputs, NonContinuousImagesDecodeLikeContinuousOnes) {
  const SyntheticCapture capture = SmallCapture();
  FrameSet views = capture.frame_set;
  for (cv::Mat& image : views.images) {
    cv::Mat padded;
    cv::copyMakeBorder(image, padded, 2, 2, 3, 3, cv::BORDER_REPLICATE);
    image = padded(cv::Rect(3, 2, image.cols, image.rows));
    ASSERT_FALSE(image.isContinuous());
  }
  const CorrespondenceMap a = Decode(capture.frame_set);
  const CorrespondenceMap b = Decode(views);
  EXPECT_TRUE(SameBytes(a.mask, b.mask));
  EXPECT_TRUE(SameBytes(a.proj_x, b.proj_x));
}

}  // namespace
}  // namespace sope
