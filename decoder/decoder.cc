#include "decoder/decoder.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>
#include <type_traits>
#include <utility>
#include <vector>

#if defined(__AVX512F__)
#include <immintrin.h>
#endif

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "decoder/chunk_workers.h"
#include "decoder/code_consistency.h"
#include "decoder/decoder_internal.h"
#include "decoder/gray_refine.h"
#include "decoder/phase_decoder.h"
#include "decoder/speckle_filter.h"
#include "projector/patterns.h"

namespace sope {
namespace internal {

namespace {
std::atomic<bool> portable_kernels_for_testing{false};
}  // namespace

bool UsePortableKernelsForTesting() {
  return portable_kernels_for_testing.load(std::memory_order_relaxed);
}
void SetPortableKernelsForTesting(bool portable) { portable_kernels_for_testing = portable; }

namespace {

// Pixels decoded together: every frame is read once per chunk, the per-chunk state
// (code words, margins, contrast) stays in L1/L2 while all frames stream past it. 2048:
// ~8% fewer cycles per decode of the statue than 4096 (perf, bench/decode_bench), 1024 more.
constexpr int kChunkPixels = 2048;
// kRobust: the direct/global split uses the pattern/inverse pairs of this many of the
// highest-frequency (lowest) bits of each axis. Two, because Gray-code stripe edges of
// different bits never coincide, so the max/min over two bits sees every pixel inside a
// stripe even where the camera blurs the finest one; not more, because the global light
// under wider stripes is no longer half of its full value (Nayar et al. 2006 need high
// frequencies) and the max/min would pick up that imbalance.
constexpr int kDirectGlobalBitsPerAxis = 2;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
// Software prefetch (PrefetchNextChunk): one chunk ahead, issued every block of pixels,
// into all cache levels (__builtin_prefetch locality 3). Measured on the statue set
// (bench/decode_bench): ~25 % faster than relying on the hardware prefetchers.
constexpr size_t kCacheLineBytes = 64;
constexpr int kPrefetchAheadPixels = kChunkPixels;
constexpr int kPrefetchBlockPixels = 256;
constexpr int kPrefetchLocality = 3;
// FinishPixelsPortable resolves stripe boundaries in blocks of this many pixels, skipping
// blocks without candidates (most of a scan: background, shadow, stripe interiors).
constexpr int kBoundaryBlock = 64;
constexpr int kAxisX = static_cast<int>(PatternAxis::kX);
constexpr int kAxisY = static_cast<int>(PatternAxis::kY);
// A pixel's weak bit is resolved to a stripe boundary only when its decided bits clear
// this many times the bit threshold (AxisCoordinate). Measured on the real captures
// (tests/real_data_decode_test: 2× keeps the pixels resolved so as consistent with their
// neighbours as OpenCV's own pixels on the statue, 1.7 points less on the dark, speckled
// kibekibe paper; 3× closes half that gap but loses 1% of the lit pixels of the virtual
// rig's darker scenes).
constexpr int kSolidMarginFactor = 2;
constexpr int kHigh = 0;  // code planes
constexpr int kLow = 1;

// The kernels below walk their n pixels in blocks of kPrefetchBlockPixels and first
// prefetch the same block of the next chunk of every frame they read. The hardware
// prefetchers stop at 4 KiB page boundaries, and with one page per frame and chunk they
// would restart cold on each of the ~44 streams; issuing the prefetches interleaved with
// the work (not as a burst) keeps the core's miss buffers from filling up. Blocks span
// several cache lines so that the inner loops run their vector bodies. Prefetches never
// fault, so running past the end of a frame is harmless. (Plain loops rather than a
// helper taking a lambda: through a closure GCC loses __restrict and stops vectorising.)
template <typename Pixel, size_t kStreams>
inline void PrefetchNextChunk(int block, const std::array<const Pixel*, kStreams>& streams) {
  constexpr int kLinePixels = static_cast<int>(kCacheLineBytes / sizeof(Pixel));
  for (const Pixel* stream : streams) {
    for (int line = 0; line < kPrefetchBlockPixels; line += kLinePixels) {
      __builtin_prefetch(stream + kPrefetchAheadPixels + block + line, /*rw=*/0, kPrefetchLocality);
    }
  }
}

inline int BlockEnd(int block, int n) { return std::min(block + kPrefetchBlockPixels, n); }

template <typename Pixel>
struct PixelTraits;
template <>
struct PixelTraits<uint8_t> {
  using Wide = int16_t;  // holds 2·p − (w + b) and 2·|p − p̄|
  static constexpr double kLevelsPerGreyLevel = 1.0;
};
template <>
struct PixelTraits<uint16_t> {
  using Wide = int32_t;
  static constexpr double kLevelsPerGreyLevel = 257.0;
};

// Margins are kept in grey levels when every bit has an inverse, and in half grey levels
// (doubled) when some bit is decided against the threshold, so that 2|p − p̄| and
// |2p − (w + b)| = 2|p − threshold| compare on one scale.
int MarginScale(const DecodePlan& plan) { return plan.any_threshold_bit ? 2 : 1; }

// Option thresholds converted to image levels (integers compare exactly: m ≥ t ⇔
// m ≥ ⌈t⌉ for integer m).
struct Thresholds {
  int min_contrast = 0;
  int min_bit_margin = 0;  // in levels / MarginScale
  // min_relative_bit_contrast × margin scale: per-pixel threshold = this × contrast.
  float relative_bit_margin = 0.0f;
  int margin_scale = 1;
  float min_direct = 0.0f;
  float robust_margin = 0.0f;
  float black_level = 0.0f;
};

struct Outputs {
  float* proj[2] = {nullptr, nullptr};  // nullptr when the axis is not coded
  uint8_t* mask = nullptr;
  float* confidence = nullptr;
};

// One bit on a pixel's code, weak and margin values (AccumulateInverseBit and
// AccumulateInverseBitGroup); diff_out: |p − p̄|.
template <typename Pixel, typename Margin, int kScale>
inline void InverseBitStep(Pixel a, Pixel b, Margin threshold, uint8_t* code, uint8_t* weak,
                           Margin* margin, Pixel* diff_out) {
  const Pixel diff = static_cast<Pixel>(std::max(a, b) - std::min(a, b));
  const Margin scaled = static_cast<Margin>(kScale * diff);
  const bool undecided = scaled < threshold;
  *code = static_cast<uint8_t>((*code << 1) | (a > b));
  *weak = static_cast<uint8_t>((*weak << 1) | undecided);
  *margin = std::min(*margin, undecided ? std::numeric_limits<Margin>::max() : scaled);
  *diff_out = diff;
}

// Code words are accumulated 8 bits per plane (Workspace::code), so that every operation
// of the per-bit loops is on bytes.
//
// code ← 2·code + [p > p̄]; weak ← 2·weak + [kScale·|p − p̄| < min_margin];
// margin ← min(margin, kScale·|p − p̄|) over the decided (not weak) bits; optionally
// max_diff ← max(max_diff, |p − p̄|) as the contrast when there are no white/black frames.
// kPerPixelThreshold false: min_margin[0] holds one threshold for all pixels (no relative
// threshold), which keeps the hot loop to its two streams.
template <typename Pixel, typename Margin, int kScale, bool kTrackMaxDiff,
          bool kPerPixelThreshold = true>
void AccumulateInverseBit(const Pixel* __restrict pattern, const Pixel* __restrict inverse, int n,
                          const Margin* __restrict min_margin, uint8_t* __restrict code,
                          uint8_t* __restrict weak, Margin* __restrict margin,
                          Pixel* __restrict max_diff) {
  const Margin uniform_margin = min_margin[0];
  for (int block = 0; block < n; block += kPrefetchBlockPixels) {
    PrefetchNextChunk<Pixel, 2>(block, {pattern, inverse});
    for (int i = block, end = BlockEnd(block, n); i < end; ++i) {
      Pixel diff = 0;
      InverseBitStep<Pixel, Margin, kScale>(pattern[i], inverse[i],
                                            kPerPixelThreshold ? min_margin[i] : uniform_margin,
                                            &code[i], &weak[i], &margin[i], &diff);
      if constexpr (kTrackMaxDiff) max_diff[i] = std::max(max_diff[i], diff);
    }
  }
}

// Two or four consecutive bits of one code plane in one pass (pattern0 / inverse0 the most
// significant; kFour: also pattern2/3): the same operations as that many
// AccumulateInverseBit calls, in the same order, so the same code, weak and margin bytes,
// but the chunk's state is loaded and stored once per group instead of once per bit (the
// bit passes were bound by those loads and stores more than by the frames streaming in).
template <bool kFour, typename Pixel, typename Margin, int kScale, bool kTrackMaxDiff,
          bool kPerPixelThreshold>
void AccumulateInverseBitGroup(const Pixel* __restrict pattern0, const Pixel* __restrict inverse0,
                               const Pixel* __restrict pattern1, const Pixel* __restrict inverse1,
                               const Pixel* __restrict pattern2, const Pixel* __restrict inverse2,
                               const Pixel* __restrict pattern3, const Pixel* __restrict inverse3,
                               int n, const Margin* __restrict min_margin,
                               uint8_t* __restrict code, uint8_t* __restrict weak,
                               Margin* __restrict margin, Pixel* __restrict max_diff) {
  const Margin uniform_margin = min_margin[0];
  for (int block = 0; block < n; block += kPrefetchBlockPixels) {
    if constexpr (kFour) {
      PrefetchNextChunk<Pixel, 8>(block, {pattern0, inverse0, pattern1, inverse1, pattern2,
                                          inverse2, pattern3, inverse3});
    } else {
      PrefetchNextChunk<Pixel, 4>(block, {pattern0, inverse0, pattern1, inverse1});
    }
    for (int i = block, end = BlockEnd(block, n); i < end; ++i) {
      const Margin threshold = kPerPixelThreshold ? min_margin[i] : uniform_margin;
      uint8_t c = code[i], w = weak[i];
      Margin m = margin[i];
      Pixel d0 = 0, d1 = 0, d2 = 0, d3 = 0;
      InverseBitStep<Pixel, Margin, kScale>(pattern0[i], inverse0[i], threshold, &c, &w, &m, &d0);
      InverseBitStep<Pixel, Margin, kScale>(pattern1[i], inverse1[i], threshold, &c, &w, &m, &d1);
      if constexpr (kFour) {
        InverseBitStep<Pixel, Margin, kScale>(pattern2[i], inverse2[i], threshold, &c, &w, &m,
                                              &d2);
        InverseBitStep<Pixel, Margin, kScale>(pattern3[i], inverse3[i], threshold, &c, &w, &m,
                                              &d3);
      }
      code[i] = c;
      weak[i] = w;
      margin[i] = m;
      if constexpr (kTrackMaxDiff) {
        max_diff[i] = std::max(std::max(max_diff[i], std::max(d0, d1)), std::max(d2, d3));
      }
    }
  }
}

// Against the per-pixel threshold (w + b) / 2 in doubled units: d = 2p − (w + b);
// code ← 2·code + [d > 0]; weak ← 2·weak + [|d| < min_margin];
// margin ← min(margin, |d|) = 2·|p − threshold| over the decided bits.
template <typename Pixel, typename Wide>
void AccumulateThresholdBit(const Pixel* __restrict pattern,
                            const Wide* __restrict white_plus_black, int n,
                            const Wide* __restrict min_margin, uint8_t* __restrict code,
                            uint8_t* __restrict weak, Wide* __restrict margin) {
  for (int block = 0; block < n; block += kPrefetchBlockPixels) {
    PrefetchNextChunk<Pixel, 1>(block, {pattern});
    for (int i = block, end = BlockEnd(block, n); i < end; ++i) {
      const Wide d = static_cast<Wide>(2 * static_cast<Wide>(pattern[i]) - white_plus_black[i]);
      const Wide magnitude = static_cast<Wide>(d < 0 ? -d : d);
      const bool undecided = magnitude < min_margin[i];
      code[i] = static_cast<uint8_t>((code[i] << 1) | (d > 0));
      weak[i] = static_cast<uint8_t>((weak[i] << 1) | undecided);
      margin[i] = std::min(margin[i], undecided ? std::numeric_limits<Wide>::max() : magnitude);
    }
  }
}

// The robust rules per bit against per-pixel integer bounds (RobustBounds, precomputed).
template <typename Pixel, typename Wide>
void AccumulateRobustBit(const Pixel* __restrict pattern, const Pixel* __restrict inverse, int n,
                         const Wide* __restrict direct_minus_slack,
                         const Wide* __restrict global_plus_slack,
                         const uint8_t* __restrict direct_dominates,
                         const uint8_t* __restrict too_dark, const Pixel* __restrict min_margin,
                         uint8_t* __restrict code, uint8_t* __restrict weak,
                         Pixel* __restrict margin) {
  for (int block = 0; block < n; block += kPrefetchBlockPixels) {
    PrefetchNextChunk<Pixel, 2>(block, {pattern, inverse});
    for (int i = block, end = BlockEnd(block, n); i < end; ++i) {
      const Pixel a = pattern[i];
      const Pixel b = inverse[i];
      const uint8_t outcome =
          ClassifyRobustBit<Wide>(a, b, direct_minus_slack[i], global_plus_slack[i],
                                  direct_dominates[i] != 0, too_dark[i] != 0);
      code[i] = static_cast<uint8_t>((code[i] << 1) | (outcome & kRobustValue));
      const Pixel diff = static_cast<Pixel>(std::max(a, b) - std::min(a, b));
      const bool undecided = (outcome & kRobustUnknown) | (diff < min_margin[i]);
      weak[i] = static_cast<uint8_t>((weak[i] << 1) | undecided);
      margin[i] = std::min(margin[i], undecided ? std::numeric_limits<Pixel>::max() : diff);
    }
  }
}

// contrast = white − black; white_plus_black = white + black (twice the threshold).
template <typename Pixel, typename Wide>
void ComputeWhiteBlack(const Pixel* __restrict white, const Pixel* __restrict black, int n,
                       Wide* __restrict contrast, Wide* __restrict white_plus_black) {
  for (int block = 0; block < n; block += kPrefetchBlockPixels) {
    PrefetchNextChunk<Pixel, 2>(block, {white, black});
    for (int i = block, end = BlockEnd(block, n); i < end; ++i) {
      contrast[i] = static_cast<Wide>(static_cast<Wide>(white[i]) - black[i]);
      white_plus_black[i] = static_cast<Wide>(static_cast<Wide>(white[i]) + black[i]);
    }
  }
}

// Per-pixel bit thresholds in margin units: max(floor, ⌈relative · contrast⌉), or the floor
// alone without a contrast (no white/black frames). `relative` already carries the margin
// scale.
template <typename Margin, typename Wide>
void ComputeBitThresholds(int n, const Wide* __restrict contrast, int floor, float relative,
                          Margin* __restrict threshold) {
  const Margin floor_margin =
      static_cast<Margin>(std::min<int>(floor, std::numeric_limits<Margin>::max()));
  if (contrast == nullptr || relative <= 0.0f) {
    std::fill_n(threshold, n, floor_margin);
    return;
  }
  constexpr float kMax = static_cast<float>(std::numeric_limits<Margin>::max());
  for (int i = 0; i < n; ++i) {
    const float scaled = std::min(std::ceil(relative * static_cast<float>(contrast[i])), kMax);
    threshold[i] = std::max(floor_margin, static_cast<Margin>(std::max(scaled, 0.0f)));
  }
}

template <typename Pixel>
void AccumulateMinMax(const Pixel* __restrict frame, int n, Pixel* __restrict level_max,
                      Pixel* __restrict level_min) {
  for (int block = 0; block < n; block += kPrefetchBlockPixels) {
    PrefetchNextChunk<Pixel, 1>(block, {frame});
    for (int i = block, end = BlockEnd(block, n); i < end; ++i) {
      level_max[i] = std::max(level_max[i], frame[i]);
      level_min[i] = std::min(level_min[i], frame[i]);
    }
  }
}

// Per-pixel integer bounds of the robust rules from the max/min over the high-frequency
// frames; clamped to [−1, max + 1], which keeps every comparison with a pixel exact.
template <typename Pixel, typename Wide>
void ComputeRobustBounds(int n, const Pixel* __restrict level_max,
                         const Pixel* __restrict level_min, const Pixel* __restrict ambient,
                         const Thresholds& thresholds, Wide* __restrict direct_minus_slack,
                         Wide* __restrict global_plus_slack, uint8_t* __restrict direct_dominates,
                         uint8_t* __restrict too_dark) {
  constexpr float kLowest = -1.0f;
  constexpr float kHighest = static_cast<float>(std::numeric_limits<Pixel>::max()) + 1.0f;
  const float black_level = thresholds.black_level;
  const float min_direct = thresholds.min_direct;
  const float robust_margin = thresholds.robust_margin;
  for (int i = 0; i < n; ++i) {
    // The light that is not the projector's (the black frame: the room's light, the
    // camera's offset) is in every frame alike: it is neither direct nor global light of
    // the projector. The split is made without it, and the bounds, which the frames'
    // values are compared with, carry it again.
    const float offset = ambient != nullptr ? static_cast<float>(ambient[i]) : 0.0f;
    const DirectGlobal light =
        SeparateDirectGlobal(static_cast<float>(level_max[i]) - offset,
                             static_cast<float>(level_min[i]) - offset, black_level);
    const RobustBounds<float> bounds = RobustBoundsOf(light, min_direct, robust_margin);
    const float low = std::ceil(bounds.direct_minus_slack + offset);
    const float high = std::floor(bounds.global_plus_slack + offset);
    direct_minus_slack[i] = static_cast<Wide>(std::min(std::max(low, kLowest), kHighest));
    global_plus_slack[i] = static_cast<Wide>(std::min(std::max(high, kLowest), kHighest));
    direct_dominates[i] = bounds.direct_dominates;
    too_dark[i] = bounds.too_dark;
  }
}

// How one axis turns code words into coordinates, and treats bits whose margin is below
// the threshold ("weak" bits).
struct AxisFinish {
  bool gray = true;  // Gray code (else plain binary)
  // Largest coordinate difference of two neighbouring code words: the coordinate step.
  float max_neighbour_gap = 1.0f;
  // The code words' coordinates (BlockOfWord and CoordinateOfBlock: computed, as a table
  // read would be a gather per pixel and axis): the lowest bit and the projector size (0 and
  // 1 for an uncoded axis).
  uint32_t lowest_bit = 0;
  uint32_t projector_size = 1;
};

AxisFinish MakeAxisFinish(const AxisPlan& axis) {
  AxisFinish finish;
  finish.gray = axis.code == PatternCode::kGray;
  // Block centres of neighbouring codes are one block apart (the last, partial block's
  // centre is closer); a little slack for float rounding.
  finish.max_neighbour_gap = static_cast<float>(1 << axis.lowest_bit) * 1.001f;
  if (axis.coded) {
    finish.lowest_bit = static_cast<uint32_t>(axis.lowest_bit);
    finish.projector_size = static_cast<uint32_t>(axis.projector_size);
  } else {
    finish.gray = false;  // words stay 0, whose coordinate is 0
  }
  return finish;
}

// Bit casts (std::bit_cast is C++20; GCC and Clang have the builtin, which unlike memcpy
// keeps the decoder's loops vectorisable).
inline uint32_t FloatBits(float value) { return __builtin_bit_cast(uint32_t, value); }
inline float FloatFromBits(uint32_t bits) { return __builtin_bit_cast(float, bits); }

// The coded block of a code word: Gray → binary (`gray_mask` all ones) or the word itself
// (0, a binary code). Words have at most 16 bits.
inline uint32_t BlockOfWord(uint32_t word, uint32_t gray_mask) {
  uint32_t binary = word;  // BinaryFromGray for 16-bit words
  binary ^= binary >> 8;
  binary ^= binary >> 4;
  binary ^= binary >> 2;
  binary ^= binary >> 1;
  return word ^ ((binary ^ word) & gray_mask);
}

// The projector coordinate of a block: its centre on the projector, NaN beyond it; in
// plain integer operations so that the caller's loop vectorises (GCC 12 does not
// vectorise a select on the comparison). `nan_bits` are kNaN's. An uncoded axis passes
// size 1 and lowest bit 0: its words stay 0, whose coordinate is then 0.
inline float CoordinateOfBlock(uint32_t block, uint32_t lowest_bit, uint32_t projector_size,
                               uint32_t nan_bits) {
  const uint32_t start = block << lowest_bit;
  const uint32_t end = std::min(start + (1u << lowest_bit), projector_size);
  const float centre = 0.5f * static_cast<float>(start + end - 1);
  // All ones when start < projector_size (both below 2^17).
  const uint32_t on_projector =
      ~static_cast<uint32_t>(static_cast<int32_t>(projector_size - 1 - start) >> 31);
  return FloatFromBits((FloatBits(centre) & on_projector) | (nan_bits & ~on_projector));
}

// The projector coordinate of a code word (MakeCoordinateLut's table is made of these).
inline float CoordinateOfWord(uint32_t word, uint32_t gray_mask, uint32_t lowest_bit,
                              uint32_t projector_size, uint32_t nan_bits) {
  return CoordinateOfBlock(BlockOfWord(word, gray_mask), lowest_bit, projector_size, nan_bits);
}

// FinishPixels' second pass over n pixels (a function of its own, called only for the
// blocks that hold candidates; its loop runs from 0, as GCC 12 does not vectorise the
// masked stores of a loop starting elsewhere): the boundary reading of the candidates
// (weak bits, enough contrast, solid decided bits), kept where it resolves — the midpoint
// of the words with the weak bits 0 and 1 (the word's own coordinate on an axis without
// weak bits: 0.5 (x + x) = x).
template <typename Margin, typename Wide>
__attribute__((noinline)) void ResolveBoundaries(
    int n, const uint8_t* __restrict code_x_high, const uint8_t* __restrict code_x_low,
    const uint8_t* __restrict code_y_high, const uint8_t* __restrict code_y_low,
    const uint8_t* __restrict weak_x_high, const uint8_t* __restrict weak_x_low,
    const uint8_t* __restrict weak_y_high, const uint8_t* __restrict weak_y_low,
    const AxisFinish& axis_x, const AxisFinish& axis_y, const Wide* __restrict contrast,
    const Margin* __restrict margin, int min_contrast, int solid_margin, float margin_scale,
    float* __restrict out_x, float* __restrict out_y, uint8_t* __restrict mask,
    float* __restrict confidence) {
  const uint32_t gray_x = axis_x.gray ? ~0u : 0u, gray_y = axis_y.gray ? ~0u : 0u;
  const bool boundary_x = axis_x.gray, boundary_y = axis_y.gray;
  const float max_gap_x = axis_x.max_neighbour_gap, max_gap_y = axis_y.max_neighbour_gap;
  const uint32_t low_x = axis_x.lowest_bit, size_x = axis_x.projector_size;
  const uint32_t low_y = axis_y.lowest_bit, size_y = axis_y.projector_size;
  const uint32_t nan_bits = FloatBits(kNaN);
  const auto coordinate_x = [&](uint32_t word) {
    return CoordinateOfWord(word, gray_x, low_x, size_x, nan_bits);
  };
  const auto coordinate_y = [&](uint32_t word) {
    return CoordinateOfWord(word, gray_y, low_y, size_y, nan_bits);
  };
  for (int i = 0; i < n; ++i) {
    const uint32_t word_x = (uint32_t{code_x_high[i]} << 8) | code_x_low[i];
    const uint32_t word_y = (uint32_t{code_y_high[i]} << 8) | code_y_low[i];
    const uint32_t weak_x = (uint32_t{weak_x_high[i]} << 8) | weak_x_low[i];
    const uint32_t weak_y = (uint32_t{weak_y_high[i]} << 8) | weak_y_low[i];
    const float ax = coordinate_x(word_x & ~weak_x), bx = coordinate_x(word_x | weak_x);
    const float ay = coordinate_y(word_y & ~weak_y), by = coordinate_y(word_y | weak_y);
    const float mid_x = 0.5f * (ax + bx), mid_y = 0.5f * (ay + by);
    const float gap_x = std::abs(ax - bx), gap_y = std::abs(ay - by);
    // Neighbours (false for NaN); an axis without weak bits is fine as it is.
    const bool ok_x = (weak_x == 0) | (boundary_x & (gap_x > 0.0f) & (gap_x <= max_gap_x));
    const bool ok_y = (weak_y == 0) | (boundary_y & (gap_y > 0.0f) & (gap_y <= max_gap_y));
    const int c = contrast[i];
    const int m = margin[i];
    const bool resolved = ((weak_x | weak_y) != 0) & (c >= min_contrast) & (m >= solid_margin) &
                          ok_x & ok_y & (mid_x == mid_x) & (mid_y == mid_y);
    out_x[i] = resolved ? mid_x : out_x[i];
    out_y[i] = resolved ? mid_y : out_y[i];
    mask[i] = resolved ? uint8_t{255} : mask[i];
    const float relative =
        static_cast<float>(m) / (margin_scale * static_cast<float>(std::max(c, 1)));
    const float halved = 0.5f * std::min(relative, 1.0f);
    confidence[i] = resolved ? halved : confidence[i];
  }
}

// Validity, coordinates and confidence of n pixels from their code words, weak-bit masks
// and weakest decided margins (in units of margin_scale × grey levels). Confidence is that
// margin relative to the contrast, halved for a pixel resolved at a boundary.
//
// Pixels with weak bits (margin below the threshold on some axis): for a Gray code the
// pixel may sit on the boundary between two neighbouring projector columns (rows) c and
// c + 1, whose code words differ in exactly one bit — the one stripe edge there,
// undecidable because the pixel straddles it. Both words are formed from the decided bits;
// when they decode to neighbours the coordinate is their midpoint — the boundary itself,
// within half a step of the truth — and otherwise the pixel is invalid: a weak bit
// anywhere else is never guessed. Only `solid` pixels are resolved, whose decided bits all
// clear kSolidMarginFactor × the bit threshold: where light is scarce a decided bit may be
// wrong too, and the boundary would be a guess. A binary code flips a run of bits at once
// at many boundaries, where noise may decide some of them either way; its weak bits always
// invalidate the pixel.
//
// Two branch-free passes that vectorise: the first takes each pixel's own word and marks
// the boundary candidates (`candidate`, scratch of n bytes); the second (ResolveBoundaries)
// visits the blocks of kBoundaryBlock pixels that hold some.
template <typename Margin, typename Wide>
void FinishPixelsPortable(
    int n, const uint8_t* __restrict code_x_high, const uint8_t* __restrict code_x_low,
    const uint8_t* __restrict code_y_high, const uint8_t* __restrict code_y_low,
    const uint8_t* __restrict weak_x_high, const uint8_t* __restrict weak_x_low,
    const uint8_t* __restrict weak_y_high, const uint8_t* __restrict weak_y_low,
    const AxisFinish& axis_x, const AxisFinish& axis_y, const Wide* __restrict contrast,
    const Margin* __restrict margin, int min_contrast, int solid_margin, float margin_scale,
    float* __restrict out_x, float* __restrict out_y, uint8_t* __restrict mask,
    float* __restrict confidence, uint8_t* __restrict candidate) {
  const uint32_t gray_x = axis_x.gray ? ~0u : 0u, gray_y = axis_y.gray ? ~0u : 0u;
  const uint32_t low_x = axis_x.lowest_bit, size_x = axis_x.projector_size;
  const uint32_t low_y = axis_y.lowest_bit, size_y = axis_y.projector_size;
  const uint32_t nan_bits = FloatBits(kNaN);
  for (int i = 0; i < n; ++i) {
    const float x = CoordinateOfWord((uint32_t{code_x_high[i]} << 8) | code_x_low[i], gray_x,
                                     low_x, size_x, nan_bits);
    const float y = CoordinateOfWord((uint32_t{code_y_high[i]} << 8) | code_y_low[i], gray_y,
                                     low_y, size_y, nan_bits);
    const int c = contrast[i];
    const int m = margin[i];
    const bool no_weak =
        (weak_x_high[i] | weak_x_low[i] | weak_y_high[i] | weak_y_low[i]) == 0;
    // x != x: NaN, the code lies beyond the projector.
    const bool valid = (c >= min_contrast) & no_weak & (x == x) & (y == y);
    out_x[i] = valid ? x : kNaN;
    out_y[i] = valid ? y : kNaN;
    mask[i] = static_cast<uint8_t>(valid ? 255 : 0);
    const float relative =
        static_cast<float>(m) / (margin_scale * static_cast<float>(std::max(c, 1)));
    // valid ? min(relative, 1) : 0 — relative is finite and ≥ 0, so the product is exact
    // (GCC 12 vectorises the product and not the select).
    confidence[i] = std::min(relative, 1.0f) * (valid ? 1.0f : 0.0f);
    candidate[i] = static_cast<uint8_t>(!no_weak & (c >= min_contrast) & (m >= solid_margin));
  }
  for (int begin = 0; begin < n; begin += kBoundaryBlock) {
    const int count = std::min(kBoundaryBlock, n - begin);
    uint8_t any = 0;
    for (int i = 0; i < count; ++i) any |= candidate[begin + i];
    if (any == 0) continue;
    ResolveBoundaries(count, code_x_high + begin, code_x_low + begin, code_y_high + begin,
                      code_y_low + begin, weak_x_high + begin, weak_x_low + begin,
                      weak_y_high + begin, weak_y_low + begin, axis_x, axis_y,
                      contrast + begin, margin + begin, min_contrast, solid_margin,
                      margin_scale, out_x + begin, out_y + begin, mask + begin,
                      confidence + begin);
  }
}

// One run of pixels for FinishPixels: the code and weak planes ([axis][kHigh / kLow]),
// contrast and weakest margin per pixel, the thresholds, and the outputs.
template <typename Margin, typename Wide>
struct FinishRun {
  int n = 0;
  const uint8_t* code[2][2] = {};
  const uint8_t* weak[2][2] = {};
  const Wide* contrast = nullptr;
  const Margin* margin = nullptr;
  int min_contrast = 0, solid_margin = 0;
  float margin_scale = 1.0f;
  float* out_x = nullptr;
  float* out_y = nullptr;
  uint8_t* mask = nullptr;
  float* confidence = nullptr;
  // The same run without its first `count` pixels.
  FinishRun Skip(int count) const {
    FinishRun rest = *this;
    rest.n = n - count;
    for (int axis = 0; axis < 2; ++axis) {
      for (int plane = 0; plane < 2; ++plane) {
        rest.code[axis][plane] += count;
        rest.weak[axis][plane] += count;
      }
    }
    rest.contrast += count;
    rest.margin += count;
    rest.out_x += count;
    rest.out_y += count;
    rest.mask += count;
    rest.confidence += count;
    return rest;
  }
};

// The AVX-512 kernel reads the boundary in one pass: when an axis has a single weak bit,
// its two words are the pixel's own and the one with that bit flipped (two weak bits on an
// axis never give neighbours: Gray neighbours differ in one bit), and flipping Gray bit k
// flips binary bits k … 0, so the other word's block is the pixel's own block XOR
// (2^(k+1) − 1): one Gray → binary conversion per axis serves both words.
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__) && \
    defined(__AVX512DQ__)
// GCC 12 flags its own intrinsics headers (the masked zero-extensions) as maybe-uninitialised
// under -march=native: a known false positive.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
// 16 values as 32-bit integers (zero- or sign-extended as their type).
template <typename T>
inline __m512i LoadEpi32(const T* p) {
  if constexpr (std::is_same_v<T, uint8_t>) {
    return _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
  } else if constexpr (std::is_same_v<T, uint16_t>) {
    return _mm512_cvtepu16_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(p)));
  } else if constexpr (std::is_same_v<T, int16_t>) {
    return _mm512_cvtepi16_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(p)));
  } else {
    static_assert(std::is_same_v<T, int32_t>);
    return _mm512_loadu_si512(p);
  }
}

