#include "recogniser/cloud_filters.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <utility>

#include <immintrin.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "core/error.h"

namespace sope {
namespace internal {
namespace {

constexpr int kAxisBits = 21;
constexpr int64_t kAxisLimit = int64_t{1} << kAxisBits;  // cells per axis in a packed key
constexpr int64_t kVoxelOffset = int64_t{1} << (kAxisBits - 1);

uint64_t PackKey(int64_t x, int64_t y, int64_t z) {
  // z slowest, x fastest: sorting keys sorts as PCL's VoxelGrid orders its voxels.
  return (static_cast<uint64_t>(z) << (2 * kAxisBits)) | (static_cast<uint64_t>(y) << kAxisBits) |
         static_cast<uint64_t>(x);
}

void UnpackKey(uint64_t key, int64_t* x, int64_t* y, int64_t* z) {
  const uint64_t mask = static_cast<uint64_t>(kAxisLimit - 1);
  *x = static_cast<int64_t>(key & mask);
  *y = static_cast<int64_t>((key >> kAxisBits) & mask);
  *z = static_cast<int64_t>(key >> (2 * kAxisBits));
}

uint64_t HashKey(uint64_t key) {
  // SplitMix64 finaliser: cheap and mixes the packed coordinates well.
  key ^= key >> 30;
  key *= 0xbf58476d1ce4e5b9ULL;
  key ^= key >> 27;
  key *= 0x94d049bb133111ebULL;
  key ^= key >> 31;
  return key;
}

size_t NextPowerOfTwo(size_t n) {
  size_t p = 1;
  while (p < n) p <<= 1;
  return p;
}

// Squared distance and index packed so that integer order = (distance, index) order
// (IEEE-754 bit patterns of non-negative floats are monotonic).
uint64_t PackCandidate(float sq_distance, int32_t index) {
  uint32_t bits;
  std::memcpy(&bits, &sq_distance, sizeof(bits));
  return (static_cast<uint64_t>(bits) << 32) | static_cast<uint32_t>(index);
}
float CandidateDistance(uint64_t packed) {
  const uint32_t bits = static_cast<uint32_t>(packed >> 32);
  float value;
  std::memcpy(&value, &bits, sizeof(value));
  return value;
}
int32_t CandidateIndex(uint64_t packed) { return static_cast<int32_t>(packed & 0xffffffffu); }

// Relative safety margin on the "no closer point outside the searched block" test: float
// rounding of a squared distance is far below it.
constexpr float kBoundMargin = 1.0f - 1e-5f;

#if defined(__AVX512F__)
// The min(16, n) smallest of the n distinct packed candidates `in`, ascending, into
// out[0, min(16, n)) (out may be in): an insertion into a sorted register pair per
// candidate — lanes greater than the candidate take their left neighbour or the
// candidate, whichever is greater.
void SmallestSixteen(const uint64_t* in, size_t n, uint64_t* out) {
  __m512i lo = _mm512_set1_epi64(-1), hi = lo;
  for (size_t i = 0; i < n; ++i) {
    const __m512i c = _mm512_set1_epi64(static_cast<long long>(in[i]));
    const __mmask8 above_lo = _mm512_cmpgt_epu64_mask(lo, c);
    const __mmask8 above_hi = _mm512_cmpgt_epu64_mask(hi, c);
    const __m512i shifted_lo = _mm512_alignr_epi64(lo, c, 7);   // c, lo0 … lo6
    const __m512i shifted_hi = _mm512_alignr_epi64(hi, lo, 7);  // lo7, hi0 … hi6
    lo = _mm512_mask_mov_epi64(lo, above_lo, _mm512_max_epu64(shifted_lo, c));
    hi = _mm512_mask_mov_epi64(hi, above_hi, _mm512_max_epu64(shifted_hi, c));
  }
  alignas(64) uint64_t sorted[16];
  _mm512_store_si512(sorted, lo);
  _mm512_store_si512(sorted + 8, hi);
  std::memcpy(out, sorted, std::min<size_t>(n, 16) * sizeof(uint64_t));
}
#endif

}  // namespace

// ---------------------------------------------------------------------------------------
// Voxel grid

namespace {

// The keys of a chunk of points (pass 1 of VoxelCentroidsOf): the packed voxel key of each
// point kept, kSkippedKey for the others. Branch-free over the chunk (GCC vectorises it):
// with `band`, a point is kept when finite and its squared norm (in double) is in
// [min_sq, max_sq]; without, every point is kept and must be finite. Returns false when a
// kept point's voxel lies outside the packed keys' range (or is not finite without `band`);
// adds the chunk's finite and kept points to *finite and *kept.
constexpr uint64_t kSkippedKey = ~uint64_t{0};  // PackKey uses 63 bits: never a key
template <bool kBand>
bool ChunkKeys(const float* __restrict xyz, int n, float inverse_leaf, double min_sq,
               double max_sq, uint64_t* __restrict keys, int64_t* finite, int64_t* kept) {
  constexpr float kFloatMax = std::numeric_limits<float>::max();
  // floor(p · (1/leaf)) + offset must lie in [0, kAxisLimit): compared in float, where
  // these bounds and every floor are exact integers.
  constexpr float kLow = -static_cast<float>(kVoxelOffset);
  constexpr float kHigh = static_cast<float>(kAxisLimit - kVoxelOffset);
  int finite_count = 0, kept_count = 0, bad = 0;
  for (int i = 0; i < n; ++i) {
    const float x = xyz[3 * i], y = xyz[3 * i + 1], z = xyz[3 * i + 2];
    const int is_finite = (std::abs(x) <= kFloatMax) & (std::abs(y) <= kFloatMax) &
                          (std::abs(z) <= kFloatMax);
    int keep = 1;
    if constexpr (kBand) {
      const double sq = static_cast<double>(x) * x + static_cast<double>(y) * y +
                        static_cast<double>(z) * z;
      keep = is_finite & (sq >= min_sq) & (sq <= max_sq);
    }
    // Cells by floor(p · (1/leaf)) (float, as PCL), in range when the product is in
    // [kLow, kHigh) (a floor is ≥ an integer bound iff the product is). The floor from an
    // int32 truncation, exact in that range; out of it the product is zeroed first (by its
    // bits: GCC turns a select into a branch around the conversion and then does not
    // vectorise), and the key becomes kSkippedKey (by an OR, for the same reason).
    const float ax = x * inverse_leaf, ay = y * inverse_leaf, az = z * inverse_leaf;
    const int in_range = (ax >= kLow) & (ax < kHigh) & (ay >= kLow) & (ay < kHigh) &
                         (az >= kLow) & (az < kHigh);
    const int ok = keep & in_range;
    const uint32_t zero_unless_ok = 0u - static_cast<uint32_t>(ok);
    const auto cell = [zero_unless_ok](float a) {
      const float product =
          __builtin_bit_cast(float, __builtin_bit_cast(uint32_t, a) & zero_unless_ok);
      const int32_t t = static_cast<int32_t>(product);
      return static_cast<uint32_t>(t - static_cast<int32_t>(static_cast<float>(t) > product) +
                                   static_cast<int32_t>(kVoxelOffset));
    };
    keys[i] = PackKey(cell(ax), cell(ay), cell(az)) | (static_cast<uint64_t>(ok) - 1);
    finite_count += is_finite;
    kept_count += keep;
    bad += keep & (in_range ^ 1);
  }
  *finite += finite_count;
  *kept += kept_count;
  return bad == 0;
}

// VoxelGridCentroids of the points kept (all, or with `band` those ChunkKeys keeps). Two
// passes per chunk of points: their keys (vectorised), then the sums per voxel.
std::vector<Eigen::Vector3f> VoxelCentroidsOf(const std::vector<Eigen::Vector3f>& points,
                                              float leaf, std::vector<uint32_t>* counts,
                                              bool band, double min_sq, double max_sq,
                                              int64_t* finite_points, int64_t* kept_points) {
  SOPE_CHECK(std::isfinite(leaf) && leaf > 0.0f, "voxel grid: leaf must be > 0 metres, got {}",
             leaf);
  if (counts != nullptr) counts->clear();
  if (points.empty()) return {};
  const float inverse_leaf = 1.0f / leaf;  // float, as pcl::VoxelGrid

  // Open addressing, each slot a voxel (key, sums, count: one cache line per probe); an
  // empty slot holds kSkippedKey, which no voxel has. At most half full.
  struct Slot {
    uint64_t key;
    uint32_t count;
    double sum[3];
  };
  size_t capacity = NextPowerOfTwo(std::max<size_t>(1024, points.size() / 16));
  std::vector<Slot> table(capacity, Slot{kSkippedKey, 0, {0.0, 0.0, 0.0}});
  size_t occupied = 0;
  // The slot of `key` (inserted empty if new).
  auto find = [&](uint64_t key) {
    size_t slot = HashKey(key) & (capacity - 1);
    while (table[slot].key != key && table[slot].key != kSkippedKey) {
      slot = (slot + 1) & (capacity - 1);
    }
    if (table[slot].key == kSkippedKey) {
      table[slot].key = key;
      ++occupied;
    }
    return &table[slot];
  };
  auto grow = [&] {
    std::vector<Slot> old(2 * capacity, Slot{kSkippedKey, 0, {0.0, 0.0, 0.0}});
    old.swap(table);
    capacity *= 2;
    occupied = 0;
    for (const Slot& slot : old) {
      if (slot.key != kSkippedKey) *find(slot.key) = slot;
    }
  };

  // Points in scan order fall into the voxel of the point before them most of the time:
  // the current voxel's sums stay in registers until the key changes (the same additions
  // in the same order, without a store → load chain per point).
  uint64_t last_key = kSkippedKey;
  Slot* current = nullptr;
  double sx = 0.0, sy = 0.0, sz = 0.0;
  uint32_t count = 0;
  auto store = [&] {
    if (current == nullptr) return;
    current->sum[0] = sx;
    current->sum[1] = sy;
    current->sum[2] = sz;
    current->count = count;
  };
  constexpr int kKeyChunk = 1024;
  alignas(64) uint64_t keys[kKeyChunk];
  const float* xyz = points.data()->data();
  static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float), "packed xyz");
  int64_t finite = 0, kept = 0;
  for (size_t begin = 0; begin < points.size(); begin += kKeyChunk) {
    const int n = static_cast<int>(std::min<size_t>(kKeyChunk, points.size() - begin));
    const bool in_range =
        band ? ChunkKeys<true>(xyz + 3 * begin, n, inverse_leaf, min_sq, max_sq, keys, &finite,
                               &kept)
             : ChunkKeys<false>(xyz + 3 * begin, n, inverse_leaf, min_sq, max_sq, keys, &finite,
                                &kept);
    if (!in_range) {
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3f& p = points[begin + static_cast<size_t>(i)];
        SOPE_CHECK(keys[i] != kSkippedKey || (band && !(IsFinitePoint(p) &&
                                                         SquaredRangeBand{min_sq, max_sq}
                                                             .Contains(p))),
                   "voxel grid: point ({}, {}, {}) is more than 2^20 leaves ({} m) from the "
                   "origin",
                   p.x(), p.y(), p.z(), leaf);
      }
    }
    for (int i = 0; i < n; ++i) {
      const uint64_t key = keys[i];
      if (key == kSkippedKey) continue;
      if (key != last_key) {
        store();
        current = find(key);
        if (2 * occupied > capacity) {
          grow();
          current = find(key);
        }
        last_key = key;
        sx = current->sum[0];
        sy = current->sum[1];
        sz = current->sum[2];
        count = current->count;
      }
      const float* p = xyz + 3 * (begin + static_cast<size_t>(i));
      sx += p[0];
      sy += p[1];
      sz += p[2];
      ++count;
    }
  }
  store();
  if (finite_points != nullptr) *finite_points = finite;
  if (kept_points != nullptr) *kept_points = kept;

