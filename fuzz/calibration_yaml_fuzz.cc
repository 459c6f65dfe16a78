// Rig calibration YAML (core/rig_calibration: ReadRigCalibration takes a path, so the
// input goes through a temporary file).
#include <cstddef>
#include <cstdint>

#include "core/error.h"
#include "core/rig_calibration.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = sope::fuzz::WriteInput(data, size, "calibration.yaml");
  try {
    const sope::RigCalibration calibration = sope::ReadRigCalibration(path);
    calibration.BaselineLength();
  } catch (const sope::Error&) {
  }
  return 0;
}
