// GCC 12 reports Eigen's AVX-512 kernels (self-initialised "undefined" registers in the
// intrinsics headers) as maybe-uninitialised under -march=native; a known false positive.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif

#include "recogniser/hashing.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <utility>

#include <Eigen/Dense>

#include "core/error.h"

namespace sope {

// ---------------------------------------------------------------------------------------
// BinaryCodes

BinaryCodes::BinaryCodes(int bits_in, int64_t num_codes) {
  SOPE_CHECK(bits_in >= 1 && bits_in <= kMaxBits, "code length must be in [1, {}] bits, got {}",
             kMaxBits, bits_in);
  SOPE_CHECK(num_codes >= 0, "number of codes must be ≥ 0, got {}", num_codes);
  bits = bits_in;
  words_per_code = WordsPerCode(bits_in);
  words.assign(static_cast<size_t>(num_codes) * words_per_code, 0);
}

void BinaryCodes::Check() const {
  SOPE_CHECK(bits >= 1 && bits <= kMaxBits, "code length must be in [1, {}] bits, got {}", kMaxBits,
             bits);
  SOPE_CHECK(words_per_code == WordsPerCode(bits),
             "codes of {} bits need {} words per code, got {}", bits, WordsPerCode(bits),
             words_per_code);
  SOPE_CHECK(words.size() % words_per_code == 0,
             "{} code words are not a multiple of {} words per code", words.size(), words_per_code);
  if (bits % 64 == 0) return;
  const uint64_t padding = ~((uint64_t{1} << (bits % 64)) - 1);
  for (int64_t i = 0; i < size(); ++i) {
    SOPE_CHECK((code(i)[words_per_code - 1] & padding) == 0,
               "code {} has padding bits above bit {} set", i, bits);
  }
}

int HammingDistance(const uint64_t* code_a, const uint64_t* code_b, int words_per_code) {
  int distance = 0;
  for (int w = 0; w < words_per_code; ++w) {
    distance += __builtin_popcountll(code_a[w] ^ code_b[w]);
  }
  return distance;
}

// ---------------------------------------------------------------------------------------
// Enums and options

std::string ToString(HashMethod method) {
  switch (method) {
    case HashMethod::kLsh:
      return "lsh";
    case HashMethod::kSpectral:
      return "sh";
    case HashMethod::kMinimalLoss:
      return "mlh";
    case HashMethod::kBinaryReconstructive:
      return "bre";
    case HashMethod::kItq:
      return "itq";
  }
  return "unknown";
}

HashMethod HashMethodFromString(const std::string& text) {
  for (HashMethod method : {HashMethod::kLsh, HashMethod::kSpectral, HashMethod::kMinimalLoss,
                            HashMethod::kBinaryReconstructive, HashMethod::kItq}) {
    if (text == ToString(method)) return method;
  }
  SOPE_THROW("unknown hash method '{}' (expected lsh, sh, mlh, bre or itq)", text);
}

std::string ToString(BreKernel kernel) {
  return kernel == BreKernel::kLinear ? "linear" : "gaussian";
}

BreKernel BreKernelFromString(const std::string& text) {
  if (text == "linear") return BreKernel::kLinear;
  if (text == "gaussian") return BreKernel::kGaussian;
  SOPE_THROW("unknown BRE kernel '{}' (expected linear or gaussian)", text);
}

void LshOptions::Check() const {
  SOPE_CHECK(std::isfinite(threshold_spread) && threshold_spread >= 0.0,
             "lsh.threshold_spread must be finite and ≥ 0, got {}", threshold_spread);
}

void MlhOptions::Check() const {
  SOPE_CHECK(margin_fraction > 0.0 && margin_fraction < 1.0,
             "mlh.margin_fraction must be in (0, 1), got {}", margin_fraction);
  SOPE_CHECK(std::isfinite(lambda) && lambda > 0.0, "mlh.lambda must be > 0, got {}", lambda);
  SOPE_CHECK(std::isfinite(learning_rate) && learning_rate > 0.0,
             "mlh.learning_rate must be > 0, got {}", learning_rate);
  SOPE_CHECK(momentum >= 0.0 && momentum < 1.0, "mlh.momentum must be in [0, 1), got {}", momentum);
  SOPE_CHECK(std::isfinite(weight_decay) && weight_decay >= 0.0,
             "mlh.weight_decay must be ≥ 0, got {}", weight_decay);
  SOPE_CHECK(iterations >= 0, "mlh.iterations must be ≥ 0, got {}", iterations);
  SOPE_CHECK(pairs_per_batch >= 2, "mlh.pairs_per_batch must be ≥ 2, got {}", pairs_per_batch);
  SOPE_CHECK(training_points >= 2, "mlh.training_points must be ≥ 2, got {}", training_points);
  SOPE_CHECK(neighbours >= 1, "mlh.neighbours must be ≥ 1, got {}", neighbours);
}

void BreOptions::Check() const {
  SOPE_CHECK(std::isfinite(bandwidth_scale) && bandwidth_scale > 0.0,
             "bre.bandwidth_scale must be > 0, got {}", bandwidth_scale);
  SOPE_CHECK(anchors >= 1, "bre.anchors must be ≥ 1, got {}", anchors);
  SOPE_CHECK(training_points >= 2, "bre.training_points must be ≥ 2, got {}", training_points);
  SOPE_CHECK(neighbours >= 1, "bre.neighbours must be ≥ 1, got {}", neighbours);
  SOPE_CHECK(updates_per_bit >= 0, "bre.updates_per_bit must be ≥ 0, got {}", updates_per_bit);
}

void ItqOptions::Check() const {
  SOPE_CHECK(iterations >= 0, "itq.iterations must be ≥ 0, got {}", iterations);
}

void HashOptions::Check() const {
  SOPE_CHECK(bits >= kMinBits && bits <= kMaxBits, "bits must be in [{}, {}], got {}", kMinBits,
             kMaxBits, bits);
  SOPE_CHECK(max_training_samples >= 2, "max_training_samples must be ≥ 2, got {}",
             max_training_samples);
  lsh.Check();
  spectral.Check();
  mlh.Check();
  bre.Check();
  itq.Check();
}

std::string HashTrainingSummary::BriefReport() const {
  return fmt::format(
      "{} {} bits on {} rows × {} dims: {} pairs, {} iterations, loss {:.4g} -> {:.4g}, "
      "{:.3f} s",
      ToString(method), bits, training_rows, input_dims, training_pairs, iterations, initial_loss,
      final_loss, seconds);
}

// ---------------------------------------------------------------------------------------
// Helpers

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
    spare_ = radius * std::sin(2.0 * M_PI * v);
    has_spare_ = true;
    return radius * std::cos(2.0 * M_PI * v);
  }

 private:
  static uint64_t Rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  uint64_t state_[4];
  bool has_spare_ = false;
  double spare_ = 0.0;
};

