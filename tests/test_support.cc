#include "tests/test_support.h"

#include "core/error.h"

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include <gtest/gtest.h>

namespace sope {
namespace testing {
namespace fs = std::filesystem;

std::optional<std::string> SharedDataDir() {
  if (const char* env = std::getenv("SOPE_DATA_DIR"); env != nullptr && fs::is_directory(env)) {
    return std::string(env);
  }
  const fs::path compiled(SOPE_SHARED_DATA_DIR);
  if (fs::is_directory(compiled)) return fs::canonical(compiled).string();
  return std::nullopt;
}

ScratchDir::ScratchDir() {
  std::random_device random;
  for (int attempt = 0; attempt < 100; ++attempt) {
    const fs::path candidate = fs::temp_directory_path() /
                               ("sope-test-" + std::to_string(::getpid()) + "-" +
                                std::to_string(random()));
    if (fs::create_directory(candidate)) {
      path_ = candidate.string();
      return;
    }
  }
  std::abort();
}

ScratchDir::~ScratchDir() {
  std::error_code ignored;
  fs::remove_all(path_, ignored);
}

RigCalibration SmallRig() {
  RigCalibration rig;
  rig.camera.width = 320;
  rig.camera.height = 240;
  rig.camera.matrix << 350, 0, 160, 0, 350, 120, 0, 0, 1;
  rig.camera.distortion = {-0.05, 0.02, 0, 0, 0};
  rig.projector.width = 256;
  rig.projector.height = 192;
  rig.projector.matrix << 380, 0, 128, 0, 380, 96, 0, 0, 1;
  rig.projector.distortion = {0, 0, 0, 0, 0};
  const double angle = std::atan2(0.15, 0.6);
  rig.proj_from_cam.rotation = RotationFromEulerXYZ(0, -angle, 0).transpose();
  rig.proj_from_cam.translation = -(rig.proj_from_cam.rotation * Eigen::Vector3d(0.15, 0, 0));
  return rig;
}

std::string ErrorOf(const std::function<void()>& action) {
  try {
    action();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

std::string Quote(const std::string& text) { return "'" + text + "'"; }

CommandRun RunCommand(const std::string& binary, const std::string& arguments,
                      const ScratchDir& scratch, const std::string& prefix) {
  const std::string out_file = scratch.File(".stdout"), err_file = scratch.File(".stderr");
  const std::string command = prefix + " " + binary + " " + arguments + " >" + Quote(out_file) +
                              " 2>" + Quote(err_file);
  const int status = std::system(command.c_str());
  CommandRun run;
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream out(out_file), err(err_file);
  std::stringstream out_text, err_text;
  out_text << out.rdbuf();
  err_text << err.rdbuf();
  run.out = out_text.str();
  run.err = err_text.str();
  return run;
}

void ExpectOneLineError(const CommandRun& run, const std::string& command,
                        const std::string& needle) {
  EXPECT_NE(run.exit_code, 0);
  EXPECT_EQ(std::count(run.err.begin(), run.err.end(), '\n'), 1) << run.err;
  EXPECT_EQ(run.err.rfind("sope " + command + ": error: ", 0), 0u) << run.err;
  EXPECT_NE(run.err.find(needle), std::string::npos)
      << "expected '" << needle << "' in: " << run.err;
}

}  // namespace testing
}  // namespace sope
