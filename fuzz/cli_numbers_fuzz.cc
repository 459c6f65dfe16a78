// The command line's value parsers (app/cli_util: sizes "WxH", number lists, poses, mesh
// and cloud units). The first byte picks the parser; the rest is the option's text.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>

#include "app/cli_util.h"
#include "core/error.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const std::string text(reinterpret_cast<const char*>(data + 1), size - 1);
  try {
    switch (data[0] % 5) {
      case 0: {
        int width = 0, height = 0;
        sope::cli::ParseSize(text, "--size", &width, &height);
        if (width <= 0 || height <= 0) __builtin_trap();  // accepted sizes are positive
        break;
      }
      case 1:
        for (const double value : sope::cli::ParseNumbers(text, "--numbers")) {
          if (!std::isfinite(value)) __builtin_trap();  // accepted numbers are finite
        }
        break;
      case 2: {
        // Accepted units are metres per unit in (0, 1000], or 0 for "auto".
        const double unit = sope::cli::ParseMeshUnit(text, "--units");
        if (!(unit == 0.0 ? text == "auto" : unit > 0.0 && unit <= 1000.0)) __builtin_trap();
        break;
      }
      case 3: {
        const double unit = sope::cli::ParseLengthUnit(text, "--cloud-units");
        if (!(unit > 0.0 && unit <= 1000.0)) __builtin_trap();
        break;
      }
      default:
        sope::cli::ParsePose(text, "--pose");
        break;
    }
  } catch (const sope::Error&) {
  }
  return 0;
}
