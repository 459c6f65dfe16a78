#include "recogniser/pose.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#if defined(__AVX512F__)
#include <immintrin.h>
#endif

#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include "core/error.h"
#include "core/units.h"

namespace sope {
namespace {

// Grids larger than this many cells get coarser cells (a query spanning the whole image).
constexpr int64_t kMaxGridCells = 1 << 22;

// atan2 to ~1e-3 rad (a 7th-order minimax polynomial on [0, 1] and octant folding): the
// signatures bin angles by several degrees.
inline float FastAtan2(float y, float x) {
  const float ax = std::abs(x), ay = std::abs(y);
  const float mx = std::max(ax, ay), mn = std::min(ax, ay);
  if (mx == 0.0f) return 0.0f;
  const float a = mn / mx;
  const float s = a * a;
  float r = ((-0.0464964749f * s + 0.15931422f) * s - 0.327622764f) * s * a + a;
  if (ay > ax) r = 1.57079637f - r;
  if (x < 0.0f) r = static_cast<float>(kPi) - r;
  return y < 0.0f ? -r : r;
}

int PositiveModulo(int value, int modulus) {
  const int r = value % modulus;
  return r < 0 ? r + modulus : r;
}

}  // namespace

Eigen::Matrix3d CamFromCanonical(const Eigen::Vector3d& direction) {
  SOPE_CHECK(direction.allFinite() && direction.norm() > 0.0,
             "CamFromCanonical: direction must be finite and non-zero");
  return Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), direction.normalized())
      .toRotationMatrix();
}

const std::vector<OptionField<PoseOptions>>& PoseOptions::Fields() {
  using O = PoseOptions;
  static const std::vector<OptionField<O>> fields = {
      Field(&O::angle_bins, "angle_bins", "Polar signature angle bins").In(8, 720),
      Field(&O::roll_hypotheses, "roll_hypotheses", "Roll hypotheses per view (≤ angle_bins/2)")
          .AtLeast(1),
      Field(&O::max_iterations, "max_iterations", "ICP iterations").AtLeast(0),
      Field(&O::initial_gate_fraction, "initial_gate_fraction",
            "Initial correspondence gate, fraction of the query radius")
          .AtLeast(0.0),
      Field(&O::final_gate, "final_gate", "Final correspondence gate").Unit("m").Above(0.0),
      Field(&O::gate_iterations, "gate_iterations", "Iterations to shrink the gate").AtLeast(1),
      Field(&O::initial_window, "initial_window", "Initial projective search window, cells")
          .AtLeast(0),
      Field(&O::final_window, "final_window", "Final projective search window, cells")
          .AtLeast(0),
      Field(&O::normal_min_cos, "normal_min_cos", "Normal agreement of correspondences, cosine")
          .In(-1.0, 1.0),
      Field(&O::point_to_point_weight, "point_to_point_weight",
            "Weight of the point-to-point term")
          .AtLeast(0.0),
      Field(&O::min_rotation_step, "min_rotation_step", "ICP stops below this rotation step")
          .Unit("rad")
          .AtLeast(0.0),
      Field(&O::min_translation_step, "min_translation_step",
            "ICP stops below this translation step")
          .Unit("m")
          .AtLeast(0.0),
      Field(&O::inlier_distance, "inlier_distance", "Verification inlier distance")
          .Unit("m")
          .Above(0.0),
      Field(&O::coverage_lateral_factor, "coverage_lateral_factor",
            "Lateral coverage tolerance, view cloud spacings")
          .Above(0.0),
      Field(&O::empty_weight, "empty_weight",
            "Verification: weight of model points with no query point on their ray")
          .AtLeast(0.0)
          .Flag("--empty-weight"),
      Field(&O::violation_weight, "violation_weight", "Verification: free-space violation weight")
          .AtLeast(0.0),
      Field(&O::coverage_samples, "coverage_samples", "Query points sampled for coverage")
          .AtLeast(1),
      Field(&O::coverage_grazing_cos, "coverage_grazing_cos",
            "Coverage weight cosine of grazing faces (0: all count fully)")
          .In(0.0, 1.0)};
  return fields;
}

