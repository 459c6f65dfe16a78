// GCC 12 reports Eigen's AVX-512 kernels as maybe-uninitialised under -march=native; a known
// false positive (as in hashing.cc).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif

#include "recogniser/features.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>

#include <Eigen/Dense>
#include <pcl/features/cvfh.h>
#include <pcl/features/our_cvfh.h>
#include <pcl/features/vfh.h>
#include <pcl/search/brute_force.h>
#include <pcl/search/kdtree.h>

#include "core/error.h"
#include "recogniser/cloud_filters.h"
#include "recogniser/pcl_convert.h"

namespace sope {
namespace internal {

void PrincipalAxes(const std::vector<Eigen::Vector3f>& points, Eigen::Vector3d* centroid,
                   Eigen::Matrix3d* axes, Eigen::Vector3d* variances) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3f& p : points) mean += p.cast<double>();
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3f& p : points) {
    const Eigen::Vector3d d = p.cast<double>() - mean;
    covariance.noalias() += d * d.transpose();
  }
  covariance /= static_cast<double>(points.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
  *centroid = mean;
  for (int c = 0; c < 3; ++c) {
    axes->col(c) = solver.eigenvectors().col(2 - c);
    (*variances)[c] = solver.eigenvalues()[2 - c];
  }
}

}  // namespace internal

namespace {

constexpr int kMaxBezierOrder = 8;
constexpr int kMaxKdeSamples = 1024;
constexpr int kVfhBins = 308;
// Fewest points ComputeFeatures accepts (the PCA of the patch and VFH need a few).
constexpr int kMinFeaturePoints = 10;
// The Bézier patch is fitted to at most this many points (a deterministic stride subsample
// of the view): 16 control points are well determined by a few hundred, and the fit then
// costs ≈ 0.8 ms (10 iterations, dev machine) instead of growing with the view.
constexpr size_t kBezierMaxPoints = 768;
// Normalised skewness at which the antisymmetric part of the control net gets weight
// tanh(1) ≈ 0.76 (see the "bezier" block in ComputeFeatures).
constexpr double kSkewnessScale = 0.1;
// Binned KDE: bin width as a fraction of the bandwidth (linear binning; relative error
// ≈ (δ/h)²/8 ≈ 1e-4) and the kernel support kept around [lo, hi], in bandwidths.
constexpr double kKdeBinsPerBandwidth = 32.0;
constexpr double kKdeSupport = 8.0;
// Robust extents for the size block: range between these quantiles of the projections.
constexpr double kExtentQuantile = 0.01;

bool IsFinite(const Eigen::Vector3f& p) {
  return std::isfinite(p.x()) && std::isfinite(p.y()) && std::isfinite(p.z());
}

// Bernstein polynomials B_i^order(t), i = 0..order, and their derivatives (db may be null).
template <int kOrder>
inline void BernsteinFixed(double t, double* b, double* db) {
  // B^(n−1) by de Casteljau's recurrence, then one more step; dB_i^n = n (B_{i−1}^{n−1} −
  // B_i^{n−1}).
  double lower[kOrder + 1];
  lower[0] = 1.0;
  const double s = 1.0 - t;
  for (int d = 1; d < kOrder; ++d) {
    lower[d] = t * lower[d - 1];
    for (int i = d - 1; i >= 1; --i) lower[i] = s * lower[i] + t * lower[i - 1];
    lower[0] = s * lower[0];
  }
  for (int i = 0; i <= kOrder; ++i) {
    const double left = i > 0 ? lower[i - 1] : 0.0;
    const double right = i < kOrder ? lower[i] : 0.0;
    b[i] = s * right + t * left;
    if (db) db[i] = kOrder * (left - right);
  }
}

inline void Bernstein(int order, double t, double* b, double* db) {
  switch (order) {
    case 0:
      b[0] = 1.0;
      if (db) db[0] = 0.0;
      return;
    case 1:
      return BernsteinFixed<1>(t, b, db);
    case 2:
      return BernsteinFixed<2>(t, b, db);
    case 3:
      return BernsteinFixed<3>(t, b, db);
    case 4:
      return BernsteinFixed<4>(t, b, db);
    case 5:
      return BernsteinFixed<5>(t, b, db);
    case 6:
      return BernsteinFixed<6>(t, b, db);
    case 7:
      return BernsteinFixed<7>(t, b, db);
    default:
      return BernsteinFixed<kMaxBezierOrder>(t, b, db);
  }
}

// p(u, v) of a patch with control points k_ij at control[3·(i·(n+1) + j) + axis], from the
// Bernstein values bu = B^m(u), bv = B^n(v); with dbu, dbv (derivatives) also ∂p/∂u, ∂p/∂v.
inline void EvaluatePatch(const double* control, int m, int n, const double* bu, const double* bv,
                          double* s) {
  s[0] = s[1] = s[2] = 0.0;
  for (int i = 0; i <= m; ++i) {
    double row[3] = {0.0, 0.0, 0.0};
    const double* k = control + 3 * i * (n + 1);
    for (int j = 0; j <= n; ++j, k += 3) {
      row[0] += bv[j] * k[0];
      row[1] += bv[j] * k[1];
      row[2] += bv[j] * k[2];
    }
    for (int a = 0; a < 3; ++a) s[a] += bu[i] * row[a];
  }
}

inline void EvaluatePatch(const double* control, int m, int n, const double* bu, const double* bv,
                          const double* dbu, const double* dbv, double* s, double* su, double* sv) {
  for (int a = 0; a < 3; ++a) s[a] = su[a] = sv[a] = 0.0;
  for (int i = 0; i <= m; ++i) {
    double row[3] = {0.0, 0.0, 0.0}, row_v[3] = {0.0, 0.0, 0.0};
    const double* k = control + 3 * i * (n + 1);
    for (int j = 0; j <= n; ++j, k += 3) {
      for (int a = 0; a < 3; ++a) {
        row[a] += bv[j] * k[a];
        row_v[a] += dbv[j] * k[a];
      }
    }
    for (int a = 0; a < 3; ++a) {
      s[a] += bu[i] * row[a];
      su[a] += dbu[i] * row[a];
      sv[a] += bu[i] * row_v[a];
    }
  }
}

double ThirdMoment(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3d& centroid,
                   const Eigen::Vector3d& axis) {
  double sum = 0.0;
  for (const Eigen::Vector3f& p : points) {
    const double t = (p.cast<double>() - centroid).dot(axis);
    sum += t * t * t;
  }
  return sum;
}

// DᵀD of the second differences of an (m+1) × (n+1) control net along u and along v.
Eigen::MatrixXd SmoothnessMatrix(int m, int n) {
  const int num_control = (m + 1) * (n + 1);
  Eigen::MatrixXd smooth = Eigen::MatrixXd::Zero(num_control, num_control);
  auto add_difference = [&](int c0, int c1, int c2) {
    const int idx[3] = {c0, c1, c2};
    const double w[3] = {1.0, -2.0, 1.0};
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) smooth(idx[r], idx[c]) += w[r] * w[c];
    }
  };
  for (int j = 0; j <= n; ++j) {
    for (int i = 1; i < m; ++i)
      add_difference((i - 1) * (n + 1) + j, i * (n + 1) + j, (i + 1) * (n + 1) + j);
  }
  for (int i = 0; i <= m; ++i) {
    for (int j = 1; j < n; ++j)
      add_difference(i * (n + 1) + j - 1, i * (n + 1) + j, i * (n + 1) + j + 1);
  }
  return smooth;
}

