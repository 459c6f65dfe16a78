// Latency of tabletop scan and recognise (issue 12): from the last captured frame of a table
// scene of 5 objects to every object's result — decode + triangulate + table segmentation +
// recognition of every cluster + scene verification (pipeline/scan_and_recognise.h tabletop
// mode: ScanFrameSet + SceneRecogniser::Recognise), median and p95, one core (OpenCV's
// thread pool set to one thread while timing, so that the decoder's sub-pixel edges and
// code consistency and everything else run on the calling thread, whose CPU time is
// measured). The frames are decoded with the options `sope scan-and-recognise` uses
// (ScanOptions: sub-pixel stripe edges, code consistency); BM_Table_AllObjects_PlainDecode
// is the plain per-pixel decode (what this benchmark measured before 2026-12-04).
// BM_Table_AllObjects decodes every frame after the capture (a replayed frame set);
// BM_Table_AllObjects_Live as the live loop does, the plain decode accumulated during the
// capture (only the last frame's bit and the finish after it). Goal: ≤ 60 ms.
//
// Tabletop scans fill pixels by code consistency only near what is not the table
// (ScanTableFrameSet); BM_Table_AllObjects_WholeImageConsistency is the same path with the
// consistency over the whole image (ScanFrameSet).
//
// Peers in the same run on the same frame sets: the same path with PCL's kd-tree
// Euclidean clustering (the former segmentation; cpu_ratio_vs_pcl_clustering), the
// segmentation stage alone both ways (BM_Segment_*), and the single-object path (range band +
// one recognition, RecogniseFrameSet), so the cost of the tabletop machinery reads as a
// ratio (table_ratio = table median / single-object median).
// Input: 4 table scenes (VirtualTableSource, 5 procedural objects each of the six smaller
// classes, the database's own instances, no clutter, hard sensor defaults), captured once at start-up (not timed),
// against a database of 10 procedural classes × 1 instance × 80 views built at start-up.
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <vector>

#include <benchmark/benchmark.h>

#include "bench/bench_support.h"
#include "calibration/scan.h"
#include "core/cv_threads.h"
#include "core/error.h"
#include "core/statistics.h"
#include "decoder/decoder.h"
#include "pipeline/scan_source.h"
#include "recogniser/database.h"
#include "recogniser/scene_recognition.h"
#include "recogniser/tools/database_builder.h"
#include "recogniser/tools/scan_recognition.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

namespace fs = std::filesystem;

constexpr int kScenes = 4;
constexpr double kGoalMs = 60.0;

struct Input {
  RigCalibration calibration;
  std::unique_ptr<Triangulator> triangulator;
  std::vector<SourceScan> scans;
  std::unique_ptr<Database> db;
  std::string dir;
  ~Input() {
    db.reset();
    if (!dir.empty()) fs::remove_all(dir);
  }
};

// The single-object peer's range band: up to the scene's farthest object point + 2 cm (the
// wall behind the table left out), from the truth — the peer's workload; the tabletop path
// gets no band from the truth (the default, as a live rig).
ObjectSegmentationOptions ObjectsBand(const ScanTruth& truth) {
  double farthest = 0.0;
  for (const ScanObjectTruth& object : truth.objects) {
    for (const Eigen::Vector3f& v : object.mesh.vertices) {
      farthest = std::max(farthest, (object.cam_from_model * v.cast<double>()).norm());
    }
  }
  ObjectSegmentationOptions band;
  band.max_range = farthest + 0.02;
  return band;
}

