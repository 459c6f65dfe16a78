// Exhaustive Hamming search over packed binary codes — the coarse stage of the thesis's
// hierarchical query (§4.6.2): flag the database entries within a Hamming radius of the
// query code (radius search) or the k nearest codes (k-best), then rank the flagged
// entries with finer features.
//
// The scan is XOR + hardware popcount over contiguous codes, specialised for 1, 2 and 4
// words per code (64/128/256 bits): with AVX-512 VPOPCNTDQ eight codes per vector, with
// AVX2 a vpshufb nibble-table popcount (Muła, Kurz & Lemire 2018), else scalar POPCNT.
// The kernel is chosen at run time from the CPU, so builds without -march=native still
// use the vector units. k-best selection does not keep a heap: distances are small
// integers, so it keeps a histogram of the candidate distances and the running k-th
// smallest distance T; a code is looked at only when its distance is < T, which after
// the first few thousand codes is rare, so the inner loop is a vector compare.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <new>
#include <string>
#include <vector>

#include "recogniser/hashing.h"

namespace sope {

// One search hit. Layout (distance then index, 32 bits each) is relied on by the
// AVX-512 radius kernel.
struct HammingMatch {
  int32_t hamming_distance = 0;  // bits
  int32_t index = 0;             // row of the code in the database
  bool operator==(const HammingMatch& other) const {
    return hamming_distance == other.hamming_distance && index == other.index;
  }
  bool operator!=(const HammingMatch& other) const { return !(*this == other); }
};

enum class PopcountKernel {
  kAuto,    // "auto": the fastest one the CPU supports
  kScalar,  // "scalar": one POPCNT per 64-bit word
  kAvx2,    // "avx2": vpshufb nibble lookup + vpsadbw, 4 words per instruction chain
  kAvx512,  // "avx512": VPOPCNTQ, 8 words per instruction
};
std::string ToString(PopcountKernel kernel);
PopcountKernel PopcountKernelFromString(const std::string& text);
// Whether `kernel` is compiled in and supported by this CPU (kAuto and kScalar: always).
bool PopcountKernelAvailable(PopcountKernel kernel);

struct HammingSearchOptions {
  // Popcount implementation; an explicit kernel the CPU lacks is an error.
  PopcountKernel kernel = PopcountKernel::kAuto;
  // Batch queries scan the database in blocks of this many bytes, each block against
  // every query of the batch, so the block stays in cache (L2-sized by default).
  int64_t block_bytes = 256 * 1024;
  void Check() const;
};

namespace internal {

// 64-byte aligned storage for the database codes (vector loads never split a line).
template <typename T>
struct CacheAlignedAllocator {
  using value_type = T;
  static constexpr std::align_val_t kAlignment{64};
  CacheAlignedAllocator() = default;
  template <typename U>
  CacheAlignedAllocator(const CacheAlignedAllocator<U>&) {}
  T* allocate(size_t n) { return static_cast<T*>(::operator new(n * sizeof(T), kAlignment)); }
  void deallocate(T* p, size_t) { ::operator delete(p, kAlignment); }
  template <typename U>
  bool operator==(const CacheAlignedAllocator<U>&) const {
    return true;
  }
  template <typename U>
  bool operator!=(const CacheAlignedAllocator<U>&) const {
    return false;
  }
};

struct KBestState;
struct RadiusState;
using KBestScanFn = void (*)(const uint64_t* codes, int words_per_code, int64_t begin, int64_t end,
                             const uint64_t* query, KBestState* state);
using RadiusScanFn = void (*)(const uint64_t* codes, int words_per_code, int64_t begin, int64_t end,
                              const uint64_t* query, RadiusState* state);

}  // namespace internal

// An immutable database of binary codes with exhaustive Hamming search. Searches are
// const, single-threaded and safe to call concurrently.
class HammingIndex {
 public:
  // Copies `database` into aligned storage. Throws sope::Error when the codes are
  // inconsistent (BinaryCodes::Check), hold ≥ 2³¹ codes, or on invalid options.
  explicit HammingIndex(const BinaryCodes& database, const HammingSearchOptions& options = {});

  int bits() const { return bits_; }
  int words_per_code() const { return words_per_code_; }
  int64_t size() const { return num_codes_; }
  // The kernel actually used (kAuto resolved).
  PopcountKernel kernel() const { return kernel_; }
  const uint64_t* code(int64_t index) const { return codes_.data() + index * words_per_code_; }

  // The min(k, size()) codes nearest to `query` (words_per_code() words; padding bits
  // are ignored), sorted by Hamming distance, ties by ascending index — the same result
  // as a stable sort of all distances. Throws sope::Error if k < 1.
  std::vector<HammingMatch> KBestSearch(const uint64_t* query, int k) const;
  // Every code within `radius_bits` of `query` (distance ≤ radius), in ascending index
  // order. A negative radius flags nothing. Throws sope::Error if radius_bits > bits().
  std::vector<HammingMatch> RadiusSearch(const uint64_t* query, int radius_bits) const;

  // Batch forms: one result per row of `queries` (same bit length as the database),
  // computed block-wise so each database block is read from memory once per batch.
  std::vector<std::vector<HammingMatch>> KBestSearch(const BinaryCodes& queries, int k) const;
  std::vector<std::vector<HammingMatch>> RadiusSearch(const BinaryCodes& queries,
                                                      int radius_bits) const;

 private:
  // `query` with its padding bits cleared (a stack copy: no allocation per query).
  using QueryWords = std::array<uint64_t, BinaryCodes::kMaxBits / 64>;
  QueryWords MaskedQuery(const uint64_t* query) const;
  int64_t BlockCodes() const;

  int bits_ = 0;
  int words_per_code_ = 0;
  int64_t num_codes_ = 0;
  HammingSearchOptions options_;
  PopcountKernel kernel_ = PopcountKernel::kScalar;
  internal::KBestScanFn kbest_scan_ = nullptr;
  internal::RadiusScanFn radius_scan_ = nullptr;
  std::vector<uint64_t, internal::CacheAlignedAllocator<uint64_t>> codes_;
};

// Reference implementation for tests and benchmarks: all distances, stable-sorted.
std::vector<HammingMatch> BruteForceKBest(const BinaryCodes& database, const uint64_t* query,
                                          int k);

}  // namespace sope
