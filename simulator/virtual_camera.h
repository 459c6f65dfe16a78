// The virtual rig as a live camera: it watches a VirtualDisplay and renders the rig's
// scene lit by whatever the display showed when each frame was exposed, on a simulated
// clock. So the live code path (RigSession: show → wait for the sensor → grab) runs end to
// end without hardware, deterministically and as fast as rendering allows — including the
// latency measurement (an injected delay of k frames) and device faults.
//
// Timing model: frame n is exposed at n·T (T = frame_period; instantaneous exposure) and
// delivered at n·T + T + jitter_n. Its image shows the pattern the display showed at
// n·T − delay_frames·T. Grab() advances the shared clock to the delivery time, as a
// blocking grab on a real camera lets time pass. Frames that nobody grabs are never
// rendered.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "capture/camera.h"
#include "capture/clock.h"
#include "core/rig_calibration.h"
#include "projector/display.h"
#include "simulator/virtual_rig.h"

namespace sope {

struct VirtualCameraOptions {
  // Time between frames, seconds.
  double frame_period = 1.0 / 30.0;
  // Transport delay in frames: frame n shows what was on the display delay_frames periods
  // before its exposure (projector processing, display pipeline).
  int delay_frames = 0;
  // Delivery jitter, seconds: uniform in [0, readout_jitter), deterministic per frame from
  // `seed`; varies the phase between Show() and the camera's frames.
  double readout_jitter = 0.0;
  uint64_t seed = 1;
  // Fault injection for tests (< 0: never). After this many delivered frames Grab() fails
  // as a vanished device does, or no frame ever arrives again (a stalled camera).
  int lose_device_after = -1;
  int stall_after = -1;

  // Throws sope::Error naming the invalid value.
  void Check() const;
};

class VirtualCamera : public Camera {
 public:
  // `rig` (its scene already set, or set later), `display` and `clock` — the display's
  // clock — must outlive the camera. Throws sope::Error when the display's size is not the
  // rig's projector size or the options are invalid.
  VirtualCamera(VirtualRig& rig, const VirtualDisplay& display, SimulatedClock& clock,
                const VirtualCameraOptions& options = {});

  // The first frame exposed at or after request.not_before (and after the last one
  // delivered). Throws sope::Error "camera virtual: no frame within …" when it would be
  // delivered after the timeout (the clock then stands at the timeout), and on the
  // injected faults.
  Frame Grab(const GrabRequest& request) override;
  int width() const override;
  int height() const override;
  double Now() const override { return clock_.Now(); }
  double frame_period() const override { return options_.frame_period; }
  std::string name() const override { return "virtual"; }
  std::string description() const override;

  // Frames delivered (rendered) so far.
  size_t delivered() const { return delivered_; }

 private:
  VirtualRig& rig_;
  const VirtualDisplay& display_;
  SimulatedClock& clock_;
  VirtualCameraOptions options_;
  int64_t next_index_ = 0;
  size_t delivered_ = 0;
};

// A whole virtual live rig on one simulated clock: the rig with `scene` set, a virtual
// display of the projector's size, and a virtual camera watching it.
struct VirtualLiveRig {
  std::unique_ptr<SimulatedClock> clock;
  std::unique_ptr<VirtualRig> rig;
  std::unique_ptr<VirtualDisplay> display;
  std::unique_ptr<VirtualCamera> camera;
};
VirtualLiveRig MakeVirtualLiveRig(const RigCalibration& calibration, const Scene& scene,
                                  const SensorOptions& sensor = {},
                                  const VirtualCameraOptions& camera = {});

// The built-in scene of `sope scan --camera virtual`: a procedural mug (seed 0) lying on
// its side, its bounding-box centre on the optical axis at `distance` metres, before a
// matte backdrop 0.15 m behind it.
Scene MakeDemoScene(double distance = kDefaultWorkingDistance);

}  // namespace sope
