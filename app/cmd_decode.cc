// sope decode --frames DIR --out DIR
#include <filesystem>

#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/pipeline_flags.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/frame_set.h"
#include "core/rig_calibration.h"
#include "decoder/decoder.h"
#include "decoder/phase_decoder.h"

namespace sope {

int RunDecode(int argc, char** argv) {
  CLI::App app{"Decode a frame set into camera->projector correspondence maps: proj_x/proj_y "
               "(EXR, NaN = invalid), mask, confidence, and colourised PNGs; for phase sets "
               "also the wrapped phase, modulation and texture.",
               "sope decode"};
  std::string frames_dir, out, calibration_path;
  cli::DecoderFlags decoder_flags;
  cli::LoggingFlags logging;
  app.add_option("--frames", frames_dir, "Frame-set directory (with frames.json)")->required();
  app.add_option("--out", out, "Output directory for the maps")->required();
  app.add_option("--calibration", calibration_path,
                 "Phase sets: calibration whose projector_response corrects the gamma ripple "
                 "(default: the frame set's calibration, when it has one)");
  decoder_flags.Add(app);
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  DecoderOptions options = decoder_flags.ToOptions();
  const FrameSet frames = LoadFrameSet(frames_dir);
  if (frames.manifest.HasPhase() && options.phase.use_calibration_response) {
    std::string path = calibration_path;
    if (path.empty() && !frames.manifest.calibration.empty()) {
      path = JoinPath(frames_dir, frames.manifest.calibration);
      if (!std::filesystem::exists(path)) path.clear();
    }
    if (!path.empty()) options.phase.response = ReadRigCalibration(path).projector_response;
  }
  CorrespondenceMap map;
  PhaseDecodeImages phase_images;
  if (frames.manifest.HasPhase()) {
    DecodePhase(frames, options, &map, &phase_images);
  } else {
    Decode(frames, options, &map);
  }
  const size_t valid = map.CountValid();
  const size_t total = static_cast<size_t>(map.width()) * map.height();
  SOPE_CHECK(valid > 0, "no pixel decoded in {} (is the projector visible? try a lower "
             "--min-contrast)", frames_dir);
  WriteCorrespondenceMap(out, map);
  if (frames.manifest.HasPhase()) WritePhaseDecodeImages(out, phase_images);
  spdlog::info("decoded {} of {} pixels ({:.1f}%) -> {}", valid, total, 100.0 * valid / total,
               out);
  return 0;
}

}  // namespace sope
