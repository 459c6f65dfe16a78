// Phase decoder speed (issue 10): sope's DecodePhase on a 1920×1280, 3-frequency 4-step set
// (x axis, periods 1024, 64 and 8 of a 1024×768 projector: 12 frames) against OpenCV's
// cv::structured_light::SinusoidalPattern (PSP: computePhaseMap per frequency from its
// 3-step frames, plus unwrapPhaseMap of the finest map — OpenCV has no temporal
// unwrapping, so its spatial unwrapper is the peer), single-threaded, in the same run; and
// against the memory-bandwidth bound of reading every frame byte once.
//
// Input: synthetic, rendered like bench/decode_bench's synthetic set (patterns warped by
// an affine camera map, blur, an albedo ramp, noise). OpenCV gets its own 3-step frames of
// the same scene (9 frames; it reads fewer bytes than we do).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>
#include <fmt/format.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/structured_light.hpp>

#include "bench/bench_support.h"
#include "core/cv_threads.h"
#include "decoder/decoder.h"
#include "decoder/phase_decoder.h"
#include "projector/patterns.h"

namespace sope {
namespace {

constexpr int kProjectorWidth = 1024;
constexpr int kProjectorHeight = 768;
constexpr int kCameraWidth = 1920;
constexpr int kCameraHeight = 1280;
const std::vector<double> kPeriods = {1024, 64, 8};
constexpr int kRepetitions = 5;
constexpr double kTwoPi = 6.283185307179586476925286766559;

struct BenchInput {
  FrameSet ours;                               // 4-step, 12 frames
  std::vector<std::vector<cv::Mat>> opencv;    // per period, 3 frames (shifts 0, 2π/3, 4π/3)
};

cv::Mat Film(const cv::Mat& pattern, cv::RNG& rng) {
  const cv::Matx23d proj_from_cam(0.5, 0.02, 40.0, -0.012, 0.55, 20.0);
  cv::Mat camera;
  cv::warpAffine(pattern, camera, proj_from_cam, cv::Size(kCameraWidth, kCameraHeight),
                 cv::INTER_LINEAR | cv::WARP_INVERSE_MAP);
  cv::GaussianBlur(camera, camera, cv::Size(), 0.8);
  cv::Mat noise(camera.size(), CV_8UC1);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 6);
  return camera * 0.8 + noise + 10;
}

const BenchInput& Input() {
  static const BenchInput input = [] {
    BenchInput result;
    PatternOptions patterns;
    patterns.projector_width = kProjectorWidth;
    patterns.projector_height = kProjectorHeight;
    patterns.axes = PatternAxes::kX;
    patterns.family = PatternFamily::kPhase;
    patterns.periods = kPeriods;
    patterns.steps = 4;
    patterns.white_black = false;
    result.ours.manifest = MakePatternManifest(patterns, kCameraWidth, kCameraHeight);
    cv::RNG rng(1);
    for (const Pattern& pattern : GeneratePatterns(patterns)) {
      result.ours.images.push_back(Film(pattern.image, rng));
    }
    result.ours.Check();
    for (double period : kPeriods) {
      std::vector<cv::Mat> group;
      for (int k = 0; k < 3; ++k) {
        FrameInfo frame;
        frame.role = FrameRole::kPhase;
        frame.axis = PatternAxis::kX;
        frame.period = period;
        frame.shift = kTwoPi * k / 3;
        group.push_back(Film(RenderPattern(frame, kProjectorWidth, kProjectorHeight), rng));
      }
      result.opencv.push_back(group);
    }
    return result;
  }();
  return input;
}

size_t Pixels() { return Input().ours.images.front().total(); }
size_t FrameBytes() { return bench::FrameBytes(Input().ours.images); }

void SetCounters(benchmark::State& state) {
  bench::SetFrameRateCounters(state, Input().ours.images);
}

// Args: threads, speckle filter on/off.
void BM_SopeDecodePhase(benchmark::State& state) {
  DecoderOptions options;
  options.num_threads = static_cast<int>(state.range(0));
  if (state.range(1) == 0) options.min_consistent_neighbours = 0;
  CorrespondenceMap map;
  DecodePhase(Input().ours, options, &map);  // the map's pages faulted in, untimed
  for (auto _ : state) {
    DecodePhase(Input().ours, options, &map);
    benchmark::DoNotOptimize(map.proj_x.data);
  }
  state.counters["decoded"] = static_cast<double>(map.CountValid()) / Pixels();
  SetCounters(state);
}
BENCHMARK(BM_SopeDecodePhase)
    ->ArgNames({"threads", "filter"})
    ->Args({1, 1})
    ->Args({1, 0})
    ->Args({2, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Repetitions(kRepetitions)
    ->ReportAggregatesOnly(true);

void BM_OpenCvSinusoidalPattern(benchmark::State& state) {
  const ScopedCvThreads one_core(1);  // OpenCV's pool on this thread only
  std::vector<cv::Ptr<cv::structured_light::SinusoidalPattern>> patterns;
  for (double period : kPeriods) {
    auto params = cv::makePtr<cv::structured_light::SinusoidalPattern::Params>();
    params->width = kProjectorWidth;
    params->height = kProjectorHeight;
    params->nbrOfPeriods = static_cast<int>(std::lround(kProjectorWidth / period));
    params->shiftValue = static_cast<float>(kTwoPi / 3);
    params->methodId = cv::structured_light::PSP;
    params->horizontal = false;
    params->setMarkers = false;
    patterns.push_back(cv::structured_light::SinusoidalPattern::create(params));
  }
  cv::Mat unwrapped;
  for (auto _ : state) {
    cv::Mat wrapped, shadow;
    for (size_t g = 0; g < patterns.size(); ++g) {
      patterns[g]->computePhaseMap(Input().opencv[g], wrapped, shadow);
    }
    patterns.back()->unwrapPhaseMap(wrapped, unwrapped, cv::Size(kCameraWidth, kCameraHeight),
                                    shadow);
    benchmark::DoNotOptimize(unwrapped.data);
  }
  SetCounters(state);
}
BENCHMARK(BM_OpenCvSinusoidalPattern)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(2);

void BM_ReadAllFrames(benchmark::State& state) {
  for (auto _ : state) benchmark::DoNotOptimize(bench::ReadEveryByte(Input().ours.images));
  SetCounters(state);
}
BENCHMARK(BM_ReadAllFrames)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Repetitions(kRepetitions)
    ->ReportAggregatesOnly(true);

using SummaryReporter = bench::MedianTimesReporter;

// Ratios of CPU time (single-threaded runs; the machines are shared).
void PrintSummary(const SummaryReporter& reporter) {
  using Times = SummaryReporter::Times;
  const Times ours = reporter.Get("BM_SopeDecodePhase/threads:1/filter:1");
  const Times unfiltered = reporter.Get("BM_SopeDecodePhase/threads:1/filter:0");
  const Times two = reporter.Get("BM_SopeDecodePhase/threads:2/filter:1");
  const Times opencv = reporter.Get("BM_OpenCvSinusoidalPattern");
  const Times read = reporter.Get("BM_ReadAllFrames");
  const double megapixels = Pixels() / 1e6;
  fmt::print("\nSummary (synthetic {}x{}, x periods 1024/64/8, 4 steps: {} frames, {:.1f} MB)\n",
             kCameraWidth, kCameraHeight, Input().ours.images.size(), FrameBytes() / 1e6);
  const auto row = [&](const char* name, const Times& times) {
    if (times.real_ms <= 0.0) return;
    fmt::print("  {:<50} {:>9.2f} CPU ms {:>9.2f} real ms {:>8.1f} Mpx/s\n", name, times.cpu_ms,
               times.real_ms, megapixels / (times.cpu_ms * 1e-3));
  };
  row("sope DecodePhase, 1 thread", ours);
  row("  ... without the speckle filter", unfiltered);
  if (two.real_ms > 0.0) {
    fmt::print("  {:<50} {:>9.2f} real ms (2 threads)\n", "sope DecodePhase, 2 threads",
               two.real_ms);
  }
  row("OpenCV SinusoidalPattern PSP x3 + unwrapPhaseMap", opencv);
  row("read every frame byte once (max-reduce)", read);
  if (ours.cpu_ms > 0.0 && opencv.cpu_ms > 0.0) {
    fmt::print("  speed-up over OpenCV SinusoidalPattern: {:.0f}x (target >= 10x)\n",
               opencv.cpu_ms / ours.cpu_ms);
  }
  if (unfiltered.cpu_ms > 0.0 && read.cpu_ms > 0.0) {
    fmt::print("  read-once time / our time (no filter): {:.2f} (1.0 = as fast as reading the "
               "frames once)\n", read.cpu_ms / unfiltered.cpu_ms);
  }
  if (ours.cpu_ms > 0.0 && read.cpu_ms > 0.0) {
    fmt::print("  read-once time / our time (filter):    {:.2f}\n", read.cpu_ms / ours.cpu_ms);
  }
}

}  // namespace
}  // namespace sope

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  sope::Input();
  sope::SummaryReporter reporter;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  sope::PrintSummary(reporter);
  benchmark::Shutdown();
  return 0;
}
