// One 64-bit hash key per integer grid cell (voxel): each coordinate, offset by 2^20 to be
// non-negative, in 21 bits. Cells must lie within ±2^20 of the origin (±1 km at 1 mm cells).
// Shared by the table segmentation's voxel thinning and clustering, the scene recogniser's
// thinned scene and model surfaces, and the near-symmetry test of a model surface.
#pragma once

#include <cmath>
#include <cstdint>

#include <Eigen/Core>

namespace sope {

inline constexpr int64_t kVoxelKeyOffset = int64_t{1} << 20;

// The key of the cell (x, y, z).
inline uint64_t PackVoxelKey(int64_t x, int64_t y, int64_t z) {
  return (static_cast<uint64_t>(x + kVoxelKeyOffset) << 42) ^
         (static_cast<uint64_t>(y + kVoxelKeyOffset) << 21) ^
         static_cast<uint64_t>(z + kVoxelKeyOffset);
}

// The integer coordinates of the cell of `p`, cells 1 / inv_leaf wide (floor of p · inv_leaf
// per axis, in float), and the cell's key.
inline Eigen::Matrix<int64_t, 3, 1> VoxelCoords(const Eigen::Vector3f& p, float inv_leaf) {
  return {static_cast<int64_t>(std::floor(p.x() * inv_leaf)),
          static_cast<int64_t>(std::floor(p.y() * inv_leaf)),
          static_cast<int64_t>(std::floor(p.z() * inv_leaf))};
}
inline uint64_t VoxelKeyOf(const Eigen::Vector3f& p, float inv_leaf) {
  const Eigen::Matrix<int64_t, 3, 1> c = VoxelCoords(p, inv_leaf);
  return PackVoxelKey(c.x(), c.y(), c.z());
}

}  // namespace sope
