#include "recogniser/segmentation.h"

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <unordered_map>

#include <Eigen/Eigenvalues>
#include <fmt/format.h>
#include <pcl/sample_consensus/ransac.h>
#include <pcl/sample_consensus/sac_model_plane.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>

#include "core/error.h"
#include "core/stopwatch.h"
#include "recogniser/pcl_convert.h"
#include "recogniser/voxel_key.h"

namespace sope {
namespace {

// Sums of points taken relative to a point near them (`origin`, so that the second moments
// lose nothing to cancellation), in double: count, Σd and the six distinct products of Σd·dᵀ.
struct PlaneSums {
  double count = 0.0;
  double x = 0.0, y = 0.0, z = 0.0;
  double xx = 0.0, xy = 0.0, xz = 0.0, yy = 0.0, yz = 0.0, zz = 0.0;
  void Add(const Eigen::Vector3f& d) {
    const double dx = d.x(), dy = d.y(), dz = d.z();
    count += 1.0;
    x += dx;
    y += dy;
    z += dz;
    xx += dx * dx;
    xy += dx * dy;
    xz += dx * dz;
    yy += dy * dy;
    yz += dy * dz;
    zz += dz * dz;
  }
};

// Least-squares plane of the summed points (centroid + smallest eigenvector of their
// covariance), normal towards the camera (the frame's origin).
bool FitPlane(const PlaneSums& s, const Eigen::Vector3f& origin, TablePlane* plane) {
  if (s.count < 3) return false;
  const Eigen::Vector3d mean = Eigen::Vector3d(s.x, s.y, s.z) / s.count;
  Eigen::Matrix3d covariance;
  covariance << s.xx, s.xy, s.xz, s.xy, s.yy, s.yz, s.xz, s.yz, s.zz;
  covariance = covariance / s.count - mean * mean.transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
  Eigen::Vector3d normal = solver.eigenvectors().col(0);
  if (!normal.allFinite()) return false;
  double offset = -normal.dot(origin.cast<double>() + mean);
  if (offset < 0) {
    normal = -normal;
    offset = -offset;
  }
  plane->normal = normal.normalized().cast<float>();
  plane->offset = static_cast<float>(offset);
  return true;
}

// The same components by PCL (kd-tree radius searches): the former method, kept as the
// benchmark's peer.
std::vector<std::vector<int>> PclEuclideanClusters(const std::vector<Eigen::Vector3f>& points,
                                                   double tolerance) {
  pcl::PointCloud<pcl::PointXYZ>::Ptr thinned(new pcl::PointCloud<pcl::PointXYZ>);
  thinned->reserve(points.size());
  for (const Eigen::Vector3f& c : points) thinned->push_back(pcl::PointXYZ(c.x(), c.y(), c.z()));
  pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
  tree->setInputCloud(thinned);
  pcl::EuclideanClusterExtraction<pcl::PointXYZ> extraction;
  extraction.setClusterTolerance(tolerance);
  extraction.setMinClusterSize(1);
  extraction.setMaxClusterSize(std::numeric_limits<int>::max());
  extraction.setSearchMethod(tree);
  extraction.setInputCloud(thinned);
  std::vector<pcl::PointIndices> clusters;
  extraction.extract(clusters);
  std::vector<std::vector<int>> out;
  for (pcl::PointIndices& c : clusters) out.push_back(std::move(c.indices));
  return out;
}

}  // namespace

// Connected components of `points` under "distance ≤ tolerance": union-find over a hash
// grid of cells `tolerance` wide (a point's neighbours within the tolerance lie in its own
// cell or the 26 around it). Returns each component's point indices, in increasing order
// of their first point.
std::vector<std::vector<int>> GridEuclideanClusters(const std::vector<Eigen::Vector3f>& points,
                                                    double tolerance) {
  const size_t n = points.size();
  const float inv_cell = static_cast<float>(1.0 / tolerance);
  const float tolerance2 = static_cast<float>(tolerance * tolerance);
  std::vector<Eigen::Vector3i> cell_of(n);
  std::vector<std::pair<uint64_t, int>> keyed(n);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f c = points[i] * inv_cell;
    cell_of[i] = Eigen::Vector3i(static_cast<int>(std::floor(c.x())),
                                 static_cast<int>(std::floor(c.y())),
                                 static_cast<int>(std::floor(c.z())));
    keyed[i] = {PackVoxelKey(cell_of[i].x(), cell_of[i].y(), cell_of[i].z()), static_cast<int>(i)};
  }
  std::sort(keyed.begin(), keyed.end());
  std::unordered_map<uint64_t, std::pair<int, int>> cells;  // key → range in `keyed`
  std::vector<std::pair<int, int>> ranges;                    // the same, in key order
  cells.reserve(n);
  for (size_t k = 0; k < n;) {
    size_t end = k;
    while (end < n && keyed[end].first == keyed[k].first) ++end;
    ranges.emplace_back(static_cast<int>(k), static_cast<int>(end));
    cells.emplace(keyed[k].first, ranges.back());
    k = end;
  }
  std::vector<int> parent(n);
  for (size_t i = 0; i < n; ++i) parent[i] = static_cast<int>(i);
  auto find = [&parent](int i) {
    while (parent[i] != i) {
      parent[i] = parent[parent[i]];
      i = parent[i];
    }
    return i;
  };
  const auto join_close = [&](int i, int j) {
    if ((points[j] - points[i]).squaredNorm() > tolerance2) return;
    const int a = find(i), b = find(j);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  };
  // Cell by cell (each holds several points at once: a thinned surface puts ~(tolerance /
  // leaf)² in one): the pairs within the cell, then those with each of the 13 neighbour
  // cells that come after it (every pair of neighbour cells once) — a hash look-up per
  // cell and neighbour rather than per point and neighbour. The components do not depend
  // on the order in which the pairs are joined.
  for (const auto& [begin, end] : ranges) {
    for (int p = begin; p < end; ++p) {
      for (int q = p + 1; q < end; ++q) join_close(keyed[p].second, keyed[q].second);
    }
    const Eigen::Vector3i& c = cell_of[keyed[begin].second];
    for (int dz = 0; dz <= 1; ++dz) {
      for (int dy = dz == 0 ? 0 : -1; dy <= 1; ++dy) {
        for (int dx = dz == 0 && dy == 0 ? 1 : -1; dx <= 1; ++dx) {
          const auto it = cells.find(PackVoxelKey(c.x() + dx, c.y() + dy, c.z() + dz));
          if (it == cells.end()) continue;
          for (int p = begin; p < end; ++p) {
            for (int q = it->second.first; q < it->second.second; ++q) {
              join_close(keyed[p].second, keyed[q].second);
            }
          }
        }
      }
    }
  }
  std::vector<int> component_of_root(n, -1);
  std::vector<std::vector<int>> components;
  for (size_t i = 0; i < n; ++i) {
    const int root = find(static_cast<int>(i));
    if (component_of_root[root] < 0) {
      component_of_root[root] = static_cast<int>(components.size());
      components.emplace_back();
    }
    components[component_of_root[root]].push_back(static_cast<int>(i));
  }
  return components;
}

