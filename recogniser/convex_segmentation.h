// Splitting a cluster of touching objects along its concave seams (issue 12): Locally
// Convex Connected Patches (Stein et al., "Object Partitioning using Local Convexity",
// CVPR 2014; pcl::LCCPSegmentation on pcl::SupervoxelClustering). Supervoxels of the
// cluster are joined across convex or smooth boundaries and kept apart across concave
// ones — two objects resting against each other meet in a concave seam, while a can, a box
// or a bottle is convex all round. An object with concave parts (a drill's handle) comes
// out in several segments; SceneRecogniser recognises the segments as well as the whole
// cluster and lets the scene verification choose (recogniser/scene_recognition.h).
// LCCP's grouping and its merging of small segments are PCL's steps, run here in the
// supervoxels' label order: PCL walks its graph's vertices in address order, which made
// the segments depend on the heap's layout (README, Tabletop scenes).
// No PCL in this header.
#pragma once

#include <cstdint>
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

// Two touching objects, each of several convex segments (a figurine lying against another:
// head, ears, limbs), are split by no single segment; they meet in a short seam, whereas
// the segments of one object share longer ones. The two-way split of `points` along its
// weakest seam: of the bipartitions of the first max_segments `segments` (ConvexSegments'
// output, largest first; points of the others are in neither part) into two groups each
// connected and of at least min_points points, the one whose contact — the pairs of
// neighbouring cells of side `cell` metres (26-neighbourhood, a cell with itself
// included) holding points of the one group and of the other — is smallest relative to the
// square root of the smaller group's points (a seam's length against the size of what it
// cuts off). Returns the two groups' point indices (increasing), or two empty vectors when
// no bipartition qualifies (fewer than 2 segments, or none of that size). Deterministic.
struct SeamSplit {
  std::vector<int> parts[2];
  uint32_t segments[2] = {0, 0};  // each part's segments, a bit each (segment 0 in part 0)
  double contact = 0.0;           // cell pairs across the seam
};
SeamSplit WeakestSeamSplit(const PointCloud& points,
                           const std::vector<std::vector<int>>& segments, double cell,
                           int min_points, int max_segments = 10);

}  // namespace sope