void PoseOptions::Check() const {
  SOPE_CHECK(final_gate > 0.0 && initial_gate_fraction >= 0.0,
             "pose: final_gate must be > 0 m and initial_gate_fraction ≥ 0, got {} and {}",
             final_gate, initial_gate_fraction);
  CheckFields(*this, Fields(), "pose: ");
  for (size_t i = 0; i < ring_edges.size(); ++i) {
    SOPE_CHECK(ring_edges[i] > 0.0f && (i == 0 || ring_edges[i] > ring_edges[i - 1]),
               "pose: ring_edges must be positive and increasing, got ring_edges[{}] = {}", i,
               ring_edges[i]);
  }
  SOPE_CHECK(roll_hypotheses <= angle_bins / 2,
             "pose: roll_hypotheses must be in [1, angle_bins/2], got {}", roll_hypotheses);
  SOPE_CHECK(initial_window >= final_window,
             "pose: need 0 ≤ final_window ≤ initial_window, got final_window {} and "
             "initial_window {}",
             final_window, initial_window);
}

// ---- ProjectiveGrid ------------------------------------------------------------------------

ProjectiveGrid::ProjectiveGrid(const std::vector<Eigen::Vector3f>& points,
                               const std::vector<Eigen::Vector3f>& normals, float cell)
    : points_(points), normals_(normals) {
  SOPE_CHECK(cell > 0.0f && std::isfinite(cell), "ProjectiveGrid: cell must be > 0, got {}", cell);
  SOPE_CHECK(normals.empty() || normals.size() == points.size(),
             "ProjectiveGrid: {} normals for {} points", normals.size(), points.size());
  float u_min = std::numeric_limits<float>::max(), v_min = u_min;
  float u_max = -u_min, v_max = -u_min;
  std::vector<int> valid;
  valid.reserve(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points[i];
    if (!(p.z() > 0.0f) || !p.allFinite()) continue;
    const float u = p.x() / p.z(), v = p.y() / p.z();
    u_min = std::min(u_min, u);
    u_max = std::max(u_max, u);
    v_min = std::min(v_min, v);
    v_max = std::max(v_max, v);
    valid.push_back(static_cast<int>(i));
  }
  if (valid.empty()) return;
  cell_ = cell;
  while (true) {
    width_ = static_cast<int>(std::floor((u_max - u_min) / cell_)) + 1;
    height_ = static_cast<int>(std::floor((v_max - v_min) / cell_)) + 1;
    if (static_cast<int64_t>(width_) * height_ <= kMaxGridCells) break;
    cell_ *= 2.0f;
  }
  inv_cell_ = 1.0f / cell_;
  u0_ = u_min;
  v0_ = v_min;
  std::vector<int> cell_of(valid.size());
  cell_start_.assign(static_cast<size_t>(width_) * height_ + 1, 0);
  for (size_t k = 0; k < valid.size(); ++k) {
    int cx, cy;
    CellOf(points[valid[k]], &cx, &cy);
    cx = std::clamp(cx, 0, width_ - 1);
    cy = std::clamp(cy, 0, height_ - 1);
    cell_of[k] = cy * width_ + cx;
    ++cell_start_[cell_of[k] + 1];
  }
  std::partial_sum(cell_start_.begin(), cell_start_.end(), cell_start_.begin());
  std::vector<int> fill(cell_start_.begin(), cell_start_.end() - 1);
  const size_t slots = valid.size();
  order_.resize(slots);
  for (std::vector<float>* v : {&x_, &y_, &z_, &nx_, &ny_, &nz_}) v->assign(slots, 0.0f);
  for (size_t k = 0; k < slots; ++k) {
    const int slot = fill[cell_of[k]]++;
    const int i = valid[k];
    order_[slot] = i;
    const Eigen::Vector3f& p = points[i];
    x_[slot] = p.x();
    y_[slot] = p.y();
    z_[slot] = p.z();
    if (!normals.empty()) {
      nx_[slot] = normals[i].x();
      ny_[slot] = normals[i].y();
      nz_[slot] = normals[i].z();
    }
  }
}

bool ProjectiveGrid::CellOf(const Eigen::Vector3f& point, int* cx, int* cy) const {
  if (!(point.z() > 0.0f)) return false;
  const float inv_z = 1.0f / point.z();
  *cx = static_cast<int>(std::floor((point.x() * inv_z - u0_) * inv_cell_));
  *cy = static_cast<int>(std::floor((point.y() * inv_z - v0_) * inv_cell_));
  return true;
}

