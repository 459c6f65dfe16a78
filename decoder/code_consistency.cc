#include "decoder/code_consistency.h"

#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.h"
#include "decoder/plane_fit_sums.h"
#include "projector/patterns.h"

namespace sope {
namespace internal {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// A pixel value as grey levels on the 8-bit scale.
template <typename Pixel>
inline float GreyOf(Pixel v) {
  if constexpr (sizeof(Pixel) == 2) {
    return v / 257.0f;
  } else {
    return static_cast<float>(v);
  }
}

inline float Grey(const cv::Mat& image, int x, int y) {
  return image.depth() == CV_16U ? GreyOf(image.at<uint16_t>(y, x))
                                 : GreyOf(image.at<uint8_t>(y, x));
}

// white − black of `cols` pixels as grey levels (8-bit scale), as Grey(white) − Grey(black).
template <typename Pixel>
void WhiteMinusBlack(const Pixel* __restrict white, const Pixel* __restrict black, int cols,
                     float* __restrict out) {
  for (int x = 0; x < cols; ++x) out[x] = GreyOf(white[x]) - GreyOf(black[x]);
}

// The frames of one code axis, from its least significant present bit up.
struct AxisFrames {
  PatternAxis axis = PatternAxis::kX;
  PatternCode code = PatternCode::kGray;
  int lowest = 0;
  int size = 0;                                  // projector pixels on the axis
  std::vector<const cv::Mat*> pattern, inverse;  // index bit − lowest; inverse may be null
  // 8-bit frames, every bit with its inverse: the window sums read the rows directly.
  bool byte_pairs = false;

  void SetByteFrames() {
    byte_pairs = !pattern.empty();
    for (size_t k = 0; k < pattern.size(); ++k) {
      byte_pairs = byte_pairs && inverse[k] != nullptr && pattern[k]->depth() == CV_8U &&
                   inverse[k]->depth() == CV_8U;
    }
  }
};

// Signed margin of bit index k at (x, y) in pattern − inverse units (grey levels, 8-bit
// scale): positive = bit 1.
inline float Margin(const AxisFrames& axis, size_t k, const cv::Mat* white, const cv::Mat* black,
                    int x, int y) {
  const float p = Grey(*axis.pattern[k], x, y);
  if (axis.inverse[k]) return p - Grey(*axis.inverse[k], x, y);
  return 2.0f * p - Grey(*white, x, y) - Grey(*black, x, y);
}

// Σ p[x] − Σ q[x] over x0 ≤ x ≤ x1 of two rows of `cols` bytes. With SSE2, eight bytes at
// a time (masked to the window and summed by psadbw) wherever eight can be read inside the
// row; integers, so the same sum in any order.
inline int RowSumDifference(const uint8_t* p, const uint8_t* q, int x0, int x1, int cols) {
  int sum = 0;
  int x = x0;
#if defined(__SSE2__)
  const __m128i zero = _mm_setzero_si128();
  for (; x <= x1 && x + 8 <= cols; x += 8) {
    const int width = std::min(8, x1 - x + 1);
    const uint64_t bits = width == 8 ? ~uint64_t{0} : (uint64_t{1} << (8 * width)) - 1;
    const __m128i mask = _mm_set_epi64x(0, static_cast<long long>(bits));
    const __m128i a = _mm_and_si128(
        _mm_loadl_epi64(reinterpret_cast<const __m128i*>(p + x)), mask);
    const __m128i b = _mm_and_si128(
        _mm_loadl_epi64(reinterpret_cast<const __m128i*>(q + x)), mask);
    sum += _mm_cvtsi128_si32(_mm_sad_epu8(a, zero)) - _mm_cvtsi128_si32(_mm_sad_epu8(b, zero));
  }
#endif
  for (; x <= x1; ++x) sum += static_cast<int>(p[x]) - static_cast<int>(q[x]);
  return sum;
}

#if defined(__SSE2__)
// Σ p − Σ q over `rows` rows (from p and q, `step` bytes apart) of eight bytes masked by
// `mask` (the window's columns in each 64-bit half): two rows per psadbw. Integers: the
// same sum as RowSumDifference row by row.
inline int WindowSumDifference(const uint8_t* p, const uint8_t* q, size_t step, int rows,
                               __m128i mask) {
  const __m128i zero = _mm_setzero_si128();
  __m128i sum = zero;
  int r = 0;
  for (; r + 2 <= rows; r += 2, p += 2 * step, q += 2 * step) {
    const __m128i a =
        _mm_unpacklo_epi64(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p)),
                           _mm_loadl_epi64(reinterpret_cast<const __m128i*>(p + step)));
    const __m128i b =
        _mm_unpacklo_epi64(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(q)),
                           _mm_loadl_epi64(reinterpret_cast<const __m128i*>(q + step)));
    sum = _mm_add_epi64(sum, _mm_sub_epi64(_mm_sad_epu8(_mm_and_si128(a, mask), zero),
                                           _mm_sad_epu8(_mm_and_si128(b, mask), zero)));
  }
  if (r < rows) {
    const __m128i low = _mm_unpacklo_epi64(mask, zero);
    const __m128i a = _mm_and_si128(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p)), low);
    const __m128i b = _mm_and_si128(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(q)), low);
    sum = _mm_add_epi64(sum, _mm_sub_epi64(_mm_sad_epu8(a, zero), _mm_sad_epu8(b, zero)));
  }
  return static_cast<int>(_mm_cvtsi128_si64(sum) +
                          _mm_cvtsi128_si64(_mm_unpackhi_epi64(sum, sum)));
}
#endif

