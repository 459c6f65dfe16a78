// The hasher interface behind Hasher (recogniser/hashing.h): one class per method, each in
// its own file (hash_lsh.cc, hash_spectral.cc, hash_mlh.cc, hash_bre.cc, hash_itq.cc),
// trained from a TrainingContext and stored as HashParameters — the serialised layout of
// format version 1, which holds every method's fields (unused ones empty) so databases
// written before this split read unchanged. Internal to the recogniser library.
//
// Include it first in a hasher's file: the diagnostic pragmas below must precede every
// Eigen header of the translation unit to cover Eigen's kernels.
#pragma once

// GCC 12 reports Eigen's AVX-512 kernels (self-initialised "undefined" registers in the
// intrinsics headers) as maybe-uninitialised under -march=native; a known false positive.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif

#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "core/units.h"
#include "recogniser/hashing.h"

namespace sope {
namespace internal {

// xoshiro256** (Blackman & Vigna) seeded by splitmix64; normals by Box–Muller. Written out
// so that training is reproducible across standard libraries.
class Random {
 public:
  explicit Random(uint64_t seed) {
    for (uint64_t& s : state_) {
      seed += 0x9e3779b97f4a7c15ull;
      uint64_t z = seed;
      z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
      z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
      s = z ^ (z >> 31);
    }
  }
  uint64_t Next() {
    const uint64_t result = Rotl(state_[1] * 5, 7) * 9;
    const uint64_t t = state_[1] << 17;
    state_[2] ^= state_[0];
    state_[3] ^= state_[1];
    state_[1] ^= state_[2];
    state_[0] ^= state_[3];
    state_[2] ^= t;
    state_[3] = Rotl(state_[3], 45);
    return result;
  }
  // Uniform in [0, 1).
  double Uniform() { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }
  // Uniform integer in [0, n), n ≥ 1.
  int64_t UniformInt(int64_t n) { return static_cast<int64_t>(Uniform() * n) % n; }
  double Normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    double u = Uniform();
    while (u <= 0.0) u = Uniform();
    const double v = Uniform();
    const double radius = std::sqrt(-2.0 * std::log(u));
    spare_ = radius * std::sin(2.0 * kPi * v);
    has_spare_ = true;
    return radius * std::cos(2.0 * kPi * v);
  }

