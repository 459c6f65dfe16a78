// sope calibrate-gamma --calibration CAL.yaml (--virtual | --frames RAMP_DIR) --out CAL.yaml
// sope calibrate-gamma --write-ramp DIR --projector WxH
#include <cmath>

#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "calibration/projector_response_calibration.h"
#include "core/error.h"
#include "core/rig_calibration.h"
#include "simulator/scene_builder.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

// The virtual rig films a matte wall this far away (metres), filling the view.
constexpr double kWallAlbedo = 0.9;
constexpr double kWallWidth = 3.0, kWallHeight = 2.0;

}  // namespace

int RunCalibrateGamma(int argc, char** argv) {
  CLI::App app{"Measure the projector -> camera intensity response from a grey ramp (uniform "
               "frames of increasing grey level) and write it into the calibration YAML as "
               "projector_response; the phase decoder then corrects the gamma ripple. "
               "--write-ramp writes the projector images (with ramp.json) to show and film; "
               "--frames reads the filmed ramp (ramp.json naming the captures in order).",
               "sope calibrate-gamma"};
  std::string calibration_path, frames_dir, ramp_out, record_dir, out, projector_size;
  bool virtual_rig = false;
  ResponseCalibrationOptions options;
  SensorOptions sensor;
  sensor.gamma = 1.0;
  sensor.projector_gamma = 2.2;
  double wall_distance = kDefaultWorkingDistance;
  cli::LoggingFlags logging;
  app.add_option("--calibration", calibration_path, "Rig calibration YAML to extend");
  CLI::Option* virtual_option =
      app.add_flag("--virtual", virtual_rig, "Film the ramp on the virtual rig (a white wall)");
  CLI::Option* frames_option =
      app.add_option("--frames", frames_dir, "Directory of a filmed ramp (ramp.json + images)")
          ->excludes(virtual_option);
  CLI::Option* write_option =
      app.add_option("--write-ramp", ramp_out, "Write the ramp's projector images to DIR")
          ->excludes(virtual_option)
          ->excludes(frames_option);
  app.add_option("--projector", projector_size,
                 "--write-ramp: projector resolution WxH (default: the calibration's)");
  app.add_option("--levels", options.levels, "Grey levels of the ramp")->capture_default_str();
  app.add_option("--min-contrast", options.min_contrast,
                 "Pixels need this brightest - darkest difference, grey levels")
      ->capture_default_str();
  app.add_option("--projector-gamma", sensor.projector_gamma, "--virtual: the projector's gamma")
      ->capture_default_str();
  app.add_option("--projector-black-level", sensor.projector_black_level,
                 "--virtual: light of a black pixel, fraction of white")
      ->capture_default_str();
  app.add_option("--projector-saturation", sensor.projector_saturation,
                 "--virtual: pixel value (0..1] from which the projector emits full white")
      ->capture_default_str();
  app.add_option("--camera-gamma", sensor.gamma, "--virtual: the camera's response gamma")
      ->capture_default_str();
  app.add_option("--wall-distance", wall_distance, "--virtual: distance of the wall, metres")
      ->capture_default_str();
  app.add_option("--seed", sensor.seed, "--virtual: noise seed")->capture_default_str();
  app.add_option("--record", record_dir, "--virtual: also write the filmed ramp to DIR");
  app.add_option("--out", out, "Output calibration YAML (the input plus projector_response)");
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();
  options.Check();

  if (write_option->count() > 0) {
    int width = 0, height = 0;
    if (!projector_size.empty()) {
      cli::ParseSize(projector_size, "--projector", &width, &height);
    } else {
      SOPE_CHECK(!calibration_path.empty(), "--write-ramp needs --projector WxH or --calibration");
      const RigCalibration calibration = ReadRigCalibration(calibration_path);
      width = calibration.projector.width;
      height = calibration.projector.height;
    }
    WriteGreyRamp(ramp_out, GreyRampPatterns(width, height, options.levels));
    spdlog::info("wrote a {}-level grey ramp for a {}x{} projector to {}", options.levels, width,
                 height, ramp_out);
    return 0;
  }
  SOPE_CHECK(virtual_rig || !frames_dir.empty(), "give --virtual, --frames DIR or --write-ramp DIR");
  SOPE_CHECK(!out.empty(), "--out is required");
  SOPE_CHECK(virtual_rig || !calibration_path.empty(), "--frames needs --calibration");
  RigCalibration calibration =
      calibration_path.empty() ? DefaultRigCalibration() : ReadRigCalibration(calibration_path);
  std::vector<cv::Mat> captures;
  if (virtual_rig) {
    sensor.Check();
    SOPE_CHECK(std::isfinite(wall_distance) && wall_distance > 0.05 && wall_distance < 100.0,
               "--wall-distance {} must be in (0.05, 100) metres", wall_distance);
    VirtualRig rig(calibration, sensor);
    Scene wall;
    wall.objects.push_back(MakeBackdrop(wall_distance, kWallWidth, kWallHeight, kWallAlbedo));
    rig.SetScene(wall);
    for (const cv::Mat& pattern : GreyRampPatterns(calibration.projector.width,
                                                   calibration.projector.height, options.levels)) {
      captures.push_back(rig.Capture(pattern));
    }
    if (!record_dir.empty()) WriteGreyRamp(record_dir, captures);
  } else {
    captures = ReadGreyRamp(frames_dir);
    SOPE_CHECK(static_cast<int>(captures.size()) == options.levels,
               "{}: {} ramp images but --levels is {}", frames_dir, captures.size(),
               options.levels);
    SOPE_CHECK(captures.front().cols == calibration.camera.width &&
                   captures.front().rows == calibration.camera.height,
               "{}: images are {}x{}, the calibration's camera is {}x{}", frames_dir,
               captures.front().cols, captures.front().rows, calibration.camera.width,
               calibration.camera.height);
  }
  const ResponseCalibrationSummary summary = MeasureProjectorResponse(captures, options);
  calibration.projector_response = summary.response;
  WriteRigCalibration(out, calibration);
  spdlog::info("{} -> {}", summary.BriefReport(), out);
  return 0;
}

}  // namespace sope