// Σ Margin over the window rows [y0, y1] × columns [x0, x1] for each of the `count` bit
// indices `bits`, into sums[bits[j]]: each bit's values added in the same row-major order
// as Margin(…, xx, yy) in a loop over the window, the bits' sums side by side (independent
// chains of additions), the frames' row pointers read once per row. 8-bit frames are
// summed in integers: their grey levels are integers and the window's partial sums far
// below 2^24, so the float additions would be exact — the same sums (with inverses, a row
// of each bit at a time: RowSumDifference).
template <typename Pixel>
void WindowMarginSums(const AxisFrames& axis, const int* bits, int count, const cv::Mat* white,
                      const cv::Mat* black, int x0, int x1, int y0, int y1, float* sums) {
  using Sum = std::conditional_t<sizeof(Pixel) == 1, int, float>;
  const auto grey = [](Pixel v) -> Sum {
    if constexpr (sizeof(Pixel) == 1) {
      return v;
    } else {
      return GreyOf(v);
    }
  };
  constexpr int kMaxBits = 32;
  const Pixel* p[kMaxBits];
  const Pixel* q[kMaxBits];
  Sum sum[kMaxBits];
  for (int j = 0; j < count; ++j) sum[j] = 0;
  for (int yy = y0; yy <= y1; ++yy) {
    bool inverses = true;
    for (int j = 0; j < count; ++j) {
      p[j] = axis.pattern[bits[j]]->ptr<Pixel>(yy);
      q[j] = axis.inverse[bits[j]] ? axis.inverse[bits[j]]->ptr<Pixel>(yy) : nullptr;
      inverses &= q[j] != nullptr;
    }
    if (inverses) {
      if constexpr (sizeof(Pixel) == 1) {
        const int cols = axis.pattern[0]->cols;
        for (int j = 0; j < count; ++j) sum[j] += RowSumDifference(p[j], q[j], x0, x1, cols);
      } else {
        for (int xx = x0; xx <= x1; ++xx) {
          for (int j = 0; j < count; ++j) sum[j] += grey(p[j][xx]) - grey(q[j][xx]);
        }
      }
    } else {
      const Pixel* w = white->ptr<Pixel>(yy);
      const Pixel* b = black->ptr<Pixel>(yy);
      for (int xx = x0; xx <= x1; ++xx) {
        for (int j = 0; j < count; ++j) {
          sum[j] += q[j] ? grey(p[j][xx]) - grey(q[j][xx])
                         : Sum{2} * grey(p[j][xx]) - grey(w[xx]) - grey(b[xx]);
        }
      }
    }
  }
  for (int j = 0; j < count; ++j) sums[bits[j]] = static_cast<float>(sum[j]);
}

