// Minimal-loss hashing (Norouzi & Fleet 2011; thesis eq. 2.18–2.20).
#include "recogniser/hash_function.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include <Eigen/Dense>

#include "core/error.h"

namespace sope {
namespace internal {

class MinimalLossHasher : public LinearHashFunction {};

// Loss-augmented inference for one pair with activations a (point i) and c (point j):
// (g, h) = argmax ℓ(‖g − h‖_H, s) + gᵀWx̃_i + hᵀWx̃_j over g, h ∈ {0,1}^q. Per bit, the
// best agreeing pair scores max(0, a + c), the best disagreeing one max(a, c); for each
// distance m the best codes make the m bits with the largest gain D − A disagree, so only
// m is searched. Writes g − b(x_i) to di and h − b(x_j) to dj.
void PairCodeChange(const float* a, const float* c, int bits, bool similar, int rho,
                    double lambda, std::vector<float>* gain, std::vector<int>* order, float* di,
                    float* dj) {
  for (int b = 0; b < bits; ++b) {
    (*gain)[b] = std::max(a[b], c[b]) - std::max(0.0f, a[b] + c[b]);
  }
  const int flips = LossAugmentedDistance(*gain, similar, rho, lambda, order);
  // order[0, flips) are the disagreeing bits.
  for (int b = 0; b < bits; ++b) {
    const float g = (a[b] + c[b] > 0.0f) ? 1.0f : 0.0f;  // agree
    di[b] = g - (a[b] > 0.0f ? 1.0f : 0.0f);
    dj[b] = g - (c[b] > 0.0f ? 1.0f : 0.0f);
  }
  for (int r = 0; r < flips; ++r) {
    const int b = (*order)[r];
    const float g = a[b] > c[b] ? 1.0f : 0.0f;  // disagree: (1, 0) or (0, 1)
    di[b] = g - (a[b] > 0.0f ? 1.0f : 0.0f);
    dj[b] = (1.0f - g) - (c[b] > 0.0f ? 1.0f : 0.0f);
  }
}

// Norouzi & Fleet 2011 (thesis eq. 2.18–2.20).
std::unique_ptr<HashFunction> TrainMinimalLoss(TrainingContext& context) {
  auto hasher = std::make_unique<MinimalLossHasher>();
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
      PairCodeChange(ai.col(p).data(), aj.col(p).data(), bits, pairs[p].similar, rho, lambda,
                     &gain, &order, delta_i.col(p).data(), delta_j.col(p).data());
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
  hasher->projection_ = weights.leftCols(dims) / static_cast<float>(scale);
  hasher->offset_ = weights.col(dims);
  return hasher;
}

std::unique_ptr<HashFunction> LoadMinimalLoss(const HashParameters& p, int bits,
                                              Eigen::Index dims) {
  return LoadLinear<MinimalLossHasher>(p, HashMethod::kMinimalLoss, bits, dims);
}

}  // namespace internal
}  // namespace sope
