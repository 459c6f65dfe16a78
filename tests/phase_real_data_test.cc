// Phase decoding of a real capture: SLMaster's relief (../shared/data/sl/slmaster-relief,
// README there): 12 phase shifts at 32 periods across a 1920-wide projector (60 px), then
// 6 Gray-code frames (5 bits giving the period index, MSB first, plus the complementary
// bit half a period wide), thresholded at the sinusoids' mean (no white/black/inverses).
//
// Frame-set description (conventions from SLMaster's sinusCompleGraycodePattern.cpp): frame
// i shows 127.5 + 127.5·cos(2π·(u mod p)/p − π + 2πi/12), i.e. the contract's
// ½(1 + cos(2πu/p − s_i)) with s_i = π − 2πi/12, phase 0 at every period start; Gray frame
// j shows the Gray code of floor(u / (1920 / 2^(j+1))). Our Gray frames code projector
// pixels in power-of-two blocks, so the manifest describes a virtual projector 32 × 64 =
// 2048 px wide (u' = u · 64/60): period 64, Gray bits 10…6 and the complementary bit 5.
// No reference cloud exists: the checks are coverage, smoothness of the decoded coordinate
// along rows, and agreement of the two Gray + phase methods (with and without the
// complementary bit).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "core/file_util.h"
#include "core/frame_set.h"
#include "decoder/decoder.h"
#include "decoder/phase_decoder.h"
#include "tests/test_support.h"

namespace sope {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kShifts = 12;
constexpr int kVirtualWidth = 2048;  // 32 periods of 64 px
constexpr double kPeriod = 64.0;
constexpr double kPixelsPerVirtual = 1920.0 / kVirtualWidth;

FrameSet LoadRelief(const std::string& directory, bool complementary) {
  FrameSet set;
  FrameSetManifest& manifest = set.manifest;
  manifest.camera_width = 1280;
  manifest.camera_height = 1024;
  manifest.projector_width = kVirtualWidth;
  manifest.projector_height = 1080;
  for (int i = 0; i < kShifts; ++i) {
    FrameInfo frame;
    frame.file = fmt::format("{:02}.png", i);
    frame.role = FrameRole::kPhase;
    frame.axis = PatternAxis::kX;
    frame.period = kPeriod;
    frame.shift = kPi - 2.0 * kPi * i / kShifts;
    manifest.frames.push_back(frame);
  }
  for (int j = 0; j < (complementary ? 6 : 5); ++j) {
    FrameInfo frame;
    frame.file = fmt::format("{:02}.png", kShifts + j);
    frame.role = FrameRole::kCode;
    frame.axis = PatternAxis::kX;
    frame.code = PatternCode::kGray;
    frame.bits = 11;
    frame.bit = 10 - j;
    manifest.frames.push_back(frame);
  }
  manifest.Check();
  for (const FrameInfo& frame : manifest.frames) {
    set.images.push_back(ReadImage(JoinPath(directory, frame.file), cv::IMREAD_GRAYSCALE));
  }
  set.Check();
  return set;
}

// Horizontally adjacent decoded pairs whose coordinates jump by more than `jump` px.
double JumpFraction(const CorrespondenceMap& map, double jump, size_t* pairs) {
  size_t count = 0, jumps = 0;
  for (int y = 0; y < map.height(); ++y) {
    for (int x = 0; x + 1 < map.width(); ++x) {
      if (!map.mask.at<uint8_t>(y, x) || !map.mask.at<uint8_t>(y, x + 1)) continue;
      ++count;
      jumps += std::abs(map.proj_x.at<float>(y, x + 1) - map.proj_x.at<float>(y, x)) > jump;
    }
  }
  *pairs = count;
  return count ? static_cast<double>(jumps) / count : 1.0;
}

TEST(PhaseRealData, SlMasterReliefDecodesSmoothlyAndBothGrayMethodsAgree) {
  SOPE_REQUIRE_SHARED_DATA(data);
  const std::string directory = JoinPath(data, "sl/slmaster-relief");
  const FrameSet with_bit = LoadRelief(directory, true);
  const FrameSet without_bit = LoadRelief(directory, false);
  DecoderOptions options;
  CorrespondenceMap map, plain;
  PhaseDecodeImages images;
  DecodePhase(with_bit, options, &map, &images);
  DecodePhase(without_bit, options, &plain);
  const size_t total = static_cast<size_t>(map.width()) * map.height();
  size_t pairs = 0;
  const double jumps = JumpFraction(map, 0.25 * kPeriod, &pairs);
  // Agreement of the two Gray + phase methods where both decoded.
  size_t both = 0, agree = 0;
  for (int y = 0; y < map.height(); ++y) {
    for (int x = 0; x < map.width(); ++x) {
      if (!map.mask.at<uint8_t>(y, x) || !plain.mask.at<uint8_t>(y, x)) continue;
      ++both;
      agree += std::abs(map.proj_x.at<float>(y, x) - plain.proj_x.at<float>(y, x)) < 1.0f;
    }
  }
  std::printf("[slmaster-relief] decoded %zu of %zu pixels (%.1f%%), without the "
              "complementary bit %zu; period jumps between neighbours %.4f%% of %zu pairs; "
              "methods agree within 1 px (%.2f SLMaster px) on %.3f%% of %zu\n",
              map.CountValid(), total, 100.0 * map.CountValid() / total, plain.CountValid(),
              100 * jumps, pairs, kPixelsPerVirtual, 100.0 * agree / std::max<size_t>(both, 1),
              both);
  if (const char* out = std::getenv("SOPE_PHASE_REAL_OUT")) {  // for looking at the maps
    WriteCorrespondenceMap(out, map);
    WritePhaseDecodeImages(out, images);
  }
  // The relief fills ~ 450 × 430 camera pixels, all lit by the projector.
  EXPECT_GT(map.CountValid(), 150000u);
  EXPECT_LT(jumps, 0.002);
  EXPECT_GT(static_cast<double>(agree) / both, 0.995);
}

}  // namespace
}  // namespace sope
