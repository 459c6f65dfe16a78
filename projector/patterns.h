// Stripe patterns for time-multiplexed structured light: Gray code and plain binary, for
// projector columns (x), rows (y) or both, with optional inverse frames and white/black
// references. The frame roles are those of the frame-set manifest (core/frame_set.h).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "core/frame_set.h"
#include "core/projector_response.h"

namespace sope {

enum class PatternAxes { kX, kY, kXY };
// Stripes: Gray or binary code (PatternOptions::code). Phase: N-step phase-shift groups at
// several periods, unwrapped hierarchically (temporal phase unwrapping). GrayPhase: a Gray
// code whose finest block is one period wide (plus, optionally, one complementary bit half
// a period wide) and one phase-shift group at that period.
enum class PatternFamily { kStripes, kPhase, kGrayPhase };
std::string ToString(PatternFamily family);
// "gray" and "binary" (stripes), "phase", "gray+phase"; sets `code` for stripes.
PatternFamily PatternFamilyFromString(const std::string& text, PatternCode* code);
std::string ToString(PatternAxes axes);
PatternAxes PatternAxesFromString(const std::string& text);  // "x", "y", "xy"

struct PatternOptions {
  int projector_width = 1024;  // pixels
  int projector_height = 768;  // pixels
  PatternAxes axes = PatternAxes::kXY;
  PatternCode code = PatternCode::kGray;
  // Add the inverse of every code frame (robust per-bit decisions, twice the frames).
  bool inverted = true;
  // Add a white and a black frame (shadow mask, colour, threshold without inverses).
  bool white_black = true;
  // Omit this many least-significant bits: the decoded coordinate then has a step of
  // 2^skip_low_bits projector pixels (useful when the camera cannot resolve fine stripes).
  int skip_low_bits = 0;
  PatternFamily family = PatternFamily::kStripes;
  // kPhase: periods in projector pixels, any order, used on every coded axis; the coarsest
  // must be ≥ the projector size on each axis (absolute). Empty: per axis the axis size,
  // then 1/8 of the previous while ≥ kMinAutoPeriod, at most 3 groups.
  std::vector<double> periods;
  // kGrayPhase: the period (a power of two, projector pixels) and whether to add the
  // complementary Gray bit half a period wide (guards the period boundaries).
  double period = 16.0;
  bool complementary_bit = true;
  // Phase shifts per group: 2π·k / steps, k = 0 … steps − 1 (≥ 3).
  int steps = 4;
  // Pre-compensation: each sinusoid value I is shown as R⁻¹(I), so that a projector with
  // response R shows the contract's sinusoid (identity: no compensation).
  ProjectorResponse precompensate;

  // Throws sope::Error naming the invalid value.
  void Check() const;
};

struct Pattern {
  FrameInfo info;  // role/axis/bit; `file` is the suggested name ("frame_07.png")
  cv::Mat image;   // CV_8UC1, projector size, 0 or 255 (stripes) or a sinusoid
};

// Smallest automatic period (PatternOptions::periods empty), projector pixels.
constexpr double kMinAutoPeriod = 8.0;
// The periods GeneratePatterns uses on an axis of `size` pixels, coarsest first.
std::vector<double> PhasePeriodsFor(const PatternOptions& options, int size);
// One line for reports: "Gray code, axes xy, inverses", "phase shift, axes x, periods
// 1024/128/16 px, 4 steps", "Gray code + phase shift at 16 px, axes xy, 4 steps".
std::string DescribePatterns(const PatternOptions& options);

// Gray code: neighbouring values differ in exactly one bit.
inline uint32_t GrayFromBinary(uint32_t value) { return value ^ (value >> 1); }
inline uint32_t BinaryFromGray(uint32_t gray) {
  gray ^= gray >> 16;
  gray ^= gray >> 8;
  gray ^= gray >> 4;
  gray ^= gray >> 2;
  gray ^= gray >> 1;
  return gray;
}
// The bit `bit` (0 = LSB) that projector coordinate `coordinate` shows.
inline bool PatternBit(PatternCode code, uint32_t coordinate, int bit) {
  const uint32_t word = code == PatternCode::kGray ? GrayFromBinary(coordinate) : coordinate;
  return (word >> bit) & 1u;
}

// The sequence in display order: white, black, then per axis (x before y) the bits from
// the most significant down, each followed by its inverse when requested; then (phase
// families) the phase groups of that axis, coarsest first, shifts in increasing order.
std::vector<Pattern> GeneratePatterns(const PatternOptions& options);
// The image of one frame (white, black, a code bit or a sinusoid) at the given projector
// size. A sinusoid is I(u) = ½·(1 + cos(2π·u/period − shift)) at the pixel centres u,
// shown as round(255 · R⁻¹(I)) with R = `precompensate`.
cv::Mat RenderPattern(const FrameInfo& frame, int projector_width, int projector_height,
                      const ProjectorResponse& precompensate = {});
// Manifest describing GeneratePatterns(options) captured by a camera of the given size.
FrameSetManifest MakePatternManifest(const PatternOptions& options, int camera_width,
                                     int camera_height);

// The manifest of a capture made with OpenCV's cv::structured_light::GrayCodePattern:
// `files` in OpenCV's order — column bits from the most significant, each pattern followed
// by its inverse, then the row bits likewise, then white, then black.
FrameSetManifest MakeOpenCvGrayCodeManifest(int projector_width, int projector_height,
                                            int camera_width, int camera_height,
                                            const std::vector<std::string>& files);

}  // namespace sope
