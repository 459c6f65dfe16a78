// The shared throw check reads the message: it passes only for the right type with the
// substring in what(), and fails (printing what did happen) otherwise.
#include "tests/test_support.h"

#include <stdexcept>

#include <gtest/gtest-spi.h>
#include <gtest/gtest.h>

#include "core/error.h"

namespace sope {
namespace {

void ThrowBadBits() { SOPE_THROW("hash bits must be in [8, 256], got {}", 7); }

TEST(ThrowsWithMessage, PassesForTheRightTypeAndSubstring) {
  EXPECT_THROW_WITH_MESSAGE(ThrowBadBits(), Error, "got 7");
  ASSERT_THROW_WITH_MESSAGE(ThrowBadBits(), Error, "hash bits");
  // Several substrings: each must be there, in any order.
  EXPECT_THROW_WITH_MESSAGE(ThrowBadBits(), Error, "got 7", "bits", "[8, 256]");
  // A base class catches a derived one, as EXPECT_THROW does.
  EXPECT_THROW_WITH_MESSAGE(ThrowBadBits(), std::runtime_error, "[8, 256]");
  testing::ExpectThrowsWithMessage<Error>(ThrowBadBits, {"got 7"});
  EXPECT_TRUE(testing::ThrowsWithMessage<Error>(ThrowBadBits, {"bits", "7"}));
}

TEST(ThrowsWithMessage, FailsWhenNothingIsThrown) {
  EXPECT_NONFATAL_FAILURE(EXPECT_THROW_WITH_MESSAGE((void)0, Error, "anything"),
                          "but threw nothing");
  const ::testing::AssertionResult result =
      testing::ThrowsWithMessage<Error>([] {}, {"anything"});
  EXPECT_FALSE(result);
}

TEST(ThrowsWithMessage, FailsForAnotherTypeAndShowsItsMessage) {
  EXPECT_NONFATAL_FAILURE(
      EXPECT_THROW_WITH_MESSAGE(throw std::logic_error("disk on fire"), Error, "disk"),
      "disk on fire");
  EXPECT_NONFATAL_FAILURE(EXPECT_THROW_WITH_MESSAGE(throw 42, Error, "42"),
                          "non-std exception");
}

TEST(ThrowsWithMessage, FailsWhenTheMessageLacksTheSubstringAndPrintsIt) {
  EXPECT_NONFATAL_FAILURE(EXPECT_THROW_WITH_MESSAGE(ThrowBadBits(), Error, "got 8"),
                          "hash bits must be in [8, 256], got 7");
  // Case matters: the substring is matched exactly.
  EXPECT_NONFATAL_FAILURE(EXPECT_THROW_WITH_MESSAGE(ThrowBadBits(), Error, "Hash"),
                          "does not contain \"Hash\"");
  EXPECT_NONFATAL_FAILURE(testing::ExpectThrowsWithMessage<Error>(ThrowBadBits, {"got 9"}),
                          "got 7");
}

TEST(ThrowsWithMessage, FailsWhenAnyOfSeveralSubstringsIsMissing) {
  EXPECT_NONFATAL_FAILURE(EXPECT_THROW_WITH_MESSAGE(ThrowBadBits(), Error, "bits", "got 8"),
                          "does not contain \"got 8\"");
}

TEST(ThrowsWithMessage, RefusesAnEmptySubstring) {
  EXPECT_NONFATAL_FAILURE(
      EXPECT_THROW_WITH_MESSAGE(ThrowBadBits(), Error, ""),  // lint-tests: allow empty-message
      "non-empty substrings");
  EXPECT_NONFATAL_FAILURE(testing::ExpectThrowsWithMessage<Error>(ThrowBadBits, {}),
                          "non-empty substrings");
}

TEST(ThrowsWithMessage, FatalFormStopsTheTest) {
  EXPECT_FATAL_FAILURE(ASSERT_THROW_WITH_MESSAGE((void)0, Error, "x"), "threw nothing");
}

TEST(ThrowsWithMessage, StreamsExtraContextLikeExpectThrow) {
  EXPECT_NONFATAL_FAILURE(EXPECT_THROW_WITH_MESSAGE((void)0, Error, "x") << "context 1234",
                          "context 1234");
}

}  // namespace
}  // namespace sope
