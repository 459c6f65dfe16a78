// Similarity-preserving binary codes for the coarse database search (thesis §2.4.2 and
// §4.6.1): a feature vector is compressed to a short bit string so that the Hamming
// distance between codes approximates the Euclidean distance between features, and the
// whole database can be scanned with XOR + popcount (recogniser/hamming_search.h).
//
// Five hashers, all trained here in C++ on the database features, one class per method
// behind recogniser/hash_function.h (hash_lsh.cc, hash_spectral.cc, hash_mlh.cc,
// hash_bre.cc, hash_itq.cc); Hasher below is the value type the database holds:
//  - LSH: Gaussian random projections of mean-centred features, thresholded at zero
//    (Charikar 2002) or, optionally, at random thresholds (Andoni & Indyk 2008) — the
//    data-independent baseline;
//  - spectral hashing (Weiss, Torralba & Fergus, NIPS 2008) — thesis eq. 4.12–4.13;
//  - minimal-loss hashing (Norouzi & Fleet, ICML 2011) — thesis eq. 2.18–2.20;
//  - binary reconstructive embedding (Kulis & Darrell, NIPS 2009) — thesis eq. 2.21;
//  - iterative quantisation (Gong & Lazebnik, CVPR 2011) — one more learned baseline.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/enum_strings.h"

namespace sope {

namespace internal {
class HashFunction;  // one class per method (recogniser/hash_function.h)
}  // namespace internal

// A set of equal-length bit strings packed into 64-bit words, one code after the other
// (row-major, contiguous). Bit b of code i is bit (b mod 64) of words[i·words_per_code +
// b / 64]; the padding bits above `bits` in the last word of each code are always zero,
// so the Hamming distance is popcount(a XOR b) summed over the words.
struct BinaryCodes {
  // Longest code a search supports (its distance histogram has kMaxBits + 1 buckets).
  static constexpr int kMaxBits = 4096;

  int bits = 0;            // code length, bits
  int words_per_code = 0;  // ⌈bits / 64⌉
  std::vector<uint64_t> words;

  BinaryCodes() = default;
  // `num_codes` all-zero codes of `bits` bits; throws sope::Error unless
  // 1 ≤ bits ≤ kMaxBits and num_codes ≥ 0.
  BinaryCodes(int bits, int64_t num_codes);