int ProjectiveGrid::Nearest(const Eigen::Vector3f& point, const Eigen::Vector3f& normal,
                            float min_cos, int window, float max_distance2,
                            float* distance2) const {
  if (x_.empty()) return -1;
  int cx, cy;
  if (!CellOf(point, &cx, &cy)) return -1;
  const int x0 = std::max(cx - window, 0), x1 = std::min(cx + window, width_ - 1);
  const int y0 = std::max(cy - window, 0), y1 = std::min(cy + window, height_ - 1);
  if (x0 > x1 || y0 > y1) return -1;
  const bool test_normal = has_normals() && normal.squaredNorm() > 0.0f;
  const float px = point.x(), py = point.y(), pz = point.z();
  const float qx = normal.x(), qy = normal.y(), qz = normal.z();
  float best = max_distance2;
  int best_slot = -1;
  for (int y = y0; y <= y1; ++y) {
    const int row = y * width_;
    const int begin = cell_start_[row + x0], end = cell_start_[row + x1 + 1];
#if defined(__AVX512F__)
    // 16 slots per step: squared distances, normal test and the running minimum in masks.
    const __m512 vpx = _mm512_set1_ps(px), vpy = _mm512_set1_ps(py), vpz = _mm512_set1_ps(pz);
    for (int slot = begin; slot < end; slot += 16) {
      const int count = std::min(16, end - slot);
      __mmask16 mask = static_cast<__mmask16>(count == 16 ? 0xFFFFu : (1u << count) - 1u);
      const __m512 dx = _mm512_sub_ps(_mm512_maskz_loadu_ps(mask, &x_[slot]), vpx);
      const __m512 dy = _mm512_sub_ps(_mm512_maskz_loadu_ps(mask, &y_[slot]), vpy);
      const __m512 dz = _mm512_sub_ps(_mm512_maskz_loadu_ps(mask, &z_[slot]), vpz);
      const __m512 d2 =
          _mm512_fmadd_ps(dx, dx, _mm512_fmadd_ps(dy, dy, _mm512_mul_ps(dz, dz)));
      mask &= _mm512_cmp_ps_mask(d2, _mm512_set1_ps(best), _CMP_LT_OQ);
      if (mask == 0) continue;
      if (test_normal) {
        const __m512 dot = _mm512_fmadd_ps(
            _mm512_maskz_loadu_ps(mask, &nx_[slot]), _mm512_set1_ps(qx),
            _mm512_fmadd_ps(_mm512_maskz_loadu_ps(mask, &ny_[slot]), _mm512_set1_ps(qy),
                            _mm512_mul_ps(_mm512_maskz_loadu_ps(mask, &nz_[slot]),
                                          _mm512_set1_ps(qz))));
        mask &= _mm512_cmp_ps_mask(dot, _mm512_set1_ps(min_cos), _CMP_GE_OQ);
        if (mask == 0) continue;
      }
      const __m512 masked = _mm512_mask_blend_ps(mask, _mm512_set1_ps(best), d2);
      const float minimum = _mm512_reduce_min_ps(masked);
      const __mmask16 at = _mm512_mask_cmp_ps_mask(mask, masked, _mm512_set1_ps(minimum), _CMP_EQ_OQ);
      best = minimum;
      best_slot = slot + __builtin_ctz(static_cast<unsigned>(at));
    }
#else
    for (int slot = begin; slot < end; ++slot) {
      const float dx = x_[slot] - px, dy = y_[slot] - py, dz = z_[slot] - pz;
      const float d2 = dx * dx + dy * dy + dz * dz;
      if (d2 >= best) continue;
      if (test_normal && nx_[slot] * qx + ny_[slot] * qy + nz_[slot] * qz < min_cos) continue;
      best = d2;
      best_slot = slot;
    }
#endif
  }
  if (best_slot < 0) return -1;
  if (distance2 != nullptr) *distance2 = best;
  return order_[best_slot];
}

int ProjectiveGrid::AlongRay(const Eigen::Vector3f& point, int window) const {
  if (x_.empty()) return -1;
  int cx, cy;
  if (!CellOf(point, &cx, &cy)) return -1;
  const int x0 = std::max(cx - window, 0), x1 = std::min(cx + window, width_ - 1);
  const int y0 = std::max(cy - window, 0), y1 = std::min(cy + window, height_ - 1);
  if (x0 > x1 || y0 > y1) return -1;
  const float u = point.x() / point.z(), v = point.y() / point.z();
  float best = std::numeric_limits<float>::max();
  int best_slot = -1;
  for (int y = y0; y <= y1; ++y) {
    const int row = y * width_;
    const int begin = cell_start_[row + x0], end = cell_start_[row + x1 + 1];
    for (int slot = begin; slot < end; ++slot) {
      const float inv_z = 1.0f / z_[slot];
      const float du = x_[slot] * inv_z - u, dv = y_[slot] * inv_z - v;
      const float d2 = du * du + dv * dv;
      if (d2 < best) {
        best = d2;
        best_slot = slot;
      }
    }
  }
  return best_slot < 0 ? -1 : order_[best_slot];
}

