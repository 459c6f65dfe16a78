// Internal to recogniser/: conversions between sope::PointCloud and pcl::PointCloud for the
// PCL algorithms we use (filters, normals, VFH, ICP, kd-trees). Include this header from
// .cc files only — it pulls PCL in, and no public header may (DESIGN.md).
//
// Build note. Debian's PCL is compiled for generic x86-64 (Eigen aligns to 16 bytes) while
// sope builds with -march=native (AVX/AVX-512: Eigen aligns fixed-size types and heap
// blocks to 32/64 bytes). Calling PCL's precompiled template instantiations from our code
// then mixes two Eigen ABIs — e.g. pcl::VFHEstimation's Eigen::VectorXf members allocated
// by the library are freed by our inline destructor with a different aligned-free — and
// corrupts the heap. So every sope_recogniser translation unit is compiled with
// PCL_NO_PRECOMPILE (recogniser/CMakeLists.txt): the PCL templates are instantiated here,
// with our flags, and the precompiled copies in libpcl_*.so are not called. Only
// non-template, Eigen-free PCL entry points are taken from the shared libraries.
#pragma once

#ifndef PCL_NO_PRECOMPILE
#error "recogniser/ must be compiled with PCL_NO_PRECOMPILE (see recogniser/pcl_convert.h)"
#endif

#include <vector>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include "core/point_cloud.h"

namespace sope {
namespace internal {

// Points only (normals and colours dropped). width = size, height = 1, is_dense when every
// point is finite.
pcl::PointCloud<pcl::PointXYZ>::Ptr ToPclXyz(const PointCloud& cloud);
// Points and normals; curvature set from `curvature` when it has one value per point,
// else 0. Throws sope::Error when the cloud has no normals.
pcl::PointCloud<pcl::PointNormal>::Ptr ToPclPointNormal(const PointCloud& cloud,
                                                        const std::vector<float>& curvature = {});
// Normals only (with curvature as above). Throws sope::Error when the cloud has no normals.
pcl::PointCloud<pcl::Normal>::Ptr ToPclNormals(const PointCloud& cloud,
                                               const std::vector<float>& curvature = {});

// Back to sope: points (and normals for PointNormal; curvature into *curvature when given).
PointCloud FromPcl(const pcl::PointCloud<pcl::PointXYZ>& cloud);
PointCloud FromPcl(const pcl::PointCloud<pcl::PointNormal>& cloud,
                   std::vector<float>* curvature = nullptr);

}  // namespace internal
}  // namespace sope
