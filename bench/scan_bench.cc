// Scan pipeline throughput on the virtual rig: pixels/s decoded and points/s triangulated
// (midpoint and linear, both axes; ray–plane with one axis), single thread, the table path
// (Triangulator::Triangulate) side by side with the exact per-point path
// (Triangulator::TriangulateExact) in the same run, plus the one-time cost of building a
// Triangulator (ray and plane tables) for a calibration. Prints a summary of the ratios.
//
// Input: a sphere before a backdrop rendered with the default rig (1280×720 camera,
// 1024×768 projector, Gray code x and y with inverses), rendered once at start-up.
#include <benchmark/benchmark.h>
#include <fmt/format.h>
#include <opencv2/core/utility.hpp>

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include "bench/bench_support.h"
#include "calibration/scan.h"
#include "calibration/triangulation.h"
#include "simulator/primitives.h"
#include "simulator/scene_builder.h"
#include "simulator/simulate_scan.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

struct Input {
  RigCalibration calibration;
  FrameSet frames;
  CorrespondenceMap map_xy;
  CorrespondenceMap map_x;
};

const Input& GetInput() {
  static const Input input = [] {
    Input in;
    in.calibration = DefaultRigCalibration();
    Scene scene;
    Placement placement;
    placement.center_in_cam = Eigen::Vector3d(0, 0, 0.58);
    scene.objects.push_back(PlaceObject(MakeSphere(0.1, 48, 96), placement));
    scene.objects.push_back(MakeBackdrop(0.72, 1.5, 1.0));
    PatternOptions patterns;
    patterns.projector_width = in.calibration.projector.width;
    patterns.projector_height = in.calibration.projector.height;
    VirtualRig rig(in.calibration);
    in.frames = SimulateScan(rig, scene, patterns).frames;
    in.map_xy = Decode(in.frames);
    in.map_x = in.map_xy;
    in.map_x.proj_y = cv::Mat();
    return in;
  }();
  return input;
}

