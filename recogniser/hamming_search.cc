#include "recogniser/hamming_search.h"

#include <algorithm>
#include <cstddef>
#include <cstring>

#if defined(__x86_64__)
#include <immintrin.h>
#define SOPE_HAMMING_X86 1
#else
#define SOPE_HAMMING_X86 0
#endif

#include "core/error.h"

namespace sope {
namespace internal {

// Running k-best selection over a scan in ascending index order. `threshold` T is the
// k-th smallest distance seen so far (bits + 1 until k codes were seen); a new code can
// only enter the result if its distance is < T, because k earlier codes (lower indices,
// which win ties) already have distance ≤ T. `below` = number of candidates with
// distance < T, maintained with a histogram of candidate distances.
struct KBestState {
  KBestState(int bits, int k_in)
      : k(k_in),
        threshold(bits + 1),
        prune_size(2 * static_cast<size_t>(k_in) + 1024),
        histogram(bits + 2, 0) {  // + 2: distance 0..bits, plus one for Finish's offsets
    candidates.reserve(std::min<size_t>(prune_size, 64 + static_cast<size_t>(k_in)));
  }

  void Offer(int distance, int64_t index) {
    if (distance >= threshold) return;
    candidates.push_back({distance, static_cast<int32_t>(index)});
    ++histogram[distance];
    if (++below >= k) {
      do {
        --threshold;
        below -= histogram[threshold];
      } while (below >= k);
      if (candidates.size() >= prune_size) Prune();
    }
  }

  // Drops candidates that can no longer be in the result: distance > T, and those at
  // distance T after the first k − below (the list is in index order).
  void Prune() {
    int keep_at_threshold = k - below;
    size_t out = 0;
    for (const HammingMatch& match : candidates) {
      if (match.hamming_distance < threshold ||
          (match.hamming_distance == threshold && keep_at_threshold-- > 0)) {
        candidates[out++] = match;
      }
    }
    candidates.resize(out);
  }

  // The result: Prune leaves exactly the min(k, seen) best in index order; a counting
  // sort by distance (stable, so ties stay in index order) finishes in O(k + bits).
  std::vector<HammingMatch> Finish() {
    Prune();
    std::fill(histogram.begin(), histogram.end(), 0);
    for (const HammingMatch& match : candidates) ++histogram[match.hamming_distance + 1];
    for (size_t d = 1; d < histogram.size(); ++d) histogram[d] += histogram[d - 1];
    std::vector<HammingMatch> sorted(candidates.size());
    for (const HammingMatch& match : candidates)
      sorted[histogram[match.hamming_distance]++] = match;
    return sorted;
  }

  int k;
  int threshold;
  int below = 0;
  size_t prune_size;
  std::vector<int32_t> histogram;
  std::vector<HammingMatch> candidates;  // ascending index order
};

// Radius matches; `matches` keeps ≥ 8 entries of slack so vector kernels can store a
// whole register and advance `count` by the number of valid lanes.
struct RadiusState {
  explicit RadiusState(int radius_in) : radius(radius_in) {}

  HammingMatch* Reserve(size_t extra) {
    if (count + extra > matches.size()) {
      matches.resize(std::max({2 * matches.size(), count + extra, size_t{1024}}));
    }
    return matches.data() + count;
  }
  // Capacity may exceed the size by up to 2× (no shrinking copy of a large result).
  std::vector<HammingMatch> Finish() {
    matches.resize(count);
    return std::move(matches);
  }

