#include "projector/patterns.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/error.h"

namespace sope {
namespace {

constexpr int kMaxProjectorSize = 1 << 15;
constexpr double kTwoPi = 6.283185307179586476925286766559;
constexpr int kMaxAutoGroups = 3;
constexpr double kAutoPeriodRatio = 8.0;
constexpr int kMaxSteps = 64;
constexpr int kMaxPeriods = 8;

bool IsPowerOfTwo(double value) {
  int exponent = 0;
  return value >= 1.0 && std::frexp(value, &exponent) == 0.5;
}
int Log2(double power_of_two) {
  int exponent = 0;
  std::frexp(power_of_two, &exponent);
  return exponent - 1;
}

void AppendPhaseGroup(const PatternOptions& options, PatternAxis axis, double period,
                      std::vector<FrameInfo>* frames) {
  for (int k = 0; k < options.steps; ++k) {
    FrameInfo frame;
    frame.role = FrameRole::kPhase;
    frame.axis = axis;
    frame.period = period;
    frame.shift = kTwoPi * k / options.steps;
    frames->push_back(frame);
  }
}

void AppendAxis(const PatternOptions& options, PatternAxis axis, std::vector<FrameInfo>* frames) {
  const int size = axis == PatternAxis::kX ? options.projector_width : options.projector_height;
  if (options.family == PatternFamily::kPhase) {
    for (double period : PhasePeriodsFor(options, size)) {
      AppendPhaseGroup(options, axis, period, frames);
    }
    return;
  }
  const int bits = BitsForSize(size);
  const int lowest_bit = options.family == PatternFamily::kGrayPhase
                             ? Log2(options.period) - (options.complementary_bit ? 1 : 0)
                             : options.skip_low_bits;
  for (int bit = bits - 1; bit >= lowest_bit; --bit) {
    for (bool inverted : {false, true}) {
      if (inverted && !options.inverted) continue;
      FrameInfo frame;
      frame.role = FrameRole::kCode;
      frame.axis = axis;
      frame.code = options.code;
      frame.bits = bits;
      frame.bit = bit;
      frame.inverted = inverted;
      frames->push_back(frame);
    }
  }
  if (options.family == PatternFamily::kGrayPhase) {
    AppendPhaseGroup(options, axis, options.period, frames);
  }
}

std::vector<FrameInfo> PatternFrames(const PatternOptions& options) {
  options.Check();
  std::vector<FrameInfo> frames;
  if (options.white_black) {
    FrameInfo white, black;
    white.role = FrameRole::kWhite;
    black.role = FrameRole::kBlack;
    frames.push_back(white);
    frames.push_back(black);
  }
  if (options.axes != PatternAxes::kY) AppendAxis(options, PatternAxis::kX, &frames);
  if (options.axes != PatternAxes::kX) AppendAxis(options, PatternAxis::kY, &frames);
  const int digits = frames.size() > 100 ? 3 : 2;
  for (size_t i = 0; i < frames.size(); ++i) {
    frames[i].file = fmt::format("frame_{:0{}}.png", i, digits);
  }
  return frames;
}

}  // namespace

std::string ToString(PatternAxes axes) {
  switch (axes) {
    case PatternAxes::kX: return "x";
    case PatternAxes::kY: return "y";
    case PatternAxes::kXY: return "xy";
  }
  return "?";
}

std::string ToString(PatternFamily family) {
  switch (family) {
    case PatternFamily::kStripes: return "stripes";
    case PatternFamily::kPhase: return "phase";
    case PatternFamily::kGrayPhase: return "gray+phase";
  }
  return "?";
}

PatternFamily PatternFamilyFromString(const std::string& text, PatternCode* code) {
  if (text == "phase") return PatternFamily::kPhase;
  if (text == "gray+phase") {
    if (code != nullptr) *code = PatternCode::kGray;
    return PatternFamily::kGrayPhase;
  }
  if (text == "gray" || text == "binary") {
    if (code != nullptr) *code = PatternCodeFromString(text);
    return PatternFamily::kStripes;
  }
  SOPE_THROW("unknown pattern code '{}' (expected gray, binary, phase or gray+phase)", text);
}

std::vector<double> PhasePeriodsFor(const PatternOptions& options, int size) {
  std::vector<double> periods = options.periods;
  if (periods.empty()) {
    for (double period = size; period >= kMinAutoPeriod &&
                               periods.size() < static_cast<size_t>(kMaxAutoGroups);
         period /= kAutoPeriodRatio) {
      periods.push_back(period);
    }
    if (periods.empty()) periods.push_back(size);
  }
  std::sort(periods.begin(), periods.end(), std::greater<double>());
  return periods;
}

std::string DescribePatterns(const PatternOptions& options) {
  const std::string axes = "axes " + ToString(options.axes);
  const std::string code = options.code == PatternCode::kGray ? "Gray code" : "binary code";
  const std::string precompensated =
      options.precompensate.IsIdentity() ? "" : ", pre-distorted for the projector response";
  switch (options.family) {
    case PatternFamily::kStripes: {
      std::string text = fmt::format("{}, {}", code, axes);
      if (options.inverted) text += ", inverses";
      if (options.skip_low_bits > 0) {
        text += fmt::format(", {} low bits skipped", options.skip_low_bits);
      }
      return text;
    }
    case PatternFamily::kPhase: {
      const auto periods = [&](int size) {
        return fmt::format("{:g}", fmt::join(PhasePeriodsFor(options, size), "/"));
      };
      std::string text;
      if (options.axes == PatternAxes::kXY && options.periods.empty()) {
        // Automatic periods follow each axis' size.
        text = fmt::format("periods {} px (x), {} px (y)", periods(options.projector_width),
                           periods(options.projector_height));
      } else {
        text = fmt::format("periods {} px", periods(options.axes == PatternAxes::kY
                                                        ? options.projector_height
                                                        : options.projector_width));
      }
      return fmt::format("phase shift, {}, {}, {} steps{}", axes, text, options.steps,
                         precompensated);
    }
    case PatternFamily::kGrayPhase:
      return fmt::format("{} + phase shift at {:g} px, {}, {} steps{}", code, options.period,
                         axes, options.steps, precompensated);
  }
  return "?";
}

PatternAxes PatternAxesFromString(const std::string& text) {
  if (text == "x") return PatternAxes::kX;
  if (text == "y") return PatternAxes::kY;
  if (text == "xy") return PatternAxes::kXY;
  SOPE_THROW("unknown axes '{}' (expected x, y or xy)", text);
}

void PatternOptions::Check() const {
  SOPE_CHECK(projector_width > 0 && projector_height > 0 &&
                 projector_width <= kMaxProjectorSize && projector_height <= kMaxProjectorSize,
             "invalid projector size {}x{}", projector_width, projector_height);
  const int min_bits = std::min(axes == PatternAxes::kY ? 99 : BitsForSize(projector_width),
                                axes == PatternAxes::kX ? 99 : BitsForSize(projector_height));
  SOPE_CHECK(skip_low_bits >= 0 && skip_low_bits < min_bits,
             "skip_low_bits {} must be in 0..{}", skip_low_bits, min_bits - 1);
  SOPE_CHECK(family == PatternFamily::kPhase || inverted || white_black,
             "patterns need inverse frames or white/black references to be decodable");
  SOPE_CHECK(family == PatternFamily::kStripes || code == PatternCode::kGray,
             "phase patterns combine with a Gray code only");
  if (family == PatternFamily::kStripes) return;
  SOPE_CHECK(steps >= 3 && steps <= kMaxSteps, "phase steps {} must be in 3..{}", steps,
             kMaxSteps);
  precompensate.Check();
  if (family == PatternFamily::kPhase) {
    SOPE_CHECK(periods.size() <= static_cast<size_t>(kMaxPeriods),
               "{} phase periods (at most {})", periods.size(), kMaxPeriods);
    for (double p : periods) {
      SOPE_CHECK(std::isfinite(p) && p > 0.0,
                 "phase period {} must be a positive, finite number of projector pixels", p);
    }
    for (size_t i = 0; i < periods.size(); ++i) {
      for (size_t j = 0; j < i; ++j) {
        SOPE_CHECK(periods[i] != periods[j], "phase period {} listed twice", periods[i]);
      }
    }
    if (!periods.empty()) {
      const double coarsest = *std::max_element(periods.begin(), periods.end());
      for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
        if ((axis == PatternAxis::kX && this->axes == PatternAxes::kY) ||
            (axis == PatternAxis::kY && this->axes == PatternAxes::kX)) {
          continue;
        }
        const int size = axis == PatternAxis::kX ? projector_width : projector_height;
        SOPE_CHECK(coarsest >= size,
                   "the coarsest phase period {} px is below the projector {} ({} px): "
                   "nothing would unwrap it (add a period ≥ {})", coarsest,
                   axis == PatternAxis::kX ? "width" : "height", size, size);
      }
    }
    return;
  }
  SOPE_CHECK(std::isfinite(period) && IsPowerOfTwo(period) && period >= (complementary_bit ? 2 : 1),
             "gray+phase period {} must be a power of two ≥ {} (the Gray code's finest "
             "stripe is one period wide)", period, complementary_bit ? 2 : 1);
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    if ((axis == PatternAxis::kX && axes == PatternAxes::kY) ||
        (axis == PatternAxis::kY && axes == PatternAxes::kX)) {
      continue;
    }
    const int size = axis == PatternAxis::kX ? projector_width : projector_height;
    SOPE_CHECK(Log2(period) - (complementary_bit ? 1 : 0) < BitsForSize(size),
               "gray+phase period {} is too wide for the projector {} ({} px)", period,
               axis == PatternAxis::kX ? "width" : "height", size);
  }
}

