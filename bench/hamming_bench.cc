// Coarse Hamming search and hash training, ours vs faiss::IndexBinaryFlat.
//
//   hamming_bench [--benchmark_filter=...]
//
// Everything single-threaded (faiss's OpenMP pool is set to 1 thread); the summary uses
// CPU time, minimum over --benchmark_repetitions. The database is
// 10^6 uniformly random codes per length (64/128/256 bits) and prefixes of it for the
// scaling curve; queries cycle through 1024 random codes. k = 10. Throughput is codes
// scanned per second (database size × queries / time). A summary table with the
// ours ÷ faiss ratios is printed at the end.
//
// Debian's libfaiss.a is built for baseline x86-64: its popcount is a call to libgcc's
// __popcountdi2, not the POPCNT instruction. So besides IndexBinaryFlat::search as
// installed (heap and counting selection), "faiss_native" runs faiss's own scan — its
// header-only HammingComputer8/16/32 and max-heap, the loop of hammings_knn_hc —
// compiled here with -march=native, i.e. faiss's algorithm with hardware popcount.
#include <omp.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>
#include <faiss/IndexBinaryFlat.h>
#include <faiss/impl/AuxIndexStructures.h>
#include <faiss/utils/Heap.h>
#include <faiss/utils/hamming.h>

#include "bench/bench_support.h"
#include "recogniser/hamming_search.h"
#include "recogniser/hashing.h"