// `count` distinct rows of [0, n) in ascending order (all rows when count ≥ n).
std::vector<int> SampleRows(int64_t n, int64_t count, Random* rng) {
  std::vector<int> rows(n);
  std::iota(rows.begin(), rows.end(), 0);
  if (count >= n) return rows;
  for (int64_t i = 0; i < count; ++i) {
    std::swap(rows[i], rows[i + rng->UniformInt(n - i)]);
  }
  rows.resize(count);
  std::sort(rows.begin(), rows.end());
  return rows;
}

// Column by column: contiguous writes, ascending reads (rows are sorted).
Eigen::MatrixXf GatherRows(const Eigen::MatrixXf& matrix, const std::vector<int>& rows) {
  Eigen::MatrixXf out(rows.size(), matrix.cols());
  for (Eigen::Index c = 0; c < matrix.cols(); ++c) {
    for (size_t r = 0; r < rows.size(); ++r) out(r, c) = matrix(rows[r], c);
  }
  return out;
}

Eigen::MatrixXf RandomGaussian(int rows, int cols, Random* rng) {
  Eigen::MatrixXf out(rows, cols);
  for (int c = 0; c < cols; ++c) {
    for (int r = 0; r < rows; ++r) out(r, c) = static_cast<float>(rng->Normal());
  }
  return out;
}

// Principal directions of mean-centred rows: the `count` eigenvectors of the covariance
// with the largest eigenvalues, as columns (dims × count), in descending order.
Eigen::MatrixXf PrincipalDirections(const Eigen::MatrixXf& centred, int count) {
  const Eigen::MatrixXd centred_d = centred.cast<double>();
  Eigen::MatrixXd covariance = centred_d.transpose() * centred_d;
  covariance /= std::max<double>(1.0, centred.rows() - 1);
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(covariance);
  // Eigen sorts eigenvalues ascending: take the last `count` columns, reversed.
  const Eigen::MatrixXd& vectors = solver.eigenvectors();
  Eigen::MatrixXf directions(centred.cols(), count);
  for (int i = 0; i < count; ++i) {
    directions.col(i) = vectors.col(vectors.cols() - 1 - i).cast<float>();
  }
  return directions;
}

// The k nearest other rows of each row of `points` (squared Euclidean distance), in
// ascending distance: indices and squared distances, row-major rows × k.
struct Neighbours {
  int k = 0;
  std::vector<int> index;
  std::vector<float> squared_distance;
};

Neighbours NearestNeighbours(const Eigen::MatrixXf& points, int k) {
  const int n = static_cast<int>(points.rows());
  Neighbours out;
  out.k = std::min(k, n - 1);
  if (out.k <= 0) return out;
  out.index.resize(static_cast<size_t>(n) * out.k);
  out.squared_distance.resize(out.index.size());
  const Eigen::VectorXf norms = points.rowwise().squaredNorm();
  constexpr int kBlockRows = 256;
  std::vector<std::pair<float, int>> candidates(n - 1);
  for (int b0 = 0; b0 < n; b0 += kBlockRows) {
    const int nb = std::min(kBlockRows, n - b0);
    // Column r holds ⟨x_j, x_{b0+r}⟩ for every j: contiguous per query row.
    const Eigen::MatrixXf dots = points * points.middleRows(b0, nb).transpose();
    for (int r = 0; r < nb; ++r) {
      const int i = b0 + r;
      int c = 0;
      for (int j = 0; j < n; ++j) {
        if (j != i) candidates[c++] = {std::max(0.0f, norms(j) + norms(i) - 2.0f * dots(j, r)), j};
      }
      // Pairs compare by (distance, index): ties go to the lower index.
      std::nth_element(candidates.begin(), candidates.begin() + (out.k - 1), candidates.end());
      std::sort(candidates.begin(), candidates.begin() + out.k);
      for (int j = 0; j < out.k; ++j) {
        out.index[static_cast<size_t>(i) * out.k + j] = candidates[j].second;
        out.squared_distance[static_cast<size_t>(i) * out.k + j] = candidates[j].first;
      }
    }
  }
  return out;
}

// Packs [activation > 0] into codes.
BinaryCodes PackSigns(const Eigen::MatrixXf& activations) {
  BinaryCodes codes(static_cast<int>(activations.cols()), activations.rows());
  for (int b = 0; b < activations.cols(); ++b) {
    const uint64_t mask = uint64_t{1} << (b & 63);
    const int word = b >> 6;
    for (int64_t i = 0; i < activations.rows(); ++i) {
      if (activations(i, b) > 0.0f) codes.code(i)[word] |= mask;
    }
  }
  return codes;
}

// Rows of `centred` scaled to unit length (zero rows stay zero). Column-wise, so a
// power-of-two row count cannot alias every element of a row to one cache set.
Eigen::MatrixXf UnitRows(const Eigen::MatrixXf& centred) {
  const Eigen::VectorXf norms = centred.rowwise().norm();
  const Eigen::VectorXf inverse =
      (norms.array() > 0.0f).select(norms.array().inverse(), 0.0f).matrix();
  return inverse.asDiagonal() * centred;
}

// Kernel values κ(anchor_q, x_i), rows × anchors.
Eigen::MatrixXf KernelMatrix(const Eigen::MatrixXf& unit_rows, const Eigen::MatrixXf& anchors,
                             BreKernel kernel, float bandwidth) {
  Eigen::MatrixXf values = unit_rows * anchors.transpose();
  if (kernel == BreKernel::kLinear) return values;
  const Eigen::VectorXf row_norms = unit_rows.rowwise().squaredNorm();
  const Eigen::VectorXf anchor_norms = anchors.rowwise().squaredNorm();
  const float inv_two_sigma2 = 1.0f / (2.0f * bandwidth * bandwidth);
  for (int q = 0; q < values.cols(); ++q) {
    for (int64_t i = 0; i < values.rows(); ++i) {
      const float d2 = std::max(0.0f, row_norms(i) + anchor_norms(q) - 2.0f * values(i, q));
      values(i, q) = std::exp(-d2 * inv_two_sigma2);
    }
  }
  return values;
}

