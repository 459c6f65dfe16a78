// Recognition speed and accuracy (issue 4): the whole query (pre-processing to refined pose)
// on a ~10k-view database, and the fine stage side by side with PCL's tutorial pipeline.
//
//   recognise_bench [--benchmark_filter=...]
//   env: SOPE_BENCH_CACHE   directory of the cached models and databases
//                           (default /tmp/sope-bench-cache)
//        SOPE_BENCH_PASSES  passes over the queries per benchmark (default 2)
//
// Data. Procedural household objects, kInstances instances of each of the 10 classes
// (WriteProceduralModels(dir, kInstances, kModelSeed)), built into
//  - the "sope" database: DatabaseOptions::Preset("sope"), 300 views per model (≈ 12k views);
//  - the "thesis" database: DatabaseOptions::Preset("thesis") of the same meshes, 18 views
//    per model (thesis layout, thesis features, MLH codes).
// Both are cached as .sopedb files named after a hash of the build options and the mesh
// files' contents, so reruns skip the 2–4 minute build. Queries: kQueries synthetic views of
// the database models (instance protocol: the same meshes), query k of model k mod models,
// rendered off the database grid by RenderSyntheticQuery (640 × 480, 57° field of view,
// default SyntheticQueryOptions: 0.4–0.8 m, rolled, off-centre, 1 mm depth noise, up to 25 %
// occluded, seed kQuerySeed), all rendered before any timing.
//
// Timing. One benchmark iteration = one query (cycling through the queries, SOPE_BENCH_PASSES
// passes). Everything on the calling thread: the recogniser is single-threaded, PCL's
// NormalEstimation / VFHEstimation and FLANN (cores = 1) too, and OMP_NUM_THREADS is set to 1
// before anything starts. Per-query times are the calling thread's CPU time (immune to
// preemption on a shared machine): RecognitionResult::timing.*_cpu for ours, the same clock
// around each stage for the PCL pipeline. Counters: median / p95 ms per query, the median of
// each stage, the mean flagged fraction, top-1 model / class accuracy (over all passes; the
// pipeline is deterministic), ratio_vs_thesis_230ms = 230 ms / median.
//
// Benchmarks:
//  BM_Recognise/sope                  default RecognitionOptions on the sope database (k-best
//                                     coarse search, fine ranking, roll + ICP + verification)
//  BM_Recognise/sope_no_class_ranking the same with AssemblyOptions::class_ranking off (the
//                                     cost of the class scores, side by side)
//  BM_Recognise/sope_no_class_screening  class ranking without class screening
//                                     (class_screen_classes 0); the summary ends with the
//                                     median ratios of sope to these
//  BM_Recognise/sope_one_screen_model one model screened per runner-up class
//                                     (class_screen_models 1, the default before 2)
//  BM_Recognise/thesis                RecognitionOptions::ThesisPreset(MLH) on the thesis
//                                     database (radius search, VFH + radial ranking, no ICP)
//  BM_Recognise/thesis_opts_sope_db   ThesisPreset(ITQ) on the sope database
//  BM_FineStage/sope_rank             ours without pose (pose_models = 0): pre-processing,
//                                     features, coarse search and fine ranking; top-1 = the
//                                     best-ranked view's model
//  BM_StagesAlone/fine+screen+refine  the fine stage, pose screening and refinement called
//                                     alone (recogniser/stages.h) on precomputed coarse
//                                     results; compare its fine/pose medians with
//                                     BM_Recognise/sope's (no widening here)
//  BM_FineStage/pcl_vfh_flann         PCL's "cluster recognition and 6DOF pose estimation
//                                     using VFH" tutorial: query → VoxelGrid (4 mm, as ours) →
//                                     NormalEstimation (k = 12, as ours; kd-tree) →
//                                     VFHEstimation (PCL defaults; kd-tree) → FLANN
//                                     kd-tree (KDTreeIndexParams(4), ChiSquareDistance,
//                                     SearchParams(512)) k = 4 nearest among the VFHs of every
//                                     database view; top-1 = the nearest view's model. Database
//                                     VFHs: pcl::VFHEstimation (defaults) of each stored view
//                                     cloud (≤ 256 points with normals) moved into its database
//                                     camera's frame, computed once before timing.
//  BM_FineStage/pcl_vfh_flann_linear  the same with FLANN's LinearIndexParams (exact; the
//                                     default in the tutorial's build_tree.cpp, where the
//                                     kd-tree line is commented out).
//  BM_FineStage/flann_on_sope_vfh     FLANN as above over the database's own fine descriptors
//                                     (VFH of the pre-processed, canonical views, unit L1),
//                                     the query's from DescribeView (our pre-processing and
//                                     features): the kd-tree in place of our coarse + fine
//                                     stages, with identical descriptors.
// A summary table is printed at the end.
//
// Measured (2026-11, 2-core shared VM, taskset -c 1, 3 passes; CPU ms per query, 12000-view
// sope database, 720-view thesis database; queries 16.6k points on average):
//   sope            median 7.6, p95 15.1; flagged 3.0 %; top-1 model 0.86, class 0.92
//                   (stages, median: pre 2.4, features 1.2, coarse 0.03, fine 0.09, pose 3.9)
//   thesis          median 3.7, p95 12.0; flagged 5.8 %; top-1 model 0.18, class 0.46
//   sope_rank       median 4.0; top-1 model 0.58, class 0.86 (model in top 4: 0.94)
//   pcl_vfh_flann   median 2.8 (kNN 0.38); top-1 model 0.38, class 0.78; linear: 4.2
//                   (kNN 1.7), 0.38 / 0.78
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <numeric>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>
#include <flann/flann.hpp>
#include <pcl/features/normal_3d.h>
#include <pcl/features/vfh.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>