namespace sope {
namespace {

constexpr int64_t kMaxCodes = 1000000;
constexpr int kK = 10;
constexpr int kQueryPool = 1024;
constexpr int kBatchQueries = 32;

BinaryCodes RandomCodes(int bits, int64_t count, uint64_t seed) {
  std::mt19937_64 rng(seed);
  BinaryCodes codes(bits, count);
  for (uint64_t& word : codes.words) word = rng();
  if (bits % 64 != 0) {
    for (int64_t i = 0; i < count; ++i) {
      codes.code(i)[codes.words_per_code - 1] &= (uint64_t{1} << (bits % 64)) - 1;
    }
  }
  return codes;
}

// Prefix of the 10^6-code database of a length, and the queries.
const BinaryCodes& Database(int bits) {
  static std::map<int, BinaryCodes> cache;
  auto it = cache.find(bits);
  if (it == cache.end()) it = cache.emplace(bits, RandomCodes(bits, kMaxCodes, bits)).first;
  return it->second;
}
const BinaryCodes& Queries(int bits) {
  static std::map<int, BinaryCodes> cache;
  auto it = cache.find(bits);
  if (it == cache.end()) it = cache.emplace(bits, RandomCodes(bits, kQueryPool, 7 + bits)).first;
  return it->second;
}
BinaryCodes Prefix(const BinaryCodes& codes, int64_t count) {
  BinaryCodes out(codes.bits, 0);
  out.words.assign(codes.words.begin(), codes.words.begin() + count * codes.words_per_code);
  return out;
}

const HammingIndex& Ours(int bits, int64_t count, PopcountKernel kernel) {
  static std::map<std::tuple<int, int64_t, PopcountKernel>, std::unique_ptr<HammingIndex>> cache;
  auto& slot = cache[{bits, count, kernel}];
  if (!slot) {
    HammingSearchOptions options;
    options.kernel = kernel;
    slot = std::make_unique<HammingIndex>(Prefix(Database(bits), count), options);
  }
  return *slot;
}

// Our words are little-endian uint64, i.e. the same bytes faiss expects for d % 64 == 0.
const faiss::IndexBinaryFlat& Faiss(int bits, int64_t count) {
  static std::map<std::pair<int, int64_t>, std::unique_ptr<faiss::IndexBinaryFlat>> cache;
  auto& slot = cache[{bits, count}];
  if (!slot) {
    slot = std::make_unique<faiss::IndexBinaryFlat>(bits);
    slot->add(count, reinterpret_cast<const uint8_t*>(Database(bits).words.data()));
  }
  return *slot;
}

const uint8_t* FaissQuery(const BinaryCodes& queries, int64_t q) {
  return reinterpret_cast<const uint8_t*>(queries.code(q));
}

void SetThroughput(benchmark::State& state, int64_t codes, int queries_per_iteration) {
  state.counters["codes/s"] =
      benchmark::Counter(static_cast<double>(codes) * queries_per_iteration * state.iterations(),
                         benchmark::Counter::kIsRate);
}

// --- k-best, one query per call -----------------------------------------------------

void OursKBest(benchmark::State& state, int bits, int64_t count, PopcountKernel kernel) {
  if (!PopcountKernelAvailable(kernel)) {
    state.SkipWithError("kernel not supported by this CPU");
    return;
  }
  const HammingIndex& index = Ours(bits, count, kernel);
  const BinaryCodes& queries = Queries(bits);
  int64_t q = 0;
  for (auto _ : state) {
    auto result = index.KBestSearch(queries.code(q), kK);
    benchmark::DoNotOptimize(result.data());
    q = (q + 1) % kQueryPool;
  }
  SetThroughput(state, count, 1);
}

void FaissKBest(benchmark::State& state, int bits, int64_t count, bool use_heap) {
  const faiss::IndexBinaryFlat& index = Faiss(bits, count);
  const_cast<faiss::IndexBinaryFlat&>(index).use_heap = use_heap;
  const BinaryCodes& queries = Queries(bits);
  std::vector<int32_t> distances(kK);
  std::vector<faiss::Index::idx_t> labels(kK);
  int64_t q = 0;
  for (auto _ : state) {
    index.search(1, FaissQuery(queries, q), kK, distances.data(), labels.data());
    benchmark::DoNotOptimize(labels.data());
    q = (q + 1) % kQueryPool;
  }
  const_cast<faiss::IndexBinaryFlat&>(index).use_heap = true;
  SetThroughput(state, count, 1);
}

template <class HammingComputer>
void FaissNativeScan(const uint8_t* codes, int64_t count, int code_size, const uint8_t* query,
                     int32_t* distances, int64_t* labels) {
  faiss::maxheap_heapify<int32_t>(kK, distances, labels);
  const HammingComputer computer(query, code_size);
  for (int64_t j = 0; j < count; ++j, codes += code_size) {
    const int32_t distance = computer.hamming(codes);
    if (distance < distances[0]) {
      faiss::maxheap_replace_top<int32_t>(kK, distances, labels, distance, j);
    }
  }
  faiss::maxheap_reorder<int32_t>(kK, distances, labels);
}

void FaissNativeKBest(benchmark::State& state, int bits, int64_t count) {
  const uint8_t* codes = reinterpret_cast<const uint8_t*>(Database(bits).words.data());
  const BinaryCodes& queries = Queries(bits);
  const int code_size = bits / 8;
  std::vector<int32_t> distances(kK);
  std::vector<int64_t> labels(kK);
  int64_t q = 0;
  for (auto _ : state) {
    const uint8_t* query = FaissQuery(queries, q);
    if (bits == 64) {
      FaissNativeScan<faiss::HammingComputer8>(codes, count, code_size, query, distances.data(),
                                               labels.data());
    } else if (bits == 128) {
      FaissNativeScan<faiss::HammingComputer16>(codes, count, code_size, query, distances.data(),
                                                labels.data());
    } else {
      FaissNativeScan<faiss::HammingComputer32>(codes, count, code_size, query, distances.data(),
                                                labels.data());
    }
    benchmark::DoNotOptimize(labels.data());
    q = (q + 1) % kQueryPool;
  }
  SetThroughput(state, count, 1);
}

// --- k-best, a batch of 32 queries per call (both block the database over queries) ----

void OursKBestBatch(benchmark::State& state, int bits) {
  const HammingIndex& index = Ours(bits, kMaxCodes, PopcountKernel::kAuto);
  const BinaryCodes batch = Prefix(Queries(bits), kBatchQueries);
  for (auto _ : state) {
    auto result = index.KBestSearch(batch, kK);
    benchmark::DoNotOptimize(result.data());
  }
  SetThroughput(state, kMaxCodes, kBatchQueries);
}

void FaissKBestBatch(benchmark::State& state, int bits) {
  const faiss::IndexBinaryFlat& index = Faiss(bits, kMaxCodes);
  std::vector<int32_t> distances(kK * kBatchQueries);
  std::vector<faiss::Index::idx_t> labels(kK * kBatchQueries);
  for (auto _ : state) {
    index.search(kBatchQueries, FaissQuery(Queries(bits), 0), kK, distances.data(), labels.data());
    benchmark::DoNotOptimize(labels.data());
  }
  SetThroughput(state, kMaxCodes, kBatchQueries);
}

// --- radius search: radius at ≈ 0.6 % of random codes (bits/2 − 2.5 σ) -----------------

int BenchRadius(int bits) { return static_cast<int>(bits / 2 - 2.5 * std::sqrt(bits) / 2); }

void OursRadius(benchmark::State& state, int bits, int radius) {
  const HammingIndex& index = Ours(bits, kMaxCodes, PopcountKernel::kAuto);
  const BinaryCodes& queries = Queries(bits);
  int64_t q = 0, flagged = 0;
  for (auto _ : state) {
    auto result = index.RadiusSearch(queries.code(q), radius);
    flagged += result.size();
    benchmark::DoNotOptimize(result.data());
    q = (q + 1) % kQueryPool;
  }
  state.counters["flagged%"] =
      100.0 * flagged / (static_cast<double>(kMaxCodes) * state.iterations());
  SetThroughput(state, kMaxCodes, 1);
}

void FaissRadius(benchmark::State& state, int bits, int radius) {
  const faiss::IndexBinaryFlat& index = Faiss(bits, kMaxCodes);
  const BinaryCodes& queries = Queries(bits);
  int64_t q = 0, flagged = 0;
  for (auto _ : state) {
    faiss::RangeSearchResult result(1);
    // faiss's range search keeps distances < radius (strict): radius + 1 flags the same set.
    index.range_search(1, FaissQuery(queries, q), radius + 1, &result);
    flagged += result.lims[1];
    q = (q + 1) % kQueryPool;
  }
  state.counters["flagged%"] =
      100.0 * flagged / (static_cast<double>(kMaxCodes) * state.iterations());
  SetThroughput(state, kMaxCodes, 1);
}

// --- hash training and encoding at 10k × 308-D --------------------------------------

const Eigen::MatrixXf& TrainingFeatures() {
  static const Eigen::MatrixXf features = [] {
    std::mt19937_64 rng(11);
    std::normal_distribution<float> normal(0.0f, 1.0f);
    Eigen::MatrixXf centres(40, 308);
    for (int i = 0; i < centres.size(); ++i) centres.data()[i] = normal(rng);
    Eigen::MatrixXf out(10000, 308);
    for (int i = 0; i < out.rows(); ++i) {
      const int c = static_cast<int>(rng() % centres.rows());
      for (int d = 0; d < out.cols(); ++d) out(i, d) = centres(c, d) + 0.5f * normal(rng);
    }
    return out;
  }();
  return features;
}

void Train(benchmark::State& state, HashMethod method, int bits) {
  HashOptions options;
  options.method = method;
  options.bits = bits;
  HashTrainingSummary summary;
  for (auto _ : state) {
    Hasher hasher = Hasher::Train(TrainingFeatures(), options, &summary);
    benchmark::DoNotOptimize(&hasher);
  }
  state.counters["loss_before"] = summary.initial_loss;
  state.counters["loss_after"] = summary.final_loss;
}

void Encode(benchmark::State& state, HashMethod method, int bits) {
  HashOptions options;
  options.method = method;
  options.bits = bits;
  const Hasher hasher = Hasher::Train(TrainingFeatures(), options);
  for (auto _ : state) {
    BinaryCodes codes = hasher.Encode(TrainingFeatures());
    benchmark::DoNotOptimize(codes.words.data());
  }
  state.counters["rows/s"] =
      benchmark::Counter(static_cast<double>(TrainingFeatures().rows()) * state.iterations(),
                         benchmark::Counter::kIsRate);
}

// Checks that ours and faiss agree on the k-best distances (faiss orders ties
// arbitrarily, so indices are not compared).
void CrossCheck() {
  for (int bits : {64, 128, 256}) {
    const HammingIndex& ours = Ours(bits, kMaxCodes, PopcountKernel::kAuto);
    const faiss::IndexBinaryFlat& theirs = Faiss(bits, kMaxCodes);
    for (int64_t q = 0; q < 4; ++q) {
      const auto mine = ours.KBestSearch(Queries(bits).code(q), kK);
      std::vector<int32_t> distances(kK);
      std::vector<faiss::Index::idx_t> labels(kK);
      theirs.search(1, FaissQuery(Queries(bits), q), kK, distances.data(), labels.data());
      for (int i = 0; i < kK; ++i) {
        if (mine[i].hamming_distance != distances[i]) {
          std::fprintf(stderr, "MISMATCH bits %d query %ld rank %d: ours %d faiss %d\n", bits,
                       static_cast<long>(q), i, mine[i].hamming_distance, distances[i]);
          std::exit(1);
        }
      }
    }
  }
}

// Records every run for the closing summary: CPU seconds per iteration (the machine may
// be shared, and CPU time leaves out preemption), the minimum over repetitions.
class SummaryReporter : public bench::DisplayReporter {
 public:
  explicit SummaryReporter(benchmark::ConsoleReporter::OutputOptions options)
      : DisplayReporter(options) {}
  void ReportRuns(const std::vector<Run>& runs) override {
    DisplayReporter::ReportRuns(runs);
    for (const Run& run : runs) {
      if (run.run_type != Run::RT_Iteration || run.error_occurred || run.iterations == 0) continue;
      const std::string name = run.run_name.function_name;  // without "/iterations:1" etc.
      const double seconds = run.cpu_accumulated_time / run.iterations;
      const auto it = seconds_.find(name);
      seconds_[name] = it == seconds_.end() ? seconds : std::min(it->second, seconds);
    }
  }

