// The live rig's backends (DESIGN.md data flow, "a rig session"): a camera spec → the
// projector display and the camera a RigSession drives. "/dev/videoN" opens V4L2 and the
// GLFW projector window; "replay:DIR" replays a recording behind a virtual display
// (nothing to project); "virtual" builds the virtual rig (simulator) watching a virtual
// display, with a scene of the caller's or the built-in one (MakeDemoScene).
#pragma once

#include <memory>
#include <string>

#include "capture/camera.h"
#include "core/rig_calibration.h"
#include "projector/display.h"
#include "simulator/virtual_camera.h"

namespace sope {

struct LiveRigOptions {
  // Projector window (a live camera): monitor index in GLFW order, or a window instead of
  // fullscreen.
  int monitor = 0;
  bool windowed = false;
  // The camera; width and height are taken from the calibration.
  CameraOptions camera;
  // The virtual camera: transport delay in frames (like a real projector's) and delivery
  // jitter as a fraction of its frame period (varies the phase between Show() and the
  // frames, as on hardware).
  int virtual_delay_frames = 2;
  double virtual_jitter = 0.5;
  // Throws sope::Error naming the invalid value.
  void Check() const;
};

// A display and a camera ready for a RigSession, and what owns them.
struct LiveRig {
  std::unique_ptr<Display> display;
  std::unique_ptr<Camera> camera;
  VirtualLiveRig virtual_rig;  // "virtual": owns the clock, rig, display and camera
  bool is_virtual() const { return virtual_rig.rig != nullptr; }
  Display& GetDisplay() { return display ? *display : *virtual_rig.display; }
  Camera& GetCamera() { return camera ? *camera : *virtual_rig.camera; }
};

// Opens the camera named by `spec` and a projector display of the calibration's projector
// size. The camera is opened first, so a missing camera fails before a window appears;
// its image size must be the calibration's camera size. For "virtual" the calibration is
// the virtual rig's and the scene `virtual_scene` (null: MakeDemoScene()). Throws
// sope::Error.
LiveRig OpenLiveRig(const std::string& spec, const RigCalibration& calibration,
                    const LiveRigOptions& options, const Scene* virtual_scene = nullptr);

}  // namespace sope
