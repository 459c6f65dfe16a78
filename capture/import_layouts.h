// Importing other tools' structured-light captures as sope frame sets (`sope import`,
// DESIGN.md): the frame order of OpenCV's cv::structured_light::GrayCodePattern (also
// procam-calibration's), SLStudio's codecs (src/codec/Codec*.cpp in jakobwilm/slstudio) and
// a generic order spec. Each layout is a list of frames in capture order; the images of a
// folder, taken in name order, are matched to it one to one.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "core/frame_set.h"
#include "core/rig_calibration.h"
#include "projector/patterns.h"

namespace sope {

enum class ImportLayout {
  // cv::structured_light::GrayCodePattern::generate(): per column bit from the most
  // significant, the pattern then its inverse; the row bits likewise; then white, black
  // (getImagesForShadowMasks, projected after the patterns by OpenCV's capture sample and by
  // procam-calibration's gen_graycode_imgs.py). 2·(⌈log2 W⌉ + ⌈log2 H⌉) + 2 images.
  kOpenCvGrayCode,
  // SLStudio EncoderGrayCode: white, black, then 10 column bits from the most significant
  // (bit ⌈log2 W⌉−1−p for p = 0..9, so low bits beyond ten are not projected), then 6 row
  // bits likewise; no inverses. `axes` selects the codec direction (CodecDir).
  kSlStudioGrayCode,
  // SLStudio EncoderPhaseShift2x3: per coded axis, three sinusoids of period size/16 with
  // shifts 0, 2π/3, 4π/3, then three of period size (the phase cue) with the same shifts;
  // columns before rows. 12 images for both axes, 6 for one.
  kSlStudioPhaseShift2x3,
  // SLStudio EncoderPhaseShift3: three sinusoids of period W across the columns, shifts
  // 0, 2π/3, 4π/3 (absolute phase, columns only).
  kSlStudioPhaseShift3,
  // SLStudio EncoderCalibration: the sequence SLStudio captures at each calibration board
  // pose — the 2x3 phase-shift sequence on both axes.
  kSlStudioCalibration,
  // The generic order of ImportOptions::order (ParseOrderSpec).
  kOrder,
};
std::string ToString(ImportLayout layout);
// "opencv-graycode", "slstudio-graycode", "slstudio-2x3", "slstudio-3", "slstudio-calibration",
// "order". Throws sope::Error naming the unknown value.
ImportLayout ImportLayoutFromString(const std::string& text);

// One frame of an imported capture, as frames.json describes it (DESIGN.md "Frame set").
struct ImportedFrame {
  enum class Role { kWhite, kBlack, kCode, kPhase, kSkip };
  Role role = Role::kCode;
  std::string file;  // relative to the frame-set directory
  PatternAxis axis = PatternAxis::kX;
  // role kCode:
  PatternCode code = PatternCode::kGray;
  int bits = 0;  // code length on this axis
  int bit = 0;   // 0 = least significant
  bool inverted = false;
  // role kPhase: I(u) = ½·(1 + cos(2π·u/period − shift)), u the projector column (x) or
  // row (y), pixel centres at integers.
  double period_px = 0.0;
  double shift_rad = 0.0;
};

struct ImportOptions {
  ImportLayout layout = ImportLayout::kOpenCvGrayCode;
  int projector_width = 0;   // pixels
  int projector_height = 0;  // pixels
  // SLStudio layouts: the coded axes (SLStudio's CodecDir: x = CodecDirHorizontal,
  // y = CodecDirVertical). slstudio-3 and slstudio-calibration ignore it.
  PatternAxes axes = PatternAxes::kXY;
  // kOrder: the order spec (ParseOrderSpec) and the code of its bit tokens.
  std::string order;
  PatternCode order_code = PatternCode::kGray;
  // Only image files whose name matches this shell pattern (fnmatch, e.g.
  // "pattern_cam1_*"); empty = every image.
  std::string select;

  // Throws sope::Error naming the invalid value.
  void Check() const;
};

// The frames a layout expects, in capture order (file names empty).
std::vector<ImportedFrame> LayoutFrames(const ImportOptions& options);

// A generic order: comma-separated tokens, one image each (ranges: several), in capture
// order. Tokens:
//   white | black | skip             references; `skip` ignores that image
//   x<b> | y<b>                      code bit b (0 = LSB) of the column / row code
//   x<b>i                            its inverse
//   x<hi>-<lo>   x<hi>-<lo>i          bits hi down to lo (or lo up to hi), patterns or inverses
//   x<hi>-<lo>+i                     the same with each pattern followed by its inverse
//   phase:<axis>:<period_px>:<shift_deg>   a sinusoid (DESIGN.md role `phase`), shift in
//                                    degrees
// Code bits use `code` with ⌈log2 size⌉ bits on their axis. OpenCV's order for a 1024x768
// projector is "x9-0+i,y9-0+i,white,black". Throws sope::Error naming the bad token.
std::vector<ImportedFrame> ParseOrderSpec(const std::string& spec, int projector_width,
                                          int projector_height, PatternCode code);

// Name order as people number files: runs of digits compare as numbers ("im2" < "im10"),
// the rest byte-wise; equal numbers with different zero padding fall back to byte order.
bool NaturalLess(const std::string& a, const std::string& b);
// Image files (png, jpg, jpeg, bmp, tif, tiff, pgm, ppm; any case) directly in `directory`
// whose name matches `select` (all when empty), in natural name order. Throws sope::Error
// when the directory cannot be read.
std::vector<std::string> ListImagesInNameOrder(const std::string& directory,
                                               const std::string& select = "");

struct ImportedFrameSet {
  int camera_width = 0;
  int camera_height = 0;
  int projector_width = 0;
  int projector_height = 0;
  std::vector<ImportedFrame> frames;  // no kSkip frames
  std::string calibration;            // optional, relative path

  // Throws sope::Error describing the first inconsistency. Sets without phase frames are
  // held to FrameSetManifest::Check(); phase groups need ≥ 3 distinct shifts, a positive
  // period, and each axis's coarsest group must be absolute (period ≥ the projector size on
  // that axis) unless Gray-code frames of that axis unwrap it.
  void Check() const;
  bool HasPhase() const;
  // The sope manifest (sets without phase frames only).
  FrameSetManifest ToManifest() const;
};

// frames.json text (format "sope-frames/1").
std::string SerializeImportedFrameSet(const ImportedFrameSet& frame_set);

// Pairs images with a layout's frames: throws sope::Error when the counts differ
// ("... expects N images, DIR has M"); kSkip frames are dropped.
ImportedFrameSet MatchImagesToLayout(const std::vector<std::string>& files,
                                     const std::vector<ImportedFrame>& layout,
                                     const std::string& directory);

struct ImportSummary {
  size_t images = 0;   // images written to the frame set
  size_t skipped = 0;  // images the layout skipped
  int camera_width = 0;
  int camera_height = 0;
  bool has_phase = false;
  bool has_calibration = false;
};

// `sope import`: lists the images of `images_dir` in name order, matches them to the layout,
// checks that they are readable and of one size, and writes `out_dir` as a whole (frames.json,
// the images copied byte for byte under their names and, when given, `calibration.yaml`).
// Throws sope::Error on a count that does not fit the layout, an unreadable image or mixed
// sizes, and a calibration whose sizes differ from the capture's.
ImportSummary ImportCapture(const std::string& images_dir, const ImportOptions& options,
                            const std::string& out_dir,
                            const std::optional<RigCalibration>& calibration = std::nullopt);

}  // namespace sope