// MLH's hinge-like loss (eq. 2.20) for Hamming distance m.
inline double MlhLoss(int m, bool similar, int rho, double lambda) {
  return similar ? std::max(m - rho + 1, 0) : lambda * std::max(rho - m + 1, 0);
}

// Distance m of MLH's loss-augmented inference: argmax over m of (sum of the m largest
// gains) + ℓ(m, s). The sum of the m largest gains is concave in m and ℓ is a hinge with
// one kink (at ρ − 1 for similar pairs, at ρ + 1 for dissimilar ones), so the objective
// is concave on each side of the kink and its maximum is one of two distances, each
// found by counting gains above a slope; O(q) per pair instead of a sort. On return
// (*order)[0, m) holds the m bits with the largest gains.
int LossAugmentedDistance(const std::vector<float>& gain, bool similar, int rho, double lambda,
                          std::vector<int>* order) {
  const int q = static_cast<int>(gain.size());
  auto count_above = [&](double slope) {
    int count = 0;
    for (float g : gain) count += g > slope;
    return count;
  };
  int kink, left, right;
  if (similar) {  // ℓ(m) = max(m − ρ + 1, 0): increments 0 up to the kink, then +1
    kink = std::min(rho - 1, q);
    left = std::min(count_above(0.0), kink);
    right = std::max(kink, count_above(-1.0));
  } else {  // ℓ(m) = λ max(ρ − m + 1, 0): increments −λ up to the kink, then 0
    kink = std::min(rho + 1, q);
    left = std::min(count_above(lambda), kink);
    right = std::max(kink, count_above(0.0));
  }
  std::iota(order->begin(), order->end(), 0);
  auto by_gain = [&](int x, int y) { return gain[x] > gain[y] || (gain[x] == gain[y] && x < y); };
  auto top_sum = [&](int count) {
    if (count == 0) return 0.0;
    if (count < q) std::nth_element(order->begin(), order->begin() + count, order->end(), by_gain);
    double sum = 0.0;
    for (int r = 0; r < count; ++r) sum += gain[(*order)[r]];
    return sum;
  };
  const double left_value = top_sum(left) + MlhLoss(left, similar, rho, lambda);
  const double right_value = top_sum(right) + MlhLoss(right, similar, rho, lambda);
  const int best = right_value > left_value ? right : left;
  if (best != right) top_sum(best);  // leave the partition of the chosen distance in *order
  return best;
}

// Little-endian byte writer / reader for the serialised hasher.
class ByteWriter {
 public:
  void U32(uint32_t value) {
    for (int i = 0; i < 4; ++i) bytes_.push_back(static_cast<uint8_t>(value >> (8 * i)));
  }
  void U64(uint64_t value) {
    for (int i = 0; i < 8; ++i) bytes_.push_back(static_cast<uint8_t>(value >> (8 * i)));
  }
  void F32(float value) {
    uint32_t bits;
    std::memcpy(&bits, &value, 4);
    U32(bits);
  }
  void Raw(const char* data, size_t size) { bytes_.insert(bytes_.end(), data, data + size); }
  // rows, cols (u64) then the entries column by column.
  void Matrix(const Eigen::MatrixXf& matrix) {
    U64(matrix.rows());
    U64(matrix.cols());
    for (Eigen::Index i = 0; i < matrix.size(); ++i) F32(matrix.data()[i]);
  }
  std::vector<uint8_t> Take() { return std::move(bytes_); }

 private:
  std::vector<uint8_t> bytes_;
};

class ByteReader {
 public:
  ByteReader(const uint8_t* data, size_t size) : data_(data), size_(size) {}
  void Need(size_t bytes, const char* field) const {
    SOPE_CHECK(bytes <= size_ - offset_,
               "hasher data truncated: field '{}' needs {} bytes at offset {}, {} left", field,
               bytes, offset_, size_ - offset_);
  }
  uint32_t U32(const char* field) {
    Need(4, field);
    uint32_t value = 0;
    for (int i = 0; i < 4; ++i) value |= uint32_t{data_[offset_ + i]} << (8 * i);
    offset_ += 4;
    return value;
  }
  uint64_t U64(const char* field) {
    Need(8, field);
    uint64_t value = 0;
    for (int i = 0; i < 8; ++i) value |= uint64_t{data_[offset_ + i]} << (8 * i);
    offset_ += 8;
    return value;
  }
  float F32(const char* field) {
    const uint32_t bits = U32(field);
    float value;
    std::memcpy(&value, &bits, 4);
    return value;
  }
  std::string Raw(size_t size, const char* field) {
    Need(size, field);
    std::string out(reinterpret_cast<const char*>(data_ + offset_), size);
    offset_ += size;
    return out;
  }
  Eigen::MatrixXf Matrix(const char* field) {
    const uint64_t rows = U64(field);
    const uint64_t cols = U64(field);
    SOPE_CHECK(rows <= (1u << 24) && cols <= (1u << 24), "hasher field '{}' has absurd size {}×{}",
               field, rows, cols);
    Need(rows * cols * 4, field);
    Eigen::MatrixXf matrix(rows, cols);
    for (Eigen::Index i = 0; i < matrix.size(); ++i) matrix.data()[i] = F32(field);
    return matrix;
  }
  size_t remaining() const { return size_ - offset_; }

 private:
  const uint8_t* data_;
  size_t size_;
  size_t offset_ = 0;
};

constexpr char kMagic[8] = {'S', 'O', 'P', 'E', 'H', 'A', 'S', 'H'};
constexpr uint32_t kFormatVersion = 1;

// ---------------------------------------------------------------------------------------
// Trainers (a friend of Hasher, so they fill its parameters directly)

struct HasherAccess {
  struct Context {
    const Eigen::MatrixXf& features;
    const HashOptions& options;
    Random* rng;
    // Subsample of ≤ max_training_samples rows, mean, and those rows centred.
    Eigen::MatrixXf sample_centred;
    Eigen::VectorXf mean;
    HashTrainingSummary* summary;
  };

  static Hasher Start(const Context& context) {
    Hasher hasher;
    hasher.method_ = context.options.method;
    hasher.bits_ = context.options.bits;
    hasher.mean_ = context.mean;
    return hasher;
  }

