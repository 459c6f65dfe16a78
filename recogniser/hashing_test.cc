#include "recogniser/hashing.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/units.h"
#include "recogniser/hamming_search.h"
#include "tests/test_support.h"
#include "recogniser/random_codes_testing.h"

namespace sope {
namespace {

constexpr HashMethod kAllMethods[] = {HashMethod::kLsh, HashMethod::kSpectral,
                                      HashMethod::kMinimalLoss, HashMethod::kBinaryReconstructive,
                                      HashMethod::kItq};

// Isotropic Gaussian clusters: centres ~ N(0, I), members = centre + σ·N(0, I); cluster
// of each row drawn at random, so row order carries no information.
Eigen::MatrixXf ClusteredFeatures(int rows, int dims, const Eigen::MatrixXf& centres, float sigma,
                                  std::mt19937_64* rng) {
  std::normal_distribution<float> normal(0.0f, 1.0f);
  std::uniform_int_distribution<int> cluster(0, static_cast<int>(centres.rows()) - 1);
  Eigen::MatrixXf features(rows, dims);
  for (int i = 0; i < rows; ++i) {
    const int c = cluster(*rng);
    for (int d = 0; d < dims; ++d) features(i, d) = centres(c, d) + sigma * normal(*rng);
  }
  return features;
}

// Ground truth: the `k` Euclidean nearest database rows of each query.
std::vector<std::vector<int>> EuclideanNeighbours(const Eigen::MatrixXf& database,
                                                  const Eigen::MatrixXf& queries, int k) {
  std::vector<std::vector<int>> truth(queries.rows());
  for (int q = 0; q < queries.rows(); ++q) {
    std::vector<std::pair<float, int>> distances(database.rows());
    for (int i = 0; i < database.rows(); ++i) {
      distances[i] = {(database.row(i) - queries.row(q)).squaredNorm(), i};
    }
    std::partial_sort(distances.begin(), distances.begin() + k, distances.end());
    for (int j = 0; j < k; ++j) truth[q].push_back(distances[j].second);
  }
  return truth;
}

struct Retrieval {
  double mean_average_precision = 0.0;  // of the full Hamming ranking (ties by index)
  double radius_recall = 0.0;           // true neighbours within the radius
  double flagged_fraction = 0.0;        // database fraction within the radius
};

Retrieval Evaluate(const BinaryCodes& database, const BinaryCodes& queries,
                   const std::vector<std::vector<int>>& truth, int radius_bits) {
  const HammingIndex index(database);
  Retrieval out;
  for (int64_t q = 0; q < queries.size(); ++q) {
    std::vector<char> relevant(database.size(), 0);
    for (int i : truth[q]) relevant[i] = 1;
    const auto ranking = index.KBestSearch(queries.code(q), static_cast<int>(database.size()));
    double hits = 0.0, precision_sum = 0.0;
    for (size_t r = 0; r < ranking.size(); ++r) {
      if (relevant[ranking[r].index]) precision_sum += ++hits / (r + 1);
    }
    out.mean_average_precision += precision_sum / truth[q].size();
    const auto flagged = index.RadiusSearch(queries.code(q), radius_bits);
    int found = 0;
    for (const HammingMatch& match : flagged) found += relevant[match.index];
    out.radius_recall += static_cast<double>(found) / truth[q].size();
    out.flagged_fraction += static_cast<double>(flagged.size()) / database.size();
  }
  out.mean_average_precision /= queries.size();
  out.radius_recall /= queries.size();
  out.flagged_fraction /= queries.size();
  return out;
}

// Mean and largest |fraction of ones − ½| over the bits.
std::pair<double, double> BitImbalance(const BinaryCodes& codes) {
  double mean = 0.0, worst = 0.0;
  for (int b = 0; b < codes.bits; ++b) {
    double ones = 0.0;
    for (int64_t i = 0; i < codes.size(); ++i) ones += codes.GetBit(i, b);
    const double imbalance = std::abs(ones / codes.size() - 0.5);
    mean += imbalance / codes.bits;
    worst = std::max(worst, imbalance);
  }
  return {mean, worst};
}

using testing::RandomCodes;

// 20 clusters in 64-D (σ = 0.7, so clusters are separated but their members' neighbour
// order is noisy), 4000 database rows, 200 held-out queries, 50 true neighbours each;
// every method trained once at 32 bits on the database.
class HashingQualityTest : public ::testing::Test {
 protected:
  static constexpr int kBits = 32;
  static constexpr int kNeighbours = 50;

