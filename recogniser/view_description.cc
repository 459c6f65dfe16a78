#include "recogniser/view_description.h"

#include "core/stopwatch.h"
#include "recogniser/pose.h"

namespace sope {
namespace {

void RotateCloud(const Eigen::Matrix3f& rotation, PointCloud* cloud) {
  for (Eigen::Vector3f& p : cloud->points) p = rotation * p;
  for (Eigen::Vector3f& n : cloud->normals) n = rotation * n;
}

}  // namespace

Eigen::Matrix3d Canonicalise(PreprocessedCloud* cloud) {
  const Eigen::Matrix3d cam_from_canonical = CamFromCanonical(cloud->centroid.cast<double>());
  const Eigen::Matrix3f canonical_from_cam = cam_from_canonical.transpose().cast<float>();
  RotateCloud(canonical_from_cam, &cloud->cloud);
  RotateCloud(canonical_from_cam, &cloud->normalised);
  cloud->centroid = canonical_from_cam * cloud->centroid;
  return cam_from_canonical;
}

ViewDescription DescribeView(const PointCloud& cloud, const PreprocessOptions& preprocess,
                             const FeatureOptions& features) {
  ViewDescription description;
  Stopwatch watch;
  description.preprocessed = Preprocess(cloud, preprocess);
  description.cam_from_canonical = Canonicalise(&description.preprocessed);
  description.preprocess_ms = watch.WallMs();
  description.preprocess_cpu_ms = watch.CpuMs();
  watch.Restart();
  description.features = ComputeFeatures(description.preprocessed, features);
  const float fine_sum = description.features.fine.cwiseAbs().sum();
  if (fine_sum > 0.0f) description.features.fine /= fine_sum;
  description.features_ms = watch.WallMs();
  description.features_cpu_ms = watch.CpuMs();
  return description;
}

}  // namespace sope
