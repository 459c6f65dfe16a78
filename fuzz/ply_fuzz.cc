// PLY, ASCII and binary of either endianness, through both readers that use the shared
// parser (core/ply_reader): point clouds (ReadPointCloud) and meshes (ReadMesh).
#include <cstddef>
#include <cstdint>

#include "core/error.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = sope::fuzz::WriteInput(data, size, "input.ply");
  try {
    sope::ReadPointCloud(path).Check();
  } catch (const sope::Error&) {
  }
  try {
    sope::ReadMesh(path);
  } catch (const sope::Error&) {
  }
  return 0;
}
