// frames.json (core/frame_set: ParseFrameSetManifest, Check, SerializeFrameSetManifest).
// Expected failures are sope::Error; anything else (another exception, a crash, a
// sanitizer report) is a finding.
#include <cstddef>
#include <cstdint>
#include <string>

#include "core/error.h"
#include "core/frame_set.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const sope::FrameSetManifest manifest = sope::ParseFrameSetManifest(text, "frames.json");
    manifest.Check();
    // A manifest that was accepted reads back the same.
    const std::string again = sope::SerializeFrameSetManifest(manifest);
    const sope::FrameSetManifest reread = sope::ParseFrameSetManifest(again, "reserialised");
    if (sope::SerializeFrameSetManifest(reread) != again) __builtin_trap();
    for (const sope::PatternAxis axis : {sope::PatternAxis::kX, sope::PatternAxis::kY}) {
      if (manifest.HasAxis(axis)) {
        manifest.AxisBits(axis);
        manifest.AxisLowestBit(axis);
      }
    }
  } catch (const sope::Error&) {
  }
  return 0;
}
