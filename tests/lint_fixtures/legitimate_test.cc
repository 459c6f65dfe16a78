// Tests that can fail, in forms the lint must not flag (scripts/lint-tests.py --self-test).
#include <gtest/gtest.h>

#include "tests/test_support.h"

namespace {

void ExpectRoundTrip(int value) { EXPECT_EQ(Decode(Encode(value)), value); }

// A helper that asserts through another helper.
void ExpectRoundTrips() {
  for (int v = 0; v < 4; ++v) ExpectRoundTrip(v);
}

#define EXPECT_CLOSE(a, b) EXPECT_NEAR(a, b, 1e-9)

class Fixture : public ::testing::Test {
 protected:
  void CheckInvariants() const { ASSERT_GT(count_, 0); }
  int count_ = 1;
};

TEST(Legitimate, Determinism) {
  // Calling a function twice may give two values: that is what a determinism test checks.
  EXPECT_EQ(Generate(42), Generate(42));
  EXPECT_EQ(rng(), rng());
  EXPECT_TRUE(Hash(data) == Hash(data));
}

TEST(Legitimate, DifferentValues) {
  EXPECT_EQ(result.timing.pose, expected.timing.pose);
  EXPECT_NEAR(a, b, 1e-6);
  EXPECT_TRUE(ok);
  EXPECT_FALSE(values.empty());
}

TEST(Legitimate, HelperAsserts) { ExpectRoundTrips(); }

TEST(Legitimate, MacroAsserts) { EXPECT_CLOSE(Compute(), 3.0); }

TEST(Legitimate, LambdaAsserts) {
  const auto expect_invalid = [](int bits) {
    EXPECT_THROW_WITH_MESSAGE(Train(bits), Error, "bits");
  };
  expect_invalid(7);
}

TEST_F(Fixture, MethodAsserts) { CheckInvariants(); }

TEST(Legitimate, SharedHelperAsserts) {
  sope::testing::ExpectOneLineError(Run(), "scan", "bit 40");
}

TEST(Legitimate, SkipsThenAsserts) {
  if (!Available()) GTEST_SKIP() << "no data";
  ASSERT_EQ(Load().size(), 3u);
}

TEST(Legitimate, FailAndAddFailureCount) {
  if (Broken()) FAIL() << "broken";
  if (Odd()) ADD_FAILURE() << "odd";
}

TEST(Legitimate, ThrowChecks) {
  EXPECT_THROW_WITH_MESSAGE(Parse("x,y"), Error, "'x,y'");
  EXPECT_NONFATAL_FAILURE(Something(), "text");
}

TEST(Legitimate, ExemptLine) {
  EXPECT_EQ(x, x);  // lint-tests: allow self-compare
}

}  // namespace
