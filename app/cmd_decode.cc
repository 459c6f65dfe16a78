// sope decode --frames DIR --out DIR
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/pipeline_flags.h"
#include "core/error.h"
#include "core/frame_set.h"
#include "decoder/decoder.h"

namespace sope {

int RunDecode(int argc, char** argv) {
  CLI::App app{"Decode a frame set into camera->projector correspondence maps: proj_x/proj_y "
               "(EXR, NaN = invalid), mask, confidence, and colourised PNGs.",
               "sope decode"};
  std::string frames_dir, out;
  cli::DecoderFlags decoder_flags;
  cli::LoggingFlags logging;
  app.add_option("--frames", frames_dir, "Frame-set directory (with frames.json)")->required();
  app.add_option("--out", out, "Output directory for the maps")->required();
  decoder_flags.Add(app);
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  const DecoderOptions options = decoder_flags.ToOptions();
  const FrameSet frames = LoadFrameSet(frames_dir);
  const CorrespondenceMap map = Decode(frames, options);
  const size_t valid = map.CountValid();
  const size_t total = static_cast<size_t>(map.width()) * map.height();
  SOPE_CHECK(valid > 0, "no pixel decoded in {} (is the projector visible? try a lower "
             "--min-contrast)", frames_dir);
  WriteCorrespondenceMap(out, map);
  spdlog::info("decoded {} of {} pixels ({:.1f}%) -> {}", valid, total, 100.0 * valid / total,
               out);
  return 0;
}

}  // namespace sope
