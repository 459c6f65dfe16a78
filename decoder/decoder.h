// Per-pixel decoding of a structured-light frame set into camera→projector
// correspondences.
#pragma once

#include <memory>
#include <string>

#include <opencv2/core/mat.hpp>

#include "core/frame_set.h"
#include "decoder/gray_subpixel_mode.h"
#include "decoder/phase_options.h"

namespace sope {

enum class BitDecision {
  // Against the inverse frame when the set has it, else against (white + black) / 2.
  kAuto,
  // Always against the per-pixel threshold (white + black) / 2.
  kThreshold,
  // Robust to indirect light (direct/global separation in the spirit of Xu & Aliaga 2007
  // and Moreno & Taubin's robust pixel classification): per-pixel direct and global
  // components are estimated from the high-frequency frames; a bit is decided only when
  // the pattern/inverse pair is unambiguous given them, otherwise the pixel is left
  // invalid rather than guessed.
  kRobust,
};
std::string ToString(BitDecision mode);
BitDecision BitDecisionFromString(const std::string& text);

struct DecoderOptions {
  // Minimum white − black contrast, grey levels on an 8-bit scale (16-bit images are
  // scaled by 1/257); darker pixels are shadow or off the projector. A pixel needs
  // white − black ≥ min_contrast (without white/black frames: the largest
  // |pattern − inverse| over the bits).
  double min_contrast = 10.0;
  // Minimum |pattern − inverse| (or |pattern − threshold| without inverses) for a bit to
  // count as decided (|d| ≥ min_bit_contrast), 8-bit grey levels. kRobust also uses it as
  // the minimum direct light.
  double min_bit_contrast = 3.0;
  // A bit also needs |pattern − inverse| ≥ min_relative_bit_contrast · (white − black)
  // (|pattern − threshold| ≥ half that), when the set has white and black frames: a pixel
  // that straddles a stripe edge sees both sides mixed, and noise must not decide it.
  // 0 (default) keeps OpenCV's absolute rule. With sharp optics 0.15–0.25 resolves more
  // edge pixels to their boundary (on the virtual rig: median depth error −35%); where the
  // finest stripes are blurred (real JPEG captures) it coarsens the finest bit instead.
  // Undecided bits are never guessed: a Gray-code pixel whose single undecided bit is the
  // one that changes between two neighbouring columns (rows) sits on their boundary and
  // decodes to it (c + ½ step); any other undecided bit invalidates the pixel.
  double min_relative_bit_contrast = 0.0;
  BitDecision bit_decision = BitDecision::kAuto;
  // kRobust only: fraction of the global component allowed to flip a decision (ε in
  // Xu & Aliaga); larger leaves more pixels undecided.
  double robust_margin = 0.1;
  // kRobust only: projector black level b in [0, 1), the fraction of a white pixel's light
  // a black projector pixel still emits (Moreno & Taubin's b in the direct/global split).
  double robust_black_level = 0.0;
  // Speckle filter: a decoded pixel must have at least this many of its 8 neighbours
  // decoded to within `neighbour_tolerance_px` projector pixels on every coded axis, else
  // it is invalidated. Isolated decodes are noise (e.g. pixels outside the projector's
  // light that pass the thresholds by chance); surfaces decode in patches. 0 disables.
  int min_consistent_neighbours = 2;
  double neighbour_tolerance_px = 2.0;
  // Threads for the decode loop; 1 = single-threaded.
  int num_threads = 1;
  // Gray-coded axes: block centres (the decoder's own output, comparable with OpenCV's) or
  // sub-pixel coordinates from the stripe edges (decoder/gray_refine.h; after the speckle
  // filter), which remove the projector-pixel steps of the depth. Scans (ScanOptions, the
  // CLI's --gray-subpixel) and calibration default to kEdges.
  GraySubpixel gray_subpixel = GraySubpixel::kOff;
  // Spatial code consistency (decoder/code_consistency.h): pixels left invalid are decoded
  // from their own bit margins within the range their decoded neighbours predict. Off here
  // (the per-pixel decode, comparable with OpenCV's); on in scans (ScanOptions) and in the
  // CLI's decode/scan commands (`--no-consistency` turns it off).
  struct Consistency {
    bool enabled = false;
    // Minimum white − black contrast of a filled pixel, grey levels (8-bit scale), and as
    // a fraction of its decoded neighbours' mean (0 = off): a pixel at a shadow's edge is
    // much darker than the lit surface beside it.
    double min_contrast = 4.0;
    double min_relative_contrast = 0.4;
    // Half side of the neighbour window, camera pixels, and the decoded neighbours needed.
    int window_radius = 3;
    int min_neighbours = 12;
    // Candidates: blocks whose centre is within this (+ half a block) of the neighbours'
    // prediction, projector px. 0.5: the prediction's block and its two neighbours at most
    // (1.0 let a second neighbour in and doubled the wrong fills on the grazing sphere).
    double search_radius_px = 0.5;
    // A bit whose margin exceeds this × min_bit_contrast must agree with the chosen code.
    double strong_bit_factor = 3.0;
    // The neighbours' coordinates must fit a plane (in camera x, y) to this RMS, projector px.
    double max_plane_rms_px = 1.0;
    // The chosen code's score must beat the runner-up's by this, grey levels (pattern −
    // inverse units, summed over the bits where the two differ).
    double min_lead = 3.0;
    // ... and their gradient must not exceed this, projector px per camera px (beyond, a
    // camera pixel sees several projector pixels and the code is a mixture).
    double max_gradient = 1.5;
    // Largest half side of the window a bit's margin is averaged over, camera pixels.
    int max_average_radius = 2;
    int passes = 8;
  } consistency;
  // Sets with phase frames (role `phase`): decoder/phase_decoder.h. min_contrast applies
  // to their white − black when they have those frames; the speckle filter and threads too.
  PhaseDecoderOptions phase;