const Input& GetInput() {
  static const std::unique_ptr<Input> input = [] {
    auto owned = std::make_unique<Input>();
    Input& in = *owned;
    in.dir = (fs::temp_directory_path() / ("sope_table_bench_" + std::to_string(::getpid())))
                 .string();
    const std::string models = in.dir + "/models";
    WriteProceduralModels(models, 1, 0);
    DatabaseOptions options = DatabaseOptions::Preset("sope");
    options.views_per_model = 80;
    WriteDatabase(in.dir + "/table.sopedb", BuildDatabase(models, options));
    in.db = Database::Open(in.dir + "/table.sopedb");
    in.calibration = DefaultRigCalibration();
    in.triangulator = std::make_unique<Triangulator>(in.calibration);
    VirtualTableSourceOptions source_options;
    source_options.calibration = in.calibration;
    source_options.objects = 5;
    // The smaller classes: five of them fit side by side in what camera and projector see.
    source_options.classes = {ObjectClass::kMug, ObjectClass::kCan, ObjectClass::kGlass,
                              ObjectClass::kBottle, ObjectClass::kBowl, ObjectClass::kWineGlass};
    source_options.instance_seed_base = 0;
    source_options.instance_count = 1;
    source_options.table.clutter = 0;
    source_options.patterns.projector_width = in.calibration.projector.width;
    source_options.patterns.projector_height = in.calibration.projector.height;
    // Scenes whose objects cannot all be placed are skipped (the next seed).
    for (uint64_t seed = 1; in.scans.size() < kScenes && seed < 40; ++seed) {
      source_options.seed = seed;
      try {
        VirtualTableSource source(source_options);
        in.scans.push_back(source.Next(0));
        in.scans.back().band = ObjectsBand(*in.scans.back().truth);
      } catch (const Error& e) {
        std::fprintf(stderr, "scene %llu skipped: %s\n", static_cast<unsigned long long>(seed),
                     e.what());
      }
    }
    return owned;
  }();
  return *input;
}

std::vector<double> table_totals, single_totals;

// CPU time of this thread, ms (the machine is shared: wall clock includes other jobs).
double ThreadCpuMs() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return 1e3 * static_cast<double>(t.tv_sec) + 1e-6 * static_cast<double>(t.tv_nsec);
}

// The tabletop path with the given clustering of the table segmentation (`adjust`, when
// given, changes the scene recognition's options: a peer), on `threads` cores (OpenCV's pool, the
// decoder, the triangulation and the pose stages; the CPU-time counters then count the
// calling thread only: read the wall-clock ones).
void RunTable(benchmark::State& state, TableSegmentationOptions::Clustering clustering,
              std::vector<double>* totals_out, bool second_looks = true,
              const std::function<void(SceneRecognitionOptions*)>& adjust = {},
              const DecoderOptions& decoder_options = ScanOptions().decoder,
              bool table_scan = true, bool live = false, int threads = 1) {
  const Input& input = GetInput();
  const ScopedCvThreads cores(threads);  // 1: OpenCV's pool on this thread only
  DecoderOptions decoder = decoder_options;
  decoder.num_threads = threads;
  TriangulationOptions triangulation;
  triangulation.num_threads = threads;
  const Triangulator triangulator(input.calibration, triangulation);
  const SceneRecogniser recogniser(*input.db);
  // The per-model caches are built before the timed scans, as the scan-and-recognise loop
  // builds them on its other core during the first capture (SceneRecogniser::WarmUp); the
  // warm-up's own time is a counter.
  {
    SceneRecognitionOptions options;
    if (adjust) adjust(&options);
    const double cpu_start = ThreadCpuMs();
    recogniser.WarmUp(options);
    state.counters["warm_up_cpu_ms"] = ThreadCpuMs() - cpu_start;
  }
  std::vector<double> total, cpu, scene_ms, segment_ms, decode_ms;
  int found = 0, known = 0;
  size_t k = 0;
  for (auto _ : state) {
    const SourceScan& in = input.scans[k++ % input.scans.size()];
    // The live loop: every frame but the last decoded while the rest is captured (not
    // timed), as ScanAndRecogniseController's frame sink does in tabletop mode.
    std::unique_ptr<IncrementalDecoder> during_capture;
    const size_t last = in.frames.images.size() - 1;
    if (live) {
      during_capture = std::make_unique<IncrementalDecoder>(in.frames.manifest,
                                                            PlainTableDecoderOptions(decoder));
      for (size_t i = 0; i < last; ++i) during_capture->AddFrame(i, in.frames.images[i]);
    }
    const auto start = std::chrono::steady_clock::now();
    const double cpu_start = ThreadCpuMs();
    SceneRecognitionOptions options;  // the default range band, as scan-and-recognise's
    options.segmentation.clustering = clustering;
    CorrespondenceMap plain;
    double plain_ms = 0.0;
    if (live) {
      during_capture->AddFrame(last, in.frames.images[last]);
      during_capture->Finish(&plain);
      plain_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                     .count();
    }
    const ScanResult result =
        table_scan ? ScanTableFrameSet(in.frames, triangulator, decoder, options.segmentation,
                                       live ? &plain : nullptr, plain_ms)
                   : ScanFrameSet(in.frames, triangulator, decoder);
    if (!second_looks) options.second_look_rounds = 0;
    if (adjust) adjust(&options);
    options.recognition.threads = threads;
    const SceneRecognitionResult scene = recogniser.Recognise(result.triangulation.cloud, options);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    cpu.push_back(ThreadCpuMs() - cpu_start);
    state.SetIterationTime(ms / 1e3);
    total.push_back(ms);
    scene_ms.push_back(scene.timing.total);
    decode_ms.push_back(result.decode_ms);
    segment_ms.push_back(scene.timing.segment);
    found += static_cast<int>(scene.objects.size());
    known += static_cast<int>(in.truth->objects.size());
  }
  if (totals_out) *totals_out = cpu;
  state.counters["frame_to_results_median_ms"] = Quantile(total, 0.5);
  state.counters["frame_to_results_p95_ms"] = Quantile(total, 0.95);
  state.counters["cpu_median_ms"] = Quantile(cpu, 0.5);
  state.counters["cpu_p95_ms"] = Quantile(cpu, 0.95);
  state.counters["segment_median_ms"] = Quantile(segment_ms, 0.5);
  state.counters["decode_median_ms"] = Quantile(decode_ms, 0.5);
  state.counters["scene_recognition_median_ms"] = Quantile(scene_ms, 0.5);
  state.counters["goal_ms"] = kGoalMs;
  state.counters["objects_reported_per_truth"] = known ? static_cast<double>(found) / known : 0.0;
}

