// Internal to recogniser/: the point-cloud kernels behind Preprocess() — voxel-grid
// thinning, exact k-nearest neighbours, statistical outlier removal and plane-fit normals.
//
// They reproduce the semantics of PCL's VoxelGrid, StatisticalOutlierRemoval and
// NormalEstimation (k neighbours) — preprocess_test.cc checks each against PCL on the same
// input — but run several times faster: PCL's FLANN k-d tree spent 1–2 µs per k-NN query
// (≈ 4 ms for SOR and again for the normals on a 4k-point thinned view, measured on the
// 2-core dev machine), which alone broke the 20 ms per-query budget of the recogniser. The
// neighbour search here is a hashed uniform grid sized to the cloud: queries are answered
// cell by cell from the 27 surrounding cells, with an exact shell-expansion fallback, so
// results are exact (ties broken by point index) and deterministic.
#pragma once

#include <cmath>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace sope {
namespace internal {

// All three coordinates finite.
inline bool IsFinitePoint(const Eigen::Vector3f& p) {
  return std::isfinite(p.x()) && std::isfinite(p.y()) && std::isfinite(p.z());
}

// A range band by squared distance from the origin, in double: min_sq ≤ ‖p‖² ≤ max_sq.
struct SquaredRangeBand {
  double min_sq = 0.0, max_sq = 0.0;
  bool Contains(const Eigen::Vector3f& p) const {
    const double sq = p.cast<double>().squaredNorm();
    return sq >= min_sq && sq <= max_sq;
  }
};

// Voxel-grid thinning as pcl::VoxelGrid (centroid per occupied voxel): voxel of p is
// floor(p · (1/leaf)) per axis (float arithmetic, as PCL), output ordered as PCL orders it
// (by z, then y, then x voxel index), centroids accumulated in double. `leaf` > 0 metres;
// coordinates must be finite and |p|/leaf < 2^20 per axis (throws sope::Error otherwise).
// When `counts` is given it receives the number of input points in each voxel.
std::vector<Eigen::Vector3f> VoxelGridCentroids(const std::vector<Eigen::Vector3f>& points,
                                                float leaf,
                                                std::vector<uint32_t>* counts = nullptr);
// VoxelGridCentroids of the finite points whose squared norm (in double) lies in
// [min_sq, max_sq] (the same centroids as after filtering them out first, without the
// copy); `finite` and `in_band` (optional) receive how many points were finite and how
// many of those in the band.
std::vector<Eigen::Vector3f> VoxelGridCentroidsInBand(const std::vector<Eigen::Vector3f>& points,
                                                      float leaf, double min_sq, double max_sq,
                                                      std::vector<uint32_t>* counts,
                                                      int64_t* finite, int64_t* in_band);

// k nearest neighbours of every point of a cloud: row i holds `count` entries, point i itself
// first (distance 0), then the others by increasing squared distance (ties by index), as
// PCL's nearestKSearch(cloud, i, k) on a duplicate-free cloud. count = min(k, cloud size).
struct NeighbourTable {
  int count = 0;
  std::vector<int32_t> index;      // size() · count
  std::vector<float> sq_distance;  // size() · count, metres²
  size_t size() const { return count == 0 ? 0 : index.size() / count; }
  const int32_t* row(size_t i) const { return index.data() + i * count; }
  const float* row_sq_distance(size_t i) const { return sq_distance.data() + i * count; }
};

// Exact k-NN on a hashed uniform grid. The cell edge is chosen from the cloud so that an
// occupied cell holds about (k + 1)/2 points (k: the neighbour count it is built for), so the
// 3×3×3 cells around a point almost always hold its k nearest (else a shell is added).
class NeighbourGrid {
 public:
  // `points` must be finite; they are copied. `expected_k` tunes the cell size.
  explicit NeighbourGrid(const std::vector<Eigen::Vector3f>& points, int expected_k = 16);

  size_t size() const { return original_index_.size(); }
  double cell_size() const { return cell_; }

