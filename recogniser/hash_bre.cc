// Binary reconstructive embedding (Kulis & Darrell 2009; thesis eq. 2.21).
#include "recogniser/hash_function.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Dense>

#include "core/error.h"

namespace sope {
namespace internal {

// bit b = [Σ_q W_bq (κ(a_q, x̂) − mean_q) > 0] over anchors a_q of unit-normalised,
// centred features x̂.
class BinaryReconstructiveHasher : public HashFunction {
 public:
  Eigen::MatrixXf Activations(const Eigen::MatrixXf& centred) const override {
    Eigen::MatrixXf kernel =
        KernelMatrix(UnitRows(centred), bre_anchors_, bre_kernel_, bre_bandwidth_);
    kernel.rowwise() -= bre_kernel_mean_.transpose();
    return kernel * projection_.transpose();
  }
  HashParameters Parameters() const override {
    HashParameters p;
    p.projection = projection_;
    p.bre_kernel = bre_kernel_;
    p.bre_bandwidth = bre_bandwidth_;
    p.bre_anchors = bre_anchors_;
    p.bre_kernel_mean = bre_kernel_mean_;
    return p;
  }

  Eigen::MatrixXf projection_;  // W, bits × anchors
  BreKernel bre_kernel_ = BreKernel::kGaussian;
  Eigen::MatrixXf bre_anchors_;
  Eigen::VectorXf bre_kernel_mean_;
  float bre_bandwidth_ = 1.0f;
};

// Training pairs of BRE: k nearest neighbours and k random partners per point; targets
// d_ij = ½‖x̂_i − x̂_j‖² scaled to [0, 1]; and the pairs each point takes part in (CSR).
struct BrePairs {
  std::vector<int> i, j;
  std::vector<double> target;
  std::vector<int> adjacency_start, adjacency;
  size_t size() const { return i.size(); }
};

BrePairs MakeBrePairs(const Eigen::MatrixXf& unit, int neighbour_count, Random* rng) {
  const int m = static_cast<int>(unit.rows());
  const Neighbours neighbours = NearestNeighbours(unit, neighbour_count);
  const int k = neighbours.k;
  BrePairs pairs;
  for (int i = 0; i < m; ++i) {
    for (int r = 0; r < k; ++r) {
      pairs.i.push_back(i);
      pairs.j.push_back(neighbours.index[static_cast<size_t>(i) * k + r]);
      int j = static_cast<int>(rng->UniformInt(m - 1));
      if (j >= i) ++j;
      pairs.i.push_back(i);
      pairs.j.push_back(j);
    }
  }
  const size_t num_pairs = pairs.size();
  pairs.target.resize(num_pairs);
  double max_target = 0.0;
  const Eigen::MatrixXf unit_columns = unit.transpose();  // one point per column
  for (size_t e = 0; e < num_pairs; ++e) {
    pairs.target[e] =
        0.5 * (unit_columns.col(pairs.i[e]) - unit_columns.col(pairs.j[e])).squaredNorm();
    max_target = std::max(max_target, pairs.target[e]);
  }
  if (max_target > 0.0) {
    for (double& value : pairs.target) value /= max_target;
  }
  pairs.adjacency_start.assign(m + 1, 0);
  for (size_t e = 0; e < num_pairs; ++e) {
    ++pairs.adjacency_start[pairs.i[e] + 1];
    ++pairs.adjacency_start[pairs.j[e] + 1];
  }
  for (int i = 0; i < m; ++i) pairs.adjacency_start[i + 1] += pairs.adjacency_start[i];
  pairs.adjacency.resize(pairs.adjacency_start[m]);
  std::vector<int> fill(pairs.adjacency_start.begin(), pairs.adjacency_start.end() - 1);
  for (size_t e = 0; e < num_pairs; ++e) {
    pairs.adjacency[fill[pairs.i[e]]++] = static_cast<int>(e);
    pairs.adjacency[fill[pairs.j[e]]++] = static_cast<int>(e);
  }
  return pairs;
}

// BRE's coordinate descent (Kulis & Darrell 2009, §3.2): one weight W_pq at a time set to
// the exact minimiser of the reconstruction loss along it, found by sweeping the
// breakpoints where a point's bit p flips.
class BreOptimiser {
 public:
  BreOptimiser(const Eigen::MatrixXf& kernel, const BrePairs& pairs, Eigen::MatrixXf weights)
      : kernel_(kernel),
        pairs_(pairs),
        bits_(static_cast<int>(weights.rows())),
        m_(static_cast<int>(kernel.rows())),
        weights_(std::move(weights)),
        activation_(kernel * weights_.transpose()),
        code_bits_(static_cast<size_t>(bits_) * m_),
        hamming_(pairs.size(), 0),
        hamming_work_(pairs.size()),
        bits_work_(m_),
        base_(m_) {
    for (int p = 0; p < bits_; ++p) {
      for (int i = 0; i < m_; ++i)
        code_bits_[static_cast<size_t>(p) * m_ + i] = activation_(i, p) > 0.0f;
    }
    for (size_t e = 0; e < pairs.size(); ++e) {
      for (int p = 0; p < bits_; ++p) {
        hamming_[e] += code_bits_[static_cast<size_t>(p) * m_ + pairs.i[e]] !=
                       code_bits_[static_cast<size_t>(p) * m_ + pairs.j[e]];
      }
    }
    breakpoints_.reserve(m_);
  }

