// Spectral hashing (Weiss, Torralba & Fergus 2008; thesis eq. 4.12–4.13).
#include "recogniser/hash_function.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include <Eigen/Dense>

#include "core/error.h"

namespace sope {
namespace internal {

// bit b = [cos(ω_b (y_{d_b} − a_{d_b})) > 0] of the PCA projections y, i.e.
// sin(π/2 + ω(y − a)) > 0 (eq. 4.12).
class SpectralHasher : public HashFunction {
 public:
  Eigen::MatrixXf Activations(const Eigen::MatrixXf& centred) const override {
    const Eigen::MatrixXf projected = centred * projection_.transpose();  // rows × npca
    const int bits = static_cast<int>(sh_direction_.size());
    Eigen::MatrixXf activation(centred.rows(), bits);
    for (int b = 0; b < bits; ++b) {
      const int direction = sh_direction_[b];
      const float omega = sh_omega_(b), lo = sh_range_min_(direction);
      // sin(π/2 + ω(y − a)) = cos(ω(y − a)).
      activation.col(b) = ((projected.col(direction).array() - lo) * omega).cos().matrix();
    }
    return activation;
  }
  HashParameters Parameters() const override {
    HashParameters p;
    p.projection = projection_;
    p.sh_direction.resize(sh_direction_.size());
    for (size_t b = 0; b < sh_direction_.size(); ++b) {
      p.sh_direction(b) = static_cast<float>(sh_direction_[b]);
    }
    p.sh_omega = sh_omega_;
    p.sh_range_min = sh_range_min_;
    return p;
  }

  Eigen::MatrixXf projection_;  // PCA directions, npca × dims
  std::vector<int32_t> sh_direction_;
  Eigen::VectorXf sh_omega_;
  Eigen::VectorXf sh_range_min_;
};

// Weiss, Torralba & Fergus 2008 (thesis §4.6.1, eq. 4.12–4.13).
std::unique_ptr<HashFunction> TrainSpectral(TrainingContext& context) {
  auto hasher = std::make_unique<SpectralHasher>();
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
      modes.push_back({static_cast<float>(k * kPi / range_length(i)), i, k});
    }
  }
  std::sort(modes.begin(), modes.end(), [](const Mode& a, const Mode& b) {
    if (a.omega != b.omega) return a.omega < b.omega;
    if (a.direction != b.direction) return a.direction < b.direction;
    return a.k < b.k;
  });
  hasher->projection_ = directions.transpose();
  hasher->sh_direction_.resize(bits);
  hasher->sh_omega_.resize(bits);
  for (int b = 0; b < bits; ++b) {
    hasher->sh_direction_[b] = modes[b].direction;
    hasher->sh_omega_(b) = modes[b].omega;
  }
  hasher->sh_range_min_ = range_min;
  context.summary->training_rows = static_cast<int>(context.sample_centred.rows());
  return hasher;
}

std::unique_ptr<HashFunction> LoadSpectral(const HashParameters& p, int bits, Eigen::Index dims) {
  const Eigen::Index npca = p.projection.rows();
  SOPE_CHECK(p.projection.cols() == dims && p.sh_direction.size() == bits &&
                 p.sh_omega.size() == bits && p.sh_range_min.size() == npca,
             "inconsistent sh hasher sizes");
  auto hasher = std::make_unique<SpectralHasher>();
  hasher->sh_direction_.resize(bits);
  for (int i = 0; i < bits; ++i) {
    SOPE_CHECK(p.sh_direction(i) >= 0 && p.sh_direction(i) < npca, "sh direction {} out of range",
               p.sh_direction(i));
    hasher->sh_direction_[i] = static_cast<int32_t>(p.sh_direction(i));
  }
  hasher->projection_ = p.projection;
  hasher->sh_omega_ = p.sh_omega;
  hasher->sh_range_min_ = p.sh_range_min;
  return hasher;
}

}  // namespace internal
}  // namespace sope
