#include "simulator/virtual_camera.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "simulator/scene_builder.h"

namespace sope {
namespace {

// Uniform in [0, 1), a pure function of (seed, index) (SplitMix64).
double UnitNoise(uint64_t seed, int64_t index) {
  uint64_t z = seed * 0x9E3779B97F4A7C15ull + static_cast<uint64_t>(index) + 1;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  return static_cast<double>(z >> 11) * 0x1.0p-53;
}

// Frames a real driver could still hold (its buffer queue): older ones are gone.
constexpr int64_t kDriverBuffers = 4;

}  // namespace

void VirtualCameraOptions::Check() const {
  SOPE_CHECK(frame_period > 0.0 && frame_period <= 10.0,
             "virtual camera frame period {} s must be in (0, 10]", frame_period);
  SOPE_CHECK(delay_frames >= 0 && delay_frames <= 100,
             "virtual camera delay {} frames must be in 0..100", delay_frames);
  SOPE_CHECK(readout_jitter >= 0.0 && readout_jitter <= frame_period,
             "virtual camera readout jitter {} s must be in [0, frame period]", readout_jitter);
}

VirtualCamera::VirtualCamera(VirtualRig& rig, const VirtualDisplay& display, SimulatedClock& clock,
                             const VirtualCameraOptions& options)
    : rig_(rig), display_(display), clock_(clock), options_(options) {
  options_.Check();
  const CameraModel& projector = rig_.calibration().projector;
  SOPE_CHECK(display_.width() == projector.width && display_.height() == projector.height,
             "virtual display is {}x{} but the virtual rig's projector is {}x{}", display_.width(),
             display_.height(), projector.width, projector.height);
}

int VirtualCamera::width() const { return rig_.calibration().camera.width; }
int VirtualCamera::height() const { return rig_.calibration().camera.height; }

Frame VirtualCamera::Grab(const GrabRequest& request) {
  SOPE_CHECK(request.timeout > 0.0, "grab timeout {} s must be positive", request.timeout);
  const double period = options_.frame_period;
  const double now = clock_.Now();
  int64_t index =
      std::max(next_index_, static_cast<int64_t>(std::floor(now / period)) - kDriverBuffers);
  if (std::isfinite(request.not_before)) {
    index = std::max(index, static_cast<int64_t>(std::ceil(request.not_before / period)) - 1);
    while (index * period < request.not_before) ++index;
  }
  const double start = index * period;
  const double delivery =
      start + period + options_.readout_jitter * UnitNoise(options_.seed, index);
  const bool stalled =
      options_.stall_after >= 0 && delivered_ >= static_cast<size_t>(options_.stall_after);
  if (stalled || delivery > now + request.timeout) {
    clock_.AdvanceTo(now + request.timeout);
    SOPE_THROW("camera virtual: no frame within {:.2f} s (timeout){}", request.timeout,
               stalled ? ": the camera stopped delivering frames" : "");
  }
  SOPE_CHECK(options_.lose_device_after < 0 ||
                 delivered_ < static_cast<size_t>(options_.lose_device_after),
             "camera virtual disappeared or failed (simulated device loss after {} frames)",
             delivered_);
  clock_.AdvanceTo(delivery);
  Frame frame;
  frame.image = rig_.Capture(display_.PatternAt(start - options_.delay_frames * period));
  frame.exposure_start = start;
  frame.sequence = static_cast<uint64_t>(index);
  next_index_ = index + 1;
  ++delivered_;
  return frame;
}

std::string VirtualCamera::description() const {
  return fmt::format("virtual camera {}x{} at {:.3g} fps, delay {} frames", width(), height(),
                     1.0 / options_.frame_period, options_.delay_frames);
}

VirtualLiveRig MakeVirtualLiveRig(const RigCalibration& calibration, const Scene& scene,
                                  const SensorOptions& sensor, const VirtualCameraOptions& camera) {
  VirtualLiveRig live;
  live.clock = std::make_unique<SimulatedClock>();
  live.rig = std::make_unique<VirtualRig>(calibration, sensor);
  live.rig->SetScene(scene);
  SimulatedClock* clock = live.clock.get();
  live.display = std::make_unique<VirtualDisplay>(
      calibration.projector.width, calibration.projector.height, [clock] { return clock->Now(); });
  live.camera = std::make_unique<VirtualCamera>(*live.rig, *live.display, *live.clock, camera);
  return live;
}

Scene MakeDemoScene(double distance) {
  Scene scene;
  Placement placement;
  // Lying on its side, opening towards the lower left, handle up and to the right.
  placement.rotation = RotationFromEulerXYZ(-1.3, 0.5, 0.3);
  placement.center_in_cam = Eigen::Vector3d(0.0, 0.0, distance);
  scene.objects.push_back(PlaceObject(LoadMeshSpec("builtin:mug"), placement));
  scene.objects.push_back(MakeBackdrop(distance + 0.15, 1.5, 1.0));
  return scene;
}

}  // namespace sope
