// Recogniser pre-processing and features on a realistic view: a procedural bottle rendered
// by the depth camera at 0.45 m (≈ 100k points). Prints per-call times of
//  - Preprocess (range band, voxel grid, outlier removal, normals, normalisation) vs the
//    same stages with PCL (VoxelGrid → StatisticalOutlierRemoval → NormalEstimation with a
//    k-d tree), on the same input;
//  - ComputeFeatures (default options, the thesis preset, CVFH, OUR-CVFH) on the
//    pre-processed view (≈ 1.5k points), and its parts (KDE, Bézier fit, VFH).
// GCC 12 reports Eigen's AVX-512 kernels as maybe-uninitialised under -march=native; a known
// false positive (as in hashing.cc).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif

#include <cmath>
#include <cstdio>

#include <benchmark/benchmark.h>
#include <pcl/features/normal_3d.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/search/kdtree.h>

#include "bench/bench_support.h"
#include "core/camera_model.h"
#include "core/rigid3d.h"
#include "core/units.h"
#include "recogniser/features.h"
#include "recogniser/preprocess.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {


const PointCloud& BottleView() {
  static const PointCloud cloud = [] {
    const CameraModel camera = MakePinhole(1280, 960, 50.0 * kPi / 180.0);
    DepthRenderer renderer(camera);
    renderer.SetMesh(MakeObject(ObjectClass::kBottle, 3));
    // Bottle lying across the view, seen slightly from above, 0.45 m away.
    const Rigid3d cam_from_model(RotationFromEulerXYZ(-1.2, 0.0, 0.4),
                                 Eigen::Vector3d(-0.02, 0.03, 0.45));
    PointCloud view = renderer.Render(cam_from_model);
    view.normals.clear();
    std::printf("bottle view: %zu points\n", view.size());
    return view;
  }();
  return cloud;
}

// A large object, as the instance protocol's CrackerBox (16 × 21 cm faces, 90k–270k points,
// pre-processing 2–3× the median query's): a procedural box scaled ×2.2 about its centre,
// two faces seen at 0.45 m.
const PointCloud& LargeBoxView() {
  static const PointCloud cloud = [] {
    const CameraModel camera = MakePinhole(1280, 960, 50.0 * kPi / 180.0);
    DepthRenderer renderer(camera);
    TriangleMesh box = MakeObject(ObjectClass::kBox, 2);
    const Eigen::Vector3d centre = box.SurfaceCentroid();
    box.Transform(0.8, -0.8 * centre);
    renderer.SetMesh(box);
    const Rigid3d cam_from_model(RotationFromEulerXYZ(-0.9, 0.0, 0.6),
                                 Eigen::Vector3d(0.0, 0.0, 0.6));
    PointCloud view = renderer.Render(cam_from_model);
    view.normals.clear();
    std::printf("large box view: %zu points\n", view.size());
    return view;
  }();
  return cloud;
}

const PreprocessedCloud& PreprocessedBottle() {
  static const PreprocessedCloud view = [] {
    PreprocessedCloud result = Preprocess(BottleView());
    std::printf("pre-processed: %s\n", result.summary.BriefReport().c_str());
    return result;
  }();
  return view;
}

void BM_Preprocess(benchmark::State& state) {
  const PointCloud& cloud = BottleView();
  for (auto _ : state) {
    PreprocessedCloud result = Preprocess(cloud);
    benchmark::DoNotOptimize(result.radius);
  }
  state.counters["input_points"] = static_cast<double>(cloud.size());
}
BENCHMARK(BM_Preprocess)->Unit(benchmark::kMillisecond);

void BM_Preprocess_LargeBox(benchmark::State& state) {
  const PointCloud& cloud = LargeBoxView();
  PreprocessSummary summary;
  for (auto _ : state) {
    PreprocessedCloud result = Preprocess(cloud);
    summary = result.summary;
    benchmark::DoNotOptimize(result.radius);
  }
  state.counters["input_points"] = static_cast<double>(cloud.size());
  state.counters["voxel_points"] = static_cast<double>(summary.voxel_points);
}
BENCHMARK(BM_Preprocess_LargeBox)->Unit(benchmark::kMillisecond);