void TableSegmentationOptions::Check() const {
  SOPE_CHECK(std::isfinite(min_range) && min_range >= 0.0,
             "table segmentation: min range must be ≥ 0 m, got {}", min_range);
  SOPE_CHECK(std::isfinite(max_range) && max_range > min_range,
             "table segmentation: max range must exceed the min range ({} m), got {}",
             min_range, max_range);
  SOPE_CHECK(plane_distance > 0.0, "table segmentation: plane distance must be > 0 m, got {}",
             plane_distance);
  SOPE_CHECK(plane_iterations >= 1, "table segmentation: plane iterations must be ≥ 1, got {}",
             plane_iterations);
  SOPE_CHECK(plane_samples >= 3, "table segmentation: plane samples must be ≥ 3, got {}",
             plane_samples);
  SOPE_CHECK(min_plane_fraction >= 0.0 && min_plane_fraction <= 1.0,
             "table segmentation: min plane fraction must be in [0, 1], got {}",
             min_plane_fraction);
  SOPE_CHECK(min_height >= 0.0 && max_height > min_height,
             "table segmentation: height band must satisfy 0 ≤ min < max, got [{}, {}] m",
             min_height, max_height);
  SOPE_CHECK(cluster_leaf > 0.0, "table segmentation: cluster leaf must be > 0 m, got {}",
             cluster_leaf);
  SOPE_CHECK(cluster_tolerance >= 0.0,
             "table segmentation: cluster tolerance must be ≥ 0 m, got {}", cluster_tolerance);
  SOPE_CHECK(max_points >= 3, "table segmentation: max points must be ≥ 3, got {}", max_points);
  SOPE_CHECK(min_cluster_points >= 1,
             "table segmentation: min cluster points must be ≥ 1, got {}", min_cluster_points);
}