  int radius;
  size_t count = 0;
  std::vector<HammingMatch> matches;
};

namespace {

// ---------------------------------------------------------------------------------------
// Scalar kernel: one POPCNT per word. W = words per code (0: run-time `words`).

template <int W>
inline int DistanceScalar(const uint64_t* a, const uint64_t* b, int words) {
  const int n = W > 0 ? W : words;
  int distance = 0;
  for (int w = 0; w < n; ++w) distance += __builtin_popcountll(a[w] ^ b[w]);
  return distance;
}

template <int W>
void KBestScanScalar(const uint64_t* codes, int words, int64_t begin, int64_t end,
                     const uint64_t* query, KBestState* state) {
  const int stride = W > 0 ? W : words;
  const uint64_t* code = codes + begin * stride;
  int threshold = state->threshold;
  for (int64_t i = begin; i < end; ++i, code += stride) {
    const int distance = DistanceScalar<W>(code, query, words);
    if (distance < threshold) {
      state->Offer(distance, i);
      threshold = state->threshold;
    }
  }
}

template <int W>
void RadiusScanScalar(const uint64_t* codes, int words, int64_t begin, int64_t end,
                      const uint64_t* query, RadiusState* state) {
  const int stride = W > 0 ? W : words;
  const uint64_t* code = codes + begin * stride;
  const int radius = state->radius;
  for (int64_t i = begin; i < end; ++i, code += stride) {
    const int distance = DistanceScalar<W>(code, query, words);
    if (distance <= radius) {
      *state->Reserve(1) = {distance, static_cast<int32_t>(i)};
      ++state->count;
    }
  }
}

}  // namespace

#if SOPE_HAMMING_X86
// ---------------------------------------------------------------------------------------
// AVX2: popcount of each 64-bit lane by a 16-entry nibble table (vpshufb) summed with
// vpsadbw (Muła, Kurz & Lemire, "Faster population counts using AVX2 instructions",
// Computer Journal 2018). Compiled for AVX2 whatever the build flags; used only when the
// CPU has it.
#pragma GCC push_options
#pragma GCC target("avx2,popcnt")
namespace {

inline __m256i Popcount64Avx2(__m256i v) {
  const __m256i lookup = _mm256_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4,  //
                                          0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
  const __m256i low_nibble = _mm256_set1_epi8(0x0f);
  const __m256i lo = _mm256_and_si256(v, low_nibble);
  const __m256i hi = _mm256_and_si256(_mm256_srli_epi16(v, 4), low_nibble);
  const __m256i per_byte =
      _mm256_add_epi8(_mm256_shuffle_epi8(lookup, lo), _mm256_shuffle_epi8(lookup, hi));
  return _mm256_sad_epu8(per_byte, _mm256_setzero_si256());
}

inline __m256i LoadAvx2(const uint64_t* p) {
  return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p));
}

// The query replicated to fill a 256-bit register (W words per code).
template <int W>
inline __m256i QueryAvx2(const uint64_t* query) {
  if constexpr (W == 1) {
    return _mm256_set1_epi64x(static_cast<long long>(query[0]));
  } else if constexpr (W == 2) {
    return _mm256_setr_epi64x(query[0], query[1], query[0], query[1]);
  } else {
    return LoadAvx2(query);
  }
}

// Distances of the 4 codes at `codes`, one per 64-bit lane, in order.
template <int W>
inline __m256i Distances4Avx2(const uint64_t* codes, __m256i q) {
  if constexpr (W == 1) {
    return Popcount64Avx2(_mm256_xor_si256(LoadAvx2(codes), q));
  } else if constexpr (W == 2) {
    const __m256i a = Popcount64Avx2(_mm256_xor_si256(LoadAvx2(codes), q));      // c0 c0 c1 c1
    const __m256i b = Popcount64Avx2(_mm256_xor_si256(LoadAvx2(codes + 4), q));  // c2 c2 c3 c3
    const __m256i sum =
        _mm256_add_epi64(_mm256_unpacklo_epi64(a, b), _mm256_unpackhi_epi64(a, b));  // c0 c2 c1 c3
    return _mm256_permute4x64_epi64(sum, _MM_SHUFFLE(3, 1, 2, 0));
  } else {
    static_assert(W == 4, "AVX2 kernel handles 1, 2 or 4 words");
    const __m256i s0 = Popcount64Avx2(_mm256_xor_si256(LoadAvx2(codes), q));
    const __m256i s1 = Popcount64Avx2(_mm256_xor_si256(LoadAvx2(codes + 4), q));
    const __m256i s2 = Popcount64Avx2(_mm256_xor_si256(LoadAvx2(codes + 8), q));
    const __m256i s3 = Popcount64Avx2(_mm256_xor_si256(LoadAvx2(codes + 12), q));
    // [c0 lo, c1 lo, c0 hi, c1 hi] and [c2 lo, c3 lo, c2 hi, c3 hi].
    const __m256i t01 =
        _mm256_add_epi64(_mm256_unpacklo_epi64(s0, s1), _mm256_unpackhi_epi64(s0, s1));
    const __m256i t23 =
        _mm256_add_epi64(_mm256_unpacklo_epi64(s2, s3), _mm256_unpackhi_epi64(s2, s3));
    return _mm256_add_epi64(_mm256_permute2x128_si256(t01, t23, 0x20),
                            _mm256_permute2x128_si256(t01, t23, 0x31));
  }
}

// Bit j set when lane j of `distances` < `bound` (both non-negative).
inline unsigned LessMaskAvx2(__m256i distances, __m256i bound) {
  return static_cast<unsigned>(
      _mm256_movemask_pd(_mm256_castsi256_pd(_mm256_cmpgt_epi64(bound, distances))));
}

template <int W>
void KBestScanAvx2(const uint64_t* codes, int words, int64_t begin, int64_t end,
                   const uint64_t* query, KBestState* state) {
  const __m256i q = QueryAvx2<W>(query);
  __m256i bound = _mm256_set1_epi64x(state->threshold);
  int64_t i = begin;
  for (; i + 8 <= end; i += 8) {
    const __m256i d0 = Distances4Avx2<W>(codes + i * W, q);
    const __m256i d1 = Distances4Avx2<W>(codes + (i + 4) * W, q);
    unsigned mask = LessMaskAvx2(d0, bound) | (LessMaskAvx2(d1, bound) << 4);
    if (mask != 0) {
      alignas(32) uint64_t distance[8];
      _mm256_store_si256(reinterpret_cast<__m256i*>(distance), d0);
      _mm256_store_si256(reinterpret_cast<__m256i*>(distance + 4), d1);
      while (mask != 0) {
        const int lane = __builtin_ctz(mask);
        mask &= mask - 1;
        state->Offer(static_cast<int>(distance[lane]), i + lane);
      }
      bound = _mm256_set1_epi64x(state->threshold);
    }
  }
  KBestScanScalar<W>(codes, words, i, end, query, state);
}

template <int W>
void RadiusScanAvx2(const uint64_t* codes, int words, int64_t begin, int64_t end,
                    const uint64_t* query, RadiusState* state) {
  const __m256i q = QueryAvx2<W>(query);
  const __m256i bound = _mm256_set1_epi64x(state->radius + 1);
  int64_t i = begin;
  for (; i + 8 <= end; i += 8) {
    const __m256i d0 = Distances4Avx2<W>(codes + i * W, q);
    const __m256i d1 = Distances4Avx2<W>(codes + (i + 4) * W, q);
    unsigned mask = LessMaskAvx2(d0, bound) | (LessMaskAvx2(d1, bound) << 4);
    if (mask != 0) {
      alignas(32) uint64_t distance[8];
      _mm256_store_si256(reinterpret_cast<__m256i*>(distance), d0);
      _mm256_store_si256(reinterpret_cast<__m256i*>(distance + 4), d1);
      HammingMatch* out = state->Reserve(8);
      int n = 0;
      while (mask != 0) {
        const int lane = __builtin_ctz(mask);
        mask &= mask - 1;
        out[n++] = {static_cast<int32_t>(distance[lane]), static_cast<int32_t>(i + lane)};
      }
      state->count += n;
    }
  }
  RadiusScanScalar<W>(codes, words, i, end, query, state);
}

}  // namespace
#pragma GCC pop_options

