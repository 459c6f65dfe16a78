// Sub-pixel Gray code: refines the block centres of a decoded Gray-code map
// from the two stripe edges that bound each pixel's block (scans and
// calibration alike).
#pragma once

#include "core/frame_set.h"
#include "decoder/decoder.h"

namespace sope {

// Refines the Gray-coded axes of `map` (decoded from `frames`) in place. A
// pixel decoded to block k sees a projector point between the two stripe edges
// that bound k; in a Gray code each edge is where one single bit flips, and
// that bit's pattern − inverse difference (pattern − (white + black)/2 without
// inverses), signed to be positive inside k, grows with the distance from its
// edge. With m₋ and m₊ the margins of the lower and upper edge's bits, the
// coordinate becomes
//   q + (step/2)·(m₋ − m₊)/(m₋ + m₊),
// exact for margins proportional to the distance (an edge blurred over at least
// the block: the usual case on real rigs, where a projector pixel spans about a
// camera pixel) and otherwise monotone and symmetric (where a projector pixel
// spans many camera pixels the margins saturate inside the block and the value
// stays near the centre there). This removes most of the quantisation error:
// the depth of a flat board then varies smoothly instead of in steps of one
// projector pixel.
//
// The map's confidence (the code's weakest bit margin) is kept: the edge bits
// are bits of the code, so it bounds the edge signal the interpolation rests
// on. Only block centres change: pixels the decoder put on a boundary (k + ½),
// values refined before (the call is idempotent), axes coded in binary or with
// phase frames (Gray + phase: already sub-pixel), and pixels whose bracketing
// edge is missing (the ends of the code range) keep their values. Throws
// sope::Error when `map` does not belong to `frames` (size).
void RefineGraySubpixel(const FrameSet& frames, CorrespondenceMap* map);

}  // namespace sope