cv::Mat RenderPattern(const FrameInfo& frame, int projector_width, int projector_height,
                      const ProjectorResponse& precompensate) {
  SOPE_CHECK(projector_width > 0 && projector_height > 0, "invalid projector size {}x{}",
             projector_width, projector_height);
  if (frame.role == FrameRole::kPhase) {
    SOPE_CHECK(std::isfinite(frame.period) && frame.period > 0.0 && std::isfinite(frame.shift),
               "invalid phase frame: period {}, shift {}", frame.period, frame.shift);
    precompensate.Check();
    const int size = frame.axis == PatternAxis::kX ? projector_width : projector_height;
    std::vector<uint8_t> values(size);
    for (int u = 0; u < size; ++u) {
      const double intensity = 0.5 * (1.0 + std::cos(kTwoPi * u / frame.period - frame.shift));
      values[u] = static_cast<uint8_t>(std::lround(255.0 * precompensate.Invert(intensity)));
    }
    cv::Mat image(projector_height, projector_width, CV_8UC1);
    for (int y = 0; y < projector_height; ++y) {
      uint8_t* row = image.ptr<uint8_t>(y);
      if (frame.axis == PatternAxis::kX) {
        std::copy(values.begin(), values.end(), row);
      } else {
        std::fill(row, row + projector_width, values[y]);
      }
    }
    return image;
  }
  if (frame.role == FrameRole::kWhite) {
    return cv::Mat(projector_height, projector_width, CV_8UC1, cv::Scalar(255));
  }
  if (frame.role == FrameRole::kBlack) {
    return cv::Mat(projector_height, projector_width, CV_8UC1, cv::Scalar(0));
  }
  const uint8_t on = frame.inverted ? 0 : 255;
  const uint8_t off = 255 - on;
  cv::Mat image(projector_height, projector_width, CV_8UC1);
  if (frame.axis == PatternAxis::kX) {
    std::vector<uint8_t> row(projector_width);
    for (int x = 0; x < projector_width; ++x) {
      row[x] = PatternBit(frame.code, static_cast<uint32_t>(x), frame.bit) ? on : off;
    }
    for (int y = 0; y < projector_height; ++y) {
      std::copy(row.begin(), row.end(), image.ptr<uint8_t>(y));
    }
  } else {
    for (int y = 0; y < projector_height; ++y) {
      const uint8_t value =
          PatternBit(frame.code, static_cast<uint32_t>(y), frame.bit) ? on : off;
      image.row(y).setTo(cv::Scalar(value));
    }
  }
  return image;
}

