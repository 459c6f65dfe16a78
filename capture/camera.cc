#include "capture/camera.h"

#include <algorithm>
#include <filesystem>

#include "capture/replay_camera.h"
#include "capture/v4l2_internal.h"
#include "core/error.h"

namespace sope {
namespace {

constexpr const char* kReplayPrefix = "replay:";

// /dev/video* present now, sorted, for "no such device" messages.
[[maybe_unused]] std::vector<std::string> PresentVideoDevices() {
  std::vector<std::string> devices;
  std::error_code error;
  for (const auto& entry : std::filesystem::directory_iterator("/dev", error)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("video", 0) == 0) devices.push_back(entry.path().string());
  }
  std::sort(devices.begin(), devices.end());
  return devices;
}

}  // namespace

void CameraOptions::Check() const {
  SOPE_CHECK(width >= 0 && height >= 0 && (width > 0) == (height > 0),
             "camera size {}x{}: give both width and height, or neither", width, height);
  SOPE_CHECK(fps >= 0.0 && fps <= 1000.0, "camera frame rate {} fps must be in 0..1000", fps);
  SOPE_CHECK(exposure >= 0.0 && exposure <= 10.0, "camera exposure {} s must be in 0..10",
             exposure);
  SOPE_CHECK(buffers >= 2 && buffers <= 32, "camera buffers {} must be in 2..32", buffers);
}

#ifdef SOPE_WITH_V4L2
bool HaveV4l2Camera() { return true; }
#else
bool HaveV4l2Camera() { return false; }
#endif

std::unique_ptr<Camera> OpenCamera(const std::string& spec, const CameraOptions& options) {
  options.Check();
  if (spec.rfind(kReplayPrefix, 0) == 0) {
    const std::string directory = spec.substr(std::char_traits<char>::length(kReplayPrefix));
    SOPE_CHECK(!directory.empty(), "camera '{}': replay needs a directory, replay:DIR", spec);
    return std::make_unique<ReplayCamera>(directory);
  }
  SOPE_CHECK(spec != "virtual",
             "camera 'virtual' needs a virtual rig and scene (simulator/virtual_camera.h); "
             "this caller cannot make one");
  SOPE_CHECK(spec.rfind("/dev/", 0) == 0,
             "camera '{}': expected /dev/videoN, replay:DIR or virtual", spec);
#ifdef SOPE_WITH_V4L2
  std::unique_ptr<internal::V4l2Device> device;
  try {
    device = internal::OpenV4l2Device(spec);
  } catch (const internal::DeviceError& error) {
    throw Error(internal::OpenErrorMessage(spec, error.error_number(), PresentVideoDevices()));
  }
  return internal::MakeV4l2Camera(std::move(device), spec, options);
#else
  SOPE_THROW("camera {}: this build has no V4L2 backend (configure with -DSOPE_WITH_V4L2=ON)",
             spec);
#endif
}

}  // namespace sope