  // In key order (as PCL's VoxelGrid orders its voxels).
  std::vector<std::pair<uint64_t, uint32_t>> order;
  order.reserve(occupied);
  for (size_t slot = 0; slot < capacity; ++slot) {
    if (table[slot].key != kSkippedKey) order.emplace_back(table[slot].key, slot);
  }
  std::sort(order.begin(), order.end());
  std::vector<Eigen::Vector3f> centroids;
  centroids.reserve(order.size());
  if (counts != nullptr) counts->reserve(order.size());
  for (const auto& [key, slot] : order) {
    const Slot& voxel = table[slot];
    if (counts != nullptr) counts->push_back(voxel.count);
    const double inv = 1.0 / voxel.count;
    centroids.emplace_back(static_cast<float>(voxel.sum[0] * inv),
                           static_cast<float>(voxel.sum[1] * inv),
                           static_cast<float>(voxel.sum[2] * inv));
  }
  return centroids;
}

}  // namespace

std::vector<Eigen::Vector3f> VoxelGridCentroids(const std::vector<Eigen::Vector3f>& points,
                                                float leaf, std::vector<uint32_t>* counts) {
  return VoxelCentroidsOf(points, leaf, counts, false, 0.0, 0.0, nullptr, nullptr);
}

std::vector<Eigen::Vector3f> VoxelGridCentroidsInBand(const std::vector<Eigen::Vector3f>& points,
                                                      float leaf, double min_sq, double max_sq,
                                                      std::vector<uint32_t>* counts,
                                                      int64_t* finite, int64_t* in_band) {
  return VoxelCentroidsOf(points, leaf, counts, true, min_sq, max_sq, finite, in_band);
}