std::vector<Pattern> GeneratePatterns(const PatternOptions& options) {
  std::vector<Pattern> patterns;
  for (const FrameInfo& frame : PatternFrames(options)) {
    patterns.push_back({frame, RenderPattern(frame, options.projector_width,
                                             options.projector_height, options.precompensate)});
  }
  return patterns;
}

FrameSetManifest MakePatternManifest(const PatternOptions& options, int camera_width,
                                     int camera_height) {
  FrameSetManifest manifest;
  manifest.camera_width = camera_width;
  manifest.camera_height = camera_height;
  manifest.projector_width = options.projector_width;
  manifest.projector_height = options.projector_height;
  manifest.frames = PatternFrames(options);
  manifest.Check();
  return manifest;
}

FrameSetManifest MakeOpenCvGrayCodeManifest(int projector_width, int projector_height,
                                            int camera_width, int camera_height,
                                            const std::vector<std::string>& files) {
  const int column_bits = BitsForSize(projector_width);
  const int row_bits = BitsForSize(projector_height);
  const size_t expected = 2 * static_cast<size_t>(column_bits + row_bits) + 2;
  SOPE_CHECK(files.size() == expected,
             "an OpenCV GrayCodePattern capture of a {}x{} projector has {} images, got {}",
             projector_width, projector_height, expected, files.size());
  FrameSetManifest manifest;
  manifest.camera_width = camera_width;
  manifest.camera_height = camera_height;
  manifest.projector_width = projector_width;
  manifest.projector_height = projector_height;
  size_t next = 0;
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    const int bits = axis == PatternAxis::kX ? column_bits : row_bits;
    for (int bit = bits - 1; bit >= 0; --bit) {
      for (bool inverted : {false, true}) {
        FrameInfo frame;
        frame.file = files[next++];
        frame.role = FrameRole::kCode;
        frame.axis = axis;
        frame.code = PatternCode::kGray;
        frame.bits = bits;
        frame.bit = bit;
        frame.inverted = inverted;
        manifest.frames.push_back(frame);
      }
    }
  }
  FrameInfo white, black;
  white.file = files[next++];
  white.role = FrameRole::kWhite;
  black.file = files[next++];
  black.role = FrameRole::kBlack;
  manifest.frames.push_back(white);
  manifest.frames.push_back(black);
  manifest.Check();
  return manifest;
}

}  // namespace sope
