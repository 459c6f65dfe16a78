#include "recogniser/preprocess.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

#include <spdlog/spdlog.h>

#include "core/error.h"
#include "recogniser/cloud_filters.h"

namespace sope {
namespace {

// Largest |coordinate| / leaf the packed voxel keys hold (cloud_filters.cc).
constexpr double kMaxLeavesFromOrigin = double(1 << 20) - 2.0;

// Work bound: the neighbour statistics, normals and descriptors after the voxel grid cost
// more than linearly on clouds that do not thin (uniform noise fills a volume, not a
// surface). A view of an object is a few thousand voxels and a whole table-top scene at the
// default 4 mm leaf ≈ 60k; beyond this the leaf is coarsened until the grid holds at most
// this many points, so the work stays ≈ linear in the input and bounded.
constexpr size_t kMaxVoxelPoints = 100000;

}  // namespace

std::string ToString(ScaleNormalisation mode) { return EnumToString(mode); }

ScaleNormalisation ScaleNormalisationFromString(const std::string& text) {
  return EnumFromString<ScaleNormalisation>(text);
}

void PreprocessOptions::Check() const {
  SOPE_CHECK(std::isfinite(min_range) && min_range >= 0.0,
             "PreprocessOptions: min_range must be ≥ 0 metres, got {}", min_range);
  SOPE_CHECK(std::isfinite(max_range) && max_range > min_range,
             "PreprocessOptions: max_range must be finite and > min_range = {} metres, got {}",
             min_range, max_range);
  SOPE_CHECK(outlier_neighbours >= 0, "PreprocessOptions: outlier_neighbours must be ≥ 0, got {}",
             outlier_neighbours);
  SOPE_CHECK(outlier_neighbours == 0 || (std::isfinite(outlier_stddev) && outlier_stddev > 0.0),
             "PreprocessOptions: outlier_stddev must be > 0, got {}", outlier_stddev);
  SOPE_CHECK(std::isfinite(outlier_min_ratio) && outlier_min_ratio >= 0.0,
             "PreprocessOptions: outlier_min_ratio must be ≥ 0, got {}", outlier_min_ratio);
  SOPE_CHECK(std::isfinite(voxel_leaf) && voxel_leaf >= 0.0,
             "PreprocessOptions: voxel_leaf must be ≥ 0 metres (0 disables), got {}", voxel_leaf);
  SOPE_CHECK(voxel_leaf == 0.0 || max_range / voxel_leaf < kMaxLeavesFromOrigin,
             "PreprocessOptions: voxel_leaf {} m is too small for max_range {} m (at most 2^20 "
             "leaves)",
             voxel_leaf, max_range);
  SOPE_CHECK(normal_neighbours >= 3, "PreprocessOptions: normal_neighbours must be ≥ 3, got {}",
             normal_neighbours);
  SOPE_CHECK(std::isfinite(median_fraction) && median_fraction >= 0.0 && median_fraction < 1.0,
             "PreprocessOptions: median_fraction must be in [0, 1), got {}", median_fraction);
  SOPE_CHECK(min_points >= 3, "PreprocessOptions: min_points must be ≥ 3, got {}", min_points);
}

std::string PreprocessSummary::BriefReport() const {
  return fmt::format(
      "{} input → {} finite → {} in range band → {} after voxel grid → {} after outlier removal "
      "→ {} with normals",
      input_points, finite_points, in_range_points, voxel_points, inlier_points, final_points);
}

namespace {

// The range band on ‖p‖ (thesis's conditional filter), compared on squared norms.
internal::SquaredRangeBand RangeBand(const PreprocessOptions& options) {
  return {options.min_range * options.min_range, options.max_range * options.max_range};
}

// Steps 1 and 2: the finite points inside the range band (the input normals and colours
// are not used: normals are re-estimated after thinning so that database and query clouds
// get the same estimator), thinned by the voxel grid (it thins 100k raw points to a few
// thousand, and the neighbour statistics are then on an even sampling) in the same pass,
// coarsened until at most kMaxVoxelPoints remain. `voxel_counts` receives the raw points
// behind each voxel (empty without a grid).
std::vector<Eigen::Vector3f> InRangeVoxels(const PointCloud& cloud,
                                           const PreprocessOptions& options,
                                           PreprocessSummary* summary,
                                           std::vector<uint32_t>* voxel_counts) {
  const internal::SquaredRangeBand band = RangeBand(options);
  std::vector<Eigen::Vector3f> points;
  if (options.voxel_leaf > 0.0) {
    points = internal::VoxelGridCentroidsInBand(
        cloud.points, static_cast<float>(options.voxel_leaf), band.min_sq, band.max_sq,
        voxel_counts, &summary->finite_points, &summary->in_range_points);
  } else {
    points.reserve(cloud.size());
    for (const Eigen::Vector3f& p : cloud.points) {
      if (!internal::IsFinitePoint(p)) continue;
      ++summary->finite_points;
      if (band.Contains(p)) points.push_back(p);
    }
    summary->in_range_points = static_cast<int64_t>(points.size());
  }
  SOPE_CHECK(summary->finite_points > 0, "Preprocess: none of the {} input points is finite",
             summary->input_points);
  SOPE_CHECK(summary->in_range_points > 0,
             "Preprocess: no point left: all {} finite points lie outside the range band "
             "[{}, {}] m",
             summary->finite_points, options.min_range, options.max_range);
  if (points.size() <= kMaxVoxelPoints) return points;
  // Coarsen from the in-range points (so the counts stay per raw point): the number of
  // voxels falls at least as the square of the leaf on a surface, faster in a volume.
  const size_t first_voxels = points.size();
  std::vector<Eigen::Vector3f> in_range;
  if (options.voxel_leaf > 0.0) {
    in_range.reserve(static_cast<size_t>(summary->in_range_points));
    for (const Eigen::Vector3f& p : cloud.points) {
      if (internal::IsFinitePoint(p) && band.Contains(p)) in_range.push_back(p);
    }
  } else {
    in_range.swap(points);
  }
  double leaf = options.voxel_leaf > 0.0 ? options.voxel_leaf : options.max_range / 1000.0;
  size_t voxels = options.voxel_leaf > 0.0 ? points.size() : in_range.size();
  while (voxels > kMaxVoxelPoints) {
    leaf *= std::max(1.25, 1.05 * std::sqrt(static_cast<double>(voxels) / kMaxVoxelPoints));
    points = internal::VoxelGridCentroids(in_range, static_cast<float>(leaf), voxel_counts);
    voxels = points.size();
  }
  spdlog::debug("Preprocess: {} points at the {} m leaf exceed {}; a {:.4f} m leaf gives {}",
                first_voxels, options.voxel_leaf, kMaxVoxelPoints, leaf, voxels);
  return points;
}

// Step 3: statistical outlier removal (weighted by the raw points behind each voxel, as if
// on the raw cloud), then normals from the k nearest inliers (the point itself included, as
// PCL's NormalEstimation::setKSearch), oriented towards the sensor at the origin. One
// neighbour table serves both: the k nearest inliers are the first k inliers of the full
// neighbour list when it holds that many. Fills out->cloud and out->curvature.
void RemoveOutliersAndFitNormals(const std::vector<Eigen::Vector3f>& points,
                                 const std::vector<uint32_t>& voxel_counts,
                                 const PreprocessOptions& options, PreprocessedCloud* out) {
  const int normal_k = options.normal_neighbours;
  const internal::NeighbourGrid grid(points, std::max(options.outlier_neighbours + 1, normal_k));
  const internal::NeighbourTable table =
      grid.AllKNearest(std::max(options.outlier_neighbours + 1, normal_k));
  std::vector<uint8_t> keep(points.size(), 1);
  if (options.outlier_neighbours > 0) {
    keep = internal::StatisticalInlierMask(
        table, options.outlier_neighbours, options.outlier_stddev,
        voxel_counts.empty() ? nullptr : &voxel_counts, options.outlier_min_ratio);
  }
  std::vector<int32_t> new_index(points.size(), -1);
  std::vector<Eigen::Vector3f> inliers;
  inliers.reserve(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    if (!keep[i]) continue;
    new_index[i] = static_cast<int32_t>(inliers.size());
    inliers.push_back(points[i]);
  }
  out->summary.inlier_points = static_cast<int64_t>(inliers.size());

  const int k = std::min<int>(normal_k, static_cast<int>(inliers.size()));
  std::vector<int32_t> neighbours;
  std::vector<float> unused_distances;
  std::unique_ptr<internal::NeighbourGrid> inlier_grid;
  auto inlier_knn = [&](size_t i) {
    if (!inlier_grid) inlier_grid = std::make_unique<internal::NeighbourGrid>(inliers, normal_k);
    inlier_grid->KNearest(inliers[i], k, &neighbours, &unused_distances);
  };
  PointCloud& result = out->cloud;
  result.points.reserve(inliers.size());
  result.normals.reserve(inliers.size());
  out->curvature.reserve(inliers.size());
  const Eigen::Vector3f sensor = Eigen::Vector3f::Zero();
  for (size_t i = 0; i < points.size(); ++i) {
    if (!keep[i]) continue;
    const size_t inlier = static_cast<size_t>(new_index[i]);
    neighbours.clear();
    const int32_t* row = table.row(i);
    for (int j = 0; j < table.count && static_cast<int>(neighbours.size()) < k; ++j) {
      if (new_index[row[j]] >= 0) neighbours.push_back(new_index[row[j]]);
    }
    if (static_cast<int>(neighbours.size()) < k) inlier_knn(inlier);
    Eigen::Vector3f normal;
    float curvature;
    if (!internal::FitNormal(inliers, neighbours.data(), static_cast<int>(neighbours.size()),
                             inliers[inlier], sensor, &normal, &curvature)) {
      continue;
    }
    result.points.push_back(inliers[inlier]);
    result.normals.push_back(normal);
    out->curvature.push_back(curvature);
  }
}

// Step 4: centroid and size normalisation (thesis §4.2.4.2): the radius is the farthest
// distance from the centroid, or the median of the distances ranked beyond the
// median_fraction quantile. Fills out->centroid, out->radius and out->normalised.
void NormaliseCentroidAndSize(const PreprocessOptions& options, PreprocessedCloud* out) {
  const PointCloud& result = out->cloud;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3f& p : result.points) centroid += p.cast<double>();
  centroid /= static_cast<double>(result.size());
  std::vector<double> distances(result.size());
  for (size_t i = 0; i < result.size(); ++i) {
    distances[i] = (result.points[i].cast<double>() - centroid).norm();
  }
  double radius = 0.0;
  if (options.normalisation == ScaleNormalisation::kFarthest) {
    radius = *std::max_element(distances.begin(), distances.end());
  } else {
    const size_t n = distances.size();
    const size_t first =
        std::min(n - 1, static_cast<size_t>(std::floor(options.median_fraction * n)));
    std::nth_element(distances.begin(), distances.begin() + first, distances.end());
    const size_t tail = n - first;
    const size_t upper = first + tail / 2;
    std::nth_element(distances.begin() + first, distances.begin() + upper, distances.end());
    radius = distances[upper];
    if (tail % 2 == 0) {
      const double lower = *std::max_element(distances.begin() + first, distances.begin() + upper);
      radius = 0.5 * (radius + lower);
    }
  }
  SOPE_CHECK(radius > 0.0 && std::isfinite(radius),
             "Preprocess: the {} remaining points coincide (normalisation radius {} m)",
             result.size(), radius);
  out->centroid = centroid.cast<float>();
  out->radius = static_cast<float>(radius);
  out->normalised.points.reserve(result.size());
  const double inv_radius = 1.0 / radius;
  for (const Eigen::Vector3f& p : result.points) {
    out->normalised.points.push_back(((p.cast<double>() - centroid) * inv_radius).cast<float>());
  }
  out->normalised.normals = result.normals;
}

}  // namespace

PreprocessedCloud Preprocess(const PointCloud& cloud, const PreprocessOptions& options) {
  options.Check();
  cloud.Check();
  SOPE_CHECK(!cloud.empty(), "Preprocess: the input cloud is empty");
  PreprocessedCloud out;
  PreprocessSummary& summary = out.summary;
  summary.input_points = static_cast<int64_t>(cloud.size());
  std::vector<uint32_t> voxel_counts;
  const std::vector<Eigen::Vector3f> points =
      InRangeVoxels(cloud, options, &summary, &voxel_counts);
  summary.voxel_points = static_cast<int64_t>(points.size());
  RemoveOutliersAndFitNormals(points, voxel_counts, options, &out);
  summary.final_points = static_cast<int64_t>(out.cloud.size());
  SOPE_CHECK(summary.final_points >= options.min_points,
             "Preprocess: only {} points left, fewer than min_points = {} ({}; range band "
             "[{}, {}] m, voxel leaf {} m, outlier removal k = {} σ×{})",
             summary.final_points, options.min_points, summary.BriefReport(), options.min_range,
             options.max_range, options.voxel_leaf, options.outlier_neighbours,
             options.outlier_stddev);
  NormaliseCentroidAndSize(options, &out);
  return out;
}

}  // namespace sope
