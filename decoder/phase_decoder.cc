#include "decoder/phase_decoder.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <vector>

#include <Eigen/Dense>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "decoder/chunk_workers.h"
#include "decoder/plane_fit_sums.h"
#include "decoder/speckle_filter.h"
#include "projector/patterns.h"

namespace sope {
namespace internal {
namespace {

constexpr double kTwoPiD = 6.283185307179586476925286766559;
constexpr float kTwoPi = static_cast<float>(kTwoPiD);
constexpr float kPi = static_cast<float>(kTwoPiD / 2);
constexpr float kHalfPi = static_cast<float>(kTwoPiD / 4);
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInfinity = std::numeric_limits<float>::infinity();
// Pixels decoded together: every frame is read once per chunk while the per-chunk sums
// stay in L1/L2 (as in the Gray decoder).
constexpr int kChunkPixels = 4096;
// Bins of a gamma correction table over [0, 2π); nearest-bin lookup errs by less than
// slope × π/bins, far below the noise.
constexpr int kCorrectionBins = 4096;
// Fixed-point iterations inverting φ_measured(φ_true) for the correction table.
constexpr int kCorrectionIterations = 6;
// Gray + phase: outside [¼, ¾] of a period the Gray index may be off by one.
constexpr float kEdgeFraction = 0.25f;
// Gray + phase without the complementary bit: a Gray bit counts as possibly misdecided at
// its edge when its |pattern − inverse| is below this fraction of the pixel's largest.
constexpr float kAmbiguousMargin = 0.5f;
constexpr int kAxisX = static_cast<int>(PatternAxis::kX);
constexpr int kAxisY = static_cast<int>(PatternAxis::kY);
constexpr int kMaxGrayBits = 16;
constexpr int kMaxGroupsPerAxis = 8;
// The local fit's tolerance: at least this many standard deviations of the pixel's
// coordinate noise (from its confidence).
constexpr double kLocalFitSigmas = 4.0;

inline float FastWrappedAtan2(float y, float x) {
  // atan on [0, 1]: Abramowitz & Stegun 4.4.49-style odd minimax polynomial.
  constexpr float a1 = 0.99997726f, a3 = -0.33262347f, a5 = 0.19354346f, a7 = -0.11643287f,
                  a9 = 0.05265332f, a11 = -0.01172120f;
  const float ax = std::abs(x), ay = std::abs(y);
  const float big = std::max(ax, ay), small = std::min(ax, ay);
  const float z = big > 0.0f ? small / big : 0.0f;
  const float z2 = z * z;
  float angle = z * (a1 + z2 * (a3 + z2 * (a5 + z2 * (a7 + z2 * (a9 + z2 * a11)))));
  angle = ay > ax ? kHalfPi - angle : angle;
  angle = x < 0.0f ? kPi - angle : angle;
  angle = y < 0.0f ? kTwoPi - angle : angle;
  return angle >= kTwoPi ? angle - kTwoPi : angle;
}

struct GroupPlan {
  double period = 0.0;
  bool absolute = false;
  std::vector<int> frames;
  PhaseFit fit;
  std::vector<float> correction;  // empty: none
  explicit GroupPlan(const PhaseGroup& group)
      : period(group.period), absolute(group.absolute), fit(group.shifts) {
    for (size_t index : group.frames) frames.push_back(static_cast<int>(index));
  }
};

struct GrayBit {
  int pattern = -1;
  int inverse = -1;  // −1: against (white + black) / 2
};

struct AxisPlan {
  bool coded = false;
  int size = 0;
  std::vector<GroupPlan> groups;  // coarsest first
  // Gray code of the axis (bits from the most significant down to lowest_bit).
  std::vector<GrayBit> gray_bits;
  int gray_lowest_bit = 0;
  bool complementary = false;  // the lowest Gray bit is half a period wide
};

struct Plan {
  std::array<AxisPlan, 2> axes;
  int white = -1;
  int black = -1;
  int degrees_of_freedom = 0;  // Σ (N_g − 3): residual degrees of freedom of the fits
};

Plan MakePlan(const FrameSetManifest& manifest, const PhaseDecoderOptions& options) {
  Plan plan;
  if (const auto white = manifest.Find(FrameRole::kWhite)) plan.white = static_cast<int>(*white);
  if (const auto black = manifest.Find(FrameRole::kBlack)) plan.black = static_cast<int>(*black);
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    AxisPlan& axis_plan = plan.axes[static_cast<int>(axis)];
    axis_plan.size = axis == PatternAxis::kX ? manifest.projector_width : manifest.projector_height;
    SOPE_CHECK(manifest.PhaseGroups(axis).size() <= static_cast<size_t>(kMaxGroupsPerAxis),
               "axis {}: {} phase groups (at most {})", ToString(axis),
               manifest.PhaseGroups(axis).size(), kMaxGroupsPerAxis);
    for (const PhaseGroup& group : manifest.PhaseGroups(axis)) {
      axis_plan.groups.emplace_back(group);
      GroupPlan& added = axis_plan.groups.back();
      added.correction = MakePhaseCorrectionTable(added.fit, options.response, kCorrectionBins);
      plan.degrees_of_freedom += static_cast<int>(group.frames.size()) - 3;
    }
    if (manifest.HasAxis(axis)) {
      SOPE_CHECK(manifest.AxisCode(axis) == PatternCode::kGray,
                 "axis {}: phase sets combine with Gray codes only", ToString(axis));
      const int bits = manifest.AxisBits(axis);
      axis_plan.gray_lowest_bit = manifest.AxisLowestBit(axis);
      SOPE_CHECK(bits - axis_plan.gray_lowest_bit <= kMaxGrayBits, "axis {}: too many Gray bits",
                 ToString(axis));
      for (int bit = bits - 1; bit >= axis_plan.gray_lowest_bit; --bit) {
        GrayBit gray;
        gray.pattern = static_cast<int>(*manifest.FindCode(axis, bit, false));
        if (const auto inverse = manifest.FindCode(axis, bit, true)) {
          gray.inverse = static_cast<int>(*inverse);
        } else {
          SOPE_CHECK((plan.white >= 0 && plan.black >= 0) || !axis_plan.groups.empty(),
                     "axis {} bit {} has no inverse frame and the set has no white and black "
                     "frames or phase frames on the axis for a threshold", ToString(axis), bit);
        }
        axis_plan.gray_bits.push_back(gray);
      }
      if (!axis_plan.groups.empty()) {
        axis_plan.complementary =
            std::ldexp(2.0, axis_plan.gray_lowest_bit) == axis_plan.groups.front().period;
      }
    }
    axis_plan.coded = !axis_plan.groups.empty() || !axis_plan.gray_bits.empty();
  }
  return plan;
}

// Per-thread scratch of one chunk.
struct Workspace {
  alignas(64) float q0[kChunkPixels];  // Σ I_k
  alignas(64) float q1[kChunkPixels];  // Σ I_k cos s_k
  alignas(64) float q2[kChunkPixels];  // Σ I_k sin s_k
  alignas(64) float ss[kChunkPixels];  // Σ I_k²
  alignas(64) float fraction[kChunkPixels];     // φ / 2π of the current group
  alignas(64) float coordinate[2][kChunkPixels];
  alignas(64) float min_modulation[kChunkPixels];
  alignas(64) float residual[kChunkPixels];     // Σ over groups of the residual sum of squares
  alignas(64) float finest_modulation[kChunkPixels];
  alignas(64) float finest_offset[kChunkPixels];
  alignas(64) float offset[kChunkPixels];  // A of the group fitted last
  alignas(64) float modulation_of_group[kChunkPixels];  // B of the group fitted last
  alignas(64) uint8_t valid[kChunkPixels];       // every check so far, all axes
  alignas(64) uint8_t axis_valid[kChunkPixels];  // the unwrapping of the current axis
  alignas(64) float absolute[kChunkPixels];      // the absolute group's coordinate
  alignas(64) float group_fraction[kMaxGroupsPerAxis][kChunkPixels];
  alignas(64) float gray_margin[kMaxGrayBits][kChunkPixels];  // signed p − p̄ (or 2p − (w + b))
  alignas(64) float gray_contrast[kChunkPixels];  // max over the bits of |margin|
  alignas(64) uint32_t gray_word[kChunkPixels];
};

struct Outputs {
  float* proj[2] = {nullptr, nullptr};
  uint8_t* mask = nullptr;
  float* confidence = nullptr;
  float* wrapped[2] = {nullptr, nullptr};
  float* modulation = nullptr;
  void* texture = nullptr;
};

struct Thresholds {
  float min_modulation = 0.0f;  // image levels
  float min_contrast = 0.0f;
  float max_unwrap_error = 0.0f;
  float noise_floor = 0.0f;  // image levels
  float levels_per_grey_level = 1.0f;
};

template <typename Pixel>
class ChunkDecoder {
 public:
  ChunkDecoder(const Plan& plan, const std::vector<const Pixel*>& frames,
               const Thresholds& thresholds, const Outputs& outputs)
      : plan_(plan),
        frames_(frames),
        thresholds_(thresholds),
        outputs_(outputs),
        ws_(std::make_unique<Workspace>()) {}

