// The speckle filter shared by the Gray-code and the phase-shift decoders.
#pragma once

#include "decoder/decoder.h"

namespace sope {
namespace internal {

// DecoderOptions::min_consistent_neighbours: clears (mask 0, confidence 0, coordinates
// NaN) every valid pixel with fewer than `min_neighbours` of its 8 neighbours within
// `tolerance` projector pixels on every coded axis (an uncoded axis is empty and agrees).
// Decisions read the unfiltered coordinates. A bit or unwrapping error moves a pixel far
// beyond the tolerance.
void RemoveSpeckles(int min_neighbours, float tolerance, CorrespondenceMap* map);

}  // namespace internal
}  // namespace sope