  // Charikar 2002 / Andoni & Indyk 2008.
  static Hasher TrainLsh(Context& context) {
    Hasher hasher = Start(context);
    const int bits = context.options.bits;
    const int dims = static_cast<int>(context.features.cols());
    hasher.projection_ = RandomGaussian(bits, dims, context.rng);
    hasher.offset_ = Eigen::VectorXf::Zero(bits);
    const double spread = context.options.lsh.threshold_spread;
    if (spread > 0.0) {
      const Eigen::MatrixXf projected = context.sample_centred * hasher.projection_.transpose();
      for (int k = 0; k < bits; ++k) {
        const double sigma =
            std::sqrt(projected.col(k).squaredNorm() / std::max<Eigen::Index>(1, projected.rows()));
        const double threshold = spread * sigma * (2.0 * context.rng->Uniform() - 1.0);
        hasher.offset_(k) = static_cast<float>(-threshold);
      }
    }
    context.summary->training_rows = static_cast<int>(context.sample_centred.rows());
    return hasher;
  }

  // Weiss, Torralba & Fergus 2008 (thesis §4.6.1, eq. 4.12–4.13).
  static Hasher TrainSpectral(Context& context) {
    Hasher hasher = Start(context);
    const int bits = context.options.bits;
    const int dims = static_cast<int>(context.features.cols());
    const int npca = std::min(bits, dims);
    const Eigen::MatrixXf directions = PrincipalDirections(context.sample_centred, npca);
    const Eigen::MatrixXf projected = context.sample_centred * directions;
    // Uniform distribution on [a, b] per direction (Weiss et al. use min − ε, max + ε).
    Eigen::VectorXf range_min(npca), range_length(npca);
    for (int i = 0; i < npca; ++i) {
      const float lo = projected.col(i).minCoeff();
      const float hi = projected.col(i).maxCoeff();
      const float pad = 1e-6f * std::max(hi - lo, 1e-6f);
      range_min(i) = lo - pad;
      range_length(i) = (hi + pad) - (lo - pad);
    }
    const float longest = range_length.maxCoeff();
    // Single-direction modes k = 1..maxMode_i, maxMode_i = ⌈(bits + 1)·R_i / max R⌉; the
    // eigenvalue grows with ω = kπ/R_i for every ε, so the bits smallest eigenvalues are
    // the bits smallest ω (ties: lower direction, then lower k).
    struct Mode {
      float omega;
      int direction;
      int k;
    };
    std::vector<Mode> modes;
    for (int i = 0; i < npca; ++i) {
      const int max_mode = static_cast<int>(std::ceil((bits + 1) * range_length(i) / longest));
      for (int k = 1; k <= std::max(1, max_mode); ++k) {
        modes.push_back({static_cast<float>(k * M_PI / range_length(i)), i, k});
      }
    }
    std::sort(modes.begin(), modes.end(), [](const Mode& a, const Mode& b) {
      if (a.omega != b.omega) return a.omega < b.omega;
      if (a.direction != b.direction) return a.direction < b.direction;
      return a.k < b.k;
    });
    hasher.projection_ = directions.transpose();
    hasher.sh_direction_.resize(bits);
    hasher.sh_omega_.resize(bits);
    for (int b = 0; b < bits; ++b) {
      hasher.sh_direction_[b] = modes[b].direction;
      hasher.sh_omega_(b) = modes[b].omega;
    }
    hasher.sh_range_min_ = range_min;
    context.summary->training_rows = static_cast<int>(context.sample_centred.rows());
    return hasher;
  }

  // Gong & Lazebnik 2011.
  static Hasher TrainItq(Context& context) {
    Hasher hasher = Start(context);
    const int bits = context.options.bits;
    const int dims = static_cast<int>(context.features.cols());
    const int npca = std::min(bits, dims);
    Eigen::MatrixXf directions = Eigen::MatrixXf::Zero(dims, bits);  // zero-padded
    directions.leftCols(npca) = PrincipalDirections(context.sample_centred, npca);
    const Eigen::MatrixXf embedded = context.sample_centred * directions;  // V, rows × bits
    const double rows = static_cast<double>(embedded.rows());
    // Random initial rotation: Q of the QR decomposition of a Gaussian matrix.
    const Eigen::MatrixXd gaussian = RandomGaussian(bits, bits, context.rng).cast<double>();
    Eigen::MatrixXd rotation = Eigen::HouseholderQR<Eigen::MatrixXd>(gaussian).householderQ();
    // ‖B − VR‖²_F / rows with B = sgn(VR): each entry contributes (1 − |z|)².
    auto quantisation_loss = [&](const Eigen::MatrixXf& rotated) {
      return static_cast<double>((1.0f - rotated.array().abs()).square().sum()) / rows;
    };
    const int iterations = context.options.itq.iterations;
    for (int it = 0; it < iterations; ++it) {
      const Eigen::MatrixXf rotated = embedded * rotation.cast<float>();
      if (it == 0) context.summary->initial_loss = quantisation_loss(rotated);
      const Eigen::MatrixXf signs = (rotated.array() > 0.0f)
                                        .select(Eigen::MatrixXf::Ones(rotated.rows(), bits),
                                                -Eigen::MatrixXf::Ones(rotated.rows(), bits));
      // Procrustes: Bᵀ V = U_B Σ U_Aᵀ  →  R = U_A U_Bᵀ.
      const Eigen::MatrixXd cross = (signs.transpose() * embedded).cast<double>();
      Eigen::BDCSVD<Eigen::MatrixXd> svd(cross, Eigen::ComputeFullU | Eigen::ComputeFullV);
      rotation = svd.matrixV() * svd.matrixU().transpose();
    }
    const Eigen::MatrixXf rotated = embedded * rotation.cast<float>();
    context.summary->final_loss = quantisation_loss(rotated);
    if (iterations == 0) context.summary->initial_loss = context.summary->final_loss;
    context.summary->iterations = iterations;
    context.summary->training_rows = static_cast<int>(embedded.rows());
    hasher.projection_ = (directions * rotation.cast<float>()).transpose();
    hasher.offset_ = Eigen::VectorXf::Zero(bits);
    return hasher;
  }