  void Decode(size_t begin, int n) {
    Workspace& ws = *ws_;
    std::fill_n(ws.valid, n, uint8_t{1});
    std::fill_n(ws.min_modulation, n, kInfinity);
    std::fill_n(ws.residual, n, 0.0f);
    std::fill_n(ws.finest_modulation, n, 0.0f);
    std::fill_n(ws.finest_offset, n, 0.0f);
    if (plan_.white >= 0 && plan_.black >= 0) CheckContrast(begin, n);
    bool finest_set = false;
    for (int axis : {kAxisX, kAxisY}) {
      const AxisPlan& axis_plan = plan_.axes[axis];
      if (!axis_plan.coded) continue;
      float* coordinate = ws.coordinate[axis];
      if (axis_plan.groups.empty()) {
        DecodeGray(axis_plan, begin, n);
        GrayBlockCentres(axis_plan, n, coordinate);
        for (int i = 0; i < n; ++i) ws.valid[i] &= ws.axis_valid[i];
        continue;
      }
      std::fill_n(ws.axis_valid, n, uint8_t{1});
      for (size_t g = 0; g < axis_plan.groups.size(); ++g) {
        const GroupPlan& group = axis_plan.groups[g];
        const bool finest = g + 1 == axis_plan.groups.size();
        FitGroup(group, begin, n, finest && !finest_set);
        std::copy_n(ws.fraction, n, ws.group_fraction[g]);
        if (finest) {
          finest_set = true;
          if (outputs_.wrapped[axis] != nullptr) {
            float* wrapped = outputs_.wrapped[axis] + begin;
            for (int i = 0; i < n; ++i) wrapped[i] = kTwoPi * ws.fraction[i];
          }
        }
        if (g == 0) {
          if (axis_plan.gray_bits.empty()) {
            AbsoluteCoordinate(group, axis_plan.size, n, coordinate);
            std::copy_n(coordinate, n, ws.absolute);
          } else {
            DecodeGray(axis_plan, begin, n);  // after the fit: may threshold at its offset
            GrayUnwrap(axis_plan, group, n, coordinate);
          }
        } else {
          TemporalUnwrap(group, n, coordinate);
        }
      }
      // On the projector: within half a pixel of the first and last pixel centres.
      const float low = -0.5f, high = static_cast<float>(axis_plan.size) - 0.5f;
      for (int i = 0; i < n; ++i) {
        const float u = coordinate[i];
        ws.axis_valid[i] = static_cast<uint8_t>(ws.axis_valid[i] & (u >= low) & (u <= high));
      }
      if (!axis_plan.groups.empty() && axis_plan.gray_bits.empty()) {
        RetryOtherBranch(axis_plan, n, coordinate);
      }
      for (int i = 0; i < n; ++i) ws.valid[i] &= ws.axis_valid[i];
    }
    Finish(begin, n);
  }