#include "bench/bench_support.h"
#include "core/camera_model.h"
#include "core/mesh.h"
#include "core/stopwatch.h"
#include "recogniser/database.h"
#include "recogniser/recogniser.h"
#include "recogniser/stages.h"
#include "recogniser/tools/database_builder.h"
#include "recogniser/tools/synthetic_queries.h"
#include "recogniser/view_description.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

namespace fs = std::filesystem;

constexpr int kInstances = 4;  // per class: 40 models
constexpr uint64_t kModelSeed = 1000;
constexpr int kQueries = 50;
constexpr uint64_t kQuerySeed = 2024;
constexpr int kNeighbours = 4;       // FLANN k
constexpr double kThesisMs = 230.0;  // the thesis's time per query

// --- data ------------------------------------------------------------------------------

uint64_t Fnv1a(const std::string& bytes, uint64_t hash = 1469598103934665603ull) {
  for (unsigned char c : bytes) {
    hash ^= c;
    hash *= 1099511628211ull;
  }
  return hash;
}

std::string ReadFileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream out;
  out << in.rdbuf();
  return out.str();
}

std::string CacheDir() {
  const char* env = std::getenv("SOPE_BENCH_CACHE");
  return env && *env ? env : "/tmp/sope-bench-cache";
}

int Passes() {
  const char* env = std::getenv("SOPE_BENCH_PASSES");
  const int passes = env ? std::atoi(env) : 2;
  return std::max(1, passes);
}

// Writes the models (deterministic; rewritten every run, cheap) and returns the directory
// and a hash of the mesh files' contents.
std::pair<std::string, uint64_t> Models() {
  const std::string dir = CacheDir() + "/models_i" + std::to_string(kInstances) + "_s" +
                          std::to_string(kModelSeed);
  std::vector<std::string> paths = WriteProceduralModels(dir, kInstances, kModelSeed);
  std::sort(paths.begin(), paths.end());
  uint64_t hash = Fnv1a("models");
  for (const std::string& path : paths) hash = Fnv1a(path + ReadFileBytes(path), hash);
  return {dir, hash};
}

