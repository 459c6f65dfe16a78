// Frame sets: a directory with `frames.json` (format "sope-frames/1", DESIGN.md) and the
// images it lists. Every module that produces or consumes captures goes through here.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

namespace sope {

// kPhase: a sinusoid I(u) = ½·(1 + cos(2π·u/period − shift)) along `axis` (DESIGN.md).
enum class FrameRole { kWhite, kBlack, kCode, kPhase };
enum class PatternAxis { kX, kY };  // x codes projector columns, y rows
enum class PatternCode { kGray, kBinary };

// Code length for `size` projector pixels: ⌈log2 size⌉, at least 1.
int BitsForSize(int size);

std::string ToString(FrameRole role);
std::string ToString(PatternAxis axis);
std::string ToString(PatternCode code);
// Throw sope::Error naming the unknown value.
FrameRole FrameRoleFromString(const std::string& text);
PatternAxis PatternAxisFromString(const std::string& text);
PatternCode PatternCodeFromString(const std::string& text);

struct FrameInfo {
  std::string file;  // relative to the frame-set directory
  FrameRole role = FrameRole::kCode;
  // Only for role == kCode:
  PatternAxis axis = PatternAxis::kX;
  PatternCode code = PatternCode::kGray;
  int bits = 0;           // code length of the full sequence on this axis
  int bit = 0;            // 0 = least significant
  bool inverted = false;  // the inverse (negative) of the pattern for `bit`
  // Only for role == kPhase (and `axis`): the sinusoid's period in projector pixels (any
  // positive real) and its phase shift in radians; u is the projector column (axis x) or
  // row (y), pixel centres at integers.
  double period = 0.0;
  double shift = 0.0;
};

// One phase-shift group: the frames of one axis and period (≥ 3 distinct shifts).
struct PhaseGroup {
  PatternAxis axis = PatternAxis::kX;
  double period = 0.0;          // projector pixels
  std::vector<size_t> frames;   // manifest indices, in manifest order
  std::vector<double> shifts;   // radians, same order
  bool absolute = false;        // period ≥ the projector size on the axis
};

struct FrameSetManifest {
  static constexpr const char* kFormat = "sope-frames/1";
  static constexpr const char* kFileName = "frames.json";

  int camera_width = 0;
  int camera_height = 0;
  int projector_width = 0;
  int projector_height = 0;
  std::vector<FrameInfo> frames;
  std::string calibration;  // optional, relative path of a calibration YAML

  // Throws sope::Error describing the first inconsistency: sizes, duplicate frames,
  // a bit ≥ bits, bits too small for the projector size, mixed codes or bit counts on one
  // axis, an inverse without its pattern, no code or phase frames at all; for phase
  // frames: a period ≤ 0 or not finite, a shift not finite, a group with < 3 distinct
  // shifts, a finer group with neither a coarser group nor Gray code to unwrap it, Gray
  // code on a phase axis whose finest stripe (2^lowest bit) is not the coarsest period
  // wide (or one complementary bit finer). A Gray code on a phase axis needs neither
  // inverses nor white/black: it can be thresholded at the sinusoids' offset.
  void Check() const;
  // Index of the frame with this role (and axis/bit/inverted for codes), if present.
  std::optional<size_t> Find(FrameRole role) const;
  std::optional<size_t> FindCode(PatternAxis axis, int bit, bool inverted) const;
  bool HasAxis(PatternAxis axis) const;
  // Bits per code on `axis` (0 when the axis is not coded) and the lowest bit present.
  int AxisBits(PatternAxis axis) const;
  int AxisLowestBit(PatternAxis axis) const;
  PatternCode AxisCode(PatternAxis axis) const;
  // Phase frames: whether there are any (on `axis`), and the groups of an axis from the
  // coarsest period to the finest (empty when the axis has no phase frames).
  bool HasPhase() const;
  bool HasPhaseAxis(PatternAxis axis) const;
  std::vector<PhaseGroup> PhaseGroups(PatternAxis axis) const;

 private:
  void CheckPhaseGroups() const;
};

// Parses `frames.json` text; `source` names it in error messages.
FrameSetManifest ParseFrameSetManifest(const std::string& json_text, const std::string& source);
std::string SerializeFrameSetManifest(const FrameSetManifest& manifest);
// Reads and checks DIR/frames.json.
FrameSetManifest ReadFrameSetManifest(const std::string& directory);

struct FrameSet {
  FrameSetManifest manifest;
  std::string directory;  // where it was loaded from (empty for in-memory sets)
  // One single-channel image (CV_8UC1 or CV_16UC1) per manifest frame, same order.
  std::vector<cv::Mat> images;
  // The white frame in colour (CV_8UC3, BGR) when the file was colour; else empty.
  cv::Mat white_color;

  // Checks the manifest and that every image is present, single-channel 8/16-bit and of
  // the manifest's camera size. Throws sope::Error naming the frame.
  void Check() const;
  const cv::Mat& Image(size_t index) const { return images.at(index); }
};

// Loads and checks a frame set. Colour images are converted to grey (the white frame's
// colour is kept for the cloud). Throws sope::Error on a missing, unreadable or
// mismatched frame, or an inconsistent manifest.
FrameSet LoadFrameSet(const std::string& directory);
// Writes images as PNG (file names from the manifest) plus frames.json into `directory`,
// atomically as a whole (StagedDirectory). Checks the set first.
void WriteFrameSet(const std::string& directory, const FrameSet& frame_set);
// Writes the images and frames.json into an existing directory, non-atomically as a whole
// (each file atomically): for callers that stage a directory with more files in it.
void WriteFrameSetFiles(const std::string& directory, const FrameSet& frame_set);

}  // namespace sope