 private:
  const Pixel* Frame(int index, size_t begin) const { return frames_[index] + begin; }

  void CheckContrast(size_t begin, int n) {
    const Pixel* __restrict white = Frame(plan_.white, begin);
    const Pixel* __restrict black = Frame(plan_.black, begin);
    uint8_t* __restrict valid = ws_->valid;
    const float min_contrast = thresholds_.min_contrast;
    for (int i = 0; i < n; ++i) {
      const float contrast = static_cast<float>(white[i]) - static_cast<float>(black[i]);
      valid[i] = static_cast<uint8_t>(valid[i] & (contrast >= min_contrast));
    }
  }

  // Least squares of one group: fraction = φ/2π (corrected), modulation checks, residuals.
  void FitGroup(const GroupPlan& group, size_t begin, int n, bool keep_texture) {
    Workspace& ws = *ws_;
    float* __restrict q0 = ws.q0;
    float* __restrict q1 = ws.q1;
    float* __restrict q2 = ws.q2;
    float* __restrict ss = ws.ss;
    std::fill_n(q0, n, 0.0f);
    std::fill_n(q1, n, 0.0f);
    std::fill_n(q2, n, 0.0f);
    std::fill_n(ss, n, 0.0f);
    for (size_t k = 0; k < group.frames.size(); ++k) {
      const Pixel* __restrict frame = Frame(group.frames[k], begin);
      const float c = group.fit.cos_shift[k], s = group.fit.sin_shift[k];
      for (int i = 0; i < n; ++i) {
        const float value = static_cast<float>(frame[i]);
        q0[i] += value;
        q1[i] += c * value;
        q2[i] += s * value;
        ss[i] += value * value;
      }
    }
    const auto& m = group.fit.inverse_normal;
    const float m00 = m[0][0], m01 = m[0][1], m02 = m[0][2], m11 = m[1][1], m12 = m[1][2],
                m22 = m[2][2];
    float* __restrict fraction = ws.fraction;
    float* __restrict min_modulation = ws.min_modulation;
    float* __restrict residual = ws.residual;
    float* __restrict finest_modulation = ws.finest_modulation;
    float* __restrict finest_offset = ws.finest_offset;
    float* __restrict offset = ws.offset;
    float* __restrict modulation_of_group = ws.modulation_of_group;
    for (int i = 0; i < n; ++i) {
      const float a = m00 * q0[i] + m01 * q1[i] + m02 * q2[i];
      const float cc = m01 * q0[i] + m11 * q1[i] + m12 * q2[i];
      const float sc = m02 * q0[i] + m12 * q1[i] + m22 * q2[i];
      const float modulation = std::sqrt(cc * cc + sc * sc);
      const float rss = ss[i] - (a * q0[i] + cc * q1[i] + sc * q2[i]);
      residual[i] += std::max(rss, 0.0f);
      min_modulation[i] = std::min(min_modulation[i], modulation);
      fraction[i] = FastWrappedAtan2(sc, cc) * (1.0f / kTwoPi);
      offset[i] = a;
      modulation_of_group[i] = modulation;
    }
    if (keep_texture) {
      std::copy_n(modulation_of_group, n, finest_modulation);
      std::copy_n(offset, n, finest_offset);
    }
    if (!group.correction.empty()) {
      const float* __restrict table = group.correction.data();
      const float bins = static_cast<float>(group.correction.size());
      const int last = static_cast<int>(group.correction.size()) - 1;
      for (int i = 0; i < n; ++i) {
        const int bin = std::min(static_cast<int>(fraction[i] * bins), last);
        float corrected = fraction[i] - table[bin];
        corrected -= std::floor(corrected);
        fraction[i] = corrected;
      }
    }
  }

  // Absolute group: u = f·P, the part of [0, P) beyond the projector folded to negative u
  // (noise at u ≈ 0 must not wrap to u ≈ P).
  void AbsoluteCoordinate(const GroupPlan& group, int size, int n, float* __restrict coordinate) {
    const float period = static_cast<float>(group.period);
    const float fold = 0.5f * (static_cast<float>(size) - 0.5f + period - 0.5f);
    const float* __restrict fraction = ws_->fraction;
    for (int i = 0; i < n; ++i) {
      const float u = fraction[i] * period;
      coordinate[i] = u > fold ? u - period : u;
    }
  }

  // k = round((u_coarse − f·P) / P), u = (k + f)·P; |u − u_coarse| > max_unwrap_error·P
  // invalidates the pixel.
  void TemporalUnwrap(const GroupPlan& group, int n, float* __restrict coordinate) {
    const float period = static_cast<float>(group.period);
    const float inverse_period = 1.0f / period;
    const float max_error = thresholds_.max_unwrap_error;
    const float* __restrict fraction = ws_->fraction;
    uint8_t* __restrict valid = ws_->axis_valid;
    for (int i = 0; i < n; ++i) {
      const float coarse = coordinate[i] * inverse_period;
      const float k = std::floor(coarse - fraction[i] + 0.5f);
      const float fine = k + fraction[i];
      const float error = std::abs(fine - coarse);
      valid[i] = static_cast<uint8_t>(valid[i] & (error <= max_error));
      coordinate[i] = fine * period;
    }
  }