  struct Trained {
    Hasher hasher;
    HashTrainingSummary summary;
    BinaryCodes database_codes;
    BinaryCodes query_codes;
  };

  static void SetUpTestSuite() {
    std::mt19937_64 rng(2024);
    std::normal_distribution<float> normal(0.0f, 1.0f);
    Eigen::MatrixXf centres(20, 64);
    for (int i = 0; i < centres.size(); ++i) centres.data()[i] = normal(rng);
    database_ = new Eigen::MatrixXf(ClusteredFeatures(4000, 64, centres, 0.7f, &rng));
    queries_ = new Eigen::MatrixXf(ClusteredFeatures(200, 64, centres, 0.7f, &rng));
    truth_ =
        new std::vector<std::vector<int>>(EuclideanNeighbours(*database_, *queries_, kNeighbours));
    trained_ = new std::map<HashMethod, Trained>();
    for (HashMethod method : kAllMethods) {
      HashOptions options;
      options.method = method;
      options.bits = kBits;
      Trained& t = (*trained_)[method];
      t.hasher = Hasher::Train(*database_, options, &t.summary);
      t.database_codes = t.hasher.Encode(*database_);
      t.query_codes = t.hasher.Encode(*queries_);
    }
  }
  static void TearDownTestSuite() {
    delete database_;
    delete queries_;
    delete truth_;
    delete trained_;
  }