// ---------------------------------------------------------------------------------------
// Neighbour grid

NeighbourGrid::NeighbourGrid(const std::vector<Eigen::Vector3f>& points, int expected_k)
    : input_(points) {
  if (input_.empty()) return;
  Eigen::Vector3d lo = input_[0].cast<double>(), hi = lo;
  for (const Eigen::Vector3f& p : input_) {
    SOPE_CHECK(std::isfinite(p.x()) && std::isfinite(p.y()) && std::isfinite(p.z()),
               "NeighbourGrid: non-finite point ({}, {}, {})", p.x(), p.y(), p.z());
    lo = lo.cwiseMin(p.cast<double>());
    hi = hi.cwiseMax(p.cast<double>());
  }
  origin_ = lo;
  Eigen::Vector3d extent = hi - lo;
  std::sort(extent.data(), extent.data() + 3, std::greater<double>());
  const double n = static_cast<double>(input_.size());
  // Surface samples: spacing ≈ √(area / n) with the area of the two largest extents.
  double cell =
      extent[0] > 0.0 ? std::sqrt(extent[0] * std::max(extent[1], 1e-3 * extent[0]) / n) : 1.0;
  Build(cell);
  const double target = std::max(3.0, (expected_k + 1) / 2.0);
  const double occupancy = n / static_cast<double>(cells_.size());
  if (cells_.size() > 1 && (occupancy < 0.5 * target || occupancy > 2.0 * target)) {
    Build(cell_ * std::clamp(std::sqrt(target / occupancy), 0.25, 4.0));
  }
}