  // An absolute group whose period barely exceeds the projector cannot tell u ≈ 0 from
  // u ≈ period when the noise is a few pixels: pixels that failed with the folded coarse
  // coordinate are unwrapped again from the other branch (u_coarse ∓ period) and kept when
  // that passes every check and lands on the projector.
  void RetryOtherBranch(const AxisPlan& axis, int n, float* __restrict coordinate) {
    Workspace& ws = *ws_;
    const float period = static_cast<float>(axis.groups.front().period);
    const float size = static_cast<float>(axis.size);
    const float max_error = thresholds_.max_unwrap_error;
    for (int i = 0; i < n; ++i) {
      if (ws.axis_valid[i]) continue;
      float u = ws.absolute[i] < 0.5f * size ? ws.absolute[i] + period : ws.absolute[i] - period;
      bool ok = true;
      for (size_t g = 1; g < axis.groups.size() && ok; ++g) {
        const float fine_period = static_cast<float>(axis.groups[g].period);
        const float coarse = u / fine_period;
        const float f = ws.group_fraction[g][i];
        const float fine = std::floor(coarse - f + 0.5f) + f;
        ok = std::abs(fine - coarse) <= max_error;
        u = fine * fine_period;
      }
      if (ok && u >= -0.5f && u <= size - 0.5f) {
        coordinate[i] = u;
        ws.axis_valid[i] = 1;
      }
    }
  }

  // Signed margins of every Gray bit and the Gray word (most significant bit first).
  void DecodeGray(const AxisPlan& axis, size_t begin, int n) {
    Workspace& ws = *ws_;
    uint32_t* __restrict word = ws.gray_word;
    float* __restrict contrast = ws.gray_contrast;
    std::fill_n(word, n, 0u);
    std::fill_n(contrast, n, 0.0f);
    for (size_t b = 0; b < axis.gray_bits.size(); ++b) {
      const GrayBit& bit = axis.gray_bits[b];
      const Pixel* __restrict pattern = Frame(bit.pattern, begin);
      float* __restrict margin = ws.gray_margin[b];
      if (bit.inverse >= 0) {
        const Pixel* __restrict inverse = Frame(bit.inverse, begin);
        for (int i = 0; i < n; ++i) {
          margin[i] = static_cast<float>(pattern[i]) - static_cast<float>(inverse[i]);
        }
      } else if (plan_.white >= 0 && plan_.black >= 0) {
        const Pixel* __restrict white = Frame(plan_.white, begin);
        const Pixel* __restrict black = Frame(plan_.black, begin);
        for (int i = 0; i < n; ++i) {
          margin[i] = 2.0f * static_cast<float>(pattern[i]) - static_cast<float>(white[i]) -
                      static_cast<float>(black[i]);
        }
      } else {
        // Against the offset A of the axis's coarsest phase group (its mean level), in the
        // same doubled units: 2·(p − A).
        const float* __restrict offset = ws.offset;
        for (int i = 0; i < n; ++i) {
          margin[i] = 2.0f * (static_cast<float>(pattern[i]) - offset[i]);
        }
      }
      for (int i = 0; i < n; ++i) {
        word[i] = (word[i] << 1) | static_cast<uint32_t>(margin[i] > 0.0f);
        contrast[i] = std::max(contrast[i], std::abs(margin[i]));
      }
    }
    for (int i = 0; i < n; ++i) word[i] = BinaryFromGray(word[i]);
  }

  // A Gray-only axis of a phase set: the centre of the decoded block.
  void GrayBlockCentres(const AxisPlan& axis, int n, float* __restrict coordinate) {
    const uint32_t block = 1u << axis.gray_lowest_bit;
    const uint32_t size = static_cast<uint32_t>(axis.size);
    for (int i = 0; i < n; ++i) {
      const uint32_t start = ws_->gray_word[i] * block;
      const uint32_t end = std::min(start + block, size);
      coordinate[i] = start < size ? 0.5f * static_cast<float>(start + end - 1) : kNaN;
      ws_->axis_valid[i] = static_cast<uint8_t>(start < size);
    }
  }

  // The coarsest group unwrapped by the Gray code: period index k, u = (k + f)·P.
  void GrayUnwrap(const AxisPlan& axis, const GroupPlan& group, int n, float* __restrict coordinate) {
    Workspace& ws = *ws_;
    const float period = static_cast<float>(group.period);
    const int bits = static_cast<int>(axis.gray_bits.size());
    const int index_bits = bits - (axis.complementary ? 1 : 0);
    const int64_t periods = static_cast<int64_t>(std::ceil(axis.size / group.period));
    for (int i = 0; i < n; ++i) {
      const float f = ws.fraction[i];
      const uint32_t word = ws.gray_word[i];
      int64_t k;
      if (axis.complementary) {
        const int64_t k1 = word >> 1;
        const int64_t k_round = (word + 1) >> 1;  // period boundaries mid-period
        k = f < kEdgeFraction ? k_round : f > 1.0f - kEdgeFraction ? k_round - 1 : k1;
      } else {
        const int64_t k1 = word;
        k = k1;
        if (f < kEdgeFraction || f > 1.0f - kEdgeFraction) {
          // Just after an edge (f < ¼): the true period is k1, or k1 + 1 when the Gray bit
          // that changes at (k1 + 1)·P was decided wrong — then that bit's margin is small
          // against the pixel's contrast. Just before an edge (f > ¾) likewise k1 − 1.
          const auto margin_at_edge = [&](int64_t edge) {
            if (edge <= 0 || edge >= periods) return kInfinity;
            const int word_bit = __builtin_ctzll(static_cast<unsigned long long>(edge));
            if (word_bit >= index_bits) return kInfinity;
            return std::abs(ws.gray_margin[bits - 1 - word_bit][i]);
          };
          const float ambiguous = kAmbiguousMargin * ws.gray_contrast[i];
          if (f < kEdgeFraction) {
            k = margin_at_edge(k1 + 1) < ambiguous ? k1 + 1 : k1;
          } else {
            k = margin_at_edge(k1) < ambiguous ? k1 - 1 : k1;
          }
        }
      }
      coordinate[i] = (static_cast<float>(k) + f) * period;
    }
  }

