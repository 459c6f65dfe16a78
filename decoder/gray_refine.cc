#include "decoder/gray_refine.h"

#include <algorithm>
#include <cmath>
#include <limits>
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

// The index of the lowest set bit of n > 0 (as __builtin_ctz), from the exponent of the
// float of n's lowest set bit (exact below 2^24): unlike the builtin, a loop of these
// vectorises.
inline int LowestSetBit(int n) {
  const float lowest = static_cast<float>(n & -n);
  return static_cast<int>((__builtin_bit_cast(uint32_t, lowest) >> 23) - 127u);
}

// Per pixel of a row of `cols` decoded values (`row`): the block whose centre the value is,
// or −1 — only block centres are refined (NaN, undecoded, is not one): the decoder puts
// pixels on a boundary (the flipping bit undecided) at k + ½, already sub-pixel, and a map
// refined before keeps its values (refining is idempotent); the ends of the code range
// have no bracketing edge —, and the coded bit (index from the lowest) that flips at the
// edge of the block (of block 1 for the others) that is not bit 0: from Gray word n − 1 to
// n the bit that flips is the lowest set bit of n, and of two consecutive blocks one is
// odd, so one of a block's two edges flips bit 0 and the other `other_bit`. One loop that
// GCC vectorises.
void CentreBlocks(const float* __restrict row, int cols, int blocks, float step,
                  int32_t* __restrict block_of, int32_t* __restrict other_bit) {
  const float half_offset = 0.5f * (step - 1.0f);  // block centre − block start
  for (int x = 0; x < cols; ++x) {
    const float position = (row[x] - half_offset) / step;  // block index
    // Nearest block (ties either way: a tie is half a block from a centre, skipped).
    const float nearest = std::floor(position + 0.5f);
    const bool centre = (std::abs(position - nearest) <= kCentreTolerance) &
                        (nearest >= 1.0f) & (nearest + 1.0f < static_cast<float>(blocks));
    const int block = centre ? static_cast<int>(nearest) : 1;
    block_of[x] = centre ? block : -1;
    other_bit[x] = std::max(LowestSetBit(block), LowestSetBit(block + 1));
  }
}

// Refines one row of `cols` pixels (`row`, in place) from CentreBlocks' blocks and the
// signed differences of bit 0 (`first`) and of each pixel's other flipping bit (`other`):
// pattern − inverse, or 2 · (pattern − threshold) without an inverse (half the swing; both
// edges of a block may be of either kind), NaN without either — positive when the pixel
// sees 1. One loop that GCC vectorises.
void RefineRow(const float* __restrict first, const float* __restrict other,
               const int32_t* __restrict block_of, int cols, float step,
               float* __restrict row) {
  for (int x = 0; x < cols; ++x) {
    const float value = row[x];
    const bool centre = block_of[x] >= 0;
    const int block = centre ? block_of[x] : 1;
    const int gray = static_cast<int>(GrayFromBinary(block));
    const int lower_bit = LowestSetBit(block), upper_bit = LowestSetBit(block + 1);
    const float lower_difference = lower_bit == 0 ? first[x] : other[x];
    const float upper_difference = upper_bit == 0 ? first[x] : other[x];
    // The margins, signed to be positive when the pixel sees the bit's value in the block.
    const float lower = ((gray >> lower_bit) & 1) ? lower_difference : -lower_difference;
    const float upper = ((gray >> upper_bit) & 1) ? upper_difference : -upper_difference;
    const bool bracketed = (lower >= 0.0f) & (upper >= 0.0f) & (lower + upper > 0.0f);
    const float refined = value + 0.5f * step * (lower - upper) / (lower + upper);
    row[x] = centre & bracketed ? refined : value;
  }
}

// Refines one axis of `coordinates` (CV_32FC1, NaN where undecoded) in place: row by row,
// CentreBlocks, then each coded bit's signed difference over the row (each frame read in
// order) kept where it is bit 0 or the pixel's other flipping bit, then RefineRow. (A table
// of every bit's differences, read per pixel at its two bits, made the last loop gather
// from it: slow where gathers are, and the table outgrew the L1 cache.)
template <typename Pixel>
void RefineRows(const std::vector<const cv::Mat*>& pattern,
                const std::vector<const cv::Mat*>& inverse, const cv::Mat& threshold, int lowest,
                int blocks, float step, cv::Mat* coordinates) {
  const int bits = static_cast<int>(pattern.size());
  const int cols = coordinates->cols;
  const int coded = bits - lowest;
  cv::parallel_for_(
      cv::Range(0, coordinates->rows),
      [&](const cv::Range& rows) {
        std::vector<float> scratch(2 * static_cast<size_t>(cols));
        float* __restrict first = scratch.data();
        float* __restrict other = scratch.data() + cols;
        std::vector<int32_t> block_of(cols), other_bit(cols);
        for (int y = rows.start; y < rows.end; ++y) {
          float* row = coordinates->ptr<float>(y);
          CentreBlocks(row, cols, blocks, step, block_of.data(), other_bit.data());
          const int32_t* __restrict wanted = other_bit.data();
          std::fill(other, other + cols, std::numeric_limits<float>::quiet_NaN());
          const float* threshold_row = threshold.empty() ? nullptr : threshold.ptr<float>(y);
          for (int k = 0; k < coded; ++k) {
            // Bit k's difference at every x (difference(x)), into `first` for bit 0 and into
            // `other` where it is the pixel's other flipping bit.
            const auto keep = [&](auto difference) {
              if (k == 0) {
                for (int x = 0; x < cols; ++x) first[x] = difference(x);
              } else {
                for (int x = 0; x < cols; ++x) other[x] = wanted[x] == k ? difference(x) : other[x];
              }
            };
            const int bit = lowest + k;
            if (pattern[bit] == nullptr || (inverse[bit] == nullptr && threshold_row == nullptr)) {
              keep([](int) { return std::numeric_limits<float>::quiet_NaN(); });
            } else if (inverse[bit] != nullptr) {
              const Pixel* __restrict p = pattern[bit]->ptr<Pixel>(y);
              const Pixel* __restrict q = inverse[bit]->ptr<Pixel>(y);
              keep([p, q](int x) { return static_cast<float>(p[x]) - static_cast<float>(q[x]); });
            } else {
              const Pixel* __restrict p = pattern[bit]->ptr<Pixel>(y);
              keep([p, threshold_row](int x) {
                return 2.0f * (static_cast<float>(p[x]) - threshold_row[x]);
              });
            }
          }
          RefineRow(first, other, block_of.data(), cols, step, row);
        }
      },
      // Stripes of rows, so that each allocates its scratch once.
      std::max(1, coordinates->rows / 16));
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
  // A block with a neighbour on both sides needs three.
  if (blocks < 3) return;
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