 private:
  static uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  uint64_t state_[4];
  bool has_spare_ = false;
  double spare_ = 0.0;
};

// `count` distinct rows of [0, n) in ascending order (all rows when count ≥ n).
std::vector<int> SampleRows(int64_t n, int64_t count, Random* rng);
// The given rows of `matrix`.
Eigen::MatrixXf GatherRows(const Eigen::MatrixXf& matrix, const std::vector<int>& rows);
// rows × cols standard normal entries.
Eigen::MatrixXf RandomGaussian(int rows, int cols, Random* rng);
// The `count` leading principal directions of mean-centred rows (dims × count).
Eigen::MatrixXf PrincipalDirections(const Eigen::MatrixXf& centred, int count);
// The k nearest other rows of each row of `points` (squared Euclidean distance), in
// ascending distance: indices and squared distances, row-major rows × k.
struct Neighbours {
  int k = 0;
  std::vector<int> index;
  std::vector<float> squared_distance;
};
Neighbours NearestNeighbours(const Eigen::MatrixXf& points, int k);
// Packs [activation > 0] into codes.
BinaryCodes PackSigns(const Eigen::MatrixXf& activations);
// Rows of `centred` scaled to unit length (zero rows stay zero).
Eigen::MatrixXf UnitRows(const Eigen::MatrixXf& centred);
// Kernel values κ(anchor_q, x_i), rows × anchors.
Eigen::MatrixXf KernelMatrix(const Eigen::MatrixXf& unit_rows, const Eigen::MatrixXf& anchors,
                             BreKernel kernel, float bandwidth);
// MLH's hinge-like loss (eq. 2.20) for Hamming distance m.
inline double MlhLoss(int m, bool similar, int rho, double lambda) {
  return similar ? std::max(m - rho + 1, 0) : lambda * std::max(rho - m + 1, 0);
}

// Every method's parameters in the serialised order (hashing.cc writes and reads them).
struct HashParameters {
  // LSH, MLH, ITQ: bit k = [projection.row(k)·(x − μ) + offset(k) > 0] (bits × dims).
  // SH: the PCA directions (npca × dims), no offset. BRE: W (bits × anchors).
  Eigen::MatrixXf projection;
  Eigen::VectorXf offset;
  // SH: per bit, the PCA direction (stored as a float), ω = kπ/(b − a) and the
  // direction's range start a.
  Eigen::VectorXf sh_direction;
  Eigen::VectorXf sh_omega;
  Eigen::VectorXf sh_range_min;
  // BRE: kernel, width σ, anchors (anchors × dims) and their mean kernel value.
  BreKernel bre_kernel = BreKernel::kGaussian;
  float bre_bandwidth = 1.0f;
  Eigen::MatrixXf bre_anchors;
  Eigen::VectorXf bre_kernel_mean;
};

// What every trainer gets.
struct TrainingContext {
  const Eigen::MatrixXf& features;
  const HashOptions& options;
  Random* rng;
  // Subsample of ≤ max_training_samples rows, mean, and those rows centred.
  Eigen::MatrixXf sample_centred;
  Eigen::VectorXf mean;
  HashTrainingSummary* summary;
};

// One trained hash function of mean-centred features.
class HashFunction {
 public:
  virtual ~HashFunction() = default;
  // Real-valued activations of centred rows, rows × bits; bit = activation > 0.
  virtual Eigen::MatrixXf Activations(const Eigen::MatrixXf& centred) const = 0;
  // The parameters to serialise.
  virtual HashParameters Parameters() const = 0;
};

// LSH, MLH and ITQ encode alike: thresholded linear projections.
class LinearHashFunction : public HashFunction {
 public:
  Eigen::MatrixXf Activations(const Eigen::MatrixXf& centred) const override {
    Eigen::MatrixXf activation = centred * projection_.transpose();
    activation.rowwise() += offset_.transpose();
    return activation;
  }
  HashParameters Parameters() const override {
    HashParameters p;
    p.projection = projection_;
    p.offset = offset_;
    return p;
  }
  // Throws sope::Error unless projection is bits × dims and offset has bits entries.
  void Load(const HashParameters& p, HashMethod method, int bits, Eigen::Index dims);

  Eigen::MatrixXf projection_;
  Eigen::VectorXf offset_;
};

// A linear hasher of type H (a LinearHashFunction) rebuilt from stored parameters.
template <class H>
std::unique_ptr<HashFunction> LoadLinear(const HashParameters& p, HashMethod method, int bits,
                                         Eigen::Index dims) {
  auto hasher = std::make_unique<H>();
  hasher->Load(p, method, bits, dims);
  return hasher;
}

// Per method: train (options.method's options, the context's rng), or rebuild from stored
// parameters (throws sope::Error on inconsistent sizes).
std::unique_ptr<HashFunction> TrainLsh(TrainingContext& context);
std::unique_ptr<HashFunction> LoadLsh(const HashParameters& p, int bits, Eigen::Index dims);
std::unique_ptr<HashFunction> TrainSpectral(TrainingContext& context);
std::unique_ptr<HashFunction> LoadSpectral(const HashParameters& p, int bits, Eigen::Index dims);
std::unique_ptr<HashFunction> TrainMinimalLoss(TrainingContext& context);
std::unique_ptr<HashFunction> LoadMinimalLoss(const HashParameters& p, int bits,
                                              Eigen::Index dims);
std::unique_ptr<HashFunction> TrainBinaryReconstructive(TrainingContext& context);
std::unique_ptr<HashFunction> LoadBinaryReconstructive(const HashParameters& p, int bits,
                                                       Eigen::Index dims);
std::unique_ptr<HashFunction> TrainItq(TrainingContext& context);
std::unique_ptr<HashFunction> LoadItq(const HashParameters& p, int bits, Eigen::Index dims);

}  // namespace internal
}  // namespace sope