  // Mean loss over the pairs.
  double MeanLoss() const {
    double total = 0.0;
    for (size_t e = 0; e < pairs_.size(); ++e) total += PairLoss(hamming_[e], e);
    return total / pairs_.size();
  }

  // Sets W_pq to its best value (unchanged when that is the current one).
  void Update(int p, int q) {
    const float w_old = weights_(p, q);
    uint8_t* bits_p = &code_bits_[static_cast<size_t>(p) * m_];
    // f_i(α) = base_i + α K_iq: bit i flips at α = −base_i / K_iq.
    breakpoints_.clear();
    for (int i = 0; i < m_; ++i) {
      const float kiq = kernel_(i, q);
      base_[i] = activation_(i, p) - w_old * kiq;
      if (kiq != 0.0f) breakpoints_.push_back({-base_[i] / kiq, i});
    }
    if (breakpoints_.empty()) return;
    std::sort(breakpoints_.begin(), breakpoints_.end(),
              [](const Breakpoint& a, const Breakpoint& b) { return a.alpha < b.alpha; });
    float alpha;
    if (!BestAlpha(q, bits_p, &alpha)) return;  // the current weight is already optimal
    // Apply: new activations, bits and pair distances.
    weights_(p, q) = alpha;
    hamming_work_ = hamming_;
    std::copy(bits_p, bits_p + m_, bits_work_.begin());
    for (int i = 0; i < m_; ++i) {
      activation_(i, p) = base_[i] + alpha * kernel_(i, q);
      if ((activation_(i, p) > 0.0f) != (bits_work_[i] != 0)) Flip(i);
    }
    hamming_.swap(hamming_work_);
    std::copy(bits_work_.begin(), bits_work_.end(), bits_p);
  }

  const Eigen::MatrixXf& weights() const { return weights_; }

 private:
  struct Breakpoint {
    float alpha;
    int i;
  };

  double PairLoss(int h, size_t e) const {
    const double r = h * (1.0 / bits_) - pairs_.target[e];
    return r * r;
  }

  // Flips bit p of point i in (bits_work_, hamming_work_); returns the loss change.
  double Flip(int i) {
    double change = 0.0;
    const uint8_t bit_i = bits_work_[i];
    for (int a = pairs_.adjacency_start[i]; a < pairs_.adjacency_start[i + 1]; ++a) {
      const int e = pairs_.adjacency[a];
      const int j = pairs_.i[e] == i ? pairs_.j[e] : pairs_.i[e];
      const int h = hamming_work_[e];
      const int h_new = h + (bits_work_[j] == bit_i ? 1 : -1);
      change += PairLoss(h_new, e) - PairLoss(h, e);
      hamming_work_[e] = h_new;
    }
    bits_work_[i] = bit_i ^ 1u;
    return change;
  }

