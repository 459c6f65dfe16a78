// Helpers shared by the tests: where the shared data lives, scratch directories.
#pragma once

#include <optional>
#include <string>

#include "core/rig_calibration.h"

namespace sope {
namespace testing {

// ../shared/data (or $SOPE_DATA_DIR) when present; nullopt otherwise — tests that need it
// GTEST_SKIP() in that case.
std::optional<std::string> SharedDataDir();
// A fresh empty directory under the system temp dir, removed by the destructor.
class ScratchDir {
 public:
  ScratchDir();
  ~ScratchDir();
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  const std::string& path() const { return path_; }
  std::string File(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

// A small rig so scenes render quickly: camera 320×240 (mild distortion), projector
// 256×192 0.15 m to its right, both converging at 0.6 m.
RigCalibration SmallRig();

// What a command run through the shell printed, and how it ended.
struct CommandRun {
  int exit_code = -1;  // −1: killed by a signal
  std::string out;
  std::string err;
};
// Single-quoted for the shell.
std::string Quote(const std::string& text);
// Runs `prefix binary arguments` through the shell, stdout and stderr captured in files of
// `scratch`.
CommandRun RunCommand(const std::string& binary, const std::string& arguments,
                      const ScratchDir& scratch, const std::string& prefix = "");
// Expects what every failing `sope` command must do: a non-zero exit and exactly one line
// on stderr, "sope <command>: error: …", containing `needle`.
void ExpectOneLineError(const CommandRun& run, const std::string& command,
                        const std::string& needle);

}  // namespace testing
}  // namespace sope

// Skips the current test when ../shared/data is absent; binds `var` to its path.
#define SOPE_REQUIRE_SHARED_DATA(var)                                     \
  const auto var##_optional = ::sope::testing::SharedDataDir();           \
  if (!var##_optional) GTEST_SKIP() << "../shared/data not present";      \
  const std::string var = *var##_optional