// Foot point of `p` on the patch (row-major control points, orders m × n): one
// Gauss–Newton step from (*u, *v), clamped to the unit square, kept only when it brings
// the surface point closer. Returns the squared distance at the kept foot point and its
// Bernstein values in bu, bv.
double FootPointStep(const double* control, int m, int n, const double p[3], double* u,
                     double* v, double* bu, double* bv) {
  double dbu[kMaxBezierOrder + 1], dbv[kMaxBezierOrder + 1];
  double bu_new[kMaxBezierOrder + 1], bv_new[kMaxBezierOrder + 1];
  const double px = p[0], py = p[1], pz = p[2];
  Bernstein(m, *u, bu, dbu);
  Bernstein(n, *v, bv, dbv);
  double s[3], su[3], sv[3];
  EvaluatePatch(control, m, n, bu, bv, dbu, dbv, s, su, sv);
  const double r[3] = {s[0] - px, s[1] - py, s[2] - pz};
  const double r_sq = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
  // (JᵀJ) δ = −Jᵀr with J = [S_u S_v], solved in closed form (2×2), lightly damped.
  const double uu = su[0] * su[0] + su[1] * su[1] + su[2] * su[2];
  const double vv = sv[0] * sv[0] + sv[1] * sv[1] + sv[2] * sv[2];
  const double uv = su[0] * sv[0] + su[1] * sv[1] + su[2] * sv[2];
  const double g0 = su[0] * r[0] + su[1] * r[1] + su[2] * r[2];
  const double g1 = sv[0] * r[0] + sv[1] * r[1] + sv[2] * r[2];
  const double damping = 1e-12 * (uu + vv) + 1e-300;
  const double h00 = uu + damping, h11 = vv + damping;
  const double det = h00 * h11 - uv * uv;
  const double du = det > 0.0 ? -(h11 * g0 - uv * g1) / det : 0.0;
  const double dv = det > 0.0 ? -(h00 * g1 - uv * g0) / det : 0.0;
  if (det > 0.0 && std::isfinite(du) && std::isfinite(dv)) {
    const double u_new = std::clamp(*u + du, 0.0, 1.0);
    const double v_new = std::clamp(*v + dv, 0.0, 1.0);
    Bernstein(m, u_new, bu_new, nullptr);
    Bernstein(n, v_new, bv_new, nullptr);
    double t[3];
    EvaluatePatch(control, m, n, bu_new, bv_new, t);
    const double t_sq =
        (t[0] - px) * (t[0] - px) + (t[1] - py) * (t[1] - py) + (t[2] - pz) * (t[2] - pz);
    if (t_sq <= r_sq) {
      *u = u_new;
      *v = v_new;
      std::copy(bu_new, bu_new + m + 1, bu);
      std::copy(bv_new, bv_new + n + 1, bv);
      return t_sq;
    }
  }
  return r_sq;
}

