#include "decoder/speckle_filter.h"

#include <cstdint>
#include <cstring>
#include <limits>
#include <utility>
#include <vector>

namespace sope {
namespace internal {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Whether neighbour (nu, nv) agrees with (u, v) within `tolerance` on both axes. Invalid
// pixels hold NaN, whose comparisons are false, so no mask is needed; an uncoded axis
// passes zeros for both.
inline bool Agrees(float u, float v, float nu, float nv, float tolerance) {
  const float du = nu - u, dv = nv - v;
  return (du <= tolerance) & (du >= -tolerance) & (dv <= tolerance) & (dv >= -tolerance);
}

// Agreement of neighbouring pixel pairs, 0 or 1 per pair, in arrays of cols + 2 entries
// (entry x + 1 for the pair starting at pixel x; the entries beyond the row stay 0). Agrees
// is symmetric (nu − u is exactly −(u − nu)), so each pair is tested once and counted for
// both of its pixels: four tests per pixel instead of eight.
struct PairAgreements {
  std::vector<uint8_t> below;        // rows y, y + 1: (x, x)
  std::vector<uint8_t> below_right;  // (x, x + 1) one row down
  std::vector<uint8_t> below_left;   // (x, x − 1) one row down
  explicit PairAgreements(int cols)
      : below(cols + 2, 0), below_right(cols + 2, 0), below_left(cols + 2, 0) {}
};

// Pairs within row (u, v) of n pixels.
void RowAgreements(const float* __restrict u, const float* __restrict v, int n, float tolerance,
                   uint8_t* __restrict right) {
  for (int x = 0; x + 1 < n; ++x) {
    right[x + 1] = Agrees(u[x], v[x], u[x + 1], v[x + 1], tolerance);
  }
}

// Pairs between row (u, v) and the row below it (ub, vb).
void RowPairAgreements(const float* __restrict u, const float* __restrict v,
                       const float* __restrict ub, const float* __restrict vb, int n,
                       float tolerance, uint8_t* __restrict below,
                       uint8_t* __restrict below_right, uint8_t* __restrict below_left) {
  for (int x = 0; x < n; ++x) below[x + 1] = Agrees(u[x], v[x], ub[x], vb[x], tolerance);
  for (int x = 0; x + 1 < n; ++x) {
    below_right[x + 1] = Agrees(u[x], v[x], ub[x + 1], vb[x + 1], tolerance);
  }
  for (int x = 1; x < n; ++x) {
    below_left[x + 1] = Agrees(u[x], v[x], ub[x - 1], vb[x - 1], tolerance);
  }
}

// flag[x] = 1 where a valid pixel of row y has fewer than `min_neighbours` agreeing
// neighbours among its 8: left and right (`row_right`, laid out as PairAgreements), the
// three above (`above`: rows y − 1, y) and the three below (`next`: rows y, y + 1).
void FlagSpeckles(const PairAgreements& above, const PairAgreements& next,
                  const uint8_t* __restrict row_right, const uint8_t* __restrict mask, int n,
                  int min_neighbours, uint8_t* __restrict flag) {
  const uint8_t* __restrict up = above.below.data();
  const uint8_t* __restrict up_left = above.below_right.data();   // (y − 1, x − 1) → (y, x)
  const uint8_t* __restrict up_right = above.below_left.data();   // (y − 1, x + 1) → (y, x)
  const uint8_t* __restrict down = next.below.data();
  const uint8_t* __restrict down_right = next.below_right.data();
  const uint8_t* __restrict down_left = next.below_left.data();
  for (int x = 0; x < n; ++x) {
    const int count = row_right[x] + row_right[x + 1] + up[x + 1] + down[x + 1] + up_left[x] +
                      up_right[x + 2] + down_right[x + 1] + down_left[x + 1];
    flag[x] = static_cast<uint8_t>((mask[x] != 0) & (count < min_neighbours));
  }
}

}  // namespace

void RemoveSpeckles(int min_neighbours, float tolerance, CorrespondenceMap* map) {
  const int rows = map->mask.rows, cols = map->mask.cols;
  const std::vector<float> zeros(cols, 0.0f);
  const std::vector<float> missing(cols, kNaN);  // the rows beyond the image
  auto row_of = [&](const cv::Mat& image, int y) -> const float* {
    if (y < 0 || y >= rows) return missing.data();
    return image.empty() ? zeros.data() : image.ptr<float>(y);
  };
  std::vector<uint8_t> flag(cols);
  std::vector<uint8_t> row_right(cols + 2, 0);
  // The pairs of rows (y − 1, y) and (y, y + 1); none above the first row.
  PairAgreements above(cols), next(cols);
  std::vector<int> cleared_previous, cleared_current;
  auto clear = [&](int y, const std::vector<int>& xs) {
    uint8_t* mask = map->mask.ptr<uint8_t>(y);
    float* confidence = map->confidence.ptr<float>(y);
    float* u = map->HasX() ? map->proj_x.ptr<float>(y) : nullptr;
    float* v = map->HasY() ? map->proj_y.ptr<float>(y) : nullptr;
    for (int x : xs) {
      mask[x] = 0;
      confidence[x] = 0.0f;
      if (u != nullptr) u[x] = kNaN;
      if (v != nullptr) v[x] = kNaN;
    }
  };
  for (int y = 0; y < rows; ++y) {
    const float* u = row_of(map->proj_x, y);
    const float* v = row_of(map->proj_y, y);
    RowAgreements(u, v, cols, tolerance, row_right.data());
    RowPairAgreements(u, v, row_of(map->proj_x, y + 1), row_of(map->proj_y, y + 1), cols,
                      tolerance, next.below.data(), next.below_right.data(),
                      next.below_left.data());
    FlagSpeckles(above, next, row_right.data(), map->mask.ptr<uint8_t>(y), cols, min_neighbours,
                 flag.data());
    std::swap(above, next);
    cleared_current.clear();
    for (int x = 0; x < cols; ++x) {
      // Skip 8 pixels at a time while none is flagged (the common case).
      if ((x & 7) == 0 && x + 8 <= cols) {
        uint64_t word = 0;
        std::memcpy(&word, flag.data() + x, sizeof(word));
        if (word == 0) {
          x += 7;
          continue;
        }
      }
      if (flag[x] != 0) cleared_current.push_back(x);
    }
    if (y > 0) clear(y - 1, cleared_previous);
    std::swap(cleared_previous, cleared_current);
  }
  if (rows > 0) clear(rows - 1, cleared_previous);
}

}  // namespace internal
}  // namespace sope
