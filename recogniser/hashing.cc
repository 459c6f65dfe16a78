// GCC 12 reports Eigen's AVX-512 kernels (self-initialised "undefined" registers in the
// intrinsics headers) as maybe-uninitialised under -march=native; a known false positive.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif

#include "recogniser/hashing.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <utility>

#include <Eigen/Dense>

#include "core/error.h"
#include "core/stopwatch.h"
#include "recogniser/hash_function.h"

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

std::string ToString(HashMethod method) { return EnumToString(method); }

HashMethod HashMethodFromString(const std::string& text) {
  return EnumFromString<HashMethod>(text);
}

std::string ToString(BreKernel kernel) { return EnumToString(kernel); }

BreKernel BreKernelFromString(const std::string& text) {
  return EnumFromString<BreKernel>(text);
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
  const Stopwatch watch;

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
  internal::TrainingContext context{
      features, options, &rng, internal::GatherRows(features, sample), Eigen::VectorXf(), out};
  context.mean = context.sample_centred.colwise().mean().transpose();
  context.sample_centred.rowwise() -= context.mean.transpose();

  Hasher hasher;
  hasher.method_ = options.method;
  hasher.bits_ = options.bits;
  hasher.mean_ = context.mean;
  switch (options.method) {
    case HashMethod::kLsh:
      hasher.function_ = internal::TrainLsh(context);
      break;
    case HashMethod::kSpectral:
      hasher.function_ = internal::TrainSpectral(context);
      break;
    case HashMethod::kMinimalLoss:
      hasher.function_ = internal::TrainMinimalLoss(context);
      break;
    case HashMethod::kBinaryReconstructive:
      hasher.function_ = internal::TrainBinaryReconstructive(context);
      break;
    case HashMethod::kItq:
      hasher.function_ = internal::TrainItq(context);
      break;
  }
  out->seconds = watch.WallSeconds();
  return hasher;
}

Eigen::MatrixXf Hasher::Activations(const Eigen::MatrixXf& features) const {
  Eigen::MatrixXf centred = features;
  centred.rowwise() -= mean_.transpose();
  return function_->Activations(centred);
}

void internal::LinearHashFunction::Load(const HashParameters& p, HashMethod method, int bits,
                                        Eigen::Index dims) {
  SOPE_CHECK(p.projection.rows() == bits && p.projection.cols() == dims && p.offset.size() == bits,
             "inconsistent {} hasher sizes", ToString(method));
  projection_ = p.projection;
  offset_ = p.offset;
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
  const internal::HashParameters p = function_->Parameters();
  writer.Matrix(p.projection);
  writer.Matrix(p.offset);
  writer.Matrix(p.sh_direction);
  writer.Matrix(p.sh_omega);
  writer.Matrix(p.sh_range_min);
  writer.U32(static_cast<uint32_t>(p.bre_kernel));
  writer.F32(p.bre_bandwidth);
  writer.Matrix(p.bre_anchors);
  writer.Matrix(p.bre_kernel_mean);
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
  internal::HashParameters p;
  p.projection = reader.Matrix("projection");
  p.offset = vector_field("offset");
  p.sh_direction = vector_field("sh_direction");
  p.sh_omega = vector_field("sh_omega");
  p.sh_range_min = vector_field("sh_range_min");
  const uint32_t kernel = reader.U32("bre_kernel");
  SOPE_CHECK(kernel <= static_cast<uint32_t>(BreKernel::kGaussian), "unknown BRE kernel id {}",
             kernel);
  p.bre_kernel = static_cast<BreKernel>(kernel);
  p.bre_bandwidth = reader.F32("bre_bandwidth");
  p.bre_anchors = reader.Matrix("bre_anchors");
  p.bre_kernel_mean = vector_field("bre_kernel_mean");
  SOPE_CHECK(reader.remaining() == 0, "hasher data has {} trailing bytes", reader.remaining());

  const Eigen::Index dims = hasher.mean_.size();
  SOPE_CHECK(dims >= 1, "hasher has no input dimensions");
  switch (hasher.method_) {
    case HashMethod::kLsh:
      hasher.function_ = internal::LoadLsh(p, b, dims);
      break;
    case HashMethod::kSpectral:
      hasher.function_ = internal::LoadSpectral(p, b, dims);
      break;
    case HashMethod::kMinimalLoss:
      hasher.function_ = internal::LoadMinimalLoss(p, b, dims);
      break;
    case HashMethod::kBinaryReconstructive:
      hasher.function_ = internal::LoadBinaryReconstructive(p, b, dims);
      break;
    case HashMethod::kItq:
      hasher.function_ = internal::LoadItq(p, b, dims);
      break;
  }
  hasher.bits_ = b;
  return hasher;
}

}  // namespace sope
