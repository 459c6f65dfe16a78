#include "projector/patterns.h"

#include <fmt/format.h>

#include "core/error.h"

namespace sope {
namespace {

constexpr int kMaxProjectorSize = 1 << 15;

void AppendAxis(const PatternOptions& options, PatternAxis axis, std::vector<FrameInfo>* frames) {
  const int size = axis == PatternAxis::kX ? options.projector_width : options.projector_height;
  const int bits = BitsForSize(size);
  for (int bit = bits - 1; bit >= options.skip_low_bits; --bit) {
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
  SOPE_CHECK(inverted || white_black,
             "patterns need inverse frames or white/black references to be decodable");
}

cv::Mat RenderPattern(const FrameInfo& frame, int projector_width, int projector_height) {
  SOPE_CHECK(projector_width > 0 && projector_height > 0, "invalid projector size {}x{}",
             projector_width, projector_height);
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
    patterns.push_back(
        {frame, RenderPattern(frame, options.projector_width, options.projector_height)});
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