void NeighbourGrid::Build(double cell_size) {
  Eigen::Vector3d hi = origin_;
  for (const Eigen::Vector3f& p : input_) hi = hi.cwiseMax(p.cast<double>());
  const double largest = (hi - origin_).maxCoeff();
  cell_ = std::max({cell_size, largest / static_cast<double>(kAxisLimit - 2), 1e-12});
  inv_cell_ = 1.0 / cell_;
  for (int a = 0; a < 3; ++a) {
    dims_[a] = static_cast<int64_t>(std::floor((hi[a] - origin_[a]) * inv_cell_)) + 1;
  }

  const size_t n = input_.size();
  std::vector<std::pair<uint64_t, int32_t>> keyed(n);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f& p = input_[i];
    keyed[i] = {Key(CellCoord(p.x(), 0), CellCoord(p.y(), 1), CellCoord(p.z(), 2)),
                static_cast<int32_t>(i)};
  }
  std::sort(keyed.begin(), keyed.end());
  xs_.resize(n);
  ys_.resize(n);
  zs_.resize(n);
  original_index_.resize(n);
  cells_.clear();
  for (size_t s = 0; s < n; ++s) {
    const int32_t i = keyed[s].second;
    xs_[s] = input_[i].x();
    ys_[s] = input_[i].y();
    zs_[s] = input_[i].z();
    original_index_[s] = i;
    if (cells_.empty() || cells_.back().key != keyed[s].first) {
      cells_.push_back(Cell{keyed[s].first, static_cast<uint32_t>(s), static_cast<uint32_t>(s)});
    }
    cells_.back().end = static_cast<uint32_t>(s + 1);
  }
  dense_.clear();
  table_.clear();
  const double grid_cells = static_cast<double>(dims_[0]) * dims_[1] * dims_[2];
  if (grid_cells <= std::max(16.0 * n, 65536.0) && grid_cells <= double(1 << 24)) {
    dense_.assign(static_cast<size_t>(grid_cells), -1);
    for (size_t c = 0; c < cells_.size(); ++c) {
      int64_t x, y, z;
      UnpackKey(cells_[c].key, &x, &y, &z);
      dense_[static_cast<size_t>(x + dims_[0] * (y + dims_[1] * z))] = static_cast<int32_t>(c);
    }
    return;
  }
  const size_t capacity = NextPowerOfTwo(2 * cells_.size() + 2);
  table_.assign(capacity, -1);
  table_mask_ = capacity - 1;
  for (size_t c = 0; c < cells_.size(); ++c) {
    uint64_t slot = HashKey(cells_[c].key) & table_mask_;
    while (table_[slot] >= 0) slot = (slot + 1) & table_mask_;
    table_[slot] = static_cast<int32_t>(c);
  }
}

int64_t NeighbourGrid::CellCoord(float value, int axis) const {
  return static_cast<int64_t>(std::floor((static_cast<double>(value) - origin_[axis]) * inv_cell_));
}

uint64_t NeighbourGrid::Key(int64_t cx, int64_t cy, int64_t cz) const {
  return PackKey(std::clamp<int64_t>(cx, 0, dims_[0] - 1), std::clamp<int64_t>(cy, 0, dims_[1] - 1),
                 std::clamp<int64_t>(cz, 0, dims_[2] - 1));
}

const NeighbourGrid::Cell* NeighbourGrid::Find(int64_t cx, int64_t cy, int64_t cz) const {
  if (cx < 0 || cy < 0 || cz < 0 || cx >= dims_[0] || cy >= dims_[1] || cz >= dims_[2]) {
    return nullptr;
  }
  if (!dense_.empty()) {
    const int32_t c = dense_[static_cast<size_t>(cx + dims_[0] * (cy + dims_[1] * cz))];
    return c >= 0 ? &cells_[c] : nullptr;
  }
  const uint64_t key = PackKey(cx, cy, cz);
  uint64_t slot = HashKey(key) & table_mask_;
  while (table_[slot] >= 0) {
    const Cell& cell = cells_[table_[slot]];
    if (cell.key == key) return &cell;
    slot = (slot + 1) & table_mask_;
  }
  return nullptr;
}