  // Throws sope::Error naming an invalid value.
  void Check() const;
};

// CorrespondenceMap::step_x / step_y of a phase-decoded axis: its coordinates are
// continuous, projector pixels.
constexpr float kPhaseCoordinateStep = 1.0f / 64.0f;

struct CorrespondenceMap {
  int projector_width = 0;
  int projector_height = 0;
  // Projector column / row per camera pixel, CV_32FC1 of the camera size, in projector
  // pixels with OpenCV's centre convention; NaN where invalid. Empty when the axis is not
  // coded. When low bits are omitted the value is the centre of the coded block.
  cv::Mat proj_x;
  cv::Mat proj_y;
  // CV_8UC1: 255 where every coded axis decoded.
  cv::Mat mask;
  // CV_32FC1 in [0, 1]: the weakest bit's margin (|pattern − inverse|, or
  // |pattern − threshold| for bits decided without an inverse, which therefore reach at
  // most 0.5) relative to the white − black contrast (or, without white/black frames, to
  // the largest |pattern − inverse|); 0 where invalid. Phase sets: modulation / noise
  // (≥ 0, a signal-to-noise ratio; decoder/phase_decoder.h).
  cv::Mat confidence;
  // Quantum of the decoded coordinates, projector pixels (2^omitted low bits); phase axes
  // are continuous (sub-pixel) and report kPhaseCoordinateStep.
  float step_x = 1.0f;
  float step_y = 1.0f;

  bool HasX() const { return !proj_x.empty(); }
  bool HasY() const { return !proj_y.empty(); }
  int width() const { return mask.cols; }
  int height() const { return mask.rows; }
  // Number of valid pixels.
  size_t CountValid() const;
};

// Decodes a checked frame set. Throws sope::Error on invalid options or an inconsistent
// set (e.g. no inverses and no white/black for the threshold; kThreshold without
// white/black; kRobust without inverses).
//
// One pass over the frames: pixels are decoded in chunks, each chunk reading its part of
// every frame once (byte-wide, vectorised per-bit loops; Gray → binary and the block
// centre through a table); it costs a small multiple of reading the frames once
// (bench/decode_bench). num_threads > 1 splits the chunks; results are identical.
CorrespondenceMap Decode(const FrameSet& frame_set, const DecoderOptions& options = {});
// The same, into `map`: its images are reused when they already have the right size and
// type and are not shared with another cv::Mat, else reallocated. Scanning repeatedly into
// one map thus avoids allocating (and page-faulting in) ~13 bytes per camera pixel per scan.
void Decode(const FrameSet& frame_set, const DecoderOptions& options, CorrespondenceMap* map);

// Decoding while the frames are still being captured (the live loop): frames arrive one at
// a time with AddFrame, each bit is accumulated over the whole image as soon as its
// frames are in (pattern and inverse, and white/black first when the set has them), and
// Finish does only what needs every bit (coordinates, boundary pixels, speckle filter).
// The map is identical to Decode(frames, options) for any arrival order. The per-frame
// work is done for 8-bit sets decoded against inverses (kAuto with inverses, the
// default); other sets (kThreshold, kRobust, threshold bits, 16-bit) keep the frames and
// decode them in Finish.
//
//   IncrementalDecoder decoder(manifest, options);
//   for (size_t i = 0; i < manifest.frames.size(); ++i) decoder.AddFrame(i, Capture(i));
//   decoder.Finish(&map);
class IncrementalDecoder {
 public:
  // Throws sope::Error on invalid options or a manifest that cannot be decoded (as Decode).
  IncrementalDecoder(const FrameSetManifest& manifest, const DecoderOptions& options = {});
  ~IncrementalDecoder();
  IncrementalDecoder(const IncrementalDecoder&) = delete;
  IncrementalDecoder& operator=(const IncrementalDecoder&) = delete;

  // Frame `index` of the manifest: camera size, 8- or 16-bit grey like the rest of the set
  // (kept by reference, not copied: the caller must not write into it until Finish).
  // Throws sope::Error on a bad index, size or type, or a frame given twice.
  void AddFrame(size_t index, const cv::Mat& image);
  // Number of frames added so far.
  size_t FramesAdded() const;
  // After every frame has been added (else sope::Error naming the first missing one):
  // the map, into `map` as Decode(…, map) does. The decoder can then be reused for the
  // next frame set with Reset.
  void Finish(CorrespondenceMap* map);
  CorrespondenceMap Finish();
  // Forgets the frames (keeps the buffers).
  void Reset();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Writes proj_x.exr / proj_y.exr (float, NaN invalid), mask.png, confidence.exr,
// correspondence.json (projector size, steps), and the colourised views proj_x.png /
// proj_y.png (hue = coordinate, black = invalid) and confidence.png into `directory`,
// creating it. Written as a whole (StagedDirectory): nothing partial on a failure or a
// signal; an existing non-empty directory is replaced only when it holds a
// correspondence.json (an earlier map), otherwise refused.
void WriteCorrespondenceMap(const std::string& directory, const CorrespondenceMap& map);
// Reads what WriteCorrespondenceMap wrote; throws sope::Error on missing/mismatched files.
CorrespondenceMap ReadCorrespondenceMap(const std::string& directory);
// A colour picture of one axis (BGR, CV_8UC3): coordinate as hue, invalid pixels black.
// Hue runs from red (0) through green and blue to magenta (projector_size − 1), so both
// ends stay distinguishable.
cv::Mat ColorizeCoordinate(const cv::Mat& coordinate, int projector_size);

}  // namespace sope