// FinishPixelsPortable 16 pixels per step with AVX-512; returns the number of pixels done
// (a multiple of 16), the rest is left to the portable loop. The same operations in the
// same order, so the same bits: GCC vectorises the portable loop over 64 byte lanes at
// once and spills (3× slower), or not at all for some margin types.
template <typename Margin, typename Wide>
int FinishPixelsAvx512(const FinishRun<Margin, Wide>& run, const AxisFinish& axis_x,
                       const AxisFinish& axis_y) {
  const int n = run.n;
  const uint8_t* code_x_high = run.code[kAxisX][kHigh];
  const uint8_t* code_x_low = run.code[kAxisX][kLow];
  const uint8_t* code_y_high = run.code[kAxisY][kHigh];
  const uint8_t* code_y_low = run.code[kAxisY][kLow];
  const uint8_t* weak_x_high = run.weak[kAxisX][kHigh];
  const uint8_t* weak_x_low = run.weak[kAxisX][kLow];
  const uint8_t* weak_y_high = run.weak[kAxisY][kHigh];
  const uint8_t* weak_y_low = run.weak[kAxisY][kLow];
  const Wide* contrast = run.contrast;
  const Margin* margin = run.margin;
  float* out_x = run.out_x;
  float* out_y = run.out_y;
  uint8_t* mask = run.mask;
  float* confidence = run.confidence;
  const int min_contrast = run.min_contrast, solid_margin = run.solid_margin;
  const float margin_scale = run.margin_scale;
  const __m512i gray_x = _mm512_set1_epi32(axis_x.gray ? -1 : 0);
  const __m512i gray_y = _mm512_set1_epi32(axis_y.gray ? -1 : 0);
  const __m512 max_gap_x = _mm512_set1_ps(axis_x.max_neighbour_gap);
  const __m512 max_gap_y = _mm512_set1_ps(axis_y.max_neighbour_gap);
  const __m128i low_x = _mm_cvtsi32_si128(static_cast<int>(axis_x.lowest_bit));
  const __m128i low_y = _mm_cvtsi32_si128(static_cast<int>(axis_y.lowest_bit));
  const __m512i step_x = _mm512_set1_epi32(static_cast<int>(1u << axis_x.lowest_bit));
  const __m512i step_y = _mm512_set1_epi32(static_cast<int>(1u << axis_y.lowest_bit));
  const __m512i size_x = _mm512_set1_epi32(static_cast<int>(axis_x.projector_size));
  const __m512i size_y = _mm512_set1_epi32(static_cast<int>(axis_y.projector_size));
  const __m512i one = _mm512_set1_epi32(1);
  const __m512i min_contrast_v = _mm512_set1_epi32(min_contrast);
  const __m512i solid_margin_v = _mm512_set1_epi32(solid_margin);
  const __m512 half = _mm512_set1_ps(0.5f);
  const __m512 one_f = _mm512_set1_ps(1.0f);
  const __m512 nan = _mm512_set1_ps(kNaN);
  const __m512 scale = _mm512_set1_ps(margin_scale);
  const __mmask16 gray_x_k = axis_x.gray ? 0xFFFF : 0, gray_y_k = axis_y.gray ? 0xFFFF : 0;
  const auto block_of_word = [](__m512i word, __m512i gray) {
    __m512i binary = _mm512_xor_si512(word, _mm512_srli_epi32(word, 8));
    binary = _mm512_xor_si512(binary, _mm512_srli_epi32(binary, 4));
    binary = _mm512_xor_si512(binary, _mm512_srli_epi32(binary, 2));
    binary = _mm512_xor_si512(binary, _mm512_srli_epi32(binary, 1));
    // word ^ ((binary ^ word) & gray): 0x78 = A ^ (B & C).
    return _mm512_ternarylogic_epi32(word, _mm512_xor_si512(binary, word), gray, 0x78);
  };
  const auto coordinate_of_block = [&](__m512i block, __m128i low, __m512i step,
                                       __m512i size) {
    const __m512i start = _mm512_sll_epi32(block, low);
    const __m512i end = _mm512_min_epu32(_mm512_add_epi32(start, step), size);
    const __m512 centre = _mm512_mul_ps(
        half, _mm512_cvtepi32_ps(_mm512_sub_epi32(_mm512_add_epi32(start, end), one)));
    return _mm512_mask_blend_ps(_mm512_cmplt_epu32_mask(start, size), nan, centre);
  };
  // (weak << 1) − [weak ≠ 0], on a Gray axis.
  const auto flip_of_weak = [&](__m512i weak, __m512i gray) {
    const __m512i doubled = _mm512_slli_epi32(weak, 1);
    return _mm512_and_si512(
        _mm512_mask_sub_epi32(doubled, _mm512_test_epi32_mask(weak, weak), doubled, one), gray);
  };
  const auto ok_axis = [](__m512i weak, __mmask16 gray, __m512 gap, __m512 max_gap,
                          __m512i one_v) {
    const __mmask16 none = _mm512_testn_epi32_mask(weak, weak);
    const __mmask16 single =
        _mm512_testn_epi32_mask(weak, _mm512_sub_epi32(weak, one_v));
    const __mmask16 neighbours = _mm512_cmp_ps_mask(gap, _mm512_setzero_ps(), _CMP_GT_OQ) &
                                 _mm512_cmp_ps_mask(gap, max_gap, _CMP_LE_OQ);
    return static_cast<__mmask16>(none | (gray & single & neighbours));
  };
  const __m512 sign = _mm512_set1_ps(-0.0f);
  const __m512 zero_f = _mm512_setzero_ps();
  int i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m512i c = LoadEpi32(contrast + i);
    const __mmask16 lit = _mm512_cmpge_epi32_mask(c, min_contrast_v);
    if (lit == 0) {
      // Shadow and background (a third of a typical scan): nothing decodes; the outputs the
      // full step below gives such pixels (NaN, mask 0, confidence +0).
      _mm512_storeu_ps(out_x + i, nan);
      _mm512_storeu_ps(out_y + i, nan);
      _mm_storeu_si128(reinterpret_cast<__m128i*>(mask + i), _mm_setzero_si128());
      _mm512_storeu_ps(confidence + i, zero_f);
      continue;
    }
    const __m512i word_x =
        _mm512_or_si512(_mm512_slli_epi32(LoadEpi32(code_x_high + i), 8), LoadEpi32(code_x_low + i));
    const __m512i word_y =
        _mm512_or_si512(_mm512_slli_epi32(LoadEpi32(code_y_high + i), 8), LoadEpi32(code_y_low + i));
    const __m512i weak_x =
        _mm512_or_si512(_mm512_slli_epi32(LoadEpi32(weak_x_high + i), 8), LoadEpi32(weak_x_low + i));
    const __m512i weak_y =
        _mm512_or_si512(_mm512_slli_epi32(LoadEpi32(weak_y_high + i), 8), LoadEpi32(weak_y_low + i));
    const __m512i block_x = block_of_word(word_x, gray_x);
    const __m512i block_y = block_of_word(word_y, gray_y);
    const __m512 x = coordinate_of_block(block_x, low_x, step_x, size_x);
    const __m512 y = coordinate_of_block(block_y, low_y, step_y, size_y);
    const __m512i m = LoadEpi32(margin + i);
    const __mmask16 no_weak =
        _mm512_testn_epi32_mask(_mm512_or_si512(weak_x, weak_y), _mm512_or_si512(weak_x, weak_y));
    const __mmask16 valid = lit & no_weak & _mm512_cmp_ps_mask(x, x, _CMP_ORD_Q) &
                            _mm512_cmp_ps_mask(y, y, _CMP_ORD_Q);
    // Boundary candidates; most steps have none (background, shadow, stripe interiors).
    __mmask16 resolved = static_cast<__mmask16>(~no_weak) & lit &
                         _mm512_cmpge_epi32_mask(m, solid_margin_v);
    __m512 mid_x = nan, mid_y = nan;
    if (resolved != 0) {
      const __m512 other_x = coordinate_of_block(
          _mm512_xor_si512(block_x, flip_of_weak(weak_x, gray_x)), low_x, step_x, size_x);
      const __m512 other_y = coordinate_of_block(
          _mm512_xor_si512(block_y, flip_of_weak(weak_y, gray_y)), low_y, step_y, size_y);
      mid_x = _mm512_mul_ps(half, _mm512_add_ps(x, other_x));
      mid_y = _mm512_mul_ps(half, _mm512_add_ps(y, other_y));
      const __m512 gap_x = _mm512_andnot_ps(sign, _mm512_sub_ps(x, other_x));
      const __m512 gap_y = _mm512_andnot_ps(sign, _mm512_sub_ps(y, other_y));
      resolved &= ok_axis(weak_x, gray_x_k, gap_x, max_gap_x, one) &
                  ok_axis(weak_y, gray_y_k, gap_y, max_gap_y, one) &
                  _mm512_cmp_ps_mask(mid_x, mid_x, _CMP_ORD_Q) &
                  _mm512_cmp_ps_mask(mid_y, mid_y, _CMP_ORD_Q);
    }
    _mm512_storeu_ps(out_x + i,
                     _mm512_mask_blend_ps(valid, _mm512_mask_blend_ps(resolved, nan, mid_x), x));
    _mm512_storeu_ps(out_y + i,
                     _mm512_mask_blend_ps(valid, _mm512_mask_blend_ps(resolved, nan, mid_y), y));
    const __mmask16 decoded = valid | resolved;
    _mm_storeu_si128(reinterpret_cast<__m128i*>(mask + i), _mm_movm_epi8(decoded));
    const __m512 relative = _mm512_div_ps(
        _mm512_cvtepi32_ps(m), _mm512_mul_ps(scale, _mm512_cvtepi32_ps(_mm512_max_epi32(c, one))));
    const __m512 capped = _mm512_maskz_mov_ps(decoded, _mm512_min_ps(relative, one_f));
    _mm512_storeu_ps(confidence + i, _mm512_mask_mul_ps(capped, resolved, capped, half));
  }
  return i;
}
#pragma GCC diagnostic pop
#endif

