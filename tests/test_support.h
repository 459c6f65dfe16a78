// Helpers shared by the tests: where the shared data lives, scratch directories, throw
// checks that read the message.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <functional>
#include <optional>
#include <string>
#include <typeinfo>
#include <vector>

#include <gtest/gtest.h>

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
// The message of the sope::Error that `action` throws, or "(no error)" when it throws none
// (for EXPECT_THAT(ErrorOf(...), HasSubstr(...)); other exception types propagate).
std::string ErrorOf(const std::function<void()>& action);

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

// Whether `statement` throws an `E` whose what() contains every one of `substrings` (STYLE
// §5: a caller mistake is an error whose message names the bad value; give the key and the
// value as separate substrings so the check does not pin the wording around them). Fails,
// saying what happened and printing the actual message, when nothing is thrown, another type
// is thrown, or the message lacks a substring; no substring, or an empty one, is refused (it
// would accept any message). With $SOPE_TEST_PRINT_THROWS set, every message caught is also
// printed to stderr (to read what a library says).
template <typename E>
::testing::AssertionResult ThrowsWithMessage(const std::function<void()>& statement,
                                             const std::vector<std::string>& substrings,
                                             const char* statement_text = "statement",
                                             const char* type_text = "the exception",
                                             const char* file = "", int line = 0) {
  std::string wanted;
  for (const std::string& substring : substrings) {
    wanted += (wanted.empty() ? "\"" : ", \"") + substring + "\"";
  }
  try {
    statement();
  } catch (const E& error) {
    const std::string message = error.what();
    if (std::getenv("SOPE_TEST_PRINT_THROWS") != nullptr) {
      std::fprintf(stderr, "SOPE-THROW %s:%d: %s\n", file, line, message.c_str());
    }
    bool refused = substrings.empty();
    for (const std::string& substring : substrings) refused = refused || substring.empty();
    if (refused) {
      return ::testing::AssertionFailure()
             << "ThrowsWithMessage needs non-empty substrings for " << statement_text
             << " (it threw \"" << message << "\")";
    }
    for (const std::string& substring : substrings) {
      if (message.find(substring) == std::string::npos) {
        return ::testing::AssertionFailure()
               << statement_text << " threw " << type_text << " with message \"" << message
               << "\", which does not contain \"" << substring << "\"";
      }
    }
    return ::testing::AssertionSuccess();
  } catch (const std::exception& other) {
    return ::testing::AssertionFailure()
           << statement_text << " was expected to throw " << type_text << " but threw "
           << typeid(other).name() << " with message \"" << other.what() << "\"";
  } catch (...) {
    return ::testing::AssertionFailure() << statement_text << " was expected to throw "
                                         << type_text << " but threw a non-std exception";
  }
  return ::testing::AssertionFailure() << statement_text << " was expected to throw "
                                       << type_text << " (message containing " << wanted
                                       << ") but threw nothing";
}

// Non-fatal check: EXPECT_TRUE(ThrowsWithMessage<E>(statement, substrings)).
template <typename E>
void ExpectThrowsWithMessage(const std::function<void()>& statement,
                             const std::vector<std::string>& substrings) {
  EXPECT_TRUE(ThrowsWithMessage<E>(statement, substrings));
}

}  // namespace testing
}  // namespace sope

// EXPECT_THROW that also reads the message: `statement` must throw `type` whose what()
// contains each of the substrings given after it:
//   EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "bits", "got 7");
// Streams like EXPECT_THROW: EXPECT_THROW_WITH_MESSAGE(...) << "why".
#define EXPECT_THROW_WITH_MESSAGE(statement, type, ...)                                \
  EXPECT_TRUE(::sope::testing::ThrowsWithMessage<type>(                                \
      [&]() { statement; }, std::vector<std::string>{__VA_ARGS__}, #statement, #type, \
      __FILE__, __LINE__))
// The fatal form (returns from the test on failure).
#define ASSERT_THROW_WITH_MESSAGE(statement, type, ...)                                \
  ASSERT_TRUE(::sope::testing::ThrowsWithMessage<type>(                                \
      [&]() { statement; }, std::vector<std::string>{__VA_ARGS__}, #statement, #type, \
      __FILE__, __LINE__))

// Skips the current test when ../shared/data is absent; binds `var` to its path.
#define SOPE_REQUIRE_SHARED_DATA(var)                                     \
  const auto var##_optional = ::sope::testing::SharedDataDir();           \
  if (!var##_optional) GTEST_SKIP() << "../shared/data not present";      \
  const std::string var = *var##_optional
