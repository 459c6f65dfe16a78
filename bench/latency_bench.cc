// Latency of scan and recognise (issue 5): from the last captured frame to the recognition
// result — decode + triangulate + range-band segmentation + recognition
// (recogniser/tools/scan_recognition.h RecogniseFrameSet) — median and 95th percentile over scans
// of different objects, side by side with the thesis's ~230 ms per recognition
// (SOPE-THESIS-NOTES.md; recognition alone, on its hardware: compare the ratio counters,
// not absolute times — this machine is shared).
//
// Three configurations in the same run, on the same frame sets:
//   sope   — the default database of `sope scan-and-recognise --virtual` (10 procedural
//            classes × 2 instances × 100 Fibonacci views, "sope" preset) and the default
//            recognition options (k-best coarse search, fine ranking, roll + ICP + verify);
//   thesis — the thesis's database preset (18 viewpoints, its features, MLH codes) and
//            RecognitionOptions::ThesisPreset (radius search, no pose refinement);
//   overlapped — the sope configuration as the live loop runs it: decoded during the
//            capture (IncrementalDecoder; after the last frame only its bit and the
//            finish), triangulated on 1 or 2 threads; with the plain per-pixel decode
//            (scan_decoder 0) and with the decoder options scans use by default
//            (scan_decoder 1: sub-pixel stripe edges and code consistency, finished after
//            the last frame — what `sope scan-and-recognise` runs).
// Input: 8 scans on the virtual rig (default 1280×720 camera, 1024×768 projector, Gray code
// x and y with inverses) of unseen procedural instances in random poses before a backdrop,
// captured through a RigSession once at start-up (not timed). The databases are built at
// start-up too (~30 s on 2 cores).
//
// Counters (milliseconds): median / p95 of frame_to_result and of its stages; thesis_ms =
// 230; ratio = median frame_to_result / 230 and recognise_ratio = median recognise / 230.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <vector>

#include <benchmark/benchmark.h>
#include <fmt/format.h>

#include "bench/bench_support.h"
#include "calibration/scan.h"
#include "core/statistics.h"
#include "capture/rig_session.h"
#include "recogniser/database.h"
#include "recogniser/recogniser.h"
#include "recogniser/tools/database_builder.h"
#include "recogniser/tools/scan_recognition.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_camera.h"

namespace sope {
namespace {

namespace fs = std::filesystem;

constexpr double kThesisMs = 230.0;
constexpr int kScans = 8;

struct Scan {
  FrameSet frames;
  RecognitionScene scene;
};

struct Input {
  RigCalibration calibration;
  std::unique_ptr<Triangulator> triangulator;
  std::vector<Scan> scans;
  std::unique_ptr<Database> sope_db, thesis_db;
  std::string dir;
  ~Input() {
    sope_db.reset();
    thesis_db.reset();
    if (!dir.empty()) fs::remove_all(dir);
  }
};

const Input& GetInput() {
  static const std::unique_ptr<Input> input = [] {
    auto owned = std::make_unique<Input>();
    Input& in = *owned;
    in.dir = (fs::temp_directory_path() / ("sope_latency_bench_" + std::to_string(::getpid())))
                 .string();
    const std::string models = in.dir + "/models";
    WriteProceduralModels(models, 2, 0);
    DatabaseOptions sope_options = DatabaseOptions::Preset("sope");
    sope_options.views_per_model = 100;
    BuildSummary summary;
    WriteDatabase(in.dir + "/sope.sopedb", BuildDatabase(models, sope_options, {}, &summary));
    std::fprintf(stderr, "sope database: %s\n", summary.BriefReport().c_str());
    WriteDatabase(in.dir + "/thesis.sopedb",
                  BuildDatabase(models, DatabaseOptions::Preset("thesis"), {}, &summary));
    std::fprintf(stderr, "thesis database: %s\n", summary.BriefReport().c_str());
    in.sope_db = Database::Open(in.dir + "/sope.sopedb");
    in.thesis_db = Database::Open(in.dir + "/thesis.sopedb");

    in.calibration = DefaultRigCalibration();
    in.triangulator = std::make_unique<Triangulator>(in.calibration);
    VirtualCameraOptions camera;
    camera.delay_frames = 2;
    camera.readout_jitter = 0.5 * camera.frame_period;
    RecognitionScene scene = MakeRecognitionScene(1, in.calibration.camera);
    VirtualLiveRig live = MakeVirtualLiveRig(in.calibration, scene.scene, {}, camera);
    RigSession session(*live.display, *live.camera);
    PatternOptions patterns;
    patterns.projector_width = in.calibration.projector.width;
    patterns.projector_height = in.calibration.projector.height;
    const std::vector<Pattern> sequence = GeneratePatterns(patterns);
    for (int k = 0; k < kScans; ++k) {
      if (k > 0) {
        scene = MakeRecognitionScene(1 + k, in.calibration.camera);
        live.rig->SetScene(scene.scene);
      }
      in.scans.push_back({session.Capture(sequence), scene});
      std::fprintf(stderr, "scan %d: %s\n", k, scene.Description().c_str());
    }
    return owned;
  }();
  return *input;
}

void Report(benchmark::State& state, const std::string& name, const std::vector<double>& values) {
  state.counters[name + "_median_ms"] = Quantile(values, 0.5);
  state.counters[name + "_p95_ms"] = Quantile(values, 0.95);
}

// Per-scan times and the class check of one configuration, reported as the counters every
// configuration shares.
struct LatencySamples {
  std::vector<double> total, decode, triangulate, segment, recognise;
  int correct = 0, runs = 0;

