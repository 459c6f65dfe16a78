#include "tests/test_support.h"

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <random>

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

}  // namespace testing
}  // namespace sope