  void Finish(size_t begin, int n) {
    Workspace& ws = *ws_;
    const float noise_floor = thresholds_.noise_floor;
    const float inverse_dof = plan_.degrees_of_freedom > 0 ? 1.0f / plan_.degrees_of_freedom : 0.0f;
    const float min_modulation = thresholds_.min_modulation;
    const float inverse_levels = 1.0f / thresholds_.levels_per_grey_level;
    const bool has_x = plan_.axes[kAxisX].coded, has_y = plan_.axes[kAxisY].coded;
    const bool any_group =
        !plan_.axes[kAxisX].groups.empty() || !plan_.axes[kAxisY].groups.empty();
    uint8_t* __restrict mask = outputs_.mask + begin;
    float* __restrict confidence = outputs_.confidence + begin;
    float* __restrict out_x = has_x ? outputs_.proj[kAxisX] + begin : nullptr;
    float* __restrict out_y = has_y ? outputs_.proj[kAxisY] + begin : nullptr;
    for (int i = 0; i < n; ++i) {
      const float modulation = any_group ? ws.min_modulation[i] : 0.0f;
      const bool valid = ws.valid[i] && (!any_group || modulation >= min_modulation);
      const float noise = std::max(std::sqrt(ws.residual[i] * inverse_dof), noise_floor);
      mask[i] = valid ? 255 : 0;
      confidence[i] = valid ? ws.finest_modulation[i] / noise : 0.0f;
      if (has_x) out_x[i] = valid ? ws.coordinate[kAxisX][i] : kNaN;
      if (has_y) out_y[i] = valid ? ws.coordinate[kAxisY][i] : kNaN;
    }
    if (outputs_.modulation != nullptr) {
      float* out = outputs_.modulation + begin;
      for (int i = 0; i < n; ++i) {
        out[i] = any_group ? ws.min_modulation[i] * inverse_levels : 0.0f;
      }
    }
    if (outputs_.texture != nullptr) {
      Pixel* out = static_cast<Pixel*>(outputs_.texture) + begin;
      constexpr float kMax = static_cast<float>(std::numeric_limits<Pixel>::max());
      for (int i = 0; i < n; ++i) {
        const float value = ws.finest_offset[i] + ws.finest_modulation[i];
        out[i] = static_cast<Pixel>(std::clamp(value + 0.5f, 0.0f, kMax));
      }
    }
    for (int axis : {kAxisX, kAxisY}) {
      if (outputs_.wrapped[axis] == nullptr) continue;
      float* wrapped = outputs_.wrapped[axis] + begin;
      for (int i = 0; i < n; ++i) {
        if (!(ws.min_modulation[i] >= min_modulation)) wrapped[i] = kNaN;
      }
    }
  }