// The run's pixels: the AVX-512 kernel where it applies, the portable loops for the rest.
// `candidate`: scratch of run.n bytes.
template <typename Margin, typename Wide>
void FinishPixels(const FinishRun<Margin, Wide>& run, const AxisFinish& axis_x,
                  const AxisFinish& axis_y, uint8_t* candidate) {
  int done = 0;
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__) && \
    defined(__AVX512DQ__)
  if (!internal::UsePortableKernelsForTesting()) done = FinishPixelsAvx512(run, axis_x, axis_y);
#endif
  const FinishRun<Margin, Wide> rest = run.Skip(done);
  FinishPixelsPortable(rest.n, rest.code[kAxisX][kHigh], rest.code[kAxisX][kLow],
                       rest.code[kAxisY][kHigh], rest.code[kAxisY][kLow],
                       rest.weak[kAxisX][kHigh], rest.weak[kAxisX][kLow],
                       rest.weak[kAxisY][kHigh], rest.weak[kAxisY][kLow], axis_x, axis_y,
                       rest.contrast, rest.margin, rest.min_contrast, rest.solid_margin,
                       rest.margin_scale, rest.out_x, rest.out_y, rest.mask, rest.confidence,
                       candidate);
}

// A run of n pixels from `begin` without its planes (the caller sets code and weak):
// contrast and margin point at the run's first pixel; outputs of an uncoded axis go to
// `discard` (n floats).
template <typename Margin, typename Wide>
FinishRun<Margin, Wide> MakeFinishRun(int n, const Wide* contrast, const Margin* margin,
                                      const Thresholds& thresholds, const Outputs& outputs,
                                      size_t begin, float* discard) {
  FinishRun<Margin, Wide> run;
  run.n = n;
  run.contrast = contrast;
  run.margin = margin;
  run.min_contrast = thresholds.min_contrast;
  run.solid_margin = kSolidMarginFactor * std::max(thresholds.min_bit_margin, 1);
  run.margin_scale = static_cast<float>(thresholds.margin_scale);
  run.out_x = outputs.proj[kAxisX] ? outputs.proj[kAxisX] + begin : discard;
  run.out_y = outputs.proj[kAxisY] ? outputs.proj[kAxisY] + begin : discard;
  run.mask = outputs.mask + begin;
  run.confidence = outputs.confidence + begin;
  return run;
}

