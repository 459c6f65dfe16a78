#include <filesystem>
#include <fstream>
#include <vector>

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

// Colour values a byte cannot hold (an ASCII "uchar" of 1208, negative ones) are clamped,
// not cast (undefined behaviour; found by ply_fuzz, 2026-12-05): the cloud is read.
TEST(CloudIo, OutOfRangeColoursAreClamped) {
  testing::ScratchDir scratch;
  WriteFileAtomic(scratch.File("c.ply"),
                  "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                  "property float z\nproperty uchar red\nproperty uchar green\n"
                  "property uchar blue\nend_header\n0 0 1 1208 -5 -1e9\n0 0 2 254.7 0 255\n");
  const PointCloud cloud = ReadPointCloud(scratch.File("c.ply"));
  ASSERT_EQ(cloud.size(), 2u);
  ASSERT_TRUE(cloud.HasColors());
  EXPECT_EQ(cloud.colors[0], Color3ub(255, 0, 0));
  EXPECT_EQ(cloud.colors[1], Color3ub(254, 0, 255));
}

TEST(CloudIo, MismatchedAttributesRefusedOnWrite) {
  testing::ScratchDir scratch;
  PointCloud cloud = TestCloud(true, false);
  cloud.colors.pop_back();
  EXPECT_THROW_WITH_MESSAGE(WritePointCloud(scratch.File("x.ply"), cloud), Error,
                            "99 colours for 100 points");
}

// Issue 13: an empty PCD, "hello world" or only "VERSION 0.7" crashed pcl::PCDReader
// (SIGSEGV); the header is validated before PCL sees the file.
TEST(CloudIo, MalformedPcdHeadersAreClearErrors) {
  testing::ScratchDir scratch;
  auto error_for = [&](const std::string& text) -> std::string {
    WriteFileAtomic(scratch.File("bad.pcd"), text);
    try {
      ReadPointCloud(scratch.File("bad.pcd"));
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  const std::string header =
      "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
      "WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\n";
  struct Case {
    std::string text, needle;
  };
  const std::vector<Case> cases = {
      {"", "empty file"},
      {"hello world", "not a PCD file"},
      {"VERSION 0.7\n", "ends before its DATA line"},
      {"VERSION 0.7", "ends before its DATA line"},
      // pcd_fuzz (crash-7ee1a620…): a lone "\r" header line crashed PCL's reader (SEGV).
      {"##}\r\n\r\n\n" + header + "DATA ascii\n0 0 1\n0 0 1\n0 0 1\n", "line 2 is blank"},
      {header + "   \nDATA ascii\n0 0 1\n0 0 1\n0 0 1\n", "line 11 is blank"},
      {header + "DATA binary\n" + std::string(20, '\0'), "truncated"},
      {header + "DATA ascii\n0 0 0.5\n", "truncated"},
      {header + "DATA binary_compressed\n", "compressed data truncated"},
      {"FIELDS x y z\nSIZE 4 4\nTYPE F F F\nWIDTH 1\nDATA ascii\n0 0 1\n", "2 sizes"},
      {"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nPOINTS 7\nDATA ascii\n0 0 1\n",
       "POINTS 7"},
      {"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH -1\nDATA ascii\n", "WIDTH '-1'"},
      {"FIELDS x y z\nSIZE 4 4 3\nTYPE F F F\nWIDTH 1\nDATA ascii\n0 0 1\n", "size 3"},
      {"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 99999999999\nHEIGHT 99999999999\n"
       "DATA binary\n", "beyond the limit"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.text.substr(0, 60));
    const std::string error = error_for(c.text);
    EXPECT_NE(error.find("bad.pcd"), std::string::npos) << error;
    EXPECT_NE(error.find(c.needle), std::string::npos) << error;
  }
  // The same header with its data reads.
  EXPECT_EQ(error_for(header + "DATA ascii\n0 0 0.5\n0 0.1 0.5\n0.1 0 0.5\n"), "");
  EXPECT_EQ(ReadPointCloud(scratch.File("bad.pcd")).size(), 3u);
}

TEST(CloudIo, PcdWriteLeavesNoTemporary) {
  testing::ScratchDir scratch;
  WritePointCloud(scratch.File("c.pcd"), TestCloud(false, false));
  EXPECT_EQ(internal::RegisteredTemporaryCount(), 0u);
  size_t entries = 0;
  for ([[maybe_unused]] const auto& entry : std::filesystem::directory_iterator(scratch.path())) {
    ++entries;
  }
  EXPECT_EQ(entries, 1u);
}

}  // namespace
}  // namespace sope