std::vector<double> pcl_cpu;
std::vector<double> plain_decode_cpu;

void BM_Table_AllObjects_PlainDecode(benchmark::State& state) {
  RunTable(state, TableSegmentationOptions::Clustering::kGrid, &plain_decode_cpu, true, {},
           DecoderOptions());
  state.SetLabel("peer: the same with the plain per-pixel decode (no sub-pixel edges, no code "
                 "consistency)");
}
std::vector<double> whole_image_cpu;

void BM_Table_AllObjects_WholeImageConsistency(benchmark::State& state) {
  RunTable(state, TableSegmentationOptions::Clustering::kGrid, &whole_image_cpu, true, {},
           ScanOptions().decoder, false);
  state.SetLabel("peer: the same with code consistency over the whole image (ScanFrameSet, "
                 "before 2026-12-05)");
}
std::vector<double> first_look_cpu;
std::vector<double> no_rolls_cpu;
std::vector<double> live_cpu;

// The path as `sope scan-and-recognise --table` runs it on a capturing source: the plain
// decode accumulated frame by frame during the capture, so that after the last frame only
// its bit, the finish and the table scan's own steps remain (what "last frame → every
// result" means for the live loop).
void BM_Table_AllObjects_Live(benchmark::State& state) {
  RunTable(state, TableSegmentationOptions::Clustering::kGrid, &live_cpu, true, {},
           ScanOptions().decoder, true, true);
  state.SetLabel("the live loop: the plain decode during the capture (IncrementalDecoder), timed "
                 "from the last frame");
}

// The live loop on both cores of a 2-core machine (`scan-and-recognise --table --threads
// 2`): the decoder's consistency and edges, both triangulations and the pose stages on two
// threads. Wall clock (frame_to_results_*); not the one-core measure.
void BM_Table_AllObjects_Live_TwoCores(benchmark::State& state) {
  RunTable(state, TableSegmentationOptions::Clustering::kGrid, nullptr, true, {},
           ScanOptions().decoder, true, true, 2);
  state.SetLabel("the live loop on 2 cores (wall clock)");
}

