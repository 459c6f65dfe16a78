// The scan pipeline, once for every caller: frame set → decode → triangulate.
#pragma once

#include <string>

#include "calibration/triangulation.h"
#include "core/frame_set.h"
#include "core/rig_calibration.h"
#include "decoder/decoder.h"

namespace sope {

struct ScanOptions {
  // Scans refine Gray codes to sub-pixel (decoder/gray_refine.h) and decode the pixels
  // the per-pixel decoder left undecided from their neighbours and their own bits
  // (decoder/code_consistency.h: dim, grazing surfaces) by default.
  DecoderOptions decoder = [] {
    DecoderOptions options;
    options.gray_subpixel = GraySubpixel::kEdges;
    options.consistency.enabled = true;
    return options;
  }();
  TriangulationOptions triangulation;
  void Check() const {
    decoder.Check();
    triangulation.Check();
  }
};

struct ScanResult {
  CorrespondenceMap correspondences;
  TriangulationResult triangulation;
  double decode_ms = 0.0;
  double triangulate_ms = 0.0;
};

// Throws sope::Error unless the calibration's camera and projector sizes are those the
// frames were captured and coded with; `calibration_source` names it in the message.
void CheckCalibrationMatchesFrames(const RigCalibration& calibration,
                                   const FrameSetManifest& manifest,
                                   const std::string& calibration_source);

// The calibration for a frame set: `calibration_path` when given, else the file the
// manifest names (relative to the frame-set directory). Throws sope::Error when neither
// exists or the sizes do not match the frames.
RigCalibration ResolveCalibration(const FrameSet& frames, const std::string& calibration_path);

// Decodes and triangulates. The white frame (colour when available) colours the cloud.
ScanResult ScanFrameSet(const FrameSet& frames, const Triangulator& triangulator,
                        const DecoderOptions& decoder_options);
ScanResult ScanFrameSet(const FrameSet& frames, const RigCalibration& calibration,
                        const ScanOptions& options = {});

// Triangulates a map of `frames` decoded already (by an IncrementalDecoder while the
// frames were captured: the live loop); `decode_ms` is the decoding left after the last
// frame, reported as ScanResult::decode_ms. The white frame colours the cloud.
ScanResult ScanDecoded(const FrameSet& frames, CorrespondenceMap correspondences,
                       double decode_ms, const Triangulator& triangulator);

}  // namespace sope