// Per-thread scratch for one chunk.
template <typename Pixel>
struct Workspace {
  using Wide = typename PixelTraits<Pixel>::Wide;
  // Code word of each axis: [axis][kHigh] holds bits 8 and up, [axis][kLow] bits 0..7.
  alignas(64) uint8_t code[2][2][kChunkPixels];
  // Weak bits (margin below the threshold), laid out like `code`.
  alignas(64) uint8_t weak[2][2][kChunkPixels];
  alignas(64) Wide contrast[kChunkPixels];          // white − black (or max |p − p̄|)
  alignas(64) Wide white_plus_black[kChunkPixels];  // 2 × the threshold
  alignas(64) Pixel margin[kChunkPixels];           // min |p − p̄| (inverse-only sets)
  alignas(64) Pixel min_margin[kChunkPixels];       // per-pixel bit thresholds, same units
  alignas(64) Wide wide_min_margin[kChunkPixels];   // … in wide_margin's units, inverse bits
  alignas(64) Wide wide_min_margin_threshold[kChunkPixels];  // … threshold bits
  alignas(64) Wide wide_margin[kChunkPixels];       // min 2|p − p̄| or |2p − (w + b)|
  alignas(64) Pixel max_diff[kChunkPixels];
  alignas(64) Pixel level_max[kChunkPixels];
  alignas(64) Pixel level_min[kChunkPixels];
  alignas(64) Wide direct_minus_slack[kChunkPixels];  // kRobust bounds (RobustBounds)
  alignas(64) Wide global_plus_slack[kChunkPixels];
  alignas(64) uint8_t direct_dominates[kChunkPixels];
  alignas(64) uint8_t too_dark[kChunkPixels];
  alignas(64) float discard[kChunkPixels];  // coordinates of an axis that is not coded
  alignas(64) uint8_t candidate[kChunkPixels];  // FinishPixelsPortable's boundary candidates
};