  // Norouzi & Fleet 2011 (thesis eq. 2.18–2.20).
  static Hasher TrainMinimalLoss(Context& context) {
    Hasher hasher = Start(context);
    const MlhOptions& mlh = context.options.mlh;
    const int bits = context.options.bits;
    const int dims = static_cast<int>(context.features.cols());
    Random& rng = *context.rng;
    const std::vector<int> rows = SampleRows(context.features.rows(), mlh.training_points, &rng);
    const int m = static_cast<int>(rows.size());
    Eigen::MatrixXf centred = GatherRows(context.features, rows);
    centred.rowwise() -= context.mean.transpose();
    const double scale = std::max(1e-12, static_cast<double>(centred.rowwise().norm().mean()));
    // x̃ = [(x − μ)/s; 1], one column per training point.
    Eigen::MatrixXf augmented(dims + 1, m);
    augmented.topRows(dims) = centred.transpose() / static_cast<float>(scale);
    augmented.row(dims).setOnes();
    const Neighbours neighbours = NearestNeighbours(centred, mlh.neighbours);
    const int k = neighbours.k;
    auto squared_distance = [&](int i, int j) {
      return (augmented.col(i) - augmented.col(j)).squaredNorm() * scale * scale;
    };
    auto radius2 = [&](int i) {
      return neighbours.squared_distance[static_cast<size_t>(i) * k + k - 1];
    };
    struct Pair {
      int i, j;
      bool similar;
    };
    // Half similar (a k-NN), half random partners labelled by the k-NN radius of i.
    auto sample_pair = [&](bool similar_half) {
      const int i = static_cast<int>(rng.UniformInt(m));
      if (similar_half) {
        return Pair{i, neighbours.index[static_cast<size_t>(i) * k + rng.UniformInt(k)], true};
      }
      int j = static_cast<int>(rng.UniformInt(m - 1));
      if (j >= i) ++j;
      return Pair{i, j, squared_distance(i, j) <= radius2(i)};
    };

    const int rho = std::max(1, static_cast<int>(std::lround(mlh.margin_fraction * bits)));
    const double lambda = mlh.lambda;
    // W over x̃: Gaussian directions (an LSH start), zero offsets.
    Eigen::MatrixXf weights(bits, dims + 1);
    weights.leftCols(dims) = RandomGaussian(bits, dims, &rng);
    weights.col(dims).setZero();
    Eigen::MatrixXf velocity = Eigen::MatrixXf::Zero(bits, dims + 1);

    // Loss on a fixed monitor set (summary only).
    std::vector<Pair> monitor;
    for (int p = 0; p < 2000; ++p) monitor.push_back(sample_pair(p % 2 == 0));
    auto monitor_loss = [&]() {
      double total = 0.0;
      Eigen::MatrixXf xi(dims + 1, monitor.size()), xj(dims + 1, monitor.size());
      for (size_t p = 0; p < monitor.size(); ++p) {
        xi.col(p) = augmented.col(monitor[p].i);
        xj.col(p) = augmented.col(monitor[p].j);
      }
      const Eigen::MatrixXf ai = weights * xi, aj = weights * xj;
      for (size_t p = 0; p < monitor.size(); ++p) {
        int distance = 0;
        for (int b = 0; b < bits; ++b) distance += (ai(b, p) > 0.0f) != (aj(b, p) > 0.0f);
        total += MlhLoss(distance, monitor[p].similar, rho, lambda);
      }
      return total / monitor.size();
    };
    context.summary->initial_loss = monitor_loss();

    const int batch = mlh.pairs_per_batch;
    Eigen::MatrixXf xi(dims + 1, batch), xj(dims + 1, batch);
    Eigen::MatrixXf delta_i(bits, batch), delta_j(bits, batch);
    std::vector<Pair> pairs(batch);
    std::vector<int> order(bits);
    std::vector<float> gain(bits);
    for (int it = 0; it < mlh.iterations; ++it) {
      for (int p = 0; p < batch; ++p) {
        pairs[p] = sample_pair(p % 2 == 0);
        xi.col(p) = augmented.col(pairs[p].i);
        xj.col(p) = augmented.col(pairs[p].j);
      }
      const Eigen::MatrixXf ai = weights * xi;  // bits × batch: W x̃_i
      const Eigen::MatrixXf aj = weights * xj;
      for (int p = 0; p < batch; ++p) {
        // Loss-augmented inference: (g, h) = argmax ℓ(‖g − h‖_H, s) + gᵀWx̃_i + hᵀWx̃_j over
        // g, h ∈ {0,1}^q. Per bit, the best agreeing pair scores max(0, a + c), the best
        // disagreeing one max(a, c); for each distance m the best codes make the m bits
        // with the largest gain D − A disagree, so only m is searched.
        const float* a = ai.col(p).data();
        const float* c = aj.col(p).data();
        for (int b = 0; b < bits; ++b) {
          gain[b] = std::max(a[b], c[b]) - std::max(0.0f, a[b] + c[b]);
        }
        const int flips = LossAugmentedDistance(gain, pairs[p].similar, rho, lambda, &order);
        // order[0, flips) are the disagreeing bits.
        float* di = delta_i.col(p).data();
        float* dj = delta_j.col(p).data();
        for (int b = 0; b < bits; ++b) {
          const float g = (a[b] + c[b] > 0.0f) ? 1.0f : 0.0f;  // agree
          di[b] = g - (a[b] > 0.0f ? 1.0f : 0.0f);
          dj[b] = g - (c[b] > 0.0f ? 1.0f : 0.0f);
        }
        for (int r = 0; r < flips; ++r) {
          const int b = order[r];
          const float g = a[b] > c[b] ? 1.0f : 0.0f;  // disagree: (1, 0) or (0, 1)
          di[b] = g - (a[b] > 0.0f ? 1.0f : 0.0f);
          dj[b] = (1.0f - g) - (c[b] > 0.0f ? 1.0f : 0.0f);
        }
      }
      // Gradient of the upper bound: Σ (g − b(x_i)) x̃_iᵀ + (h − b(x_j)) x̃_jᵀ.
      Eigen::MatrixXf gradient = delta_i * xi.transpose() + delta_j * xj.transpose();
      gradient /= static_cast<float>(batch);
      // Weight decay on the directions only, not the offsets (as in the authors' code).
      gradient.leftCols(dims) += static_cast<float>(mlh.weight_decay) * weights.leftCols(dims);
      velocity = static_cast<float>(mlh.momentum) * velocity -
                 static_cast<float>(mlh.learning_rate) * gradient;
      weights += velocity;
    }
    context.summary->final_loss = monitor_loss();
    context.summary->iterations = mlh.iterations;
    context.summary->training_rows = m;
    context.summary->training_pairs = static_cast<int64_t>(mlh.iterations) * batch;
    // bit = [w[:d]ᵀ(x − μ)/s + w[d] > 0].
    hasher.projection_ = weights.leftCols(dims) / static_cast<float>(scale);
    hasher.offset_ = weights.col(dims);
    return hasher;
  }

