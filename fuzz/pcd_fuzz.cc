// PCD point clouds (core/cloud_io: the header is validated before PCL's reader sees it).
#include <cstddef>
#include <cstdint>

#include "core/error.h"
#include "core/point_cloud.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = sope::fuzz::WriteInput(data, size, "input.pcd");
  try {
    sope::ReadPointCloud(path).Check();
  } catch (const sope::Error&) {
  }
  return 0;
}