// ---------------------------------------------------------------------------------------
// AVX-512 VPOPCNTDQ: XOR + VPOPCNTQ on 8 words at once; multi-word codes are summed with
// two-source permutes, so every vector holds the distances of 8 consecutive codes.
#pragma GCC push_options
#pragma GCC target("avx512f,avx512vpopcntdq,avx2,popcnt")
// GCC 12's intrinsics self-initialise an "undefined" register (__Y = __Y), which
// -Wuninitialized reports once inlined; nothing here reads uninitialised data.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
namespace {

inline __m512i Load512(const uint64_t* p) { return _mm512_loadu_si512(p); }

template <int W>
inline __m512i QueryAvx512(const uint64_t* query) {
  if constexpr (W == 1) {
    return _mm512_set1_epi64(static_cast<long long>(query[0]));
  } else if constexpr (W == 2) {
    return _mm512_broadcast_i32x4(_mm_loadu_si128(reinterpret_cast<const __m128i*>(query)));
  } else {
    return _mm512_broadcast_i64x4(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(query)));
  }
}

// Lanes (a0 a2 a4 a6 b0 b2 b4 b6) + (a1 a3 a5 a7 b1 b3 b5 b7): adjacent pairs summed.
inline __m512i PairSum(__m512i a, __m512i b) {
  const __m512i even = _mm512_setr_epi64(0, 2, 4, 6, 8, 10, 12, 14);
  const __m512i odd = _mm512_setr_epi64(1, 3, 5, 7, 9, 11, 13, 15);
  return _mm512_add_epi64(_mm512_permutex2var_epi64(a, even, b),
                          _mm512_permutex2var_epi64(a, odd, b));
}