  // The min(k, size()) points nearest to `query` (any point in space), by increasing
  // squared distance, ties by index.
  void KNearest(const Eigen::Vector3f& query, int k, std::vector<int32_t>* indices,
                std::vector<float>* sq_distances) const;
  // The table above for every point of the cloud, k ≥ 1.
  NeighbourTable AllKNearest(int k) const;

 private:
  struct Cell {
    uint64_t key;
    uint32_t begin, end;  // range in the sorted point arrays
  };
  void Build(double cell_size);
  int64_t CellCoord(float value, int axis) const;
  uint64_t Key(int64_t cx, int64_t cy, int64_t cz) const;
  const Cell* Find(int64_t cx, int64_t cy, int64_t cz) const;
  // Appends the (key-sorted) cells of the Chebyshev ring `ring` around (cx, cy, cz).
  void GatherRing(int64_t cx, int64_t cy, int64_t cz, int64_t ring,
                  std::vector<const Cell*>* cells) const;

  std::vector<Eigen::Vector3f> input_;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  double cell_ = 1.0, inv_cell_ = 1.0;
  int64_t dims_[3] = {1, 1, 1};
  // Points sorted by cell key (then index), structure of arrays.
  std::vector<float> xs_, ys_, zs_;
  std::vector<int32_t> original_index_;
  std::vector<Cell> cells_;  // by key
  // Cell lookup: a dense array over the grid when it is small (the usual case: one object),
  // else an open-addressing hash table; both hold indices into cells_, −1 = empty.
  std::vector<int32_t> dense_;
  std::vector<int32_t> table_;
  uint64_t table_mask_ = 0;
};

// Statistical outlier removal as pcl::StatisticalOutlierRemoval: d_i = mean distance of
// point i to its `mean_k` nearest neighbours (the table must hold mean_k + 1 entries per
// row, the point itself first); keep i iff d_i ≤ mean(d) + stddev_multiplier · std(d)
// (sample standard deviation). Returns a keep mask.
// With `weights` (one per point, e.g. the raw points each voxel centroid stands for) the
// mean and standard deviation are weighted: on a voxel-thinned cloud they then estimate the
// statistics of the raw cloud, where sparse outliers are a small minority — unweighted, a
// few hundred isolated raw outliers become hundreds of single-point voxels beside a few
// thousand surface voxels and inflate σ until they pass the test.
// With `min_ratio` > 0 the threshold is at least min_ratio · mean(d) (see
// PreprocessOptions::outlier_min_ratio); 0 gives PCL's rule.
std::vector<uint8_t> StatisticalInlierMask(const NeighbourTable& table, int mean_k,
                                           double stddev_multiplier,
                                           const std::vector<uint32_t>* weights = nullptr,
                                           double min_ratio = 0.0);

// The smallest eigenvalue of the symmetric positive semi-definite 3×3 `covariance` and a
// unit eigenvector of it (Newton's method on the characteristic polynomial, then the
// eigenvector from cross products: no trigonometry; Eigen's direct solver where that
// eigenvalue is not simple). Returns false when the trace is not positive and finite.
bool SmallestEigenpair(const Eigen::Matrix3d& covariance, double* value, Eigen::Vector3d* vector);

// Least-squares plane of the points `neighbours` (indices into `points`), as
// pcl::NormalEstimation: unit normal = eigenvector of the smallest eigenvalue of the
// neighbourhood covariance, flipped so that (viewpoint − point)·normal ≥ 0, and the surface
// variation λ0 / (λ0 + λ1 + λ2) as the curvature. Returns false (NaN outputs) for fewer
// than 3 neighbours or a non-finite fit.
bool FitNormal(const std::vector<Eigen::Vector3f>& points, const int32_t* neighbours, int count,
               const Eigen::Vector3f& point, const Eigen::Vector3f& viewpoint,
               Eigen::Vector3f* normal, float* curvature);

}  // namespace internal
}  // namespace sope
