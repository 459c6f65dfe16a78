// Flags shared by several commands: the pattern sequence, decoder and triangulation
// options. Each binds CLI11 options to an options struct and checks it.
#pragma once

#include <string>

#include <CLI/CLI.hpp>

#include "calibration/triangulation.h"
#include "decoder/decoder.h"
#include "projector/patterns.h"

namespace sope {
namespace cli {

struct PatternFlags {
  std::string axes = "xy";
  std::string code = "gray";
  bool no_inverse = false;
  bool no_white_black = false;
  int skip_low_bits = 0;
  // Phase families (--code phase | gray+phase).
  std::string periods;  // comma-separated, projector pixels; empty: automatic
  double period = 16.0;
  int steps = 4;
  bool no_complementary = false;
  double pattern_gamma = 1.0;  // pre-compensate a projector gamma (1 = none)

  void Add(CLI::App& app);
  // Options for a projector of the given size; checked.
  PatternOptions ToOptions(int projector_width, int projector_height) const;
};

struct DecoderFlags {
  DecoderOptions options;
  std::string mode = "auto";
  std::string gray_subpixel = "edges";
  bool consistency = false;
  bool no_gamma_correction = false;
  void Add(CLI::App& app);
  DecoderOptions ToOptions() const;
};

struct TriangulationFlags {
  TriangulationOptions options;
  std::string method = "midpoint";
  void Add(CLI::App& app);
  TriangulationOptions ToOptions() const;
};

}  // namespace cli
}  // namespace sope