  static int WordsPerCode(int bits) { return (bits + 63) / 64; }
  int64_t size() const {
    return words_per_code == 0 ? 0 : static_cast<int64_t>(words.size()) / words_per_code;
  }
  bool empty() const { return size() == 0; }
  const uint64_t* code(int64_t index) const { return words.data() + index * words_per_code; }
  uint64_t* code(int64_t index) { return words.data() + index * words_per_code; }
  bool GetBit(int64_t index, int bit) const { return (code(index)[bit >> 6] >> (bit & 63)) & 1u; }
  void SetBit(int64_t index, int bit, bool value) {
    const uint64_t mask = uint64_t{1} << (bit & 63);
    uint64_t& word = code(index)[bit >> 6];
    word = value ? (word | mask) : (word & ~mask);
  }
  // Throws sope::Error naming the problem unless the layout is consistent (bits in
  // [1, kMaxBits], words_per_code = ⌈bits/64⌉, words.size() a multiple of it) and every
  // padding bit is zero.
  void Check() const;
};

// Hamming distance, bits, between two codes of `words_per_code` words.
int HammingDistance(const uint64_t* code_a, const uint64_t* code_b, int words_per_code);

enum class HashMethod {
  kLsh,                   // "lsh"
  kSpectral,              // "sh"
  kMinimalLoss,           // "mlh"
  kBinaryReconstructive,  // "bre"
  kItq,                   // "itq"
};
template <>
struct EnumTable<HashMethod> {
  static constexpr const char* kWhat = "hash method";
  static constexpr EnumName<HashMethod> kNames[] = {{HashMethod::kLsh, "lsh"},
                                                   {HashMethod::kSpectral, "sh"},
                                                   {HashMethod::kMinimalLoss, "mlh"},
                                                   {HashMethod::kBinaryReconstructive, "bre"},
                                                   {HashMethod::kItq, "itq"}};
};
std::string ToString(HashMethod method);
// Accepts the short names above; throws sope::Error naming the text otherwise.
HashMethod HashMethodFromString(const std::string& text);

// Kernel of BRE's hash functions h(x) = thr(Σ_q W_q κ(anchor_q, x)).
enum class BreKernel {
  kLinear,    // "linear": κ(a, x) = aᵀx on unit-normalised, mean-centred features
  kGaussian,  // "gaussian": κ(a, x) = exp(−‖a − x‖² / (2σ²))
};
template <>
struct EnumTable<BreKernel> {
  static constexpr const char* kWhat = "BRE kernel";
  static constexpr EnumName<BreKernel> kNames[] = {{BreKernel::kLinear, "linear"},
                                                  {BreKernel::kGaussian, "gaussian"}};
};
std::string ToString(BreKernel kernel);
BreKernel BreKernelFromString(const std::string& text);

// Locality-sensitive hashing: bit k = [w_kᵀ(x − μ) > t_k], w_k ~ N(0, I).
struct LshOptions {
  // Half-width of the uniform distribution of the random thresholds t_k, in units of the
  // standard deviation of w_kᵀ(x − μ) on the training data. 0 gives sign random
  // projections (Charikar's SimHash, the baseline of Norouzi & Fleet that the thesis
  // used); > 0 gives Andoni–Indyk style random thresholds at the cost of less balanced
  // bits.
  double threshold_spread = 0.0;
  void Check() const;
};

// Spectral hashing has no free parameters beyond the code length: the eigenvalue
// 1 − exp(−ε²/2 · |kπ/(b − a)|²) (eq. 4.13) is monotonic in the mode frequency for every
// ε, so the choice of modes does not depend on the affinity width ε.
struct SpectralOptions {
  void Check() const {}
};

// Minimal-loss hashing, Norouzi & Fleet 2011: b(x) = thr(W x̃), x̃ = [(x − μ)/s; 1] (s = mean
// training norm; the constant 1 gives each bit a learned offset as in the authors'
// code), W learned by stochastic descent on the convex-concave upper bound of the
// empirical hinge-like loss (eq. 2.20) with loss-augmented inference per pair.
struct MlhOptions {
  // ρ, the Hamming margin, as a fraction of the code length: similar pairs should differ
  // in < ρ bits, dissimilar ones in > ρ. ρ = max(1, round(fraction · bits)); 0.15 is the
  // search radius the thesis used for MLH codes.
  double margin_fraction = 0.15;
  // λ, ratio of the penalty slopes for dissimilar vs similar pairs (eq. 2.20). λ > 1
  // keeps bits informative: with λ ≤ 1 the cheapest way to keep neighbours within ρ is
  // to switch bits off (constant), and the codes collapse (measured in hashing_test.cc).
  double lambda = 2.0;
  // Step size η of the perceptron-like updates W ← W + η[ψ(x, b(x)) − ψ(x, ĝ)], per pair
  // (updates are averaged over a mini-batch); features are scaled to unit mean norm.
  double learning_rate = 0.003;
  double momentum = 0.9;
  // L2 shrinkage of the hyperplane directions per step (relative to the learning rate).
  double weight_decay = 1e-4;
  // Mini-batch steps.
  int iterations = 1500;
  // Training pairs per mini-batch, half similar (from the k nearest neighbours), half
  // random (labelled by the neighbour radius of their first point).
  int pairs_per_batch = 100;
  // Rows drawn from the training features for pair generation (subsampled at random).
  int training_points = 5000;
  // Euclidean nearest neighbours (within those rows) that count as similar.
  int neighbours = 30;
  void Check() const;
};

// Binary reconstructive embedding, Kulis & Darrell 2009: kernel hash functions over
// anchor points, h_p(x) = thr(Σ_q W_pq (κ(a_q, x̂) − κ̄_q)), x̂ = (x − μ)/‖x − μ‖ and κ̄
// the training mean of each kernel value; W minimises Σ (m_ij/q − d_ij)² (eq. 2.21), d_ij
// = ½‖x̂_i − x̂_j‖² normalised to [0, 1] by the largest training pair, by exact coordinate
// descent (each weight set to the minimiser of the piecewise-constant loss along it).
struct BreOptions {
  BreKernel kernel = BreKernel::kGaussian;
  // Gaussian kernel width σ as a multiple of the RMS distance between training points
  // and anchors (unit-normalised features).
  double bandwidth_scale = 0.5;
  // Anchor points a_q, drawn from the training rows.
  int anchors = 128;
  // Rows drawn from the training features (the loss has O(rows · pairs_per_point) terms).
  int training_points = 1000;
  // Per training point: its nearest neighbours and as many random partners form the pairs.
  int neighbours = 16;
  // Coordinate-descent updates per bit (each picks a random anchor weight of that bit).
  int updates_per_bit = 50;
  void Check() const;
};

// Iterative quantisation, Gong & Lazebnik 2011: PCA to `bits` dimensions, then the
// rotation R minimising ‖B − VR‖²_F by alternating B = sgn(VR) and orthogonal Procrustes
// (SVD). When bits > feature dimension the PCA embedding is zero-padded to `bits`
// dimensions and R is a bits × bits rotation of it (every bit is still a hyperplane
// through the mean; necessarily correlated).
struct ItqOptions {
  int iterations = 50;
  void Check() const;
};

struct HashOptions {
  // ITQ: on the clustered test data (hashing_test.cc) it recalls 97–99 % of the true
  // neighbours within the 15 % radius while flagging ≈ 5 % of the database (MLH: 94–99 %
  // flagging 5–7 %, with some bits collapsing; LSH: 14–23 %), ranks them better than LSH,
  // and trains in milliseconds. Of the thesis's methods MLH is the closest alternative
  // for radius flagging, SH and BRE for the full Hamming ranking.
  HashMethod method = HashMethod::kItq;
  // Code length, bits, in [kMinBits, kMaxBits]; codes are stored in ⌈bits/64⌉ words.
  int bits = 64;
  // Seed of every random choice (projections, subsamples, pairs, initialisations);
  // training is deterministic for a seed.
  uint64_t seed = 42;
  // Rows used for the mean, the PCA and the ITQ rotation (a random subset when the
  // training set is larger).
  int max_training_samples = 20000;

