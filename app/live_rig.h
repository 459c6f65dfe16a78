// Flags of the commands that capture live (`scan --camera`, `calibrate --camera`,
// `scan-and-recognise`) → the live rig's options (pipeline/live_rig.h opens the backends),
// and Ctrl-C as a flag the capture checks. No algorithms here.
#pragma once

#include <CLI/CLI.hpp>
#include <atomic>
#include <memory>
#include <string>

#include "capture/rig_session.h"
#include "pipeline/live_rig.h"

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
  // The display, camera and virtual-camera options; checked.
  LiveRigOptions RigOptions() const;
};

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
