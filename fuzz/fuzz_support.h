// Helpers shared by the libFuzzer targets (fuzz/README.md). Not part of the library.
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace sope {
namespace fuzz {

// The parsers that take a path read the input from a file: one per target and extension
// in a private temporary directory, rewritten for every input (the directory goes when the
// process exits normally; after a crash it is left in $TMPDIR as sope-fuzz-*).
inline std::string WriteInput(const uint8_t* data, size_t size, const std::string& name) {
  static const std::string directory = [] {
    const char* tmp = std::getenv("TMPDIR");
    std::string pattern = std::string(tmp && *tmp ? tmp : "/tmp") + "/sope-fuzz-XXXXXX";
    if (::mkdtemp(&pattern[0]) == nullptr) std::abort();
    static std::string to_remove;
    to_remove = pattern;
    std::atexit([] { std::system(("rm -rf '" + to_remove + "'").c_str()); });
    return pattern;
  }();
  const std::string path = directory + "/" + name;
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) std::abort();
  if (size > 0 && std::fwrite(data, 1, size, file) != size) std::abort();
  if (std::fclose(file) != 0) std::abort();
  return path;
}

}  // namespace fuzz
}  // namespace sope
