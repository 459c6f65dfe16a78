// Decoder internals shared by decoder.cc and its tests: the decoding plan resolved from a
// manifest, the code → coordinate table and the robust per-bit classification. Not part
// of the public API.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "core/frame_set.h"
#include "decoder/decoder.h"

namespace sope {
namespace internal {

// Tests: the decoders' SIMD kernels (AVX-512 builds) have portable loops that give the same
// bits; true makes every decode use the portable loops (decoder_test compares the two).
// Process-wide; not for concurrent decodes.
bool UsePortableKernelsForTesting();
void SetPortableKernelsForTesting(bool portable);

// Which frames decide one bit: the pattern and its inverse, or the pattern against the
// per-pixel threshold (white + black) / 2 when `inverse` < 0.
struct BitFrames {
  int pattern = -1;
  int inverse = -1;
};

struct AxisPlan {
  bool coded = false;
  int projector_size = 0;  // projector pixels along the axis
  int lowest_bit = 0;      // omitted low bits: the coordinate step is 2^lowest_bit
  PatternCode code = PatternCode::kGray;
  // Present bits from the most significant down: the code word is built as
  // code ← 2·code + bit, so it ends as the top (bits − lowest_bit) bits of the code.
  std::vector<BitFrames> bits_msb_first;
};

// Everything Decode needs, resolved once from the manifest and the options.
struct DecodePlan {
  std::array<AxisPlan, 2> axes;  // indexed by PatternAxis
  int white = -1;                // frame indices, −1 when absent
  int black = -1;
  BitDecision mode = BitDecision::kAuto;  // kAuto/kThreshold/kRobust as resolved
  bool any_threshold_bit = false;         // some bit is decided against (white + black) / 2
  // kRobust: frames whose per-pixel max/min estimate the direct and global light.
  std::vector<int> direct_global_frames;
};

// Resolves the frames of every bit; throws sope::Error when the set cannot be decoded
// with the requested mode (threshold without white/black, robust without inverses).
DecodePlan MakeDecodePlan(const FrameSetManifest& manifest, const DecoderOptions& options);

// Table from a code word of (bits − lowest_bit) bits (the top bits of a `bits`-bit code)
// to the projector coordinate: Gray → binary for Gray codes, then the centre of the
// coded block, (b · 2^k) + (min(2^k, size − b · 2^k) − 1) / 2 with k = lowest_bit (the
// centre of the part of the block that lies on the projector); NaN when the block starts
// at or beyond `projector_size`. The decoder computes these per pixel, with the same
// arithmetic (the table states the mapping for tests and tools). Throws sope::Error on an
// invalid layout (bits outside 1..16, lowest_bit ≥ bits, projector_size ≤ 0).
std::vector<float> MakeCoordinateLut(PatternCode code, int bits, int lowest_bit,
                                     int projector_size);

// Direct and global light of a pixel from the maximum and minimum it shows over
// high-frequency patterns (Nayar et al. 2006, with the projector black level b of
// Moreno & Taubin 2012): L_d = (L_max − L_min) / (1 − b),
// L_g = 2 (L_min − b · L_max) / (1 − b²). Grey levels in, grey levels out.
struct DirectGlobal {
  float direct = 0.0f;
  float global = 0.0f;
};
inline DirectGlobal SeparateDirectGlobal(float max_level, float min_level, float black_level) {
  const float direct = (max_level - min_level) / (1.0f - black_level);
  const float global =
      2.0f * (min_level - black_level * max_level) / (1.0f - black_level * black_level);
  return {direct, global > 0.0f ? global : 0.0f};
}

// Robust classification of one bit (Xu & Aliaga 2007, rules as in Moreno & Taubin 2012
// §5) from the pattern value p, its inverse p̄ and the pixel's direct L_d / global L_g
// light, all in grey levels; e = margin · L_g is the slack the global light is allowed:
//   L_d < min_direct                       → unknown
//   L_d > L_g + e:  p > p̄ → 1, p < p̄ → 0  (direct light dominates)
//   p < L_d − e ∧ p̄ > L_g + e              → 0
//   p > L_g + e ∧ p̄ < L_d − e              → 1
//   otherwise                              → unknown
// The per-pixel part is computed once per pixel (RobustBoundsOf); the per-bit part
// (ClassifyRobustBit) is branch-free so the decode loop vectorises. Integer images use
// integer bounds: p < L_d − e ⇔ p < ⌈L_d − e⌉ and p > L_g + e ⇔ p > ⌊L_g + e⌋.
template <typename T>
struct RobustBounds {
  T direct_minus_slack;  // L_d − e
  T global_plus_slack;   // L_g + e
  // Bytes, not bool: GCC 12 vectorises the loop that fills them only then.
  uint8_t direct_dominates;  // L_d > L_g + e
  uint8_t too_dark;          // L_d < min_direct
};
inline RobustBounds<float> RobustBoundsOf(DirectGlobal light, float min_direct, float margin) {
  const float slack = margin * light.global;
  const float global_plus_slack = light.global + slack;
  return {light.direct - slack, global_plus_slack, light.direct > global_plus_slack,
          light.direct < min_direct};
}

// Outcome of ClassifyRobustBit: bit 0 the decided value, kRobustUnknown set when the bit
// cannot be decided (bit 0 is then meaningless). A byte rather than a struct so that the
// decode loop vectorises.
constexpr uint8_t kRobustValue = 1;
constexpr uint8_t kRobustUnknown = 2;
template <typename T>
inline uint8_t ClassifyRobustBit(T pattern, T inverse, T direct_minus_slack, T global_plus_slack,
                                 bool direct_dominates, bool too_dark) {
  const bool zero = (pattern < direct_minus_slack) & (inverse > global_plus_slack);
  const bool one = (pattern > global_plus_slack) & (inverse < direct_minus_slack);
  const bool value = (direct_dominates & (pattern > inverse)) | (!direct_dominates & one);
  const bool unknown =
      too_dark | (!direct_dominates & !zero & !one) | (direct_dominates & (pattern == inverse));
  return static_cast<uint8_t>(value | (unknown << 1));
}
template <typename T>
inline uint8_t ClassifyRobustBit(T pattern, T inverse, const RobustBounds<T>& bounds) {
  return ClassifyRobustBit(pattern, inverse, bounds.direct_minus_slack, bounds.global_plus_slack,
                           bounds.direct_dominates, bounds.too_dark);
}

}  // namespace internal
}  // namespace sope