void BM_Decode(benchmark::State& state) {
  const Input& input = GetInput();
  CorrespondenceMap map;
  Decode(input.frames, DecoderOptions(), &map);  // the map's pages faulted in, untimed
  for (auto _ : state) {
    Decode(input.frames, DecoderOptions(), &map);
    benchmark::DoNotOptimize(map.mask.data);
  }
  state.counters["pixels/s"] = benchmark::Counter(
      static_cast<double>(input.frames.manifest.camera_width) * input.frames.manifest.camera_height,
      benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Decode)->Unit(benchmark::kMillisecond)->Repetitions(5)->ReportAggregatesOnly(true);

// Decoding with the options scans use by default (ScanOptions: sub-pixel stripe edges,
// code consistency) beside the plain per-pixel decode above: arguments (edges, consistency).
void BM_DecodeScanOptions(benchmark::State& state) {
  const Input& input = GetInput();
  DecoderOptions options;
  options.gray_subpixel = state.range(0) != 0 ? GraySubpixel::kEdges : GraySubpixel::kOff;
  options.consistency.enabled = state.range(1) != 0;
  CorrespondenceMap map;
  Decode(input.frames, options, &map);  // the map's pages faulted in, untimed
  for (auto _ : state) {
    Decode(input.frames, options, &map);
    benchmark::DoNotOptimize(map.mask.data);
  }
  state.counters["valid"] = static_cast<double>(cv::countNonZero(map.mask));
}
BENCHMARK(BM_DecodeScanOptions)
    ->ArgsProduct({{0, 1}, {0, 1}})
    ->ArgNames({"edges", "consistency"})
    ->MeasureProcessCPUTime()
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

// The live loop's decode with IncrementalDecoder: frames added as they are captured, so
// that after the last frame only its bit and the finish remain. Timed: AddFrame(last) +
// Finish (the last-frame → map latency), beside BM_Decode (the batch decode, all of it
// after the last frame); "total" adds every frame (the whole work, overlapped with
// capture in the live loop). scan_defaults 1: with the options scans use (sub-pixel edges
// and code consistency, both after the last frame: they need every bit), wall and process
// CPU time.
void BM_DecodeIncremental(benchmark::State& state) {
  const Input& input = GetInput();
  const bool last_frame_only = state.range(0) == 1;
  const bool scan_defaults = state.range(1) == 1;
  const FrameSet& frames = input.frames;
  const size_t count = frames.images.size();
  IncrementalDecoder decoder(frames.manifest,
                             scan_defaults ? ScanOptions().decoder : DecoderOptions());
  CorrespondenceMap map;
  for (auto _ : state) {
    if (last_frame_only) {
      state.PauseTiming();
      decoder.Reset();
      for (size_t i = 0; i + 1 < count; ++i) decoder.AddFrame(i, frames.images[i]);
      state.ResumeTiming();
      decoder.AddFrame(count - 1, frames.images[count - 1]);
    } else {
      decoder.Reset();
      for (size_t i = 0; i < count; ++i) decoder.AddFrame(i, frames.images[i]);
    }
    decoder.Finish(&map);
    benchmark::DoNotOptimize(map.mask.data);
  }
  state.SetLabel(fmt::format("{}{}", last_frame_only ? "last frame -> map" : "total",
                             scan_defaults ? ", scan defaults" : ""));
}
BENCHMARK(BM_DecodeIncremental)
    ->ArgsProduct({{1, 0}, {0, 1}})
    ->ArgNames({"last_frame_only", "scan_defaults"})
    ->MeasureProcessCPUTime()
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

// Arguments: method (0 midpoint, 1 linear, 2 ray–plane with x only), path (0 exact
// per-point, 1 tables).
void BM_Triangulate(benchmark::State& state) {
  const Input& input = GetInput();
  TriangulationOptions options;
  options.method = state.range(0) == 1 ? TriangulationMethod::kLinear : TriangulationMethod::kMidpoint;
  const bool one_axis = state.range(0) == 2;
  const bool tables = state.range(1) == 1;
  const Triangulator triangulator(input.calibration, options);
  const CorrespondenceMap& map = one_axis ? input.map_x : input.map_xy;
  size_t points = 0;
  for (auto _ : state) {
    const TriangulationResult result = tables ? triangulator.Triangulate(map, cv::Mat())
                                              : triangulator.TriangulateExact(map, cv::Mat());
    points = result.cloud.size();
    benchmark::DoNotOptimize(result.cloud.points.data());
  }
  state.SetLabel(fmt::format("{} {}", one_axis ? "ray-plane (x only)" : ToString(options.method),
                             tables ? "tables" : "exact"));
  state.counters["points"] = static_cast<double>(points);
  state.counters["points/s"] =
      benchmark::Counter(static_cast<double>(points), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Triangulate)
    ->ArgsProduct({{0, 1, 2}, {0, 1}})
    ->ArgNames({"method", "tables"})
    ->Unit(benchmark::kMillisecond)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

// The table path on `threads` threads (wall clock: the CPU time counts only the main
// thread), beside the single-threaded runs above.
void BM_TriangulateThreads(benchmark::State& state) {
  const Input& input = GetInput();
  TriangulationOptions options;
  options.method = state.range(0) == 1 ? TriangulationMethod::kLinear : TriangulationMethod::kMidpoint;
  options.num_threads = static_cast<int>(state.range(1));
  const bool one_axis = state.range(0) == 2;
  const Triangulator triangulator(input.calibration, options);
  const CorrespondenceMap& map = one_axis ? input.map_x : input.map_xy;
  size_t points = 0;
  for (auto _ : state) {
    const TriangulationResult result = triangulator.Triangulate(map, cv::Mat());
    points = result.cloud.size();
    benchmark::DoNotOptimize(result.cloud.points.data());
  }
  state.SetLabel(fmt::format("{} tables, {} threads",
                             one_axis ? "ray-plane (x only)" : ToString(options.method),
                             options.num_threads));
  state.counters["points"] = static_cast<double>(points);
}
BENCHMARK(BM_TriangulateThreads)
    ->ArgsProduct({{0, 1, 2}, {1, 2}})
    ->ArgNames({"method", "threads"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

void BM_TriangulatorSetUp(benchmark::State& state) {
  const Input& input = GetInput();
  TriangulationOptions options;
  options.num_threads = static_cast<int>(state.range(0));
  size_t bytes = 0;
  for (auto _ : state) {
    Triangulator triangulator(input.calibration, options);
    bytes = triangulator.TableBytes();
    benchmark::DoNotOptimize(&triangulator);
  }
  state.counters["table MB"] = static_cast<double>(bytes) / 1e6;
}
// Threads: the set-up runs in cv::parallel_for_ (OpenCV's pool); `threads` only labels the
// pool size set for the run.
BENCHMARK(BM_TriangulatorSetUp)
    ->Arg(1)
    ->Arg(2)
    ->ArgName("threads")
    ->Setup([](const benchmark::State& state) { cv::setNumThreads(static_cast<int>(state.range(0))); })
    ->Teardown([](const benchmark::State&) { cv::setNumThreads(-1); })
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

// Keeps the median CPU time (ms) and counters (points) of every benchmark for the summary.
using SummaryReporter = bench::MedianTimesReporter;

// Ratios use CPU time (medians of 5): on a shared machine the wall clock of a
// single-threaded run also counts the time other processes held its core.
void PrintSummary(const SummaryReporter& reporter) {
  fmt::print("\nSummary (1280x720 camera, 1024x768 projector, 1 thread, CPU-time medians)\n");
  fmt::print("  {:<22} {:>9} {:>12} {:>9} {:>12} {:>8}\n", "", "exact ms", "exact Mpt/s",
             "tables ms", "tables Mpt/s", "speed-up");
  const char* names[] = {"midpoint", "linear", "ray-plane (x only)"};
  for (int method = 0; method < 3; ++method) {
    const auto exact = reporter.Get(fmt::format("BM_Triangulate/method:{}/tables:0", method));
    const auto tables = reporter.Get(fmt::format("BM_Triangulate/method:{}/tables:1", method));
    if (exact.cpu_ms <= 0.0 || tables.cpu_ms <= 0.0) continue;
    fmt::print("  {:<22} {:>9.2f} {:>12.2f} {:>9.2f} {:>12.2f} {:>7.1f}x\n", names[method],
               exact.cpu_ms, exact.Counter("points") / exact.cpu_ms * 1e-3, tables.cpu_ms,
               tables.Counter("points") / tables.cpu_ms * 1e-3, exact.cpu_ms / tables.cpu_ms);
  }
  // The table path agrees with the exact path on this scene (the same points, depth within
  // 1e-6 m: calibration_test), checked once here on the rendered sphere and backdrop.
  for (int method = 0; method < 3; ++method) {
    if (reporter.Get(fmt::format("BM_Triangulate/method:{}/tables:1", method)).cpu_ms <= 0.0) {
      continue;
    }
    const Input& input = GetInput();
    TriangulationOptions options;
    options.method = method == 1 ? TriangulationMethod::kLinear : TriangulationMethod::kMidpoint;
    const Triangulator triangulator(input.calibration, options);
    const CorrespondenceMap& map = method == 2 ? input.map_x : input.map_xy;
    const TriangulationResult tables = triangulator.Triangulate(map, cv::Mat());
    const TriangulationResult exact = triangulator.TriangulateExact(map, cv::Mat());
    double max_difference = 0.0;
    size_t compared = 0, only_one = 0;
    for (int y = 0; y < tables.depth.rows; ++y) {
      for (int x = 0; x < tables.depth.cols; ++x) {
        const float a = tables.depth.at<float>(y, x), b = exact.depth.at<float>(y, x);
        if (std::isnan(a) != std::isnan(b)) ++only_one;
        if (std::isnan(a) || std::isnan(b)) continue;
        max_difference = std::max<double>(max_difference, std::abs(a - b));
        ++compared;
      }
    }
    fmt::print("  {:<22} tables vs exact: {} points, max depth difference {:.2e} m, {} pixels "
               "triangulated by one path only\n",
               names[method], compared, max_difference, only_one);
  }
  fmt::print("  wall clock (exact on 1 thread; tables on 1 and 2 threads):\n");
  for (int method = 0; method < 3; ++method) {
    const auto exact = reporter.Get(fmt::format("BM_Triangulate/method:{}/tables:0", method));
    const auto one = reporter.Get(fmt::format("BM_TriangulateThreads/method:{}/threads:1", method));
    const auto two = reporter.Get(fmt::format("BM_TriangulateThreads/method:{}/threads:2", method));
    if (exact.real_ms <= 0.0 || one.real_ms <= 0.0 || two.real_ms <= 0.0) continue;
    fmt::print("  {:<22} exact {:.2f} ms; tables 1 thread {:.2f} ms ({:.1f}x, {:.1f} Mpt/s), "
               "2 threads {:.2f} ms ({:.1f}x, {:.1f} Mpt/s)\n",
               names[method], exact.real_ms, one.real_ms, exact.real_ms / one.real_ms,
               one.Counter("points") / one.real_ms * 1e-3, two.real_ms, exact.real_ms / two.real_ms,
               two.Counter("points") / two.real_ms * 1e-3);
  }
  const auto batch = reporter.Get("BM_Decode");
  const auto last = reporter.Get("BM_DecodeIncremental/last_frame_only:1");
  const auto total = reporter.Get("BM_DecodeIncremental/last_frame_only:0");
  if (batch.cpu_ms > 0.0 && last.cpu_ms > 0.0) {
    fmt::print("  decode after the last frame: batch {:.2f} ms, incremental {:.2f} ms ({:.1f}x); "
               "incremental total {:.2f} ms (CPU)\n",
               batch.cpu_ms, last.cpu_ms, batch.cpu_ms / last.cpu_ms, total.cpu_ms);
  }
  for (int threads : {1, 2}) {
    const auto set_up = reporter.Get(fmt::format("BM_TriangulatorSetUp/threads:{}", threads));
    if (set_up.real_ms > 0.0) {
      // With one thread the CPU time is all of the work; with two it counts only the main
      // thread's share. Real time on a loaded machine also counts waiting for a core.
      fmt::print("  table set-up, {} thread(s): {:.1f} ms real, {:.1f} ms CPU (main thread)\n",
                 threads, set_up.real_ms, set_up.cpu_ms);
    }
  }
}

}  // namespace
}  // namespace sope

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  sope::GetInput();  // render and decode before timing
  sope::SummaryReporter reporter;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  sope::PrintSummary(reporter);
  benchmark::Shutdown();
  return 0;
}
