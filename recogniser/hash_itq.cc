// Iterative quantisation (Gong & Lazebnik 2011): PCA, then the rotation minimising the
// quantisation loss.
#include "recogniser/hash_function.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include <Eigen/Dense>

#include "core/error.h"

namespace sope {
namespace internal {

class ItqHasher : public LinearHashFunction {};

// Gong & Lazebnik 2011.
std::unique_ptr<HashFunction> TrainItq(TrainingContext& context) {
  auto hasher = std::make_unique<ItqHasher>();
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
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(cross, Eigen::ComputeFullU | Eigen::ComputeFullV);
    rotation = svd.matrixV() * svd.matrixU().transpose();
  }
  const Eigen::MatrixXf rotated = embedded * rotation.cast<float>();
  context.summary->final_loss = quantisation_loss(rotated);
  if (iterations == 0) context.summary->initial_loss = context.summary->final_loss;
  context.summary->iterations = iterations;
  context.summary->training_rows = static_cast<int>(embedded.rows());
  hasher->projection_ = (directions * rotation.cast<float>()).transpose();
  hasher->offset_ = Eigen::VectorXf::Zero(bits);
  return hasher;
}

std::unique_ptr<HashFunction> LoadItq(const HashParameters& p, int bits, Eigen::Index dims) {
  return LoadLinear<ItqHasher>(p, HashMethod::kItq, bits, dims);
}

}  // namespace internal
}  // namespace sope
