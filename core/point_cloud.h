// Point clouds and their files (DESIGN.md "Point clouds"). PCL stays out of this header;
// recogniser/ converts to pcl::PointCloud where PCL algorithms need it.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace sope {

using Color3ub = Eigen::Matrix<uint8_t, 3, 1>;  // red, green, blue

struct PointCloud {
  std::vector<Eigen::Vector3f> points;  // metres, in the frame the producer states
  std::vector<Color3ub> colors;         // empty, or one per point
  std::vector<Eigen::Vector3f> normals; // empty, or one unit normal per point

  size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
  bool HasColors() const { return !colors.empty(); }
  bool HasNormals() const { return !normals.empty(); }
  // Throws sope::Error when colours/normals do not match the points in number.
  void Check() const;
  // Number of points with all three coordinates finite.
  size_t CountFinite() const;
};

enum class PlyFormat { kBinaryLittleEndian, kAscii };

// Reads PLY (ASCII or binary, either endianness; float or double x y z, optional
// red green blue and nx ny nz) or PCD (by extension; any PCL PCD encoding). Throws
// sope::Error naming the file on anything malformed or truncated.
PointCloud ReadPointCloud(const std::string& path);
// Writes PLY (by default binary little-endian: x y z float32, red green blue uchar when
// coloured, nx ny nz float32 when present) or PCD (binary) when `path` ends in .pcd.
// Atomic. Throws sope::Error on failure.
void WritePointCloud(const std::string& path, const PointCloud& cloud,
                     PlyFormat ply_format = PlyFormat::kBinaryLittleEndian);

}  // namespace sope
