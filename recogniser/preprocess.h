// Pre-processing of a query or database cloud (thesis §4.2): range band, statistical
// outlier removal, voxel-grid thinning, normals, and size normalisation into the unit
// ball. The stages have the semantics of PCL's ConditionalRemoval (on ‖p‖), VoxelGrid,
// StatisticalOutlierRemoval and NormalEstimation (k neighbours) and are checked against
// them in preprocess_test.cc; they run on a hashed-grid k-NN (recogniser/cloud_filters.h):
// PCL's VoxelGrid + StatisticalOutlierRemoval + NormalEstimation take ≈ 6 ms on a 93k-point
// view, these ≈ 3 ms (bench/features_bench.cc). Order: finite + range band, then voxel
// grid, then outlier removal (statistics weighted by the raw points per voxel, see
// outlier_min_ratio) and normals on the thinned cloud. No PCL in this header.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/enum_strings.h"
#include "core/point_cloud.h"

namespace sope {

enum class ScaleNormalisation {
  kFarthest,  // thesis: the farthest point from the centroid lies on the unit sphere
  kMedian,    // thesis's robust variant: the median distance of the points beyond the
              // `median_fraction` quantile (outliers cannot inflate it)
};
template <>
struct EnumTable<ScaleNormalisation> {
  static constexpr const char* kWhat = "scale normalisation";
  static constexpr EnumName<ScaleNormalisation> kNames[] = {
      {ScaleNormalisation::kFarthest, "farthest"}, {ScaleNormalisation::kMedian, "median"}};
};
std::string ToString(ScaleNormalisation mode);
ScaleNormalisation ScaleNormalisationFromString(const std::string& text);  // farthest|median

struct PreprocessOptions {
  // Range band (thesis: conditional / pass-through filter, also the segmentation): keep
  // points whose distance from the sensor (‖p‖, metres) lies in [min_range, max_range].
  double min_range = 0.05;
  double max_range = 2.0;
  // Statistical outlier removal (PCL StatisticalOutlierRemoval): k neighbours, reject a
  // mean neighbour distance beyond mean + outlier_stddev · σ. 0 neighbours disables.
  int outlier_neighbours = 16;
  double outlier_stddev = 2.0;
  // sope addition: floor of that threshold as a multiple of the mean neighbour distance — a
  // point is rejected only when its mean distance exceeds both mean + outlier_stddev·σ and
  // outlier_min_ratio·mean. On the voxel-thinned cloud the spacing is nearly constant, σ
  // only reflects lattice jitter, and mean + 2σ alone strips 5–11 % of a clean view (its
  // silhouette; measured on rendered procedural objects); with 2 ≥ 99.7 % is kept and
  // isolated outliers ≥ 3 cm off the surface are still all removed. 0 gives PCL's rule.
  // The mean and σ are weighted by the raw points behind each voxel, so they describe the
  // raw cloud, where sparse outliers are few (unweighted, 1 % raw outliers become ≈ 20 % of
  // the voxels and hundreds survive).
  double outlier_min_ratio = 2.0;
  // Voxel grid leaf, metres (centroid per voxel). 0 disables.
  double voxel_leaf = 0.004;
  // Normals from this many nearest neighbours (PCL NormalEstimation), oriented towards
  // the sensor at the origin.
  int normal_neighbours = 12;
  ScaleNormalisation normalisation = ScaleNormalisation::kMedian;
  double median_fraction = 0.8;  // kMedian: quantile beyond which points are ranked
  // Clouds with fewer points than this after filtering are refused (sope::Error).
  int min_points = 50;

  void Check() const;
};

// How many points each stage left (for reports and for the error message).
struct PreprocessSummary {
  int64_t input_points = 0;
  int64_t finite_points = 0;    // all coordinates finite
  int64_t in_range_points = 0;  // ... and min_range ≤ ‖p‖ ≤ max_range
  int64_t voxel_points = 0;     // after the voxel grid (= in_range_points when disabled)
  int64_t inlier_points = 0;    // after statistical outlier removal
  int64_t final_points = 0;     // with a valid normal: the size of the output clouds
  // "100000 input → 99000 finite → … → 1500 with normals".
  std::string BriefReport() const;
};

struct PreprocessedCloud {
  // Filtered, thinned cloud in the sensor (camera) frame, metres, with unit normals
  // facing the sensor.
  PointCloud cloud;
  // Centroid of `cloud` (camera frame, metres) and the normalisation radius (metres):
  // normalised = (cloud − centroid) / radius (inside the unit ball with kFarthest).
  Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
  float radius = 1.0f;
  // The same points centred and scaled (viewer-centred frame: axes stay the camera's, no
  // PCA alignment — thesis §4.2.4), with the same normals. With kMedian a few points
  // (≈ (1 − median_fraction)/2 of them) lie just outside the unit ball.
  PointCloud normalised;
  // Surface variation λ0 / (λ0 + λ1 + λ2) of each point's normal neighbourhood (PCL's
  // NormalEstimation "curvature"), one per point of `cloud`; used by CVFH / OUR-CVFH.
  std::vector<float> curvature;
  PreprocessSummary summary;
};

// Input normals and colours are ignored: normals are always re-estimated on the thinned
// cloud, so database views and scanned queries get the same estimator.
// Throws sope::Error with one clear message on invalid options, an empty cloud, a cloud
// with no finite point, no point in the range band, or fewer than options.min_points
// points left after filtering (the message gives the count after every stage).
PreprocessedCloud Preprocess(const PointCloud& cloud, const PreprocessOptions& options = {});

}  // namespace sope