  // CPU seconds per iteration, or NaN when the run is absent (filtered out).
  double Seconds(const std::string& name) const {
    const auto it = seconds_.find(name);
    return it == seconds_.end() ? std::nan("") : it->second;
  }

  void PrintSummary() const {
    std::printf("\n=== k-best (k = %d), one query per call, single thread ===\n", kK);
    std::printf(
        "(faiss = IndexBinaryFlat::search as installed, heap / counting selection;\n"
        " native = faiss's HammingComputer + heap scan compiled with -march=native)\n");
    std::printf("%5s %8s | %9s %9s %9s %9s | %8s %8s %8s | %6s %6s %6s\n", "bits", "codes",
                "ours us", "faiss us", "count us", "native us", "ours G/s", "faiss G/s",
                "nativeG/s", "ratio", "r.cnt", "r.nat");
    for (int bits : {64, 128, 256}) {
      for (int64_t n : {int64_t{1000}, int64_t{10000}, int64_t{100000}, kMaxCodes}) {
        const double ours = Seconds(Name("kbest/ours", bits, n));
        const double faiss = Seconds(Name("kbest/faiss_heap", bits, n));
        const double faiss_counting = Seconds(Name("kbest/faiss_counting", bits, n));
        const double native = Seconds(Name("kbest/faiss_native", bits, n));
        std::printf("%5d %8ld | %9.2f %9.2f %9.2f %9.2f | %8.3f %8.3f %8.3f | %6.1f %6.1f %6.2f\n",
                    bits, static_cast<long>(n), 1e6 * ours, 1e6 * faiss, 1e6 * faiss_counting,
                    1e6 * native, n / ours * 1e-9, n / faiss * 1e-9, n / native * 1e-9,
                    faiss / ours, faiss_counting / ours, native / ours);
      }
    }
    std::printf("\n=== 10^6 codes: batch of %d queries, radius search, kernels ===\n",
                kBatchQueries);
    std::printf(
        "(radius: ≈ 0.6 %% flagged; half: radius = bits/2, ≈ 55 %% flagged; kernels:\n"
        " our k-best with each popcount kernel)\n");
    std::printf("%6s | %10s %10s %7s | %10s %10s %7s | %10s %10s %7s | %9s %9s %9s\n", "bits",
                "batch ours", "faiss", "ratio", "radius us", "faiss us", "ratio", "half us",
                "faiss us", "ratio", "scalar", "avx2", "avx512");
    for (int bits : {64, 128, 256}) {
      const double batch_ours = Seconds("kbest_batch32/ours/" + std::to_string(bits));
      const double batch_faiss = Seconds("kbest_batch32/faiss/" + std::to_string(bits));
      const double radius_ours = Seconds("radius/ours/" + std::to_string(bits));
      const double radius_faiss = Seconds("radius/faiss/" + std::to_string(bits));
      const double half_ours = Seconds("radius_half/ours/" + std::to_string(bits));
      const double half_faiss = Seconds("radius_half/faiss/" + std::to_string(bits));
      std::printf(
          "%6d | %8.0fus %8.0fus %7.2f | %10.1f %10.1f %7.2f | %10.1f %10.1f %7.2f | "
          "%7.1fus %7.1fus %7.1fus\n",
          bits, 1e6 * batch_ours, 1e6 * batch_faiss, batch_faiss / batch_ours, 1e6 * radius_ours,
          1e6 * radius_faiss, radius_faiss / radius_ours, 1e6 * half_ours, 1e6 * half_faiss,
          half_faiss / half_ours, 1e6 * Seconds(Name("kernel/scalar", bits, kMaxCodes)),
          1e6 * Seconds(Name("kernel/avx2", bits, kMaxCodes)),
          1e6 * Seconds(Name("kernel/avx512", bits, kMaxCodes)));
    }
    std::printf("\n=== hashing, 10000 × 308 features ===\n");
    std::printf("%6s %6s %12s %12s\n", "method", "bits", "train ms", "encode ms");
    for (int bits : {64, 256}) {
      for (HashMethod method : {HashMethod::kLsh, HashMethod::kSpectral, HashMethod::kMinimalLoss,
                                HashMethod::kBinaryReconstructive, HashMethod::kItq}) {
        const std::string suffix = ToString(method) + "/" + std::to_string(bits);
        std::printf("%6s %6d %12.1f %12.2f\n", ToString(method).c_str(), bits,
                    1e3 * Seconds("train/" + suffix), 1e3 * Seconds("encode/" + suffix));
      }
    }
  }