  void Add(benchmark::State& state, double ms, const ScanRecognition& result,
           const RecognitionScene& scene) {
    state.SetIterationTime(ms / 1e3);
    total.push_back(ms);
    decode.push_back(result.timing.decode);
    triangulate.push_back(result.timing.triangulate);
    segment.push_back(result.timing.segment);
    recognise.push_back(result.timing.recognise);
    correct += !result.recognition.empty() &&
               result.recognition.best().class_name == ToString(scene.object_class);
    ++runs;
  }

  void Report(benchmark::State& state) const {
    sope::Report(state, "frame_to_result", total);
    sope::Report(state, "decode", decode);
    sope::Report(state, "triangulate", triangulate);
    sope::Report(state, "segment", segment);
    sope::Report(state, "recognise", recognise);
    state.counters["thesis_ms"] = kThesisMs;
    state.counters["ratio"] = Quantile(total, 0.5) / kThesisMs;
    // Class top-1 on these unseen instances (a sanity figure, not the accuracy benchmark).
    state.counters["class_correct"] = runs ? static_cast<double>(correct) / runs : 0.0;
  }
};

// `widen_batch` ≥ 0 overrides WideningOptions::batch_models (0: the widened search in one
// batch, as before issue 14's early stop).
void RunLatency(benchmark::State& state, bool thesis, int widen_batch = -1) {
  const Input& input = GetInput();
  const Database& db = thesis ? *input.thesis_db : *input.sope_db;
  const Recogniser recogniser(db);
  RecognitionOptions options =
      thesis ? RecognitionOptions::ThesisPreset(db.options().hash.method) : RecognitionOptions();
  if (widen_batch >= 0) options.widening.batch_models = widen_batch;
  LatencySamples samples;
  size_t k = 0;
  for (auto _ : state) {
    const Scan& scan = input.scans[k++ % input.scans.size()];
    const auto start = std::chrono::steady_clock::now();
    const ScanRecognition result = RecogniseFrameSet(
        scan.frames, *input.triangulator, DecoderOptions(), scan.scene.segmentation, recogniser,
        options);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
            .count();
    samples.Add(state, ms, result, scan.scene);
  }
  samples.Report(state);
  state.counters["recognise_ratio"] = Quantile(samples.recognise, 0.5) / kThesisMs;
  state.SetLabel(thesis            ? "thesis database + ThesisPreset"
                 : widen_batch >= 0 ? fmt::format("sope database + defaults, widening "
                                                  "batch_models {}",
                                                  widen_batch)
                                    : "sope database + defaults");
}

// The live loop as ScanAndRecogniseController runs it for a capturing source: every frame
// but the last goes into an IncrementalDecoder while the rest is captured (not timed:
// it overlaps the capture); timed from the last frame: its AddFrame, Finish, the
// triangulation (`threads` threads) of the decoded map, segmentation and recognition
// (sope database + defaults, the pose stages on `pose_threads` threads), as the sope
// configuration above. `scan_decoder` 1: the decoder options scans use by default
// (ScanOptions: sub-pixel stripe edges and code consistency, on `threads` threads) — the
// live loop as `sope scan-and-recognise` runs it; 0: the plain per-pixel decode.
void BM_FrameToResult_Overlapped(benchmark::State& state) {
  const Input& input = GetInput();
  const Database& db = *input.sope_db;
  const Recogniser recogniser(db);
  RecognitionOptions options;
  options.threads = static_cast<int>(state.range(1));
  TriangulationOptions triangulation;
  triangulation.num_threads = static_cast<int>(state.range(0));
  const Triangulator triangulator(input.calibration, triangulation);
  const bool scan_decoder = state.range(2) != 0;
  DecoderOptions decoder_options = scan_decoder ? ScanOptions().decoder : DecoderOptions();
  if (scan_decoder) decoder_options.num_threads = triangulation.num_threads;
  IncrementalDecoder decoder(input.scans.front().frames.manifest, decoder_options);
  LatencySamples samples;
  size_t k = 0;
  for (auto _ : state) {
    const Scan& scan = input.scans[k++ % input.scans.size()];
    const FrameSet& frames = scan.frames;
    const size_t last = frames.images.size() - 1;
    decoder.Reset();
    for (size_t i = 0; i < last; ++i) decoder.AddFrame(i, frames.images[i]);
    const auto start = std::chrono::steady_clock::now();
    decoder.AddFrame(last, frames.images[last]);
    CorrespondenceMap map = decoder.Finish();
    const double decode_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
            .count();
    const ScanRecognition result =
        RecogniseScan(ScanDecoded(frames, std::move(map), decode_ms, triangulator),
                      scan.scene.segmentation, recogniser, options);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
            .count();
    samples.Add(state, ms, result, scan.scene);
  }
  samples.Report(state);
  state.SetLabel(fmt::format(
      "sope database + defaults, decoded during capture{}, {} thread(s), pose stages on {}",
      scan_decoder ? " with the scan defaults (edges, consistency)" : "",
      triangulation.num_threads, options.threads));
}

void BM_FrameToResult_Sope(benchmark::State& state) { RunLatency(state, false); }
void BM_FrameToResult_Thesis(benchmark::State& state) { RunLatency(state, true); }
// The widened pose search in one batch (no early stop): the p95 before issue 14's step.
void BM_FrameToResult_SopeWidenAtOnce(benchmark::State& state) { RunLatency(state, false, 0); }
// 5 passes over the 8 scans: enough samples for a p95.
BENCHMARK(BM_FrameToResult_Sope)->Iterations(5 * kScans)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FrameToResult_Thesis)->Iterations(5 * kScans)->UseManualTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FrameToResult_SopeWidenAtOnce)
    ->Iterations(5 * kScans)
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);
// (triangulation threads, pose-stage threads): 1 and 2 cores as before, then 2 cores with
// the pose screening and refinement on both (RecognitionOptions::threads).
BENCHMARK(BM_FrameToResult_Overlapped)
    ->Args({1, 1, 0})
    ->Args({2, 1, 0})
    ->Args({2, 2, 0})
    ->Args({1, 1, 1})
    ->Args({2, 2, 1})
    ->ArgNames({"threads", "pose_threads", "scan_decoder"})
    ->Iterations(5 * kScans)
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace sope

SOPE_BENCHMARK_MAIN();
