// sope import --layout opencv-graycode|slstudio-...|order --projector WxH --images DIR --out DIR
//             [--order SPEC] [--select GLOB] [--calibration FILE --calibration-format F
//             --units mm|cm|m]
#include <optional>

#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "capture/foreign_calibration.h"
#include "capture/import_layouts.h"
#include "core/error.h"

namespace sope {

int RunImport(int argc, char** argv) {
  CLI::App app{"Write a frame set (frames.json + the images) for a capture made with another "
               "tool's pattern order; images are taken in name order (digit runs compare as "
               "numbers). Layouts: opencv-graycode (cv::structured_light::GrayCodePattern and "
               "procam-calibration: column then row bits MSB first, each pattern then its "
               "inverse, then white, black), slstudio-graycode, slstudio-2x3, slstudio-3, "
               "slstudio-calibration (SLStudio's codecs), order (--order SPEC).",
               "sope import"};
  std::string layout_text, projector_size, images, out, order, code_text = "gray", select;
  std::string axes_text = "xy", calibration_path, calibration_format, units;
  cli::LoggingFlags logging;
  app.add_option("--layout", layout_text, "Pattern order of the capture")->required();
  app.add_option("--projector", projector_size, "Projector resolution WxH")->required();
  app.add_option("--images", images, "Folder of the captured images")->required();
  app.add_option("--out", out, "Frame-set directory to write")->required();
  app.add_option("--order", order,
                 "Layout 'order': comma-separated tokens in capture order: white, black, skip, "
                 "x<bit>[i], y<bit>[i], x<hi>-<lo>[i|+i] (+i: each pattern then its inverse), "
                 "phase:<x|y>:<period_px>:<shift_deg>; e.g. x9-0+i,y9-0+i,white,black");
  app.add_option("--code", code_text, "Code of --order's bit tokens: gray|binary")
      ->capture_default_str();
  app.add_option("--axes", axes_text, "SLStudio layouts: coded axes x|y|xy (SLStudio's CodecDir)")
      ->capture_default_str();
  app.add_option("--select", select,
                 "Only images whose file name matches this shell pattern (e.g. 'pattern_cam1_*')");
  app.add_option("--calibration", calibration_path,
                 "The capture's camera-projector calibration in another tool's format, written "
                 "as calibration.yaml (metres)");
  app.add_option("--calibration-format", calibration_format,
                 "procam (procam-calibration's calibration_result.xml) | slstudio "
                 "(SLStudio's calibration.xml)");
  app.add_option("--units", units, "Length unit of the foreign calibration: mm|cm|m");
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  ImportOptions options;
  options.layout = ImportLayoutFromString(layout_text);
  cli::ParseSize(projector_size, "--projector", &options.projector_width,
                 &options.projector_height);
  options.order = order;
  options.order_code = PatternCodeFromString(code_text);
  options.axes = PatternAxesFromString(axes_text);
  options.select = select;
  options.Check();

  std::optional<RigCalibration> calibration;
  if (!calibration_path.empty()) {
    SOPE_CHECK(!calibration_format.empty(),
               "--calibration needs --calibration-format procam|slstudio");
    SOPE_CHECK(!units.empty(), "--calibration needs --units mm|cm|m (the foreign file's length "
               "unit: that of the board it was calibrated with)");
    calibration = ReadForeignCalibration(
        calibration_path, ForeignCalibrationFormatFromString(calibration_format),
        LengthUnitFromString(units), options.projector_width, options.projector_height);
  } else {
    SOPE_CHECK(calibration_format.empty() && units.empty(),
               "--calibration-format and --units go with --calibration FILE");
  }
  const ImportSummary summary = ImportCapture(images, options, out, calibration);
  spdlog::info("imported {} images ({}x{}{}{}) as layout {} -> {}{}", summary.images,
               summary.camera_width, summary.camera_height, summary.has_phase ? ", phase" : "",
               summary.skipped > 0 ? fmt::format(", {} skipped", summary.skipped) : "",
               ToString(options.layout), out,
               summary.has_calibration ? " (with calibration.yaml)" : "");
  return 0;
}

}  // namespace sope
