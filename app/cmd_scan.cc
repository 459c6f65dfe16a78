// sope scan --frames DIR [--calibration CAL.yaml] --out CLOUD.ply
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/pipeline_flags.h"
#include "calibration/scan.h"
#include "core/error.h"
#include "core/frame_set.h"
#include "core/point_cloud.h"

namespace sope {

int RunScan(int argc, char** argv) {
  CLI::App app{"Decode and triangulate a frame set into a coloured point cloud (metres, "
               "camera frame): PLY (binary, or ASCII with --ascii) or PCD by extension.",
               "sope scan"};
  std::string frames_dir, calibration_path, out, maps_dir;
  bool ascii = false;
  cli::DecoderFlags decoder_flags;
  cli::TriangulationFlags triangulation_flags;
  cli::LoggingFlags logging;
  app.add_option("--frames", frames_dir, "Frame-set directory (with frames.json)")->required();
  app.add_option("--calibration", calibration_path,
                 "Rig calibration YAML (default: the one frames.json names)");
  app.add_option("--out", out, "Output cloud (.ply or .pcd)")->required();
  app.add_flag("--ascii", ascii, "Write ASCII PLY instead of binary");
  app.add_option("--maps", maps_dir, "Also write the decoded maps to this directory");
  decoder_flags.Add(app);
  triangulation_flags.Add(app);
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  ScanOptions options;
  options.decoder = decoder_flags.ToOptions();
  options.triangulation = triangulation_flags.ToOptions();
  const FrameSet frames = LoadFrameSet(frames_dir);
  const RigCalibration calibration = ResolveCalibration(frames, calibration_path);
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