namespace {

// The cloud's points in the range band, every `keep_every`-th point kept so that at most
// about `max_points` remain.
std::vector<int> RangeBand(const PointCloud& cloud, const TableSegmentationOptions& options) {
  const double lo2 = options.min_range * options.min_range;
  const double hi2 = options.max_range * options.max_range;
  std::vector<int> band;
  band.reserve(cloud.size());
  size_t in_band = 0;
  for (size_t i = 0; i < cloud.size(); ++i) {
    const double r2 = cloud.points[i].cast<double>().squaredNorm();
    in_band += r2 >= lo2 && r2 <= hi2;
  }
  const size_t keep_every =
      std::max<size_t>(1, (in_band + options.max_points - 1) / static_cast<size_t>(options.max_points));
  for (size_t i = 0; i < cloud.size(); i += keep_every) {
    const double r2 = cloud.points[i].cast<double>().squaredNorm();
    if (r2 >= lo2 && r2 <= hi2) band.push_back(static_cast<int>(i));
  }
  return band;
}

// The plane refitted by least squares on its inliers among `band`, once per tolerance
// (metres) in `tolerances`; `inliers` counts those of the last round. False when a fit fails.
bool RefitOnInliers(const PointCloud& cloud, const std::vector<int>& band,
                    std::initializer_list<double> tolerances, TablePlane* plane) {
  for (const double tolerance : tolerances) {
    // The inliers summed as they are found (one pass), about the plane's point nearest the
    // camera: the table's points lie within a few decimetres of it.
    const Eigen::Vector3f origin = -plane->offset * plane->normal;
    PlaneSums sums;
    for (int i : band) {
      const Eigen::Vector3f& p = cloud.points[i];
      if (std::abs(plane->Height(p)) <= tolerance) sums.Add(p - origin);
    }
    plane->inliers = static_cast<int>(sums.count);
    if (!FitPlane(sums, origin, plane)) return false;
  }
  return true;
}

// The table plane: RANSAC on an even subsample of the band, then least squares on every
// inlier (twice). `found` when at least `needed` (and 3) band points lie on it.
TablePlane FitTablePlane(const PointCloud& cloud, const std::vector<int>& band,
                         const TableSegmentationOptions& options, size_t needed) {
  const size_t stride =
      std::max<size_t>(1, band.size() / static_cast<size_t>(options.plane_samples));
  pcl::PointCloud<pcl::PointXYZ>::Ptr sample(new pcl::PointCloud<pcl::PointXYZ>);
  for (size_t k = 0; k < band.size(); k += stride) {
    const Eigen::Vector3f& p = cloud.points[band[k]];
    sample->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  }
  // RANSAC with the plane model alone, as pcl::SACSegmentation(SACMODEL_PLANE, SAC_RANSAC)
  // runs it (same seeds, probability 0.99, no coefficient refinement): SACSegmentation
  // instantiates every model and estimator of sample_consensus here (PCL_NO_PRECOMPILE),
  // which was ~2 min of this file's compile.
  TablePlane plane;
  if (sample->size() < 3) return plane;
  const auto model = std::make_shared<pcl::SampleConsensusModelPlane<pcl::PointXYZ>>(sample);
  pcl::RandomSampleConsensus<pcl::PointXYZ> ransac(model, options.plane_distance);
  ransac.setMaxIterations(options.plane_iterations);
  Eigen::VectorXf coefficients;
  if (!ransac.computeModel(0)) return plane;
  ransac.getModelCoefficients(coefficients);
  if (coefficients.size() != 4) return plane;
  Eigen::Vector3f normal(coefficients[0], coefficients[1], coefficients[2]);
  const float norm = normal.norm();
  if (!(norm > 0 && std::isfinite(norm))) return plane;
  plane.normal = normal / norm;
  plane.offset = coefficients[3] / norm;
  RefitOnInliers(cloud, band, {options.plane_distance, options.plane_distance}, &plane);
  plane.found = static_cast<size_t>(plane.inliers) >= std::max<size_t>(needed, 3);
  return plane;
}

// How far below a plane a point must lie to be under it, not on it (its noise, an object's
// lowest rows): what DescendToSupportingPlane and PointsBelow count.
double MinGapBelow(const TableSegmentationOptions& options) {
  return std::max(2.0 * options.min_height, 3.0 * options.plane_distance);
}

// A horizontal face larger than the visible table (the top of a big box, a tray) wins the
// RANSAC: everything then lies below "the table" and nothing stands on it. The table is the
// plane the objects rest on, so while a plane parallel to the found one (within
// kParallelDegrees) lies below it — no farther than max_height (a floor under a desk is
// farther) — and holds at least `needed` band points, that plane is taken instead. Candidate
// heights are the peaks of a histogram of the band's heights below the plane (bins
// plane_distance wide): a parallel face piles its points into one bin, walls and slopes
// spread theirs.
TablePlane DescendToSupportingPlane(const PointCloud& cloud, const std::vector<int>& band,
                                    const TableSegmentationOptions& options, size_t needed,
                                    TablePlane plane) {
  constexpr double kParallelDegrees = 8.0;
  const double min_gap = MinGapBelow(options);
  const double bin = options.plane_distance;
  const int bins = static_cast<int>(std::ceil(options.max_height / bin)) + 1;
  for (int step = 0; step < 4; ++step) {
    std::vector<int> count(bins, 0);
    for (int i : band) {
      const double depth = -plane.Height(cloud.points[i]);  // below the plane: > 0
      if (depth < min_gap || depth > options.max_height) continue;
      ++count[std::min(bins - 1, static_cast<int>(depth / bin))];
    }
    // The fullest bin with its two neighbours (a face's points straddle bin edges).
    int best = -1, best_count = 0;
    for (int b = 0; b < bins; ++b) {
      const int c = count[b] + (b > 0 ? count[b - 1] : 0) + (b + 1 < bins ? count[b + 1] : 0);
      if (c > best_count) best = b, best_count = c;
    }
    if (best < 0 || static_cast<size_t>(best_count) < needed) return plane;
    TablePlane lower = plane;
    lower.offset = plane.offset + static_cast<float>((best + 0.5) * bin);  // shifted down
    // A face slightly tilted against the found plane (fitted with a few points of the box's
    // sides) straddles several bins: the first fit takes a wider slab.
    const double d = options.plane_distance;
    if (!RefitOnInliers(cloud, band, {3 * d, d, d}, &lower)) return plane;
    const double cos_angle = std::abs(static_cast<double>(lower.normal.dot(plane.normal)));
    if (cos_angle < std::cos(kParallelDegrees * M_PI / 180.0) ||
        static_cast<size_t>(lower.inliers) < needed || lower.offset <= plane.offset) {
      return plane;
    }
    lower.found = true;
    plane = lower;
  }
  return plane;
}

// Points voxel-thinned to their voxel centroids; each input point keeps its voxel.
struct VoxelGrid {
  std::vector<int> voxel_of_point;         // per input point
  std::vector<Eigen::Vector3f> centroids;  // per voxel
};

VoxelGrid ThinToVoxels(const PointCloud& cloud, const std::vector<int>& indices, double leaf) {
  const float inv_leaf = static_cast<float>(1.0 / leaf);
  std::unordered_map<uint64_t, int> voxel_of_key;
  voxel_of_key.reserve(indices.size() / 4);
  VoxelGrid grid;
  grid.voxel_of_point.resize(indices.size());
  std::vector<Eigen::Vector3d> voxel_sum;
  std::vector<int> voxel_count;
  for (size_t k = 0; k < indices.size(); ++k) {
    const Eigen::Vector3f& p = cloud.points[indices[k]];
    const uint64_t key = VoxelKeyOf(p, inv_leaf);
    auto [it, inserted] = voxel_of_key.emplace(key, static_cast<int>(voxel_sum.size()));
    if (inserted) {
      voxel_sum.emplace_back(Eigen::Vector3d::Zero());
      voxel_count.push_back(0);
    }
    grid.voxel_of_point[k] = it->second;
    voxel_sum[it->second] += p.cast<double>();
    ++voxel_count[it->second];
  }
  grid.centroids.resize(voxel_sum.size());
  for (size_t v = 0; v < voxel_sum.size(); ++v) {
    grid.centroids[v] = (voxel_sum[v] / voxel_count[v]).cast<float>();
  }
  return grid;
}

// Euclidean clusters of the voxels of the points `above` the table, as clusters of the
// points, those of at least `min_cluster_points` points, largest first.
std::vector<ObjectCluster> ClusterAbovePoints(const PointCloud& cloud,
                                              const std::vector<int>& above,
                                              const TableSegmentationOptions& options) {
  const VoxelGrid grid = ThinToVoxels(cloud, above, options.cluster_leaf);
  const double tolerance = options.ClusterTolerance();
  const std::vector<std::vector<int>> voxel_clusters =
      options.clustering == TableSegmentationOptions::Clustering::kPclKdTree
          ? PclEuclideanClusters(grid.centroids, tolerance)
          : GridEuclideanClusters(grid.centroids, tolerance);
  std::vector<int> cluster_of_voxel(grid.centroids.size(), -1);
  for (size_t c = 0; c < voxel_clusters.size(); ++c) {
    for (int v : voxel_clusters[c]) cluster_of_voxel[v] = static_cast<int>(c);
  }
  std::vector<ObjectCluster> clusters(voxel_clusters.size());
  for (size_t k = 0; k < above.size(); ++k) {
    const int c = cluster_of_voxel[grid.voxel_of_point[k]];
    if (c >= 0) clusters[c].indices.push_back(above[k]);
  }
  std::vector<ObjectCluster> kept;
  for (ObjectCluster& cluster : clusters) {
    if (static_cast<int>(cluster.indices.size()) < options.min_cluster_points) continue;
    std::sort(cluster.indices.begin(), cluster.indices.end());
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    cluster.cloud.points.reserve(cluster.indices.size());
    for (int i : cluster.indices) {
      cluster.cloud.points.push_back(cloud.points[i]);
      if (cloud.HasColors()) cluster.cloud.colors.push_back(cloud.colors[i]);
      sum += cloud.points[i].cast<double>();
    }
    cluster.centroid = (sum / static_cast<double>(cluster.indices.size())).cast<float>();
    kept.push_back(std::move(cluster));
  }
  std::stable_sort(kept.begin(), kept.end(), [](const ObjectCluster& a, const ObjectCluster& b) {
    // Equal sizes: the first point first (an order both clusterings share).
    if (a.indices.size() != b.indices.size()) return a.indices.size() > b.indices.size();
    return a.indices.front() < b.indices.front();
  });
  return kept;
}

// Band points the table plane must hold.
size_t PlaneNeeds(const std::vector<int>& band, const TableSegmentationOptions& options) {
  return static_cast<size_t>(std::ceil(options.min_plane_fraction * band.size()));
}

// Band points lying between min_gap and max_height below `plane` (what the camera could
// not see under a table, short of a floor).
std::vector<int> PointsBelow(const PointCloud& cloud, const std::vector<int>& band,
                             const TableSegmentationOptions& options, const TablePlane& plane) {
  const double min_gap = MinGapBelow(options);
  std::vector<int> below;
  for (int i : band) {
    const double depth = -plane.Height(cloud.points[i]);
    if (depth >= min_gap && depth <= options.max_height) below.push_back(i);
  }
  return below;
}

// A large face of an object turned to the camera (the front of a box bigger than the table
// seen around it) can win the RANSAC: the table, the objects behind and the box's top then
// lie below "the table". A camera sees nothing under a table short of the floor, so when at
// least `needed` band points lie below the found plane (within max_height), the plane of
// those points is the table instead — if at most a quarter as many points lie below it, and
// the found plane's points stand on it (90% of them above it). A table with a wall behind
// it keeps its plane: the wall's points lie above the table, not below.
TablePlane BeneathAFaceOfAnObject(const PointCloud& cloud, const std::vector<int>& band,
                                  const TableSegmentationOptions& options, size_t needed,
                                  const TablePlane& plane) {
  const std::vector<int> below = PointsBelow(cloud, band, options, plane);
  if (below.size() < std::max<size_t>(needed, 3)) return plane;
  const size_t lower_needed = (needed + 1) / 2;
  TablePlane lower = FitTablePlane(cloud, below, options, lower_needed);
  if (!lower.found) return plane;
  // The largest face below may be a big box's top; the table is under it.
  lower = DescendToSupportingPlane(cloud, band, options, lower_needed, lower);
  const double d = options.plane_distance;
  if (!RefitOnInliers(cloud, band, {d, d}, &lower) ||
      static_cast<size_t>(lower.inliers) < lower_needed) {
    return plane;
  }
  if (PointsBelow(cloud, band, options, lower).size() * 4 > below.size()) return plane;
  size_t on_plane = 0, standing = 0;
  for (int i : band) {
    if (std::abs(plane.Height(cloud.points[i])) > d) continue;
    ++on_plane;
    standing += lower.Height(cloud.points[i]) >= -d;
  }
  if (standing < 0.9 * on_plane) return plane;
  lower.found = true;
  return lower;
}

// The table plane of the band's points (RANSAC, least squares, the supporting plane
// below), facing the camera.
TablePlane PlaneOfBand(const PointCloud& cloud, const std::vector<int>& band,
                       const TableSegmentationOptions& options) {
  const size_t needed = PlaneNeeds(band, options);
  TablePlane plane = FitTablePlane(cloud, band, options, needed);
  if (plane.found) plane = DescendToSupportingPlane(cloud, band, options, needed, plane);
  if (plane.found) plane = BeneathAFaceOfAnObject(cloud, band, options, needed, plane);
  if (plane.found && plane.offset < 0) {  // cannot happen after FitPlane, kept as an invariant
    plane.normal = -plane.normal;
    plane.offset = -plane.offset;
  }
  return plane;
}

}  // namespace