// ---- query, signatures, roll ----------------------------------------------------------------

std::vector<float> PolarSignature(const std::vector<Eigen::Vector3f>& points,
                                  const std::vector<Eigen::Vector3f>& normals,
                                  float centroid_depth, float radius, const PoseOptions& options) {
  const int bins = options.angle_bins;
  const int rings = static_cast<int>(options.ring_edges.size()) + 1;
  constexpr int kChannels = 3;
  const int rows = kChannels * rings;
  std::vector<float> raw(static_cast<size_t>(rows) * bins, 0.0f);
  const float inv_radius = radius > 0.0f ? 1.0f / radius : 1.0f;
  const float bins_per_radian = static_cast<float>(bins / (2.0 * kPi));
  const bool has_normals = normals.size() == points.size();
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points[i];
    const float rho_m = std::hypot(p.x(), p.y());
    const float rho = rho_m * inv_radius;
    int ring = 0;
    while (ring < rings - 1 && rho >= options.ring_edges[ring]) ++ring;
    float angle = FastAtan2(p.y(), p.x());
    if (angle < 0.0f) angle += static_cast<float>(2.0 * kPi);
    const float position = angle * bins_per_radian;
    const int a0 = static_cast<int>(std::floor(position)) % bins;
    const int a1 = (a0 + 1) % bins;
    const float frac = position - std::floor(position);
    const float depth = (p.z() - centroid_depth) * inv_radius;
    float radial_normal = 0.0f;
    if (has_normals && rho_m > 0.0f) {
      radial_normal = (normals[i].x() * p.x() + normals[i].y() * p.y()) / rho_m;
    }
    const float values[kChannels] = {1.0f, depth, radial_normal};
    for (int c = 0; c < kChannels; ++c) {
      float* row = &raw[static_cast<size_t>(c * rings + ring) * bins];
      row[a0] += (1.0f - frac) * values[c];
      row[a1] += frac * values[c];
    }
  }
  // Circular smoothing [¼ ½ ¼], then zero mean and unit norm per row.
  std::vector<float> signature(raw.size(), 0.0f);
  for (int r = 0; r < rows; ++r) {
    const float* in = &raw[static_cast<size_t>(r) * bins];
    float* out = &signature[static_cast<size_t>(r) * bins];
    double mean = 0.0;
    for (int a = 0; a < bins; ++a) {
      out[a] = 0.25f * in[PositiveModulo(a - 1, bins)] + 0.5f * in[a] +
               0.25f * in[(a + 1) % bins];
      mean += out[a];
    }
    mean /= bins;
    double norm2 = 0.0;
    for (int a = 0; a < bins; ++a) {
      out[a] -= static_cast<float>(mean);
      norm2 += static_cast<double>(out[a]) * out[a];
    }
    const double norm = std::sqrt(norm2);
    const float scale = norm > 1e-6 ? static_cast<float>(1.0 / norm) : 0.0f;
    for (int a = 0; a < bins; ++a) out[a] *= scale;
  }
  return signature;
}