void NeighbourGrid::GatherRing(int64_t cx, int64_t cy, int64_t cz, int64_t ring,
                               std::vector<const Cell*>* cells) const {
  for (int64_t dz = -ring; dz <= ring; ++dz) {
    for (int64_t dy = -ring; dy <= ring; ++dy) {
      const bool inner = std::abs(dz) < ring && std::abs(dy) < ring;
      // Inside the ring's shell only x = ±ring are new.
      const int64_t step = inner ? 2 * ring : 1;
      for (int64_t dx = -ring; dx <= ring; dx += std::max<int64_t>(step, 1)) {
        if (const Cell* cell = Find(cx + dx, cy + dy, cz + dz)) cells->push_back(cell);
      }
    }
  }
}

void NeighbourGrid::KNearest(const Eigen::Vector3f& query, int k, std::vector<int32_t>* indices,
                             std::vector<float>* sq_distances) const {
  indices->clear();
  sq_distances->clear();
  const int want = std::min<int>(k, static_cast<int>(size()));
  if (want <= 0) return;
  const int64_t c[3] = {CellCoord(query.x(), 0), CellCoord(query.y(), 1), CellCoord(query.z(), 2)};
  // Distance from the query to the faces of its own cell.
  double face = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    const double lo = origin_[a] + c[a] * cell_;
    face = std::min({face, query[a] - lo, lo + cell_ - query[a]});
  }
  face = std::max(face, 0.0);
  std::vector<uint64_t> candidates;
  std::vector<const Cell*> cells;
  // Rings before the first one that reaches the grid are empty.
  int64_t first_ring = 0;
  for (int a = 0; a < 3; ++a) {
    first_ring = std::max({first_ring, -c[a], c[a] - (dims_[a] - 1)});
  }
  bool brute_force = false;
  for (int64_t ring = 0;; ++ring) {
    // Far from the cloud (an isolated outlier, a query point outside it) shells of empty
    // cells dominate: once a shell holds more cells than the grid has occupied ones, scan
    // every point instead (O(n), exact).
    const double shell_cells =
        std::pow(2.0 * ring + 1.0, 3) - std::pow(std::max(2.0 * ring - 1.0, 0.0), 3);
    if (ring > 1 && shell_cells > 4.0 * static_cast<double>(cells_.size())) {
      brute_force = true;
      break;
    }
    if (ring < first_ring) continue;
    cells.clear();
    GatherRing(c[0], c[1], c[2], ring, &cells);
    for (const Cell* cell : cells) {
      for (uint32_t s = cell->begin; s < cell->end; ++s) {
        const float dx = xs_[s] - query.x(), dy = ys_[s] - query.y(), dz = zs_[s] - query.z();
        candidates.push_back(PackCandidate(dx * dx + dy * dy + dz * dz, original_index_[s]));
      }
    }
    bool covered = true;
    for (int a = 0; a < 3; ++a)
      covered = covered && c[a] - ring <= 0 && c[a] + ring >= dims_[a] - 1;
    if (static_cast<int>(candidates.size()) >= want) {
      std::nth_element(candidates.begin(), candidates.begin() + (want - 1), candidates.end());
      const double bound = ring * cell_ + face;
      if (covered || CandidateDistance(candidates[want - 1]) <
                         static_cast<float>(bound * bound) * kBoundMargin) {
        break;
      }
    } else if (covered) {
      break;
    }
  }
  if (brute_force) {
    candidates.clear();
    for (size_t s = 0; s < size(); ++s) {
      const float dx = xs_[s] - query.x(), dy = ys_[s] - query.y(), dz = zs_[s] - query.z();
      candidates.push_back(PackCandidate(dx * dx + dy * dy + dz * dz, original_index_[s]));
    }
    std::nth_element(candidates.begin(), candidates.begin() + (want - 1), candidates.end());
  }
  std::sort(candidates.begin(), candidates.begin() + want);
  for (int j = 0; j < want; ++j) {
    indices->push_back(CandidateIndex(candidates[j]));
    sq_distances->push_back(CandidateDistance(candidates[j]));
  }
}