template <typename Pixel>
class ChunkDecoder {
 public:
  using Wide = typename PixelTraits<Pixel>::Wide;

  ChunkDecoder(const DecodePlan& plan, const std::vector<const Pixel*>& frames,
               const Thresholds& thresholds, const Outputs& outputs)
      : plan_(plan),
        frames_(frames),
        thresholds_(thresholds),
        outputs_(outputs),
        finish_x_(MakeAxisFinish(plan.axes[kAxisX])),
        finish_y_(MakeAxisFinish(plan.axes[kAxisY])),
        workspace_(std::make_unique<Workspace<Pixel>>()) {}

  // Decodes pixels [begin, begin + n) of the (continuous) images.
  void Decode(size_t begin, int n) {
    Workspace<Pixel>& ws = *workspace_;
    std::memset(ws.code, 0, sizeof(ws.code));
    std::memset(ws.weak, 0, sizeof(ws.weak));
    const bool has_white_black = plan_.white >= 0 && plan_.black >= 0;
    if (has_white_black) ComputeContrast(begin, n);

    if (plan_.mode == BitDecision::kRobust) {
      EstimateDirectGlobal(begin, n);
      std::fill_n(ws.margin, n, std::numeric_limits<Pixel>::max());
      ComputeBitThresholds(n, has_white_black ? ws.contrast : nullptr, thresholds_.min_bit_margin,
                           thresholds_.relative_bit_margin, ws.min_margin);
      ForEachBit([&](uint8_t* code, uint8_t* weak, const BitFrames& bit) {
        AccumulateRobustBit(Frame(bit.pattern, begin), Frame(bit.inverse, begin), n,
                            ws.direct_minus_slack, ws.global_plus_slack, ws.direct_dominates,
                            ws.too_dark, ws.min_margin, code, weak, ws.margin);
      });
      if (!has_white_black) {
        for (int i = 0; i < n; ++i) ws.contrast[i] = ws.level_max[i] - ws.level_min[i];
      }
      Finish(begin, n, ws.margin);
    } else if (!plan_.any_threshold_bit) {
      // The hot path: every bit against its inverse, margins in the pixel type.
      std::fill_n(ws.margin, n, std::numeric_limits<Pixel>::max());
      ComputeBitThresholds(n, has_white_black ? ws.contrast : nullptr, thresholds_.min_bit_margin,
                           thresholds_.relative_bit_margin, ws.min_margin);
      if (has_white_black && thresholds_.relative_bit_margin > 0.0f) {
        AccumulateInverseBitGroups<false, true>(begin, n, nullptr);
      } else if (has_white_black) {
        AccumulateInverseBitGroups<false, false>(begin, n, nullptr);
      } else {
        std::fill_n(ws.max_diff, n, Pixel{0});
        AccumulateInverseBitGroups<true, true>(begin, n, ws.max_diff);
        for (int i = 0; i < n; ++i) ws.contrast[i] = ws.max_diff[i];
      }
      Finish(begin, n, ws.margin);
    } else {
      // Some bits against the threshold: margins in doubled units (MarginScale).
      std::fill_n(ws.wide_margin, n, std::numeric_limits<Wide>::max());
      // Doubled units: 2|p − p̄| ≥ 2·r·C for inverse bits, 2|p − t| ≥ r·C for threshold bits
      // (|p − t| is half of |p − p̄| for the same mix of light).
      ComputeBitThresholds(n, ws.contrast, thresholds_.min_bit_margin,
                           thresholds_.relative_bit_margin, ws.wide_min_margin);
      ComputeBitThresholds(n, ws.contrast, thresholds_.min_bit_margin,
                           0.5f * thresholds_.relative_bit_margin, ws.wide_min_margin_threshold);
      ForEachBit([&](uint8_t* code, uint8_t* weak, const BitFrames& bit) {
        if (bit.inverse >= 0) {
          AccumulateInverseBit<Pixel, Wide, 2, false>(Frame(bit.pattern, begin),
                                                      Frame(bit.inverse, begin), n,
                                                      ws.wide_min_margin, code, weak,
                                                      ws.wide_margin, nullptr);
        } else {
          AccumulateThresholdBit(Frame(bit.pattern, begin), ws.white_plus_black, n,
                                 ws.wide_min_margin_threshold, code, weak, ws.wide_margin);
        }
      });
      Finish(begin, n, ws.wide_margin);
    }
  }

 private:
  // The chunk of frame `index` that starts at pixel `begin`.
  const Pixel* Frame(int index, size_t begin) const { return frames_[index] + begin; }

  // Calls function(code plane, weak plane, bit) for every bit, most significant first: the
  // first (bits − 8) bits of an axis shift into its high planes, the last 8 into its low.
  template <typename Function>
  void ForEachBit(Function&& function) {
    for (int axis : {kAxisX, kAxisY}) {
      const std::vector<BitFrames>& bits = plan_.axes[axis].bits_msb_first;
      const size_t high_bits = bits.size() > 8 ? bits.size() - 8 : 0;
      for (size_t k = 0; k < bits.size(); ++k) {
        const int plane = k < high_bits ? kHigh : kLow;
        function(workspace_->code[axis][plane], workspace_->weak[axis][plane], bits[k]);
      }
    }
  }

  // Every bit of an inverse-only set (the hot path) in ForEachBit's order, four (or two)
  // consecutive bits of an axis that shift into the same code plane at once
  // (AccumulateInverseBitGroup: the same bytes as one bit at a time).
  template <bool kTrackMaxDiff, bool kPerPixelThreshold>
  void AccumulateInverseBitGroups(size_t begin, int n, Pixel* max_diff) {
    Workspace<Pixel>& ws = *workspace_;
    for (int axis : {kAxisX, kAxisY}) {
      const std::vector<BitFrames>& bits = plan_.axes[axis].bits_msb_first;
      const size_t high_bits = bits.size() > 8 ? bits.size() - 8 : 0;
      for (size_t k = 0; k < bits.size();) {
        const int plane = k < high_bits ? kHigh : kLow;
        const size_t left = (plane == kHigh ? high_bits : bits.size()) - k;
        uint8_t* code = ws.code[axis][plane];
        uint8_t* weak = ws.weak[axis][plane];
        const BitFrames* b = bits.data() + k;
        if (left == 1) {
          AccumulateInverseBit<Pixel, Pixel, 1, kTrackMaxDiff, kPerPixelThreshold>(
              Frame(b[0].pattern, begin), Frame(b[0].inverse, begin), n, ws.min_margin, code,
              weak, ws.margin, max_diff);
          k += 1;
          continue;
        }
        const bool four = left >= 4;
        const auto frame = [&](int j, bool pattern) {
          return j < (four ? 4 : 2) ? Frame(pattern ? b[j].pattern : b[j].inverse, begin)
                                    : nullptr;
        };
        const auto group = four ? &AccumulateInverseBitGroup<true, Pixel, Pixel, 1, kTrackMaxDiff,
                                                             kPerPixelThreshold>
                                : &AccumulateInverseBitGroup<false, Pixel, Pixel, 1,
                                                             kTrackMaxDiff, kPerPixelThreshold>;
        group(frame(0, true), frame(0, false), frame(1, true), frame(1, false), frame(2, true),
              frame(2, false), frame(3, true), frame(3, false), n, ws.min_margin, code, weak,
              ws.margin, max_diff);
        k += four ? 4 : 2;
      }
    }
  }

  void ComputeContrast(size_t begin, int n) {
    ComputeWhiteBlack(Frame(plan_.white, begin), Frame(plan_.black, begin), n, workspace_->contrast,
                      workspace_->white_plus_black);
  }

  void EstimateDirectGlobal(size_t begin, int n) {
    Workspace<Pixel>& ws = *workspace_;
    std::fill_n(ws.level_max, n, Pixel{0});
    std::fill_n(ws.level_min, n, std::numeric_limits<Pixel>::max());
    for (int index : plan_.direct_global_frames) {
      AccumulateMinMax(Frame(index, begin), n, ws.level_max, ws.level_min);
    }
    const Pixel* ambient = plan_.black >= 0 ? Frame(plan_.black, begin) : nullptr;
    ComputeRobustBounds(n, ws.level_max, ws.level_min, ambient, thresholds_,
                        ws.direct_minus_slack, ws.global_plus_slack, ws.direct_dominates,
                        ws.too_dark);
  }

  template <typename Margin>
  void Finish(size_t begin, int n, const Margin* margin) {
    Workspace<Pixel>& ws = *workspace_;
    auto run = MakeFinishRun(n, ws.contrast, margin, thresholds_, outputs_, begin, ws.discard);
    for (int axis : {kAxisX, kAxisY}) {
      for (int plane : {kHigh, kLow}) {
        run.code[axis][plane] = ws.code[axis][plane];
        run.weak[axis][plane] = ws.weak[axis][plane];
      }
    }
    FinishPixels(run, finish_x_, finish_y_, ws.candidate);
  }