  // Kulis & Darrell 2009 (thesis eq. 2.21).
  static Hasher TrainBinaryReconstructive(Context& context) {
    Hasher hasher = Start(context);
    const BreOptions& bre = context.options.bre;
    const int bits = context.options.bits;
    Random& rng = *context.rng;
    const std::vector<int> rows = SampleRows(context.features.rows(), bre.training_points, &rng);
    const int m = static_cast<int>(rows.size());
    Eigen::MatrixXf centred = GatherRows(context.features, rows);
    centred.rowwise() -= context.mean.transpose();
    const Eigen::MatrixXf unit = UnitRows(centred);

    // Anchors and kernel features, centred by their training means.
    const std::vector<int> anchor_rows = SampleRows(m, bre.anchors, &rng);
    const Eigen::MatrixXf anchors = GatherRows(unit, anchor_rows);
    const int t = static_cast<int>(anchors.rows());
    float bandwidth = 1.0f;
    if (bre.kernel == BreKernel::kGaussian) {
      // Mean of ‖x̂_i − a_q‖² = ‖x̂_i‖² + ‖a_q‖² − 2⟨x̂_i, a_q⟩ over all (i, q).
      const double mean_d2 = unit.rowwise().squaredNorm().mean() +
                             anchors.rowwise().squaredNorm().mean() -
                             2.0 * (unit * anchors.transpose()).mean();
      bandwidth = static_cast<float>(bre.bandwidth_scale * std::sqrt(std::max(mean_d2, 1e-12)));
    }
    Eigen::MatrixXf kernel = KernelMatrix(unit, anchors, bre.kernel, bandwidth);
    const Eigen::VectorXf kernel_mean = kernel.colwise().mean().transpose();
    kernel.rowwise() -= kernel_mean.transpose();

    // Pairs: k nearest neighbours and k random partners per point; targets
    // d_ij = ½‖x̂_i − x̂_j‖² scaled to [0, 1].
    const Neighbours neighbours = NearestNeighbours(unit, bre.neighbours);
    const int k = neighbours.k;
    std::vector<int> pair_i, pair_j;
    std::vector<double> target;
    for (int i = 0; i < m; ++i) {
      for (int r = 0; r < k; ++r) {
        pair_i.push_back(i);
        pair_j.push_back(neighbours.index[static_cast<size_t>(i) * k + r]);
        int j = static_cast<int>(rng.UniformInt(m - 1));
        if (j >= i) ++j;
        pair_i.push_back(i);
        pair_j.push_back(j);
      }
    }
    const size_t num_pairs = pair_i.size();
    target.resize(num_pairs);
    double max_target = 0.0;
    const Eigen::MatrixXf unit_columns = unit.transpose();  // one point per column
    for (size_t e = 0; e < num_pairs; ++e) {
      target[e] = 0.5 * (unit_columns.col(pair_i[e]) - unit_columns.col(pair_j[e])).squaredNorm();
      max_target = std::max(max_target, target[e]);
    }
    if (max_target > 0.0) {
      for (double& value : target) value /= max_target;
    }
    // Adjacency (CSR): the pairs each point takes part in.
    std::vector<int> adjacency_start(m + 1, 0), adjacency;
    for (size_t e = 0; e < num_pairs; ++e) {
      ++adjacency_start[pair_i[e] + 1];
      ++adjacency_start[pair_j[e] + 1];
    }
    for (int i = 0; i < m; ++i) adjacency_start[i + 1] += adjacency_start[i];
    adjacency.resize(adjacency_start[m]);
    {
      std::vector<int> fill(adjacency_start.begin(), adjacency_start.end() - 1);
      for (size_t e = 0; e < num_pairs; ++e) {
        adjacency[fill[pair_i[e]]++] = static_cast<int>(e);
        adjacency[fill[pair_j[e]]++] = static_cast<int>(e);
      }
    }

    Eigen::MatrixXf weights = RandomGaussian(bits, t, &rng);
    Eigen::MatrixXf activation = kernel * weights.transpose();      // m × bits
    std::vector<uint8_t> code_bits(static_cast<size_t>(bits) * m);  // bit p of point i at p·m + i
    for (int p = 0; p < bits; ++p) {
      for (int i = 0; i < m; ++i)
        code_bits[static_cast<size_t>(p) * m + i] = activation(i, p) > 0.0f;
    }
    std::vector<int> hamming(num_pairs, 0);
    for (size_t e = 0; e < num_pairs; ++e) {
      for (int p = 0; p < bits; ++p) {
        hamming[e] += code_bits[static_cast<size_t>(p) * m + pair_i[e]] !=
                      code_bits[static_cast<size_t>(p) * m + pair_j[e]];
      }
    }
    const double inv_bits = 1.0 / bits;
    auto pair_loss = [&](int h, size_t e) {
      const double r = h * inv_bits - target[e];
      return r * r;
    };
    auto total_loss = [&]() {
      double total = 0.0;
      for (size_t e = 0; e < num_pairs; ++e) total += pair_loss(hamming[e], e);
      return total;
    };
    context.summary->initial_loss = total_loss() / num_pairs;

    // Flips bit p of point i in (bits_p, hamming_work); returns the loss change.
    std::vector<int> hamming_work(num_pairs);
    std::vector<uint8_t> bits_work(m);
    auto flip = [&](int i) {
      double change = 0.0;
      const uint8_t bit_i = bits_work[i];
      for (int a = adjacency_start[i]; a < adjacency_start[i + 1]; ++a) {
        const int e = adjacency[a];
        const int j = pair_i[e] == i ? pair_j[e] : pair_i[e];
        const int h = hamming_work[e];
        const int h_new = h + (bits_work[j] == bit_i ? 1 : -1);
        change += pair_loss(h_new, e) - pair_loss(h, e);
        hamming_work[e] = h_new;
      }
      bits_work[i] = bit_i ^ 1u;
      return change;
    };

    struct Breakpoint {
      float alpha;
      int i;
    };
    std::vector<Breakpoint> breakpoints;
    breakpoints.reserve(m);
    std::vector<float> base(m);
    const int64_t updates = static_cast<int64_t>(bre.updates_per_bit) * bits;
    for (int64_t u = 0; u < updates; ++u) {
      const int p = static_cast<int>(u % bits);
      const int q = static_cast<int>(rng.UniformInt(t));
      const float w_old = weights(p, q);
      uint8_t* bits_p = &code_bits[static_cast<size_t>(p) * m];
      // f_i(α) = base_i + α K_iq: bit i flips at α = −base_i / K_iq.
      breakpoints.clear();
      for (int i = 0; i < m; ++i) {
        const float kiq = kernel(i, q);
        base[i] = activation(i, p) - w_old * kiq;
        if (kiq != 0.0f) breakpoints.push_back({-base[i] / kiq, i});
      }
      if (breakpoints.empty()) continue;
      std::sort(breakpoints.begin(), breakpoints.end(),
                [](const Breakpoint& a, const Breakpoint& b) { return a.alpha < b.alpha; });
      // Start at α → −∞ and sweep upwards, one flip per breakpoint.
      hamming_work = hamming;
      std::copy(bits_p, bits_p + m, bits_work.begin());
      double change = 0.0;
      for (int i = 0; i < m; ++i) {
        const float kiq = kernel(i, q);
        const uint8_t at_minus_infinity = kiq > 0.0f ? 0 : kiq < 0.0f ? 1 : (base[i] > 0.0f);
        if (bits_work[i] != at_minus_infinity) change += flip(i);
      }
      double best_change = change;
      int best_position = -1;  // −1: before the first breakpoint; r: after breakpoint r
      const int count = static_cast<int>(breakpoints.size());
      for (int r = 0; r < count; ++r) {
        change += flip(breakpoints[r].i);
        // Only between distinct breakpoints can α realise this configuration.
        const bool realisable = r + 1 == count || breakpoints[r + 1].alpha > breakpoints[r].alpha;
        if (realisable && change < best_change) {
          best_change = change;
          best_position = r;
        }
      }
      if (best_change >= -1e-12) continue;  // the current weight is already optimal
      const float first = breakpoints.front().alpha, last = breakpoints.back().alpha;
      const float margin = std::max(1e-6f, (last - first) / std::max(1, count - 1));
      float alpha;
      if (best_position < 0) {
        alpha = first - margin;
      } else if (best_position == count - 1) {
        alpha = last + margin;
      } else {
        alpha = 0.5f * (breakpoints[best_position].alpha + breakpoints[best_position + 1].alpha);
      }
      // Apply: new activations, bits and pair distances.
      weights(p, q) = alpha;
      hamming_work = hamming;
      std::copy(bits_p, bits_p + m, bits_work.begin());
      for (int i = 0; i < m; ++i) {
        activation(i, p) = base[i] + alpha * kernel(i, q);
        if ((activation(i, p) > 0.0f) != (bits_work[i] != 0)) flip(i);
      }
      hamming.swap(hamming_work);
      std::copy(bits_work.begin(), bits_work.end(), bits_p);
    }
    context.summary->final_loss = total_loss() / num_pairs;
    context.summary->iterations = static_cast<int>(updates);
    context.summary->training_rows = m;
    context.summary->training_pairs = static_cast<int64_t>(num_pairs);

    hasher.bre_kernel_ = bre.kernel;
    hasher.bre_bandwidth_ = bandwidth;
    hasher.bre_anchors_ = anchors;
    hasher.bre_kernel_mean_ = kernel_mean;
    hasher.projection_ = weights;
    return hasher;
  }
};

}  // namespace internal

