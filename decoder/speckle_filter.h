// The speckle filter shared by the Gray-code and the phase-shift decoders.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "decoder/chunk_workers.h"
#include "decoder/decoder.h"

namespace sope {
namespace internal {

// DecoderOptions::min_consistent_neighbours: clears (mask 0, confidence 0, coordinates
// NaN) every valid pixel with fewer than `min_neighbours` of its 8 neighbours within
// `tolerance` projector pixels on every coded axis (an uncoded axis is empty and agrees).
// Decisions read the unfiltered coordinates. A bit or unwrapping error moves a pixel far
// beyond the tolerance.
void RemoveSpeckles(int min_neighbours, float tolerance, CorrespondenceMap* map);

// The same filter over rows [first_row, end_row) of the map, row by row as the rows are
// decoded (top to bottom): a row is filtered once the row below it is final, while both
// are still in the cache. It reads rows first_row − 1 … end_row unfiltered, so the
// flagged pixels of its first and last rows are cleared only by ClearEdges, once the
// neighbouring ranges are filtered too. The map's images must have their final size when
// the filter is made; rows not yet announced are not read.
//
//   SpeckleFilter filter(min_neighbours, tolerance, &map);  // every row
//   ... decode rows [0, r) ...  filter.RowsDecoded(r);  ...
//   filter.Finish();      // every row decoded
//   filter.ClearEdges();
class SpeckleFilter {
 public:
  // end_row < 0: the map's rows.
  SpeckleFilter(int min_neighbours, float tolerance, CorrespondenceMap* map, int first_row = 0,
                int end_row = -1);
  // Rows first_row − 1 … rows − 1 hold their final, unfiltered values.
  void RowsDecoded(int rows);
  // Every row the filter reads is decoded: filters the rest of its rows and clears the
  // flagged pixels of all but the first and last.
  void Finish();
  // Clears the flagged pixels of the first and last rows (after Finish).
  void ClearEdges();
  // The rows it filters: [first_row, end_row).
  int first_row() const { return first_row_; }
  int end_row() const { return end_row_; }

 private:
  // Agreement of neighbouring pixel pairs, 0 or 1 per pair, in arrays of cols + 2 entries
  // (entry x + 1 for the pair starting at pixel x; the entries beyond the row stay 0).
  struct PairAgreements {
    std::vector<uint8_t> below;        // rows y, y + 1: (x, x)
    std::vector<uint8_t> below_right;  // (x, x + 1) one row down
    std::vector<uint8_t> below_left;   // (x, x − 1) one row down
    explicit PairAgreements(int cols);
  };
  const float* Row(const cv::Mat& image, int y) const;
  void Pairs(int y, PairAgreements* pairs) const;  // rows y, y + 1
  void FilterRow(int y);
  void Clear(int y, const std::vector<int>& xs);

  const int min_neighbours_;
  const float tolerance_;
  CorrespondenceMap* map_;
  const int rows_, cols_;
  const int first_row_, end_row_;
  int next_row_;  // the next row to filter
  std::vector<float> zeros_, missing_;  // an uncoded axis; the rows beyond the image
  std::vector<uint8_t> flag_, row_right_;
  PairAgreements above_, next_;  // the pairs of rows (y − 1, y) and (y, y + 1)
  // Flagged pixels of the row filtered last, of the first row, and of the last row.
  std::vector<int> cleared_previous_, cleared_current_, first_row_flags_, last_row_flags_;
};

// The filter while several workers decode contiguous pixel ranges of the map (the
// decoders' chunk workers): each worker filters the rows inside its range as it decodes
// them (PixelsDecoded, from that worker's thread only), and Finish filters the rows
// between the ranges once every worker is done. The map equals RemoveSpeckles'.
class BandedSpeckleFilter {
 public:
  // worker_pixels[w] = [begin, end) of worker w, in order, covering the map's pixels.
  BandedSpeckleFilter(int min_neighbours, float tolerance, CorrespondenceMap* map,
                      const std::vector<std::pair<size_t, size_t>>& worker_pixels);
  // Worker w's pixels [begin, end) are decoded.
  void PixelsDecoded(size_t worker, size_t end);
  void Finish();

 private:
  const int min_neighbours_;
  const float tolerance_;
  CorrespondenceMap* map_;
  std::vector<std::unique_ptr<SpeckleFilter>> bands_;  // per worker; null: no row inside
};

// The decoders' chunk loop with the speckle filter fused in: decode_chunk(worker, begin, n)
// for every chunk of `chunk_pixels` of the map's `total` pixels on `num_workers` workers
// (RunChunksOnWorkers), each worker filtering its rows as it decodes them when
// min_neighbours > 0 (BandedSpeckleFilter), the rows between workers at the end.
template <typename DecodeChunk>
void DecodeChunksAndFilter(size_t total, size_t chunk_pixels, size_t num_workers,
                           int min_neighbours, float tolerance, CorrespondenceMap* map,
                           const DecodeChunk& decode_chunk) {
  const size_t num_chunks = (total + chunk_pixels - 1) / chunk_pixels;
  std::optional<BandedSpeckleFilter> filter;
  if (min_neighbours > 0) {
    std::vector<std::pair<size_t, size_t>> worker_pixels;
    for (size_t w = 0; w < num_workers; ++w) {
      const auto [first, last] = WorkerChunks(w, num_chunks, num_workers);
      worker_pixels.emplace_back(first * chunk_pixels, std::min(last * chunk_pixels, total));
    }
    filter.emplace(min_neighbours, tolerance, map, worker_pixels);
  }
  RunChunksOnWorkers(num_chunks, num_workers, [&](size_t worker, size_t chunk) {
    const size_t begin = chunk * chunk_pixels;
    const size_t end = std::min(begin + chunk_pixels, total);
    decode_chunk(worker, begin, static_cast<int>(end - begin));
    if (filter) filter->PixelsDecoded(worker, end);
  });
  if (filter) filter->Finish();
}

}  // namespace internal
}  // namespace sope
