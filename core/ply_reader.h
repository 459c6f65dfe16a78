// Internal: a small PLY parser shared by the point-cloud and mesh readers.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace sope {
namespace internal {

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::kFloat32;  // scalar type, or the item type of a list
  bool is_list = false;
  PlyType list_count_type = PlyType::kUint8;
};

struct PlyElement {
  std::string name;
  size_t count = 0;
  std::vector<PlyProperty> properties;
  // Scalar properties as double, one row per element (lists are stored separately).
  std::vector<std::vector<double>> rows;
  // The first list property per element (e.g. vertex_indices), if any.
  std::vector<std::vector<int64_t>> lists;

  // Column of a scalar property, −1 when absent.
  int Column(const std::string& property_name) const;
};

// Parses a whole PLY file (ascii, binary_little_endian, binary_big_endian). Only
// `wanted` elements keep their data (others are skipped). Throws sope::Error naming the
// file on malformed or truncated input.
std::vector<PlyElement> ReadPly(const std::string& path, const std::vector<std::string>& wanted);

}  // namespace internal
}  // namespace sope