TablePlane FindTablePlane(const PointCloud& cloud, const TableSegmentationOptions& options) {
  options.Check();
  const std::vector<int> band = RangeBand(cloud, options);
  if (band.size() < 3) return TablePlane();
  return PlaneOfBand(cloud, band, options);
}

TableSegmentation SegmentTable(const PointCloud& cloud, const TableSegmentationOptions& options) {
  options.Check();
  cloud.Check();
  const Stopwatch watch;
  SOPE_CHECK(cloud.size() >= 3,
             "table segmentation: the cloud has {} point(s); a table plane needs at least 3",
             cloud.size());
  const size_t finite = cloud.CountFinite();
  SOPE_CHECK(finite == cloud.size(),
             "table segmentation: the cloud has {} non-finite point(s) (NaN or infinite "
             "coordinates) of {}",
             cloud.size() - finite, cloud.size());
  TableSegmentation out;

  // Points in the range band.
  const std::vector<int> band = RangeBand(cloud, options);
  out.finite_points = static_cast<int>(band.size());
  if (band.size() < 3) {
    out.message = fmt::format("no plane: {} point(s) in the range band [{}, {}] m", band.size(),
                              options.min_range, options.max_range);
    out.ms = watch.WallMs();
    return out;
  }

  // 1. RANSAC on an even subsample, then least squares on every inlier.
  const size_t needed = PlaneNeeds(band, options);
  TablePlane plane = PlaneOfBand(cloud, band, options);
  out.plane = plane;
  if (!plane.found) {
    out.message = fmt::format("no plane: {} of {} points on the best plane (at least {} needed)",
                              plane.inliers, band.size(), needed);
    out.ms = watch.WallMs();
    return out;
  }

  // 2. Points in the height band, voxel-thinned (each raw point keeps its voxel).
  std::vector<int> above;
  for (int i : band) {
    const float h = plane.Height(cloud.points[i]);
    if (h >= options.min_height && h <= options.max_height) above.push_back(i);
  }
  out.above_points = static_cast<int>(above.size());
  if (static_cast<int>(above.size()) < options.min_cluster_points) {
    out.message = fmt::format("nothing on the table: {} point(s) {}–{} m above the plane",
                              above.size(), options.min_height, options.max_height);
    out.ms = watch.WallMs();
    return out;
  }

  // 3. Euclidean clusters of the voxels.
  out.clusters = ClusterAbovePoints(cloud, above, options);
  if (out.clusters.empty()) {
    out.message = fmt::format("nothing on the table: {} point(s) above the plane, no cluster of "
                              "{} or more",
                              above.size(), options.min_cluster_points);
  }
  out.ms = watch.WallMs();
  return out;
}

}  // namespace sope