NeighbourTable NeighbourGrid::AllKNearest(int k) const {
  SOPE_CHECK(k >= 1, "AllKNearest: k must be ≥ 1, got {}", k);
  NeighbourTable table;
  const size_t n = size();
  table.count = static_cast<int>(std::min<size_t>(k, n));
  if (table.count == 0) return table;
  table.index.resize(n * table.count);
  table.sq_distance.resize(n * table.count);
  const int others = table.count - 1;

  // Candidates of one cell's points: the 3×3×3 block around it ("near"), and the ring of
  // cells at Chebyshev distance 2 ("far", gathered only when a point needs it).
  struct Candidates {
    std::vector<float> x, y, z;
    std::vector<int32_t> index;
    void Clear() {
      x.clear();
      y.clear();
      z.clear();
      index.clear();
    }
  };
  auto gather = [&](const std::vector<const Cell*>& cells, Candidates* out) {
    out->Clear();
    for (const Cell* c : cells) {
      out->x.insert(out->x.end(), xs_.begin() + c->begin, xs_.begin() + c->end);
      out->y.insert(out->y.end(), ys_.begin() + c->begin, ys_.begin() + c->end);
      out->z.insert(out->z.end(), zs_.begin() + c->begin, zs_.begin() + c->end);
      out->index.insert(out->index.end(), original_index_.begin() + c->begin,
                        original_index_.begin() + c->end);
    }
  };
  // A block's candidates are kept only inside the radius it is guaranteed to cover: a
  // nearer one beyond it could hide outside the block, so the others-th nearest must lie
  // inside anyway, and the selection then runs on about half the block's points.
  std::vector<uint64_t> candidates;
  auto add = [&](const Candidates& from, float qx, float qy, float qz, int32_t self,
                 float max_sq) {
    size_t n = candidates.size();
    candidates.resize(n + from.index.size() + 8);  // + 8: full-width stores of compressed lanes
    uint64_t* out = candidates.data();
    size_t j = 0;
#if defined(__AVX512F__) && defined(__FMA__)
    // 16 at a time: the same squared distances (the scalar loop's contraction,
    // fma(dz, dz, fma(dx, dx, dy·dy))), the kept ones packed in order by a register
    // compress and a full-width store (the + 8 above).
    const __m512 vx = _mm512_set1_ps(qx), vy = _mm512_set1_ps(qy), vz = _mm512_set1_ps(qz);
    const __m512 vmax = _mm512_set1_ps(max_sq);
    const __m512i vself = _mm512_set1_epi32(self);
    for (; j + 16 <= from.index.size(); j += 16) {
      const __m512 dx = _mm512_sub_ps(_mm512_loadu_ps(from.x.data() + j), vx);
      const __m512 dy = _mm512_sub_ps(_mm512_loadu_ps(from.y.data() + j), vy);
      const __m512 dz = _mm512_sub_ps(_mm512_loadu_ps(from.z.data() + j), vz);
      const __m512 sq = _mm512_fmadd_ps(dz, dz, _mm512_fmadd_ps(dx, dx, _mm512_mul_ps(dy, dy)));
      const __m512i index = _mm512_loadu_si512(from.index.data() + j);
      const __mmask16 keep = _mm512_cmp_ps_mask(sq, vmax, _CMP_LT_OQ) &
                             _mm512_cmpneq_epi32_mask(index, vself);
      const __m512i bits = _mm512_castps_si512(sq);
      const __m512i lo = _mm512_or_si512(
          _mm512_slli_epi64(_mm512_cvtepu32_epi64(_mm512_castsi512_si256(bits)), 32),
          _mm512_cvtepu32_epi64(_mm512_castsi512_si256(index)));
      const __m512i hi = _mm512_or_si512(
          _mm512_slli_epi64(_mm512_cvtepu32_epi64(_mm512_extracti64x4_epi64(bits, 1)), 32),
          _mm512_cvtepu32_epi64(_mm512_extracti64x4_epi64(index, 1)));
      const __mmask8 keep_lo = static_cast<__mmask8>(keep);
      const __mmask8 keep_hi = static_cast<__mmask8>(keep >> 8);
      _mm512_storeu_si512(out + n, _mm512_maskz_compress_epi64(keep_lo, lo));
      n += static_cast<size_t>(__builtin_popcount(keep_lo));
      _mm512_storeu_si512(out + n, _mm512_maskz_compress_epi64(keep_hi, hi));
      n += static_cast<size_t>(__builtin_popcount(keep_hi));
    }
#endif
    for (; j < from.index.size(); ++j) {
      const float dx = from.x[j] - qx, dy = from.y[j] - qy, dz = from.z[j] - qz;
      const float sq = dx * dx + dy * dy + dz * dz;
      out[n] = PackCandidate(sq, from.index[j]);  // kept by advancing past it (no branch)
      n += static_cast<size_t>(sq < max_sq) & static_cast<size_t>(from.index[j] != self);
    }
    candidates.resize(n);
  };
  // True (and the first `others` candidates sorted) when `others` candidates lie inside the
  // covered radius (all candidates do, by `add`).
  auto settle = [&]() {
    if (static_cast<int>(candidates.size()) < others) return false;
#if defined(__AVX512F__)
    if (others <= 16) {
      SmallestSixteen(candidates.data(), candidates.size(), candidates.data());
      return true;
    }
#endif
    std::nth_element(candidates.begin(), candidates.begin() + (others - 1), candidates.end());
    std::sort(candidates.begin(), candidates.begin() + others);
    return true;
  };
  auto covered_sq = [](double bound) { return static_cast<float>(bound * bound) * kBoundMargin; };

  std::vector<const Cell*> cells;
  Candidates near, far;
  float previous_kth_sq = std::numeric_limits<float>::infinity();
  std::vector<int32_t> slow_indices;
  std::vector<float> slow_distances;
  for (const Cell& cell : cells_) {
    int64_t gx, gy, gz;
    UnpackKey(cell.key, &gx, &gy, &gz);
    cells.clear();
    GatherRing(gx, gy, gz, 0, &cells);
    GatherRing(gx, gy, gz, 1, &cells);
    gather(cells, &near);
    bool far_ready = false;
    const double lo[3] = {origin_[0] + gx * cell_, origin_[1] + gy * cell_,
                          origin_[2] + gz * cell_};
    for (uint32_t s = cell.begin; s < cell.end; ++s) {
      const float qx = xs_[s], qy = ys_[s], qz = zs_[s];
      const int32_t self = original_index_[s];
      int32_t* out_index = table.index.data() + static_cast<size_t>(self) * table.count;
      float* out_distance = table.sq_distance.data() + static_cast<size_t>(self) * table.count;
      out_index[0] = self;
      out_distance[0] = 0.0f;
      if (others == 0) continue;
      double face = std::numeric_limits<double>::infinity();
      const float q[3] = {qx, qy, qz};
      for (int a = 0; a < 3; ++a) face = std::min({face, q[a] - lo[a], lo[a] + cell_ - q[a]});
      face = std::max(face, 0.0);
      // First inside a guess of the others-th distance (the previous point's, 20% wider;
      // neighbours have similar ones), then inside the whole covered radius.
      const float near_sq = covered_sq(cell_ + face);
      const float guess_sq = std::min(near_sq, 1.44f * previous_kth_sq);
      candidates.clear();
      add(near, qx, qy, qz, self, guess_sq);
      bool done = settle();
      if (!done && guess_sq < near_sq) {
        candidates.clear();
        add(near, qx, qy, qz, self, near_sq);
        done = settle();
      }
      if (!done) {
        if (!far_ready) {
          cells.clear();
          GatherRing(gx, gy, gz, 2, &cells);
          gather(cells, &far);
          far_ready = true;
        }
        const float far_sq = covered_sq(2.0 * cell_ + face);
        candidates.clear();
        add(near, qx, qy, qz, self, far_sq);
        add(far, qx, qy, qz, self, far_sq);
        done = settle();
      }
      if (done) {
        previous_kth_sq = CandidateDistance(candidates[others - 1]);
        for (int j = 0; j < others; ++j) {
          out_index[j + 1] = CandidateIndex(candidates[j]);
          out_distance[j + 1] = CandidateDistance(candidates[j]);
        }
        continue;
      }
      // Rare: a sparse neighbourhood; expand shells around the point. The point itself is
      // among the k + 1 nearest (distance 0; a coincident point with a lower index may
      // precede it), so drop it and keep the first `others` of the rest.
      KNearest(input_[self], table.count + 1, &slow_indices, &slow_distances);
      int j = 0;
      for (size_t m = 0; m < slow_indices.size() && j < others; ++m) {
        if (slow_indices[m] == self) continue;
        out_index[j + 1] = slow_indices[m];
        out_distance[j + 1] = slow_distances[m];
        ++j;
      }
    }
  }
  return table;
}