// The database of a preset, built once and cached by options and mesh contents.
std::unique_ptr<Database> CachedDatabase(const std::string& preset, const std::string& models_dir,
                                         uint64_t models_hash) {
  const DatabaseOptions options = DatabaseOptions::Preset(preset);
  const uint64_t key = Fnv1a(DatabaseOptionsToJson(options) + "|v" +
                                 std::to_string(kDatabaseFormatVersion),
                             models_hash);
  char name[128];
  std::snprintf(name, sizeof(name), "/%s_i%d_s%llu_%016llx.sopedb", preset.c_str(), kInstances,
                static_cast<unsigned long long>(kModelSeed), static_cast<unsigned long long>(key));
  const std::string path = CacheDir() + name;
  if (!fs::exists(path)) {
    std::printf("building the %s database (cached as %s) ...\n", preset.c_str(), path.c_str());
    std::fflush(stdout);
    BuildSummary summary;
    const DatabaseData data = BuildDatabase(models_dir, options, {}, &summary, 2);
    std::printf("%s\n", summary.BriefReport().c_str());
    WriteDatabase(path, data);
  }
  auto db = Database::Open(path);
  std::printf("%s database: %d models, %d views, %d-bit %s codes (%s)\n", preset.c_str(),
              db->num_models(), db->num_views(), db->options().hash.bits,
              ToString(db->options().hash.method).c_str(), path.c_str());
  return db;
}

struct Query {
  std::string model_name, class_name;
  PointCloud cloud;  // camera frame, metres
};

std::vector<Query> MakeQueries(const Database& db) {
  const CameraModel camera = MakePinhole(640, 480, 1.0);
  DepthRenderer renderer(camera);
  std::mt19937_64 rng(kQuerySeed);
  const SyntheticQueryOptions options;
  std::vector<Query> queries;
  for (int k = 0; k < kQueries; ++k) {
    const ModelRecord& model = db.model(k % db.num_models());
    TriangleMesh mesh = ReadMesh(model.source_path);
    for (auto& v : mesh.vertices) v = (v.cast<double>() * model.scale).cast<float>();
    renderer.SetMesh(mesh);
    Query q;
    q.model_name = model.name;
    q.class_name = model.class_name;
    SyntheticQuery query;
    do {
      query = RenderSyntheticQuery(&renderer, camera, model.center, model.bounding_radius, options,
                                   &rng);
    } while (query.cloud.size() < 300);
    q.cloud = std::move(query.cloud);
    queries.push_back(std::move(q));
  }
  return queries;
}

struct Data {
  std::unique_ptr<Database> sope_db, thesis_db;
  std::vector<Query> queries;
};

Data& GetData() {
  static Data data = [] {
    Data d;
    fs::create_directories(CacheDir());
    const auto [models_dir, models_hash] = Models();
    d.sope_db = CachedDatabase("sope", models_dir, models_hash);
    d.thesis_db = CachedDatabase("thesis", models_dir, models_hash);
    d.queries = MakeQueries(*d.sope_db);
    double points = 0;
    for (const Query& q : d.queries) points += static_cast<double>(q.cloud.size());
    std::printf("%zu queries, mean %.0f points\n", d.queries.size(), points / d.queries.size());
    return d;
  }();
  return data;
}

// --- statistics and the summary ----------------------------------------------------------

double Quantile(std::vector<double> values, double q) {
  if (values.empty()) return std::nan("");
  std::sort(values.begin(), values.end());
  // Nearest rank: the smallest value with at least a fraction q of the values ≤ it.
  const double rank = std::ceil(q * static_cast<double>(values.size()));
  const size_t index = static_cast<size_t>(std::clamp(rank, 1.0, double(values.size()))) - 1;
  return values[index];
}
double Median(const std::vector<double>& values) {
  if (values.empty()) return std::nan("");
  std::vector<double> v = values;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}
double Mean(const std::vector<double>& values) {
  if (values.empty()) return std::nan("");
  return std::accumulate(values.begin(), values.end(), 0.0) / values.size();
}

struct Samples {
  std::vector<double> total, wall;                      // ms per query (CPU, wall)
  std::map<std::string, std::vector<double>> stages;    // ms per query, CPU
  std::vector<double> flagged;                          // fraction
  int queries = 0, model_ok = 0, class_ok = 0, model_in_top = 0;
};

struct Row {
  std::string name;
  double median = 0, p95 = 0, wall_median = 0, flagged = 0, model = 0, class_acc = 0, top = 0;
  std::map<std::string, double> stage_medians, stage_p95;
};
std::vector<Row>& Rows() {
  static std::vector<Row> rows;
  return rows;
}

