#include "core/point_cloud.h"

#include "core/error.h"

namespace sope {

void PointCloud::Check() const {
  SOPE_CHECK(colors.empty() || colors.size() == points.size(),
             "point cloud has {} colours for {} points", colors.size(), points.size());
  SOPE_CHECK(normals.empty() || normals.size() == points.size(),
             "point cloud has {} normals for {} points", normals.size(), points.size());
}

size_t PointCloud::CountFinite() const {
  size_t count = 0;
  for (const Eigen::Vector3f& point : points) count += point.allFinite() ? 1 : 0;
  return count;
}

}  // namespace sope