  const DecodePlan& plan_;
  const std::vector<const Pixel*>& frames_;
  const Thresholds thresholds_;
  const Outputs outputs_;
  const AxisFinish finish_x_, finish_y_;
  std::unique_ptr<Workspace<Pixel>> workspace_;
};

// With a speckle filter (min_neighbours > 0), each worker filters its rows as it decodes
// them, while they are in the cache (BandedSpeckleFilter).
template <typename Pixel>
void DecodeAllPixels(const DecodePlan& plan, const std::vector<cv::Mat>& images,
                     const Thresholds& thresholds, const Outputs& outputs, int num_threads,
                     int min_neighbours, float tolerance, CorrespondenceMap* map) {
  std::vector<const Pixel*> frames;
  frames.reserve(images.size());
  for (const cv::Mat& image : images) frames.push_back(image.ptr<Pixel>());
  const size_t total = images.front().total();
  const size_t num_chunks = (total + kChunkPixels - 1) / kChunkPixels;
  const size_t num_workers = NumChunkWorkers(num_threads, num_chunks);
  // Workspaces are allocated here so that no worker can fail.
  std::vector<ChunkDecoder<Pixel>> decoders;
  decoders.reserve(num_workers);
  for (size_t w = 0; w < num_workers; ++w) decoders.emplace_back(plan, frames, thresholds, outputs);
  DecodeChunksAndFilter(total, kChunkPixels, num_workers, min_neighbours, tolerance, map,
                        [&](size_t worker, size_t begin, int n) {
                          decoders[worker].Decode(begin, n);
                        });
}

Thresholds MakeThresholds(const DecodePlan& plan, const DecoderOptions& options,
                          double levels_per_grey_level) {
  Thresholds thresholds;
  thresholds.min_contrast =
      static_cast<int>(std::ceil(options.min_contrast * levels_per_grey_level));
  thresholds.margin_scale = MarginScale(plan);
  thresholds.min_bit_margin = static_cast<int>(
      std::ceil(options.min_bit_contrast * levels_per_grey_level * thresholds.margin_scale));
  thresholds.relative_bit_margin =
      static_cast<float>(options.min_relative_bit_contrast * thresholds.margin_scale);
  thresholds.min_direct = static_cast<float>(options.min_bit_contrast * levels_per_grey_level);
  thresholds.robust_margin = static_cast<float>(options.robust_margin);
  thresholds.black_level = static_cast<float>(options.robust_black_level);
  return thresholds;
}

// Makes `image` a continuous image of this size and type that nobody else references,
// reusing its memory when it already is one.
void PrepareOutput(cv::Size size, int type, cv::Mat* image) {
  const bool shared = image->u != nullptr && image->u->refcount > 1;
  if (shared || !image->isContinuous() || image->isSubmatrix()) image->release();
  image->create(size, type);
}

// Files of a correspondence-map directory.
constexpr const char* kMapFormat = "sope-correspondence/1";
constexpr const char* kMapJson = "correspondence.json";
constexpr const char* kMaskFile = "mask.png";
constexpr const char* kConfidenceFile = "confidence.exr";
constexpr const char* kConfidencePng = "confidence.png";
// Hue range of ColorizeCoordinate, degrees: red (0) … magenta (300), so that both ends
// of the projector stay distinguishable (a full circle would wrap red to red).
constexpr float kMaxHueDeg = 300.0f;

std::string AxisFile(PatternAxis axis, const char* extension) {
  return fmt::format("proj_{}.{}", ToString(axis), extension);
}

void CheckMap(const CorrespondenceMap& map) {
  SOPE_CHECK(map.projector_width > 0 && map.projector_height > 0,
             "correspondence map: invalid projector size {}x{}", map.projector_width,
             map.projector_height);
  SOPE_CHECK(!map.mask.empty() && map.mask.type() == CV_8UC1,
             "correspondence map: the mask must be a non-empty CV_8UC1 image");
  SOPE_CHECK(map.HasX() || map.HasY(), "correspondence map: no coded axis");
  const cv::Size size = map.mask.size();
  for (const auto& [name, image] : {std::pair<const char*, const cv::Mat*>{"proj_x", &map.proj_x},
                                    {"proj_y", &map.proj_y},
                                    {"confidence", &map.confidence}}) {
    if (image == &map.confidence || !image->empty()) {
      SOPE_CHECK(image->type() == CV_32FC1 && image->size() == size,
                 "correspondence map: {} is {} {}x{}, expected CV_32FC1 of the mask size {}x{}",
                 name, cv::typeToString(image->type()), image->cols, image->rows, size.width,
                 size.height);
    }
  }
  SOPE_CHECK(map.step_x > 0.0f && map.step_y > 0.0f, "correspondence map: invalid steps {} {}",
             map.step_x, map.step_y);
}

cv::Mat ColorizeConfidence(const cv::Mat& confidence, const cv::Mat& mask) {
  cv::Mat levels;
  confidence.convertTo(levels, CV_8U, 255.0);
  cv::Mat colour;
  cv::applyColorMap(levels, colour, cv::COLORMAP_VIRIDIS);
  colour.setTo(cv::Scalar::all(0), mask == 0);
  return colour;
}

}  // namespace

namespace {

void CheckCodeLayout(int bits, int lowest_bit, int projector_size) {
  SOPE_CHECK(bits >= 1 && bits <= 16 && lowest_bit >= 0 && lowest_bit < bits && projector_size > 0,
             "invalid code layout: bits {}, lowest bit {}, projector size {}", bits, lowest_bit,
             projector_size);
}

}  // namespace

std::vector<float> MakeCoordinateLut(PatternCode code, int bits, int lowest_bit,
                                     int projector_size) {
  CheckCodeLayout(bits, lowest_bit, projector_size);
  const uint32_t gray_mask = code == PatternCode::kGray ? ~0u : 0u;
  const uint32_t nan_bits = FloatBits(kNaN);
  std::vector<float> lut(size_t{1} << (bits - lowest_bit));
  for (uint32_t word = 0; word < lut.size(); ++word) {
    lut[word] = CoordinateOfWord(word, gray_mask, static_cast<uint32_t>(lowest_bit),
                                 static_cast<uint32_t>(projector_size), nan_bits);
  }
  return lut;
}

DecodePlan MakeDecodePlan(const FrameSetManifest& manifest, const DecoderOptions& options) {
  DecodePlan plan;
  plan.mode = options.bit_decision;
  const auto index_or_none = [](std::optional<size_t> index) {
    return index ? static_cast<int>(*index) : -1;
  };
  plan.white = index_or_none(manifest.Find(FrameRole::kWhite));
  plan.black = index_or_none(manifest.Find(FrameRole::kBlack));
  const bool has_white_black = plan.white >= 0 && plan.black >= 0;
  SOPE_CHECK(plan.mode != BitDecision::kThreshold || has_white_black,
             "threshold decoding needs a white and a black frame; the set has {}",
             plan.white < 0 && plan.black < 0 ? "neither"
             : plan.white < 0                 ? "no white"
                                              : "no black");
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    if (!manifest.HasAxis(axis)) continue;
    AxisPlan& axis_plan = plan.axes[static_cast<int>(axis)];
    axis_plan.coded = true;
    axis_plan.projector_size =
        axis == PatternAxis::kX ? manifest.projector_width : manifest.projector_height;
    axis_plan.lowest_bit = manifest.AxisLowestBit(axis);
    axis_plan.code = manifest.AxisCode(axis);
    const int bits = manifest.AxisBits(axis);
    for (int bit = bits - 1; bit >= axis_plan.lowest_bit; --bit) {
      const std::optional<size_t> pattern = manifest.FindCode(axis, bit, false);
      const std::optional<size_t> inverse = manifest.FindCode(axis, bit, true);
      SOPE_CHECK(pattern.has_value(), "axis {} bit {}: no pattern frame", ToString(axis), bit);
      BitFrames frames;
      frames.pattern = static_cast<int>(*pattern);
      if (inverse && plan.mode != BitDecision::kThreshold)
        frames.inverse = static_cast<int>(*inverse);
      if (plan.mode == BitDecision::kRobust) {
        SOPE_CHECK(frames.inverse >= 0,
                   "robust decoding needs the inverse of every code frame "
                   "(direct/global separation); axis {} bit {} has none",
                   ToString(axis), bit);
      }
      if (frames.inverse < 0) {
        SOPE_CHECK(has_white_black,
                   "axis {} bit {} has no inverse frame and the set has no "
                   "white and black frames for a threshold",
                   ToString(axis), bit);
        plan.any_threshold_bit = true;
      }
      axis_plan.bits_msb_first.push_back(frames);
    }
    CheckCodeLayout(bits, axis_plan.lowest_bit, axis_plan.projector_size);
    if (plan.mode == BitDecision::kRobust) {
      const std::vector<BitFrames>& present = axis_plan.bits_msb_first;
      const size_t count = std::min<size_t>(kDirectGlobalBitsPerAxis, present.size());
      for (size_t k = present.size() - count; k < present.size(); ++k) {
        plan.direct_global_frames.push_back(present[k].pattern);
        plan.direct_global_frames.push_back(present[k].inverse);
      }
    }
  }
  return plan;
}

}  // namespace internal

std::string ToString(BitDecision mode) {
  switch (mode) {
    case BitDecision::kAuto: return "auto";
    case BitDecision::kThreshold: return "threshold";
    case BitDecision::kRobust: return "robust";
  }
  return "?";
}

BitDecision BitDecisionFromString(const std::string& text) {
  if (text == "auto") return BitDecision::kAuto;
  if (text == "threshold") return BitDecision::kThreshold;
  if (text == "robust") return BitDecision::kRobust;
  SOPE_THROW("unknown bit decision '{}' (expected auto, threshold or robust)", text);
}