void CheckBezierFitInputs(const std::vector<Eigen::Vector3f>& points, int order_u, int order_v,
                          int iterations, double smoothing) {
  SOPE_CHECK(
      order_u >= 1 && order_u <= kMaxBezierOrder && order_v >= 1 && order_v <= kMaxBezierOrder,
      "FitBezierPatch: orders must be in [1, {}], got ({}, {})", kMaxBezierOrder, order_u, order_v);
  SOPE_CHECK(iterations >= 0, "FitBezierPatch: iterations must be ≥ 0, got {}", iterations);
  SOPE_CHECK(std::isfinite(smoothing) && smoothing >= 0.0,
             "FitBezierPatch: smoothing must be ≥ 0, got {}", smoothing);
  SOPE_CHECK(points.size() >= 3, "FitBezierPatch: need at least 3 points, got {}", points.size());
  for (const Eigen::Vector3f& p : points) {
    SOPE_CHECK(IsFinite(p), "FitBezierPatch: non-finite point ({}, {}, {})", p.x(), p.y(), p.z());
  }
}

// The patch's base plane: origin and the two largest principal axes e1, e2 (normal e3).
struct PatchFrame {
  Eigen::Vector3d origin;
  Eigen::Vector3d e1, e2, e3;
};

// Signs made deterministic: the normal axis faces the viewpoint (else: positive third
// moment along it), the first axis has a positive third moment (skewness), the second
// completes a right-handed frame.
PatchFrame PrincipalPatchFrame(const std::vector<Eigen::Vector3f>& points,
                               const Eigen::Vector3f* viewpoint) {
  PatchFrame frame;
  Eigen::Matrix3d axes;
  Eigen::Vector3d variances;
  internal::PrincipalAxes(points, &frame.origin, &axes, &variances);
  const Eigen::Vector3d& origin = frame.origin;
  frame.e1 = axes.col(0);
  frame.e3 = axes.col(2);
  const bool flip_normal = viewpoint != nullptr
                               ? (viewpoint->cast<double>() - origin).dot(frame.e3) < 0.0
                               : ThirdMoment(points, origin, frame.e3) < 0.0;
  if (flip_normal) frame.e3 = -frame.e3;
  if (ThirdMoment(points, origin, frame.e1) < 0.0) frame.e1 = -frame.e1;
  frame.e2 = frame.e3.cross(frame.e1);
  return frame;
}

BezierPatch FitBezierPatchImpl(const std::vector<Eigen::Vector3f>& points, int order_u, int order_v,
                               int iterations, const Eigen::Vector3f* viewpoint, double smoothing) {
  CheckBezierFitInputs(points, order_u, order_v, iterations, smoothing);
  const int m = order_u, n = order_v;
  const int num_control = (m + 1) * (n + 1);
  const size_t count = points.size();

  // 1. The plane of the two largest principal axes.
  const PatchFrame frame = PrincipalPatchFrame(points, viewpoint);
  const Eigen::Vector3d& origin = frame.origin;
  const Eigen::Vector3d& e1 = frame.e1;
  const Eigen::Vector3d& e2 = frame.e2;

  Eigen::MatrixX3d target(count, 3);
  Eigen::VectorXd a(count), b(count);
  for (size_t k = 0; k < count; ++k) {
    const Eigen::Vector3d p = points[k].cast<double>();
    target.row(k) = p.transpose();
    a[k] = (p - origin).dot(e1);
    b[k] = (p - origin).dot(e2);
  }
  const double a_min = a.minCoeff(), b_min = b.minCoeff();
  const double a_range = std::max(a.maxCoeff() - a_min, 1e-9);
  const double b_range = std::max(b.maxCoeff() - b_min, 1e-9);

  // Equidistant control points on that plane: the flat patch p(u, v) = origin + (a_min +
  // u·Δa) e1 + (b_min + v·Δb) e2 (linear precision of Bézier surfaces), so the initial
  // foot points are the projections.
  Eigen::MatrixX3d control(num_control, 3);
  for (int i = 0; i <= m; ++i) {
    for (int j = 0; j <= n; ++j) {
      const Eigen::Vector3d k =
          origin + (a_min + a_range * i / m) * e1 + (b_min + b_range * j / n) * e2;
      control.row(i * (n + 1) + j) = k.transpose();
    }
  }
  Eigen::VectorXd u = ((a.array() - a_min) / a_range).matrix();
  Eigen::VectorXd v = ((b.array() - b_min) / b_range).matrix();

  // Smoothness term DᵀD (second differences of the control net along u and along v), per
  // point and per control point, so the balance with the data term does not depend on
  // the number of points or the order.
  const Eigen::MatrixXd smooth =
      SmoothnessMatrix(m, n) * (smoothing * static_cast<double>(count) / num_control);

  // Row-major copy of the control points for the evaluator.
  std::vector<double> control_flat(3 * num_control);
  auto flatten = [&]() {
    for (int c = 0; c < num_control; ++c) {
      for (int a = 0; a < 3; ++a) control_flat[3 * c + a] = control(c, a);
    }
  };
  flatten();
  // Row k: the tensor-product basis B_i(u_k) B_j(v_k) at point k's foot point. The foot-point
  // step leaves it up to date for the next least-squares step.
  Eigen::MatrixXd basis(count, num_control);
  auto set_basis_row = [&](size_t k, const double* bu, const double* bv) {
    for (int i = 0; i <= m; ++i) {
      for (int j = 0; j <= n; ++j) basis(k, i * (n + 1) + j) = bu[i] * bv[j];
    }
  };
  double bu[kMaxBezierOrder + 1], bv[kMaxBezierOrder + 1];
  double sum_sq = 0.0;  // Σ‖p(u_k, v_k) − p_k‖² at the current foot points
  for (size_t k = 0; k < count; ++k) {
    Bernstein(m, u[k], bu, nullptr);
    Bernstein(n, v[k], bv, nullptr);
    set_basis_row(k, bu, bv);
    double s[3];
    EvaluatePatch(control_flat.data(), m, n, bu, bv, s);
    sum_sq += (Eigen::Vector3d(s[0], s[1], s[2]) - target.row(k).transpose()).squaredNorm();
  }

  Eigen::MatrixXd normal_matrix(num_control, num_control);
  for (int iteration = 0; iteration < iterations; ++iteration) {
    // 2. Control points by linear least squares for the current foot points:
    // min Σ_k ‖Σ_ij B_i(u_k) B_j(v_k) k_ij − p_k‖² + smoothness.
    normal_matrix = smooth;
    normal_matrix.selfadjointView<Eigen::Lower>().rankUpdate(basis.transpose());
    const Eigen::MatrixX3d rhs = basis.transpose() * target;
    const Eigen::LDLT<Eigen::MatrixXd> solver(normal_matrix.selfadjointView<Eigen::Lower>());
    const Eigen::MatrixX3d updated = solver.solve(rhs);
    if (solver.info() == Eigen::Success && updated.allFinite()) {
      control = updated;
      flatten();
    }

    // 3. Foot points: one Gauss–Newton step per point from its previous (u, v), clamped to
    // the unit square, kept only when it brings the surface point closer.
    sum_sq = 0.0;
    for (size_t k = 0; k < count; ++k) {
      const double p[3] = {target(k, 0), target(k, 1), target(k, 2)};
      sum_sq += FootPointStep(control_flat.data(), m, n, p, &u[k], &v[k], bu, bv);
      set_basis_row(k, bu, bv);
    }
  }

  BezierPatch result;
  result.order_u = m;
  result.order_v = n;
  result.origin = origin.cast<float>();
  result.axis_u = e1.cast<float>();
  result.axis_v = e2.cast<float>();
  result.control.resize(num_control);
  for (int c = 0; c < num_control; ++c)
    result.control[c] = control.row(c).transpose().cast<float>();
  result.rms_residual = std::sqrt(sum_sq / static_cast<double>(count));
  return result;
}