// Signed margins of every bit at (x, y), each averaged over a square window of half side
// min(max_radius, ⌊stripe / 4⌋) camera pixels, `stripe` the bit's stripe width in camera
// pixels at the local coordinate gradient `gradient` (projector px per camera px): the
// window stays well inside one stripe, so averaging removes noise without mixing stripes
// except within a quarter stripe of an edge (where the pixel is between two neighbouring
// blocks anyway).
void Margins(const AxisFrames& axis, const cv::Mat* white, const cv::Mat* black, int x, int y,
             float gradient, int max_radius, std::vector<float>* margins) {
  const int num_bits = static_cast<int>(axis.pattern.size());
  SOPE_CHECK(num_bits <= 32, "code consistency: {} bits on an axis (at most 32)", num_bits);
  margins->resize(num_bits);
  const int rows = axis.pattern[0]->rows, cols = axis.pattern[0]->cols;
  const bool sixteen = axis.pattern[0]->depth() == CV_16U;
  // The bits by the radius of their window (0 … max_radius), each group's sums together.
  int radius_of[32];
  for (int k = 0; k < num_bits; ++k) {
    const float stripe = static_cast<float>(1 << (k + axis.lowest)) / std::max(gradient, 1e-3f);
    radius_of[k] = std::min(max_radius, static_cast<int>(stripe / 4.0f));
  }
#if defined(__SSE2__)
  if (axis.byte_pairs) {
    // Each bit's window straight from its two frames' rows (integer sums: the same as the
    // grouped path's), where eight bytes can be read inside the row.
    for (int k = 0; k < num_bits; ++k) {
      const int radius = radius_of[k];
      const int x0 = std::max(0, x - radius), x1 = std::min(cols - 1, x + radius);
      const int y0 = std::max(0, y - radius), y1 = std::min(rows - 1, y + radius);
      const int width = x1 - x0 + 1, height = y1 - y0 + 1;
      const cv::Mat& pattern = *axis.pattern[k];
      const cv::Mat& inverse = *axis.inverse[k];
      int sum = 0;
      if (x0 + 8 <= cols && width <= 8 && pattern.step == inverse.step) {
        const uint64_t bits = width == 8 ? ~uint64_t{0} : (uint64_t{1} << (8 * width)) - 1;
        const __m128i mask = _mm_set1_epi64x(static_cast<long long>(bits));
        sum = WindowSumDifference(pattern.ptr<uint8_t>(y0) + x0, inverse.ptr<uint8_t>(y0) + x0,
                                  pattern.step, height, mask);
      } else {
        for (int yy = y0; yy <= y1; ++yy) {
          sum += RowSumDifference(pattern.ptr<uint8_t>(yy), inverse.ptr<uint8_t>(yy), x0, x1,
                                  cols);
        }
      }
      (*margins)[k] = static_cast<float>(sum) / static_cast<float>(width * height);
    }
    return;
  }
#endif
  bool grouped[32] = {};
  for (int first = 0; first < num_bits; ++first) {
    if (grouped[first]) continue;
    const int radius = radius_of[first];
    int bits[32];
    int count = 0;
    for (int k = first; k < num_bits; ++k) {
      if (!grouped[k] && radius_of[k] == radius) {
        bits[count++] = k;
        grouped[k] = true;
      }
    }
    const int x0 = std::max(0, x - radius), x1 = std::min(cols - 1, x + radius);
    const int y0 = std::max(0, y - radius), y1 = std::min(rows - 1, y + radius);
    if (sixteen) {
      WindowMarginSums<uint16_t>(axis, bits, count, white, black, x0, x1, y0, y1, margins->data());
    } else {
      WindowMarginSums<uint8_t>(axis, bits, count, white, black, x0, x1, y0, y1, margins->data());
    }
    const float samples = static_cast<float>((x1 - x0 + 1) * (y1 - y0 + 1));
    for (int j = 0; j < count; ++j) (*margins)[bits[j]] /= samples;
  }
}

// Candidates decided by one task of the pool.
constexpr int kCandidatesPerStripe = 64;

// fn(x) for each x < cols whose byte in `bytes` is not 0, in increasing order, reading
// eight bytes at a time (marks are sparse): `bytes` must be readable up to
// cols rounded up to a multiple of 8. fn may clear the byte it is given.
template <typename Fn>
void ForEachMarked(const uint8_t* bytes, int cols, const Fn& fn) {
  for (int x = 0; x < cols; x += 8) {
    uint64_t eight = 0;
    std::memcpy(&eight, bytes + x, 8);
    if (eight == 0) continue;
    for (int xx = x; xx < std::min(cols, x + 8); ++xx) {
      if (bytes[xx] != 0) fn(xx);
    }
  }
}

