// Phase decoding against synthetic captures with a known camera → projector mapping: the
// projector images of projector/patterns, defocused, sampled at sub-pixel projector
// coordinates, through a projector response, with noise and 8-bit quantisation.
#include "decoder/phase_decoder.h"

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "tests/test_support.h"
#include "core/statistics.h"
#include "decoder/decoder.h"
#include "projector/patterns.h"

namespace sope {
namespace {

constexpr double kTwoPi = 6.283185307179586476925286766559;

struct Capture {
  int camera_width = 160;
  int camera_height = 120;
  // Projector coordinate seen by camera pixel (x, y): u = u0 + ux·x + uy·y (same for v).
  double u0 = 3.3, ux = 1.37, uy = 0.21;
  double v0 = 2.1, vx = 0.13, vy = 1.41;
  double albedo_gain = 120.0;  // grey levels of a white projector pixel
  double ambient = 20.0;       // grey levels
  double noise_sigma = 1.5;    // grey levels
  double defocus_sigma_px = 0.8;
  ProjectorResponse response;  // of the projector
  uint64_t seed = 7;
};

double TrueU(const Capture& c, int x, int y) { return c.u0 + c.ux * x + c.uy * y; }
double TrueV(const Capture& c, int x, int y) { return c.v0 + c.vx * x + c.vy * y; }

// Bilinear sample of a float image at (u, v), clamped to the border.
float Sample(const cv::Mat& image, double u, double v) {
  const double cu = std::clamp(u, 0.0, image.cols - 1.0), cv_ = std::clamp(v, 0.0, image.rows - 1.0);
  const int x0 = std::min(static_cast<int>(cu), image.cols - 2);
  const int y0 = std::min(static_cast<int>(cv_), image.rows - 2);
  const float fx = static_cast<float>(cu - x0), fy = static_cast<float>(cv_ - y0);
  const float top = image.at<float>(y0, x0) * (1 - fx) + image.at<float>(y0, x0 + 1) * fx;
  const float bottom = image.at<float>(y0 + 1, x0) * (1 - fx) + image.at<float>(y0 + 1, x0 + 1) * fx;
  return top * (1 - fy) + bottom * fy;
}

// Phase frames are rendered analytically (a defocused sinusoid keeps its phase and loses
// modulation by exp(−2π²σ²/P²)); stripes and white/black by sampling the defocused
// projector image (bilinear sampling of a sinusoid would bend it by itself).
FrameSet Render(const PatternOptions& patterns, const Capture& c) {
  FrameSet set;
  set.manifest = MakePatternManifest(patterns, c.camera_width, c.camera_height);
  std::mt19937_64 engine(c.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (const Pattern& pattern : GeneratePatterns(patterns)) {
    const FrameInfo& info = pattern.info;
    cv::Mat emitted;
    if (info.role != FrameRole::kPhase) {
      emitted.create(pattern.image.size(), CV_32FC1);
      for (int y = 0; y < emitted.rows; ++y) {
        for (int x = 0; x < emitted.cols; ++x) {
          emitted.at<float>(y, x) =
              static_cast<float>(c.response.Apply(pattern.image.at<uint8_t>(y, x) / 255.0));
        }
      }
      if (c.defocus_sigma_px > 0) {
        cv::GaussianBlur(emitted, emitted, cv::Size(), c.defocus_sigma_px, c.defocus_sigma_px,
                         cv::BORDER_REPLICATE);
      }
    }
    const double attenuation =
        info.role == FrameRole::kPhase
            ? std::exp(-0.5 * std::pow(kTwoPi * c.defocus_sigma_px / info.period, 2))
            : 1.0;
    cv::Mat image(c.camera_height, c.camera_width, CV_8UC1);
    for (int y = 0; y < c.camera_height; ++y) {
      for (int x = 0; x < c.camera_width; ++x) {
        const double u = TrueU(c, x, y), v = TrueV(c, x, y);
        double light;
        if (info.role == FrameRole::kPhase) {
          const double w = info.axis == PatternAxis::kX ? u : v;
          light = c.response.Apply(
              0.5 * (1.0 + attenuation * std::cos(kTwoPi * w / info.period - info.shift)));
        } else {
          light = Sample(emitted, u, v);
        }
        const double value = c.ambient + c.albedo_gain * light + c.noise_sigma * normal(engine);
        image.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(value);
      }
    }
    set.images.push_back(image);
  }
  return set;
}

struct Errors {
  double decoded_fraction = 0.0;
  double median = 0.0;
  double outlier_fraction = 0.0;  // > 1 px
  double max = 0.0;
};

// Over pixels whose true coordinates lie inside the projector, 2 px from its border.
Errors Compare(const CorrespondenceMap& map, const Capture& c, int projector_width,
               int projector_height) {
  std::vector<double> errors;
  size_t inside = 0, outliers = 0;
  Errors result;
  for (int y = 0; y < map.height(); ++y) {
    for (int x = 0; x < map.width(); ++x) {
      const double u = TrueU(c, x, y), v = TrueV(c, x, y);
      if (u < 2 || v < 2 || u > projector_width - 3 || v > projector_height - 3) continue;
      ++inside;
      if (map.mask.at<uint8_t>(y, x) == 0) continue;
      double error = 0.0;
      if (map.HasX()) error = std::max(error, std::abs(map.proj_x.at<float>(y, x) - u));
      if (map.HasY()) error = std::max(error, std::abs(map.proj_y.at<float>(y, x) - v));
      errors.push_back(error);
      outliers += error > 1.0;
      result.max = std::max(result.max, error);
    }
  }
  result.decoded_fraction = inside ? static_cast<double>(errors.size()) / inside : 0.0;
  result.median = Median(errors);
  result.outlier_fraction = errors.empty() ? 1.0 : static_cast<double>(outliers) / errors.size();
  return result;
}

PatternOptions PhasePatterns(int width, int height, std::vector<double> periods, int steps) {
  PatternOptions options;
  options.projector_width = width;
  options.projector_height = height;
  options.family = PatternFamily::kPhase;
  options.periods = std::move(periods);
  options.steps = steps;
  options.white_black = false;
  return options;
}

TEST(PhaseDecoder, WrappedAtan2MatchesStdAtan2) {
  std::mt19937 engine(3);
  std::uniform_real_distribution<float> uniform(-100.0f, 100.0f);
  double worst = 0.0;
  for (int i = 0; i < 200000; ++i) {
    const float y = uniform(engine), x = uniform(engine);
    double expected = std::atan2(static_cast<double>(y), static_cast<double>(x));
    if (expected < 0) expected += kTwoPi;
    const double got = internal::WrappedAtan2(y, x);
    ASSERT_GE(got, 0.0);
    ASSERT_LT(got, kTwoPi);
    worst = std::max(worst, std::abs(std::remainder(got - expected, kTwoPi)));
  }
  EXPECT_LT(worst, 1e-5);
  EXPECT_EQ(internal::WrappedAtan2(0.0f, 0.0f), 0.0f);
  EXPECT_NEAR(internal::WrappedAtan2(-1e-30f, 1.0f), 0.0, 1e-6);
}

TEST(PhaseDecoder, NoiselessThreeFrequencyFourStepIsExact) {
  const PatternOptions patterns = PhasePatterns(256, 192, {256, 32, 8}, 4);
  Capture capture;
  capture.noise_sigma = 0.0;
  const FrameSet set = Render(patterns, capture);
  const CorrespondenceMap map = Decode(set);
  const Errors errors = Compare(map, capture, 256, 192);
  EXPECT_GE(errors.decoded_fraction, 0.999);
  // 8-bit patterns and 8-bit captures quantise; the fit averages that out.
  EXPECT_LT(errors.median, 0.01);
  EXPECT_LT(errors.max, 0.05);
  EXPECT_EQ(map.step_x, kPhaseCoordinateStep);
  EXPECT_EQ(map.step_y, kPhaseCoordinateStep);
}

TEST(PhaseDecoder, ArbitraryShiftsAreSolvedByLeastSquares) {
  // Five uneven shifts at period 16 under an absolute group of three uneven shifts.
  FrameSetManifest manifest;
  const int width = 128, height = 96;
  PatternOptions base = PhasePatterns(width, height, {128}, 3);
  base.axes = PatternAxes::kX;
  Capture capture;
  capture.noise_sigma = 0.5;
  capture.ux = 0.7;
  capture.uy = 0.05;
  std::vector<FrameInfo> frames;
  for (double shift : {0.3, 1.9, 4.4}) {
    FrameInfo f;
    f.role = FrameRole::kPhase;
    f.axis = PatternAxis::kX;
    f.period = 128;
    f.shift = shift;
    frames.push_back(f);
  }
  for (double shift : {0.0, 0.5, 2.0, 3.0, 5.5}) {
    FrameInfo f;
    f.role = FrameRole::kPhase;
    f.axis = PatternAxis::kX;
    f.period = 16;
    f.shift = shift;
    frames.push_back(f);
  }
  FrameSet set;
  set.manifest.camera_width = capture.camera_width;
  set.manifest.camera_height = capture.camera_height;
  set.manifest.projector_width = width;
  set.manifest.projector_height = height;
  std::mt19937_64 engine(1);
  std::normal_distribution<double> normal(0.0, capture.noise_sigma);
  for (size_t i = 0; i < frames.size(); ++i) {
    frames[i].file = "f" + std::to_string(i) + ".png";
    set.manifest.frames.push_back(frames[i]);
    cv::Mat image(capture.camera_height, capture.camera_width, CV_8UC1);
    for (int y = 0; y < image.rows; ++y) {
      for (int x = 0; x < image.cols; ++x) {
        const double u = TrueU(capture, x, y);
        const double value =
            30 + 100 * 0.5 * (1 + std::cos(kTwoPi * u / frames[i].period - frames[i].shift)) +
            normal(engine);
        image.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(value);
      }
    }
    set.images.push_back(image);
  }
  const CorrespondenceMap map = Decode(set);
  EXPECT_FALSE(map.HasY());
  const Errors errors = Compare(map, capture, width, height);
  EXPECT_GE(errors.decoded_fraction, 0.999);
  EXPECT_LT(errors.median, 0.02);
  EXPECT_EQ(errors.outlier_fraction, 0.0);
}

TEST(PhaseDecoder, SixteenFoldPeriodRatiosUnwrapAtRealisticNoise) {
  // 1024 → 64 → 4: the coarse coordinate must predict the fine period index from a phase
  // 16× coarser; dark surface (B = 40 grey levels), σ = 2 grey levels.
  const PatternOptions patterns = PhasePatterns(1024, 768, {1024, 64, 4}, 4);
  Capture capture;
  capture.ux = 5.3;
  capture.uy = 0.4;
  capture.vx = 0.3;
  capture.vy = 5.1;
  capture.albedo_gain = 80.0;
  capture.noise_sigma = 2.0;
  capture.defocus_sigma_px = 0.5;
  const FrameSet set = Render(patterns, capture);
  DecoderOptions options;
  options.min_consistent_neighbours = 0;  // the unwrapping alone
  const CorrespondenceMap map = Decode(set, options);
  const Errors errors = Compare(map, capture, 1024, 768);
  EXPECT_GE(errors.decoded_fraction, 0.99);
  EXPECT_LT(errors.median, 0.05);
  EXPECT_LE(errors.outlier_fraction, 0.001);
}

TEST(PhaseDecoder, UnwrapDisagreementInvalidatesInsteadOfGuessing) {
  const PatternOptions patterns = PhasePatterns(256, 192, {256, 16}, 4);
  Capture capture;
  capture.noise_sigma = 0.5;
  FrameSet set = Render(patterns, capture);
  // Corrupt the coarse x group in a block of pixels: shift its phase by 0.42 of the fine
  // period (a coarse coordinate off by 6.7 px), by rendering it for other u.
  const std::vector<PhaseGroup> groups = set.manifest.PhaseGroups(PatternAxis::kX);
  ASSERT_EQ(groups.size(), 2u);
  const cv::Rect block(40, 30, 20, 20);
  for (size_t k = 0; k < groups[0].frames.size(); ++k) {
    cv::Mat& image = set.images[groups[0].frames[k]];
    for (int y = block.y; y < block.y + block.height; ++y) {
      for (int x = block.x; x < block.x + block.width; ++x) {
        const double u = TrueU(capture, x, y) + 0.42 * 16.0;
        const double value =
            capture.ambient +
            capture.albedo_gain * 0.5 * (1 + std::cos(kTwoPi * u / 256 - groups[0].shifts[k]));
        image.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(value);
      }
    }
  }
  DecoderOptions options;
  options.min_consistent_neighbours = 0;
  const CorrespondenceMap map = Decode(set, options);
  EXPECT_EQ(cv::countNonZero(map.mask(block)), 0);  // 0.42 periods > 0.35: invalid
  // With a looser check the same pixels decode, and correctly (the error is < ½ period).
  options.phase.max_unwrap_error = 0.45;
  const CorrespondenceMap loose = Decode(set, options);
  EXPECT_EQ(cv::countNonZero(loose.mask(block)), block.area());
  EXPECT_NEAR(loose.proj_x.at<float>(block.y + 5, block.x + 5),
              TrueU(capture, block.x + 5, block.y + 5), 0.1);
}

// Gray + phase: with and without the complementary bit, the period boundaries (which
// coincide with Gray stripe edges) must not produce off-by-one-period spikes.
class GrayPhase : public ::testing::TestWithParam<bool> {};

TEST_P(GrayPhase, NoPeriodJumpsAtGrayEdges) {
  PatternOptions patterns;
  patterns.projector_width = 256;
  patterns.projector_height = 192;
  patterns.family = PatternFamily::kGrayPhase;
  patterns.period = 16;
  patterns.steps = 4;
  patterns.complementary_bit = GetParam();
  Capture capture;
  capture.noise_sigma = 2.0;
  capture.defocus_sigma_px = 1.2;  // blurred stripe edges: the Gray code errs near them
  capture.ux = 0.93;               // many pixels within a pixel of an edge
  const FrameSet set = Render(patterns, capture);
  DecoderOptions options;
  options.min_consistent_neighbours = 0;  // no filter hides the spikes
  const CorrespondenceMap map = Decode(set, options);
  const Errors errors = Compare(map, capture, 256, 192);
  EXPECT_GE(errors.decoded_fraction, 0.99);
  EXPECT_EQ(errors.outlier_fraction, 0.0) << "max error " << errors.max;
  // One 4-step group at period 16, B ≈ 57, σ = 2: σ_u = 16/2π · σ/(B·√2) ≈ 0.06 px per axis.
  EXPECT_LT(errors.median, 0.1);
}

INSTANTIATE_TEST_SUITE_P(ComplementaryBit, GrayPhase, ::testing::Bool());

// The 4-step phase error under gamma 2.2 without correction, and with the response.
TEST(PhaseDecoder, ResponseCorrectionRemovesTheGammaRipple) {
  const PatternOptions patterns = PhasePatterns(256, 192, {256, 32}, 4);
  Capture capture;
  capture.noise_sigma = 0.0;
  capture.defocus_sigma_px = 0.0;
  capture.response = ProjectorResponse::Gamma(2.2);
  capture.uy = 0.0;  // u along rows only
  const FrameSet set = Render(patterns, capture);
  DecoderOptions options;
  options.min_consistent_neighbours = 0;
  options.phase.local_fit_radius = 0;  // the per-pixel correction alone (the fit smooths)
  const CorrespondenceMap plain = Decode(set, options);
  options.phase.response = ProjectorResponse::Gamma(2.2);
  const CorrespondenceMap corrected = Decode(set, options);
  // The ripple: coordinate error against the fine phase, its 4th harmonic.
  const auto ripple = [&](const CorrespondenceMap& map, double* rms) {
    double c = 0, s = 0, sum2 = 0;
    int n = 0;
    for (int x = 5; x < 150; ++x) {
      const double u = TrueU(capture, x, 60);
      const double error = map.proj_x.at<float>(60, x) - u;
      const double phase = kTwoPi * u / 32;
      c += error * std::cos(4 * phase);
      s += error * std::sin(4 * phase);
      sum2 += error * error;
      ++n;
    }
    *rms = std::sqrt(sum2 / n);
    return 2.0 * std::hypot(c, s) / n;  // amplitude of the 4φ component, projector pixels
  };
  double plain_rms = 0, corrected_rms = 0;
  const double plain_ripple = ripple(plain, &plain_rms);
  const double corrected_ripple = ripple(corrected, &corrected_rms);
  RecordProperty("plain_ripple_px", std::to_string(plain_ripple));
  RecordProperty("corrected_ripple_px", std::to_string(corrected_ripple));
  std::printf("gamma 2.2, period 32: 4φ ripple %.4f px (rms %.4f) uncorrected, %.4f px (rms "
              "%.4f) corrected\n", plain_ripple, plain_rms, corrected_ripple, corrected_rms);
  EXPECT_GT(plain_ripple, 0.05);  // a visible ripple at period 32
  EXPECT_GT(plain_ripple, 0.8 * std::sqrt(2.0) * plain_rms);  // the error is mostly that ripple
  EXPECT_LT(corrected_ripple, 0.1 * plain_ripple);
}

TEST(PhaseDecoder, WhiteBlackOptionalTextureAndImages) {
  PatternOptions patterns = PhasePatterns(256, 192, {256, 16}, 3);
  patterns.white_black = true;
  Capture capture;
  capture.defocus_sigma_px = 0.0;
  const FrameSet set = Render(patterns, capture);
  CorrespondenceMap map;
  PhaseDecodeImages images;
  DecodePhase(set, DecoderOptions{}, &map, &images);
  ASSERT_FALSE(images.wrapped_phase_x.empty());
  ASSERT_FALSE(images.wrapped_phase_y.empty());
  // The synthesised texture is the white frame: ambient + gain.
  const cv::Mat& white = set.images[*set.manifest.Find(FrameRole::kWhite)];
  const cv::Rect inner(10, 10, 100, 80);
  EXPECT_NEAR(cv::mean(images.texture(inner))[0], cv::mean(white(inner))[0], 2.0);
  EXPECT_NEAR(cv::mean(images.modulation(inner))[0], capture.albedo_gain / 2, 2.0);
  // Confidence is modulation / noise: 60 / ~1.5.
  EXPECT_GT(cv::mean(map.confidence(inner))[0], 10.0);
  // Outside the projector's light the mask is off from the modulation alone.
  Capture dark = capture;
  dark.albedo_gain = 4.0;
  const CorrespondenceMap none = Decode(Render(patterns, dark));
  EXPECT_LT(none.CountValid(), 50u);
}

TEST(PhaseDecoder, InvalidOptionsNameTheValue) {
  const FrameSet set = Render(PhasePatterns(64, 48, {64}, 3), Capture{});
  DecoderOptions options;
  options.phase.max_unwrap_error = 0.6;
  EXPECT_THROW_WITH_MESSAGE(Decode(set, options), Error, "max_unwrap_error 0.6");
  options = {};
  options.phase.min_modulation = -1;
  EXPECT_THROW_WITH_MESSAGE(Decode(set, options), Error, "min_modulation -1");
  options = {};
  options.phase.response.table = {0.0, 0.7, 0.6, 1.0};
  EXPECT_THROW_WITH_MESSAGE(Decode(set, options), Error, "must not decrease");
  options = {};
  options.phase.local_fit_radius = 5;
  EXPECT_THROW_WITH_MESSAGE(Decode(set, options), Error, "local_fit_radius 5");
}

// The local fit of the coordinate: noise averaged on a smooth surface, nothing mixed across
// a depth step (a jump of the coordinate), a period-jump outlier neither pulled in nor
// pulling its neighbours.
TEST(PhaseDecoder, LocalFitAveragesNoiseButKeepsStepsAndOutliers) {
  const int rows = 60, cols = 80;
  cv::Mat truth(rows, cols, CV_32FC1), coordinate(rows, cols, CV_32FC1);
  cv::Mat mask(rows, cols, CV_8UC1, cv::Scalar(255));
  std::mt19937_64 engine(3);
  std::normal_distribution<float> noise(0.0f, 0.08f);
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      // A tilted plane, a step of 2 px at x = 40 (a small depth step), a hole.
      truth.at<float>(y, x) = 5.0f + 1.2f * x + 0.3f * y + (x >= 40 ? 2.0f : 0.0f);
      coordinate.at<float>(y, x) = truth.at<float>(y, x) + noise(engine);
    }
  }
  mask(cv::Rect(10, 10, 5, 5)).setTo(0);
  coordinate.at<float>(30, 20) += 8.0f;  // a period jump of the 8-px group
  PhaseDecoderOptions options;
  cv::Mat fitted = coordinate.clone();
  internal::FitCoordinatesLocally(options, mask, cv::Mat(), 1.0, &fitted);
  std::vector<double> before, after;
  double worst_at_step = 0;
  for (int y = 1; y < rows - 1; ++y) {
    for (int x = 1; x < cols - 1; ++x) {
      if (mask.at<uint8_t>(y, x) == 0 || (y == 30 && x == 20)) continue;
      const double error = std::abs(fitted.at<float>(y, x) - truth.at<float>(y, x));
      if (x == 39 || x == 40) worst_at_step = std::max(worst_at_step, error);
      if (std::abs(y - 30) <= 1 && std::abs(x - 20) <= 1) {
        EXPECT_LT(error, 0.3) << x << "," << y;
      }
      before.push_back(std::abs(coordinate.at<float>(y, x) - truth.at<float>(y, x)));
      after.push_back(error);
    }
  }
  std::printf("[local fit] median |error| %.4f px before, %.4f after; worst beside the step "
              "%.3f px\n", Median(before), Median(after), worst_at_step);
  EXPECT_LT(Median(after), 0.45 * Median(before));
  EXPECT_LT(worst_at_step, 0.4);  // 5σ of the raw noise; mixing the step would give ~0.7
  EXPECT_NEAR(fitted.at<float>(30, 20), truth.at<float>(30, 20) + 8.0f, 0.3);
  EXPECT_EQ(fitted.at<float>(12, 12), coordinate.at<float>(12, 12));  // masked: untouched
}

}  // namespace
}  // namespace sope