// ---------------------------------------------------------------------------------------
// Statistical outlier removal and normals

std::vector<uint8_t> StatisticalInlierMask(const NeighbourTable& table, int mean_k,
                                           double stddev_multiplier,
                                           const std::vector<uint32_t>* weights, double min_ratio) {
  const size_t n = table.size();
  std::vector<uint8_t> keep(n, 1);
  const int used = std::min(mean_k, table.count - 1);
  if (n < 2 || used < 1) return keep;
  SOPE_CHECK(weights == nullptr || weights->size() == n,
             "StatisticalInlierMask: {} weights for {} points", weights ? weights->size() : 0, n);
  std::vector<float> distances(n);
  double sum = 0.0, sq_sum = 0.0, count = 0.0;
  for (size_t i = 0; i < n; ++i) {
    const float* d = table.row_sq_distance(i);
    double row_sum = 0.0;
    for (int j = 1; j <= used; ++j) row_sum += std::sqrt(d[j]);
    distances[i] = static_cast<float>(row_sum / used);
    const double w = weights != nullptr ? (*weights)[i] : 1.0;
    sum += w * distances[i];
    sq_sum += w * (distances[i] * distances[i]);  // float product, as PCL
    count += w;
  }
  const double mean = sum / count;
  const double variance = (sq_sum - sum * sum / count) / (count - 1.0);
  const double threshold =
      std::max(mean + stddev_multiplier * std::sqrt(std::max(variance, 0.0)), min_ratio * mean);
  for (size_t i = 0; i < n; ++i) keep[i] = !(distances[i] > threshold);
  return keep;
}

