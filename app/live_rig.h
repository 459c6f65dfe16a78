// Flags and backend choice for commands that capture live (`scan --camera`, later
// `calibrate --camera`, `scan-and-recognise`): a camera spec → the projector display and
// camera to drive a RigSession with. "virtual" builds the virtual rig with a built-in
// scene; "/dev/videoN" opens V4L2 and the GLFW projector window; "replay:DIR" replays a
// recording behind a virtual display. No algorithms here.
#pragma once

#include <CLI/CLI.hpp>
#include <atomic>
#include <memory>
#include <string>

#include "capture/camera.h"
#include "capture/rig_session.h"
#include "core/rig_calibration.h"
#include "projector/display.h"
#include "simulator/virtual_camera.h"

namespace sope {
namespace cli {

// Binds the live-capture options except the camera spec itself (the command adds
// --camera, since it competes with --frames).
struct LiveRigFlags {
  // Projector window.
  int monitor = 0;
  bool windowed = false;
  // Camera.
  std::string camera_format = "auto";
  double fps = 0.0;
  double exposure_ms = 0.0;
  double gain = -1.0;
  bool keep_auto = false;
  // Session.
  double latency_ms = -1.0;
  double settle_ms = 0.0;
  double timeout_s = 2.0;
  // Virtual camera: transport delay in frames (like a real projector's).
  int virtual_delay_frames = 2;

  void Add(CLI::App& app);
  // `cancel` (may be null) stops the session; checked.
  RigSessionOptions SessionOptions(const std::atomic<bool>* cancel) const;
  CameraOptions CameraOptionsFor(const RigCalibration& calibration) const;
};

// A display and a camera ready for a RigSession, and what owns them.
struct LiveRig {
  std::unique_ptr<Display> display;
  std::unique_ptr<Camera> camera;
  VirtualLiveRig virtual_rig;  // for "virtual": owns the clock, rig, display and camera
  Display& GetDisplay() { return display ? *display : *virtual_rig.display; }
  Camera& GetCamera() { return camera ? *camera : *virtual_rig.camera; }
};

// Opens the camera named by `spec` and a projector display of the calibration's projector
// size. The camera is opened first, so a missing camera fails before a window appears;
// its image size must be the calibration's camera size. For "virtual" the calibration is
// the virtual rig's true one and the scene is MakeDemoScene(). Throws sope::Error.
LiveRig OpenLiveRig(const std::string& spec, const RigCalibration& calibration,
                    const LiveRigFlags& flags);

// While alive, SIGINT and SIGTERM set `flag()` instead of killing the process, so a live
// capture stops between frames and cleans up (no half-written recording). A second signal
// kills as usual.
class InterruptFlag {
 public:
  InterruptFlag();
  ~InterruptFlag();
  InterruptFlag(const InterruptFlag&) = delete;
  InterruptFlag& operator=(const InterruptFlag&) = delete;
  const std::atomic<bool>* flag() const;
};

}  // namespace cli
}  // namespace sope