// The least float ≥ `value`: for a float c, c ≥ value ⇔ c ≥ FloatAtLeast(value) (the
// options are doubles, the contrasts floats).
inline float FloatAtLeast(double value) {
  float f = static_cast<float>(value);
  if (static_cast<double>(f) < value) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

// The first pass's candidates in one row of `cols` pixels: flags[x] = 1 when the pixel is
// undecoded (mask 0), has at least `min_contrast` and at least `min_neighbours` decoded
// pixels in its window of half side `radius`, counted from the integral image's rows
// `top` (the window's first row) and `bottom` (one past its last). `left` (cols + 1) is
// scratch: the window rows' decoded pixels left of each column. Loops GCC vectorises.
void FlagFirstCandidates(const int* __restrict top, const int* __restrict bottom,
                         const uint8_t* __restrict mask, const float* __restrict contrast,
                         int cols, int radius, int min_neighbours, float min_contrast,
                         int* __restrict left, uint8_t* __restrict flags) {
  for (int x = 0; x <= cols; ++x) left[x] = bottom[x] - top[x];
  const auto flag = [&](int x, int in_window) {
    flags[x] = static_cast<uint8_t>((mask[x] == 0) & (contrast[x] >= min_contrast) &
                                    (in_window >= min_neighbours));
  };
  // The window's columns x − radius … x + radius, clipped to the image at both ends.
  const int first_whole = std::min(radius, cols);
  const int end_whole = std::max(first_whole, cols - radius - 1);
  for (int x = 0; x < first_whole; ++x) {
    flag(x, left[std::min(cols, x + radius + 1)] - left[0]);
  }
  for (int x = first_whole; x < end_whole; ++x) {
    flag(x, left[x + radius + 1] - left[x - radius]);
  }
  for (int x = end_whole; x < cols; ++x) {
    flag(x, left[cols] - left[std::max(0, x - radius)]);
  }
}

// The decoded pixels of a window (FillFromConsistentNeighbours): the first `count`
// entries of each array; room for the whole window.
struct Neighbourhood {
  std::vector<int> dx, dy;
  std::vector<float> contrast;
  std::vector<float> value[2];  // the coded axes' coordinates
  int count = 0;
  // Room for `window` neighbours, and the 16 a vector step may store past them.
  void Resize(int window) {
    const size_t n = static_cast<size_t>(window) + 16;
    if (dx.size() >= n) return;
    for (std::vector<int>* v : {&dx, &dy}) v->resize(n);
    for (std::vector<float>* v : {&contrast, &value[0], &value[1]}) v->resize(n);
  }
};

// Appends the decoded pixels (mask non-zero) among columns [x0, x1] of one window row to
// `out` from out->count on, in column order: offsets (xx − x, dy), contrasts and the two
// coordinate slots. With AVX-512 16 columns a step (compress stores: the same arrays as
// the portable loop, which writes every column and advances the count by the decoded ones).
inline void AppendDecodedRow(const uint8_t* mask_row, const float* contrast_row,
                             const float* row0, const float* row1, int x0, int x1, int x,
                             int dy, Neighbourhood* out) {
  int count = out->count;
  int* __restrict dxs = out->dx.data();
  int* __restrict dys = out->dy.data();
  float* __restrict contrasts = out->contrast.data();
  float* __restrict value0 = out->value[0].data();
  float* __restrict value1 = out->value[1].data();
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
  const __m512i iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512i row_offset = _mm512_set1_epi32(dy);
  for (int xx = x0; xx <= x1; xx += 16) {
    const int lanes = std::min(16, x1 - xx + 1);
    const __mmask16 tail = static_cast<__mmask16>((1u << lanes) - 1u);
    const __m128i m = _mm_maskz_loadu_epi8(tail, mask_row + xx);
    const __mmask16 keep = _mm_mask_test_epi8_mask(tail, m, m);
    if (keep == 0) continue;
    const __m512i offsets = _mm512_add_epi32(_mm512_set1_epi32(xx - x), iota);
    _mm512_storeu_si512(dxs + count, _mm512_maskz_compress_epi32(keep, offsets));
    _mm512_storeu_si512(dys + count, _mm512_maskz_compress_epi32(keep, row_offset));
    const __m512 contrast = _mm512_maskz_loadu_ps(tail, contrast_row + xx);
    _mm512_storeu_ps(contrasts + count, _mm512_maskz_compress_ps(keep, contrast));
    _mm512_storeu_ps(value0 + count,
                     _mm512_maskz_compress_ps(keep, _mm512_maskz_loadu_ps(tail, row0 + xx)));
    _mm512_storeu_ps(value1 + count,
                     _mm512_maskz_compress_ps(keep, _mm512_maskz_loadu_ps(tail, row1 + xx)));
    count += __builtin_popcount(keep);
  }
#else
  for (int xx = x0; xx <= x1; ++xx) {
    dxs[count] = xx - x;
    dys[count] = dy;
    contrasts[count] = contrast_row[xx];
    value0[count] = row0[xx];
    value1[count] = row1[xx];
    count += mask_row[xx] != 0;
  }
#endif
  out->count = count;
}

struct Choice {
  float coordinate = kNaN;
  float confidence = 0.0f;
};

// The best-supported block near `predicted` (see FillFromConsistentNeighbours).
Choice ChooseBlock(const AxisFrames& axis, const std::vector<float>& margins, float predicted,
                   float contrast, const DecoderOptions& options) {
  const int step = 1 << axis.lowest;
  const int blocks = (axis.size + step - 1) / step;
  const float centre_offset = 0.5f * (step - 1);
  const float radius = static_cast<float>(options.consistency.search_radius_px);
  const int first =
      std::max(0, static_cast<int>(std::floor((predicted - radius - centre_offset) / step)));
  const int last = std::min(
      blocks - 1, static_cast<int>(std::ceil((predicted + radius - centre_offset) / step)));
  const float strong =
      static_cast<float>(options.consistency.strong_bit_factor * options.min_bit_contrast);
  float best = -std::numeric_limits<float>::infinity(), second = best, third = best;
  int best_block = -1, second_block = -1;
  // Each block's score Σ ±margin_k adds in the order of k (its own chain of additions);
  // kLanes blocks side by side (vector lanes), then weighed in the order of the blocks.
  constexpr int kLanes = 8;
  const int num_bits = static_cast<int>(margins.size());
  for (int lane0 = first; lane0 <= last; lane0 += kLanes) {
    uint32_t word[kLanes];
    float scores[kLanes];
    int contradicted[kLanes];
    for (int b = 0; b < kLanes; ++b) {
      const uint32_t block = static_cast<uint32_t>(lane0 + b);
      word[b] = axis.code == PatternCode::kGray ? GrayFromBinary(block) : block;
      scores[b] = 0.0f;
      contradicted[b] = 0;
    }
    for (int k = 0; k < num_bits; ++k) {
      const float margin = margins[k];
      for (int b = 0; b < kLanes; ++b) {
        const float signed_margin = ((word[b] >> k) & 1u) ? margin : -margin;
        scores[b] += signed_margin;
        contradicted[b] |= signed_margin <= -strong;
      }
    }
    for (int b = 0; b < kLanes && lane0 + b <= last; ++b) {
      const int block = lane0 + b;
      const float centre = block * step + centre_offset;
      if (std::abs(centre - predicted) > radius + 0.5f * step) continue;
      if (contradicted[b]) continue;
      const float score = scores[b];
      if (score > best) {
        third = second;
        second = best;
        second_block = best_block;
        best = score;
        best_block = block;
      } else if (score > second) {
        third = second;
        second = score;
        second_block = block;
      } else if (score > third) {
        third = score;
      }
    }
  }
  Choice choice;
  if (best_block < 0) return choice;
  const float min_lead = static_cast<float>(options.consistency.min_lead);
  const float lead = std::isfinite(second) ? best - second : best;
  if (lead >= min_lead) {
    const int end = std::min((best_block + 1) * step, axis.size);
    choice.coordinate = 0.5f * static_cast<float>(best_block * step + end - 1);
    choice.confidence = std::min(0.5f, lead / (4.0f * std::max(contrast, 1.0f)));
    return choice;
  }
  // Two neighbouring blocks tie: their codes differ in the one bit that flips at their
  // shared edge and that bit's margin is small, so the pixel sees that edge — it takes the
  // edge's coordinate, provided the two beat every other candidate by the lead.
  const float lead_over_rest = std::isfinite(third) ? second - third : second;
  if (std::abs(best_block - second_block) == 1 && lead_over_rest >= min_lead) {
    choice.coordinate = static_cast<float>(std::max(best_block, second_block) * step) - 0.5f;
    choice.confidence = std::min(0.5f, lead_over_rest / (8.0f * std::max(contrast, 1.0f)));
  }
  return choice;
}

}  // namespace
}  // namespace internal