void Report(benchmark::State& state, const std::string& name, const Samples& s) {
  Row row;
  row.name = name;
  row.median = Median(s.total);
  row.p95 = Quantile(s.total, 0.95);
  row.wall_median = Median(s.wall);
  row.flagged = s.flagged.empty() ? std::nan("") : Mean(s.flagged);
  row.model = static_cast<double>(s.model_ok) / s.queries;
  row.class_acc = static_cast<double>(s.class_ok) / s.queries;
  row.top = static_cast<double>(s.model_in_top) / s.queries;
  state.counters["median_ms"] = row.median;
  state.counters["p95_ms"] = row.p95;
  state.counters["wall_median_ms"] = row.wall_median;
  if (!s.flagged.empty()) state.counters["flagged_frac"] = row.flagged;
  state.counters["top1_model"] = row.model;
  state.counters["top1_class"] = row.class_acc;
  state.counters["model_in_top4"] = row.top;
  state.counters["ratio_vs_thesis_230ms"] = kThesisMs / row.median;
  for (const auto& [stage, values] : s.stages) {
    row.stage_medians[stage] = Median(values);
    row.stage_p95[stage] = Quantile(values, 0.95);
    state.counters[stage + "_ms"] = row.stage_medians[stage];
  }
  // Keep the last run of a name (repetitions overwrite).
  auto& rows = Rows();
  auto it = std::find_if(rows.begin(), rows.end(), [&](const Row& r) { return r.name == name; });
  if (it == rows.end()) rows.push_back(row);
  else *it = row;
}

// --- ours ------------------------------------------------------------------------------

void BM_Recognise(benchmark::State& state, const std::string& name, bool thesis_db,
                  RecognitionOptions options) {
  Data& data = GetData();
  const Database& db = thesis_db ? *data.thesis_db : *data.sope_db;
  const Recogniser recogniser(db);
  Samples s;
  size_t q = 0;
  for (auto _ : state) {
    const Query& query = data.queries[q];
    q = (q + 1) % data.queries.size();
    const Stopwatch watch;
    const RecognitionResult result = recogniser.Recognise(query.cloud, options);
    s.wall.push_back(watch.WallMs());
    const RecognitionTimings& t = result.timing;
    s.total.push_back(t.total_cpu);
    s.stages["pre"].push_back(t.preprocess_cpu);
    s.stages["feat"].push_back(t.features_cpu);
    s.stages["coarse"].push_back(t.coarse_cpu);
    s.stages["fine"].push_back(t.fine_cpu);
    s.stages["pose"].push_back(t.pose_cpu);
    s.flagged.push_back(result.flagged_fraction);
    ++s.queries;
    if (!result.empty()) {
      s.model_ok += result.best().model_name == query.model_name;
      s.class_ok += result.best().class_name == query.class_name;
      for (const Suggestion& suggestion : result.suggestions) {
        if (suggestion.model_name == query.model_name) {
          ++s.model_in_top;
          break;
        }
      }
    }
  }
  Report(state, name, s);
}

// The stages called alone (recogniser/stages.h): pre-processing, features and the coarse
// search done once per query before timing; each iteration times the fine stage and the
// pose screening + refinement (no widening) on their own, CPU ms — beside BM_Recognise/sope's
// fine and pose stages in the same run. Top-1: the best refined hypothesis's model.
void BM_StagesAlone(benchmark::State& state) {
  Data& data = GetData();
  const Database& db = *data.sope_db;
  const RecognitionOptions options;
  std::vector<ViewDescription> queries;
  std::vector<CoarseResult> coarse;
  queries.reserve(data.queries.size());
  coarse.reserve(data.queries.size());
  for (const Query& query : data.queries) {
    queries.push_back(DescribeQuery(db, query.cloud));
    coarse.push_back(CoarseStage(db, queries.back(), options));
  }
  Samples s;
  size_t q = 0;
  for (auto _ : state) {
    const size_t i = q;
    q = (q + 1) % data.queries.size();
    const Stopwatch watch;
    StageContext context(db, queries[i], coarse[i]);
    const FineResult fine = FineStage(&context, options);
    const double fine_ms = watch.CpuMs();
    const ScreeningRequest plan = PlanScreening(context, fine, options);
    const RefinementResult refined = RefinePoses(
        &context, ScreenPoses(&context, fine, plan, options), options.refinement.candidates, options);
    const double total_ms = watch.CpuMs();
    s.wall.push_back(watch.WallMs());
    s.total.push_back(total_ms);
    s.stages["fine"].push_back(fine_ms);
    s.stages["pose"].push_back(total_ms - fine_ms);
    s.flagged.push_back(static_cast<double>(coarse[i].flagged.size()) / db.num_views());
    ++s.queries;
    const PoseCandidate* best = nullptr;
    for (const PoseCandidate& c : refined.candidates) {
      if (c.refined && (best == nullptr || c.alignment.score > best->alignment.score)) best = &c;
    }
    if (best != nullptr) {
      const ModelRecord& model = db.model(best->model);
      s.model_ok += model.name == data.queries[i].model_name;
      s.class_ok += model.class_name == data.queries[i].class_name;
    }
  }
  Report(state, "BM_StagesAlone/fine+screen+refine", s);
}