void BM_Table_AllObjects_NoRolls(benchmark::State& state) {
  RunTable(state, TableSegmentationOptions::Clustering::kGrid, &no_rolls_cpu, true,
           [](SceneRecognitionOptions* o) { o->roll_steps = 0; });
  state.SetLabel("peer: the same without rolled hypotheses (models turned about their axis of "
                 "near symmetry)");
}

std::vector<double> rolls_everywhere_cpu;

void BM_Table_AllObjects_RollExplainedClusters(benchmark::State& state) {
  RunTable(state, TableSegmentationOptions::Clustering::kGrid, &rolls_everywhere_cpu, true,
           [](SceneRecognitionOptions* o) { o->roll_explained_clusters = true; });
  state.SetLabel("peer: the same with other classes' rolled hypotheses also on clusters the "
                 "class ranked first explains (before 2026-12-07)");
}

void BM_Table_AllObjects_FirstLookOnly(benchmark::State& state) {
  RunTable(state, TableSegmentationOptions::Clustering::kGrid, &first_look_cpu, false);
  state.SetLabel("peer: the same without second looks (remainders, twins, convex splits, joins "
                 "of clusters left unexplained)");
}

void BM_Table_AllObjects_PclClustering(benchmark::State& state) {
  RunTable(state, TableSegmentationOptions::Clustering::kPclKdTree, &pcl_cpu);
  state.SetLabel("peer: the same with PCL's kd-tree Euclidean clustering (the former path)");
}

void BM_Table_AllObjects(benchmark::State& state) {
  RunTable(state, TableSegmentationOptions::Clustering::kGrid, &table_totals);
  if (!pcl_cpu.empty()) {
    state.counters["cpu_ratio_vs_pcl_clustering"] =
        Quantile(table_totals, 0.5) / Quantile(pcl_cpu, 0.5);
  }
  if (!no_rolls_cpu.empty()) {
    state.counters["cpu_ratio_vs_no_rolls"] = Quantile(table_totals, 0.5) / Quantile(no_rolls_cpu, 0.5);
  }
  if (!rolls_everywhere_cpu.empty()) {
    state.counters["cpu_ratio_vs_rolls_on_explained_clusters"] =
        Quantile(table_totals, 0.5) / Quantile(rolls_everywhere_cpu, 0.5);
  }
  if (!plain_decode_cpu.empty()) {
    state.counters["cpu_ratio_vs_plain_decode"] =
        Quantile(table_totals, 0.5) / Quantile(plain_decode_cpu, 0.5);
  }
  if (!whole_image_cpu.empty()) {
    state.counters["cpu_ratio_vs_whole_image_consistency"] =
        Quantile(table_totals, 0.5) / Quantile(whole_image_cpu, 0.5);
  }
  if (!live_cpu.empty()) {
    state.counters["cpu_ratio_live_vs_this"] =
        Quantile(live_cpu, 0.5) / Quantile(table_totals, 0.5);
  }
  if (!first_look_cpu.empty()) {
    state.counters["cpu_ratio_vs_first_look_only"] =
        Quantile(table_totals, 0.5) / Quantile(first_look_cpu, 0.5);
  }
  state.SetLabel("5 objects on a table: decode + triangulate + segment (grid clusters) + every "
                 "cluster + verify");
}

// The segmentation stage alone on the triangulated clouds, both clusterings.
void RunSegment(benchmark::State& state, TableSegmentationOptions::Clustering clustering) {
  const Input& input = GetInput();
  static std::vector<PointCloud> clouds;
  if (clouds.empty()) {
    for (const SourceScan& in : input.scans) {
      clouds.push_back(ScanFrameSet(in.frames, *input.triangulator, ScanOptions().decoder)
                           .triangulation.cloud);
    }
  }
  std::vector<double> cpu;
  size_t k = 0, clusters = 0;
  for (auto _ : state) {
    TableSegmentationOptions options;
    options.clustering = clustering;
    const double cpu_start = ThreadCpuMs();
    const TableSegmentation seg = SegmentTable(clouds[k++ % clouds.size()], options);
    cpu.push_back(ThreadCpuMs() - cpu_start);
    clusters += seg.clusters.size();
  }
  state.counters["cpu_median_ms"] = Quantile(cpu, 0.5);
  state.counters["cpu_p95_ms"] = Quantile(cpu, 0.95);
  state.counters["clusters_per_scan"] = static_cast<double>(clusters) / cpu.size();
}
void BM_Segment_Grid(benchmark::State& state) {
  RunSegment(state, TableSegmentationOptions::Clustering::kGrid);
}
void BM_Segment_PclKdTree(benchmark::State& state) {
  RunSegment(state, TableSegmentationOptions::Clustering::kPclKdTree);
}

