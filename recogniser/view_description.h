// One code path that turns a partial view into what the database stores and the query is
// compared with — used by the database builder for every rendered view and by the
// recogniser for every query, so both are pre-processed and featurised identically.
//
//   Preprocess (recogniser/preprocess.h) → canonical frame → ComputeFeatures
//
// The canonical frame (recogniser/pose.h) turns the sensor about its centre so that the
// view's centroid lies on the optical axis: the thesis's viewer-centred features then do
// not depend on where in the image the object appears (a database camera looks at the
// model's centre; a query object can be anywhere in the field of view), and the only
// freedom left between a query and a database view of the same aspect is the roll about
// that axis.
#pragma once

#include <Eigen/Core>

#include "core/point_cloud.h"
#include "core/stopwatch.h"
#include "recogniser/features.h"
#include "recogniser/preprocess.h"

namespace sope {

struct ViewDescription {
  // The pre-processed view with cloud, normals, centroid and normalised cloud expressed
  // in the canonical frame (centroid = (0, 0, ‖centroid‖)).
  PreprocessedCloud preprocessed;
  // X_cam = cam_from_canonical · X_canonical (a rotation about the sensor centre).
  Eigen::Matrix3d cam_from_canonical = Eigen::Matrix3d::Identity();
  // features.fine is scaled to unit L1 norm (histograms compared as distributions).
  ViewFeatures features;
  // Wall-clock and calling-thread CPU time of the two stages, milliseconds.
  double preprocess_ms = 0.0;
  double features_ms = 0.0;
  double preprocess_cpu_ms = 0.0;
  double features_cpu_ms = 0.0;
};

// Rotates a pre-processed cloud (points, normals, centroid, normalised points and normals)
// into its canonical frame; returns cam_from_canonical.
Eigen::Matrix3d Canonicalise(PreprocessedCloud* cloud);

// Preprocess → Canonicalise → ComputeFeatures → fine vector to unit L1 norm. `cloud` in the sensor frame (metres).
// Throws sope::Error from Preprocess (empty, no finite point, too few points) or
// ComputeFeatures.
ViewDescription DescribeView(const PointCloud& cloud, const PreprocessOptions& preprocess,
                             const FeatureOptions& features);

}  // namespace sope
