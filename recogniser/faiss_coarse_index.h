// The scale-out path of the coarse stage (issue 15): the database's binary codes as a FAISS
// binary index, so a coarse search over 10^8 views can be served by FAISS (IndexBinaryIVF,
// HNSW, sharded) or by a vector database that reads FAISS binary indexes (e.g. Milvus
// BIN_IVF_FLAT), and `sope recognise --coarse-index FILE` can use such an index instead of
// the in-memory Hamming scan. FAISS headers stay in the .cc (PIMPL).
//
// File (faiss::write_index_binary): an IndexBinaryIDMap whose ids are the database's view
// indices (database order), over an IndexBinaryFlat of d = 8·⌈bits/8⌉ bits; each code is
// the first d/8 bytes of our little-endian uint64 words (padding bits zero), so FAISS's
// Hamming distances are ours. A sidecar `FILE.json` names the views: code bits, view count,
// classes and, per model, its name, class and view range [first_view, first_view + views).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "recogniser/hamming_search.h"
#include "recogniser/hashing.h"

namespace sope {

class Database;

// Writes `database`'s codes as described above to `path` (atomically) and `path`.json.
// Throws sope::Error on I/O failure.
void WriteFaissBinaryIndex(const Database& database, const std::string& path);
// The same for bare codes (ids 0..n−1): for tests and benchmarks.
void WriteFaissBinaryIndex(const BinaryCodes& codes, const std::string& path);

// A coarse index read from a FAISS binary index file: any faiss::IndexBinary (an IDMap over
// a flat or IVF index, …) whose ids are view indices.
class FaissCoarseIndex {
 public:
  // Throws sope::Error when the file is not a FAISS binary index, or its dimension or size
  // do not fit `bits` / `num_views` (pass ≤ 0 to skip a check).
  static std::unique_ptr<FaissCoarseIndex> Read(const std::string& path, int bits = 0,
                                                int64_t num_views = 0);
  ~FaissCoarseIndex();
  FaissCoarseIndex(const FaissCoarseIndex&) = delete;
  FaissCoarseIndex& operator=(const FaissCoarseIndex&) = delete;

  int bits() const;      // the index's dimension d (a multiple of 8)
  int64_t size() const;  // codes in the index
  // The min(k, size()) nearest codes as HammingIndex::KBestSearch returns them: sorted by
  // distance, ties by ascending view index. FAISS's k-NN breaks ties its own way, so the
  // codes at the k-th distance are gathered with a range search (distance ≤ the k-th) and
  // the whole list sorted, which makes an exact index return exactly our list. `query` has
  // ⌈bits/64⌉ words. Thread-safe (FAISS searches are const); single-threaded unless FAISS's
  // OpenMP pool says otherwise.
  std::vector<HammingMatch> KBestSearch(const uint64_t* query, int k) const;

 private:
  struct Impl;
  explicit FaissCoarseIndex(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace sope