template <int W>
inline __m512i Distances8Avx512(const uint64_t* codes, __m512i q) {
  if constexpr (W == 1) {
    return _mm512_popcnt_epi64(_mm512_xor_si512(Load512(codes), q));
  } else if constexpr (W == 2) {
    const __m512i p0 = _mm512_popcnt_epi64(_mm512_xor_si512(Load512(codes), q));
    const __m512i p1 = _mm512_popcnt_epi64(_mm512_xor_si512(Load512(codes + 8), q));
    return PairSum(p0, p1);
  } else {
    static_assert(W == 4, "AVX-512 kernel handles 1, 2 or 4 words");
    const __m512i p0 = _mm512_popcnt_epi64(_mm512_xor_si512(Load512(codes), q));
    const __m512i p1 = _mm512_popcnt_epi64(_mm512_xor_si512(Load512(codes + 8), q));
    const __m512i p2 = _mm512_popcnt_epi64(_mm512_xor_si512(Load512(codes + 16), q));
    const __m512i p3 = _mm512_popcnt_epi64(_mm512_xor_si512(Load512(codes + 24), q));
    return PairSum(PairSum(p0, p1), PairSum(p2, p3));
  }
}

inline void OfferMasked(__m512i distances, unsigned mask, int64_t first_index, KBestState* state) {
  alignas(64) uint64_t distance[8];
  _mm512_store_si512(distance, distances);
  while (mask != 0) {
    const int lane = __builtin_ctz(mask);
    mask &= mask - 1;
    state->Offer(static_cast<int>(distance[lane]), first_index + lane);
  }
}