// The decode alone on the table scenes, one core: the scan defaults (arg 1: sub-pixel
// edges and code consistency, what scan-and-recognise runs) or the plain per-pixel decode
// (arg 0). Dim, grazing table scenes leave many pixels to the code consistency.
void BM_DecodeTableScene(benchmark::State& state) {
  const Input& input = GetInput();
  const ScopedCvThreads one_core(1);  // OpenCV's pool on this thread only
  const DecoderOptions options = state.range(0) != 0 ? ScanOptions().decoder : DecoderOptions();
  CorrespondenceMap map;
  size_t k = 0, valid = 0;
  for (auto _ : state) {
    Decode(input.scans[k++ % input.scans.size()].frames, options, &map);
    valid += map.CountValid();
  }
  state.counters["valid_per_scan"] = static_cast<double>(valid) / static_cast<double>(k);
  state.SetLabel(state.range(0) != 0 ? "scan defaults (edges, consistency)" : "plain decode");
}

void BM_SingleObjectPath(benchmark::State& state) {
  const Input& input = GetInput();
  const Recogniser recogniser(*input.db);
  const ScopedCvThreads one_core(1);  // OpenCV's pool on this thread only
  std::vector<double> total, cpu;
  size_t k = 0;
  for (auto _ : state) {
    const SourceScan& in = input.scans[k++ % input.scans.size()];
    const auto start = std::chrono::steady_clock::now();
    const double cpu_start = ThreadCpuMs();
    const ScanRecognition result =
        RecogniseFrameSet(in.frames, *input.triangulator, ScanOptions().decoder,
                          *in.band, recogniser, {});
    benchmark::DoNotOptimize(result.recognition.suggestions.size());
    cpu.push_back(ThreadCpuMs() - cpu_start);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    state.SetIterationTime(ms / 1e3);
    total.push_back(ms);
  }
  single_totals = cpu;
  state.counters["frame_to_result_median_ms"] = Quantile(total, 0.5);
  state.counters["frame_to_result_p95_ms"] = Quantile(total, 0.95);
  state.counters["cpu_median_ms"] = Quantile(cpu, 0.5);
  state.counters["cpu_p95_ms"] = Quantile(cpu, 0.95);
  if (!table_totals.empty()) {  // CPU medians: the machine is shared
    state.counters["table_ratio"] = Quantile(table_totals, 0.5) / Quantile(cpu, 0.5);
  }
  state.SetLabel("peer: range band + one recognition on the same frames");
}

BENCHMARK(BM_Segment_PclKdTree)->Iterations(5 * kScenes);
BENCHMARK(BM_Segment_Grid)->Iterations(5 * kScenes);
BENCHMARK(BM_Table_AllObjects_PclClustering)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Table_AllObjects_NoRolls)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Table_AllObjects_RollExplainedClusters)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Table_AllObjects_PlainDecode)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Table_AllObjects_WholeImageConsistency)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Table_AllObjects_FirstLookOnly)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Table_AllObjects_Live)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Table_AllObjects_Live_TwoCores)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Table_AllObjects)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_DecodeTableScene)
    ->Arg(0)
    ->Arg(1)
    ->ArgName("scan_defaults")
    ->Iterations(5 * kScenes)
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SingleObjectPath)->Iterations(5 * kScenes)->UseManualTime()->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace sope

SOPE_BENCHMARK_MAIN();