bool SmallestEigenpair(const Eigen::Matrix3d& covariance, double* value,
                       Eigen::Vector3d* vector) {
  const double trace = covariance.trace();
  if (!(trace > 0.0) || !std::isfinite(trace)) return false;
  // On A = C / trace (eigenvalues in [0, 1], summing to 1): the characteristic polynomial
  // f(λ) = λ³ − λ² + c1·λ − c0 is increasing and concave below its smallest root (which is
  // at most the mean eigenvalue, 1/3), so Newton's method from 0 rises to it monotonically;
  // fast when the root is simple, as a surface's normal direction is.
  const Eigen::Matrix3d a = covariance / trace;
  const double c1 = a(0, 0) * a(1, 1) - a(0, 1) * a(0, 1) + a(0, 0) * a(2, 2) -
                    a(0, 2) * a(0, 2) + a(1, 1) * a(2, 2) - a(1, 2) * a(1, 2);
  const double c0 = a.determinant();
  double lambda = 0.0;
  bool converged = false;
  for (int iteration = 0; iteration < 32; ++iteration) {
    const double f = ((lambda - 1.0) * lambda + c1) * lambda - c0;
    const double slope = (3.0 * lambda - 2.0) * lambda + c1;
    if (!(slope > 0.0)) break;  // a double root (or rounding at one): not this method's
    if (f >= 0.0) {             // at the root to rounding (or just past it, at 0: keep 0)
      converged = true;
      break;
    }
    const double next = lambda - f / slope;
    if (next <= lambda * (1.0 + 4.0 * std::numeric_limits<double>::epsilon())) {
      converged = true;
      break;
    }
    lambda = next;
  }
  // The eigenvector: the largest cross product of two rows of A − λI (as Eigen's direct
  // solver). Its norm is about (λ1 − λ)(λ2 − λ), the slope of f at the root: below 1e-4,
  // λ near a double (or triple) root, which Newton's method approaches slowly and rounding
  // stops short of, Eigen's direct solver takes over.
  Eigen::Vector3d best = Eigen::Vector3d::Zero();
  double best_norm = 0.0;
  if (converged) {
    const Eigen::Matrix3d shifted = a - lambda * Eigen::Matrix3d::Identity();
    const Eigen::Vector3d r0 = shifted.row(0), r1 = shifted.row(1), r2 = shifted.row(2);
    for (const Eigen::Vector3d& c : {r0.cross(r1), r0.cross(r2), r1.cross(r2)}) {
      const double n = c.squaredNorm();
      if (n > best_norm) {
        best_norm = n;
        best = c;
      }
    }
  }
  if (!(best_norm > 1e-8)) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver;
    solver.computeDirect(covariance);
    *value = solver.eigenvalues()[0];
    *vector = solver.eigenvectors().col(0);
    return vector->allFinite() && std::isfinite(*value);
  }
  *value = lambda * trace;
  *vector = best / std::sqrt(best_norm);
  return true;
}

bool FitNormal(const std::vector<Eigen::Vector3f>& points, const int32_t* neighbours, int count,
               const Eigen::Vector3f& point, const Eigen::Vector3f& viewpoint,
               Eigen::Vector3f* normal, float* curvature) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  *normal = Eigen::Vector3f::Constant(nan);
  *curvature = nan;
  if (count < 3) return false;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (int j = 0; j < count; ++j) mean += points[neighbours[j]].cast<double>();
  mean /= count;
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (int j = 0; j < count; ++j) {
    const Eigen::Vector3d d = points[neighbours[j]].cast<double>() - mean;
    covariance.noalias() += d * d.transpose();
  }
  covariance /= count;
  double smallest;
  Eigen::Vector3d n;
  // False for a trace not positive and finite, or a non-finite fallback result.
  if (!SmallestEigenpair(covariance, &smallest, &n)) return false;
  n.normalize();
  if ((viewpoint - point).cast<double>().dot(n) < 0.0) n = -n;
  *normal = n.cast<float>();
  *curvature = static_cast<float>(std::abs(smallest / covariance.trace()));
  return true;
}

}  // namespace internal
}  // namespace sope