// ---------------------------------------------------------------------------------------
// Hasher

Hasher Hasher::Train(const Eigen::MatrixXf& features, const HashOptions& options,
                     HashTrainingSummary* summary) {
  options.Check();
  SOPE_CHECK(features.rows() >= 2, "hash training needs ≥ 2 feature rows, got {}", features.rows());
  SOPE_CHECK(features.cols() >= 1, "hash training needs ≥ 1 feature column, got {}",
             features.cols());
  SOPE_CHECK(features.allFinite(), "hash training features contain NaN or infinity");
  const auto start = std::chrono::steady_clock::now();

  HashTrainingSummary local_summary;
  HashTrainingSummary* out = summary != nullptr ? summary : &local_summary;
  *out = HashTrainingSummary();
  out->method = options.method;
  out->bits = options.bits;
  out->input_dims = static_cast<int>(features.cols());
  out->initial_loss = out->final_loss = std::numeric_limits<double>::quiet_NaN();

  internal::Random rng(options.seed);
  const std::vector<int> sample =
      internal::SampleRows(features.rows(), options.max_training_samples, &rng);
  internal::HasherAccess::Context context{
      features, options, &rng, internal::GatherRows(features, sample), Eigen::VectorXf(), out};
  context.mean = context.sample_centred.colwise().mean().transpose();
  context.sample_centred.rowwise() -= context.mean.transpose();

  Hasher hasher;
  switch (options.method) {
    case HashMethod::kLsh:
      hasher = internal::HasherAccess::TrainLsh(context);
      break;
    case HashMethod::kSpectral:
      hasher = internal::HasherAccess::TrainSpectral(context);
      break;
    case HashMethod::kMinimalLoss:
      hasher = internal::HasherAccess::TrainMinimalLoss(context);
      break;
    case HashMethod::kBinaryReconstructive:
      hasher = internal::HasherAccess::TrainBinaryReconstructive(context);
      break;
    case HashMethod::kItq:
      hasher = internal::HasherAccess::TrainItq(context);
      break;
  }
  out->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return hasher;
}

Eigen::MatrixXf Hasher::Activations(const Eigen::MatrixXf& features) const {
  Eigen::MatrixXf centred = features;
  centred.rowwise() -= mean_.transpose();
  switch (method_) {
    case HashMethod::kLsh:
    case HashMethod::kMinimalLoss:
    case HashMethod::kItq: {
      Eigen::MatrixXf activation = centred * projection_.transpose();
      activation.rowwise() += offset_.transpose();
      return activation;
    }
    case HashMethod::kSpectral: {
      const Eigen::MatrixXf projected = centred * projection_.transpose();  // rows × npca
      Eigen::MatrixXf activation(features.rows(), bits_);
      for (int b = 0; b < bits_; ++b) {
        const int direction = sh_direction_[b];
        const float omega = sh_omega_(b), lo = sh_range_min_(direction);
        // sin(π/2 + ω(y − a)) = cos(ω(y − a)).
        activation.col(b) = ((projected.col(direction).array() - lo) * omega).cos().matrix();
      }
      return activation;
    }
    case HashMethod::kBinaryReconstructive: {
      Eigen::MatrixXf kernel = internal::KernelMatrix(internal::UnitRows(centred), bre_anchors_,
                                                      bre_kernel_, bre_bandwidth_);
      kernel.rowwise() -= bre_kernel_mean_.transpose();
      return kernel * projection_.transpose();
    }
  }
  SOPE_THROW("unknown hash method {}", static_cast<int>(method_));
}

