// FaissCoarseIndex against HammingIndex: the same k-best lists (distances, views, order)
// from a FAISS binary index written by WriteFaissBinaryIndex, on 10^4 random codes.
#include "recogniser/faiss_coarse_index.h"

#include <random>

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/file_util.h"
#include "tests/test_support.h"
#include "recogniser/random_codes_testing.h"

namespace sope {
namespace {

using testing::RandomCodes;

class FaissCoarse : public ::testing::TestWithParam<int> {};

TEST_P(FaissCoarse, SameTopKAsOurHammingSearch) {
  const int bits = GetParam();
  constexpr int64_t kCodes = 10000;
  const BinaryCodes codes = RandomCodes(bits, kCodes, 11);
  const BinaryCodes queries = RandomCodes(bits, 100, 12);
  testing::ScratchDir scratch;
  const std::string path = scratch.File("codes.faissbin");
  WriteFaissBinaryIndex(codes, path);
  const std::unique_ptr<FaissCoarseIndex> faiss = FaissCoarseIndex::Read(path, bits, kCodes);
  EXPECT_EQ(faiss->size(), kCodes);
  EXPECT_EQ(faiss->bits(), 8 * ((bits + 7) / 8));
  const HammingIndex ours(codes);
  size_t compared = 0;
  for (int k : {1, 10, 48, 300, 20000}) {
    for (int64_t q = 0; q < queries.size(); ++q) {
      const std::vector<HammingMatch> expected = ours.KBestSearch(queries.code(q), k);
      const std::vector<HammingMatch> actual = faiss->KBestSearch(queries.code(q), k);
      ASSERT_EQ(actual.size(), expected.size()) << "k " << k << " query " << q;
      for (size_t i = 0; i < expected.size(); ++i) {
        ASSERT_EQ(actual[i], expected[i]) << "k " << k << " query " << q << " rank " << i;
      }
      compared += expected.size();
    }
  }
  EXPECT_GT(compared, 100u * 10000);
  // A query equal to a database code finds it at distance 0 first.
  const std::vector<HammingMatch> self = faiss->KBestSearch(codes.code(1234), 3);
  EXPECT_EQ(self[0].index, 1234);
  EXPECT_EQ(self[0].hamming_distance, 0);
}

INSTANTIATE_TEST_SUITE_P(Bits, FaissCoarse, ::testing::Values(64, 100, 256));

TEST(FaissCoarse, RefusesOtherFilesAndMismatchedIndexes) {
  testing::ScratchDir scratch;
  WriteFileAtomic(scratch.File("junk.bin"), "not a faiss index at all");
  EXPECT_THROW(FaissCoarseIndex::Read(scratch.File("junk.bin")), Error);
  EXPECT_THROW(FaissCoarseIndex::Read(scratch.File("missing.bin")), Error);
  WriteFaissBinaryIndex(RandomCodes(64, 100, 1), scratch.File("codes.bin"));
  EXPECT_THROW(FaissCoarseIndex::Read(scratch.File("codes.bin"), 128, 100), Error);
  EXPECT_THROW(FaissCoarseIndex::Read(scratch.File("codes.bin"), 64, 101), Error);
  EXPECT_NO_THROW(FaissCoarseIndex::Read(scratch.File("codes.bin"), 64, 100));
  const std::string sidecar = ReadFileToString(scratch.File("codes.bin.json"), "sidecar");
  EXPECT_NE(sidecar.find("\"views\": 100"), std::string::npos) << sidecar;
}

}  // namespace
}  // namespace sope
