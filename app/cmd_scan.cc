// sope scan --frames DIR [--calibration CAL.yaml] --out CLOUD.ply
// sope scan --camera /dev/videoN|virtual|replay:DIR [--calibration CAL.yaml] [--record DIR]
//           --out CLOUD.ply
#include <memory>
#include <optional>

#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/live_rig.h"
#include "app/pipeline_flags.h"
#include "calibration/scan.h"
#include "core/error.h"
#include "core/point_cloud.h"
#include "core/rig_calibration.h"
#include "pipeline/scan_source.h"
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
  std::unique_ptr<ScanSource> source;
  std::optional<cli::InterruptFlag> interrupt;  // live: Ctrl-C stops between frames
  if (camera.empty()) {
    source = std::make_unique<FrameSetDirectorySource>(std::vector<std::string>{frames_dir},
                                                       calibration_path);
  } else {
    SOPE_CHECK(!calibration_path.empty() || camera == "virtual",
               "--camera {} needs --calibration CAL.yaml", camera);
    LiveRigSourceOptions live;
    live.spec = camera;
    live.calibration = calibration_path.empty() ? DefaultRigCalibration()
                                                : ReadRigCalibration(calibration_path);
    if (!calibration_path.empty()) live.calibration_source = calibration_path;
    live.patterns = pattern_flags.ToOptions(live.calibration.projector.width,
                                            live.calibration.projector.height);
    live.rig = live_flags.RigOptions();
    interrupt.emplace();
    live.session = live_flags.SessionOptions(interrupt->flag());
    live.record_directory = record_dir;
    source = std::make_unique<LiveRigSource>(live);
  }
  std::optional<cli::Progress> progress;
  const SourceScan scan = source->Next(0, [&](size_t done, size_t total) {
    if (!progress) progress.emplace("capturing", total);
    progress->Update(done);
  });
  progress.reset();
  CheckCalibrationMatchesFrames(scan.calibration, scan.frames.manifest, scan.calibration_source);
  const ScanResult result = ScanFrameSet(scan.frames, scan.calibration, options);
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
