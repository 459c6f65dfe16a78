// The virtual rig's Gaussian deviates against the standard normal distribution.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "core/split_mix.h"
#include "simulator/sensor_noise.h"

namespace sope::internal {
namespace {

constexpr int kRowLength = 1281;  // odd: the last deviate has no sine partner
constexpr int kRows = 2000;       // 2.56 M deviates

uint64_t RowSeed(int row) {  // as the rig seeds its rows: one SplitMix64 step
  return SplitMix{static_cast<uint64_t>(row)}.Next();
}

std::vector<std::vector<float>> Rows() {
  std::vector<std::vector<float>> rows(kRows, std::vector<float>(kRowLength));
  for (int r = 0; r < kRows; ++r) FillStandardNormal(RowSeed(r), kRowLength, rows[r].data());
  return rows;
}

double NormalCdf(double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); }

// Pearson correlation of pairs (a[i], b[i]).
double Correlation(const std::vector<double>& a, const std::vector<double>& b) {
  double ma = 0, mb = 0;
  for (size_t i = 0; i < a.size(); ++i) ma += a[i], mb += b[i];
  ma /= a.size();
  mb /= b.size();
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    sab += (a[i] - ma) * (b[i] - mb);
    saa += (a[i] - ma) * (a[i] - ma);
    sbb += (b[i] - mb) * (b[i] - mb);
  }
  return sab / std::sqrt(saa * sbb);
}

TEST(SensorNoise, DeviatesAreStandardNormal) {
  const std::vector<std::vector<float>> rows = Rows();
  std::vector<double> all;
  all.reserve(static_cast<size_t>(kRows) * kRowLength);
  for (const std::vector<float>& row : rows) all.insert(all.end(), row.begin(), row.end());
  const double n = static_cast<double>(all.size());
  double sum = 0, sum_sq = 0, beyond_2 = 0, beyond_3 = 0, largest = 0;
  for (const double z : all) {
    ASSERT_TRUE(std::isfinite(z));
    sum += z;
    sum_sq += z * z;
    beyond_2 += std::abs(z) > 2.0;
    beyond_3 += std::abs(z) > 3.0;
    largest = std::max(largest, std::abs(z));
  }
  const double mean = sum / n, variance = sum_sq / n - mean * mean;
  // Standard errors at n = 2.56 M: mean 6e-4, variance 9e-4, P(|z| > 2) 1.3e-4,
  // P(|z| > 3) 3.2e-5; the bounds are 5–8 of them.
  EXPECT_NEAR(mean, 0.0, 0.004);
  EXPECT_NEAR(variance, 1.0, 0.006);
  EXPECT_NEAR(beyond_2 / n, 2.0 * NormalCdf(-2.0), 0.001);
  EXPECT_NEAR(beyond_3 / n, 2.0 * NormalCdf(-3.0), 0.00025);
  EXPECT_LE(largest, 5.8);  // 24-bit uniforms: r ≤ √(2·24·ln 2) = 5.77
  EXPECT_GT(largest, 4.5);  // P(max of 2.56 M below 4.5) ≈ 1e-4

  // Kolmogorov–Smirnov distance to Φ: ≈ 0.87/√n = 5e-4 for a true normal sample.
  std::sort(all.begin(), all.end());
  double ks = 0.0;
  for (size_t i = 0; i < all.size(); i += 7) {  // every 7th order statistic suffices
    const double cdf = NormalCdf(all[i]);
    ks = std::max({ks, std::abs(cdf - i / n), std::abs(cdf - (i + 1) / n)});
  }
  EXPECT_LT(ks, 0.0025);
}

TEST(SensorNoise, NeighboursRowsAndPairPartnersAreUncorrelated) {
  const std::vector<std::vector<float>> rows = Rows();
  const int half = (kRowLength + 1) / 2;  // where the sines start
  std::vector<double> a, b, cos_part, sin_part, row_a, row_b;
  for (int r = 0; r < kRows; ++r) {
    for (int x = 0; x + 1 < kRowLength; ++x) {
      a.push_back(rows[r][x]);
      b.push_back(rows[r][x + 1]);
    }
    for (int j = 0; j + half < kRowLength; ++j) {
      cos_part.push_back(rows[r][j]);
      sin_part.push_back(rows[r][half + j]);
    }
    if (r + 1 < kRows) {
      for (int x = 0; x < kRowLength; ++x) {
        row_a.push_back(rows[r][x]);
        row_b.push_back(rows[r + 1][x]);
      }
    }
  }
  // Standard error of a correlation of ~2.5 M (1.3 M) pairs: 6e-4 (9e-4).
  EXPECT_LT(std::abs(Correlation(a, b)), 0.004);
  EXPECT_LT(std::abs(Correlation(row_a, row_b)), 0.004);
  EXPECT_LT(std::abs(Correlation(cos_part, sin_part)), 0.005);
  // Box–Muller partners are independent, not merely uncorrelated: their squares too.
  for (double& v : cos_part) v *= v;
  for (double& v : sin_part) v *= v;
  EXPECT_LT(std::abs(Correlation(cos_part, sin_part)), 0.006);
}

TEST(SensorNoise, SameSeedSameRowOtherSeedOtherRow) {
  std::vector<float> first(640), again(640), other(640);
  FillStandardNormal(42, 640, first.data());
  FillStandardNormal(42, 640, again.data());
  FillStandardNormal(43, 640, other.data());
  EXPECT_EQ(first, again);
  int equal = 0;
  for (int x = 0; x < 640; ++x) equal += first[x] == other[x];
  EXPECT_LT(equal, 3);
  // Seeds differing only in their high word give other rows too.
  FillStandardNormal(42 + (uint64_t{1} << 32), 640, other.data());
  equal = 0;
  for (int x = 0; x < 640; ++x) equal += first[x] == other[x];
  EXPECT_LT(equal, 3);
  // A count of 1 and of 0 work (nothing written for 0).
  float one = 99.0f;
  FillStandardNormal(7, 0, &one);
  EXPECT_EQ(one, 99.0f);
  FillStandardNormal(7, 1, &one);
  EXPECT_TRUE(std::isfinite(one));
  EXPECT_NE(one, 99.0f);
}

TEST(SensorNoise, NoiseHasTheSensorsVariance) {
  // σ² = read² + shot · signal; a negative (black-level) signal gets the read noise alone.
  const float read_variance = 1.5f * 1.5f, shot_noise = 0.4f;
  for (const float signal_level : {-3.0f, 0.0f, 20.0f, 200.0f}) {
    const std::vector<float> signal(kRowLength, signal_level);
    std::vector<float> out(kRowLength);
    double sum = 0, sum_sq = 0;
    const int rows = 400;
    for (int r = 0; r < rows; ++r) {
      AddSensorNoise(RowSeed(r), signal.data(), kRowLength, read_variance, shot_noise,
                     out.data());
      for (const float v : out) {
        sum += v - signal_level;
        sum_sq += (v - signal_level) * (v - signal_level);
      }
    }
    const double n = static_cast<double>(rows) * kRowLength;
    const double expected = read_variance + shot_noise * std::max(signal_level, 0.0f);
    const double mean = sum / n;
    // Standard errors: mean √(σ²/n), variance σ²·√(2/n) (n = 512 k).
    EXPECT_NEAR(mean, 0.0, 6.0 * std::sqrt(expected / n)) << signal_level;
    EXPECT_NEAR(sum_sq / n - mean * mean, expected, 6.0 * expected * std::sqrt(2.0 / n))
        << signal_level;
  }
}

}  // namespace
}  // namespace sope::internal