struct KdeBlock {
  const char* name;
  float lo, hi;
};

// Per-point primitive features of a normalised view (thesis §2.2.2.1).
struct PrimitiveFeatures {
  std::vector<float> radial;     // R = ‖p‖
  std::vector<float> alignment;  // A = |⟨R̂, N̂⟩|
  std::vector<float> tangent;    // D = R·A
  std::vector<float> radial_dir[3];
  std::vector<float> normal_dir[3];
};

PrimitiveFeatures ComputePrimitives(const PointCloud& normalised) {
  PrimitiveFeatures f;
  const size_t n = normalised.size();
  f.radial.resize(n);
  f.alignment.resize(n);
  f.tangent.resize(n);
  for (int a = 0; a < 3; ++a) {
    f.radial_dir[a].resize(n);
    f.normal_dir[a].resize(n);
  }
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d p = normalised.points[i].cast<double>();
    const Eigen::Vector3d normal = normalised.normals[i].cast<double>().normalized();
    const double r = p.norm();
    const Eigen::Vector3d direction = r > 1e-12 ? Eigen::Vector3d(p / r) : Eigen::Vector3d::Zero();
    const double alignment = std::abs(direction.dot(normal));
    f.radial[i] = static_cast<float>(r);
    f.alignment[i] = static_cast<float>(alignment);
    f.tangent[i] = static_cast<float>(r * alignment);
    for (int a = 0; a < 3; ++a) {
      f.radial_dir[a][i] = static_cast<float>(direction[a]);
      f.normal_dir[a][i] = static_cast<float>(normal[a]);
    }
  }
  return f;
}

float Quantile(std::vector<float>* values, double q) {
  const size_t index =
      std::min(values->size() - 1, static_cast<size_t>(std::llround(q * (values->size() - 1))));
  std::nth_element(values->begin(), values->begin() + index, values->end());
  return (*values)[index];
}

// Curvature per point when the pre-processing did not supply it (hand-made clouds).
std::vector<float> EstimateCurvature(const PointCloud& cloud) {
  constexpr int kNeighbours = 12;
  const internal::NeighbourGrid grid(cloud.points, kNeighbours);
  const internal::NeighbourTable table = grid.AllKNearest(kNeighbours);
  std::vector<float> curvature(cloud.size(), 0.0f);
  for (size_t i = 0; i < cloud.size(); ++i) {
    Eigen::Vector3f normal;
    float c;
    if (internal::FitNormal(cloud.points, table.row(i), table.count, cloud.points[i],
                            Eigen::Vector3f::Zero(), &normal, &c)) {
      curvature[i] = c;
    }
  }
  return curvature;
}

