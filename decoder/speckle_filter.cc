#include "decoder/speckle_filter.h"

#if defined(__AVX512F__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <limits>
#include <utility>
#include <vector>

#include "decoder/decoder_internal.h"

namespace sope {
namespace internal {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Whether neighbour (nu, nv) agrees with (u, v) within `tolerance` on both axes. Invalid
// pixels hold NaN, whose comparisons are false, so no mask is needed; an uncoded axis
// passes zeros for both.
inline bool Agrees(float u, float v, float nu, float nv, float tolerance) {
  const float du = nu - u, dv = nv - v;
  return (du <= tolerance) & (du >= -tolerance) & (dv <= tolerance) & (dv >= -tolerance);
}

#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
// Agrees for 16 pixels (u, v) and their neighbours at nu, nv: |nu − u| ≤ t and
// |nv − v| ≤ t, false for NaN — the same decisions as Agrees — as 16 bytes of 0 or 1.
inline __m128i AgreesAvx512(__m512 u, __m512 v, const float* nu, const float* nv,
                            __m512 tolerance) {
  const __m512 sign = _mm512_set1_ps(-0.0f);
  const __m512 du = _mm512_andnot_ps(sign, _mm512_sub_ps(_mm512_loadu_ps(nu), u));
  const __m512 dv = _mm512_andnot_ps(sign, _mm512_sub_ps(_mm512_loadu_ps(nv), v));
  const __mmask16 agree = _mm512_mask_cmp_ps_mask(_mm512_cmp_ps_mask(du, tolerance, _CMP_LE_OQ),
                                                  dv, tolerance, _CMP_LE_OQ);
  return _mm_maskz_mov_epi8(agree, _mm_set1_epi8(1));
}
inline void Store16(uint8_t* destination, __m128i bytes) {
  _mm_storeu_si128(reinterpret_cast<__m128i*>(destination), bytes);
}
#endif

// Pairs within row (u, v) of n pixels.
void RowAgreements(const float* __restrict u, const float* __restrict v, int n, float tolerance,
                   uint8_t* __restrict right) {
  int x = 0;
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
  if (!UsePortableKernelsForTesting()) {
    const __m512 t = _mm512_set1_ps(tolerance);
    for (; x + 16 < n; x += 16) {
      Store16(right + x + 1,
              AgreesAvx512(_mm512_loadu_ps(u + x), _mm512_loadu_ps(v + x), u + x + 1, v + x + 1, t));
    }
  }
#endif
  for (; x + 1 < n; ++x) {
    right[x + 1] = Agrees(u[x], v[x], u[x + 1], v[x + 1], tolerance);
  }
}

// Pairs between row (u, v) and the row below it (ub, vb).
void RowPairAgreements(const float* __restrict u, const float* __restrict v,
                       const float* __restrict ub, const float* __restrict vb, int n,
                       float tolerance, uint8_t* __restrict below,
                       uint8_t* __restrict below_right, uint8_t* __restrict below_left) {
  // The first pixel has no neighbour below-left.
  if (n > 0) below[1] = Agrees(u[0], v[0], ub[0], vb[0], tolerance);
  if (n > 1) below_right[1] = Agrees(u[0], v[0], ub[1], vb[1], tolerance);
  int x = 1;
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
  if (!UsePortableKernelsForTesting()) {
    const __m512 t = _mm512_set1_ps(tolerance);
    for (; x + 16 < n; x += 16) {
      const __m512 ux = _mm512_loadu_ps(u + x), vx = _mm512_loadu_ps(v + x);
      Store16(below + x + 1, AgreesAvx512(ux, vx, ub + x, vb + x, t));
      Store16(below_right + x + 1, AgreesAvx512(ux, vx, ub + x + 1, vb + x + 1, t));
      Store16(below_left + x + 1, AgreesAvx512(ux, vx, ub + x - 1, vb + x - 1, t));
    }
  }
#endif
  for (; x < n; ++x) {
    below[x + 1] = Agrees(u[x], v[x], ub[x], vb[x], tolerance);
    if (x + 1 < n) below_right[x + 1] = Agrees(u[x], v[x], ub[x + 1], vb[x + 1], tolerance);
    below_left[x + 1] = Agrees(u[x], v[x], ub[x - 1], vb[x - 1], tolerance);
  }
}

// Appends to `flagged` the x of every valid pixel of row y with fewer than
// `min_neighbours` agreeing neighbours among its 8: left and right (`row_right`, laid out
// as the pair arrays), the three above (pairs of rows y − 1, y) and the three below (rows
// y, y + 1). `flag` is scratch of n bytes.
void CollectSpeckles(const uint8_t* __restrict up, const uint8_t* __restrict up_left,
                     const uint8_t* __restrict up_right, const uint8_t* __restrict down,
                     const uint8_t* __restrict down_right, const uint8_t* __restrict down_left,
                     const uint8_t* __restrict row_right, const uint8_t* __restrict mask, int n,
                     int min_neighbours, uint8_t* __restrict flag, std::vector<int>* flagged) {
  int x = 0;
#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
  if (!UsePortableKernelsForTesting()) {
    // Counts of at most 8 in bytes; a valid pixel is flagged when its count is below the
    // minimum, 64 pixels per step, and the flagged ones are visited bit by bit.
    const auto load = [](const uint8_t* p) { return _mm512_loadu_si512(p); };
    const __m512i minimum = _mm512_set1_epi8(static_cast<char>(std::min(min_neighbours, 9)));
    for (; x + 64 <= n; x += 64) {
      __m512i count = _mm512_add_epi8(load(row_right + x), load(row_right + x + 1));
      count = _mm512_add_epi8(count, _mm512_add_epi8(load(up + x + 1), load(down + x + 1)));
      count = _mm512_add_epi8(count, _mm512_add_epi8(load(up_left + x), load(up_right + x + 2)));
      count = _mm512_add_epi8(count,
                              _mm512_add_epi8(load(down_right + x + 1), load(down_left + x + 1)));
      const __m512i valid = load(mask + x);
      uint64_t bits = _mm512_mask_cmplt_epu8_mask(_mm512_test_epi8_mask(valid, valid), count,
                                                  minimum);
      while (bits != 0) {
        flagged->push_back(x + __builtin_ctzll(bits));
        bits &= bits - 1;
      }
    }
  }
#endif
  // The rest: flags first (a loop GCC vectorises), then the flagged ones, skipping 8
  // pixels at a time while none is (the common case).
  const int first = x;
  for (; x < n; ++x) {
    const int count = row_right[x] + row_right[x + 1] + up[x + 1] + down[x + 1] + up_left[x] +
                      up_right[x + 2] + down_right[x + 1] + down_left[x + 1];
    flag[x] = static_cast<uint8_t>((mask[x] != 0) & (count < min_neighbours));
  }
  for (x = first; x < n; ++x) {
    if (((x - first) & 7) == 0 && x + 8 <= n) {
      uint64_t word = 0;
      std::memcpy(&word, flag + x, sizeof(word));
      if (word == 0) {
        x += 7;
        continue;
      }
    }
    if (flag[x] != 0) flagged->push_back(x);
  }
}

}  // namespace

SpeckleFilter::PairAgreements::PairAgreements(int cols)
    : below(cols + 2, 0), below_right(cols + 2, 0), below_left(cols + 2, 0) {}

SpeckleFilter::SpeckleFilter(int min_neighbours, float tolerance, CorrespondenceMap* map,
                             int first_row, int end_row)
    : min_neighbours_(min_neighbours),
      tolerance_(tolerance),
      map_(map),
      rows_(map->mask.rows),
      cols_(map->mask.cols),
      first_row_(first_row),
      end_row_(end_row < 0 ? rows_ : end_row),
      next_row_(first_row),
      zeros_(cols_, 0.0f),
      missing_(cols_, kNaN),
      flag_(cols_),
      row_right_(cols_ + 2, 0),
      above_(cols_),
      next_(cols_) {}

const float* SpeckleFilter::Row(const cv::Mat& image, int y) const {
  if (y < 0 || y >= rows_) return missing_.data();
  return image.empty() ? zeros_.data() : image.ptr<float>(y);
}

void SpeckleFilter::Pairs(int y, PairAgreements* pairs) const {
  RowPairAgreements(Row(map_->proj_x, y), Row(map_->proj_y, y), Row(map_->proj_x, y + 1),
                    Row(map_->proj_y, y + 1), cols_, tolerance_, pairs->below.data(),
                    pairs->below_right.data(), pairs->below_left.data());
}

void SpeckleFilter::Clear(int y, const std::vector<int>& xs) {
  uint8_t* mask = map_->mask.ptr<uint8_t>(y);
  float* confidence = map_->confidence.ptr<float>(y);
  float* u = map_->HasX() ? map_->proj_x.ptr<float>(y) : nullptr;
  float* v = map_->HasY() ? map_->proj_y.ptr<float>(y) : nullptr;
  for (int x : xs) {
    mask[x] = 0;
    confidence[x] = 0.0f;
    if (u != nullptr) u[x] = kNaN;
    if (v != nullptr) v[x] = kNaN;
  }
}

// Flags row y from the unfiltered rows y − 1 … y + 1, then clears row y − 1's flags (which
// row y's decisions had to see unfiltered), or keeps them when it is the first row.
void SpeckleFilter::FilterRow(int y) {
  // Above the image the pairs stay 0 (nothing agrees with a missing row).
  if (y == first_row_ && y > 0) Pairs(y - 1, &above_);
  RowAgreements(Row(map_->proj_x, y), Row(map_->proj_y, y), cols_, tolerance_,
                row_right_.data());
  Pairs(y, &next_);
  // Above: (y − 1, x − 1) → (y, x) is the pair below-right of (y − 1, x − 1), etc.
  cleared_current_.clear();
  CollectSpeckles(above_.below.data(), above_.below_right.data(), above_.below_left.data(),
                  next_.below.data(), next_.below_right.data(), next_.below_left.data(),
                  row_right_.data(), map_->mask.ptr<uint8_t>(y), cols_, min_neighbours_,
                  flag_.data(), &cleared_current_);
  std::swap(above_, next_);
  if (y - 1 == first_row_) {
    first_row_flags_.swap(cleared_previous_);
  } else if (y > first_row_) {
    Clear(y - 1, cleared_previous_);
  }
  std::swap(cleared_previous_, cleared_current_);
}

void SpeckleFilter::RowsDecoded(int rows) {
  // Row y needs row y + 1, the image's last row none.
  const int last = std::min(end_row_, rows >= rows_ ? rows_ : rows - 1);
  while (next_row_ < last) FilterRow(next_row_++);
}

void SpeckleFilter::Finish() {
  RowsDecoded(rows_);
  if (next_row_ > first_row_) last_row_flags_.swap(cleared_previous_);
  cleared_previous_.clear();
}

void SpeckleFilter::ClearEdges() {
  if (end_row_ > first_row_) Clear(end_row_ - 1, last_row_flags_);
  if (end_row_ - 1 > first_row_) Clear(first_row_, first_row_flags_);
  last_row_flags_.clear();
  first_row_flags_.clear();
}

void RemoveSpeckles(int min_neighbours, float tolerance, CorrespondenceMap* map) {
  SpeckleFilter filter(min_neighbours, tolerance, map);
  filter.Finish();
  filter.ClearEdges();
}

BandedSpeckleFilter::BandedSpeckleFilter(
    int min_neighbours, float tolerance, CorrespondenceMap* map,
    const std::vector<std::pair<size_t, size_t>>& worker_pixels)
    : min_neighbours_(min_neighbours), tolerance_(tolerance), map_(map) {
  const size_t cols = static_cast<size_t>(map->mask.cols);
  const int rows = map->mask.rows;
  const size_t total = cols * static_cast<size_t>(rows);
  for (const auto& [begin, end] : worker_pixels) {
    // The rows a worker can filter alone: those whose rows above and below are its own
    // whole rows (or beyond the image).
    const int first_whole = static_cast<int>((begin + cols - 1) / cols);
    const int end_whole = static_cast<int>(end / cols);
    const int first = begin == 0 ? 0 : first_whole + 1;
    const int last = end >= total ? rows : end_whole - 1;
    bands_.push_back(first < last ? std::make_unique<SpeckleFilter>(min_neighbours, tolerance,
                                                                    map, first, last)
                                  : nullptr);
  }
}

void BandedSpeckleFilter::PixelsDecoded(size_t worker, size_t end) {
  if (bands_[worker] == nullptr) return;
  bands_[worker]->RowsDecoded(static_cast<int>(end / static_cast<size_t>(map_->mask.cols)));
}

void BandedSpeckleFilter::Finish() {
  std::vector<std::unique_ptr<SpeckleFilter>> filters;
  int row = 0;  // the rows between the bands
  for (const auto& band : bands_) {
    if (band == nullptr) continue;
    band->Finish();
    if (row < band->first_row()) {
      filters.push_back(std::make_unique<SpeckleFilter>(min_neighbours_, tolerance_, map_, row,
                                                        band->first_row()));
      filters.back()->Finish();
    }
    row = band->end_row();
  }
  if (row < map_->mask.rows) {
    filters.push_back(std::make_unique<SpeckleFilter>(min_neighbours_, tolerance_, map_, row));
    filters.back()->Finish();
  }
  for (auto& band : bands_) {
    if (band != nullptr) band->ClearEdges();
  }
  for (auto& filter : filters) filter->ClearEdges();
}

}  // namespace internal
}  // namespace sope
