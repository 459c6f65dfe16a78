// Scan pipeline throughput on the virtual rig: pixels/s decoded and points/s triangulated
// (midpoint and linear, both axes; ray–plane with one axis), single thread, plus the
// one-time cost of building a Triangulator (ray tables) for a calibration.
//
// Input: a sphere before a backdrop rendered with the default rig (1280×720 camera,
// 1024×768 projector, Gray code x and y with inverses), rendered once at start-up.
#include <benchmark/benchmark.h>
#include <fmt/format.h>

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
  for (auto _ : state) {
    Decode(input.frames, DecoderOptions(), &map);
    benchmark::DoNotOptimize(map.mask.data);
  }
  state.counters["pixels/s"] = benchmark::Counter(
      static_cast<double>(input.frames.manifest.camera_width) * input.frames.manifest.camera_height,
      benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Decode)->Unit(benchmark::kMillisecond);

void BM_Triangulate(benchmark::State& state) {
  const Input& input = GetInput();
  TriangulationOptions options;
  options.method = state.range(0) == 1 ? TriangulationMethod::kLinear : TriangulationMethod::kMidpoint;
  const bool one_axis = state.range(0) == 2;
  const Triangulator triangulator(input.calibration, options);
  const CorrespondenceMap& map = one_axis ? input.map_x : input.map_xy;
  size_t points = 0;
  for (auto _ : state) {
    const TriangulationResult result = triangulator.Triangulate(map, cv::Mat());
    points = result.cloud.size();
    benchmark::DoNotOptimize(result.cloud.points.data());
  }
  state.SetLabel(one_axis ? "ray-plane (x only)" : ToString(options.method));
  state.counters["points"] = static_cast<double>(points);
  state.counters["points/s"] =
      benchmark::Counter(static_cast<double>(points), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Triangulate)->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

void BM_TriangulatorSetUp(benchmark::State& state) {
  const Input& input = GetInput();
  for (auto _ : state) {
    Triangulator triangulator(input.calibration);
    benchmark::DoNotOptimize(&triangulator);
  }
}
BENCHMARK(BM_TriangulatorSetUp)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace sope

SOPE_BENCHMARK_MAIN();
