#include "recogniser/hamming_search.h"

#include <algorithm>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/test_support.h"
#include "recogniser/random_codes_testing.h"

namespace sope {
namespace {

using testing::RandomCodes;

// Codes at a controlled distance from `query`: code i flips the first d_i bits, so
// distances can be forced (descending, all equal, ...).
BinaryCodes CodesAtDistances(const std::vector<int>& distances, const BinaryCodes& query) {
  BinaryCodes codes(query.bits, static_cast<int64_t>(distances.size()));
  for (size_t i = 0; i < distances.size(); ++i) {
    for (int b = 0; b < query.bits; ++b) {
      codes.SetBit(i, b, query.GetBit(0, b) != (b < distances[i]));
    }
  }
  return codes;
}

std::vector<PopcountKernel> AvailableKernels() {
  std::vector<PopcountKernel> kernels;
  for (PopcountKernel kernel :
       {PopcountKernel::kScalar, PopcountKernel::kAvx2, PopcountKernel::kAvx512}) {
    if (PopcountKernelAvailable(kernel)) kernels.push_back(kernel);
  }
  return kernels;
}

std::vector<HammingMatch> BruteForceRadius(const BinaryCodes& database, const uint64_t* query,
                                           int radius) {
  std::vector<HammingMatch> out;
  for (int64_t i = 0; i < database.size(); ++i) {
    const int d = HammingDistance(database.code(i), query, database.words_per_code);
    if (d <= radius) out.push_back({d, static_cast<int32_t>(i)});
  }
  return out;
}

TEST(BinaryCodesTest, LayoutAndBits) {
  BinaryCodes codes(70, 3);
  EXPECT_EQ(codes.words_per_code, 2);
  EXPECT_EQ(codes.size(), 3);
  codes.SetBit(1, 69, true);
  codes.SetBit(1, 0, true);
  EXPECT_TRUE(codes.GetBit(1, 69));
  EXPECT_TRUE(codes.GetBit(1, 0));
  EXPECT_FALSE(codes.GetBit(0, 69));
  EXPECT_EQ(codes.code(1)[1], uint64_t{1} << 5);
  EXPECT_EQ(HammingDistance(codes.code(0), codes.code(1), 2), 2);
  EXPECT_NO_THROW(codes.Check());
  codes.code(2)[1] |= uint64_t{1} << 6;  // padding bit 70
  EXPECT_THROW_WITH_MESSAGE(codes.Check(), Error, "code 2", "padding bits");
  EXPECT_THROW_WITH_MESSAGE(BinaryCodes(0, 1), Error, "code length", "got 0");
  EXPECT_THROW_WITH_MESSAGE(BinaryCodes(BinaryCodes::kMaxBits + 1, 1), Error, "code length",
                            "got 4097");
  EXPECT_THROW_WITH_MESSAGE(BinaryCodes(8, -1), Error, "number of codes", "got -1");
}

TEST(HammingSearchTest, KernelNamesRoundTrip) {
  for (PopcountKernel kernel : {PopcountKernel::kAuto, PopcountKernel::kScalar,
                                PopcountKernel::kAvx2, PopcountKernel::kAvx512}) {
    EXPECT_EQ(PopcountKernelFromString(ToString(kernel)), kernel);
  }
  EXPECT_THROW_WITH_MESSAGE(PopcountKernelFromString("sse9"), Error, "'sse9'");
  EXPECT_TRUE(PopcountKernelAvailable(PopcountKernel::kScalar));
}

// k-best and radius results equal brute force for every kernel, many code lengths
// (including ones that are not a whole number of words and the generic > 4-word path),
// database sizes that are not multiples of the vector width, and k around n.
TEST(HammingSearchTest, MatchesBruteForceForAllLengthsAndKernels) {
  for (int bits : {8, 24, 63, 64, 100, 128, 192, 200, 256, 320}) {
    for (int64_t n : {int64_t{1}, int64_t{7}, int64_t{33}, int64_t{1000}, int64_t{4099}}) {
      const BinaryCodes database = RandomCodes(bits, n, 1000 * bits + n);
      const BinaryCodes queries = RandomCodes(bits, 5, 7 * bits + n);
      for (PopcountKernel kernel : AvailableKernels()) {
        HammingSearchOptions options;
        options.kernel = kernel;
        const HammingIndex index(database, options);
        for (int64_t q = 0; q < queries.size(); ++q) {
          for (int k : {1, 3, 10, 64, static_cast<int>(n), static_cast<int>(n) + 5}) {
            ASSERT_EQ(index.KBestSearch(queries.code(q), k),
                      BruteForceKBest(database, queries.code(q), k))
                << "bits " << bits << " n " << n << " k " << k << " kernel " << ToString(kernel);
          }
          for (int radius : {-1, 0, bits / 4, bits / 2 - 2, bits / 2, bits}) {
            ASSERT_EQ(index.RadiusSearch(queries.code(q), radius),
                      BruteForceRadius(database, queries.code(q), radius))
                << "bits " << bits << " n " << n << " radius " << radius << " kernel "
                << ToString(kernel);
          }
        }
      }
    }
  }
}

// 8-bit codes over thousands of entries: every distance is heavily tied, so the result
// is decided by the tie rule (ascending index).
TEST(HammingSearchTest, TiesAreOrderedByIndex) {
  const BinaryCodes database = RandomCodes(8, 5000, 3);
  const BinaryCodes query = RandomCodes(8, 1, 4);
  for (PopcountKernel kernel : AvailableKernels()) {
    HammingSearchOptions options;
    options.kernel = kernel;
    const HammingIndex index(database, options);
    const std::vector<HammingMatch> result = index.KBestSearch(query.code(0), 300);
    ASSERT_EQ(result.size(), 300u);
    for (size_t i = 1; i < result.size(); ++i) {
      ASSERT_TRUE(result[i - 1].hamming_distance < result[i].hamming_distance ||
                  (result[i - 1].hamming_distance == result[i].hamming_distance &&
                   result[i - 1].index < result[i].index));
    }
    EXPECT_EQ(result, BruteForceKBest(database, query.code(0), 300));
  }
  // All codes identical: the first k indices.
  const BinaryCodes same = CodesAtDistances(std::vector<int>(100, 3), query);
  const std::vector<HammingMatch> result = HammingIndex(same).KBestSearch(query.code(0), 10);
  ASSERT_EQ(result.size(), 10u);
  for (int i = 0; i < 10; ++i) EXPECT_EQ(result[i], (HammingMatch{3, i}));
}

// Distances that decrease along the scan make every code a candidate: exercises the
// candidate pruning and the running threshold.
TEST(HammingSearchTest, AdversarialScanOrder) {
  const BinaryCodes query = RandomCodes(256, 1, 9);
  std::vector<int> distances(20000);
  for (size_t i = 0; i < distances.size(); ++i)
    distances[i] = 256 - static_cast<int>(i * 256 / distances.size());
  const BinaryCodes database = CodesAtDistances(distances, query);
  for (PopcountKernel kernel : AvailableKernels()) {
    HammingSearchOptions options;
    options.kernel = kernel;
    const HammingIndex index(database, options);
    for (int k : {1, 5, 100, 3000}) {
      EXPECT_EQ(index.KBestSearch(query.code(0), k), BruteForceKBest(database, query.code(0), k));
    }
  }
}

TEST(HammingSearchTest, BatchEqualsSingleQueriesAcrossBlocks) {
  for (int bits : {64, 128, 200, 256}) {
    const BinaryCodes database = RandomCodes(bits, 10007, bits);
    const BinaryCodes queries = RandomCodes(bits, 13, bits + 1);
    HammingSearchOptions options;
    options.block_bytes = 1024;  // many blocks, block edges inside vector groups
    const HammingIndex index(database, options);
    const auto kbest = index.KBestSearch(queries, 25);
    const auto radius = index.RadiusSearch(queries, bits / 2 - bits / 16);
    ASSERT_EQ(kbest.size(), 13u);
    ASSERT_EQ(radius.size(), 13u);
    for (int64_t q = 0; q < queries.size(); ++q) {
      EXPECT_EQ(kbest[q], index.KBestSearch(queries.code(q), 25));
      EXPECT_EQ(kbest[q], BruteForceKBest(database, queries.code(q), 25));
      EXPECT_EQ(radius[q], index.RadiusSearch(queries.code(q), bits / 2 - bits / 16));
    }
  }
}

TEST(HammingSearchTest, EmptyDatabaseAndEmptyBatch) {
  const BinaryCodes empty(64, 0);
  const HammingIndex index(empty);
  const BinaryCodes query = RandomCodes(64, 1, 1);
  EXPECT_EQ(index.size(), 0);
  EXPECT_TRUE(index.KBestSearch(query.code(0), 5).empty());
  EXPECT_TRUE(index.RadiusSearch(query.code(0), 64).empty());
  const auto batch = index.KBestSearch(query, 5);
  ASSERT_EQ(batch.size(), 1u);
  EXPECT_TRUE(batch[0].empty());
  EXPECT_TRUE(HammingIndex(RandomCodes(64, 10, 2)).KBestSearch(BinaryCodes(64, 0), 3).empty());
}

TEST(HammingSearchTest, KLargerThanDatabaseReturnsAllSorted) {
  const BinaryCodes database = RandomCodes(128, 37, 5);
  const BinaryCodes query = RandomCodes(128, 1, 6);
  const std::vector<HammingMatch> result = HammingIndex(database).KBestSearch(query.code(0), 1000);
  ASSERT_EQ(result.size(), 37u);
  EXPECT_EQ(result, BruteForceKBest(database, query.code(0), 37));
}

TEST(HammingSearchTest, QueryPaddingBitsAreIgnored) {
  const BinaryCodes database = RandomCodes(100, 500, 8);
  BinaryCodes query = RandomCodes(100, 1, 9);
  const HammingIndex index(database);
  const auto clean_kbest = index.KBestSearch(query.code(0), 20);
  const auto clean_radius = index.RadiusSearch(query.code(0), 45);
  std::vector<uint64_t> dirty(query.code(0), query.code(0) + 2);
  dirty[1] |= ~uint64_t{0} << 36;  // bits 100..127
  EXPECT_EQ(index.KBestSearch(dirty.data(), 20), clean_kbest);
  EXPECT_EQ(index.RadiusSearch(dirty.data(), 45), clean_radius);
}

TEST(HammingSearchTest, RejectsInvalidArguments) {
  const BinaryCodes database = RandomCodes(64, 10, 1);
  const HammingIndex index(database);
  const BinaryCodes query = RandomCodes(64, 1, 2);
  EXPECT_THROW_WITH_MESSAGE(index.KBestSearch(query.code(0), 0), Error, "k ≥ 1", "got 0");
  EXPECT_THROW_WITH_MESSAGE(index.KBestSearch(query, -1), Error, "k ≥ 1", "got -1");
  EXPECT_THROW_WITH_MESSAGE(index.RadiusSearch(query.code(0), 65), Error, "search radius 65",
                            "64 bits");
  EXPECT_TRUE(index.RadiusSearch(query.code(0), -1).empty());
  EXPECT_THROW_WITH_MESSAGE(index.KBestSearch(RandomCodes(128, 1, 3), 1), Error, "128 bits",
                            "the database 64");
  EXPECT_THROW_WITH_MESSAGE(index.RadiusSearch(RandomCodes(32, 1, 3), 1), Error, "32 bits",
                            "the database 64");
  BinaryCodes bad = RandomCodes(60, 3, 4);
  bad.code(1)[0] |= uint64_t{1} << 62;  // padding
  EXPECT_THROW_WITH_MESSAGE(HammingIndex{bad}, Error, "code 1", "padding bits");
  BinaryCodes ragged = RandomCodes(64, 3, 4);
  ragged.words_per_code = 2;  // inconsistent with bits
  EXPECT_THROW_WITH_MESSAGE(HammingIndex{ragged}, Error, "64 bits", "got 2");
  HammingSearchOptions options;
  options.block_bytes = 10;
  EXPECT_THROW_WITH_MESSAGE(HammingIndex(database, options), Error, "block_bytes", "got 10");
  for (PopcountKernel kernel : {PopcountKernel::kAvx2, PopcountKernel::kAvx512}) {
    if (!PopcountKernelAvailable(kernel)) {
      HammingSearchOptions unsupported;
      unsupported.kernel = kernel;
      EXPECT_THROW_WITH_MESSAGE(HammingIndex(database, unsupported), Error,
                                "'" + ToString(kernel) + "'", "not supported by this CPU");
    }
  }
}

}  // namespace
}  // namespace sope