// Median distance to the nearest other point, metres.
double CloudResolution(const std::vector<Eigen::Vector3f>& points) {
  const internal::NeighbourGrid grid(points, 2);
  const internal::NeighbourTable table = grid.AllKNearest(2);
  if (table.count < 2) return 0.0;
  std::vector<float> distances(table.size());
  for (size_t i = 0; i < table.size(); ++i) distances[i] = std::sqrt(table.row_sq_distance(i)[1]);
  return Quantile(&distances, 0.5);
}

Eigen::VectorXf FineHistogram(const PreprocessedCloud& view, FineDescriptor descriptor) {
  using Signature = pcl::VFHSignature308;
  const auto xyz = internal::ToPclXyz(view.cloud);
  pcl::PointCloud<Signature> signatures;
  if (descriptor == FineDescriptor::kVfh) {
    const auto normals = internal::ToPclNormals(view.cloud);
    pcl::VFHEstimation<pcl::PointXYZ, pcl::Normal, Signature> vfh;
    vfh.setInputCloud(xyz);
    vfh.setInputNormals(normals);
    // VFH uses no neighbourhoods; the brute-force "search" avoids building a k-d tree.
    vfh.setSearchMethod(pcl::make_shared<pcl::search::BruteForce<pcl::PointXYZ>>());
    vfh.setViewPoint(0.0f, 0.0f, 0.0f);  // the sensor, camera frame
    // PCL computes the viewpoint direction as the 4-vector (viewpoint − centroid) with the
    // centroid's w = 1 (compute3DCentroid since PCL PR #781) and normalises it in 4-D, which
    // shrinks every cosine by |d| / √(|d|² + 1) (d in metres): at 0.5 m a normal facing the
    // sensor lands in bin 92 of 128 instead of 127, and the histogram depends on the
    // distance. setCentroidToUse stores the centroid with w = 0, which avoids that; the angle
    // features are unaffected (computePairFeatures zeroes w).
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const Eigen::Vector3f& p : view.cloud.points) centroid += p.cast<double>();
    centroid /= static_cast<double>(view.cloud.size());
    vfh.setUseGivenCentroid(true);
    vfh.setCentroidToUse(Eigen::Vector3f(centroid.cast<float>()));
    vfh.setNormalizeBins(true);
    vfh.compute(signatures);
  } else {
    const std::vector<float> curvature =
        view.curvature.size() == view.cloud.size() ? view.curvature : EstimateCurvature(view.cloud);
    const auto normals = internal::ToPclNormals(view.cloud, curvature);
    // PCL's defaults are tuned for a 5 mm voxel grid (tolerances 3 leaves); scale them to
    // this cloud's sampling.
    const float leaf = static_cast<float>(std::max(CloudResolution(view.cloud.points), 1e-4));
    const float tolerance = 3.0f * leaf;
    const auto tree = pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>(false);
    if (descriptor == FineDescriptor::kCvfh) {
      pcl::CVFHEstimation<pcl::PointXYZ, pcl::Normal, Signature> cvfh;
      cvfh.setInputCloud(xyz);
      cvfh.setInputNormals(normals);
      cvfh.setSearchMethod(tree);
      cvfh.setViewPoint(0.0f, 0.0f, 0.0f);
      cvfh.setClusterTolerance(tolerance);
      cvfh.setRadiusNormals(tolerance);
      cvfh.setNormalizeBins(true);
      cvfh.compute(signatures);
    } else {
      pcl::OURCVFHEstimation<pcl::PointXYZ, pcl::Normal, Signature> ourcvfh;
      ourcvfh.setInputCloud(xyz);
      ourcvfh.setInputNormals(normals);
      ourcvfh.setSearchMethod(tree);
      ourcvfh.setViewPoint(0.0f, 0.0f, 0.0f);
      ourcvfh.setClusterTolerance(tolerance);
      ourcvfh.setRadiusNormals(tolerance);
      ourcvfh.setNormalizeBins(true);
      ourcvfh.compute(signatures);
    }
  }
  SOPE_CHECK(!signatures.empty(), "ComputeFeatures: PCL {} produced no histogram for {} points",
             ToString(descriptor), view.cloud.size());
  Eigen::VectorXf histogram(kVfhBins);
  for (int b = 0; b < kVfhBins; ++b) histogram[b] = signatures[0].histogram[b];
  return histogram;
}

}  // namespace

// ---------------------------------------------------------------------------------------
// Enums and options

std::string ToString(FineDescriptor descriptor) { return EnumToString(descriptor); }

FineDescriptor FineDescriptorFromString(const std::string& text) {
  return EnumFromString<FineDescriptor>(text);
}

void FeatureOptions::Check() const {
  SOPE_CHECK(std::isfinite(kde_bandwidth) && kde_bandwidth > 0.0,
             "FeatureOptions: kde_bandwidth must be > 0, got {}", kde_bandwidth);
  SOPE_CHECK(kde_samples >= 2 && kde_samples <= kMaxKdeSamples,
             "FeatureOptions: kde_samples must be in [2, {}], got {}", kMaxKdeSamples, kde_samples);
  const bool patch = bezier_order_u != 0 || bezier_order_v != 0;
  SOPE_CHECK(!patch || (bezier_order_u >= 1 && bezier_order_u <= kMaxBezierOrder &&
                        bezier_order_v >= 1 && bezier_order_v <= kMaxBezierOrder),
             "FeatureOptions: Bézier orders must both be 0 (no patch) or both in [1, {}], got "
             "({}, {})",
             kMaxBezierOrder, bezier_order_u, bezier_order_v);
  SOPE_CHECK(std::isfinite(bezier_smoothing) && bezier_smoothing >= 0.0,
             "FeatureOptions: bezier_smoothing must be ≥ 0, got {}", bezier_smoothing);
  SOPE_CHECK(bezier_iterations >= 0 && bezier_iterations <= 1000,
             "FeatureOptions: bezier_iterations must be in [0, 1000], got {}", bezier_iterations);
  SOPE_CHECK(fine == FineDescriptor::kVfh || fine == FineDescriptor::kCvfh ||
                 fine == FineDescriptor::kOurCvfh,
             "FeatureOptions: unknown fine descriptor {}", static_cast<int>(fine));
}

