// Internal to calibration/triangulation.cc and triangulation_exact.cc: the per-row front
// and back ends of the fast path — picking a camera row's candidate pixels (mask ∧ region)
// together with their camera rays and decoded coordinates as contiguous arrays, and writing
// the accepted points, their pixels and the row of the depth image back out in row order —
// and the input checks both paths share.
//
// Both are compaction (a data-dependent number of outputs per input), which GCC does not
// vectorise: with AVX-512 (F, BW, VL) they use its compress / expand instructions, 16
// pixels per step; elsewhere plain loops with the same results.
#pragma once

#include <cstdint>
#include <cstring>
#include <limits>

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>
#include <opencv2/core/types.hpp>

#include "core/rig_calibration.h"
#include "decoder/decoder.h"

#if defined(__AVX512F__) && defined(__AVX512BW__) && defined(__AVX512VL__)
#include <immintrin.h>
#define SOPE_TRIANGULATION_AVX512 1
#else
#define SOPE_TRIANGULATION_AVX512 0
#endif

namespace sope::triangulation_rows {

// Throws sope::Error when the map (or the white image, when not empty) disagrees with the
// calibration in camera or projector size, or the white image's type is not supported.
void CheckInputs(const RigCalibration& calibration, const CorrespondenceMap& map,
                 const cv::Mat& white);

// Extra entries every output array of SelectCandidates needs past the row's width (a step
// stores 16 lanes whatever it keeps).
constexpr int kSlack = 16;

// One camera row's inputs over [x_begin, x_end): mask (non-zero = decoded), region
// (nullptr = every pixel), the camera-ray table row (x/z, y/z interleaved) and the decoded
// coordinates (nullptr = axis not coded: NaN).
struct RowInputs {
  const uint8_t* mask = nullptr;
  const uint8_t* region = nullptr;
  const float* rays = nullptr;
  const float* map_x = nullptr;
  const float* map_y = nullptr;
  int x_begin = 0, x_end = 0;
  // The same arrays one row down (nullptr: none), prefetched while this row is picked:
  // the hardware prefetchers lose track of the four row streams at each row's end.
  const uint8_t* next_mask = nullptr;
  const float* next_rays = nullptr;
  const float* next_map_x = nullptr;
  const float* next_map_y = nullptr;
};

#if SOPE_TRIANGULATION_AVX512
// EmitRow's permutations from three registers of 16 x, y and z values to 48 interleaved
// floats: output float f of a group is component f % 3 of point f / 3 — in register v,
// lane l: pick_xy[v][l] from (x, y) (y as index 16 + point) or, where is_z[v] has bit l,
// pick_z[v][l] from z.
struct InterleaveTables {
  alignas(64) int32_t pick_xy[3][16] = {};
  alignas(64) int32_t pick_z[3][16] = {};
  __mmask16 is_z[3] = {};
  constexpr InterleaveTables() {
    for (int v = 0; v < 3; ++v) {
      for (int lane = 0; lane < 16; ++lane) {
        const int f = 16 * v + lane, point = f / 3, component = f % 3;
        pick_xy[v][lane] = component == 1 ? 16 + point : point;
        pick_z[v][lane] = point;
        if (component == 2) is_z[v] = static_cast<__mmask16>(is_z[v] | (1u << lane));
      }
    }
  }
};

// The candidates (mask ∧ region) among the pixels x … x + 15 that `tail` keeps.
inline __mmask16 CandidateLanes(const RowInputs& in, int x, __mmask16 tail) {
  const __m128i m = _mm_maskz_loadu_epi8(tail, in.mask + x);
  __mmask16 keep = _mm_mask_test_epi8_mask(tail, m, m);
  if (in.region != nullptr) {
    const __m128i r = _mm_maskz_loadu_epi8(tail, in.region + x);
    keep = _mm_mask_test_epi8_mask(keep, r, r);
  }
  return keep;
}
#endif

// The candidates' columns, rays and coordinates, in column order; returns their number.
// Every output array holds at least (x_end − x_begin) + kSlack entries.
inline int SelectCandidates(const RowInputs& in, int* __restrict xs, float* __restrict ray_x,
                            float* __restrict ray_y, float* __restrict coded_u,
                            float* __restrict coded_v) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  int n = 0;
#if SOPE_TRIANGULATION_AVX512
  const __m512i iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512i even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
  const __m512i odd = _mm512_add_epi32(even, _mm512_set1_epi32(1));
  const __m512 nan = _mm512_set1_ps(kNaN);
  for (int x = in.x_begin; x < in.x_end; x += 16) {
    if (in.next_rays != nullptr) {
      __builtin_prefetch(in.next_rays + 2 * x, 0, 3);
      __builtin_prefetch(in.next_rays + 2 * x + 16, 0, 3);
      if (in.next_map_x != nullptr) __builtin_prefetch(in.next_map_x + x, 0, 3);
      if (in.next_map_y != nullptr) __builtin_prefetch(in.next_map_y + x, 0, 3);
      if ((x & 63) == 0) __builtin_prefetch(in.next_mask + x, 0, 3);
    }
    const int count = in.x_end - x < 16 ? in.x_end - x : 16;
    const __mmask16 tail = static_cast<__mmask16>((1u << count) - 1u);
    const __mmask16 keep = CandidateLanes(in, x, tail);
    if (keep == 0) continue;
    const __m512i columns = _mm512_add_epi32(_mm512_set1_epi32(x), iota);
    _mm512_storeu_si512(xs + n, _mm512_maskz_compress_epi32(keep, columns));
    const __m512 u = in.map_x ? _mm512_maskz_loadu_ps(tail, in.map_x + x) : nan;
    const __m512 v = in.map_y ? _mm512_maskz_loadu_ps(tail, in.map_y + x) : nan;
    _mm512_storeu_ps(coded_u + n, _mm512_maskz_compress_ps(keep, u));
    _mm512_storeu_ps(coded_v + n, _mm512_maskz_compress_ps(keep, v));
    const __mmask16 low = static_cast<__mmask16>(count >= 8 ? 0xFFFFu : (1u << (2 * count)) - 1u);
    const __mmask16 high =
        static_cast<__mmask16>(count <= 8 ? 0u : count == 16 ? 0xFFFFu : (1u << (2 * (count - 8))) - 1u);
    const __m512 first = _mm512_maskz_loadu_ps(low, in.rays + 2 * x);
    const __m512 second = _mm512_maskz_loadu_ps(high, in.rays + 2 * x + 16);
    _mm512_storeu_ps(ray_x + n,
                     _mm512_maskz_compress_ps(keep, _mm512_permutex2var_ps(first, even, second)));
    _mm512_storeu_ps(ray_y + n,
                     _mm512_maskz_compress_ps(keep, _mm512_permutex2var_ps(first, odd, second)));
    n += __builtin_popcount(keep);
  }
#else
  for (int x = in.x_begin; x < in.x_end; ++x) {
    xs[n] = x;
    n += (in.mask[x] != 0) & (in.region == nullptr || in.region[x] != 0);
  }
  for (int i = 0; i < n; ++i) {
    const int x = xs[i];
    ray_x[i] = in.rays[2 * x];
    ray_y[i] = in.rays[2 * x + 1];
    coded_u[i] = in.map_x ? in.map_x[x] : kNaN;
    coded_v[i] = in.map_y ? in.map_y[x] : kNaN;
  }
#endif
  return n;
}

