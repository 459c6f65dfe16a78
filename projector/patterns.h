// Stripe patterns for time-multiplexed structured light: Gray code and plain binary, for
// projector columns (x), rows (y) or both, with optional inverse frames and white/black
// references. The frame roles are those of the frame-set manifest (core/frame_set.h).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "core/frame_set.h"

namespace sope {

enum class PatternAxes { kX, kY, kXY };
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

  // Throws sope::Error naming the invalid value.
  void Check() const;
};

struct Pattern {
  FrameInfo info;  // role/axis/bit; `file` is the suggested name ("frame_07.png")
  cv::Mat image;   // CV_8UC1, projector size, 0 or 255
};

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
// the most significant down, each followed by its inverse when requested.
std::vector<Pattern> GeneratePatterns(const PatternOptions& options);
// The image of one frame (white, black or a code bit) at the given projector size.
cv::Mat RenderPattern(const FrameInfo& frame, int projector_width, int projector_height);
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
