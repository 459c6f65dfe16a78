#include "core/statistics.h"

#include <cmath>

#include <gtest/gtest.h>

namespace sope {
namespace {

TEST(Statistics, QuantilesByRank) {
  EXPECT_TRUE(std::isnan(Median({})));
  EXPECT_TRUE(std::isnan(Quantile({}, 0.95)));
  EXPECT_EQ(Median({7.0}), 7.0);
  EXPECT_EQ(Median({3.0, 1.0, 2.0}), 2.0);
  EXPECT_EQ(Median({4.0, 1.0, 3.0, 2.0}), 3.0);  // the upper of the two middle values
  std::vector<double> hundred;
  for (int i = 100; i >= 1; --i) hundred.push_back(i);
  EXPECT_EQ(Quantile(hundred, 0.95), 96.0);  // rank ⌊95⌋ of 1…100
  EXPECT_EQ(Quantile(hundred, 1.0), 100.0);  // clamped to the last
  EXPECT_EQ(Quantile(hundred, 0.0), 1.0);
}

}  // namespace
}  // namespace sope