BinaryCodes Hasher::Encode(const Eigen::MatrixXf& features) const {
  SOPE_CHECK(trained(), "Encode called on an untrained hasher");
  SOPE_CHECK(features.cols() == input_dims(), "hasher expects {} feature columns, got {}",
             input_dims(), features.cols());
  BinaryCodes codes(bits_, features.rows());
  constexpr Eigen::Index kBlockRows = 4096;
  for (Eigen::Index begin = 0; begin < features.rows(); begin += kBlockRows) {
    const Eigen::Index rows = std::min(kBlockRows, features.rows() - begin);
    const BinaryCodes block = internal::PackSigns(Activations(features.middleRows(begin, rows)));
    std::copy(block.words.begin(), block.words.end(),
              codes.words.begin() + begin * codes.words_per_code);
  }
  return codes;
}

std::vector<uint8_t> Hasher::Serialize() const {
  SOPE_CHECK(trained(), "Serialize called on an untrained hasher");
  internal::ByteWriter writer;
  writer.Raw(internal::kMagic, sizeof(internal::kMagic));
  writer.U32(internal::kFormatVersion);
  writer.U32(static_cast<uint32_t>(method_));
  writer.U32(static_cast<uint32_t>(bits_));
  writer.Matrix(mean_);
  writer.Matrix(projection_);
  writer.Matrix(offset_);
  Eigen::MatrixXf direction(sh_direction_.size(), 1);
  for (size_t b = 0; b < sh_direction_.size(); ++b)
    direction(b) = static_cast<float>(sh_direction_[b]);
  writer.Matrix(direction);
  writer.Matrix(sh_omega_);
  writer.Matrix(sh_range_min_);
  writer.U32(static_cast<uint32_t>(bre_kernel_));
  writer.F32(bre_bandwidth_);
  writer.Matrix(bre_anchors_);
  writer.Matrix(bre_kernel_mean_);
  return writer.Take();
}

Hasher Hasher::Deserialize(const uint8_t* data, size_t size) {
  SOPE_CHECK(data != nullptr || size == 0, "hasher data is null");
  internal::ByteReader reader(data, size);
  const std::string magic = reader.Raw(sizeof(internal::kMagic), "magic");
  SOPE_CHECK(magic == std::string(internal::kMagic, sizeof(internal::kMagic)),
             "not a sope hasher (bad magic)");
  const uint32_t version = reader.U32("version");
  SOPE_CHECK(version == internal::kFormatVersion,
             "unsupported hasher format version {} (this build reads {})", version,
             internal::kFormatVersion);
  Hasher hasher;
  const uint32_t method = reader.U32("method");
  SOPE_CHECK(method <= static_cast<uint32_t>(HashMethod::kItq), "unknown hash method id {}",
             method);
  hasher.method_ = static_cast<HashMethod>(method);
  const uint32_t bits = reader.U32("bits");
  SOPE_CHECK(bits >= HashOptions::kMinBits && bits <= HashOptions::kMaxBits,
             "hasher has {} bits, outside [{}, {}]", bits, HashOptions::kMinBits,
             HashOptions::kMaxBits);
  const int b = static_cast<int>(bits);
  auto vector_field = [&](const char* field) -> Eigen::VectorXf {
    const Eigen::MatrixXf matrix = reader.Matrix(field);
    SOPE_CHECK(matrix.cols() == 1 || matrix.size() == 0, "hasher field '{}' is not a vector",
               field);
    return Eigen::Map<const Eigen::VectorXf>(matrix.data(), matrix.size());
  };
  hasher.mean_ = vector_field("mean");
  hasher.projection_ = reader.Matrix("projection");
  hasher.offset_ = vector_field("offset");
  const Eigen::VectorXf direction = vector_field("sh_direction");
  hasher.sh_omega_ = vector_field("sh_omega");
  hasher.sh_range_min_ = vector_field("sh_range_min");
  const uint32_t kernel = reader.U32("bre_kernel");
  SOPE_CHECK(kernel <= static_cast<uint32_t>(BreKernel::kGaussian), "unknown BRE kernel id {}",
             kernel);
  hasher.bre_kernel_ = static_cast<BreKernel>(kernel);
  hasher.bre_bandwidth_ = reader.F32("bre_bandwidth");
  hasher.bre_anchors_ = reader.Matrix("bre_anchors");
  hasher.bre_kernel_mean_ = vector_field("bre_kernel_mean");
  SOPE_CHECK(reader.remaining() == 0, "hasher data has {} trailing bytes", reader.remaining());

  const Eigen::Index dims = hasher.mean_.size();
  SOPE_CHECK(dims >= 1, "hasher has no input dimensions");
  switch (hasher.method_) {
    case HashMethod::kLsh:
    case HashMethod::kMinimalLoss:
    case HashMethod::kItq:
      SOPE_CHECK(hasher.projection_.rows() == b && hasher.projection_.cols() == dims &&
                     hasher.offset_.size() == b,
                 "inconsistent {} hasher sizes", ToString(hasher.method_));
      break;
    case HashMethod::kSpectral: {
      const Eigen::Index npca = hasher.projection_.rows();
      SOPE_CHECK(hasher.projection_.cols() == dims && direction.size() == b &&
                     hasher.sh_omega_.size() == b && hasher.sh_range_min_.size() == npca,
                 "inconsistent sh hasher sizes");
      hasher.sh_direction_.resize(b);
      for (int i = 0; i < b; ++i) {
        SOPE_CHECK(direction(i) >= 0 && direction(i) < npca, "sh direction {} out of range",
                   direction(i));
        hasher.sh_direction_[i] = static_cast<int32_t>(direction(i));
      }
      break;
    }
    case HashMethod::kBinaryReconstructive:
      SOPE_CHECK(hasher.bre_anchors_.cols() == dims && hasher.projection_.rows() == b &&
                     hasher.projection_.cols() == hasher.bre_anchors_.rows() &&
                     hasher.bre_kernel_mean_.size() == hasher.bre_anchors_.rows() &&
                     hasher.bre_bandwidth_ > 0.0f,
                 "inconsistent bre hasher sizes");
      break;
  }
  hasher.bits_ = b;
  return hasher;
}

}  // namespace sope