  static std::string Name(const std::string& prefix, int bits, int64_t n) {
    return prefix + "/" + std::to_string(bits) + "/" + std::to_string(n);
  }

 private:
  std::map<std::string, double> seconds_;
};

void RegisterAll() {
  using Reporter = SummaryReporter;
  for (int bits : {64, 128, 256}) {
    for (int64_t n : {int64_t{1000}, int64_t{10000}, int64_t{100000}, kMaxCodes}) {
      benchmark::RegisterBenchmark(Reporter::Name("kbest/ours", bits, n).c_str(), OursKBest, bits,
                                   n, PopcountKernel::kAuto);
      benchmark::RegisterBenchmark(Reporter::Name("kbest/faiss_heap", bits, n).c_str(), FaissKBest,
                                   bits, n, true);
      benchmark::RegisterBenchmark(Reporter::Name("kbest/faiss_counting", bits, n).c_str(),
                                   FaissKBest, bits, n, false);
      benchmark::RegisterBenchmark(Reporter::Name("kbest/faiss_native", bits, n).c_str(),
                                   FaissNativeKBest, bits, n);
    }
  }
  for (int bits : {64, 128, 256}) {
    benchmark::RegisterBenchmark(("kbest_batch32/ours/" + std::to_string(bits)).c_str(),
                                 OursKBestBatch, bits);
    benchmark::RegisterBenchmark(("kbest_batch32/faiss/" + std::to_string(bits)).c_str(),
                                 FaissKBestBatch, bits);
    // A selective radius (≈ 0.6 % flagged) and the thesis's LSH radius, half the code
    // length (≈ 55 % flagged).
    benchmark::RegisterBenchmark(("radius/ours/" + std::to_string(bits)).c_str(), OursRadius, bits,
                                 BenchRadius(bits));
    benchmark::RegisterBenchmark(("radius/faiss/" + std::to_string(bits)).c_str(), FaissRadius,
                                 bits, BenchRadius(bits));
    benchmark::RegisterBenchmark(("radius_half/ours/" + std::to_string(bits)).c_str(), OursRadius,
                                 bits, bits / 2);
    benchmark::RegisterBenchmark(("radius_half/faiss/" + std::to_string(bits)).c_str(), FaissRadius,
                                 bits, bits / 2);
    for (PopcountKernel kernel :
         {PopcountKernel::kScalar, PopcountKernel::kAvx2, PopcountKernel::kAvx512}) {
      benchmark::RegisterBenchmark(
          Reporter::Name("kernel/" + ToString(kernel), bits, kMaxCodes).c_str(), OursKBest, bits,
          kMaxCodes, kernel);
    }
  }
  for (int bits : {64, 256}) {
    for (HashMethod method : {HashMethod::kLsh, HashMethod::kSpectral, HashMethod::kMinimalLoss,
                              HashMethod::kBinaryReconstructive, HashMethod::kItq}) {
      const std::string suffix = ToString(method) + "/" + std::to_string(bits);
      benchmark::RegisterBenchmark(("train/" + suffix).c_str(), Train, method, bits)
          ->Iterations(1)
          ->Unit(benchmark::kMillisecond);
      benchmark::RegisterBenchmark(("encode/" + suffix).c_str(), Encode, method, bits)
          ->Unit(benchmark::kMillisecond);
    }
  }
}

}  // namespace
}  // namespace sope

int main(int argc, char** argv) {
  omp_set_num_threads(1);
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  sope::CrossCheck();
  sope::RegisterAll();
  // Colour only on a terminal, so logs stay readable.
  sope::SummaryReporter reporter(isatty(fileno(stdout)) ? benchmark::ConsoleReporter::OO_Defaults
                                                        : benchmark::ConsoleReporter::OO_Tabular);
  benchmark::RunSpecifiedBenchmarks(&reporter);
  reporter.PrintSummary();
  benchmark::Shutdown();
  return 0;
}