FeatureOptions FeatureOptions::ThesisPreset() {
  FeatureOptions options;
  options.kde_bandwidth = 0.35355339059327373;  // 1 / (2√2)
  options.direction_components_xyz = true;
  options.bezier_order_u = 3;
  options.bezier_order_v = 3;
  options.metric_size = false;
  options.fine = FineDescriptor::kVfh;
  return options;
}

// ---------------------------------------------------------------------------------------
// Layout

namespace {

std::vector<KdeBlock> KdeBlocks(const FeatureOptions& options) {
  std::vector<KdeBlock> blocks = {
      {"kde_R", 0.0f, 1.0f}, {"kde_A", 0.0f, 1.0f}, {"kde_D", 0.0f, 1.0f}};
  if (options.direction_components_xyz) {
    for (const char* name : {"kde_Rx", "kde_Ry", "kde_Rz", "kde_Nx", "kde_Ny", "kde_Nz"}) {
      blocks.push_back({name, -1.0f, 1.0f});
    }
  } else {
    blocks.push_back({"kde_Rz", -1.0f, 1.0f});
    blocks.push_back({"kde_Nz", -1.0f, 1.0f});
  }
  return blocks;
}

bool HasPatch(const FeatureOptions& options) {
  return options.bezier_order_u > 0 && options.bezier_order_v > 0;
}

}  // namespace

std::vector<std::pair<std::string, int>> CoarseLayout(const FeatureOptions& options) {
  options.Check();
  std::vector<std::pair<std::string, int>> layout;
  for (const KdeBlock& block : KdeBlocks(options))
    layout.emplace_back(block.name, options.kde_samples);
  if (HasPatch(options)) {
    layout.emplace_back("bezier", 3 * (options.bezier_order_u + 1) * (options.bezier_order_v + 1));
    layout.emplace_back("bezier_axes", options.direction_components_xyz ? 6 : 2);
  }
  if (options.metric_size) layout.emplace_back("size", 4);
  return layout;
}

int CoarseDimension(const FeatureOptions& options) {
  int dimension = 0;
  for (const auto& block : CoarseLayout(options)) dimension += block.second;
  return dimension;
}

int FineDimension(const FeatureOptions& options) {
  options.Check();
  return kVfhBins;
}

// ---------------------------------------------------------------------------------------
// Building blocks

Eigen::VectorXf KernelDensity(const std::vector<float>& values, float lo, float hi, int samples,
                              float bandwidth) {
  SOPE_CHECK(std::isfinite(lo) && std::isfinite(hi) && hi > lo,
             "KernelDensity: need finite lo < hi, got [{}, {}]", lo, hi);
  SOPE_CHECK(samples >= 2 && samples <= kMaxKdeSamples,
             "KernelDensity: samples must be in [2, {}], got {}", kMaxKdeSamples, samples);
  SOPE_CHECK(std::isfinite(bandwidth) && bandwidth > 0.0f,
             "KernelDensity: bandwidth must be > 0, got {}", bandwidth);
  SOPE_CHECK(!values.empty(), "KernelDensity: no values");
  for (float value : values) {
    SOPE_CHECK(std::isfinite(value), "KernelDensity: non-finite value {}", value);
  }
  const double h = bandwidth;
  const double step = (static_cast<double>(hi) - lo) / (samples - 1);
  const float scale = static_cast<float>(-0.5 / (h * h));
  Eigen::VectorXf density(samples);

  // Linear binning (Wand & Jones 1995, §D.2) onto a grid of width h/32 over the kernel's
  // reach of [lo, hi]; exact Gaussian sums when that is cheaper (few values).
  const double grid_lo = lo - kKdeSupport * h;
  const double grid_hi = hi + kKdeSupport * h;
  const double bin = h / kKdeBinsPerBandwidth;
  const int64_t bins = static_cast<int64_t>(std::ceil((grid_hi - grid_lo) / bin)) + 1;
  const bool binned = static_cast<int64_t>(values.size()) * samples >
                      static_cast<int64_t>(values.size()) + bins * samples;
  Eigen::ArrayXf centres, weights;
  if (binned) {
    Eigen::ArrayXd accumulated = Eigen::ArrayXd::Zero(bins);
    for (float value : values) {
      const double t = (value - grid_lo) / bin;
      if (t < 0.0 || t > static_cast<double>(bins - 1)) continue;  // beyond kKdeSupport·h
      const int64_t left = std::min<int64_t>(static_cast<int64_t>(t), bins - 2);
      const double frac = t - left;
      accumulated[left] += 1.0 - frac;
      accumulated[left + 1] += frac;
    }
    centres.resize(bins);
    for (int64_t b = 0; b < bins; ++b) centres[b] = static_cast<float>(grid_lo + b * bin);
    weights = accumulated.cast<float>();
  } else {
    centres =
        Eigen::Map<const Eigen::ArrayXf>(values.data(), static_cast<Eigen::Index>(values.size()));
  }
  for (int s = 0; s < samples; ++s) {
    const float x = static_cast<float>(lo + s * step);
    const Eigen::ArrayXf kernel = ((centres - x).square() * scale).exp();
    density[s] = binned ? (kernel * weights).sum() : kernel.sum();
  }
  const float total = density.sum();
  if (total > 0.0f && std::isfinite(total)) {
    density /= total;
  } else {
    density.setZero();
  }
  return density;
}

