// Order statistics for reports and robust scales.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace sope {

// The element of rank ⌊q·n⌋ (0-based, clamped to n − 1) of `values` in ascending order:
// q = 0.5 is the upper median, q = 0.95 the 95th percentile. NaN when `values` is empty.
inline double Quantile(std::vector<double> values, double q) {
  if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
  const size_t rank = std::min(values.size() - 1, static_cast<size_t>(q * values.size()));
  std::nth_element(values.begin(), values.begin() + rank, values.end());
  return values[rank];
}

// Quantile(values, 0.5): the middle value, the upper one of the two for an even count.
inline double Median(std::vector<double> values) { return Quantile(std::move(values), 0.5); }

}  // namespace sope
