// SplitMix64 (Steele, Lea, Flood 2014): a tiny seeded generator that gives the same numbers
// on every platform and standard library, for scenes and queries that must reproduce from
// their seed.
#pragma once

#include <cstdint>

namespace sope {

struct SplitMix {
  uint64_t state;
  uint64_t Next() {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  double Uniform() { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }  // [0, 1)
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }
};

}  // namespace sope