  const Plan& plan_;
  const std::vector<const Pixel*>& frames_;
  const Thresholds thresholds_;
  const Outputs outputs_;
  std::unique_ptr<Workspace> ws_;
};

// With a speckle filter (min_neighbours > 0), each worker filters its rows as it decodes
// them (DecodeChunksAndFilter).
template <typename Pixel>
void DecodeAll(const Plan& plan, const std::vector<cv::Mat>& images, const Thresholds& thresholds,
               const Outputs& outputs, int num_threads, int min_neighbours, float tolerance,
               CorrespondenceMap* map) {
  std::vector<const Pixel*> frames;
  frames.reserve(images.size());
  for (const cv::Mat& image : images) frames.push_back(image.ptr<Pixel>());
  const size_t total = images.front().total();
  const size_t num_chunks = (total + kChunkPixels - 1) / kChunkPixels;
  const size_t num_workers = NumChunkWorkers(num_threads, num_chunks);
  // Workspaces are allocated here so that no worker can fail.
  std::vector<ChunkDecoder<Pixel>> decoders;
  decoders.reserve(num_workers);
  for (size_t w = 0; w < num_workers; ++w) decoders.emplace_back(plan, frames, thresholds, outputs);
  DecodeChunksAndFilter(total, kChunkPixels, num_workers, min_neighbours, tolerance, map,
                        [&](size_t worker, size_t begin, int n) {
                          decoders[worker].Decode(begin, n);
                        });
}

void PrepareOutput(cv::Size size, int type, cv::Mat* image) {
  const bool shared = image->u != nullptr && image->u->refcount > 1;
  if (shared || !image->isContinuous() || image->isSubmatrix()) image->release();
  image->create(size, type);
}

}  // namespace

float WrappedAtan2(float y, float x) { return FastWrappedAtan2(y, x); }

namespace {

// Of two one-sided slopes the smaller (0 when they disagree in sign; a NaN one — no
// neighbour on that side — yields the other). Branch-free (selects only), so that the row
// loop below vectorises.
inline float Minmod(float a, float b) {
  const bool no_a = std::isnan(a), no_b = std::isnan(b);
  const float smaller = std::abs(a) < std::abs(b) ? a : b;
  const float agreed = (a > 0.0f) != (b > 0.0f) ? 0.0f : smaller;
  return no_a ? (no_b ? 0.0f : b) : (no_b ? a : agreed);
}

// FitCoordinatesLocally's common case with a radius of 1, for the pixels x ∈ [1, cols − 1)
// of a row that has rows above and below (m0/u0 above, m1/u1 the row, m2/u2 below;
// `confidence` the row's or nullptr): the pixel and its 8 neighbours valid, all 9 within
// the tolerance of the minmod-slope prediction and then of the plane fitted to them (its
// centre value the window's mean). ok[x] says whether it applies, value[x] is then the
// coordinate. The same float operations as the per-pixel code — the same results — as a
// loop over the row that GCC vectorises.
template <bool kConfidence>
void FitFullWindowsOfRow(const uint8_t* m0, const uint8_t* m1, const uint8_t* m2,
                         const float* u0, const float* u1, const float* u2,
                         const float* confidence, float min_tolerance, float sigmas, int cols,
                         float* __restrict value, uint8_t* __restrict ok) {
  for (int x = 1; x + 1 < cols; ++x) {
    const bool window = (m1[x] != 0) & ((m0[x - 1] & m0[x] & m0[x + 1] & m1[x - 1] & m1[x + 1] &
                                         m2[x - 1] & m2[x] & m2[x + 1]) != 0);
    const float centre = u1[x];
    const float tolerance =
        kConfidence ? std::max(min_tolerance, sigmas / confidence[x]) : min_tolerance;
    const float slope_x = Minmod((u1[x + 1] - centre) * 1.0f, (u1[x - 1] - centre) * -1.0f);
    const float slope_y = Minmod((u2[x] - centre) * 1.0f, (u0[x] - centre) * -1.0f);
    const float d[9] = {u0[x - 1] - centre, u0[x] - centre, u0[x + 1] - centre,
                        u1[x - 1] - centre, 0.0f, u1[x + 1] - centre,
                        u2[x - 1] - centre, u2[x] - centre, u2[x + 1] - centre};
    bool all_in = true;
    float sum = 0.0f, sum_x = 0.0f, sum_y = 0.0f;
    for (int k = 0; k < 9; ++k) {
      const float dx = static_cast<float>(k % 3 - 1), dy = static_cast<float>(k / 3 - 1);
      all_in &= std::abs(d[k] - slope_x * dx - slope_y * dy) <= tolerance;
      sum += d[k];
      sum_x += dx * d[k];
      sum_y += dy * d[k];
    }
    const float a = sum / 9.0f, b = sum_x / 6.0f, c = sum_y / 6.0f;
    for (int k = 0; k < 9; ++k) {
      const float dx = static_cast<float>(k % 3 - 1), dy = static_cast<float>(k / 3 - 1);
      all_in &= std::abs(d[k] - a - b * dx - c * dy) <= tolerance;
    }
    ok[x] = window & all_in;
    value[x] = centre + a;
  }
}

}  // namespace

void FitCoordinatesLocally(const PhaseDecoderOptions& options, const cv::Mat& mask,
                           const cv::Mat& confidence, double noise_scale, cv::Mat* coordinate,
                           int num_threads) {
  const int rows = mask.rows, cols = mask.cols, r = options.local_fit_radius;
  const float min_tolerance = static_cast<float>(options.local_fit_tolerance_px);
  const float sigmas = static_cast<float>(kLocalFitSigmas * noise_scale);
  const int min_samples = 2 * r + 3;
  const cv::Mat raw = coordinate->clone();
  const int window = (2 * r + 1) * (2 * r + 1);
  const auto fit_rows = [&](const cv::Range& range) {
    std::vector<float> dxs(window), dys(window), us(window);
    std::vector<float> full_value(cols);
    std::vector<uint8_t> full_ok(cols, 0);
    for (int y = range.start; y < range.end; ++y) {
      const uint8_t* valid = mask.ptr<uint8_t>(y);
      const float* centre_row = raw.ptr<float>(y);
      float* out = coordinate->ptr<float>(y);
      // The common case first, for the whole row: a 3×3 window all on the surface.
      const bool full_windows = r == 1 && y > 0 && y + 1 < rows && cols >= 3;
      if (full_windows) {
        const auto fit = confidence.empty() ? FitFullWindowsOfRow<false> : FitFullWindowsOfRow<true>;
        fit(mask.ptr<uint8_t>(y - 1), valid, mask.ptr<uint8_t>(y + 1), raw.ptr<float>(y - 1),
            centre_row, raw.ptr<float>(y + 1),
            confidence.empty() ? nullptr : confidence.ptr<float>(y), min_tolerance, sigmas, cols,
            full_value.data(), full_ok.data());
      }
      for (int x = 0; x < cols; ++x) {
        if (valid[x] == 0) continue;
        if (full_windows && x > 0 && x + 1 < cols && full_ok[x] != 0) {
          out[x] = full_value[x];
          continue;
        }
        const float centre = centre_row[x];
        const float tolerance =
            confidence.empty() ? min_tolerance
                               : std::max(min_tolerance, sigmas / confidence.at<float>(y, x));
        // The slopes at the pixel: of the one-sided differences the smaller (minmod; 0 when
        // they disagree in sign), so that a step beside the pixel does not tilt the
        // prediction that decides which neighbours lie on its surface.
        const auto one_sided = [&](int dx, int dy) {
          const int nx = x + dx, ny = y + dy;
          if (nx < 0 || nx >= cols || ny < 0 || ny >= rows || mask.at<uint8_t>(ny, nx) == 0) {
            return std::numeric_limits<float>::quiet_NaN();
          }
          return (raw.at<float>(ny, nx) - centre) * static_cast<float>(dx + dy);
        };
        const float slope_x = Minmod(one_sided(1, 0), one_sided(-1, 0));
        const float slope_y = Minmod(one_sided(0, 1), one_sided(0, -1));
        int n = 0;
        for (int dy = -r; dy <= r; ++dy) {
          const int ny = y + dy;
          if (ny < 0 || ny >= rows) continue;
          const uint8_t* nvalid = mask.ptr<uint8_t>(ny);
          const float* nu = raw.ptr<float>(ny);
          for (int dx = -r; dx <= r; ++dx) {
            const int nx = x + dx;
            if (nx < 0 || nx >= cols || nvalid[nx] == 0) continue;
            const float predicted = centre + slope_x * static_cast<float>(dx) +
                                    slope_y * static_cast<float>(dy);
            if (!(std::abs(nu[nx] - predicted) <= tolerance)) continue;
            dxs[n] = static_cast<float>(dx);
            dys[n] = static_cast<float>(dy);
            us[n] = nu[nx] - centre;
            ++n;
          }
        }
        // Two passes: fit, drop the samples off the plane, refit.
        float value = 0.0f;
        bool fitted = false;
        for (int pass = 0; pass < 2 && n >= min_samples; ++pass) {
          PlaneFitSums sums;
          for (int k = 0; k < n; ++k) sums.Add(dxs[k], dys[k], us[k]);
          Eigen::Matrix3d normal;
          normal << sums.n, sums.x, sums.y, sums.x, sums.xx, sums.xy, sums.y, sums.xy, sums.yy;
          const Eigen::Vector3d rhs(sums.u, sums.xu, sums.yu);
          const Eigen::LDLT<Eigen::Matrix3d> ldlt(normal);
          if (ldlt.info() != Eigen::Success || !(std::abs(ldlt.vectorD().minCoeff()) > 1e-6)) {
            fitted = false;
            break;
          }
          const Eigen::Vector3d plane = ldlt.solve(rhs);
          value = static_cast<float>(plane(0));
          fitted = true;
          if (pass == 1) break;
          int kept = 0;
          for (int k = 0; k < n; ++k) {
            const float residual = us[k] - static_cast<float>(plane(0) + plane(1) * dxs[k] +
                                                               plane(2) * dys[k]);
            if (std::abs(residual) > tolerance) continue;
            dxs[kept] = dxs[k];
            dys[kept] = dys[k];
            us[kept] = us[k];
            ++kept;
          }
          if (kept == n) break;
          n = kept;
          fitted = false;
        }
        if (fitted) out[x] = centre + value;
      }
    }
  };
  if (num_threads > 1) {
    cv::parallel_for_(cv::Range(0, rows), fit_rows, num_threads);
  } else {
    fit_rows(cv::Range(0, rows));
  }
}


PhaseFit::PhaseFit(const std::vector<double>& shifts) {
  SOPE_CHECK(shifts.size() >= 3, "phase group with {} shifts (needs ≥ 3)", shifts.size());
  Eigen::Matrix3d normal = Eigen::Matrix3d::Zero();
  for (double shift : shifts) {
    const Eigen::Vector3d row(1.0, std::cos(shift), std::sin(shift));
    normal += row * row.transpose();
    cos_shift.push_back(static_cast<float>(std::cos(shift)));
    sin_shift.push_back(static_cast<float>(std::sin(shift)));
  }
  const Eigen::FullPivLU<Eigen::Matrix3d> lu(normal);
  SOPE_CHECK(lu.rank() == 3, "phase group: the shifts do not determine a sinusoid (fewer than "
             "3 distinct shifts)");
  const Eigen::Matrix3d inverse = lu.inverse();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) inverse_normal[r][c] = static_cast<float>(inverse(r, c));
  }
}

