// sope project [--monitor N] [--windowed] [--projector WxH] [pattern flags] [--interval S]
// Shows the pattern sequence on the projector, stepping with keys, for setting up a rig.
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/live_rig.h"
#include "app/pipeline_flags.h"
#include "capture/clock.h"
#include "capture/replay_camera.h"
#include "core/error.h"
#include "projector/display.h"
#include "projector/patterns.h"

namespace sope {

int RunProject(int argc, char** argv) {
  CLI::App app{
      "Show the stripe pattern sequence on the projector (GLFW window, fullscreen, one "
      "pattern pixel per projector pixel). Keys: space or right arrow = next, left "
      "arrow = previous, q or Esc = quit.",
      "sope project"};
  int monitor = 0;
  bool windowed = false, list_monitors = false;
  std::string projector_size;
  double interval = 0.0;
  cli::PatternFlags pattern_flags;
  cli::LoggingFlags logging;
  app.add_option("--monitor", monitor, "Monitor index (see --list-monitors)")
      ->capture_default_str();
  app.add_flag("--windowed", windowed, "A window instead of fullscreen (development)");
  app.add_option("--projector", projector_size,
                 "Projector resolution WxH (default: the monitor's mode; 1024x768 windowed). "
                 "Fullscreen requires the monitor to run at exactly this size");
  app.add_option("--interval", interval,
                 "Advance by itself every this many seconds and exit after the last pattern "
                 "(0: keys only)")
      ->capture_default_str();
  app.add_flag("--list-monitors", list_monitors, "Print the connected monitors and exit");
  pattern_flags.Add(app);
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();
  SOPE_CHECK(interval >= 0.0, "--interval {} must be >= 0", interval);

  if (list_monitors) {
    for (const MonitorInfo& info : ListMonitors()) {
      std::printf("%d: %s %dx%d@%dHz\n", info.index, info.name.c_str(), info.width, info.height,
                  info.refresh_hz);
    }
    return 0;
  }
  DisplayOptions options;
  options.monitor = monitor;
  options.windowed = windowed;
  if (!projector_size.empty()) {
    cli::ParseSize(projector_size, "--projector", &options.width, &options.height);
  } else if (!windowed) {
    const std::vector<MonitorInfo> monitors = ListMonitors();
    SOPE_CHECK(monitor >= 0 && monitor < static_cast<int>(monitors.size()),
               "no monitor {} ({} connected; see --list-monitors)", monitor, monitors.size());
    options.width = monitors[monitor].width;
    options.height = monitors[monitor].height;
  }
  const std::vector<Pattern> patterns =
      GeneratePatterns(pattern_flags.ToOptions(options.width, options.height));
  const std::unique_ptr<Display> display = OpenGlfwDisplay(options);
  const cli::InterruptFlag interrupt;
  size_t index = 0;
  bool shown = false;
  double next_step = 0.0;
  while (!interrupt.flag()->load()) {
    if (!shown) {
      display->Show(patterns[index].image);
      spdlog::info("{}/{}: {}", index + 1, patterns.size(),
                   DescribeFrameInfo(patterns[index].info));
      shown = true;
      next_step = MonotonicSeconds() + interval;
    }
    const double wait = interval > 0.0 ? std::max(next_step - MonotonicSeconds(), 0.0) : 0.1;
    DisplayKey key = display->WaitKey(wait);
    if (key == DisplayKey::kNone && interval > 0.0 && MonotonicSeconds() >= next_step) {
      if (index + 1 == patterns.size()) break;
      key = DisplayKey::kNext;
    }
    if (key == DisplayKey::kQuit) break;
    if (key == DisplayKey::kNext && index + 1 < patterns.size()) {
      ++index;
      shown = false;
    } else if (key == DisplayKey::kPrevious && index > 0) {
      --index;
      shown = false;
    }
  }
  return 0;
}

}  // namespace sope