  static Eigen::MatrixXf* database_;
  static Eigen::MatrixXf* queries_;
  static std::vector<std::vector<int>>* truth_;
  static std::map<HashMethod, Trained>* trained_;
};

Eigen::MatrixXf* HashingQualityTest::database_ = nullptr;
Eigen::MatrixXf* HashingQualityTest::queries_ = nullptr;
std::vector<std::vector<int>>* HashingQualityTest::truth_ = nullptr;
std::map<HashMethod, HashingQualityTest::Trained>* HashingQualityTest::trained_ = nullptr;

// Measured on this data at 32 bits over 13 data sets of this generator (each with its
// own training seed): mAP of the Hamming ranking for the 50 true Euclidean neighbours;
// radius 5 bits = 15 %, the thesis's MLH/BRE flagging radius; a cluster is 5 % of the
// database.
//   random codes  mAP 0.014–0.015
//   lsh  mAP 0.293–0.336   radius recall 0.14–0.23 flagging 0.5–0.8 %
//        (mean mAP over 8 projection seeds 0.302–0.327)
//   sh   mAP 0.345–0.362   radius recall 0.35–0.67 flagging 1.3–2.9 %
//   mlh  mAP 0.314–0.335   radius recall 0.94–0.99 flagging 4.7–6.8 %
//   bre  mAP 0.339–0.359   radius recall 0.46–0.62 flagging 1.8–2.5 %
//   itq  mAP 0.334–0.352   radius recall 0.97–0.99 flagging 4.7–5.0 %
// SH, BRE and ITQ beat LSH's mean ranking quality by ≥ 0.017 on every data set; MLH's
// ranking is level with LSH (its loss only asks neighbours to be within ρ bits, not
// ordered), but it recalls the neighbours within its margin, which is what the coarse
// search's radius flagging needs.
TEST_F(HashingQualityTest, SimilarityPreservedBetterThanRandom) {
  const int radius = static_cast<int>(std::lround(0.15 * kBits));
  const BinaryCodes random_db = RandomCodes(kBits, database_->rows(), 1);
  const BinaryCodes random_queries = RandomCodes(kBits, queries_->rows(), 2);
  const Retrieval random = Evaluate(random_db, random_queries, *truth_, radius);
  std::printf("%-6s %8s %14s %10s %16s  %s\n", "method", "mAP", "radius recall", "flagged",
              "bit imbalance", "training");
  std::printf("%-6s %8.4f %14.3f %9.2f%%\n", "random", random.mean_average_precision,
              random.radius_recall, 100.0 * random.flagged_fraction);
  std::map<HashMethod, Retrieval> retrieval;
  for (HashMethod method : kAllMethods) {
    const Trained& t = trained_->at(method);
    retrieval[method] = Evaluate(t.database_codes, t.query_codes, *truth_, radius);
    const auto [mean_imbalance, worst_imbalance] = BitImbalance(t.database_codes);
    std::printf("%-6s %8.4f %14.3f %9.2f%% %7.3f / %5.3f  %s\n", ToString(method).c_str(),
                retrieval[method].mean_average_precision, retrieval[method].radius_recall,
                100.0 * retrieval[method].flagged_fraction, mean_imbalance, worst_imbalance,
                t.summary.BriefReport().c_str());
    EXPECT_GT(retrieval[method].mean_average_precision, 10.0 * random.mean_average_precision)
        << ToString(method);
    EXPECT_GT(retrieval[method].mean_average_precision, 0.25) << ToString(method);
  }
  // LSH's quality varies with its random projections (0.293–0.336 over 9 data sets), so
  // the learned methods are compared with LSH's mean over 8 projection seeds.
  double lsh = 0.0;
  for (uint64_t seed = 1; seed <= 8; ++seed) {
    HashOptions options;
    options.method = HashMethod::kLsh;
    options.bits = kBits;
    options.seed = seed;
    const Hasher hasher = Hasher::Train(*database_, options);
    lsh += Evaluate(hasher.Encode(*database_), hasher.Encode(*queries_), *truth_, radius)
               .mean_average_precision /
           8.0;
  }
  std::printf("lsh mAP over 8 seeds: %.4f\n", lsh);
  EXPECT_GT(retrieval[HashMethod::kSpectral].mean_average_precision, lsh + 0.01);
  EXPECT_GT(retrieval[HashMethod::kBinaryReconstructive].mean_average_precision, lsh + 0.01);
  EXPECT_GT(retrieval[HashMethod::kItq].mean_average_precision, lsh + 0.01);
  EXPECT_GT(retrieval[HashMethod::kMinimalLoss].mean_average_precision, 0.9 * lsh);
  // The radius operating point: MLH and ITQ find ≥ 90 % of the neighbours flagging
  // < 10 % of the database; LSH finds < 40 %.
  for (HashMethod method : {HashMethod::kMinimalLoss, HashMethod::kItq}) {
    EXPECT_GT(retrieval[method].radius_recall, 0.9) << ToString(method);
    EXPECT_LT(retrieval[method].flagged_fraction, 0.1) << ToString(method);
  }
  EXPECT_LT(retrieval[HashMethod::kLsh].radius_recall, 0.4);
}

// Measured (32 bits, same data): mean / worst |ones − ½| — lsh 0.02/0.06, sh 0.12–0.15 /
// 0.30–0.40 (the first mode of a direction splits its range, not its mass), mlh 0.21–0.23
// / 0.43–0.50 (the hinge loss lets bits go constant), bre 0.015/0.05, itq 0.02/0.07.
TEST_F(HashingQualityTest, BitsAreBalancedOnTrainingData) {
  const std::map<HashMethod, std::pair<double, double>> limits = {
      {HashMethod::kLsh, {0.05, 0.15}},
      {HashMethod::kSpectral, {0.22, 0.48}},
      {HashMethod::kMinimalLoss, {0.30, 0.5}},
      {HashMethod::kBinaryReconstructive, {0.05, 0.15}},
      {HashMethod::kItq, {0.05, 0.15}}};
  for (HashMethod method : kAllMethods) {
    const auto [mean_imbalance, worst_imbalance] =
        BitImbalance(trained_->at(method).database_codes);
    EXPECT_LT(mean_imbalance, limits.at(method).first) << ToString(method);
    EXPECT_LE(worst_imbalance, limits.at(method).second) << ToString(method);
  }
}

// The iterative trainers reduce their own objective (measured: MLH eq. 2.20 1.7 → 0.2,
// BRE eq. 2.21 −30 %, ITQ quantisation loss −30 %).
TEST_F(HashingQualityTest, TrainingReducesItsLoss) {
  for (HashMethod method :
       {HashMethod::kMinimalLoss, HashMethod::kBinaryReconstructive, HashMethod::kItq}) {
    const HashTrainingSummary& summary = trained_->at(method).summary;
    EXPECT_LT(summary.final_loss, 0.9 * summary.initial_loss) << summary.BriefReport();
    EXPECT_GT(summary.iterations, 0);
    EXPECT_EQ(summary.bits, kBits);
    EXPECT_EQ(summary.input_dims, 64);
  }
  for (HashMethod method : {HashMethod::kLsh, HashMethod::kSpectral}) {
    EXPECT_TRUE(std::isnan(trained_->at(method).summary.final_loss));
  }
}

TEST_F(HashingQualityTest, SerializeRoundTripGivesIdenticalCodes) {
  for (HashMethod method : kAllMethods) {
    const Trained& t = trained_->at(method);
    const std::vector<uint8_t> bytes = t.hasher.Serialize();
    const Hasher restored = Hasher::Deserialize(bytes);
    EXPECT_EQ(restored.method(), method);
    EXPECT_EQ(restored.bits(), kBits);
    EXPECT_EQ(restored.input_dims(), 64);
    EXPECT_EQ(restored.Encode(*queries_).words, t.query_codes.words) << ToString(method);
    EXPECT_EQ(restored.Serialize(), bytes);
    // Every truncation is a clear error, never a crash or a half-read hasher.
    for (size_t size = 0; size < bytes.size(); size += std::max<size_t>(1, bytes.size() / 97)) {
      EXPECT_THROW_WITH_MESSAGE(Hasher::Deserialize(bytes.data(), size), Error,
                                "hasher data truncated")
          << size;
    }
    EXPECT_THROW_WITH_MESSAGE(Hasher::Deserialize(bytes.data(), bytes.size() - 1), Error,
                              "hasher data truncated");
    std::vector<uint8_t> longer = bytes;
    longer.push_back(0);
    EXPECT_THROW_WITH_MESSAGE(Hasher::Deserialize(longer), Error, "1 trailing bytes");
  }
  std::vector<uint8_t> bytes = trained_->at(HashMethod::kLsh).hasher.Serialize();
  std::vector<uint8_t> bad_magic = bytes;
  bad_magic[0] = 'X';
  EXPECT_THROW_WITH_MESSAGE(Hasher::Deserialize(bad_magic), Error, "bad magic");
  std::vector<uint8_t> bad_version = bytes;
  bad_version[8] = 99;
  EXPECT_THROW_WITH_MESSAGE(Hasher::Deserialize(bad_version), Error, "format version 99");
  std::vector<uint8_t> bad_method = bytes;
  bad_method[12] = 17;
  EXPECT_THROW_WITH_MESSAGE(Hasher::Deserialize(bad_method), Error, "hash method id 17");
  EXPECT_THROW_WITH_MESSAGE(Hasher::Deserialize(nullptr, 0), Error, "hasher data truncated");
}

TEST(HashingTest, CodesAreDeterministicForASeed) {
  std::mt19937_64 rng(5);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  Eigen::MatrixXf centres(5, 24);
  for (int i = 0; i < centres.size(); ++i) centres.data()[i] = normal(rng);
  const Eigen::MatrixXf features = ClusteredFeatures(600, 24, centres, 0.5f, &rng);
  for (HashMethod method : kAllMethods) {
    HashOptions options;
    options.method = method;
    options.bits = 40;  // not a multiple of 64: padding stays zero
    options.mlh.iterations = 200;
    options.bre.updates_per_bit = 10;
    const BinaryCodes a = Hasher::Train(features, options).Encode(features);
    const BinaryCodes b = Hasher::Train(features, options).Encode(features);
    EXPECT_EQ(a.bits, 40);
    EXPECT_EQ(a.size(), 600);
    EXPECT_NO_THROW(a.Check());
    EXPECT_EQ(a.words, b.words) << ToString(method);
    if (method != HashMethod::kSpectral) {  // SH has no random choice below 20000 rows
      options.seed = 43;
      const BinaryCodes c = Hasher::Train(features, options).Encode(features);
      EXPECT_NE(a.words, c.words) << ToString(method);
    }
  }
}

// More bits than feature dimensions: SH uses several modes per direction, ITQ rotates a
// zero-padded PCA embedding; all methods still separate the clusters.
TEST(HashingTest, MoreBitsThanDimensions) {
  std::mt19937_64 rng(6);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  Eigen::MatrixXf centres(8, 12);
  for (int i = 0; i < centres.size(); ++i) centres.data()[i] = 2.0f * normal(rng);
  const Eigen::MatrixXf database = ClusteredFeatures(800, 12, centres, 0.5f, &rng);
  const Eigen::MatrixXf queries = ClusteredFeatures(50, 12, centres, 0.5f, &rng);
  const auto truth = EuclideanNeighbours(database, queries, 20);
  for (HashMethod method : kAllMethods) {
    HashOptions options;
    options.method = method;
    options.bits = 64;
    options.mlh.iterations = 300;
    options.bre.updates_per_bit = 10;
    const Hasher hasher = Hasher::Train(database, options);
    const Retrieval retrieval =
        Evaluate(hasher.Encode(database), hasher.Encode(queries), truth, 10);
    // Random codes give ≈ 20/800 = 0.025.
    EXPECT_GT(retrieval.mean_average_precision, 0.25) << ToString(method);
  }
}

// Spectral hashing against its closed form: for independent uniform coordinates on
// [0, 4] × [0, 1.5] the PCA directions are the axes, and the modes in order of ω = kπ/R
// are (x, k=1) π/4, (x, 2) π/2, (y, 1) π/1.5, (x, 3) 3π/4, (x, 4) π; bit = cos(ω·u) > 0
// with u the offset from the range start (up to the sign of each PCA direction).
TEST(HashingTest, SpectralHashingMatchesAnalyticEigenfunctions) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> ux(0.0f, 4.0f), uy(0.0f, 1.5f);
  Eigen::MatrixXf features(5000, 2);
  for (int i = 0; i < features.rows(); ++i) features.row(i) << ux(rng), uy(rng);
  HashOptions options;
  options.method = HashMethod::kSpectral;
  options.bits = 8;
  const Hasher hasher = Hasher::Train(features, options);
  const BinaryCodes codes = hasher.Encode(features);
  const int axis[] = {0, 0, 1, 0, 0};
  const int mode[] = {1, 2, 1, 3, 4};
  const float length[] = {4.0f, 1.5f};
  for (int b = 0; b < 5; ++b) {
    int agree_forward = 0, agree_mirrored = 0;
    for (int i = 0; i < features.rows(); ++i) {
      const float u = features(i, axis[b]) / length[axis[b]];  // in [0, 1]
      const bool forward = std::cos(mode[b] * kPi * u) > 0.0;
      const bool mirrored = std::cos(mode[b] * kPi * (1.0 - u)) > 0.0;
      agree_forward += codes.GetBit(i, b) == forward;
      agree_mirrored += codes.GetBit(i, b) == mirrored;
    }
    const double agreement =
        static_cast<double>(std::max(agree_forward, agree_mirrored)) / features.rows();
    EXPECT_GT(agreement, 0.98) << "bit " << b;
  }
}

// The O(q) loss-augmented inference against brute force over every distance m.
TEST(HashingTest, LossAugmentedInferenceMatchesBruteForce) {
  std::mt19937_64 rng(8);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  for (int trial = 0; trial < 3000; ++trial) {
    const int q = std::vector<int>{8, 13, 32, 64}[trial % 4];
    const bool similar = (trial / 4) % 2 == 0;
    const int rho = 1 + static_cast<int>(rng() % q);
    const double lambda = std::vector<double>{0.5, 1.0, 2.0, 5.0}[(trial / 8) % 4];
    const float scale = std::vector<float>{0.1f, 1.0f, 4.0f}[(trial / 32) % 3];
    std::vector<float> gain(q);
    for (float& g : gain) g = scale * normal(rng);
    if (trial % 5 == 0) gain[1] = gain[0];  // ties
    auto loss = [&](int m) {
      return similar ? std::max(m - rho + 1, 0) : lambda * std::max(rho - m + 1, 0);
    };
    std::vector<float> sorted = gain;
    std::sort(sorted.rbegin(), sorted.rend());
    double best = loss(0), prefix = 0.0;
    for (int m = 1; m <= q; ++m) {
      prefix += sorted[m - 1];
      best = std::max(best, prefix + loss(m));
    }
    std::vector<int> order(q);
    const int m = internal::LossAugmentedDistance(gain, similar, rho, lambda, &order);
    ASSERT_GE(m, 0);
    ASSERT_LE(m, q);
    double chosen = 0.0, top = 0.0;
    for (int r = 0; r < m; ++r) {
      chosen += gain[order[r]];
      top += sorted[r];
    }
    EXPECT_NEAR(chosen, top, 1e-4) << "order does not hold the " << m << " largest gains";
    EXPECT_NEAR(chosen + loss(m), best, 1e-4) << "trial " << trial;
  }
}

TEST(HashingTest, EnumNamesRoundTrip) {
  for (HashMethod method : kAllMethods) EXPECT_EQ(HashMethodFromString(ToString(method)), method);
  EXPECT_EQ(ToString(HashMethod::kSpectral), "sh");
  EXPECT_EQ(ToString(HashMethod::kMinimalLoss), "mlh");
  EXPECT_EQ(ToString(HashMethod::kBinaryReconstructive), "bre");
  EXPECT_THROW_WITH_MESSAGE(HashMethodFromString("pq"), Error, "'pq'");
  for (BreKernel kernel : {BreKernel::kLinear, BreKernel::kGaussian}) {
    EXPECT_EQ(BreKernelFromString(ToString(kernel)), kernel);
  }
  EXPECT_THROW_WITH_MESSAGE(BreKernelFromString("rbf"), Error, "'rbf'");
}

TEST(HashingTest, InvalidOptionsAndInputsThrow) {
  const Eigen::MatrixXf features = Eigen::MatrixXf::Random(100, 8);
  auto train_with = [&](auto mutate) {
    HashOptions options;
    mutate(options);
    return Hasher::Train(features, options);
  };
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.bits = 7; }), Error, "bits", "got 7");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.bits = 257; }), Error, "bits",
                            "got 257");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.max_training_samples = 1; }), Error,
                            "max_training_samples", "got 1");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.lsh.threshold_spread = -1.0; }),
                            Error, "threshold_spread", "got -1");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.mlh.margin_fraction = 1.0; }), Error,
                            "margin_fraction", "got 1");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.mlh.lambda = 0.0; }), Error, "lambda",
                            "got 0");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.mlh.learning_rate = -0.1; }), Error,
                            "learning_rate", "got -0.1");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.mlh.momentum = 1.0; }), Error,
                            "momentum", "got 1");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.mlh.pairs_per_batch = 1; }), Error,
                            "pairs_per_batch", "got 1");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.bre.anchors = 0; }), Error, "anchors",
                            "got 0");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.bre.bandwidth_scale = 0.0; }), Error,
                            "bandwidth_scale", "got 0");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.bre.neighbours = 0; }), Error,
                            "neighbours", "got 0");
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) { o.itq.iterations = -1; }), Error,
                            "iterations", "got -1");
  // An option of another method is checked too: options are validated as a whole.
  EXPECT_THROW_WITH_MESSAGE(train_with([](HashOptions& o) {
                              o.method = HashMethod::kLsh;
                              o.bre.training_points = 1;
                            }),
                            Error, "training_points", "got 1");

  HashOptions options;
  options.method = HashMethod::kLsh;
  EXPECT_THROW_WITH_MESSAGE(Hasher::Train(Eigen::MatrixXf::Random(1, 8), options), Error,
                            "feature rows", "got 1");
  EXPECT_THROW_WITH_MESSAGE(Hasher::Train(Eigen::MatrixXf(10, 0), options), Error, "feature column",
                            "got 0");
  Eigen::MatrixXf with_nan = features;
  with_nan(3, 4) = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW_WITH_MESSAGE(Hasher::Train(with_nan, options), Error, "NaN or infinity");

  const Hasher hasher = Hasher::Train(features, options);
  EXPECT_THROW_WITH_MESSAGE(hasher.Encode(Eigen::MatrixXf::Random(5, 9)), Error,
                            "8 feature columns", "got 9");
  EXPECT_EQ(hasher.Encode(Eigen::MatrixXf(0, 8)).size(), 0);
  const Hasher untrained;
  EXPECT_FALSE(untrained.trained());
  EXPECT_THROW_WITH_MESSAGE(untrained.Encode(features), Error, "untrained");
  EXPECT_THROW_WITH_MESSAGE(untrained.Serialize(), Error, "untrained");
}

}  // namespace
}  // namespace sope