std::vector<RollHypothesis> EstimateRoll(const std::vector<float>& query_signature,
                                         const std::vector<float>& view_signature,
                                         const PoseOptions& options) {
  const int bins = options.angle_bins;
  SOPE_CHECK(query_signature.size() == view_signature.size() &&
                 query_signature.size() % bins == 0 && !query_signature.empty(),
             "EstimateRoll: signatures of {} and {} values for {} bins", query_signature.size(),
             view_signature.size(), bins);
  const int rows = static_cast<int>(query_signature.size()) / bins;
  int valid_rows = 0;
  std::vector<int> active;
  for (int r = 0; r < rows; ++r) {
    float nq = 0.0f, nv = 0.0f;
    for (int a = 0; a < bins; ++a) {
      nq += std::abs(query_signature[r * bins + a]);
      nv += std::abs(view_signature[r * bins + a]);
    }
    if (nq > 0.0f && nv > 0.0f) {
      active.push_back(r);
      ++valid_rows;
    }
  }
  std::vector<double> correlation(bins, 0.0);
  if (valid_rows > 0) {
    // corr(s) = Σ_a q[a]·v[(a − s) mod bins]; with v doubled, v[(a − s) mod bins] =
    // doubled[a − s + bins], a contiguous window for each s.
    std::vector<float> doubled(2 * bins);
    std::vector<float> sums(bins, 0.0f);
    for (int r : active) {
      const float* q = &query_signature[static_cast<size_t>(r) * bins];
      const float* v = &view_signature[static_cast<size_t>(r) * bins];
      std::copy(v, v + bins, doubled.begin());
      std::copy(v, v + bins, doubled.begin() + bins);
      for (int s = 0; s < bins; ++s) {
        const float* window = &doubled[bins - s];
        float sum = 0.0f;
        for (int a = 0; a < bins; ++a) sum += q[a] * window[a];
        sums[s] += sum;
      }
    }
    for (int s = 0; s < bins; ++s) correlation[s] = sums[s] / valid_rows;
  }
  // Local maxima, best first, at least two bins apart.
  std::vector<int> peaks;
  for (int s = 0; s < bins; ++s) {
    const double c = correlation[s];
    if (c >= correlation[PositiveModulo(s - 1, bins)] && c >= correlation[(s + 1) % bins]) {
      peaks.push_back(s);
    }
  }
  if (peaks.empty()) peaks.push_back(0);
  std::sort(peaks.begin(), peaks.end(),
            [&](int a, int b) { return correlation[a] > correlation[b]; });
  std::vector<RollHypothesis> hypotheses;
  std::vector<int> taken;
  for (int s : peaks) {
    if (static_cast<int>(hypotheses.size()) >= options.roll_hypotheses) break;
    bool near = false;
    for (int t : taken) {
      const int d = std::abs(s - t);
      if (std::min(d, bins - d) < 2) near = true;
    }
    if (near) continue;
    taken.push_back(s);
    const double cm = correlation[PositiveModulo(s - 1, bins)], c0 = correlation[s],
                 cp = correlation[(s + 1) % bins];
    const double denominator = cm - 2.0 * c0 + cp;
    const double offset =
        denominator < -1e-12 ? std::clamp(0.5 * (cm - cp) / denominator, -0.5, 0.5) : 0.0;
    RollHypothesis hypothesis;
    hypothesis.roll = (s + offset) * 2.0 * kPi / bins;
    hypothesis.correlation = c0;
    hypotheses.push_back(hypothesis);
  }
  return hypotheses;
}

PoseQuery MakePoseQuery(const PointCloud& cloud_in_cam, const Eigen::Vector3f& centroid_in_cam,
                        float radius, float spacing, const PoseOptions& options) {
  SOPE_CHECK(cloud_in_cam.normals.size() == cloud_in_cam.points.size() && !cloud_in_cam.empty(),
             "MakePoseQuery: the cloud needs points and normals");
  SOPE_CHECK(centroid_in_cam.allFinite() && centroid_in_cam.norm() > 0.0f,
             "MakePoseQuery: invalid centroid");
  SOPE_CHECK(spacing > 0.0f && radius > 0.0f, "MakePoseQuery: spacing and radius must be > 0");
  PoseQuery query;
  query.cam_from_canonical = CamFromCanonical(centroid_in_cam.cast<double>());
  const Eigen::Matrix3f canonical_from_cam = query.cam_from_canonical.transpose().cast<float>();
  query.points.resize(cloud_in_cam.size());
  query.normals.resize(cloud_in_cam.size());
  for (size_t i = 0; i < cloud_in_cam.size(); ++i) {
    query.points[i] = canonical_from_cam * cloud_in_cam.points[i];
    query.normals[i] = canonical_from_cam * cloud_in_cam.normals[i];
  }
  query.centroid_depth = centroid_in_cam.norm();
  query.radius = radius;
  query.spacing = spacing;
  query.grid = ProjectiveGrid(query.points, query.normals, spacing / query.centroid_depth);
  query.signature =
      PolarSignature(query.points, query.normals, query.centroid_depth, radius, options);
  const size_t n = query.points.size();
  const size_t samples = std::min<size_t>(n, options.coverage_samples);
  int bits = 0;
  while ((size_t{1} << bits) < samples) ++bits;
  query.coverage_sample.reserve(samples);
  for (size_t k = 0; k < (size_t{1} << bits); ++k) {
    size_t reversed = 0;
    for (int b = 0; b < bits; ++b) reversed |= ((k >> b) & 1u) << (bits - 1 - b);
    if (reversed < samples) query.coverage_sample.push_back(static_cast<int>(reversed * n / samples));
  }
  return query;
}

