// Flags shared by several commands: the pattern sequence, decoder and triangulation
// options. Each binds CLI11 options to an options struct and checks it.
#pragma once

#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "calibration/triangulation.h"
#include "decoder/decoder.h"
#include "projector/patterns.h"
#include "simulator/table_scene.h"

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
  bool consistency = true;  // set before Add() for another default (calibrate: off)
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

// Tabletop scenes (`simulate --table`, `scan-and-recognise --virtual --table`): --table,
// --clutter, --tilt-min/--tilt-max, --table-distance, and with `objects_flags` --objects N
// and --mesh (repeated: these objects instead of procedural ones).
struct TableFlags {
  bool table = false;
  int objects = 0;  // 0: 3-5 per scene
  std::vector<std::string> meshes;
  TableSceneOptions scene;
  void Add(CLI::App& app, bool objects_flags);
  // Clutter, tilt, distance and the --mesh objects (sized as build-db does); seed and
  // backdrop are the caller's.
  TableSceneOptions ToOptions() const;
};

}  // namespace cli
}  // namespace sope