std::vector<float> MakePhaseCorrectionTable(const PhaseFit& fit, const ProjectorResponse& response,
                                            int bins) {
  if (response.IsIdentity()) return {};
  SOPE_CHECK(bins >= 16, "phase correction: {} bins", bins);
  // Measured phase as a function of the true phase, from the response applied to the
  // sinusoid samples (any α·R + β gives the same phase).
  const size_t n = fit.cos_shift.size();
  std::vector<double> error(bins);  // φ_measured(φ_true) − φ_true at φ_true = 2π·t/bins
  Eigen::Matrix3d inverse;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) inverse(r, c) = fit.inverse_normal[r][c];
  }
  for (int t = 0; t < bins; ++t) {
    const double phase = kTwoPiD * t / bins;
    Eigen::Vector3d q = Eigen::Vector3d::Zero();
    for (size_t k = 0; k < n; ++k) {
      const double cos_s = fit.cos_shift[k], sin_s = fit.sin_shift[k];
      // cos(φ − s) = cos φ cos s + sin φ sin s
      const double sample =
          response.Apply(0.5 * (1.0 + std::cos(phase) * cos_s + std::sin(phase) * sin_s));
      q += sample * Eigen::Vector3d(1.0, cos_s, sin_s);
    }
    const Eigen::Vector3d x = inverse * q;
    const double measured = std::atan2(x(2), x(1));
    error[t] = std::remainder(measured - phase, kTwoPiD);
  }
  const auto error_at = [&](double phase) {
    double position = phase / kTwoPiD * bins;
    position -= std::floor(position / bins) * bins;
    const int t0 = static_cast<int>(position) % bins;
    const int t1 = (t0 + 1) % bins;
    const double w = position - std::floor(position);
    return (1.0 - w) * error[t0] + w * error[t1];
  };
  // Inverse: φ_true solves φ_true + e(φ_true) = φ_measured (fixed point; |e'| < 1).
  std::vector<float> table(bins);
  for (int m = 0; m < bins; ++m) {
    const double measured = kTwoPiD * (m + 0.5) / bins;
    double truth = measured;
    for (int it = 0; it < kCorrectionIterations; ++it) truth = measured - error_at(truth);
    table[m] = static_cast<float>((measured - truth) / kTwoPiD);  // in periods
  }
  return table;
}

}  // namespace internal

void PhaseDecoderOptions::Check() const {
  SOPE_CHECK(std::isfinite(min_modulation) && min_modulation >= 0.0 && min_modulation <= 128.0,
             "phase min_modulation {} must be in [0, 128] grey levels", min_modulation);
  SOPE_CHECK(std::isfinite(max_unwrap_error) && max_unwrap_error > 0.0 && max_unwrap_error < 0.5,
             "phase max_unwrap_error {} must be in (0, 0.5) periods", max_unwrap_error);
  SOPE_CHECK(std::isfinite(noise_floor) && noise_floor > 0.0 && noise_floor <= 255.0,
             "phase noise_floor {} must be in (0, 255] grey levels", noise_floor);
  SOPE_CHECK(local_fit_radius >= 0 && local_fit_radius <= 3,
             "phase local_fit_radius {} must be in [0, 3] pixels", local_fit_radius);
  SOPE_CHECK(std::isfinite(local_fit_tolerance_px) && local_fit_tolerance_px > 0.0,
             "phase local_fit_tolerance_px {} must be > 0", local_fit_tolerance_px);
  response.Check();
}

