// Gaussian deviates for the virtual rig's sensor noise, a whole image row at a time.
#pragma once

#include <cstdint>

namespace sope::internal {

// Fills out[0 .. count) with standard normal deviates (mean 0, variance 1) that depend only
// on (seed, count): the same arguments give the same values on every call and thread, so a
// row of a frame is reproducible whatever thread renders it.
//
// Box–Muller on a counter-based hash: pair j of uniforms comes from hashing (seed, j), and
// gives out[j] = r·cos θ and out[half + j] = r·sin θ (half = ⌈count / 2⌉; for an odd count
// the last pair's sine is dropped). The uniforms have 24 bits, so |deviate| ≤ 5.8 (the
// normal's mass beyond is 7e-9); log, sine and cosine are polynomials accurate to a few
// float ulps. Unlike std::normal_distribution (Marsaglia's polar method: a rejection loop,
// one pair at a time) every step is branch-free arithmetic the compiler vectorises — the
// virtual rig's noise pass was a fifth of a calibration test's CPU time.
void FillStandardNormal(uint64_t seed, int count, float* out);

// The sensor's noise on a row of linear grey levels: out[x] = signal[x] + σ(x)·n[x] with
// σ² = read_variance + shot_noise · max(signal[x], 0) and n = FillStandardNormal(seed,
// count). `out` must not overlap `signal`.
void AddSensorNoise(uint64_t seed, const float* signal, int count, float read_variance,
                    float shot_noise, float* out);

}  // namespace sope::internal
