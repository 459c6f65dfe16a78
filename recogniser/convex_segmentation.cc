#include "recogniser/convex_segmentation.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <utility>
#include <unordered_map>

#include <pcl/point_types.h>
#include <pcl/segmentation/lccp_segmentation.h>
#include <pcl/segmentation/supervoxel_clustering.h>

#include "core/error.h"
#include "recogniser/voxel_key.h"

namespace sope {

void ConvexSegmentationOptions::Check() const {
  SOPE_CHECK(voxel_resolution > 0 && seed_resolution > voxel_resolution,
             "convex segmentation: need 0 < voxel resolution < seed resolution, got {} and {} m",
             voxel_resolution, seed_resolution);
  SOPE_CHECK(spatial_importance >= 0 && normal_importance >= 0,
             "convex segmentation: importances must be ≥ 0, got {} and {}", spatial_importance,
             normal_importance);
  SOPE_CHECK(concavity_tolerance_deg >= 0 && concavity_tolerance_deg < 90,
             "convex segmentation: concavity tolerance must be in [0, 90) degrees, got {}",
             concavity_tolerance_deg);
  SOPE_CHECK(smoothness_threshold >= 0,
             "convex segmentation: smoothness threshold must be ≥ 0, got {}",
             smoothness_threshold);
  SOPE_CHECK(min_segment_supervoxels >= 0,
             "convex segmentation: min segment supervoxels must be ≥ 0, got {}",
             min_segment_supervoxels);
}

namespace {

// LCCPSegmentation's doGrouping, recursiveSegmentGrowing, computeSegmentAdjacency and
// mergeSmallSegments (PCL 1.13, the same steps and containers) with the supervoxels
// visited in increasing label order instead of the graph's vertex order.
std::map<uint32_t, uint32_t> GroupSupervoxels(
    const std::vector<uint32_t>& labels,
    const std::map<uint32_t, std::vector<uint32_t>>& neighbours,
    const std::set<std::pair<uint32_t, uint32_t>>& valid, uint32_t min_segment_size) {
  static const std::vector<uint32_t> kNone;
  const auto neighbours_of = [&](uint32_t label) -> const std::vector<uint32_t>& {
    const auto it = neighbours.find(label);
    return it == neighbours.end() ? kNone : it->second;
  };
  // Grouping: the supervoxels joined by valid (convex) edges, a segment each (from 1;
  // 0: not reached yet).
  std::map<uint32_t, uint32_t> sv_to_segment;
  for (const uint32_t label : labels) sv_to_segment[label] = 0;
  std::map<uint32_t, std::set<uint32_t>> segment_to_svs;
  uint32_t segment = 1;
  std::vector<uint32_t> stack;
  for (const uint32_t label : labels) {
    if (sv_to_segment[label] != 0) continue;
    stack.assign(1, label);
    sv_to_segment[label] = segment;
    while (!stack.empty()) {
      const uint32_t sv = stack.back();
      stack.pop_back();
      segment_to_svs[segment].insert(sv);
      for (const uint32_t other : neighbours_of(sv)) {
        if (sv_to_segment[other] == 0 &&
            valid.count({std::min(sv, other), std::max(sv, other)}) > 0) {
          sv_to_segment[other] = segment;
          stack.push_back(other);
        }
      }
    }
    ++segment;
  }
  if (min_segment_size == 0) return sv_to_segment;
  std::map<uint32_t, std::set<uint32_t>> segment_neighbours;
  const auto compute_adjacency = [&] {
    segment_neighbours.clear();
    for (const uint32_t label : labels) {
      const uint32_t current = sv_to_segment[label];
      for (const uint32_t other : neighbours_of(label)) {
        const uint32_t theirs = sv_to_segment[other];
        if (current != theirs) segment_neighbours[current].insert(theirs);
      }
    }
  };
  compute_adjacency();
  std::set<uint32_t> filtered;
  bool again = true;
  while (again) {
    again = false;
    // A pass that moves no supervoxel leaves everything as it was: PCL would repeat it
    // for ever; here it ends the merging.
    bool moved = false;
    for (const uint32_t label : labels) {
      const uint32_t current = sv_to_segment[label];
      uint32_t largest = current;
      size_t largest_size = segment_to_svs[current].size();
      if (segment_neighbours[current].empty()) continue;
      if (segment_to_svs[current].size() > min_segment_size) continue;
      again = true;
      for (const uint32_t other : segment_neighbours[current]) {
        if (segment_to_svs[other].size() >= largest_size) {
          largest = other;
          largest_size = segment_to_svs[other].size();
        }
      }
      if (largest == current || filtered.count(largest) > 0) continue;
      sv_to_segment[label] = largest;
      moved = true;
      filtered.insert(current);
      for (const uint32_t sv : segment_to_svs[current]) segment_to_svs[largest].insert(sv);
    }
    for (const uint32_t gone : filtered) segment_to_svs.erase(gone);
    compute_adjacency();
    again = again && moved;
  }
  return sv_to_segment;
}

}  // namespace

std::vector<std::vector<int>> ConvexSegments(const PointCloud& points,
                                             const ConvexSegmentationOptions& options) {
  options.Check();
  for (const Eigen::Vector3f& p : points.points) {
    SOPE_CHECK(p.allFinite(), "convex segmentation: the cloud has a non-finite point");
  }
  const int n = static_cast<int>(points.size());
  if (n < 10) {
    std::vector<int> all(n);
    for (int i = 0; i < n; ++i) all[i] = i;
    return n > 0 ? std::vector<std::vector<int>>{all} : std::vector<std::vector<int>>{};
  }
  using PointT = pcl::PointXYZRGBA;
  pcl::PointCloud<PointT>::Ptr cloud(new pcl::PointCloud<PointT>);
  cloud->resize(n);
  for (int i = 0; i < n; ++i) {
    PointT& q = (*cloud)[i];
    q.x = points.points[i].x();
    q.y = points.points[i].y();
    q.z = points.points[i].z();
    q.rgba = 0;
  }
  pcl::SupervoxelClustering<PointT> supervoxels(static_cast<float>(options.voxel_resolution),
                                               static_cast<float>(options.seed_resolution));
  // The cloud is in the camera frame but not an organised depth image: plain voxels.
  supervoxels.setUseSingleCameraTransform(false);
  supervoxels.setInputCloud(cloud);
  supervoxels.setColorImportance(0.0f);
  supervoxels.setSpatialImportance(static_cast<float>(options.spatial_importance));
  supervoxels.setNormalImportance(static_cast<float>(options.normal_importance));
  std::map<std::uint32_t, pcl::Supervoxel<PointT>::Ptr> clusters;
  supervoxels.extract(clusters);
  std::multimap<std::uint32_t, std::uint32_t> adjacency;
  supervoxels.getSupervoxelAdjacency(adjacency);
  pcl::PointCloud<pcl::PointXYZL>::Ptr labelled = supervoxels.getLabeledCloud();

  if (clusters.size() > 1) {
    pcl::LCCPSegmentation<PointT> lccp;
    lccp.setConcavityToleranceThreshold(static_cast<float>(options.concavity_tolerance_deg));
    lccp.setSanityCheck(true);
    lccp.setSmoothnessCheck(true, static_cast<float>(options.voxel_resolution),
                            static_cast<float>(options.seed_resolution),
                            static_cast<float>(options.smoothness_threshold));
    lccp.setKFactor(0);
    lccp.setMinSegmentSize(static_cast<std::uint32_t>(options.min_segment_supervoxels));
    lccp.setInputSupervoxels(clusters, adjacency);
    lccp.segment();
    // LCCP's edge classification only; its grouping and merging walk the graph's vertices
    // in address order (boost setS), which made the segments depend on the heap's layout.
    pcl::LCCPSegmentation<PointT>::SupervoxelAdjacencyList graph;
    lccp.getSVAdjacencyList(graph);
    std::vector<uint32_t> labels;
    labels.reserve(clusters.size());
    for (const auto& [label, supervoxel] : clusters) labels.push_back(label);
    std::map<uint32_t, std::vector<uint32_t>> neighbours;
    std::set<std::pair<uint32_t, uint32_t>> valid;
    for (auto [edge, end] = boost::edges(graph); edge != end; ++edge) {
      const uint32_t a = graph[boost::source(*edge, graph)];
      const uint32_t b = graph[boost::target(*edge, graph)];
      if (a == b) continue;
      neighbours[a].push_back(b);
      neighbours[b].push_back(a);
      if (graph[*edge].is_valid) valid.emplace(std::min(a, b), std::max(a, b));
    }
    for (auto& [label, list] : neighbours) std::sort(list.begin(), list.end());
    const std::map<uint32_t, uint32_t> segment_of = GroupSupervoxels(
        labels, neighbours, valid, static_cast<uint32_t>(options.min_segment_supervoxels));
    for (pcl::PointXYZL& point : *labelled) {
      const auto it = segment_of.find(point.label);
      point.label = it == segment_of.end() ? 0 : it->second;
    }
  }
  std::unordered_map<std::uint32_t, int> segment_of_label;
  std::vector<std::vector<int>> segments;
  for (int i = 0; i < n; ++i) {
    const std::uint32_t label = (*labelled)[i].label;
    if (label == 0) continue;  // no supervoxel took it
    auto [it, inserted] = segment_of_label.emplace(label, static_cast<int>(segments.size()));
    if (inserted) segments.emplace_back();
    segments[it->second].push_back(i);
  }
  std::stable_sort(segments.begin(), segments.end(),
                   [](const std::vector<int>& a, const std::vector<int>& b) {
                     return a.size() > b.size();
                   });
  return segments;
}

SeamSplit WeakestSeamSplit(const PointCloud& points,
                           const std::vector<std::vector<int>>& segments, double cell,
                           int min_points, int max_segments) {
  SOPE_CHECK(cell > 0.0 && std::isfinite(cell), "WeakestSeamSplit: cell must be > 0, got {}",
             cell);
  SOPE_CHECK(max_segments >= 2 && max_segments <= 16,
             "WeakestSeamSplit: max_segments must be in [2, 16], got {}", max_segments);
  SeamSplit best;
  const int k = std::min<int>(max_segments, static_cast<int>(segments.size()));
  if (k < 2) return best;
  // Per cell, the segments with points in it (a bit each).
  std::unordered_map<uint64_t, uint16_t> labels;
  const float inverse = static_cast<float>(1.0 / cell);
  std::vector<int64_t> sizes(k, 0);
  for (int s = 0; s < k; ++s) {
    sizes[s] = static_cast<int64_t>(segments[s].size());
    for (const int i : segments[s]) {
      const Eigen::Vector3f& p = points.points[i];
      SOPE_CHECK(p.allFinite(), "WeakestSeamSplit: point {} is not finite", i);
      labels[VoxelKeyOf(p, inverse)] |= static_cast<uint16_t>(1u << s);
    }
  }
  // contact[a][b]: cell pairs (c, d), d = c or a neighbour of c, with a in c and b in d
  // (each unordered pair of cells once).
  std::vector<std::vector<double>> contact(k, std::vector<double>(k, 0.0));
  const auto add_pair = [&](uint16_t in_c, uint16_t in_d) {
    for (int a = 0; a < k; ++a) {
      if (!(in_c >> a & 1u)) continue;
      for (int b = 0; b < k; ++b) {
        if (b != a && (in_d >> b & 1u)) contact[std::min(a, b)][std::max(a, b)] += 1.0;
      }
    }
  };
  // Keys differ by a constant per neighbour offset (each coordinate in its own bits, the
  // cells well inside the key's range).
  std::vector<uint64_t> forward;  // the 13 neighbours after a cell in key order
  for (int dx = -1; dx <= 1; ++dx) {
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dz = -1; dz <= 1; ++dz) {
        const uint64_t offset = PackVoxelKey(dx, dy, dz) - PackVoxelKey(0, 0, 0);
        if (static_cast<int64_t>(offset) > 0) forward.push_back(offset);
      }
    }
  }
  for (const auto& [key, in_c] : labels) {
    if (in_c & (in_c - 1)) add_pair(in_c, in_c);  // two segments in one cell
    for (const uint64_t offset : forward) {
      const auto it = labels.find(key + offset);
      if (it != labels.end()) add_pair(in_c, it->second);
    }
  }
  // Connected groups: segment adjacency by any contact.
  std::vector<uint32_t> adjacent(k, 0);
  for (int a = 0; a < k; ++a) {
    for (int b = a + 1; b < k; ++b) {
      if (contact[a][b] > 0.0) {
        adjacent[a] |= 1u << b;
        adjacent[b] |= 1u << a;
      }
    }
  }
  const auto connected = [&](uint32_t group) {
    uint32_t reached = group & (~group + 1u);  // its lowest segment
    while (true) {
      uint32_t grown = reached;
      for (int a = 0; a < k; ++a) {
        if (reached >> a & 1u) grown |= adjacent[a] & group;
      }
      if (grown == reached) return reached == group;
      reached = grown;
    }
  };
  const uint32_t all = (1u << k) - 1u;
  double best_ratio = std::numeric_limits<double>::infinity();
  uint32_t best_group = 0;
  // Groups holding segment 0 (the other side is its complement): each bipartition once.
  for (uint32_t group = 1; group < all; group += 2) {
    const uint32_t other = all & ~group;
    int64_t n[2] = {0, 0};
    for (int s = 0; s < k; ++s) n[(group >> s & 1u) ? 0 : 1] += sizes[s];
    const int64_t smaller = std::min(n[0], n[1]);
    if (smaller < min_points) continue;
    double across = 0.0;
    for (int a = 0; a < k; ++a) {
      for (int b = a + 1; b < k; ++b) {
        if (((group >> a) & 1u) != ((group >> b) & 1u)) across += contact[a][b];
      }
    }
    const double ratio = across / std::sqrt(static_cast<double>(smaller));
    if (ratio < best_ratio && connected(group) && connected(other)) {
      best_ratio = ratio;
      best_group = group;
      best.contact = across;
    }
  }
  if (best_group == 0) return best;
  best.segments[0] = best_group;
  best.segments[1] = all & ~best_group;
  for (int s = 0; s < k; ++s) {
    std::vector<int>& part = best.parts[(best_group >> s & 1u) ? 0 : 1];
    part.insert(part.end(), segments[s].begin(), segments[s].end());
  }
  for (std::vector<int>& part : best.parts) std::sort(part.begin(), part.end());
  return best;
}

}  // namespace sope