BezierPatch FitBezierPatch(const std::vector<Eigen::Vector3f>& points, int order_u, int order_v,
                           int iterations) {
  return FitBezierPatchImpl(points, order_u, order_v, iterations, nullptr, kDefaultBezierSmoothing);
}

BezierPatch FitBezierPatch(const std::vector<Eigen::Vector3f>& points, int order_u, int order_v,
                           int iterations, const Eigen::Vector3f& viewpoint, double smoothing) {
  return FitBezierPatchImpl(points, order_u, order_v, iterations, &viewpoint, smoothing);
}

Eigen::Vector3f EvaluateBezier(const BezierPatch& patch, float u, float v) {
  const int m = patch.order_u, n = patch.order_v;
  SOPE_CHECK(m >= 0 && m <= kMaxBezierOrder && n >= 0 && n <= kMaxBezierOrder &&
                 patch.control.size() == static_cast<size_t>((m + 1) * (n + 1)),
             "EvaluateBezier: order ({}, {}) does not match {} control points", m, n,
             patch.control.size());
  double bu[kMaxBezierOrder + 1], bv[kMaxBezierOrder + 1];
  Bernstein(m, u, bu, nullptr);
  Bernstein(n, v, bv, nullptr);
  Eigen::Vector3d s = Eigen::Vector3d::Zero();
  for (int i = 0; i <= m; ++i) {
    for (int j = 0; j <= n; ++j) s += bu[i] * bv[j] * patch.control[i * (n + 1) + j].cast<double>();
  }
  return s.cast<float>();
}

// ---------------------------------------------------------------------------------------
// Features of a view

namespace {

// The Bézier patch block (thesis §4.3.2): control points in the patch's own right-handed
// frame (e1, e2, e1 × e2 — roll-invariant), then the spanning vectors.
void AppendPatchBlock(const PreprocessedCloud& view, const FeatureOptions& options,
                      std::vector<float>* coarse) {
  const PointCloud& normalised = view.normalised;
  const size_t n = normalised.size();
  const int m = options.bezier_order_u, n_order = options.bezier_order_v;
  std::vector<Eigen::Vector3f> subsample;
  const std::vector<Eigen::Vector3f>* fit_points = &normalised.points;
  if (n > kBezierMaxPoints) {
    subsample.reserve(kBezierMaxPoints);
    for (size_t k = 0; k < kBezierMaxPoints; ++k) {
      subsample.push_back(normalised.points[(k * n) / kBezierMaxPoints]);
    }
    fit_points = &subsample;
  }
  const Eigen::Vector3f sensor = -view.centroid / view.radius;  // normalised frame
  const BezierPatch patch = FitBezierPatch(*fit_points, m, n_order, options.bezier_iterations,
                                           sensor, options.bezier_smoothing);
  Eigen::Matrix3f frame;
  frame.col(0) = patch.axis_u;
  frame.col(1) = patch.axis_v;
  frame.col(2) = patch.axis_u.cross(patch.axis_v);
  const int num_control = static_cast<int>(patch.control.size());
  std::vector<Eigen::Vector3f> local(num_control);
  for (int c = 0; c < num_control; ++c)
    local[c] = frame.transpose() * (patch.control[c] - patch.origin);
  // The sign of e1 (and with it e2) is fixed by the skewness along e1, which is ill-defined
  // for nearly symmetric views; the opposite choice gives the net turned by 180° about
  // e1 × e2: k_ij → k_(m−i)(n−j), (a, b, h) → (−a, −b, h). Split the net into the parts
  // symmetric and antisymmetric under that turn and weight the antisymmetric part by
  // tanh(skewness / 0.1): the block is then continuous where the sign choice flips.
  double m2 = 0.0, m3 = 0.0;
  for (const Eigen::Vector3f& p : *fit_points) {
    const double t = (p - patch.origin).dot(patch.axis_u);
    m2 += t * t;
    m3 += t * t * t;
  }
  const double count = static_cast<double>(fit_points->size());
  m2 /= count;
  m3 /= count;
  const double skewness = m2 > 0.0 ? m3 / std::pow(m2, 1.5) : 0.0;
  const float weight = static_cast<float>(std::tanh(std::abs(skewness) / kSkewnessScale));
  for (int i = 0; i <= m; ++i) {
    for (int j = 0; j <= n_order; ++j) {
      const Eigen::Vector3f& k = local[i * (n_order + 1) + j];
      const Eigen::Vector3f& o = local[(m - i) * (n_order + 1) + (n_order - j)];
      const Eigen::Vector3f turned(-o.x(), -o.y(), o.z());
      const Eigen::Vector3f value = 0.5f * (k + turned) + weight * 0.5f * (k - turned);
      coarse->insert(coarse->end(), value.data(), value.data() + 3);
    }
  }
  // Spanning vectors in camera axes: with direction_components_xyz as the thesis has them
  // (signs as chosen above); otherwise only |z| of each — roll-invariant, and invariant to
  // the sign ambiguity of a principal axis.
  if (options.direction_components_xyz) {
    coarse->insert(coarse->end(), patch.axis_u.data(), patch.axis_u.data() + 3);
    coarse->insert(coarse->end(), patch.axis_v.data(), patch.axis_v.data() + 3);
  } else {
    coarse->push_back(std::abs(patch.axis_u.z()));
    coarse->push_back(std::abs(patch.axis_v.z()));
  }
}

// The metric size block (sope): log radius, then the robust extents along the principal
// axes, metres.
void AppendMetricSizeBlock(const PreprocessedCloud& view, std::vector<float>* coarse) {
  const PointCloud& normalised = view.normalised;
  const size_t n = normalised.size();
  Eigen::Vector3d centroid, variances;
  Eigen::Matrix3d axes;
  internal::PrincipalAxes(normalised.points, &centroid, &axes, &variances);
  float extents[3];
  std::vector<float> projection(n);
  for (int a = 0; a < 3; ++a) {
    for (size_t i = 0; i < n; ++i) {
      projection[i] =
          static_cast<float>((normalised.points[i].cast<double>() - centroid).dot(axes.col(a)));
    }
    const float low = Quantile(&projection, kExtentQuantile);
    const float high = Quantile(&projection, 1.0 - kExtentQuantile);
    extents[a] = (high - low) * view.radius;
  }
  std::sort(extents, extents + 3, std::greater<float>());
  coarse->push_back(std::log(view.radius));
  coarse->insert(coarse->end(), extents, extents + 3);
}

}  // namespace