// Peer: PCL's filters and normals on the same input and parameters (without the
// normalisation, which is negligible).
void BM_PclPreprocessStages(benchmark::State& state) {
  const PointCloud& cloud = BottleView();
  const PreprocessOptions options;
  size_t out_points = 0;
  for (auto _ : state) {
    auto xyz = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    xyz->reserve(cloud.size());
    for (const Eigen::Vector3f& p : cloud.points) {
      const float r = p.norm();
      if (std::isfinite(r) && r >= options.min_range && r <= options.max_range) {
        xyz->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
      }
    }
    auto voxels = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    pcl::VoxelGrid<pcl::PointXYZ> grid;
    const float leaf = static_cast<float>(options.voxel_leaf);
    grid.setLeafSize(leaf, leaf, leaf);
    grid.setInputCloud(xyz);
    grid.filter(*voxels);
    auto inliers = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
    sor.setMeanK(options.outlier_neighbours);
    sor.setStddevMulThresh(options.outlier_stddev);
    sor.setInputCloud(voxels);
    sor.filter(*inliers);
    pcl::PointCloud<pcl::Normal> normals;
    pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal> estimator;
    estimator.setSearchMethod(pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
    estimator.setKSearch(options.normal_neighbours);
    estimator.setViewPoint(0.0f, 0.0f, 0.0f);
    estimator.setInputCloud(inliers);
    estimator.compute(normals);
    out_points = normals.size();
    benchmark::DoNotOptimize(out_points);
  }
  state.counters["output_points"] = static_cast<double>(out_points);
}
BENCHMARK(BM_PclPreprocessStages)->Unit(benchmark::kMillisecond);

void RunFeatures(benchmark::State& state, const FeatureOptions& options) {
  const PreprocessedCloud& view = PreprocessedBottle();
  for (auto _ : state) {
    ViewFeatures features = ComputeFeatures(view, options);
    benchmark::DoNotOptimize(features.coarse.data());
  }
  state.counters["points"] = static_cast<double>(view.cloud.size());
  state.counters["coarse_dims"] = CoarseDimension(options);
}

void BM_ComputeFeatures_Default(benchmark::State& state) { RunFeatures(state, FeatureOptions()); }
BENCHMARK(BM_ComputeFeatures_Default)->Unit(benchmark::kMillisecond);

void BM_ComputeFeatures_ThesisPreset(benchmark::State& state) {
  RunFeatures(state, FeatureOptions::ThesisPreset());
}
BENCHMARK(BM_ComputeFeatures_ThesisPreset)->Unit(benchmark::kMillisecond);

void BM_ComputeFeatures_Cvfh(benchmark::State& state) {
  FeatureOptions options;
  options.fine = FineDescriptor::kCvfh;
  RunFeatures(state, options);
}
BENCHMARK(BM_ComputeFeatures_Cvfh)->Unit(benchmark::kMillisecond);

void BM_ComputeFeatures_OurCvfh(benchmark::State& state) {
  FeatureOptions options;
  options.fine = FineDescriptor::kOurCvfh;
  RunFeatures(state, options);
}
BENCHMARK(BM_ComputeFeatures_OurCvfh)->Unit(benchmark::kMillisecond);

// Parts.
void BM_KernelDensity_R(benchmark::State& state) {
  const PreprocessedCloud& view = PreprocessedBottle();
  std::vector<float> radial;
  for (const Eigen::Vector3f& p : view.normalised.points) radial.push_back(p.norm());
  const FeatureOptions options;
  for (auto _ : state) {
    Eigen::VectorXf density = KernelDensity(radial, 0.0f, 1.0f, options.kde_samples,
                                            static_cast<float>(options.kde_bandwidth));
    benchmark::DoNotOptimize(density.data());
  }
}
BENCHMARK(BM_KernelDensity_R)->Unit(benchmark::kMicrosecond);

void BM_FitBezierPatch(benchmark::State& state) {
  const PreprocessedCloud& view = PreprocessedBottle();
  std::vector<Eigen::Vector3f> points;
  const size_t n = view.normalised.size(), wanted = std::min<size_t>(n, 768);
  for (size_t k = 0; k < wanted; ++k) points.push_back(view.normalised.points[k * n / wanted]);
  for (auto _ : state) {
    BezierPatch patch = FitBezierPatch(points, 3, 3, 10);
    benchmark::DoNotOptimize(patch.rms_residual);
  }
  state.counters["points"] = static_cast<double>(points.size());
}
BENCHMARK(BM_FitBezierPatch)->Unit(benchmark::kMicrosecond);

void BM_ComputeFeatures_VfhOnly(benchmark::State& state) {
  FeatureOptions options;
  options.bezier_order_u = options.bezier_order_v = 0;
  options.metric_size = false;
  RunFeatures(state, options);
}
BENCHMARK(BM_ComputeFeatures_VfhOnly)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace sope

SOPE_BENCHMARK_MAIN();
