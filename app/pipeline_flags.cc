#include "app/pipeline_flags.h"

#include "app/cli_util.h"

namespace sope {
namespace cli {

void PatternFlags::Add(CLI::App& app) {
  app.add_option("--axes", axes, "Coded projector axes: x (columns), y (rows) or xy")
      ->capture_default_str();
  app.add_option("--code", code,
                 "gray or binary (stripes), phase (phase shift at --periods) or gray+phase "
                 "(Gray code + one phase group at --period)")
      ->capture_default_str();
  app.add_option("--periods", periods,
                 "--code phase: comma-separated periods in projector pixels, e.g. 1024,64,8 "
                 "(the coarsest >= the projector size; default: size, size/8, size/64)");
  app.add_option("--period", period,
                 "--code gray+phase: period in projector pixels (a power of two)")
      ->capture_default_str();
  app.add_option("--steps", steps, "Phase shifts per period (>= 3)")->capture_default_str();
  app.add_flag("--no-complementary", no_complementary,
               "--code gray+phase: omit the complementary Gray bit half a period wide");
  app.add_option("--pattern-gamma", pattern_gamma,
                 "Pre-distort sinusoids for a projector of this gamma (1 = none)")
      ->capture_default_str();
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
  options.family = PatternFamilyFromString(code, &options.code);
  if (!periods.empty()) options.periods = ParseNumbers(periods, "--periods");
  options.period = period;
  options.steps = steps;
  options.complementary_bit = !no_complementary;
  if (pattern_gamma != 1.0) options.precompensate = ProjectorResponse::Gamma(pattern_gamma);
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
  app.add_option("--min-modulation", options.phase.min_modulation,
                 "Phase sets: minimum sinusoid amplitude of every group, grey levels")
      ->capture_default_str();
  app.add_option("--max-unwrap-error", options.phase.max_unwrap_error,
                 "Phase sets: coarse and fine coordinates may differ by this fraction of the "
                 "fine period, else the pixel is invalid")
      ->capture_default_str();
  app.add_option("--gray-subpixel", gray_subpixel,
                 "Gray codes: off (stripe centres, integer) or edges (sub-pixel from the two "
                 "stripe edges around each pixel)")
      ->capture_default_str();
  app.add_flag("--consistency,!--no-consistency", consistency,
               std::string("Code sets: also decode pixels left undecided from their own bit "
                           "margins within the range their decoded neighbours predict (dim, "
                           "grazing surfaces); default ") +
                   (consistency ? "on" : "off"));
  app.add_flag("--no-gamma-correction", no_gamma_correction,
               "Phase sets: ignore the calibration's projector_response (e.g. for patterns "
               "pre-distorted with --pattern-gamma)");
  app.add_option("--threads", options.num_threads,
                 "Threads for decoding (and triangulating, in commands that triangulate; and "
                 "the pose screening and a table's clusters, in scan-and-recognise)")
      ->capture_default_str();
}

DecoderOptions DecoderFlags::ToOptions() const {
  DecoderOptions result = options;
  result.bit_decision = BitDecisionFromString(mode);
  result.gray_subpixel = GraySubpixelFromString(gray_subpixel);
  result.consistency.enabled = consistency;
  if (no_gamma_correction) result.phase.use_calibration_response = false;
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

void TableFlags::Add(CLI::App& app, bool objects_flags) {
  app.add_flag("--table", table,
               objects_flags
                   ? "Tabletop scans: segment by the table plane and recognise every object; "
                     "on the virtual rig, scan tabletop scenes (objects in stable resting "
                     "poses on a table seen from 30-60 degrees above, truth of every object)"
                   : "A tabletop scene: objects in stable resting poses on a table seen from "
                     "30-60 degrees above (simulator/table_scene.h), ground truth of every "
                     "object");
  auto* group = app.add_option_group("table scenes (--table)");
  if (objects_flags) {
    group->add_option("--objects", objects,
                      "Procedural objects per table scene (default: 3-5, drawn per scene)");
    group->add_option("--mesh", meshes,
                      "--table: put these meshes (files or builtin:CLASS[:SEED]; the database "
                      "should hold them) on the table instead of procedural objects");
  }
  group->add_option("--clutter", scene.clutter,
                    "Unknown clutter objects (tori, stones: in no database) on the table")
      ->capture_default_str();
  group->add_option("--tilt-min", scene.camera_tilt_deg_min, "Camera tilt range, degrees")
      ->capture_default_str();
  group->add_option("--tilt-max", scene.camera_tilt_deg_max, "Camera tilt range, degrees")
      ->capture_default_str();
  group->add_option("--table-distance", scene.table_distance,
                    "Camera centre to the table along the optical axis, metres")
      ->capture_default_str();
}

TableSceneOptions TableFlags::ToOptions() const {
  TableSceneOptions options = scene;
  for (const std::string& mesh : meshes) {
    TableObjectSpec object;
    object.spec = mesh;
    object.size = kSizeAsDatabase;
    options.objects.push_back(object);
  }
  return options;
}

}  // namespace cli
}  // namespace sope