std::vector<float> ViewSignature(const Rigid3d& view_cam_from_model,
                                 const Eigen::Vector3f& view_centroid_in_model, float view_radius,
                                 const std::vector<Eigen::Vector3f>& model_points,
                                 const std::vector<Eigen::Vector3f>& model_normals,
                                 const PoseOptions& options,
                                 Rigid3d* canonical_view_from_model_out) {
  const Eigen::Vector3d centroid_in_view_cam =
      view_cam_from_model * view_centroid_in_model.cast<double>();
  const Eigen::Matrix3d view_cam_from_canonical = CamFromCanonical(centroid_in_view_cam);
  const Rigid3d canonical_view_from_model =
      Rigid3d(view_cam_from_canonical.transpose(), Eigen::Vector3d::Zero()) * view_cam_from_model;
  if (canonical_view_from_model_out != nullptr) {
    *canonical_view_from_model_out = canonical_view_from_model;
  }
  const Eigen::Matrix3f rotation = canonical_view_from_model.rotation.cast<float>();
  const Eigen::Vector3f translation = canonical_view_from_model.translation.cast<float>();
  std::vector<Eigen::Vector3f> points(model_points.size()), normals(model_normals.size());
  for (size_t i = 0; i < model_points.size(); ++i) points[i] = rotation * model_points[i] + translation;
  for (size_t i = 0; i < model_normals.size(); ++i) normals[i] = rotation * model_normals[i];
  return PolarSignature(points, normals, static_cast<float>(centroid_in_view_cam.norm()),
                        view_radius, options);
}

