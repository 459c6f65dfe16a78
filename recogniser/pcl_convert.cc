#include "recogniser/pcl_convert.h"

#include <cmath>

#include "core/error.h"

namespace sope {
namespace internal {
namespace {

bool IsFinite(const Eigen::Vector3f& p) {
  return std::isfinite(p.x()) && std::isfinite(p.y()) && std::isfinite(p.z());
}

template <typename PclCloud>
void SetOrganisation(PclCloud* cloud, bool dense) {
  cloud->width = static_cast<uint32_t>(cloud->size());
  cloud->height = 1;
  cloud->is_dense = dense;
}

float CurvatureAt(const std::vector<float>& curvature, size_t count, size_t i) {
  return curvature.size() == count ? curvature[i] : 0.0f;
}

}  // namespace

pcl::PointCloud<pcl::PointXYZ>::Ptr ToPclXyz(const PointCloud& cloud) {
  auto out = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  out->resize(cloud.size());
  bool dense = true;
  for (size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3f& p = cloud.points[i];
    (*out)[i].getVector3fMap() = p;
    dense = dense && IsFinite(p);
  }
  SetOrganisation(out.get(), dense);
  return out;
}

pcl::PointCloud<pcl::PointNormal>::Ptr ToPclPointNormal(const PointCloud& cloud,
                                                        const std::vector<float>& curvature) {
  SOPE_CHECK(cloud.normals.size() == cloud.size(),
             "ToPclPointNormal: the cloud has {} points but {} normals", cloud.size(),
             cloud.normals.size());
  auto out = pcl::make_shared<pcl::PointCloud<pcl::PointNormal>>();
  out->resize(cloud.size());
  bool dense = true;
  for (size_t i = 0; i < cloud.size(); ++i) {
    pcl::PointNormal& q = (*out)[i];
    q.getVector3fMap() = cloud.points[i];
    q.getNormalVector3fMap() = cloud.normals[i];
    q.curvature = CurvatureAt(curvature, cloud.size(), i);
    dense = dense && IsFinite(cloud.points[i]) && IsFinite(cloud.normals[i]);
  }
  SetOrganisation(out.get(), dense);
  return out;
}

pcl::PointCloud<pcl::Normal>::Ptr ToPclNormals(const PointCloud& cloud,
                                               const std::vector<float>& curvature) {
  SOPE_CHECK(cloud.normals.size() == cloud.size(),
             "ToPclNormals: the cloud has {} points but {} normals", cloud.size(),
             cloud.normals.size());
  auto out = pcl::make_shared<pcl::PointCloud<pcl::Normal>>();
  out->resize(cloud.size());
  bool dense = true;
  for (size_t i = 0; i < cloud.size(); ++i) {
    pcl::Normal& n = (*out)[i];
    n.getNormalVector3fMap() = cloud.normals[i];
    n.curvature = CurvatureAt(curvature, cloud.size(), i);
    dense = dense && IsFinite(cloud.normals[i]);
  }
  SetOrganisation(out.get(), dense);
  return out;
}

PointCloud FromPcl(const pcl::PointCloud<pcl::PointXYZ>& cloud) {
  PointCloud out;
  out.points.reserve(cloud.size());
  for (const pcl::PointXYZ& p : cloud) out.points.push_back(p.getVector3fMap());
  return out;
}

PointCloud FromPcl(const pcl::PointCloud<pcl::PointNormal>& cloud, std::vector<float>* curvature) {
  PointCloud out;
  out.points.reserve(cloud.size());
  out.normals.reserve(cloud.size());
  if (curvature != nullptr) {
    curvature->clear();
    curvature->reserve(cloud.size());
  }
  for (const pcl::PointNormal& p : cloud) {
    out.points.push_back(p.getVector3fMap());
    out.normals.push_back(p.getNormalVector3fMap());
    if (curvature != nullptr) curvature->push_back(p.curvature);
  }
  return out;
}

}  // namespace internal
}  // namespace sope
