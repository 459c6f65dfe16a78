// Helpers shared by the tests: where the shared data lives, scratch directories.
#pragma once

#include <optional>
#include <string>

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

}  // namespace testing
}  // namespace sope

// Skips the current test when ../shared/data is absent; binds `var` to its path.
#define SOPE_REQUIRE_SHARED_DATA(var)                                     \
  const auto var##_optional = ::sope::testing::SharedDataDir();           \
  if (!var##_optional) GTEST_SKIP() << "../shared/data not present";      \
  const std::string var = *var##_optional