  LshOptions lsh;
  SpectralOptions spectral;
  MlhOptions mlh;
  BreOptions bre;
  ItqOptions itq;

  static constexpr int kMinBits = 8;
  static constexpr int kMaxBits = 256;

  // Throws sope::Error naming the first invalid value; the options of every method are
  // checked, not only those of `method`.
  void Check() const;
};

// What training did (Ceres-style summary). Losses are means over the training pairs (MLH:
// eq. 2.20 on a fixed monitor set; BRE: eq. 2.21) or the ITQ quantisation loss
// ‖B − VR‖²_F / rows; NaN for LSH and SH, which have none.
struct HashTrainingSummary {
  HashMethod method = HashMethod::kLsh;
  int bits = 0;
  int input_dims = 0;
  int training_rows = 0;       // rows the method learned from (after subsampling)
  int64_t training_pairs = 0;  // MLH: pairs visited; BRE: pairs in the loss
  int iterations = 0;
  double initial_loss = 0.0;
  double final_loss = 0.0;
  double seconds = 0.0;
  std::string BriefReport() const;
};

// A trained hash function: features (rows) → packed binary codes. A value type; cheap to
// copy relative to training. Thread-safe for concurrent Encode calls.
class Hasher {
 public:
  // An untrained hasher; Encode and Serialize throw.
  Hasher() = default;

  // Learns a hash function of options.bits bits from `features` (rows = samples, columns =
  // feature dimensions). Throws sope::Error on invalid options, fewer than 2 rows, no
  // columns or non-finite values. Learned methods need a few times more rows than bits to
  // be meaningful; MLH and BRE subsample rows and pairs so training stays in seconds.
  static Hasher Train(const Eigen::MatrixXf& features, const HashOptions& options,
                      HashTrainingSummary* summary = nullptr);

  // Codes of each row of `features` (columns must equal input_dims()), computed in
  // blocks of rows so memory stays O(block × (dims + bits)) for any number of rows.
  BinaryCodes Encode(const Eigen::MatrixXf& features) const;

  // Versioned little-endian byte form (magic "SOPEHASH", format version, method, sizes,
  // float32 parameters) for the database file.
  std::vector<uint8_t> Serialize() const;
  // Inverse of Serialize. Throws sope::Error on a wrong magic, an unknown version, a
  // truncated buffer (naming the field), inconsistent sizes or trailing bytes.
  static Hasher Deserialize(const uint8_t* data, size_t size);
  static Hasher Deserialize(const std::vector<uint8_t>& buffer) {
    return Deserialize(buffer.data(), buffer.size());
  }

  bool trained() const { return bits_ > 0; }
  HashMethod method() const { return method_; }
  int bits() const { return bits_; }
  int input_dims() const { return static_cast<int>(mean_.size()); }

 private:
  // Real-valued activations, rows × bits; bit = activation > 0.
  Eigen::MatrixXf Activations(const Eigen::MatrixXf& features) const;

  HashMethod method_ = HashMethod::kLsh;
  int bits_ = 0;
  // Training mean μ, input_dims.
  Eigen::VectorXf mean_;
  // The method's function of x − μ (immutable once trained, so copies share it).
  std::shared_ptr<const internal::HashFunction> function_;
};

namespace internal {

// MLH's loss-augmented inference for one pair (exposed for tests). `gain[b]` = best
// disagreeing minus best agreeing score of bit b; returns the Hamming distance m
// maximising (sum of the m largest gains) + ℓ(m, s) (eq. 2.20, ρ = `rho`, λ = `lambda`)
// and leaves the m bits with the largest gains in (*order)[0, m). `order` must have
// gain.size() entries.
int LossAugmentedDistance(const std::vector<float>& gain, bool similar, int rho, double lambda,
                          std::vector<int>* order);

}  // namespace internal
}  // namespace sope