template <int W>
void KBestScanAvx512(const uint64_t* codes, int words, int64_t begin, int64_t end,
                     const uint64_t* query, KBestState* state) {
  const __m512i q = QueryAvx512<W>(query);
  __m512i bound = _mm512_set1_epi64(state->threshold);
  int64_t i = begin;
  // Two vectors per iteration: one rarely-taken branch per 16 codes.
  for (; i + 16 <= end; i += 16) {
    const __m512i d0 = Distances8Avx512<W>(codes + i * W, q);
    const __m512i d1 = Distances8Avx512<W>(codes + (i + 8) * W, q);
    const __mmask8 m0 = _mm512_cmplt_epu64_mask(d0, bound);
    const __mmask8 m1 = _mm512_cmplt_epu64_mask(d1, bound);
    if ((m0 | m1) != 0) {
      OfferMasked(d0, m0, i, state);
      OfferMasked(d1, m1, i + 8, state);  // Offer re-checks against the updated T
      bound = _mm512_set1_epi64(state->threshold);
    }
  }
  for (; i + 8 <= end; i += 8) {
    const __m512i d = Distances8Avx512<W>(codes + i * W, q);
    const __mmask8 m = _mm512_cmplt_epu64_mask(d, bound);
    if (m != 0) {
      OfferMasked(d, m, i, state);
      bound = _mm512_set1_epi64(state->threshold);
    }
  }
  KBestScanScalar<W>(codes, words, i, end, query, state);
}

template <int W>
void RadiusScanAvx512(const uint64_t* codes, int words, int64_t begin, int64_t end,
                      const uint64_t* query, RadiusState* state) {
  static_assert(sizeof(HammingMatch) == 8 && offsetof(HammingMatch, hamming_distance) == 0 &&
                    offsetof(HammingMatch, index) == 4,
                "the radius kernel stores (index << 32 | distance) as one HammingMatch");
  const __m512i q = QueryAvx512<W>(query);
  const __m512i radius = _mm512_set1_epi64(state->radius);
  const __m512i lane_offset = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
  int64_t i = begin;
  // Branch-free: every group of 8 stores its compressed matches (possibly none) and
  // advances by their count, so a flagged fraction of a few percent costs no
  // mispredictions. Register-form compress + full store: the memory form of
  // VPCOMPRESSQ is microcoded on some CPUs.
  // Output pointer, count and capacity live in registers; the state is synced only when
  // the buffer grows.
  __m512i index = _mm512_add_epi64(_mm512_set1_epi64(i), lane_offset);
  const __m512i step = _mm512_set1_epi64(8);
  size_t count = state->count;
  HammingMatch* out = state->Reserve(8) - count;
  size_t capacity = state->matches.size();
  for (; i + 8 <= end; i += 8) {
    if (count + 8 > capacity) {
      state->count = count;
      out = state->Reserve(8) - count;
      capacity = state->matches.size();
    }
    const __m512i d = Distances8Avx512<W>(codes + i * W, q);
    const __mmask8 m = _mm512_cmple_epu64_mask(d, radius);
    const __m512i packed = _mm512_or_si512(d, _mm512_slli_epi64(index, 32));
    _mm512_storeu_si512(out + count, _mm512_maskz_compress_epi64(m, packed));
    count += __builtin_popcount(m);
    index = _mm512_add_epi64(index, step);
  }
  state->count = count;
  RadiusScanScalar<W>(codes, words, i, end, query, state);
}

}  // namespace
#pragma GCC diagnostic pop
#pragma GCC pop_options
#endif  // SOPE_HAMMING_X86

namespace {

KBestScanFn SelectKBestScan(PopcountKernel kernel, int words) {
#if SOPE_HAMMING_X86
  if (words == 1 || words == 2 || words == 4) {
    if (kernel == PopcountKernel::kAvx512) {
      return words == 1 ? KBestScanAvx512<1> : words == 2 ? KBestScanAvx512<2> : KBestScanAvx512<4>;
    }
    if (kernel == PopcountKernel::kAvx2) {
      return words == 1 ? KBestScanAvx2<1> : words == 2 ? KBestScanAvx2<2> : KBestScanAvx2<4>;
    }
  }
#endif
  switch (words) {
    case 1:
      return KBestScanScalar<1>;
    case 2:
      return KBestScanScalar<2>;
    case 3:
      return KBestScanScalar<3>;
    case 4:
      return KBestScanScalar<4>;
    default:
      return KBestScanScalar<0>;
  }
}

RadiusScanFn SelectRadiusScan(PopcountKernel kernel, int words) {
#if SOPE_HAMMING_X86
  if (words == 1 || words == 2 || words == 4) {
    if (kernel == PopcountKernel::kAvx512) {
      return words == 1   ? RadiusScanAvx512<1>
             : words == 2 ? RadiusScanAvx512<2>
                          : RadiusScanAvx512<4>;
    }
    if (kernel == PopcountKernel::kAvx2) {
      return words == 1 ? RadiusScanAvx2<1> : words == 2 ? RadiusScanAvx2<2> : RadiusScanAvx2<4>;
    }
  }
#endif
  switch (words) {
    case 1:
      return RadiusScanScalar<1>;
    case 2:
      return RadiusScanScalar<2>;
    case 3:
      return RadiusScanScalar<3>;
    case 4:
      return RadiusScanScalar<4>;
    default:
      return RadiusScanScalar<0>;
  }
}

}  // namespace
}  // namespace internal

