#include "pipeline/live_rig.h"

#include <spdlog/spdlog.h>

#include "core/error.h"

namespace sope {

void LiveRigOptions::Check() const {
  SOPE_CHECK(monitor >= 0, "projector monitor index must be ≥ 0, got {}", monitor);
  SOPE_CHECK(virtual_delay_frames >= 0, "virtual camera delay must be ≥ 0 frames, got {}",
             virtual_delay_frames);
  SOPE_CHECK(virtual_jitter >= 0.0 && virtual_jitter < 1.0,
             "virtual camera jitter must be in [0, 1) frame periods, got {}", virtual_jitter);
}

LiveRig OpenLiveRig(const std::string& spec, const RigCalibration& calibration,
                    const LiveRigOptions& options, const Scene* virtual_scene) {
  options.Check();
  LiveRig rig;
  if (spec == "virtual") {
    VirtualCameraOptions camera;
    camera.delay_frames = options.virtual_delay_frames;
    camera.readout_jitter = options.virtual_jitter * camera.frame_period;
    rig.virtual_rig = MakeVirtualLiveRig(
        calibration, virtual_scene ? *virtual_scene : MakeDemoScene(), {}, camera);
    spdlog::info("virtual rig: {}, {}", rig.virtual_rig.camera->description(),
                 virtual_scene ? "procedural objects before a backdrop"
                               : "built-in scene (a mug before a backdrop)");
    return rig;
  }
  CameraOptions camera = options.camera;
  camera.width = calibration.camera.width;
  camera.height = calibration.camera.height;
  camera.Check();
  rig.camera = OpenCamera(spec, camera);
  SOPE_CHECK(rig.camera->width() == calibration.camera.width &&
                 rig.camera->height() == calibration.camera.height,
             "camera {} delivers {}x{} but the calibration is for a {}x{} camera",
             rig.camera->name(), rig.camera->width(), rig.camera->height(),
             calibration.camera.width, calibration.camera.height);
  spdlog::info("camera: {}", rig.camera->description());
  if (!rig.camera->live()) {  // a replay: nothing to project
    rig.display =
        std::make_unique<VirtualDisplay>(calibration.projector.width, calibration.projector.height);
    return rig;
  }
  DisplayOptions display;
  display.monitor = options.monitor;
  display.windowed = options.windowed;
  display.width = calibration.projector.width;
  display.height = calibration.projector.height;
  rig.display = OpenGlfwDisplay(display);
  spdlog::info("projector: {}", rig.display->name());
  return rig;
}

}  // namespace sope
