// Planted tests that cannot fail, for scripts/lint-tests.py --self-test (not compiled).
// Every line marked LINT-EXPECT must be reported with that kind, and nothing else.
#include <gtest/gtest.h>

TEST(Planted, SelfCompare) {
  Result result = Run();
  EXPECT_EQ(result.timing.pose, result.timing.pose);  // LINT-EXPECT: self-compare
  EXPECT_NEAR(result.error,  result.error, 1e-9);  // LINT-EXPECT: self-compare
  ASSERT_EQ(cloud.size(), cloud .size());  // LINT-EXPECT: self-compare
  EXPECT_DOUBLE_EQ(a->value(), a->value());  // LINT-EXPECT: self-compare
  EXPECT_TRUE(x == x);  // LINT-EXPECT: self-compare
  EXPECT_LE(  // LINT-EXPECT: self-compare
      result.total,
      result.total);
}

TEST(Planted, Constants) {
  ASSERT_TRUE(true);  // LINT-EXPECT: constant
  EXPECT_FALSE(false);  // LINT-EXPECT: constant
  EXPECT_TRUE(1);  // LINT-EXPECT: constant
}

TEST(Planted, NoAssertion) {  // LINT-EXPECT: no-assertion
  const int value = Compute();
  Log(value);  // EXPECT_EQ(value, 3) in a comment does not count
  const char* text = "ASSERT_TRUE(value) in a string does not count";
}

TEST(Planted, SkipOnly) {  // LINT-EXPECT: no-assertion
  if (std::getenv("SOPE_CONTACT_SHEET_DIR") == nullptr) GTEST_SKIP() << "not set";
  RenderPictures();
}

TEST_F(PlantedFixture, CallsAHelperThatDoesNotAssert) {  // LINT-EXPECT: no-assertion
  PrintReport(Run());
}

TEST(Planted, SucceedIsNotAnAssertion) {  // LINT-EXPECT: no-assertion
  Run();
  SUCCEED();
}

TEST(Planted, EmptyMessage) {
  EXPECT_THROW_WITH_MESSAGE(Parse("x"), Error, "");  // LINT-EXPECT: empty-message
}

TEST(Planted, Empty) {}  // LINT-EXPECT: no-assertion

TEST(Planted, NoSubstring) {
  EXPECT_THROW_WITH_MESSAGE(Parse("x"), Error);  // LINT-EXPECT: empty-message
  ASSERT_THROW_WITH_MESSAGE(Parse("x"), Error, "x", "");  // LINT-EXPECT: empty-message
}
