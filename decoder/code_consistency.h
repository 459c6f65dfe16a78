// Spatial code consistency: decodes the pixels the per-pixel decoder left invalid (dim,
// grazing surfaces, stripe edges without inverse frames) from their decoded neighbours and
// their own bit margins, never against a clearly decided bit.
#pragma once

#include "core/frame_set.h"
#include "decoder/decoder.h"

namespace sope {

// Fills invalid pixels of the code-coded axes of `map` (decoded from `frames`). Surfaces
// decode in patches and their projector coordinates vary smoothly, so an invalid pixel
// with enough decoded neighbours has a predicted coordinate (their median, per axis); the
// code words of the blocks within options.search_radius_px of it are the candidates, and
// the pixel takes the one its own bits support best — the maximum-likelihood word under
// equal Gaussian noise on every bit, score Σ_b ±d_b with d_b the bit's signed margin
// (pattern − inverse, or 2·(pattern − (white + black)/2) without inverses) — provided that
//   • the pixel's contrast is ≥ options.min_contrast grey levels,
//   • no bit decided by more than options.strong_bit_factor × min_bit_contrast disagrees
//     with it (the prediction is then wrong: an occlusion edge, another surface), and
//   • it beats the runner-up by ≥ options.consistency.min_lead (its bits do decide) — or,
//     when the two best are neighbouring blocks (their Gray words differ in the one bit
//     that flips at their shared edge, whose margin is then small: the pixel sees that
//     edge), both beat every other candidate by it, and the pixel takes the edge's
//     coordinate (k + ½ between blocks k and k + 1; confidence halved).
// A per-pixel decision relative to the pixel's own margins, so it works at any contrast;
// the neighbours only bound the search, so a pixel cannot take a code its bits contradict.
// Filled pixels get the block centre (then RefineGraySubpixel, when on) and confidence
// (best − runner-up score) / (4·contrast), at most ½. Repeated options.passes times, each
// pass growing from the pixels filled before. Axes with phase frames are left alone.
// `region` (CV_8UC1 of the camera size, or empty: everywhere) limits the filled pixels to
// its non-zero ones (decoded neighbours outside it still count): a tabletop scan fills
// only near what stands on the table (recogniser/tools/scan_recognition.h).
// `seeds` (CV_8UC1 of the camera size, or empty: no such limit) marks the decoded pixels
// the fills grow from (a tabletop scan: those whose points stand on the table): a pixel is
// decided only when its window holds a seed, and a filled pixel is a seed when at least
// half its decoded neighbours are — the fills spread over the surfaces of the seeds, not
// across the table around them.
void FillFromConsistentNeighbours(const FrameSet& frames, const DecoderOptions& options,
                                  CorrespondenceMap* map, const cv::Mat& region = cv::Mat(),
                                  const cv::Mat& seeds = cv::Mat());

}  // namespace sope
