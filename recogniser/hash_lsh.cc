// LSH: Gaussian random projections of mean-centred features, thresholded at zero
// (Charikar 2002) or at random thresholds (Andoni & Indyk 2008).
#include "recogniser/hash_function.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include <Eigen/Dense>

#include "core/error.h"

namespace sope {
namespace internal {

class LshHasher : public LinearHashFunction {};

// Charikar 2002 / Andoni & Indyk 2008.
std::unique_ptr<HashFunction> TrainLsh(TrainingContext& context) {
  auto hasher = std::make_unique<LshHasher>();
  const int bits = context.options.bits;
  const int dims = static_cast<int>(context.features.cols());
  hasher->projection_ = RandomGaussian(bits, dims, context.rng);
  hasher->offset_ = Eigen::VectorXf::Zero(bits);
  const double spread = context.options.lsh.threshold_spread;
  if (spread > 0.0) {
    const Eigen::MatrixXf projected = context.sample_centred * hasher->projection_.transpose();
    for (int k = 0; k < bits; ++k) {
      const double sigma =
          std::sqrt(projected.col(k).squaredNorm() / std::max<Eigen::Index>(1, projected.rows()));
      const double threshold = spread * sigma * (2.0 * context.rng->Uniform() - 1.0);
      hasher->offset_(k) = static_cast<float>(-threshold);
    }
  }
  context.summary->training_rows = static_cast<int>(context.sample_centred.rows());
  return hasher;
}

std::unique_ptr<HashFunction> LoadLsh(const HashParameters& p, int bits, Eigen::Index dims) {
  return LoadLinear<LshHasher>(p, HashMethod::kLsh, bits, dims);
}

}  // namespace internal
}  // namespace sope