std::vector<PoseHypothesis> InitialPoses(const Rigid3d& view_cam_from_model,
                                         const Eigen::Vector3f& view_centroid_in_model,
                                         float view_radius,
                                         const std::vector<Eigen::Vector3f>& model_points,
                                         const std::vector<Eigen::Vector3f>& model_normals,
                                         const PoseQuery& query, const PoseOptions& options) {
  Rigid3d canonical_view_from_model;
  const std::vector<float> signature =
      ViewSignature(view_cam_from_model, view_centroid_in_model, view_radius, model_points,
                    model_normals, options, &canonical_view_from_model);
  std::vector<PoseHypothesis> hypotheses;
  for (const RollHypothesis& roll : EstimateRoll(query.signature, signature, options)) {
    PoseHypothesis hypothesis;
    hypothesis.roll = roll;
    hypothesis.canonical_from_model.rotation =
        Eigen::AngleAxisd(roll.roll, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
        canonical_view_from_model.rotation;
    hypothesis.canonical_from_model.translation =
        Eigen::Vector3d(0.0, 0.0, query.centroid_depth) -
        hypothesis.canonical_from_model.rotation * view_centroid_in_model.cast<double>();
    hypotheses.push_back(hypothesis);
  }
  return hypotheses;
}

// ---- ICP ------------------------------------------------------------------------------------

IcpResult RefinePose(const std::vector<Eigen::Vector3f>& model_points,
                     const std::vector<Eigen::Vector3f>& model_normals, const PoseQuery& query,
                     const Rigid3d& initial, const PoseOptions& options, int iterations,
                     double initial_gate_override) {
  SOPE_CHECK(model_points.size() == model_normals.size(),
             "RefinePose: {} points but {} normals", model_points.size(), model_normals.size());
  if (iterations <= 0) iterations = options.max_iterations;
  IcpResult result;
  result.canonical_from_model = initial;
  const double final_gate = options.final_gate;
  const double initial_gate =
      std::max(final_gate, initial_gate_override > 0.0
                               ? initial_gate_override
                               : options.initial_gate_fraction * query.radius);
  const float min_cos = static_cast<float>(options.normal_min_cos);
  const double lambda = options.point_to_point_weight;
  const size_t n = model_points.size();
  std::vector<Eigen::Vector3f> p(n), np(n);
  std::vector<int> match(n);
  for (int it = 0; it < iterations; ++it) {
    const double progress = std::min(1.0, static_cast<double>(it) / options.gate_iterations);
    const double gate = initial_gate * std::pow(final_gate / initial_gate, progress);
    // Wide projective search only while the gate is wide (a cell is ≈ one point spacing).
    const int window =
        gate > 2.5 * query.spacing ? options.initial_window : options.final_window;
    const float gate2 = static_cast<float>(gate * gate);
    const Eigen::Matrix3f rotation = result.canonical_from_model.rotation.cast<float>();
    const Eigen::Vector3f translation = result.canonical_from_model.translation.cast<float>();
    Eigen::Vector3d center = Eigen::Vector3d::Zero();
    int matched = 0;
    for (size_t i = 0; i < n; ++i) {
      match[i] = -1;
      p[i] = rotation * model_points[i] + translation;
      np[i] = rotation * model_normals[i];
      if (np[i].dot(p[i]) >= 0.0f) continue;  // facing away from the sensor
      float d2;
      const int j = query.grid.Nearest(p[i], np[i], min_cos, window, gate2, &d2);
      if (j < 0) continue;
      match[i] = j;
      center += p[i].cast<double>();
      ++matched;
    }
    result.correspondences = matched;
    result.iterations = it + 1;
    if (matched < 6) break;
    center /= matched;
    const Eigen::Vector3f center_f = center.cast<float>();
    const float sigma2 = static_cast<float>((gate / 3.0) * (gate / 3.0));
    const float lambda_f = static_cast<float>(lambda);
    Eigen::Matrix<float, 6, 6> normal_matrix = Eigen::Matrix<float, 6, 6>::Zero();
    Eigen::Matrix<float, 6, 1> rhs = Eigen::Matrix<float, 6, 1>::Zero();
    // Point-to-point sums: Σw, Σw·pc, Σw·[pc]×ᵀ[pc]× pieces via Σw·pc·pcᵀ, Σw·diff, Σw·pc×diff.
    float sw3 = 0.0f;
    Eigen::Vector3f swp = Eigen::Vector3f::Zero(), swd = Eigen::Vector3f::Zero(),
                    swpxd = Eigen::Vector3f::Zero();
    Eigen::Matrix3f swpp = Eigen::Matrix3f::Zero();
    double sum_r2 = 0.0;
    for (size_t i = 0; i < n; ++i) {
      if (match[i] < 0) continue;
      const Eigen::Vector3f pc = p[i] - center_f;
      const Eigen::Vector3f q = query.points[match[i]] - center_f;
      const Eigen::Vector3f& nq = query.normals[match[i]];
      const Eigen::Vector3f diff = pc - q;
      const float r = diff.dot(nq);
      sum_r2 += static_cast<double>(r) * r;
      const float w = sigma2 / (sigma2 + r * r);
      Eigen::Matrix<float, 6, 1> jacobian;
      jacobian.head<3>() = pc.cross(nq);
      jacobian.tail<3>() = nq;
      normal_matrix.noalias() += (w * jacobian) * jacobian.transpose();
      rhs.noalias() += (w * r) * jacobian;
      if (lambda_f > 0.0f) {
        const float w3 = lambda_f * sigma2 / (sigma2 + diff.squaredNorm());
        sw3 += w3;
        swp += w3 * pc;
        swd += w3 * diff;
        swpxd += w3 * pc.cross(diff);
        swpp.noalias() += (w3 * pc) * pc.transpose();
      }
    }
    if (lambda_f > 0.0f) {
      // Residual diff + ω × pc + τ: J = [−[pc]×, I]. JᵀJ = [[|pc|²I − pc·pcᵀ, [pc]×], [−[pc]×, I]]
      // summed with weights; Jᵀ·diff = [pc × diff, diff].
      const Eigen::Matrix3f rot_rot = swpp.trace() * Eigen::Matrix3f::Identity() - swpp;
      Eigen::Matrix3f cross_p;
      cross_p << 0.0f, -swp.z(), swp.y(), swp.z(), 0.0f, -swp.x(), -swp.y(), swp.x(), 0.0f;
      normal_matrix.topLeftCorner<3, 3>() += rot_rot;
      normal_matrix.topRightCorner<3, 3>() += cross_p;
      normal_matrix.bottomLeftCorner<3, 3>() += cross_p.transpose();
      normal_matrix.bottomRightCorner<3, 3>() += sw3 * Eigen::Matrix3f::Identity();
      rhs.head<3>() += swpxd;
      rhs.tail<3>() += swd;
    }
    result.rms = std::sqrt(sum_r2 / matched);
    Eigen::Matrix<double, 6, 6> normal_matrix_d = normal_matrix.cast<double>();
    normal_matrix_d.diagonal().array() += 1e-12;
    const Eigen::Matrix<double, 6, 1> delta = -normal_matrix_d.ldlt().solve(rhs.cast<double>());
    if (!delta.allFinite()) break;
    const Eigen::Vector3d omega = delta.head<3>(), tau = delta.tail<3>();
    const double angle = omega.norm();
    const Eigen::Matrix3d step =
        angle > 0.0 ? Eigen::AngleAxisd(angle, omega / angle).toRotationMatrix()
                    : Eigen::Matrix3d::Identity();
    Rigid3d& pose = result.canonical_from_model;
    pose.rotation = step * pose.rotation;
    pose.translation = step * (pose.translation - center) + center + tau;
    if (progress >= 1.0 && angle < options.min_rotation_step &&
        tau.norm() < options.min_translation_step) {
      result.converged = true;
      break;
    }
  }
  return result;
}

// ---- verification ---------------------------------------------------------------------------

AlignmentScore ScoreAlignment(const std::vector<Eigen::Vector3f>& model_points,
                              const std::vector<Eigen::Vector3f>& model_normals,
                              float model_spacing, const PoseQuery& query,
                              const Rigid3d& canonical_from_model, const PoseOptions& options,
                              int coverage_samples) {
  AlignmentScore score;
  const Eigen::Matrix3f rotation = canonical_from_model.rotation.cast<float>();
  const Eigen::Vector3f translation = canonical_from_model.translation.cast<float>();
  const float inlier = static_cast<float>(options.inlier_distance);
  const float min_cos = static_cast<float>(options.normal_min_cos);
  std::vector<Eigen::Vector3f> visible_points, visible_normals;
  visible_points.reserve(model_points.size());
  visible_normals.reserve(model_points.size());
  double sum_d2 = 0.0;
  for (size_t i = 0; i < model_points.size(); ++i) {
    const Eigen::Vector3f p = rotation * model_points[i] + translation;
    const Eigen::Vector3f n = rotation * model_normals[i];
    if (n.dot(p) >= 0.0f) continue;
    ++score.visible;
    visible_points.push_back(p);
    visible_normals.push_back(n);
    float d2;
    if (query.grid.Nearest(p, n, min_cos, 1, inlier * inlier, &d2) >= 0) {
      ++score.fitting;
      sum_d2 += d2;
      continue;
    }
    const int k = query.grid.AlongRay(p, 1);
    if (k < 0) {
      ++score.empty;
      continue;
    }
    const float query_range = query.grid.point(k).norm(), model_range = p.norm();
    if (query_range > model_range + inlier) {
      ++score.violations;
    } else if (query_range < model_range - inlier) {
      ++score.occluded;
    } else {
      ++score.empty;  // at the right depth but not a fit (normal or lateral offset)
    }
  }
  const double denominator = score.fitting + options.violation_weight * score.violations +
                             options.empty_weight * score.empty;
  score.model_fit = denominator > 0.0 ? score.fitting / denominator : 0.0;
  score.rms = score.fitting > 0 ? std::sqrt(sum_d2 / score.fitting) : 0.0;
  if (visible_points.empty() || query.coverage_sample.empty()) return score;

  // Query points explained by the model: a model point within `inlier` of the query
  // point's tangent plane and within the lateral reach of the model's sampling.
  const float lateral = static_cast<float>(options.coverage_lateral_factor) *
                        std::max(model_spacing, query.spacing);
  const ProjectiveGrid model_grid(visible_points, visible_normals,
                                  std::max(model_spacing, query.spacing) / query.centroid_depth);
  const float reach2 = lateral * lateral + inlier * inlier;
  const int window = std::max(
      1, static_cast<int>(std::ceil(lateral / std::max(model_spacing, query.spacing))));
  // Query points on surfaces seen nearly edge-on count less: weight min(1, cos(incidence)
  // / coverage_grazing_cos). The database view nearest to the pose is up to about half
  // the grid spacing away, so a face within ~the grid spacing of edge-on in the query may
  // be back-facing in that view and missing from its cloud; yet the voxel grid keeps as
  // many points of such a face as of a frontal one of the same area. Counted in full, it
  // cost the right box up to a fifth of its coverage and let a larger wrong model that
  // happens to reach it win.
  double covered = 0.0, total = 0.0;
  const size_t samples =
      coverage_samples > 0
          ? std::min(query.coverage_sample.size(), static_cast<size_t>(coverage_samples))
          : query.coverage_sample.size();
  for (size_t k = 0; k < samples; ++k) {
    const int index = query.coverage_sample[k];
    const Eigen::Vector3f& q = query.points[index];
    const float q_norm = q.norm();
    const double incidence_cos =
        q_norm > 0.0f ? std::abs(query.normals[index].dot(q)) / q_norm : 1.0;
    const double weight = options.coverage_grazing_cos > 0.0
                              ? std::min(1.0, incidence_cos / options.coverage_grazing_cos)
                              : 1.0;
    total += weight;
    float d2;
    const int j = model_grid.Nearest(q, query.normals[index], min_cos, window, reach2, &d2);
    if (j < 0) continue;
    if (std::abs((q - visible_points[j]).dot(visible_normals[j])) < inlier) covered += weight;
  }
  score.query_coverage = total > 0.0 ? covered / total : 0.0;
  score.score = score.model_fit * score.query_coverage;
  return score;
}

}  // namespace sope