std::string ToString(PopcountKernel kernel) {
  switch (kernel) {
    case PopcountKernel::kAuto:
      return "auto";
    case PopcountKernel::kScalar:
      return "scalar";
    case PopcountKernel::kAvx2:
      return "avx2";
    case PopcountKernel::kAvx512:
      return "avx512";
  }
  return "unknown";
}

PopcountKernel PopcountKernelFromString(const std::string& text) {
  for (PopcountKernel kernel : {PopcountKernel::kAuto, PopcountKernel::kScalar,
                                PopcountKernel::kAvx2, PopcountKernel::kAvx512}) {
    if (text == ToString(kernel)) return kernel;
  }
  SOPE_THROW("unknown popcount kernel '{}' (expected auto, scalar, avx2 or avx512)", text);
}

bool PopcountKernelAvailable(PopcountKernel kernel) {
  switch (kernel) {
    case PopcountKernel::kAuto:
    case PopcountKernel::kScalar:
      return true;
#if SOPE_HAMMING_X86
    case PopcountKernel::kAvx2:
      return __builtin_cpu_supports("avx2");
    case PopcountKernel::kAvx512:
      return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vpopcntdq");
#else
    default:
      return false;
#endif
  }
  return false;
}

void HammingSearchOptions::Check() const {
  SOPE_CHECK(PopcountKernelAvailable(kernel), "popcount kernel '{}' is not supported by this CPU",
             ToString(kernel));
  SOPE_CHECK(block_bytes >= 1024, "block_bytes must be ≥ 1024, got {}", block_bytes);
}

HammingIndex::HammingIndex(const BinaryCodes& database, const HammingSearchOptions& options)
    : options_(options) {
  options_.Check();
  database.Check();
  SOPE_CHECK(database.size() < (int64_t{1} << 31), "a Hamming index holds < 2^31 codes, got {}",
             database.size());
  bits_ = database.bits;
  words_per_code_ = database.words_per_code;
  num_codes_ = database.size();
  codes_.assign(database.words.begin(), database.words.end());
  kernel_ = options_.kernel;
  if (kernel_ == PopcountKernel::kAuto) {
    kernel_ = PopcountKernelAvailable(PopcountKernel::kAvx512) ? PopcountKernel::kAvx512
              : PopcountKernelAvailable(PopcountKernel::kAvx2) ? PopcountKernel::kAvx2
                                                               : PopcountKernel::kScalar;
  }
  kbest_scan_ = internal::SelectKBestScan(kernel_, words_per_code_);
  radius_scan_ = internal::SelectRadiusScan(kernel_, words_per_code_);
}

HammingIndex::QueryWords HammingIndex::MaskedQuery(const uint64_t* query) const {
  QueryWords masked;
  std::copy(query, query + words_per_code_, masked.begin());
  if (bits_ % 64 != 0) masked[words_per_code_ - 1] &= (uint64_t{1} << (bits_ % 64)) - 1;
  return masked;
}

int64_t HammingIndex::BlockCodes() const {
  const int64_t code_bytes = 8 * static_cast<int64_t>(words_per_code_);
  return std::max<int64_t>(64, options_.block_bytes / code_bytes / 64 * 64);
}

