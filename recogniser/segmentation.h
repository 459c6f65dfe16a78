// Tabletop segmentation (issue 12): the dominant plane of a scan (the table), the points
// above it, and their Euclidean clusters — one per object, or one per group of touching
// objects (SceneRecogniser resolves those by recognising the cluster's remainder again,
// recogniser/scene_recognition.h). The single-object case keeps the range band
// (recogniser/tools/scan_recognition.h SegmentByRange).
//
// Method (Rusu 2009, "Semantic 3D object maps", ch. 6; PCL's tabletop pipeline):
//  1. RANSAC plane (pcl::SACSegmentation, SACMODEL_PLANE) on an even subsample of the
//     cloud, refined by least squares on all its inliers; the normal is turned towards the
//     camera (origin), so height h(p) = n·p + d is positive above the table.
//  2. Points with h in [min_height, max_height] (and inside the range band), voxel-thinned.
//  3. Euclidean clusters of the thinned points (voxel centroids) with a tolerance of
//     cluster_tolerance (0: 2.5 voxel leaves — scale-aware: it follows the sampling, not
//     the object): connected components of "within the tolerance", found by union-find over
//     a hash grid of cells one tolerance wide (each centroid meets only the centroids of its
//     27 cells: O(n), no tree). The same connectivity as pcl::EuclideanClusterExtraction,
//     which is kept as an option (clustering = kPclKdTree, the peer of
//     bench/table_latency_bench). Each raw point joins its voxel's cluster.
// No plane (fewer than min_plane_fraction of the points on it) is a result, not an error:
// the table is not in view. No PCL in this header.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/point_cloud.h"

namespace sope {

struct TableSegmentationOptions {
  // Range band, metres from the camera (‖p‖): points outside are ignored altogether.
  double min_range = 0.05;
  double max_range = 2.0;
  // RANSAC: inlier distance (metres), iterations, and the points it samples from (an even
  // subsample of the cloud: the plane is found in the same time on any scan size).
  double plane_distance = 0.004;
  int plane_iterations = 200;
  int plane_samples = 6000;
  // The plane must hold at least this fraction of the finite points in the band.
  double min_plane_fraction = 0.15;
  // Height band above the plane, metres: objects start min_height above it (the plane's
  // noise stays out) and end max_height above it.
  double min_height = 0.006;
  double max_height = 0.4;
  // Voxel leaf of the thinned points above the plane (metres) and the clustering distance
  // (metres; 0: 2.5 × cluster_leaf).
  double cluster_leaf = 0.003;
  double cluster_tolerance = 0.0;
  // How the clusters are found: the hash-grid union-find (default) or PCL's kd-tree
  // Euclidean cluster extraction (the former method; same clusters, several times slower).
  enum class Clustering { kGrid, kPclKdTree };
  Clustering clustering = Clustering::kGrid;
  // Clusters with fewer raw points are dropped (specks, the plane's ragged edge).
  int min_cluster_points = 150;
  // A cloud of more points (in the band) is evenly subsampled to about this many first
  // (every k-th point, in cloud order — for a triangulated scan, a regular pixel pattern):
  // the plane, the clusters and their indices then refer to the kept points. A 1280×720
  // scan of a table holds ~600k points; recognition thins to 4 mm voxels anyway.
  int max_points = 150000;
  // The clustering distance in effect: cluster_tolerance, or 2.5 × cluster_leaf when 0.
  double ClusterTolerance() const {
    return cluster_tolerance > 0 ? cluster_tolerance : 2.5 * cluster_leaf;
  }
  // Throws sope::Error naming the invalid value.
  void Check() const;
};

struct TablePlane {
  bool found = false;
  // n·p + d = 0, n unit, facing the camera (d > 0: the camera is above the table).
  Eigen::Vector3f normal = Eigen::Vector3f::UnitZ();
  float offset = 0.0f;
  int inliers = 0;  // raw points within plane_distance
  // Height of `point` above the table, metres (camera frame).
  float Height(const Eigen::Vector3f& point) const { return normal.dot(point) + offset; }
};

struct ObjectCluster {
  std::vector<int> indices;  // into the input cloud, increasing
  PointCloud cloud;          // those points (with their colours)
  Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
};

struct TableSegmentation {
  TablePlane plane;
  std::vector<ObjectCluster> clusters;  // largest first (ties: lowest first index)
  int finite_points = 0;                // in the range band
  int above_points = 0;                 // in the height band
  double ms = 0.0;                      // wall clock
  // Why there is no cluster ("no plane: 120 of 5000 points on the best plane", "nothing
  // above the table"); empty when there are clusters.
  std::string message;
};

// Throws sope::Error on invalid options, on a cloud with a non-finite point (the message
// gives the count) and on a cloud of fewer than 3 points (no plane can be fitted). A cloud
// without a plane or with nothing on the table gives no clusters and says why.
TableSegmentation SegmentTable(const PointCloud& cloud, const TableSegmentationOptions& options = {});

// Connected components of `points` under "distance ≤ tolerance" (metres): union-find over
// a hash grid of cells `tolerance` wide. Each component's point indices, in increasing
// order of their first point.
std::vector<std::vector<int>> GridEuclideanClusters(const std::vector<Eigen::Vector3f>& points,
                                                    double tolerance);

// The table plane alone (SegmentTable's first step, on the same points): `found` false
// when there is none. For a cloud of finite points (a triangulated scan); throws
// sope::Error on invalid options.
TablePlane FindTablePlane(const PointCloud& cloud, const TableSegmentationOptions& options = {});

}  // namespace sope
