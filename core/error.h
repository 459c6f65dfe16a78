// Errors, three kinds (STYLE.md §5):
//  - caller mistakes at a public API: throw sope::Error with a message naming the value
//    (SOPE_CHECK / SOPE_THROW);
//  - expected failures (board not found, pixel undecodable): std::optional / summaries;
//  - internal invariants: assert().
// The CLI turns a sope::Error into one line on stderr and a non-zero exit.
#pragma once

#include <stdexcept>
#include <string>

#include <fmt/format.h>

namespace sope {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

}  // namespace sope

// Throws sope::Error with a fmt-formatted message.
#define SOPE_THROW(...) throw ::sope::Error(::fmt::format(__VA_ARGS__))

// Throws sope::Error with a fmt-formatted message unless `condition` holds.
#define SOPE_CHECK(condition, ...)  \
  do {                              \
    if (!(condition)) {             \
      SOPE_THROW(__VA_ARGS__);      \
    }                               \
  } while (false)
