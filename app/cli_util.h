// Small pieces every command shares: option parsing of sizes and poses, progress on a
// terminal, logging setup. No algorithms here.
#pragma once

#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "core/rigid3d.h"

namespace sope {
namespace cli {

// "1024x768" → width, height. Throws sope::Error naming `option` on malformed text.
void ParseSize(const std::string& text, const std::string& option, int* width, int* height);
// "rx,ry,rz,tx,ty,tz" (degrees, metres) → b_from_a with R = Rz·Ry·Rx.
Rigid3d ParsePose(const std::string& text, const std::string& option);
// Comma-separated numbers.
std::vector<double> ParseNumbers(const std::string& text, const std::string& option);

// The unit of mesh files, as metres per file unit: "auto" → 0 (the size rule of
// core/object_size.h guesses), "m" 1, "cm" 0.01, "mm" 0.001, "in" 0.0254, or a positive
// number (metres per unit). Throws sope::Error naming `option` otherwise.
double ParseMeshUnit(const std::string& text, const std::string& option);
// The same without "auto": the unit of a point cloud's coordinates.
double ParseLengthUnit(const std::string& text, const std::string& option);
// Adds `--units` (bound to *text, default "auto") with the help every mesh-reading command
// shares.
void AddMeshUnitFlag(CLI::App& app, std::string* text);

// Parses argv with CLI11. Returns -1 to continue, or the exit code to return now: 0 after
// --help, 2 after a usage error (unknown flag, missing value, malformed number), printed as
// one line "<app name>: error: <what>" like every other error.
int Parse(CLI::App& app, int argc, char** argv);

// Adds --verbose/--quiet to `app`; ApplyLogging() sets spdlog's level from them.
struct LoggingFlags {
  bool verbose = false;
  bool quiet = false;
  void Add(CLI::App& app);
  void Apply() const;
};

// A one-line progress bar on stderr when it is a terminal (nothing otherwise).
class Progress {
 public:
  Progress(std::string label, size_t total);
  ~Progress();
  void Update(size_t done);

 private:
  std::string label_;
  size_t total_;
  bool enabled_;
};

}  // namespace cli
}  // namespace sope
