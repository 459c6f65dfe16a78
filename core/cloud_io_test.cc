#include <fstream>

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/file_util.h"
#include "core/point_cloud.h"
#include "tests/test_support.h"

namespace sope {
namespace {

PointCloud TestCloud(bool colors, bool normals) {
  PointCloud cloud;
  for (int i = 0; i < 100; ++i) {
    cloud.points.emplace_back(0.01f * i, -0.5f + 0.003f * i, 0.6f + 1e-4f * i);
    if (colors) cloud.colors.emplace_back(i, 255 - i, 2 * i);
    if (normals) cloud.normals.push_back(Eigen::Vector3f(0.1f * i, 1, -1).normalized());
  }
  return cloud;
}

void ExpectSame(const PointCloud& a, const PointCloud& b, float tolerance) {
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(a.HasColors(), b.HasColors());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_LE((a.points[i] - b.points[i]).norm(), tolerance);
    if (a.HasColors()) {
      EXPECT_EQ(a.colors[i], b.colors[i]);
    }
  }
}

TEST(CloudIo, PlyBinaryAndAsciiRoundTrip) {
  testing::ScratchDir scratch;
  for (bool colors : {false, true}) {
    for (bool normals : {false, true}) {
      const PointCloud cloud = TestCloud(colors, normals);
      WritePointCloud(scratch.File("b.ply"), cloud);
      ExpectSame(cloud, ReadPointCloud(scratch.File("b.ply")), 0.0f);
      WritePointCloud(scratch.File("a.ply"), cloud, PlyFormat::kAscii);
      const PointCloud ascii = ReadPointCloud(scratch.File("a.ply"));
      ExpectSame(cloud, ascii, 0.0f);
      EXPECT_EQ(ascii.HasNormals(), normals);
    }
  }
}

TEST(CloudIo, PcdRoundTrip) {
  testing::ScratchDir scratch;
  for (bool colors : {false, true}) {
    const PointCloud cloud = TestCloud(colors, false);
    WritePointCloud(scratch.File("c.pcd"), cloud);
    ExpectSame(cloud, ReadPointCloud(scratch.File("c.pcd")), 0.0f);
  }
}

TEST(CloudIo, BigEndianDoublePly) {
  testing::ScratchDir scratch;
  std::string bytes =
      "ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty double x\n"
      "property double y\nproperty double z\nend_header\n";
  for (double v : {1.5, -2.25, 3.0}) {
    unsigned char raw[8];
    std::memcpy(raw, &v, 8);
    for (int k = 7; k >= 0; --k) bytes.push_back(static_cast<char>(raw[k]));
  }
  WriteFileAtomic(scratch.File("be.ply"), bytes);
  const PointCloud cloud = ReadPointCloud(scratch.File("be.ply"));
  ASSERT_EQ(cloud.size(), 1u);
  EXPECT_EQ(cloud.points[0], Eigen::Vector3f(1.5f, -2.25f, 3.0f));
}

TEST(CloudIo, TruncatedAndMalformedFilesAreErrors) {
  testing::ScratchDir scratch;
  WritePointCloud(scratch.File("full.ply"), TestCloud(true, false));
  std::string bytes = ReadFileToString(scratch.File("full.ply"), "test");
  WriteFileAtomic(scratch.File("cut.ply"), bytes.substr(0, bytes.size() - 10));
  EXPECT_THROW_WITH_MESSAGE(ReadPointCloud(scratch.File("cut.ply")), Error, "cut.ply", "truncated");
  WriteFileAtomic(scratch.File("magic.ply"), "plx\nformat ascii 1.0\nend_header\n");
  EXPECT_THROW_WITH_MESSAGE(ReadPointCloud(scratch.File("magic.ply")), Error, "magic.ply", "magic");
  WriteFileAtomic(scratch.File("noxyz.ply"),
                  "ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n");
  EXPECT_THROW_WITH_MESSAGE(ReadPointCloud(scratch.File("noxyz.ply")), Error, "noxyz.ply",
                            "x, y, z");
  WriteFileAtomic(scratch.File("bad.pcd"), "# .PCD v0.7\nFIELDS x y\nnonsense");
  EXPECT_THROW_WITH_MESSAGE(ReadPointCloud(scratch.File("bad.pcd")), Error, "bad.pcd");
  EXPECT_THROW_WITH_MESSAGE(ReadPointCloud(scratch.File("cloud.xyz")), Error, "cloud.xyz", "'xyz'");
  EXPECT_THROW_WITH_MESSAGE(ReadPointCloud(scratch.File("missing.ply")), Error, "missing.ply",
                            "no such file");
}

TEST(CloudIo, MismatchedAttributesRefusedOnWrite) {
  testing::ScratchDir scratch;
  PointCloud cloud = TestCloud(true, false);
  cloud.colors.pop_back();
  EXPECT_THROW_WITH_MESSAGE(WritePointCloud(scratch.File("x.ply"), cloud), Error,
                            "99 colours for 100 points");
}

}  // namespace
}  // namespace sope
