// Splitting a cluster of touching objects along its concave seams (issue 12): Locally
// Convex Connected Patches (Stein et al., "Object Partitioning using Local Convexity",
// CVPR 2014; pcl::LCCPSegmentation on pcl::SupervoxelClustering). Supervoxels of the
// cluster are joined across convex or smooth boundaries and kept apart across concave
// ones — two objects resting against each other meet in a concave seam, while a can, a box
// or a bottle is convex all round. An object with concave parts (a drill's handle) comes
// out in several segments; SceneRecogniser recognises the segments as well as the whole
// cluster and lets the scene verification choose (recogniser/scene_recognition.h).
// No PCL in this header.
#pragma once

#include <vector>

#include "core/point_cloud.h"

namespace sope {

struct ConvexSegmentationOptions {
  // Supervoxels: voxel and seed resolutions (metres), and the weights of the distance in
  // space and between normals when voxels are assigned to seeds.
  double voxel_resolution = 0.004;
  double seed_resolution = 0.02;
  double spatial_importance = 1.0;
  double normal_importance = 4.0;
  // LCCP: a boundary is concave when its normals close in by more than this (degrees);
  // neighbours whose normals and centroids agree within the smoothness threshold are
  // joined regardless (PCL's smoothness check, a fraction of the seed resolution).
  double concavity_tolerance_deg = 10.0;
  double smoothness_threshold = 0.1;
  // Segments of fewer supervoxels are merged into their largest neighbour.
  int min_segment_supervoxels = 3;
  void Check() const;  // throws sope::Error naming the invalid value
};

// The segments of `points` (camera frame, metres; normals ignored), each the indices of
// its points into `points`, increasing; largest first. Points no supervoxel took (isolated
// specks) are in no segment. Fewer than 10 points: one segment of them all. Throws
// sope::Error on invalid options or a non-finite point. Deterministic.
std::vector<std::vector<int>> ConvexSegments(const PointCloud& points,
                                             const ConvexSegmentationOptions& options = {});

}  // namespace sope