// --- PCL tutorial pipeline ---------------------------------------------------------------

using Vfh = pcl::VFHSignature308;
constexpr int kVfhBins = 308;

// VFH as in the tutorial: PCL defaults (viewpoint at the origin = the sensor, normalised
// bins, PCL's own centroid), kd-tree search method.
Vfh ComputeVfh(const pcl::PointCloud<pcl::PointXYZ>::Ptr& xyz,
               const pcl::PointCloud<pcl::Normal>::Ptr& normals) {
  pcl::VFHEstimation<pcl::PointXYZ, pcl::Normal, Vfh> vfh;
  vfh.setInputCloud(xyz);
  vfh.setInputNormals(normals);
  vfh.setSearchMethod(pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
  pcl::PointCloud<Vfh> out;
  vfh.compute(out);
  return out.points.at(0);
}

struct FlannIndex {
  std::vector<float> storage;
  std::unique_ptr<flann::Index<flann::ChiSquareDistance<float>>> index;
  std::vector<int> view_model;  // row → database model
  double build_ms = 0.0, describe_ms = 0.0;

  // kd-tree: KDTreeIndexParams(4) (the tutorial's commented-out alternative, the one its
  // title names); linear: LinearIndexParams (the tutorial's build_tree.cpp default, exact).
  void Build(int rows, bool linear = false) {
    // The kd-trees split on randomly chosen dimensions (rand()): seed it, so the index, and
    // the accuracy, do not depend on what ran before in the process.
    flann::seed_random(1);
    const Stopwatch watch;
    flann::Matrix<float> matrix(storage.data(), rows, kVfhBins);
    index = linear ? std::make_unique<flann::Index<flann::ChiSquareDistance<float>>>(
                         matrix, flann::LinearIndexParams())
                   : std::make_unique<flann::Index<flann::ChiSquareDistance<float>>>(
                         matrix, flann::KDTreeIndexParams(4));
    index->buildIndex();
    build_ms = watch.CpuMs();
  }

  std::vector<int> Search(const float* histogram) const {
    std::vector<float> query(histogram, histogram + kVfhBins);
    flann::Matrix<float> q(query.data(), 1, kVfhBins);
    std::vector<std::vector<int>> indices;
    std::vector<std::vector<float>> distances;
    flann::SearchParams params(512);
    params.cores = 1;
    index->knnSearch(q, indices, distances, kNeighbours, params);
    return indices[0];
  }
};

// The VFH of every stored view cloud, in its database camera's frame.
const FlannIndex& PclKdTreeIndex();
const FlannIndex& PclLinearIndex() {
  static const FlannIndex index = [] {
    const FlannIndex& kdtree = PclKdTreeIndex();
    FlannIndex out;
    out.storage = kdtree.storage;
    out.view_model = kdtree.view_model;
    out.describe_ms = kdtree.describe_ms;
    out.Build(static_cast<int>(out.view_model.size()), true);
    return out;
  }();
  return index;
}
const FlannIndex& PclIndex(bool linear) { return linear ? PclLinearIndex() : PclKdTreeIndex(); }
const FlannIndex& PclKdTreeIndex() {
  static const FlannIndex index = [] {
    const Database& db = *GetData().sope_db;
    FlannIndex out;
    const Stopwatch watch;
    out.storage.resize(static_cast<size_t>(db.num_views()) * kVfhBins);
    PointCloud cloud;
    for (int v = 0; v < db.num_views(); ++v) {
      db.ViewCloud(v, &cloud);
      const Rigid3d& cam_from_model = db.view(v).cam_from_model;
      const Eigen::Matrix3f rotation = cam_from_model.rotation.cast<float>();
      const Eigen::Vector3f translation = cam_from_model.translation.cast<float>();
      auto xyz = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
      auto normals = pcl::make_shared<pcl::PointCloud<pcl::Normal>>();
      for (size_t i = 0; i < cloud.size(); ++i) {
        const Eigen::Vector3f p = rotation * cloud.points[i] + translation;
        const Eigen::Vector3f n = rotation * cloud.normals[i];
        xyz->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
        normals->push_back(pcl::Normal(n.x(), n.y(), n.z()));
      }
      const Vfh vfh = ComputeVfh(xyz, normals);
      std::copy(vfh.histogram, vfh.histogram + kVfhBins, out.storage.begin() + v * kVfhBins);
      out.view_model.push_back(db.view(v).model);
    }
    out.describe_ms = watch.CpuMs();
    out.Build(db.num_views());
    std::printf("PCL VFH of %d stored view clouds: %.0f ms; FLANN kd-tree build %.0f ms\n",
                db.num_views(), out.describe_ms, out.build_ms);
    return out;
  }();
  return index;
}

// The database's own fine descriptors.
const FlannIndex& SopeVfhIndex() {
  static const FlannIndex index = [] {
    const Database& db = *GetData().sope_db;
    FlannIndex out;
    out.storage.resize(static_cast<size_t>(db.num_views()) * kVfhBins);
    for (int v = 0; v < db.num_views(); ++v) {
      std::copy(db.fine(v), db.fine(v) + kVfhBins, out.storage.begin() + v * kVfhBins);
      out.view_model.push_back(db.view(v).model);
    }
    out.Build(db.num_views());
    return out;
  }();
  return index;
}

void Score(const Database& db, const Query& query, const std::vector<int>& neighbours,
           const std::vector<int>& view_model, Samples* s) {
  ++s->queries;
  if (neighbours.empty() || neighbours[0] < 0) return;
  const ModelRecord& best = db.model(view_model[neighbours[0]]);
  s->model_ok += best.name == query.model_name;
  s->class_ok += best.class_name == query.class_name;
  for (int n : neighbours) {
    if (n >= 0 && db.model(view_model[n]).name == query.model_name) {
      ++s->model_in_top;
      break;
    }
  }
}

void BM_PclVfhFlann(benchmark::State& state, bool linear) {
  Data& data = GetData();
  const Database& db = *data.sope_db;
  const FlannIndex& index = PclIndex(linear);
  const double leaf = db.options().preprocess.voxel_leaf;
  const int neighbours = db.options().preprocess.normal_neighbours;
  Samples s;
  size_t q = 0;
  for (auto _ : state) {
    const Query& query = data.queries[q];
    q = (q + 1) % data.queries.size();
    const Stopwatch total;
    Stopwatch stage;
    // Pre-processing: voxel grid, normals (towards the sensor at the origin).
    auto raw = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    raw->reserve(query.cloud.size());
    for (const Eigen::Vector3f& p : query.cloud.points) {
      if (p.allFinite()) raw->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
    }
    auto down = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    pcl::VoxelGrid<pcl::PointXYZ> grid;
    grid.setInputCloud(raw);
    grid.setLeafSize(leaf, leaf, leaf);
    grid.filter(*down);
    pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal> estimation;
    estimation.setInputCloud(down);
    estimation.setSearchMethod(pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
    estimation.setKSearch(neighbours);
    auto normals = pcl::make_shared<pcl::PointCloud<pcl::Normal>>();
    estimation.compute(*normals);
    // Points without a normal are dropped (VFH needs finite normals).
    auto xyz = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    auto good_normals = pcl::make_shared<pcl::PointCloud<pcl::Normal>>();
    for (size_t i = 0; i < down->size(); ++i) {
      const pcl::Normal& n = (*normals)[i];
      if (std::isfinite(n.normal_x) && std::isfinite(n.normal_y) && std::isfinite(n.normal_z)) {
        xyz->push_back((*down)[i]);
        good_normals->push_back(n);
      }
    }
    s.stages["pre"].push_back(stage.CpuMs());
    stage.Restart();
    const Vfh vfh = ComputeVfh(xyz, good_normals);
    s.stages["feat"].push_back(stage.CpuMs());
    stage.Restart();
    const std::vector<int> result = index.Search(vfh.histogram);
    s.stages["knn"].push_back(stage.CpuMs());
    s.total.push_back(total.CpuMs());
    s.wall.push_back(total.WallMs());
    Score(db, query, result, index.view_model, &s);
  }
  Report(state, linear ? "BM_FineStage/pcl_vfh_flann_linear" : "BM_FineStage/pcl_vfh_flann", s);
}

void BM_FlannOnSopeVfh(benchmark::State& state) {
  Data& data = GetData();
  const Database& db = *data.sope_db;
  const FlannIndex& index = SopeVfhIndex();
  Samples s;
  size_t q = 0;
  for (auto _ : state) {
    const Query& query = data.queries[q];
    q = (q + 1) % data.queries.size();
    const Stopwatch total;
    const ViewDescription description =
        DescribeView(query.cloud, db.options().preprocess, db.options().features);
    s.stages["pre"].push_back(description.preprocess_cpu_ms);
    s.stages["feat"].push_back(description.features_cpu_ms);
    Stopwatch stage;
    const std::vector<int> result = index.Search(description.features.fine.data());
    s.stages["knn"].push_back(stage.CpuMs());
    s.total.push_back(total.CpuMs());
    s.wall.push_back(total.WallMs());
    Score(db, query, result, index.view_model, &s);
  }
  Report(state, "BM_FineStage/flann_on_sope_vfh", s);
}

// --- summary -----------------------------------------------------------------------------

void PrintSummary() {
  const Data& data = GetData();
  std::printf("\n=== recognition, %zu queries × %d passes, one thread, CPU ms per query ===\n",
              data.queries.size(), Passes());
  std::printf("sope database %d views, thesis database %d views\n", data.sope_db->num_views(),
              data.thesis_db->num_views());
  std::printf("%-34s %8s %8s %8s %8s | %6s %6s %6s | %7s %7s %7s %7s %7s %7s\n", "benchmark",
              "median", "p95", "wall med", "flagged", "model", "class", "m.top4", "pre", "feat",
              "coarse", "fine", "pose", "knn");
  for (const Row& r : Rows()) {
    auto stage = [&](const char* key) {
      const auto it = r.stage_medians.find(key);
      return it == r.stage_medians.end() ? std::nan("") : it->second;
    };
    std::printf("%-34s %8.2f %8.2f %8.2f %7.2f%% | %6.3f %6.3f %6.3f | %7.2f %7.2f %7.3f %7.3f %7.2f %7.3f\n",
                r.name.c_str(), r.median, r.p95, r.wall_median, 100.0 * r.flagged, r.model,
                r.class_acc, r.top, stage("pre"), stage("feat"), stage("coarse"), stage("fine"),
                stage("pose"), stage("knn"));
  }
  std::printf("(stage columns: medians over queries; ratio vs the thesis's 230 ms = 230 / median)\n");
  std::printf("\np95 per stage, CPU ms:\n%-34s %7s %7s %7s %7s %7s %7s\n", "benchmark", "pre", "feat",
              "coarse", "fine", "pose", "knn");
  for (const Row& r : Rows()) {
    auto stage = [&](const char* key) {
      const auto it = r.stage_p95.find(key);
      return it == r.stage_p95.end() ? std::nan("") : it->second;
    };
    std::printf("%-34s %7.2f %7.2f %7.3f %7.3f %7.2f %7.3f\n", r.name.c_str(), stage("pre"),
                stage("feat"), stage("coarse"), stage("fine"), stage("pose"), stage("knn"));
  }
  for (const Row& r : Rows()) {
    std::printf("  %-34s ratio_vs_thesis_230ms %.1f\n", r.name.c_str(), kThesisMs / r.median);
  }
  // The cost of class-aware ranking, same run: median CPU time of the default against the
  // same options without class ranking and without class screening.
  auto median_of = [](const std::string& name) {
    for (const Row& r : Rows()) {
      if (r.name == name) return r.median;
    }
    return std::nan("");
  };
  const double sope = median_of("BM_Recognise/sope");
  std::printf("\nmedian ratio BM_Recognise/sope / sope_no_class_ranking %.3f, "
              "/ sope_no_class_screening %.3f, / sope_one_screen_model %.3f\n",
              sope / median_of("BM_Recognise/sope_no_class_ranking"),
              sope / median_of("BM_Recognise/sope_no_class_screening"),
              sope / median_of("BM_Recognise/sope_one_screen_model"));
}

void RegisterAll() {
  const int iterations = kQueries * Passes();
  RecognitionOptions sope_options;
  RecognitionOptions rank_only;
  rank_only.screening.models = 0;
  const RecognitionOptions thesis_mlh = RecognitionOptions::ThesisPreset(HashMethod::kMinimalLoss);
  const RecognitionOptions thesis_itq = RecognitionOptions::ThesisPreset(HashMethod::kItq);
  auto add = [&](const std::string& name, auto&&... args) {
    benchmark::RegisterBenchmark(name.c_str(), args...)
        ->Iterations(iterations)
        ->Unit(benchmark::kMillisecond);
  };
  add("BM_Recognise/sope", BM_Recognise, std::string("BM_Recognise/sope"), false, sope_options);
  // The same without class-aware ranking (issue 16): its cost, side by side.
  RecognitionOptions no_class_ranking;
  no_class_ranking.assembly.class_ranking = false;
  add("BM_Recognise/sope_no_class_ranking", BM_Recognise,
      std::string("BM_Recognise/sope_no_class_ranking"), false, no_class_ranking);
  // Class ranking without the class screening (AssemblyOptions::class_screen_classes 0):
  // the cost of the extra refined hypothesis per class, side by side.
  RecognitionOptions no_class_screening;
  no_class_screening.assembly.class_screen_classes = 0;
  add("BM_Recognise/sope_no_class_screening", BM_Recognise,
      std::string("BM_Recognise/sope_no_class_screening"), false, no_class_screening);
  // One model screened per runner-up class (the default before 1266af1 was 1, now 2): the
  // cost of the second model, side by side.
  RecognitionOptions one_screen_model;
  one_screen_model.assembly.class_screen_models = 1;
  add("BM_Recognise/sope_one_screen_model", BM_Recognise,
      std::string("BM_Recognise/sope_one_screen_model"), false, one_screen_model);
  add("BM_Recognise/thesis", BM_Recognise, std::string("BM_Recognise/thesis"), true, thesis_mlh);
  add("BM_Recognise/thesis_opts_sope_db", BM_Recognise,
      std::string("BM_Recognise/thesis_opts_sope_db"), false, thesis_itq);
  add("BM_FineStage/sope_rank", BM_Recognise, std::string("BM_FineStage/sope_rank"), false,
      rank_only);
  add("BM_StagesAlone/fine+screen+refine", BM_StagesAlone);
  add("BM_FineStage/pcl_vfh_flann", BM_PclVfhFlann, false);
  add("BM_FineStage/pcl_vfh_flann_linear", BM_PclVfhFlann, true);
  add("BM_FineStage/flann_on_sope_vfh", BM_FlannOnSopeVfh);
}

}  // namespace
}  // namespace sope

int main(int argc, char** argv) {
  // Nothing may run in parallel: no OpenMP pool (Eigen, PCL) beyond the calling thread.
  setenv("OMP_NUM_THREADS", "1", 1);
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  sope::bench::DisplayReporter reporter(isatty(fileno(stdout))
                                            ? benchmark::ConsoleReporter::OO_Defaults
                                            : benchmark::ConsoleReporter::OO_Tabular);
  sope::GetData();  // build or load the databases and render the queries before timing
  sope::RegisterAll();
  benchmark::RunSpecifiedBenchmarks(&reporter);
  sope::PrintSummary();
  benchmark::Shutdown();
  return 0;
}