std::vector<HammingMatch> HammingIndex::KBestSearch(const uint64_t* query, int k) const {
  SOPE_CHECK(k >= 1, "k-best search needs k ≥ 1, got {}", k);
  const QueryWords masked = MaskedQuery(query);
  internal::KBestState state(bits_, k);
  kbest_scan_(codes_.data(), words_per_code_, 0, num_codes_, masked.data(), &state);
  return state.Finish();
}

std::vector<HammingMatch> HammingIndex::RadiusSearch(const uint64_t* query, int radius_bits) const {
  SOPE_CHECK(radius_bits <= bits_, "search radius {} exceeds the code length {} bits", radius_bits,
             bits_);
  if (radius_bits < 0) return {};
  const QueryWords masked = MaskedQuery(query);
  internal::RadiusState state(radius_bits);
  radius_scan_(codes_.data(), words_per_code_, 0, num_codes_, masked.data(), &state);
  return state.Finish();
}

std::vector<std::vector<HammingMatch>> HammingIndex::KBestSearch(const BinaryCodes& queries,
                                                                 int k) const {
  SOPE_CHECK(k >= 1, "k-best search needs k ≥ 1, got {}", k);
  SOPE_CHECK(queries.bits == bits_, "query codes have {} bits, the database {}", queries.bits,
             bits_);
  queries.Check();
  const int64_t num_queries = queries.size();
  std::vector<internal::KBestState> states(num_queries, internal::KBestState(bits_, k));
  const int64_t block = BlockCodes();
  for (int64_t begin = 0; begin < num_codes_; begin += block) {
    const int64_t end = std::min(num_codes_, begin + block);
    for (int64_t q = 0; q < num_queries; ++q) {
      kbest_scan_(codes_.data(), words_per_code_, begin, end, queries.code(q), &states[q]);
    }
  }
  std::vector<std::vector<HammingMatch>> results(num_queries);
  for (int64_t q = 0; q < num_queries; ++q) results[q] = states[q].Finish();
  return results;
}

std::vector<std::vector<HammingMatch>> HammingIndex::RadiusSearch(const BinaryCodes& queries,
                                                                  int radius_bits) const {
  SOPE_CHECK(queries.bits == bits_, "query codes have {} bits, the database {}", queries.bits,
             bits_);
  SOPE_CHECK(radius_bits <= bits_, "search radius {} exceeds the code length {} bits", radius_bits,
             bits_);
  queries.Check();
  const int64_t num_queries = queries.size();
  std::vector<std::vector<HammingMatch>> results(num_queries);
  if (radius_bits < 0) return results;
  std::vector<internal::RadiusState> states(num_queries, internal::RadiusState(radius_bits));
  const int64_t block = BlockCodes();
  for (int64_t begin = 0; begin < num_codes_; begin += block) {
    const int64_t end = std::min(num_codes_, begin + block);
    for (int64_t q = 0; q < num_queries; ++q) {
      radius_scan_(codes_.data(), words_per_code_, begin, end, queries.code(q), &states[q]);
    }
  }
  for (int64_t q = 0; q < num_queries; ++q) results[q] = states[q].Finish();
  return results;
}

std::vector<HammingMatch> BruteForceKBest(const BinaryCodes& database, const uint64_t* query,
                                          int k) {
  SOPE_CHECK(k >= 1, "k-best search needs k ≥ 1, got {}", k);
  std::vector<HammingMatch> all(database.size());
  for (int64_t i = 0; i < database.size(); ++i) {
    all[i] = {HammingDistance(database.code(i), query, database.words_per_code),
              static_cast<int32_t>(i)};
  }
  std::stable_sort(all.begin(), all.end(), [](const HammingMatch& a, const HammingMatch& b) {
    return a.hamming_distance < b.hamming_distance;
  });
  if (all.size() > static_cast<size_t>(k)) all.resize(k);
  return all;
}

}  // namespace sope