void DecoderOptions::Check() const {
  SOPE_CHECK(std::isfinite(min_contrast) && min_contrast >= 0.0 && min_contrast <= 255.0,
             "min_contrast {} must be in [0, 255] grey levels", min_contrast);
  SOPE_CHECK(
      std::isfinite(min_bit_contrast) && min_bit_contrast >= 0.0 && min_bit_contrast <= 255.0,
      "min_bit_contrast {} must be in [0, 255] grey levels", min_bit_contrast);
  SOPE_CHECK(std::isfinite(min_relative_bit_contrast) && min_relative_bit_contrast >= 0.0 &&
                 min_relative_bit_contrast < 1.0,
             "min_relative_bit_contrast {} must be in [0, 1)", min_relative_bit_contrast);
  SOPE_CHECK(std::isfinite(robust_margin) && robust_margin >= 0.0 && robust_margin <= 10.0,
             "robust_margin {} must be in [0, 10]", robust_margin);
  SOPE_CHECK(
      std::isfinite(robust_black_level) && robust_black_level >= 0.0 && robust_black_level < 1.0,
      "robust_black_level {} must be in [0, 1)", robust_black_level);
  SOPE_CHECK(min_consistent_neighbours >= 0 && min_consistent_neighbours <= 8,
             "min_consistent_neighbours {} must be in 0..8", min_consistent_neighbours);
  SOPE_CHECK(std::isfinite(neighbour_tolerance_px) && neighbour_tolerance_px >= 0.0,
             "neighbour_tolerance_px {} must be ≥ 0", neighbour_tolerance_px);
  SOPE_CHECK(num_threads >= 1 && num_threads <= 1024, "num_threads {} must be in 1..1024",
             num_threads);
  SOPE_CHECK(bit_decision == BitDecision::kAuto || bit_decision == BitDecision::kThreshold ||
                 bit_decision == BitDecision::kRobust,
             "invalid bit_decision {}", static_cast<int>(bit_decision));
  SOPE_CHECK(gray_subpixel == GraySubpixel::kOff || gray_subpixel == GraySubpixel::kEdges,
             "invalid gray_subpixel {}", static_cast<int>(gray_subpixel));
  SOPE_CHECK(std::isfinite(consistency.min_contrast) && consistency.min_contrast >= 0.0 &&
                 consistency.min_contrast <= 255.0,
             "consistency.min_contrast {} must be in [0, 255] grey levels",
             consistency.min_contrast);
  SOPE_CHECK(std::isfinite(consistency.min_relative_contrast) &&
                 consistency.min_relative_contrast >= 0.0 &&
                 consistency.min_relative_contrast <= 1.0,
             "consistency.min_relative_contrast {} must be in [0, 1]",
             consistency.min_relative_contrast);
  SOPE_CHECK(consistency.window_radius >= 1 && consistency.window_radius <= 32,
             "consistency.window_radius {} must be in 1..32", consistency.window_radius);
  SOPE_CHECK(consistency.min_neighbours >= 1 &&
                 consistency.min_neighbours <=
                     (2 * consistency.window_radius + 1) * (2 * consistency.window_radius + 1) - 1,
             "consistency.min_neighbours {} must be in 1..(window side² − 1)",
             consistency.min_neighbours);
  SOPE_CHECK(std::isfinite(consistency.search_radius_px) && consistency.search_radius_px > 0.0,
             "consistency.search_radius_px {} must be > 0", consistency.search_radius_px);
  SOPE_CHECK(std::isfinite(consistency.strong_bit_factor) && consistency.strong_bit_factor >= 1.0,
             "consistency.strong_bit_factor {} must be >= 1", consistency.strong_bit_factor);
  SOPE_CHECK(consistency.max_average_radius >= 0 && consistency.max_average_radius <= 16,
             "consistency.max_average_radius {} must be in 0..16",
             consistency.max_average_radius);
  SOPE_CHECK(consistency.passes >= 1 && consistency.passes <= 100,
             "consistency.passes {} must be in 1..100", consistency.passes);
  phase.Check();
}

size_t CorrespondenceMap::CountValid() const {
  return mask.empty() ? 0 : static_cast<size_t>(cv::countNonZero(mask));
}

CorrespondenceMap Decode(const FrameSet& frame_set, const DecoderOptions& options) {
  CorrespondenceMap map;
  Decode(frame_set, options, &map);
  return map;
}

void Decode(const FrameSet& frame_set, const DecoderOptions& options, CorrespondenceMap* map) {
  SOPE_CHECK(map != nullptr, "Decode: no output map");
  if (frame_set.manifest.HasPhase()) return DecodePhase(frame_set, options, map);
  options.Check();
  frame_set.Check();
  const FrameSetManifest& manifest = frame_set.manifest;
  const internal::DecodePlan plan = internal::MakeDecodePlan(manifest, options);

  // The kernels walk every image as one flat array.
  std::vector<cv::Mat> images;
  images.reserve(frame_set.images.size());
  for (const cv::Mat& image : frame_set.images) {
    images.push_back(image.isContinuous() ? image : image.clone());
  }

  map->projector_width = manifest.projector_width;
  map->projector_height = manifest.projector_height;
  map->step_x = map->step_y = 1.0f;
  const cv::Size size(manifest.camera_width, manifest.camera_height);
  internal::Outputs outputs;
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    const internal::AxisPlan& axis_plan = plan.axes[static_cast<int>(axis)];
    cv::Mat& coordinate = axis == PatternAxis::kX ? map->proj_x : map->proj_y;
    if (!axis_plan.coded) {
      coordinate.release();
      continue;
    }
    internal::PrepareOutput(size, CV_32FC1, &coordinate);
    outputs.proj[static_cast<int>(axis)] = coordinate.ptr<float>();
    (axis == PatternAxis::kX ? map->step_x : map->step_y) =
        static_cast<float>(1 << axis_plan.lowest_bit);
  }
  internal::PrepareOutput(size, CV_8UC1, &map->mask);
  internal::PrepareOutput(size, CV_32FC1, &map->confidence);
  outputs.mask = map->mask.ptr<uint8_t>();
  outputs.confidence = map->confidence.ptr<float>();

  if (images.front().depth() == CV_8U) {
    internal::DecodeAllPixels<uint8_t>(
        plan, images,
        internal::MakeThresholds(plan, options,
                                 internal::PixelTraits<uint8_t>::kLevelsPerGreyLevel),
        outputs, options.num_threads, options.min_consistent_neighbours,
        static_cast<float>(options.neighbour_tolerance_px), map);
  } else {
    internal::DecodeAllPixels<uint16_t>(
        plan, images,
        internal::MakeThresholds(plan, options,
                                 internal::PixelTraits<uint16_t>::kLevelsPerGreyLevel),
        outputs, options.num_threads, options.min_consistent_neighbours,
        static_cast<float>(options.neighbour_tolerance_px), map);
  }
  if (options.consistency.enabled) FillFromConsistentNeighbours(frame_set, options, map);
  if (options.gray_subpixel == GraySubpixel::kEdges) RefineGraySubpixel(frame_set, map);
}

cv::Mat ColorizeCoordinate(const cv::Mat& coordinate, int projector_size) {
  SOPE_CHECK(coordinate.type() == CV_32FC1, "ColorizeCoordinate: expected a CV_32FC1 image, got {}",
             cv::typeToString(coordinate.type()));
  SOPE_CHECK(projector_size > 0, "ColorizeCoordinate: invalid projector size {}", projector_size);
  const float hue_per_pixel =
      internal::kMaxHueDeg / static_cast<float>(std::max(projector_size - 1, 1));
  cv::Mat hsv(coordinate.size(), CV_32FC3);
  for (int y = 0; y < coordinate.rows; ++y) {
    const float* in = coordinate.ptr<float>(y);
    cv::Vec3f* out = hsv.ptr<cv::Vec3f>(y);
    for (int x = 0; x < coordinate.cols; ++x) {
      const bool valid = std::isfinite(in[x]);
      const float hue =
          valid ? std::clamp(in[x] * hue_per_pixel, 0.0f, internal::kMaxHueDeg) : 0.0f;
      out[x] = cv::Vec3f(hue, 1.0f, valid ? 1.0f : 0.0f);
    }
  }
  cv::Mat bgr;
  cv::cvtColor(hsv, bgr, cv::COLOR_HSV2BGR);
  cv::Mat colour;
  bgr.convertTo(colour, CV_8UC3, 255.0);
  return colour;
}

void WriteCorrespondenceMap(const std::string& directory_path, const CorrespondenceMap& map) {
  internal::CheckMap(map);
  // Staged as a whole: a full disk or a signal leaves no half map directory.
  StagedDirectory staged(directory_path, internal::kMapJson);
  const std::string& directory = staged.path();
  nlohmann::json root;
  root["format"] = internal::kMapFormat;
  root["camera"] = {{"width", map.width()}, {"height", map.height()}};
  root["projector"] = {{"width", map.projector_width}, {"height", map.projector_height}};
  nlohmann::json axes = nlohmann::json::object();
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    const bool is_x = axis == PatternAxis::kX;
    const cv::Mat& coordinate = is_x ? map.proj_x : map.proj_y;
    if (coordinate.empty()) continue;
    WriteImageAtomic(JoinPath(directory, internal::AxisFile(axis, "exr")), coordinate);
    WriteImageAtomic(
        JoinPath(directory, internal::AxisFile(axis, "png")),
        ColorizeCoordinate(coordinate, is_x ? map.projector_width : map.projector_height));
    axes[ToString(axis)] = {{"file", internal::AxisFile(axis, "exr")},
                            {"step", is_x ? map.step_x : map.step_y}};
  }
  root["axes"] = axes;
  root["mask"] = internal::kMaskFile;
  root["confidence"] = internal::kConfidenceFile;
  WriteImageAtomic(JoinPath(directory, internal::kMaskFile), map.mask);
  WriteImageAtomic(JoinPath(directory, internal::kConfidenceFile), map.confidence);
  WriteImageAtomic(JoinPath(directory, internal::kConfidencePng),
                   internal::ColorizeConfidence(map.confidence, map.mask));
  // Last, so that a complete correspondence.json implies complete images.
  WriteFileAtomic(JoinPath(directory, internal::kMapJson), root.dump(2) + "\n");
  staged.Commit();
}

CorrespondenceMap ReadCorrespondenceMap(const std::string& directory) {
  const std::string json_path = JoinPath(directory, internal::kMapJson);
  const std::string text = ReadFileToString(json_path, "correspondence map");
  nlohmann::json root;
  try {
    root = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {  // parse_error, or a number overflow
    SOPE_THROW("{}: not valid JSON ({})", json_path, e.what());
  }
  CorrespondenceMap map;
  int camera_width = 0, camera_height = 0;
  try {
    const std::string format = root.at("format").get<std::string>();
    SOPE_CHECK(format == internal::kMapFormat, "{}: unsupported format '{}' (expected '{}')",
               json_path, format, internal::kMapFormat);
    camera_width = root.at("camera").at("width").get<int>();
    camera_height = root.at("camera").at("height").get<int>();
    map.projector_width = root.at("projector").at("width").get<int>();
    map.projector_height = root.at("projector").at("height").get<int>();
    const nlohmann::json& axes = root.at("axes");
    for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
      if (!axes.contains(ToString(axis))) continue;
      const nlohmann::json& entry = axes.at(ToString(axis));
      const std::string file = entry.at("file").get<std::string>();
      SOPE_CHECK(file.find('/') == std::string::npos, "{}: file '{}' must be a plain name",
                 json_path, file);
      const cv::Mat image = ReadImage(JoinPath(directory, file));
      const float step = entry.at("step").get<float>();
      if (axis == PatternAxis::kX) {
        map.proj_x = image;
        map.step_x = step;
      } else {
        map.proj_y = image;
        map.step_y = step;
      }
    }
    map.mask = ReadImage(JoinPath(directory, root.at("mask").get<std::string>()));
    map.confidence = ReadImage(JoinPath(directory, root.at("confidence").get<std::string>()));
  } catch (const nlohmann::json::exception& e) {
    SOPE_THROW("{}: missing or mistyped field ({})", json_path, e.what());
  }
  try {
    internal::CheckMap(map);
  } catch (const Error& e) {
    SOPE_THROW("{}: {}", directory, e.what());
  }
  SOPE_CHECK(map.width() == camera_width && map.height() == camera_height,
             "{}: images are {}x{} but correspondence.json says {}x{}", directory, map.width(),
             map.height(), camera_width, camera_height);
  return map;
}

}  // namespace sope

