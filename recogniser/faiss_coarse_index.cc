#include "recogniser/faiss_coarse_index.h"

#include <algorithm>
#include <cstring>

#include <faiss/IndexBinaryFlat.h>
#include <faiss/IndexIDMap.h>
#include <faiss/impl/AuxIndexStructures.h>
#include <faiss/impl/FaissException.h>
#include <faiss/impl/io.h>
#include <faiss/index_io.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "recogniser/database.h"

namespace sope {
namespace {

int FaissBits(int bits) { return 8 * ((bits + 7) / 8); }

// Bytes 0..d/8−1 of the little-endian words of one code.
void CodeBytes(const uint64_t* words, int bytes, uint8_t* out) {
  std::memcpy(out, words, bytes);  // x86-64 and every FAISS target are little-endian
}

std::string SerializeIndex(const BinaryCodes& codes) {
  codes.Check();
  const int d = FaissBits(codes.bits);
  const int bytes = d / 8;
  faiss::IndexBinaryFlat flat(d);
  faiss::IndexBinaryIDMap index(&flat);
  index.code_size = flat.code_size;  // the IDMap constructor leaves it 0; readers need it
  std::vector<uint8_t> data(static_cast<size_t>(codes.size()) * bytes);
  std::vector<faiss::IndexBinary::idx_t> ids(codes.size());
  for (int64_t i = 0; i < codes.size(); ++i) {
    CodeBytes(codes.code(i), bytes, data.data() + i * bytes);
    ids[i] = i;
  }
  faiss::VectorIOWriter writer;
  try {
    index.add_with_ids(codes.size(), data.data(), ids.data());
    faiss::write_index_binary(&index, &writer);
  } catch (const faiss::FaissException& e) {
    SOPE_THROW("FAISS: {}", e.what());
  }
  return std::string(writer.data.begin(), writer.data.end());
}

}  // namespace

void WriteFaissBinaryIndex(const BinaryCodes& codes, const std::string& path) {
  WriteFileAtomic(path, SerializeIndex(codes));
  nlohmann::json sidecar = {{"format", "sope-faiss-ids/1"},
                            {"bits", codes.bits},
                            {"faiss_bits", FaissBits(codes.bits)},
                            {"views", codes.size()}};
  WriteFileAtomic(path + ".json", sidecar.dump(2) + "\n");
}

void WriteFaissBinaryIndex(const Database& database, const std::string& path) {
  const BinaryCodes& codes = database.codes();
  WriteFileAtomic(path, SerializeIndex(codes));
  nlohmann::json models = nlohmann::json::array();
  for (const ModelRecord& model : database.models()) {
    models.push_back({{"name", model.name},
                      {"class", model.class_name},
                      {"first_view", model.first_view},
                      {"views", model.num_views}});
  }
  nlohmann::json sidecar = {{"format", "sope-faiss-ids/1"},
                            {"database", database.path()},
                            {"bits", codes.bits},
                            {"faiss_bits", FaissBits(codes.bits)},
                            {"views", codes.size()},
                            {"id", "view index in database order"},
                            {"classes", database.classes()},
                            {"models", models}};
  WriteFileAtomic(path + ".json", sidecar.dump(2) + "\n");
}

struct FaissCoarseIndex::Impl {
  std::unique_ptr<faiss::IndexBinary> index;
  int bytes = 0;
};

FaissCoarseIndex::FaissCoarseIndex(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
FaissCoarseIndex::~FaissCoarseIndex() = default;

std::unique_ptr<FaissCoarseIndex> FaissCoarseIndex::Read(const std::string& path, int bits,
                                                         int64_t num_views) {
  RequireReadableFile(path, "coarse index");
  auto impl = std::make_unique<Impl>();
  try {
    impl->index.reset(faiss::read_index_binary(path.c_str()));
  } catch (const faiss::FaissException& e) {
    SOPE_THROW("coarse index {}: not a FAISS binary index ({})", path,
               std::string(e.what()).substr(0, 200));
  }
  SOPE_CHECK(impl->index != nullptr, "coarse index {}: not a FAISS binary index", path);
  // d/8, not code_size: an IndexBinaryIDMap constructed around another index (as FAISS's
  // own writers do) stores code_size 0.
  SOPE_CHECK(impl->index->d > 0 && impl->index->d % 8 == 0,
             "coarse index {}: dimension {} is not a positive multiple of 8", path,
             impl->index->d);
  impl->bytes = impl->index->d / 8;
  SOPE_CHECK(bits <= 0 || impl->index->d == FaissBits(bits),
             "coarse index {}: {}-bit codes, the database has {}-bit codes", path,
             impl->index->d, bits);
  SOPE_CHECK(num_views <= 0 || impl->index->ntotal == num_views,
             "coarse index {}: {} codes, the database has {} views", path, impl->index->ntotal,
             num_views);
  return std::unique_ptr<FaissCoarseIndex>(new FaissCoarseIndex(std::move(impl)));
}

int FaissCoarseIndex::bits() const { return impl_->index->d; }
int64_t FaissCoarseIndex::size() const { return impl_->index->ntotal; }

std::vector<HammingMatch> FaissCoarseIndex::KBestSearch(const uint64_t* query, int k) const {
  SOPE_CHECK(k >= 1, "k-best search: k must be ≥ 1, got {}", k);
  const faiss::IndexBinary& index = *impl_->index;
  const int64_t n = std::min<int64_t>(k, index.ntotal);
  if (n == 0) return {};
  std::vector<uint8_t> bytes(impl_->bytes);
  CodeBytes(query, impl_->bytes, bytes.data());
  std::vector<int32_t> distances(n);
  std::vector<faiss::IndexBinary::idx_t> labels(n);
  std::vector<HammingMatch> matches;
  try {
    index.search(1, bytes.data(), n, distances.data(), labels.data());
    int32_t kth = 0;
    for (int64_t i = 0; i < n; ++i) {
      if (labels[i] >= 0) kth = std::max(kth, distances[i]);
    }
    // Every code at distance ≤ the k-th (FAISS: strictly below the radius).
    faiss::RangeSearchResult range(1);
    index.range_search(1, bytes.data(), kth + 1, &range);
    for (size_t j = range.lims[0]; j < range.lims[1]; ++j) {
      HammingMatch match;
      match.hamming_distance = static_cast<int32_t>(range.distances[j]);
      match.index = static_cast<int32_t>(range.labels[j]);
      matches.push_back(match);
    }
  } catch (const faiss::FaissException&) {
    // An index without range search (e.g. HNSW): its k-NN list, in our order.
    matches.clear();
    for (int64_t i = 0; i < n; ++i) {
      if (labels[i] < 0) continue;
      HammingMatch match;
      match.hamming_distance = distances[i];
      match.index = static_cast<int32_t>(labels[i]);
      matches.push_back(match);
    }
  }
  std::sort(matches.begin(), matches.end(), [](const HammingMatch& a, const HammingMatch& b) {
    return a.hamming_distance != b.hamming_distance ? a.hamming_distance < b.hamming_distance
                                                    : a.index < b.index;
  });
  if (static_cast<int64_t>(matches.size()) > n) matches.resize(n);
  return matches;
}

}  // namespace sope