void DecodePhase(const FrameSet& frame_set, const DecoderOptions& options, CorrespondenceMap* map,
                 PhaseDecodeImages* images) {
  SOPE_CHECK(map != nullptr, "DecodePhase: no output map");
  options.Check();
  frame_set.Check();
  const FrameSetManifest& manifest = frame_set.manifest;
  SOPE_CHECK(manifest.HasPhase(), "DecodePhase: the frame set has no phase frames");
  const internal::Plan plan = internal::MakePlan(manifest, options.phase);

  std::vector<cv::Mat> frames;
  frames.reserve(frame_set.images.size());
  for (const cv::Mat& image : frame_set.images) {
    frames.push_back(image.isContinuous() ? image : image.clone());
  }
  const bool sixteen_bit = frames.front().depth() == CV_16U;
  const float levels = sixteen_bit ? 257.0f : 1.0f;
  internal::Thresholds thresholds;
  thresholds.levels_per_grey_level = levels;
  thresholds.min_modulation = static_cast<float>(options.phase.min_modulation) * levels;
  thresholds.min_contrast = static_cast<float>(options.min_contrast) * levels;
  thresholds.max_unwrap_error = static_cast<float>(options.phase.max_unwrap_error);
  thresholds.noise_floor = static_cast<float>(options.phase.noise_floor) * levels;

  map->projector_width = manifest.projector_width;
  map->projector_height = manifest.projector_height;
  const cv::Size size(manifest.camera_width, manifest.camera_height);
  internal::Outputs outputs;
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    const int a = static_cast<int>(axis);
    const internal::AxisPlan& axis_plan = plan.axes[a];
    cv::Mat& coordinate = axis == PatternAxis::kX ? map->proj_x : map->proj_y;
    float& step = axis == PatternAxis::kX ? map->step_x : map->step_y;
    step = 1.0f;
    if (!axis_plan.coded) {
      coordinate.release();
      continue;
    }
    internal::PrepareOutput(size, CV_32FC1, &coordinate);
    outputs.proj[a] = coordinate.ptr<float>();
    step = axis_plan.groups.empty() ? static_cast<float>(1 << axis_plan.gray_lowest_bit)
                                    : kPhaseCoordinateStep;
  }
  internal::PrepareOutput(size, CV_8UC1, &map->mask);
  internal::PrepareOutput(size, CV_32FC1, &map->confidence);
  outputs.mask = map->mask.ptr<uint8_t>();
  outputs.confidence = map->confidence.ptr<float>();
  if (images != nullptr) {
    for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
      const int a = static_cast<int>(axis);
      cv::Mat& wrapped = axis == PatternAxis::kX ? images->wrapped_phase_x : images->wrapped_phase_y;
      if (plan.axes[a].groups.empty()) {
        wrapped.release();
        continue;
      }
      internal::PrepareOutput(size, CV_32FC1, &wrapped);
      outputs.wrapped[a] = wrapped.ptr<float>();
    }
    internal::PrepareOutput(size, CV_32FC1, &images->modulation);
    internal::PrepareOutput(size, sixteen_bit ? CV_16UC1 : CV_8UC1, &images->texture);
    outputs.modulation = images->modulation.ptr<float>();
    outputs.texture = images->texture.data;
  }
  const float tolerance = static_cast<float>(options.neighbour_tolerance_px);
  if (sixteen_bit) {
    internal::DecodeAll<uint16_t>(plan, frames, thresholds, outputs, options.num_threads,
                                  options.min_consistent_neighbours, tolerance, map);
  } else {
    internal::DecodeAll<uint8_t>(plan, frames, thresholds, outputs, options.num_threads,
                                 options.min_consistent_neighbours, tolerance, map);
  }
  if (options.phase.local_fit_radius > 0) {
    for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
      const internal::AxisPlan& axis_plan = plan.axes[static_cast<int>(axis)];
      if (axis_plan.groups.empty()) continue;
      cv::Mat& coordinate = axis == PatternAxis::kX ? map->proj_x : map->proj_y;
      // σ_u = P/(2π·B/σ·√(N/2)) for the finest group's N samples; confidence = B/σ.
      const internal::GroupPlan& finest = axis_plan.groups.back();
      const double noise_scale =
          finest.period / (internal::kTwoPiD * std::sqrt(0.5 * finest.frames.size()));
      internal::FitCoordinatesLocally(options.phase, map->mask, map->confidence, noise_scale,
                                      &coordinate, options.num_threads);
    }
  }
}

cv::Mat SynthesizePhaseTexture(const FrameSet& frame_set) {
  DecoderOptions options;
  options.min_consistent_neighbours = 0;
  CorrespondenceMap map;
  PhaseDecodeImages images;
  DecodePhase(frame_set, options, &map, &images);
  return images.texture;
}

void WritePhaseDecodeImages(const std::string& directory, const PhaseDecodeImages& images) {
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    const cv::Mat& wrapped = axis == PatternAxis::kX ? images.wrapped_phase_x : images.wrapped_phase_y;
    if (wrapped.empty()) continue;
    const std::string name = fmt::format("phase_{}", ToString(axis));
    WriteImageAtomic(JoinPath(directory, name + ".exr"), wrapped);
    cv::Mat grey;
    wrapped.convertTo(grey, CV_8U, 255.0 / (2.0 * 3.14159265358979323846));
    grey.setTo(cv::Scalar(0), wrapped != wrapped);  // NaN: black
    WriteImageAtomic(JoinPath(directory, name + ".png"), grey);
  }
  if (!images.modulation.empty()) {
    WriteImageAtomic(JoinPath(directory, "modulation.exr"), images.modulation);
    cv::Mat grey;
    images.modulation.convertTo(grey, CV_8U, 2.0);
    WriteImageAtomic(JoinPath(directory, "modulation.png"), grey);
  }
  if (!images.texture.empty()) WriteImageAtomic(JoinPath(directory, "texture.png"), images.texture);
}

}  // namespace sope
