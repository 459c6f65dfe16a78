#include "app/live_rig.h"

#include <spdlog/spdlog.h>

#include <csignal>

#include "core/error.h"

namespace sope {
namespace cli {
namespace {

std::atomic<bool> interrupted{false};
struct sigaction previous_int, previous_term;

void OnSignal(int signal_number) {
  if (interrupted.exchange(true)) {  // second signal: default action
    std::signal(signal_number, SIG_DFL);
    std::raise(signal_number);
  }
}

}  // namespace

void LiveRigFlags::Add(CLI::App& app) {
  app.add_option("--monitor", monitor, "Projector: monitor index (GLFW order)")
      ->capture_default_str();
  app.add_flag("--windowed", windowed,
               "Projector: a window instead of fullscreen (development; the pattern must fit "
               "the desktop)");
  app.add_option("--camera-format", camera_format,
                 "Camera pixel format: auto (raw first), grey, yuyv, mjpeg")
      ->capture_default_str();
  app.add_option("--fps", fps, "Camera frame rate, frames/s (0: the driver's default)")
      ->capture_default_str();
  app.add_option("--exposure", exposure_ms, "Camera exposure time, ms (0: keep the current)")
      ->capture_default_str();
  app.add_option("--gain", gain, "Camera gain, device units (< 0: keep the current)")
      ->capture_default_str();
  app.add_flag("--keep-auto", keep_auto,
               "Leave auto exposure/gain/white balance on (frames then differ in brightness)");
  app.add_option("--latency", latency_ms,
                 "Projector-to-camera latency, ms (< 0: measure it by flashing black/white)")
      ->capture_default_str();
  app.add_option("--settle", settle_ms, "Extra wait after the latency, ms")->capture_default_str();
  app.add_option("--timeout", timeout_s, "Give up when a frame takes longer, seconds")
      ->capture_default_str();
}

RigSessionOptions LiveRigFlags::SessionOptions(const std::atomic<bool>* cancel) const {
  RigSessionOptions options;
  options.latency = latency_ms < 0.0 ? -1.0 : 1e-3 * latency_ms;
  options.settle = 1e-3 * settle_ms;
  options.grab_timeout = timeout_s;
  options.cancel = cancel;
  options.Check();
  return options;
}

LiveRigOptions LiveRigFlags::RigOptions() const {
  LiveRigOptions options;
  options.monitor = monitor;
  options.windowed = windowed;
  options.camera.pixel_format = PixelFormatFromString(camera_format);
  options.camera.fps = fps;
  options.camera.exposure = 1e-3 * exposure_ms;
  options.camera.gain = gain;
  options.camera.manual = !keep_auto;
  options.virtual_delay_frames = virtual_delay_frames;
  options.Check();
  return options;
}

InterruptFlag::InterruptFlag() {
  interrupted = false;
  struct sigaction action {};
  action.sa_handler = OnSignal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, &previous_int);
  sigaction(SIGTERM, &action, &previous_term);
}

InterruptFlag::~InterruptFlag() {
  sigaction(SIGINT, &previous_int, nullptr);
  sigaction(SIGTERM, &previous_term, nullptr);
}

const std::atomic<bool>* InterruptFlag::flag() const { return &interrupted; }

}  // namespace cli
}  // namespace sope