ViewFeatures ComputeFeatures(const PreprocessedCloud& view, const FeatureOptions& options) {
  options.Check();
  const PointCloud& normalised = view.normalised;
  const size_t n = normalised.size();
  SOPE_CHECK(n >= static_cast<size_t>(kMinFeaturePoints),
             "ComputeFeatures: need at least {} points, got {}", kMinFeaturePoints, n);
  SOPE_CHECK(normalised.normals.size() == n,
             "ComputeFeatures: the cloud has {} points but {} normals (run Preprocess)", n,
             normalised.normals.size());
  SOPE_CHECK(view.cloud.size() == n && view.cloud.normals.size() == n,
             "ComputeFeatures: the metric cloud ({} points, {} normals) does not match the "
             "normalised one ({} points)",
             view.cloud.size(), view.cloud.normals.size(), n);
  SOPE_CHECK(std::isfinite(view.radius) && view.radius > 0.0f,
             "ComputeFeatures: normalisation radius must be > 0 metres, got {}", view.radius);
  for (size_t i = 0; i < n; ++i) {
    SOPE_CHECK(IsFinite(normalised.points[i]) && IsFinite(view.cloud.points[i]),
               "ComputeFeatures: point {} is not finite", i);
    SOPE_CHECK(IsFinite(normalised.normals[i]) && normalised.normals[i].squaredNorm() > 0.25f &&
                   IsFinite(view.cloud.normals[i]),
               "ComputeFeatures: normal {} is missing or not a unit vector", i);
  }

  std::vector<float> coarse;
  coarse.reserve(256);
  const float bandwidth = static_cast<float>(options.kde_bandwidth);
  auto append_kde = [&](const std::vector<float>& values, const KdeBlock& block) {
    const Eigen::VectorXf density =
        KernelDensity(values, block.lo, block.hi, options.kde_samples, bandwidth);
    coarse.insert(coarse.end(), density.data(), density.data() + density.size());
  };

  // Shape distributions (thesis §4.3.1).
  const PrimitiveFeatures primitives = ComputePrimitives(normalised);
  for (const KdeBlock& block : KdeBlocks(options)) {
    const std::string name = block.name;
    const std::vector<float>* values = nullptr;
    if (name == "kde_R") values = &primitives.radial;
    if (name == "kde_A") values = &primitives.alignment;
    if (name == "kde_D") values = &primitives.tangent;
    for (int a = 0; a < 3; ++a) {
      if (name == std::string("kde_R") + "xyz"[a]) values = &primitives.radial_dir[a];
      if (name == std::string("kde_N") + "xyz"[a]) values = &primitives.normal_dir[a];
    }
    assert(values != nullptr);
    append_kde(*values, block);
  }

  // Bézier patch (thesis §4.3.2) and metric size (sope).
  if (HasPatch(options)) AppendPatchBlock(view, options, &coarse);
  if (options.metric_size) AppendMetricSizeBlock(view, &coarse);

  ViewFeatures features;
  features.coarse =
      Eigen::Map<const Eigen::VectorXf>(coarse.data(), static_cast<Eigen::Index>(coarse.size()));
  assert(features.coarse.size() == CoarseDimension(options));
  features.fine = FineHistogram(view, options.fine);
  return features;
}

}  // namespace sope
