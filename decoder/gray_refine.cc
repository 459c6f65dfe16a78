#include "decoder/gray_refine.h"

#include <cmath>
#include <opencv2/core.hpp>
#include <vector>

#include "core/error.h"
#include "projector/patterns.h"

namespace sope {
namespace internal {
namespace {

// A decoded value within this many blocks of a block centre is a centre (the
// decoder's values are exact table entries; refined values are almost never
// that close).
constexpr float kCentreTolerance = 1e-4f;

// RefineAxis's per-pixel work over the rows of `coordinates`, for frames of type Pixel:
// each row's frame pointers taken once, then per pixel the margins of the bits that flip
// at the edges of its block.
template <typename Pixel>
void RefineRows(const std::vector<const cv::Mat*>& pattern,
                const std::vector<const cv::Mat*>& inverse, const cv::Mat& threshold, int lowest,
                int blocks, float step, cv::Mat* coordinates) {
  const int bits = static_cast<int>(pattern.size());
  const float half_offset = 0.5f * (step - 1.0f);  // block centre − block start
  cv::parallel_for_(cv::Range(0, coordinates->rows), [&](const cv::Range& rows) {
    std::vector<const Pixel*> pattern_row(bits, nullptr), inverse_row(bits, nullptr);
    for (int y = rows.start; y < rows.end; ++y) {
      for (int bit = lowest; bit < bits; ++bit) {
        pattern_row[bit] = pattern[bit] ? pattern[bit]->ptr<Pixel>(y) : nullptr;
        inverse_row[bit] = inverse[bit] ? inverse[bit]->ptr<Pixel>(y) : nullptr;
      }
      const float* threshold_row = threshold.empty() ? nullptr : threshold.ptr<float>(y);
      // Signed margin of `bit` at x: positive when the pixel sees the bit's value `on`. A
      // bit decided against the threshold has half the swing of one against its inverse;
      // both edges of a block may be of either kind, so the threshold margin is doubled.
      const auto margin = [&](int bit, bool on, int x) -> float {
        if (pattern_row[bit] == nullptr) return -1.0f;
        float difference;
        const float p = static_cast<float>(pattern_row[bit][x]);
        if (inverse_row[bit] != nullptr) {
          difference = p - static_cast<float>(inverse_row[bit][x]);
        } else if (threshold_row != nullptr) {
          difference = 2.0f * (p - threshold_row[x]);
        } else {
          return -1.0f;
        }
        return on ? difference : -difference;
      };
      float* row = coordinates->ptr<float>(y);
      for (int x = 0; x < coordinates->cols; ++x) {
        const float value = row[x];
        if (!std::isfinite(value)) continue;
        const float position = (value - half_offset) / step;  // block index
        // Nearest block (ties either way: a tie is half a block from a centre, skipped).
        const int block = static_cast<int>(std::floor(position + 0.5f));
        // Only block centres are refined: the decoder puts pixels on a boundary (the
        // flipping bit undecided) at k + ½, already sub-pixel, and a map refined before
        // keeps its values (refining is idempotent).
        if (std::abs(position - block) > kCentreTolerance) continue;
        if (block <= 0 || block + 1 >= blocks) continue;
        const uint32_t gray = GrayFromBinary(block);
        // The single bit that flips at each edge of the block: from Gray word n − 1 to n
        // the bit that flips is the lowest set bit of n.
        const int lower_bit = __builtin_ctz(static_cast<uint32_t>(block)) + lowest;
        const int upper_bit = __builtin_ctz(static_cast<uint32_t>(block + 1)) + lowest;
        const float lower = margin(lower_bit, (gray >> (lower_bit - lowest)) & 1u, x);
        const float upper = margin(upper_bit, (gray >> (upper_bit - lowest)) & 1u, x);
        if (!(lower >= 0.0f) || !(upper >= 0.0f) || lower + upper <= 0.0f) continue;
        row[x] = value + 0.5f * step * (lower - upper) / (lower + upper);
      }
    }
  });
}

// Refines one axis of `coordinates` (CV_32FC1, NaN where undecoded) in place.
void RefineAxis(const FrameSet& frames, PatternAxis axis, float step, cv::Mat* coordinates) {
  const FrameSetManifest& manifest = frames.manifest;
  if (!manifest.HasAxis(axis) || manifest.AxisCode(axis) != PatternCode::kGray) return;
  if (manifest.HasPhaseAxis(axis)) return;  // Gray + phase: already sub-pixel
  const int bits = manifest.AxisBits(axis);
  const int lowest = manifest.AxisLowestBit(axis);
  const int size = axis == PatternAxis::kX ? manifest.projector_width : manifest.projector_height;
  const int blocks = (size + (1 << lowest) - 1) >> lowest;  // coded blocks on this axis
  // Per coded bit: the pattern frame and what it is compared with (inverse, or
  // threshold).
  std::vector<const cv::Mat*> pattern(bits, nullptr), inverse(bits, nullptr);
  for (int bit = lowest; bit < bits; ++bit) {
    if (const auto index = manifest.FindCode(axis, bit, false))
      pattern[bit] = &frames.Image(*index);
    if (const auto index = manifest.FindCode(axis, bit, true)) inverse[bit] = &frames.Image(*index);
  }
  // The threshold (white + black) / 2, only when some bit has no inverse.
  bool all_inverses = true;
  for (int bit = lowest; bit < bits; ++bit) all_inverses &= inverse[bit] != nullptr;
  cv::Mat threshold;
  const auto white = manifest.Find(FrameRole::kWhite), black = manifest.Find(FrameRole::kBlack);
  if (!all_inverses && white && black) {
    cv::addWeighted(frames.Image(*white), 0.5, frames.Image(*black), 0.5, 0.0, threshold, CV_32F);
  }
  const bool sixteen = frames.images.front().depth() == CV_16U;
  if (sixteen) {
    RefineRows<uint16_t>(pattern, inverse, threshold, lowest, blocks, step, coordinates);
  } else {
    RefineRows<uint8_t>(pattern, inverse, threshold, lowest, blocks, step, coordinates);
  }
}

}  // namespace
}  // namespace internal

std::string ToString(GraySubpixel mode) {
  switch (mode) {
    case GraySubpixel::kOff:
      return "off";
    case GraySubpixel::kEdges:
      return "edges";
  }
  return "?";
}

GraySubpixel GraySubpixelFromString(const std::string& text) {
  if (text == "off") return GraySubpixel::kOff;
  if (text == "edges") return GraySubpixel::kEdges;
  SOPE_THROW("unknown Gray sub-pixel mode '{}' (expected off or edges)", text);
}

void RefineGraySubpixel(const FrameSet& frames, CorrespondenceMap* map) {
  SOPE_CHECK(map != nullptr, "RefineGraySubpixel: no map");
  SOPE_CHECK(map->width() == frames.manifest.camera_width &&
                 map->height() == frames.manifest.camera_height,
             "RefineGraySubpixel: the map is {}x{} but the frames are {}x{}", map->width(),
             map->height(), frames.manifest.camera_width, frames.manifest.camera_height);
  if (map->HasX()) internal::RefineAxis(frames, PatternAxis::kX, map->step_x, &map->proj_x);
  if (map->HasY()) internal::RefineAxis(frames, PatternAxis::kY, map->step_y, &map->proj_y);
}

}  // namespace sope
