// The Gray sub-pixel mode of DecoderOptions (decoder/gray_refine.h has the
// method).
#pragma once

#include <string>

namespace sope {

// Whether Decode refines Gray-coded axes to sub-pixel
// (DecoderOptions::gray_subpixel).
enum class GraySubpixel {
  // Block centres: the integer coordinate (the block's centre when low bits are
  // omitted).
  kOff,
  // Refined from the stripe edges (RefineGraySubpixel) on every Gray-coded
  // axis.
  kEdges,
};
std::string ToString(GraySubpixel mode);
GraySubpixel GraySubpixelFromString(const std::string& text);  // "off", "edges"

}  // namespace sope
