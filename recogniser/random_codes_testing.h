// Uniformly random binary codes for the hashing, Hamming-search and FAISS tests (one
// definition, so the tests of one binary can be compiled together).
#pragma once

#include <cstdint>
#include <random>

#include "recogniser/hashing.h"

namespace sope::testing {

// `count` codes of `bits` bits, each bit a fair coin of std::mt19937_64(seed).
inline BinaryCodes RandomCodes(int bits, int64_t count, uint64_t seed) {
  std::mt19937_64 rng(seed);
  BinaryCodes codes(bits, count);
  for (int64_t i = 0; i < count; ++i) {
    for (int b = 0; b < bits; ++b) codes.SetBit(i, b, (rng() & 1u) != 0);
  }
  return codes;
}

}  // namespace sope::testing
