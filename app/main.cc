// sope — structured-light scanning, object recognition and pose estimation.
// One binary, one table of commands (COLMAP style).
#include <cstdio>
#include <cstring>
#include <exception>
#include <string>

#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "app/commands.h"
#include "core/allocator.h"
#include "core/error.h"
#include "core/file_util.h"

namespace {

struct Command {
  const char* name;
  int (*run)(int argc, char** argv);
  const char* summary;
};

constexpr Command kCommands[] = {
    {"patterns", sope::RunPatterns,
     "write Gray/binary stripe or phase-shift patterns as PNG + frames.json"},
    {"simulate", sope::RunSimulate, "render a frame set on the virtual rig, with ground truth"},
    {"decode", sope::RunDecode, "decode a frame set into projector correspondence maps"},
    {"scan", sope::RunScan, "decode and triangulate a frame set into a point cloud"},
    {"project", sope::RunProject, "show the pattern sequence on the projector, stepping with keys"},
    {"calibrate", sope::RunCalibrate, "calibrate camera and projector from checkerboard frame sets"},
    {"calibrate-gamma", sope::RunCalibrateGamma,
     "measure the projector response (gamma) from a grey ramp into the calibration"},
    {"build-db", sope::RunBuildDb, "build a recognition database from a models directory"},
    {"recognise", sope::RunRecognise, "recognise an object in a point cloud and estimate its pose"},
    {"scan-and-recognise", sope::RunScanAndRecognise,
     "scan, recognise the object and estimate its pose (live, replayed or virtual)"},
    {"objects", sope::RunObjects, "write procedural household objects as a models directory"},
    {"eval", sope::RunEval, "evaluate the recogniser on synthetic queries with ground truth"},
    {"import", sope::RunImport, "write a frame set for another tool's capture (OpenCV, SLStudio)"},
    {"export-db", sope::RunExportDb, "write a database's coarse codes as a FAISS binary index"},
};

void PrintUsage(std::FILE* stream) {
  std::fputs("usage: sope <command> [options]   (sope <command> --help for its options)\n\n"
             "commands:\n",
             stream);
  for (const Command& command : kCommands) {
    std::fputs(fmt::format("  {:<20} {}\n", command.name, command.summary).c_str(), stream);
  }
}

}  // namespace

int main(int argc, char** argv) {
  sope::ConfigureAllocatorForFrames();
  spdlog::set_default_logger(spdlog::stderr_color_mt("sope"));
  spdlog::set_pattern("%^%l%$: %v");
  if (argc < 2 || std::strcmp(argv[1], "--help") == 0 || std::strcmp(argv[1], "-h") == 0) {
    PrintUsage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  if (std::strcmp(argv[1], "--version") == 0) {
    std::puts("sope " SOPE_VERSION);
    return 0;
  }
  for (const Command& command : kCommands) {
    if (command.name != std::string(argv[1])) continue;
    try {
      // Before any thread starts: SIGINT/SIGTERM remove staged outputs and end with one line.
      sope::InstallInterruptPolicy(fmt::format("sope {}", command.name));
      return command.run(argc - 1, argv + 1);
    } catch (const sope::Error& e) {
      std::fputs(fmt::format("sope {}: error: {}\n", command.name, e.what()).c_str(), stderr);
    } catch (const std::exception& e) {
      std::fputs(fmt::format("sope {}: internal error: {}\n", command.name, e.what()).c_str(),
                 stderr);
    }
    return 1;
  }
  std::fputs(fmt::format("sope: unknown command '{}'\n\n", argv[1]).c_str(), stderr);
  PrintUsage(stderr);
  return 2;
}
