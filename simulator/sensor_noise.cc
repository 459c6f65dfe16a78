#include "simulator/sensor_noise.h"

#include <cmath>
#include <cstring>

namespace sope::internal {
namespace {

// A 32-bit integer hash with low bias (C. Wellons' "lowbias32" constants).
inline uint32_t Mix32(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return x;
}

inline float FloatFromBits(uint32_t bits) {
  float value;
  std::memcpy(&value, &bits, sizeof(value));
  return value;
}

inline uint32_t BitsOfFloat(float value) {
  uint32_t bits;
  std::memcpy(&bits, &value, sizeof(bits));
  return bits;
}

// ln(x) for a positive normal float: x = m·2^e with m in [√½, √2), ln m = 2·atanh(s) with
// s = (m − 1)/(m + 1), |s| ≤ 0.172, by its series to s⁹ (truncation < 1e-9).
inline float Log(float x) {
  const uint32_t bits = BitsOfFloat(x);
  float exponent = static_cast<float>(static_cast<int32_t>(bits >> 23) - 127);
  float m = FloatFromBits((bits & 0x007fffffU) | 0x3f800000U);  // [1, 2)
  const bool high = m > 1.41421356f;
  m = high ? 0.5f * m : m;
  exponent = high ? exponent + 1.0f : exponent;
  const float s = (m - 1.0f) / (m + 1.0f);
  const float s2 = s * s;
  const float series =
      s * (2.0f + s2 * (2.0f / 3.0f + s2 * (2.0f / 5.0f + s2 * (2.0f / 7.0f + s2 * (2.0f / 9.0f)))));
  return exponent * 0.693147180559945f + series;
}

// One Box–Muller pair from two 32-bit hashes: r·cos θ and r·sin θ, θ uniform in [−π, π).
// sin and cos of the half angle a = θ/2 in [−π/2, π/2) by their Taylor series (to a¹¹ and
// a¹²: truncation < 6e-8), then the double-angle formulas.
inline void BoxMuller(uint32_t h1, uint32_t h2, float* cosine_deviate, float* sine_deviate) {
  constexpr float kUnit = 1.0f / 16777216.0f;  // 2^-24
  constexpr float kPi = 3.14159265358979f;
  const float u1 = (static_cast<float>(static_cast<int32_t>(h1 >> 8)) + 1.0f) * kUnit;  // (0, 1]
  const float u2 = static_cast<float>(static_cast<int32_t>(h2 >> 8)) * kUnit;           // [0, 1)
  const float r = std::sqrt(-2.0f * Log(u1));
  const float a = kPi * (u2 - 0.5f);
  const float a2 = a * a;
  const float sin_a =
      a * (1.0f + a2 * (-1.0f / 6.0f +
                        a2 * (1.0f / 120.0f +
                              a2 * (-1.0f / 5040.0f + a2 * (1.0f / 362880.0f +
                                                            a2 * (-1.0f / 39916800.0f))))));
  const float cos_a =
      1.0f + a2 * (-0.5f + a2 * (1.0f / 24.0f +
                                 a2 * (-1.0f / 720.0f +
                                       a2 * (1.0f / 40320.0f +
                                             a2 * (-1.0f / 3628800.0f +
                                                   a2 * (1.0f / 479001600.0f))))));
  *cosine_deviate = r * (cos_a * cos_a - sin_a * sin_a);
  *sine_deviate = r * (2.0f * sin_a * cos_a);
}

}  // namespace

void FillStandardNormal(uint64_t seed, int count, float* out) {
  if (count <= 0) return;
  const uint32_t lo = static_cast<uint32_t>(seed);
  const uint32_t hi = static_cast<uint32_t>(seed >> 32);
  const int half = count / 2;       // full pairs
  const int first_half = count - half;  // ⌈count / 2⌉: the cosines
  float* cosines = out;
  float* sines = out + first_half;
  for (int j = 0; j < half; ++j) {
    const uint32_t key = 2U * static_cast<uint32_t>(j) + lo;
    BoxMuller(Mix32(Mix32(key) ^ hi), Mix32(Mix32(key + 1U) ^ hi), &cosines[j], &sines[j]);
  }
  if (first_half > half) {  // odd count: the last pair's cosine alone
    const uint32_t key = 2U * static_cast<uint32_t>(half) + lo;
    float unused;
    BoxMuller(Mix32(Mix32(key) ^ hi), Mix32(Mix32(key + 1U) ^ hi), &cosines[half], &unused);
  }
}

void AddSensorNoise(uint64_t seed, const float* signal, int count, float read_variance,
                    float shot_noise, float* out) {
  FillStandardNormal(seed, count, out);
  for (int x = 0; x < count; ++x) {
    const float level = signal[x] > 0.0f ? signal[x] : 0.0f;
    out[x] = signal[x] + std::sqrt(read_variance + shot_noise * level) * out[x];
  }
}

}  // namespace sope::internal
