// Our PLY/PCD files read by PCL's readers, and PCL's files (PLY, ASCII / binary /
// binary_compressed PCD) read by ours (issue 15). Open3D's side is in python/tests.
#include <random>

#include <gtest/gtest.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include "core/point_cloud.h"
#include "tests/test_support.h"

namespace sope {
namespace {

PointCloud RandomCloud(size_t n, uint32_t seed) {
  std::mt19937 random(seed);
  std::uniform_real_distribution<float> coordinate(-0.5f, 0.5f);
  std::uniform_int_distribution<int> channel(0, 255);
  PointCloud cloud;
  for (size_t i = 0; i < n; ++i) {
    cloud.points.emplace_back(coordinate(random), coordinate(random), coordinate(random));
    cloud.colors.emplace_back(channel(random), channel(random), channel(random));
  }
  return cloud;
}

void ExpectSame(const PointCloud& ours, const pcl::PointCloud<pcl::PointXYZRGB>& theirs) {
  ASSERT_EQ(theirs.size(), ours.size());
  for (size_t i = 0; i < ours.size(); ++i) {
    ASSERT_EQ(theirs[i].x, ours.points[i].x()) << i;
    ASSERT_EQ(theirs[i].y, ours.points[i].y()) << i;
    ASSERT_EQ(theirs[i].z, ours.points[i].z()) << i;
    ASSERT_EQ(theirs[i].r, ours.colors[i][0]) << i;
    ASSERT_EQ(theirs[i].g, ours.colors[i][1]) << i;
    ASSERT_EQ(theirs[i].b, ours.colors[i][2]) << i;
  }
}

TEST(PclRoundTrip, PclReadsOurPlyAndPcd) {
  const PointCloud cloud = RandomCloud(3000, 1);
  testing::ScratchDir scratch;
  WritePointCloud(scratch.File("ours.ply"), cloud);
  WritePointCloud(scratch.File("ours.pcd"), cloud);
  pcl::PointCloud<pcl::PointXYZRGB> from_ply, from_pcd;
  ASSERT_EQ(pcl::io::loadPLYFile(scratch.File("ours.ply"), from_ply), 0);
  ASSERT_EQ(pcl::io::loadPCDFile(scratch.File("ours.pcd"), from_pcd), 0);
  ExpectSame(cloud, from_ply);
  ExpectSame(cloud, from_pcd);
}

TEST(PclRoundTrip, WeReadPclsFiles) {
  const PointCloud cloud = RandomCloud(3000, 2);
  pcl::PointCloud<pcl::PointXYZRGB> theirs;
  for (size_t i = 0; i < cloud.size(); ++i) {
    pcl::PointXYZRGB point;
    point.x = cloud.points[i].x();
    point.y = cloud.points[i].y();
    point.z = cloud.points[i].z();
    point.r = cloud.colors[i][0];
    point.g = cloud.colors[i][1];
    point.b = cloud.colors[i][2];
    theirs.push_back(point);
  }
  testing::ScratchDir scratch;
  ASSERT_EQ(pcl::io::savePCDFileBinary(scratch.File("binary.pcd"), theirs), 0);
  ASSERT_EQ(pcl::io::savePCDFileBinaryCompressed(scratch.File("compressed.pcd"), theirs), 0);
  ASSERT_EQ(pcl::io::savePCDFileASCII(scratch.File("ascii.pcd"), theirs), 0);
  ASSERT_EQ(pcl::io::savePLYFileBinary(scratch.File("binary.ply"), theirs), 0);
  for (const char* name : {"binary.pcd", "compressed.pcd", "ascii.pcd", "binary.ply"}) {
    SCOPED_TRACE(name);
    const PointCloud read = ReadPointCloud(scratch.File(name));
    ASSERT_EQ(read.size(), cloud.size());
    ASSERT_TRUE(read.HasColors());
    for (size_t i = 0; i < cloud.size(); ++i) {
      // ASCII PCD prints 8 significant digits: within a float's rounding there.
      ASSERT_NEAR(read.points[i].x(), cloud.points[i].x(), 1e-7f) << i;
      ASSERT_NEAR(read.points[i].y(), cloud.points[i].y(), 1e-7f) << i;
      ASSERT_NEAR(read.points[i].z(), cloud.points[i].z(), 1e-7f) << i;
      ASSERT_EQ(read.colors[i], cloud.colors[i]) << i;
    }
  }
}

}  // namespace
}  // namespace sope
