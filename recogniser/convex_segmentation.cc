#include "recogniser/convex_segmentation.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <unordered_map>

#include <pcl/point_types.h>
#include <pcl/segmentation/lccp_segmentation.h>
#include <pcl/segmentation/supervoxel_clustering.h>

#include "core/error.h"

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
    lccp.relabelCloud(*labelled);
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

}  // namespace sope