namespace sope {

// Whole-image state of the incremental path (8-bit, every bit against its inverse): the
// workspace of ChunkDecoder's hot path for all pixels at once, so that each bit can be
// accumulated when its frames arrive; Finish runs ChunkDecoder's finish per chunk.
struct IncrementalDecoder::Impl {
  using Pixel = uint8_t;
  FrameSetManifest manifest;
  DecoderOptions options;
  internal::DecodePlan plan;
  internal::Thresholds thresholds;
  std::vector<cv::Mat> images;  // by manifest index; empty until added
  size_t added = 0;
  int depth = -1;  // CV_8U / CV_16U of the first frame
  bool has_white_black = false;
  // The per-frame path applies (decided by the plan and the first frame's depth).
  bool incremental = false;
  bool prepared = false;  // white/black (or the uniform thresholds) are in
  size_t total = 0;       // pixels
  // Next bit of each axis to accumulate (bits_msb_first order).
  std::array<size_t, 2> next_bit{0, 0};
  std::vector<uint8_t> code[2][2], weak[2][2];
  std::vector<Pixel> margin, min_margin, max_diff;
  std::vector<int16_t> contrast, white_plus_black;

  const Pixel* Frame(int index) const { return images[index].ptr<Pixel>(); }

  // Runs kernel(begin, n) over the image in chunks (the kernels' prefetch distance).
  template <typename Kernel>
  void ForChunks(Kernel&& kernel) {
    for (size_t begin = 0; begin < total; begin += internal::kChunkPixels) {
      kernel(begin, static_cast<int>(std::min<size_t>(internal::kChunkPixels, total - begin)));
    }
  }

  void Start() {
    total = static_cast<size_t>(manifest.camera_width) * manifest.camera_height;
    for (int axis = 0; axis < 2; ++axis) {
      for (int plane = 0; plane < 2; ++plane) {
        code[axis][plane].assign(total, 0);
        weak[axis][plane].assign(total, 0);
      }
    }
    margin.assign(total, std::numeric_limits<Pixel>::max());
    min_margin.resize(total);
    contrast.resize(total);
    white_plus_black.resize(total);
    if (!has_white_black) {
      max_diff.assign(total, 0);
      ForChunks([&](size_t begin, int n) {
        internal::ComputeBitThresholds(n, static_cast<const int16_t*>(nullptr),
                                       thresholds.min_bit_margin,
                                       thresholds.relative_bit_margin, min_margin.data() + begin);
      });
      prepared = true;
    }
  }

  // Does every step whose frames are in: white/black first, then each axis's bits in order.
  void Progress() {
    if (!prepared) {
      if (images[plan.white].empty() || images[plan.black].empty()) return;
      ForChunks([&](size_t begin, int n) {
        internal::ComputeWhiteBlack(Frame(plan.white) + begin, Frame(plan.black) + begin, n,
                                    contrast.data() + begin, white_plus_black.data() + begin);
        internal::ComputeBitThresholds(n, contrast.data() + begin, thresholds.min_bit_margin,
                                       thresholds.relative_bit_margin, min_margin.data() + begin);
      });
      prepared = true;
    }
    for (int axis : {internal::kAxisX, internal::kAxisY}) {
      const std::vector<internal::BitFrames>& bits = plan.axes[axis].bits_msb_first;
      const size_t high_bits = bits.size() > 8 ? bits.size() - 8 : 0;
      for (; next_bit[axis] < bits.size(); ++next_bit[axis]) {
        const size_t k = next_bit[axis];
        const internal::BitFrames& bit = bits[k];
        if (images[bit.pattern].empty() || images[bit.inverse].empty()) break;
        const int plane = k < high_bits ? internal::kHigh : internal::kLow;
        uint8_t* code_plane = code[axis][plane].data();
        uint8_t* weak_plane = weak[axis][plane].data();
        // The kernel variants of ChunkDecoder::Decode's hot path.
        ForChunks([&](size_t begin, int n) {
          const Pixel* pattern = Frame(bit.pattern) + begin;
          const Pixel* inverse = Frame(bit.inverse) + begin;
          if (has_white_black && thresholds.relative_bit_margin > 0.0f) {
            internal::AccumulateInverseBit<Pixel, Pixel, 1, false, true>(
                pattern, inverse, n, min_margin.data() + begin, code_plane + begin,
                weak_plane + begin, margin.data() + begin, nullptr);
          } else if (has_white_black) {
            internal::AccumulateInverseBit<Pixel, Pixel, 1, false, false>(
                pattern, inverse, n, min_margin.data() + begin, code_plane + begin,
                weak_plane + begin, margin.data() + begin, nullptr);
          } else {
            internal::AccumulateInverseBit<Pixel, Pixel, 1, true>(
                pattern, inverse, n, min_margin.data() + begin, code_plane + begin,
                weak_plane + begin, margin.data() + begin, max_diff.data() + begin);
          }
        });
      }
    }
  }

  void FinishIncremental(CorrespondenceMap* map) {
    if (!has_white_black) {
      for (size_t i = 0; i < total; ++i) contrast[i] = max_diff[i];
    }
    // The map's images, as Decode prepares them.
    map->projector_width = manifest.projector_width;
    map->projector_height = manifest.projector_height;
    map->step_x = map->step_y = 1.0f;
    const cv::Size size(manifest.camera_width, manifest.camera_height);
    internal::Outputs outputs;
    for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
      const internal::AxisPlan& axis_plan = plan.axes[static_cast<int>(axis)];
      cv::Mat& coordinate = axis == PatternAxis::kX ? map->proj_x : map->proj_y;
      if (!axis_plan.coded) {
        coordinate.release();
        continue;
      }
      internal::PrepareOutput(size, CV_32FC1, &coordinate);
      outputs.proj[static_cast<int>(axis)] = coordinate.ptr<float>();
      (axis == PatternAxis::kX ? map->step_x : map->step_y) =
          static_cast<float>(1 << axis_plan.lowest_bit);
    }
    internal::PrepareOutput(size, CV_8UC1, &map->mask);
    internal::PrepareOutput(size, CV_32FC1, &map->confidence);
    outputs.mask = map->mask.ptr<uint8_t>();
    outputs.confidence = map->confidence.ptr<float>();
    // ChunkDecoder::Finish per chunk.
    const internal::AxisFinish finish_x = internal::MakeAxisFinish(plan.axes[internal::kAxisX]);
    const internal::AxisFinish finish_y = internal::MakeAxisFinish(plan.axes[internal::kAxisY]);
    std::vector<float> discard(internal::kChunkPixels);
    std::vector<uint8_t> candidate(internal::kChunkPixels);
    // One worker, filtering the rows as they are finished.
    internal::DecodeChunksAndFilter(
        total, internal::kChunkPixels, 1, options.min_consistent_neighbours,
        static_cast<float>(options.neighbour_tolerance_px), map,
        [&](size_t /*worker*/, size_t begin, int n) {
          using internal::kAxisX;
          using internal::kAxisY;
          using internal::kHigh;
          using internal::kLow;
          auto run = internal::MakeFinishRun(
              n, contrast.data() + begin, margin.data() + begin, thresholds, outputs, begin,
              discard.data());
          for (int axis : {kAxisX, kAxisY}) {
            for (int plane : {kHigh, kLow}) {
              run.code[axis][plane] = code[axis][plane].data() + begin;
              run.weak[axis][plane] = weak[axis][plane].data() + begin;
            }
          }
          internal::FinishPixels(run, finish_x, finish_y, candidate.data());
        });
  }
};

IncrementalDecoder::IncrementalDecoder(const FrameSetManifest& manifest,
                                       const DecoderOptions& options)
    : impl_(std::make_unique<Impl>()) {
  options.Check();
  manifest.Check();
  impl_->manifest = manifest;
  impl_->options = options;
  impl_->plan = internal::MakeDecodePlan(manifest, options);
  impl_->has_white_black = impl_->plan.white >= 0 && impl_->plan.black >= 0;
  Reset();
}

IncrementalDecoder::~IncrementalDecoder() = default;

void IncrementalDecoder::Reset() {
  Impl& d = *impl_;
  d.images.assign(d.manifest.frames.size(), cv::Mat());
  d.added = 0;
  d.depth = -1;
  d.incremental = false;
  d.prepared = false;
  d.next_bit = {0, 0};
}

size_t IncrementalDecoder::FramesAdded() const { return impl_->added; }

void IncrementalDecoder::AddFrame(size_t index, const cv::Mat& image) {
  Impl& d = *impl_;
  SOPE_CHECK(index < d.images.size(), "frame index {} is out of range (the set has {} frames)",
             index, d.images.size());
  SOPE_CHECK(d.images[index].empty(), "frame {} was already added", index);
  SOPE_CHECK(!image.empty() && image.channels() == 1 &&
                 (image.depth() == CV_8U || image.depth() == CV_16U),
             "frame {}: expected a single-channel 8- or 16-bit image", index);
  SOPE_CHECK(image.cols == d.manifest.camera_width && image.rows == d.manifest.camera_height,
             "frame {} is {}x{} but the set's camera is {}x{}", index, image.cols, image.rows,
             d.manifest.camera_width, d.manifest.camera_height);
  SOPE_CHECK(d.depth < 0 || image.depth() == d.depth,
             "frame {}: every frame of a set must have the same bit depth", index);
  if (d.depth < 0) {
    d.depth = image.depth();
    d.incremental = d.depth == CV_8U && d.plan.mode != BitDecision::kRobust &&
                    !d.plan.any_threshold_bit;
    if (d.incremental) {
      d.thresholds = internal::MakeThresholds(
          d.plan, d.options, internal::PixelTraits<uint8_t>::kLevelsPerGreyLevel);
      d.Start();
    }
  }
  d.images[index] = image.isContinuous() ? image : image.clone();
  ++d.added;
  if (d.incremental) d.Progress();
}

void IncrementalDecoder::Finish(CorrespondenceMap* map) {
  SOPE_CHECK(map != nullptr, "IncrementalDecoder::Finish: no output map");
  Impl& d = *impl_;
  for (size_t i = 0; i < d.images.size(); ++i) {
    SOPE_CHECK(!d.images[i].empty(), "frame {} ('{}') has not been added", i,
               d.manifest.frames[i].file);
  }
  if (!d.incremental) {
    FrameSet frames;
    frames.manifest = d.manifest;
    frames.images = d.images;
    Decode(frames, d.options, map);
    return;
  }
  d.Progress();
  d.FinishIncremental(map);
  if (d.options.gray_subpixel == GraySubpixel::kEdges || d.options.consistency.enabled) {
    FrameSet frames;
    frames.manifest = d.manifest;
    frames.images = d.images;
    if (d.options.consistency.enabled) FillFromConsistentNeighbours(frames, d.options, map);
    if (d.options.gray_subpixel == GraySubpixel::kEdges) RefineGraySubpixel(frames, map);
  }
}

CorrespondenceMap IncrementalDecoder::Finish() {
  CorrespondenceMap map;
  Finish(&map);
  return map;
}

}  // namespace sope