// Writes the accepted (ok[i] != 0) of the n candidates of camera row y to points / pixels
// from index 0 (the portable loop may also write up to n entries: every candidate, the
// accepted ones kept), and the row's depth over [x_begin, x_end)
// (z of an accepted candidate, NaN elsewhere; the caller fills the rest of the row).
// `z_or_nan` is scratch of n + kSlack floats. Returns the number accepted.
inline int EmitRow(const RowInputs& in, int y, const int* __restrict xs,
                   const float* __restrict px, const float* __restrict py,
                   const float* __restrict pz, const uint8_t* __restrict ok, int n,
                   float* __restrict z_or_nan, Eigen::Vector3f* __restrict points,
                   cv::Point* __restrict pixels, float* __restrict depth) {
  static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float), "packed xyz");
  static_assert(sizeof(cv::Point) == 2 * sizeof(int), "packed (x, y)");
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  for (int i = 0; i < n; ++i) z_or_nan[i] = ok[i] ? pz[i] : kNaN;
  int kept = 0;
#if SOPE_TRIANGULATION_AVX512
  // Depth: each 16 pixels take the next popcount(candidates) values, expanded to their
  // columns.
  const __m512 nan = _mm512_set1_ps(kNaN);
  int next = 0;
  for (int x = in.x_begin; x < in.x_end; x += 16) {
    const int count = in.x_end - x < 16 ? in.x_end - x : 16;
    const __mmask16 tail = static_cast<__mmask16>((1u << count) - 1u);
    const __mmask16 keep = CandidateLanes(in, x, tail);
    // A plain load and the register form of expand: the memory form is slow on AMD's
    // Zen 4 (as compress to memory is).
    _mm512_mask_storeu_ps(depth + x, tail,
                          _mm512_mask_expand_ps(nan, keep, _mm512_loadu_ps(z_or_nan + next)));
    next += __builtin_popcount(keep);
  }
  // Points and pixels: compress the accepted lanes, interleave to xyz / (x, y).
  static constexpr InterleaveTables kTables{};
  const __m512i pick_xy0 = _mm512_load_si512(kTables.pick_xy[0]);
  const __m512i pick_xy1 = _mm512_load_si512(kTables.pick_xy[1]);
  const __m512i pick_xy2 = _mm512_load_si512(kTables.pick_xy[2]);
  const __m512i pick_z0 = _mm512_load_si512(kTables.pick_z[0]);
  const __m512i pick_z1 = _mm512_load_si512(kTables.pick_z[1]);
  const __m512i pick_z2 = _mm512_load_si512(kTables.pick_z[2]);
  const __mmask16* is_z = kTables.is_z;
  const __m512i low_pairs = _mm512_setr_epi32(0, 16, 1, 16, 2, 16, 3, 16, 4, 16, 5, 16, 6, 16, 7, 16);
  const __m512i high_pairs =
      _mm512_setr_epi32(8, 16, 9, 16, 10, 16, 11, 16, 12, 16, 13, 16, 14, 16, 15, 16);
  const __m512i row = _mm512_set1_epi32(y);
  float* out_xyz = reinterpret_cast<float*>(points);
  int32_t* out_pixels = reinterpret_cast<int32_t*>(pixels);
  const auto first_bits = [](int bits) {
    return static_cast<__mmask16>(bits <= 0 ? 0u : bits >= 16 ? 0xFFFFu : (1u << bits) - 1u);
  };
  for (int i = 0; i < n; i += 16) {
    const int count = n - i < 16 ? n - i : 16;
    const __mmask16 tail = static_cast<__mmask16>((1u << count) - 1u);
    const __m128i o = _mm_maskz_loadu_epi8(tail, ok + i);
    const __mmask16 accept = _mm_mask_test_epi8_mask(tail, o, o);
    if (accept == 0) continue;
    const int c = __builtin_popcount(accept);
    const __m512 x = _mm512_maskz_compress_ps(accept, _mm512_loadu_ps(px + i));
    const __m512 y3 = _mm512_maskz_compress_ps(accept, _mm512_loadu_ps(py + i));
    const __m512 z = _mm512_maskz_compress_ps(accept, _mm512_loadu_ps(pz + i));
    const __m512 v0 = _mm512_mask_permutexvar_ps(_mm512_permutex2var_ps(x, pick_xy0, y3), is_z[0],
                                                 pick_z0, z);
    const __m512 v1 = _mm512_mask_permutexvar_ps(_mm512_permutex2var_ps(x, pick_xy1, y3), is_z[1],
                                                 pick_z1, z);
    const __m512 v2 = _mm512_mask_permutexvar_ps(_mm512_permutex2var_ps(x, pick_xy2, y3), is_z[2],
                                                 pick_z2, z);
    float* dst = out_xyz + 3 * kept;
    _mm512_mask_storeu_ps(dst, first_bits(3 * c), v0);
    _mm512_mask_storeu_ps(dst + 16, first_bits(3 * c - 16), v1);
    _mm512_mask_storeu_ps(dst + 32, first_bits(3 * c - 32), v2);
    const __m512i columns =
        _mm512_maskz_compress_epi32(accept, _mm512_loadu_si512(xs + i));
    int32_t* pix = out_pixels + 2 * kept;
    _mm512_mask_storeu_epi32(pix, first_bits(2 * c),
                             _mm512_permutex2var_epi32(columns, low_pairs, row));
    _mm512_mask_storeu_epi32(pix + 16, first_bits(2 * c - 16),
                             _mm512_permutex2var_epi32(columns, high_pairs, row));
    kept += c;
  }
#else
  std::fill(depth + in.x_begin, depth + in.x_end, kNaN);
  for (int i = 0; i < n; ++i) {
    const int x = xs[i];
    points[kept] = Eigen::Vector3f(px[i], py[i], pz[i]);
    pixels[kept] = cv::Point(x, y);
    depth[x] = z_or_nan[i];
    kept += ok[i] != 0;
  }
#endif
  return kept;
}

}  // namespace sope::triangulation_rows
