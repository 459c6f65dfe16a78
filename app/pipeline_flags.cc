#include "app/pipeline_flags.h"

namespace sope {
namespace cli {

void PatternFlags::Add(CLI::App& app) {
  app.add_option("--axes", axes, "Coded projector axes: x (columns), y (rows) or xy")
      ->capture_default_str();
  app.add_option("--code", code, "gray or binary")->capture_default_str();
  app.add_flag("--no-inverse", no_inverse, "Omit the inverse of each code frame");
  app.add_flag("--no-white-black", no_white_black, "Omit the white and black frames");
  app.add_option("--skip-low-bits", skip_low_bits,
                 "Omit this many least significant bits (coordinate step 2^k px)")
      ->capture_default_str();
}

PatternOptions PatternFlags::ToOptions(int projector_width, int projector_height) const {
  PatternOptions options;
  options.projector_width = projector_width;
  options.projector_height = projector_height;
  options.axes = PatternAxesFromString(axes);
  options.code = PatternCodeFromString(code);
  options.inverted = !no_inverse;
  options.white_black = !no_white_black;
  options.skip_low_bits = skip_low_bits;
  options.Check();
  return options;
}

void DecoderFlags::Add(CLI::App& app) {
  app.add_option("--min-contrast", options.min_contrast,
                 "Minimum white-black contrast, grey levels (darker = shadow)")
      ->capture_default_str();
  app.add_option("--min-bit-contrast", options.min_bit_contrast,
                 "Minimum pattern-inverse difference for a bit to count as decided")
      ->capture_default_str();
  app.add_option("--min-relative-bit-contrast", options.min_relative_bit_contrast,
                 "Also require |pattern-inverse| >= this fraction of white-black (0 = off; "
                 "0.15-0.25 with sharp optics)")
      ->capture_default_str();
  app.add_option("--min-neighbours", options.min_consistent_neighbours,
                 "Speckle filter: consistent decoded neighbours (of 8) a pixel needs (0 = off)")
      ->capture_default_str();
  app.add_option("--decode-mode", mode,
                 "Bit decisions: auto (inverse if present), threshold, robust (indirect light)")
      ->capture_default_str();
  app.add_option("--threads", options.num_threads,
                 "Threads for decoding (and triangulating, in commands that triangulate)")->capture_default_str();
}

DecoderOptions DecoderFlags::ToOptions() const {
  DecoderOptions result = options;
  result.bit_decision = BitDecisionFromString(mode);
  result.Check();
  return result;
}

void TriangulationFlags::Add(CLI::App& app) {
  app.add_option("--method", method, "Two-axis triangulation: midpoint or linear")
      ->capture_default_str();
  app.add_option("--min-depth", options.min_depth, "Keep points with z >= this, metres")
      ->capture_default_str();
  app.add_option("--max-depth", options.max_depth, "Keep points with z <= this, metres")
      ->capture_default_str();
  app.add_option("--max-reprojection", options.max_reprojection_px,
                 "Reject points whose rays miss by more projector pixels (<= 0: off)")
      ->capture_default_str();
}

TriangulationOptions TriangulationFlags::ToOptions() const {
  TriangulationOptions result = options;
  result.method = TriangulationMethodFromString(method);
  result.Check();
  return result;
}

}  // namespace cli
}  // namespace sope