void FillFromConsistentNeighbours(const FrameSet& frames, const DecoderOptions& options,
                                  CorrespondenceMap* map, const cv::Mat& region,
                                  const cv::Mat& seeds) {
  using namespace internal;
  SOPE_CHECK(map != nullptr, "FillFromConsistentNeighbours: no map");
  const FrameSetManifest& manifest = frames.manifest;
  SOPE_CHECK(map->width() == manifest.camera_width && map->height() == manifest.camera_height,
             "FillFromConsistentNeighbours: the map is {}x{} but the frames are {}x{}",
             map->width(), map->height(), manifest.camera_width, manifest.camera_height);
  SOPE_CHECK(region.empty() || (region.type() == CV_8UC1 && region.cols == map->width() &&
                                region.rows == map->height()),
             "FillFromConsistentNeighbours: the region must be empty or 8-bit {}x{}, got {}x{} "
             "of type {}",
             map->width(), map->height(), region.cols, region.rows, region.type());
  SOPE_CHECK(seeds.empty() || (seeds.type() == CV_8UC1 && seeds.cols == map->width() &&
                               seeds.rows == map->height()),
             "FillFromConsistentNeighbours: the seeds must be empty or 8-bit {}x{}, got {}x{} "
             "of type {}",
             map->width(), map->height(), seeds.cols, seeds.rows, seeds.type());
  std::vector<AxisFrames> axes;
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    const bool coded = axis == PatternAxis::kX ? map->HasX() : map->HasY();
    if (!coded) continue;
    // Every coded axis must be a code axis with all its frames, or nothing is filled.
    if (!manifest.HasAxis(axis) || manifest.HasPhaseAxis(axis)) return;
    AxisFrames frames_of_axis;
    frames_of_axis.axis = axis;
    frames_of_axis.code = manifest.AxisCode(axis);
    frames_of_axis.lowest = manifest.AxisLowestBit(axis);
    frames_of_axis.size =
        axis == PatternAxis::kX ? manifest.projector_width : manifest.projector_height;
    for (int bit = frames_of_axis.lowest; bit < manifest.AxisBits(axis); ++bit) {
      const auto pattern = manifest.FindCode(axis, bit, false);
      if (!pattern) return;
      const auto inverse = manifest.FindCode(axis, bit, true);
      frames_of_axis.pattern.push_back(&frames.Image(*pattern));
      frames_of_axis.inverse.push_back(inverse ? &frames.Image(*inverse) : nullptr);
    }
    frames_of_axis.SetByteFrames();
    axes.push_back(frames_of_axis);
  }
  if (axes.empty()) return;
  const auto white_index = manifest.Find(FrameRole::kWhite);
  const auto black_index = manifest.Find(FrameRole::kBlack);
  const cv::Mat* white = white_index ? &frames.Image(*white_index) : nullptr;
  const cv::Mat* black = black_index ? &frames.Image(*black_index) : nullptr;
  for (const AxisFrames& axis : axes) {
    for (const cv::Mat* inverse : axis.inverse) {
      if (inverse == nullptr && !(white && black)) return;  // cannot form the margins
    }
  }
  const int rows = map->height(), cols = map->width();
  const int radius = options.consistency.window_radius;
  // Per pixel, once (every pass reads it, for the pixel and its neighbours): white − black,
  // or without them the largest bit margin.
  cv::Mat contrast_image(rows, cols, CV_32FC1);
  cv::parallel_for_(cv::Range(0, rows), [&](const cv::Range& range) {
    for (int y = range.start; y < range.end; ++y) {
      float* row = contrast_image.ptr<float>(y);
      if (white && black) {
        if (white->depth() == CV_16U) {
          WhiteMinusBlack(white->ptr<uint16_t>(y), black->ptr<uint16_t>(y), cols, row);
        } else {
          WhiteMinusBlack(white->ptr<uint8_t>(y), black->ptr<uint8_t>(y), cols, row);
        }
        continue;
      }
      for (int x = 0; x < cols; ++x) {
        float contrast = 0.0f;
        for (const AxisFrames& axis : axes) {
          for (size_t k = 0; k < axis.pattern.size(); ++k)
            contrast = std::max(contrast, std::abs(Margin(axis, k, white, black, x, y)));
        }
        row[x] = contrast;
      }
    }
  });
  const auto contrast_at = [&](int x, int y) { return contrast_image.at<float>(y, x); };
  // A pixel's decision reads only the map around it as it was before the pass (and its
  // own, fixed, frames): each pass decides from the unchanged map and its fills are
  // written after it, and a later pass looks only at the pixels within the window of a
  // pixel filled by the pass before — the others would see the same neighbours as before
  // and decide as before. The same fills as re-deciding every pixel in every pass.
  struct Fill {
    int x = 0, y = 0;
    float coordinate[2] = {kNaN, kNaN};
    float confidence = 0.0f;
    bool seed = false;  // with `seeds`: the filled pixel is one
  };
  // With `seeds`: the seeds so far (the given ones and the fills that became seeds; a
  // pass reads it as it was before the pass, as the map).
  cv::Mat seed;
  if (!seeds.empty()) cv::compare(seeds, 0, seed, cv::CMP_NE);
  // The seeds in the window around (x, y).
  const auto seeds_near = [&](int x, int y) {
    const int x0 = std::max(0, x - radius), x1 = std::min(cols - 1, x + radius);
    int n = 0;
    for (int yy = std::max(0, y - radius); yy <= std::min(rows - 1, y + radius); ++yy) {
      const uint8_t* row = seed.ptr<uint8_t>(yy);
      for (int xx = x0; xx <= x1; ++xx) n += row[xx] != 0;
    }
    return n;
  };
  // The pixels a pass decides (undecoded, with enough contrast; after the first pass near
  // a fill of the pass before), and the marks of the windows around the fills (a scratch
  // image, its marks cleared as they are read).
  std::vector<cv::Point> candidates;
  cv::Mat listed;
  const float min_contrast = FloatAtLeast(options.consistency.min_contrast);
  for (int pass = 0; pass < options.consistency.passes; ++pass) {
    const cv::Mat& mask_before = map->mask;
    // The coded axes' coordinate maps (slot 1 repeats slot 0 with one axis).
    const cv::Mat* coordinates_before[2];
    for (size_t a = 0; a < axes.size(); ++a) {
      coordinates_before[a] = axes[a].axis == PatternAxis::kX ? &map->proj_x : &map->proj_y;
    }
    if (axes.size() == 1) coordinates_before[1] = coordinates_before[0];
    // The window around (x, y): its pixels decoded before this pass, in row-major order
    // (every sum below adds in this order), with their offsets, contrasts and coordinates
    // (each row's pointers read once; every pixel written, the count advanced by the
    // decoded ones only: no branch on the mask).
    const int window = (2 * radius + 1) * (2 * radius + 1);
    const auto decoded_neighbours = [&](int x, int y, Neighbourhood* out) {
      out->count = 0;
      const int x0 = std::max(0, x - radius), x1 = std::min(cols - 1, x + radius);
      for (int yy = std::max(0, y - radius); yy <= std::min(rows - 1, y + radius); ++yy) {
        AppendDecodedRow(mask_before.ptr<uint8_t>(yy), contrast_image.ptr<float>(yy),
                         coordinates_before[0]->ptr<float>(yy),
                         coordinates_before[1]->ptr<float>(yy), x0, x1, x, yy - y, out);
      }
    };
    // Per thread: the working arrays of one decision.
    struct Scratch {
      std::vector<float> margins;
      Neighbourhood neighbours;
    };
    // Whether the pixel (x, y) — undecoded, with enough contrast (the callers pick such
    // candidates) — is filled, and with what (*out).
    const auto decide = [&](int x, int y, Scratch* scratch, Fill* out) -> bool {
      std::vector<float>& margins = scratch->margins;
      Neighbourhood& neighbours = scratch->neighbours;
      const int near_seeds = seed.empty() ? 0 : seeds_near(x, y);
      if (!seed.empty() && near_seeds == 0) return false;  // not on a seed's surface
      neighbours.Resize(window);
      const float contrast = contrast_at(x, y);
      decoded_neighbours(x, y, &neighbours);
      const int count = neighbours.count;
      const int* dx = neighbours.dx.data();
      const int* dy = neighbours.dy.data();
      // Too few decoded neighbours for the plane fit below.
      if (count < options.consistency.min_neighbours) return false;
      // Relative to the decoded neighbours': a pixel much darker than the surface
      // around it is at a shadow's edge (partly lit, its code a mixture), whereas a
      // dim, grazing surface darkens smoothly with its neighbours.
      if (options.consistency.min_relative_contrast > 0.0) {
        float sum = 0.0f;
        for (int i = 0; i < count; ++i) sum += neighbours.contrast[i];
        if (contrast < options.consistency.min_relative_contrast * sum / count) return false;
      }
      // The neighbours' prediction of every axis first (their coordinates are in cache),
      // then the pixel's own bit margins (the frames: far more memory) only when every
      // axis has one. Least-squares plane u = c + gx·dx + gy·dy through the decoded neighbours, per
      // axis: the prediction at the pixel and the local gradient. Σ basis·basisᵀ, basis =
      // (1, dx, dy), depends only on which neighbours are decoded: summed (in integers:
      // the same sums as in doubles, exactly) and inverted once for both axes; Σ basis·u
      // per axis.
      int sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0;
      for (int i = 0; i < count; ++i) {
        sx += dx[i];
        sy += dy[i];
        sxx += dx[i] * dx[i];
        sxy += dx[i] * dy[i];
        syy += dy[i] * dy[i];
      }
      const double n = count;
      const cv::Matx33d normal(n, sx, sy, sx, sxx, sxy, sy, sxy, syy);
      if (cv::determinant(normal) < 1e-6) return false;
      const cv::Matx33d inverse = normal.inv();
      // Both slots' sums in one loop and their residuals in another (independent chains
      // of additions, each in the neighbours' order), then the tests axis by axis.
      const float* values0 = neighbours.value[0].data();
      const float* values1 = neighbours.value[1].data();
      PlaneFitSums sums[2];  // Σ basis·u only
      for (int i = 0; i < count; ++i) {
        sums[0].AddValue(dx[i], dy[i], values0[i]);
        sums[1].AddValue(dx[i], dy[i], values1[i]);
      }
      cv::Vec3d planes[2];
      for (int slot = 0; slot < 2; ++slot) {
        planes[slot] = inverse * cv::Vec3d(sums[slot].u, sums[slot].xu, sums[slot].yu);
      }
      double residuals[2] = {0.0, 0.0};
      for (int i = 0; i < count; ++i) {
        const double fx = static_cast<float>(dx[i]), fy = static_cast<float>(dy[i]);
        const double r0 = values0[i] - (planes[0][0] + planes[0][1] * fx + planes[0][2] * fy);
        const double r1 = values1[i] - (planes[1][0] + planes[1][1] * fx + planes[1][2] * fy);
        residuals[0] += r0 * r0;
        residuals[1] += r1 * r1;
      }
      float predicted[2], gradient[2];
      for (size_t a = 0; a < axes.size(); ++a) {
        const cv::Vec3d& plane = planes[a];
        const double residual = residuals[a];
        // Not a smooth surface around the pixel (an edge, another object): no prediction.
        if (std::sqrt(residual / count) > options.consistency.max_plane_rms_px) {
          return false;
        }
        predicted[a] = static_cast<float>(plane[0]);
        // Beyond the projector's outermost pixel centre: the pixel sees the edge of the
        // projected light (its code is the edge block's only by extrapolation), not a
        // code — filled, it triangulated to a point off the surface.
        if (!(predicted[a] >= 0.0f && predicted[a] <= static_cast<float>(axes[a].size - 1))) {
          return false;
        }
        gradient[a] = static_cast<float>(std::hypot(plane[1], plane[2]));
        // Stripes compressed below the camera's resolution (a surface seen at grazing
        // incidence): the neighbours cannot bound the code to a pixel.
        if (!(gradient[a] <= options.consistency.max_gradient)) return false;
      }
      Choice choices[2];
      for (size_t a = 0; a < axes.size(); ++a) {
        Margins(axes[a], white, black, x, y, gradient[a], options.consistency.max_average_radius,
                &margins);
        choices[a] = ChooseBlock(axes[a], margins, predicted[a], contrast, options);
        if (!std::isfinite(choices[a].coordinate)) return false;
      }
      Fill& fill = *out;
      fill.x = x;
      fill.y = y;
      fill.seed = !seed.empty() && 2 * near_seeds >= count;
      fill.confidence = 1.0f;
      for (size_t a = 0; a < axes.size(); ++a) {
        fill.coordinate[a] = choices[a].coordinate;
        fill.confidence = std::min(fill.confidence, choices[a].confidence);
      }
      return true;
    };
    // The first pass's candidates: every pixel undecoded, with enough contrast and (where
    // most pixels stop) enough decoded pixels in its window — counted from an integral
    // image, a row at a time —, in row-major order.
    if (pass == 0) {
      cv::Mat decoded, decoded_sums;  // 1 where decoded; (rows + 1) × (cols + 1) sums
      cv::threshold(mask_before, decoded, 0, 1, cv::THRESH_BINARY);
      cv::integral(decoded, decoded_sums, CV_32S);
      const int min_neighbours = options.consistency.min_neighbours;
      std::vector<std::vector<cv::Point>> candidates_per_row(rows);
      cv::parallel_for_(cv::Range(0, rows), [&](const cv::Range& range) {
        std::vector<int> left(cols + 1);
        std::vector<uint8_t> flags(cols + 8, 0);  // read eight at a time
        for (int y = range.start; y < range.end; ++y) {
          FlagFirstCandidates(decoded_sums.ptr<int>(std::max(0, y - radius)),
                              decoded_sums.ptr<int>(std::min(rows - 1, y + radius) + 1),
                              mask_before.ptr<uint8_t>(y), contrast_image.ptr<float>(y), cols,
                              radius, min_neighbours, min_contrast, left.data(), flags.data());
          if (!region.empty()) {
            const uint8_t* inside = region.ptr<uint8_t>(y);
            for (int x = 0; x < cols; ++x) flags[x] &= static_cast<uint8_t>(inside[x] != 0);
          }
          ForEachMarked(flags.data(), cols,
                        [&](int x) { candidates_per_row[y].emplace_back(x, y); });
        }
      }, std::max(1, rows / 16));  // stripes of rows: the scratch rows allocated once each
      for (const std::vector<cv::Point>& row_candidates : candidates_per_row) {
        candidates.insert(candidates.end(), row_candidates.begin(), row_candidates.end());
      }
    }
    std::vector<Fill> decided(candidates.size());
    std::vector<uint8_t> filled_here(candidates.size(), 0);
    cv::parallel_for_(cv::Range(0, static_cast<int>(candidates.size())),
                      [&](const cv::Range& range) {
                        Scratch scratch;
                        for (int i = range.start; i < range.end; ++i) {
                          filled_here[i] =
                              decide(candidates[i].x, candidates[i].y, &scratch, &decided[i]);
                        }
                      },
                      // Stripes of kCandidatesPerStripe candidates (OpenCV's default is one
                      // per stripe): a scratch per stripe.
                      std::max(1.0, static_cast<double>(candidates.size()) / kCandidatesPerStripe));
    std::vector<Fill> fills;
    for (size_t i = 0; i < candidates.size(); ++i) {
      if (filled_here[i]) fills.push_back(decided[i]);
    }
    if (fills.empty()) break;
    for (const Fill& fill : fills) {
      for (size_t a = 0; a < axes.size(); ++a) {
        (axes[a].axis == PatternAxis::kX ? map->proj_x : map->proj_y)
            .at<float>(fill.y, fill.x) = fill.coordinate[a];
      }
      map->mask.at<uint8_t>(fill.y, fill.x) = 255;
      map->confidence.at<float>(fill.y, fill.x) = fill.confidence;
      if (fill.seed) seed.at<uint8_t>(fill.y, fill.x) = 255;
    }
    // The next pass's candidates: the pixels still undecoded within a fill's window, with
    // enough contrast, in row-major order (a pass's decisions do not depend on their
    // order). The fills' windows are marked in `listed` first (they overlap: each pixel is
    // then tested once), then the rows they span are read eight marks at a time, clearing
    // the marks.
    if (listed.empty()) listed = cv::Mat::zeros(rows, cols + 8, CV_8UC1);
    candidates.clear();
    int first_row = rows, last_row = -1;
    for (const Fill& fill : fills) {
      const int x0 = std::max(0, fill.x - radius), x1 = std::min(cols - 1, fill.x + radius);
      const int y0 = std::max(0, fill.y - radius), y1 = std::min(rows - 1, fill.y + radius);
      for (int yy = y0; yy <= y1; ++yy) {
        std::memset(listed.ptr<uint8_t>(yy) + x0, 1, static_cast<size_t>(x1 - x0 + 1));
      }
      first_row = std::min(first_row, y0);
      last_row = std::max(last_row, y1);
    }
    for (int yy = first_row; yy <= last_row; ++yy) {
      uint8_t* listed_row = listed.ptr<uint8_t>(yy);
      const uint8_t* mask_row = map->mask.ptr<uint8_t>(yy);
      const float* contrast_row = contrast_image.ptr<float>(yy);
      const uint8_t* inside = region.empty() ? nullptr : region.ptr<uint8_t>(yy);
      ForEachMarked(listed_row, cols, [&](int x) {
        listed_row[x] = 0;
        if (mask_row[x] == 0 && contrast_row[x] >= min_contrast &&
            (inside == nullptr || inside[x] != 0)) {
          candidates.emplace_back(x, yy);
        }
      });
    }
  }
}

}  // namespace sope
