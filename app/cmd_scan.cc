// sope scan --frames DIR [--calibration CAL.yaml] --out CLOUD.ply
// sope scan --camera /dev/videoN|virtual|replay:DIR [--calibration CAL.yaml] [--record DIR]
//           --out CLOUD.ply
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/live_rig.h"
#include "app/pipeline_flags.h"
#include "calibration/scan.h"
#include "capture/rig_session.h"
#include "core/error.h"
#include "core/frame_set.h"
#include "core/point_cloud.h"
#include "core/rig_calibration.h"
#include "simulator/virtual_rig.h"

namespace sope {

int RunScan(int argc, char** argv) {
  CLI::App app{"Decode and triangulate a frame set into a coloured point cloud (metres, "
               "camera frame): PLY (binary, or ASCII with --ascii) or PCD by extension.",
               "sope scan"};
  std::string frames_dir, calibration_path, out, maps_dir, camera, record_dir;
  bool ascii = false;
  cli::DecoderFlags decoder_flags;
  cli::TriangulationFlags triangulation_flags;
  cli::PatternFlags pattern_flags;
  cli::LiveRigFlags live_flags;
  cli::LoggingFlags logging;
  CLI::Option* frames_option =
      app.add_option("--frames", frames_dir, "Frame-set directory (with frames.json)");
  app.add_option("--camera", camera,
                 "Capture live instead: /dev/videoN (V4L2 camera + projector window), "
                 "virtual (the virtual rig with a built-in scene) or replay:DIR")
      ->excludes(frames_option);
  app.add_option("--calibration", calibration_path,
                 "Rig calibration YAML (default: the one frames.json names; with --camera "
                 "virtual: the virtual rig's own)");
  app.add_option("--record", record_dir,
                 "--camera: keep the captured frame set (with calibration.yaml and "
                 "capture.json) in this directory, for `sope scan --frames DIR`");
  app.add_option("--out", out, "Output cloud (.ply or .pcd)")->required();
  app.add_flag("--ascii", ascii, "Write ASCII PLY instead of binary");
  app.add_option("--maps", maps_dir, "Also write the decoded maps to this directory");
  decoder_flags.Add(app);
  triangulation_flags.Add(app);
  auto* live_group = app.add_option_group("live capture (--camera)");
  pattern_flags.Add(*live_group);
  live_flags.Add(*live_group);
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  ScanOptions options;
  options.decoder = decoder_flags.ToOptions();
  options.triangulation = triangulation_flags.ToOptions();
  options.triangulation.num_threads = options.decoder.num_threads;
  SOPE_CHECK(!frames_dir.empty() || !camera.empty(), "one of --frames or --camera is required");
  SOPE_CHECK(record_dir.empty() || !camera.empty(), "--record needs --camera");
  FrameSet frames;
  RigCalibration calibration;
  if (camera.empty()) {
    frames = LoadFrameSet(frames_dir);
    calibration = ResolveCalibration(frames, calibration_path);
  } else {
    SOPE_CHECK(!calibration_path.empty() || camera == "virtual",
               "--camera {} needs --calibration CAL.yaml", camera);
    calibration = calibration_path.empty() ? DefaultRigCalibration()
                                           : ReadRigCalibration(calibration_path);
    const PatternOptions patterns =
        pattern_flags.ToOptions(calibration.projector.width, calibration.projector.height);
    const cli::InterruptFlag interrupt;
    const RigSessionOptions session_options = live_flags.SessionOptions(interrupt.flag());
    cli::LiveRig rig = cli::OpenLiveRig(camera, calibration, live_flags);
    RigSession session(rig.GetDisplay(), rig.GetCamera(), session_options);
    const std::vector<Pattern> sequence = GeneratePatterns(patterns);
    cli::Progress capture_progress("capturing", sequence.size());
    const auto on_frame = [&](size_t done, size_t) { capture_progress.Update(done); };
    frames = record_dir.empty() ? session.Capture(sequence, on_frame)
                                : session.Record(sequence, record_dir, &calibration, on_frame);
    if (!record_dir.empty()) {
      spdlog::info("recorded {} frames -> {}", frames.images.size(), record_dir);
    }
  }
  CheckCalibrationMatchesFrames(calibration, frames.manifest,
                                calibration_path.empty() ? "the calibration" : calibration_path);
  const ScanResult result = ScanFrameSet(frames, calibration, options);
  if (!maps_dir.empty()) WriteCorrespondenceMap(maps_dir, result.correspondences);
  const PointCloud& cloud = result.triangulation.cloud;
  SOPE_CHECK(!cloud.empty(), "no points: {} pixels decoded, none triangulated inside the "
             "depth band [{}, {}] m (wrong calibration?)",
             result.correspondences.CountValid(), options.triangulation.min_depth,
             options.triangulation.max_depth);
  WritePointCloud(out, cloud, ascii ? PlyFormat::kAscii : PlyFormat::kBinaryLittleEndian);
  spdlog::info("{} points ({} decoded pixels, {} rejected) -> {}; decode {:.1f} ms, "
               "triangulate {:.1f} ms",
               cloud.size(), result.correspondences.CountValid(), result.triangulation.rejected,
               out, result.decode_ms, result.triangulate_ms);
  return 0;
}

}  // namespace sope