  // Sweeps α from −∞ upwards over the sorted breakpoints; the α (between distinct
  // breakpoints, or beyond the ends) of the lowest loss, false when no α lowers it.
  bool BestAlpha(int q, const uint8_t* bits_p, float* alpha) {
    hamming_work_ = hamming_;
    std::copy(bits_p, bits_p + m_, bits_work_.begin());
    double change = 0.0;
    for (int i = 0; i < m_; ++i) {
      const float kiq = kernel_(i, q);
      const uint8_t at_minus_infinity = kiq > 0.0f ? 0 : kiq < 0.0f ? 1 : (base_[i] > 0.0f);
      if (bits_work_[i] != at_minus_infinity) change += Flip(i);
    }
    double best_change = change;
    int best_position = -1;  // −1: before the first breakpoint; r: after breakpoint r
    const int count = static_cast<int>(breakpoints_.size());
    for (int r = 0; r < count; ++r) {
      change += Flip(breakpoints_[r].i);
      // Only between distinct breakpoints can α realise this configuration.
      const bool realisable = r + 1 == count || breakpoints_[r + 1].alpha > breakpoints_[r].alpha;
      if (realisable && change < best_change) {
        best_change = change;
        best_position = r;
      }
    }
    if (best_change >= -1e-12) return false;
    const float first = breakpoints_.front().alpha, last = breakpoints_.back().alpha;
    const float margin = std::max(1e-6f, (last - first) / std::max(1, count - 1));
    if (best_position < 0) {
      *alpha = first - margin;
    } else if (best_position == count - 1) {
      *alpha = last + margin;
    } else {
      *alpha = 0.5f * (breakpoints_[best_position].alpha + breakpoints_[best_position + 1].alpha);
    }
    return true;
  }

  const Eigen::MatrixXf& kernel_;
  const BrePairs& pairs_;
  const int bits_, m_;
  Eigen::MatrixXf weights_;
  Eigen::MatrixXf activation_;      // m × bits
  std::vector<uint8_t> code_bits_;  // bit p of point i at p·m + i
  std::vector<int> hamming_;
  std::vector<int> hamming_work_;
  std::vector<uint8_t> bits_work_;
  std::vector<float> base_;
  std::vector<Breakpoint> breakpoints_;
};

// Kulis & Darrell 2009 (thesis eq. 2.21).
std::unique_ptr<HashFunction> TrainBinaryReconstructive(TrainingContext& context) {
  auto hasher = std::make_unique<BinaryReconstructiveHasher>();
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

  const BrePairs pairs = MakeBrePairs(unit, bre.neighbours, &rng);
  BreOptimiser optimiser(kernel, pairs, RandomGaussian(bits, t, &rng));
  context.summary->initial_loss = optimiser.MeanLoss();
  const int64_t updates = static_cast<int64_t>(bre.updates_per_bit) * bits;
  for (int64_t u = 0; u < updates; ++u) {
    const int p = static_cast<int>(u % bits);
    const int q = static_cast<int>(rng.UniformInt(t));
    optimiser.Update(p, q);
  }
  context.summary->final_loss = optimiser.MeanLoss();
  context.summary->iterations = static_cast<int>(updates);
  context.summary->training_rows = m;
  context.summary->training_pairs = static_cast<int64_t>(pairs.size());

  hasher->bre_kernel_ = bre.kernel;
  hasher->bre_bandwidth_ = bandwidth;
  hasher->bre_anchors_ = anchors;
  hasher->bre_kernel_mean_ = kernel_mean;
  hasher->projection_ = optimiser.weights();
  return hasher;
}

std::unique_ptr<HashFunction> LoadBinaryReconstructive(const HashParameters& p, int bits,
                                                       Eigen::Index dims) {
  SOPE_CHECK(p.bre_anchors.cols() == dims && p.projection.rows() == bits &&
                 p.projection.cols() == p.bre_anchors.rows() &&
                 p.bre_kernel_mean.size() == p.bre_anchors.rows() && p.bre_bandwidth > 0.0f,
             "inconsistent bre hasher sizes");
  auto hasher = std::make_unique<BinaryReconstructiveHasher>();
  hasher->projection_ = p.projection;
  hasher->bre_kernel_ = p.bre_kernel;
  hasher->bre_bandwidth_ = p.bre_bandwidth;
  hasher->bre_anchors_ = p.bre_anchors;
  hasher->bre_kernel_mean_ = p.bre_kernel_mean;
  return hasher;
}

}  // namespace internal
}  // namespace sope
