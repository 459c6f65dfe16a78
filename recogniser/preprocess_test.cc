// Pre-processing against ground truth: constructed clouds whose filtered result is known,
// analytic sphere caps, rendered views of a sphere, and PCL's own filters as the reference
// for the stages whose semantics we reproduce (VoxelGrid, StatisticalOutlierRemoval,
// NormalEstimation, ConditionalRemoval on ‖p‖).
// GCC 12 reports Eigen's AVX-512 kernels as maybe-uninitialised under -march=native; a known
// false positive (as in hashing.cc).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif

#include "recogniser/preprocess.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <pcl/features/normal_3d.h>
#include <pcl/filters/conditional_removal.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/search/kdtree.h>

#include "core/camera_model.h"
#include "core/error.h"
#include "core/rigid3d.h"
#include "core/units.h"
#include "recogniser/cloud_filters.h"
#include "recogniser/pcl_convert.h"
#include "simulator/primitives.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"
#include "tests/test_support.h"

namespace sope {
namespace {

using Eigen::Vector3d;
using Eigen::Vector3f;

constexpr float kNan = std::numeric_limits<float>::quiet_NaN();

// Expects `statement` to throw sope::Error whose one-line message contains `fragment`.
#define EXPECT_ERROR_WITH(statement, fragment)                         \
  do {                                                                 \
    try {                                                              \
      statement;                                                       \
      ADD_FAILURE() << "no sope::Error from " #statement;              \
    } catch (const ::sope::Error& error) {                             \
      const std::string message = error.what();                        \
      EXPECT_NE(message.find(fragment), std::string::npos) << message; \
      EXPECT_EQ(message.find('\n'), std::string::npos) << message;     \
    }                                                                  \
  } while (false)

double AngleBetween(const Vector3d& a, const Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

// A view of `mesh` by an ideal depth camera (640×480, 60° horizontal field of view).
PointCloud RenderView(const TriangleMesh& mesh, const Rigid3d& cam_from_model,
                      const CameraModel& camera = MakePinhole(640, 480, 60.0 * kPi / 180.0)) {
  DepthRenderer renderer(camera);
  renderer.SetMesh(mesh);
  return renderer.Render(cam_from_model);
}

// Area-uniform samples of the spherical cap of `radius` about `centre` seen from the origin
// (the cap of points whose normal makes an angle ≤ `half_angle` with the direction to the
// sensor), by a Fibonacci spiral: cos θ uniform in [cos α, 1].
std::vector<Vector3f> SphereCap(const Vector3d& centre, double radius, double half_angle, int n) {
  const Vector3d axis = -centre.normalized();  // towards the sensor
  const Vector3d e1 = axis.unitOrthogonal(), e2 = axis.cross(e1);
  const double golden = kPi * (3.0 - std::sqrt(5.0));
  std::vector<Vector3f> points;
  for (int i = 0; i < n; ++i) {
    const double cos_theta = 1.0 - (1.0 - std::cos(half_angle)) * (i + 0.5) / n;
    const double sin_theta = std::sqrt(std::max(0.0, 1.0 - cos_theta * cos_theta));
    const double phi = golden * i;
    const Vector3d direction =
        cos_theta * axis + sin_theta * (std::cos(phi) * e1 + std::sin(phi) * e2);
    points.push_back((centre + radius * direction).cast<float>());
  }
  return points;
}

// Brute-force k nearest (self first, then by (float squared distance, index)).
std::vector<int32_t> BruteForceKnn(const std::vector<Vector3f>& points, size_t i, int k) {
  std::vector<std::pair<float, int32_t>> all;
  for (size_t j = 0; j < points.size(); ++j) {
    if (j == i) continue;
    const float dx = points[j].x() - points[i].x(), dy = points[j].y() - points[i].y(),
                dz = points[j].z() - points[i].z();
    all.emplace_back(dx * dx + dy * dy + dz * dz, static_cast<int32_t>(j));
  }
  const size_t keep = std::min<size_t>(all.size(), static_cast<size_t>(std::max(k - 1, 0)));
  std::partial_sort(all.begin(), all.begin() + keep, all.end());
  std::vector<int32_t> result = {static_cast<int32_t>(i)};
  for (int j = 0; j + 1 < k && j < static_cast<int>(all.size()); ++j)
    result.push_back(all[j].second);
  return result;
}

// ---------------------------------------------------------------------------------------
// Options and enums

TEST(PreprocessOptions, DefaultsAreValidAndInvalidValuesAreNamed) {
  EXPECT_NO_THROW(PreprocessOptions().Check());
  auto expect_invalid = [](auto mutate, const char* field) {
    PreprocessOptions options;
    mutate(options);
    EXPECT_ERROR_WITH(options.Check(), field);
  };
  expect_invalid([](PreprocessOptions& o) { o.min_range = -0.1; }, "min_range");
  expect_invalid([](PreprocessOptions& o) { o.max_range = 0.01; }, "max_range");
  expect_invalid([](PreprocessOptions& o) { o.max_range = INFINITY; }, "max_range");
  expect_invalid([](PreprocessOptions& o) { o.outlier_neighbours = -1; }, "outlier_neighbours");
  expect_invalid([](PreprocessOptions& o) { o.outlier_stddev = 0.0; }, "outlier_stddev");
  expect_invalid([](PreprocessOptions& o) { o.outlier_min_ratio = -1.0; }, "outlier_min_ratio");
  expect_invalid([](PreprocessOptions& o) { o.voxel_leaf = -0.001; }, "voxel_leaf");
  expect_invalid([](PreprocessOptions& o) { o.voxel_leaf = 1e-9; }, "voxel_leaf");
  expect_invalid([](PreprocessOptions& o) { o.normal_neighbours = 2; }, "normal_neighbours");
  expect_invalid([](PreprocessOptions& o) { o.median_fraction = 1.0; }, "median_fraction");
  expect_invalid([](PreprocessOptions& o) { o.min_points = 2; }, "min_points");
  PreprocessOptions disabled;
  disabled.outlier_neighbours = 0;
  disabled.outlier_stddev = 0.0;  // ignored when outlier removal is off
  disabled.voxel_leaf = 0.0;
  EXPECT_NO_THROW(disabled.Check());
}

TEST(ScaleNormalisation, StringsRoundTrip) {
  for (ScaleNormalisation mode : {ScaleNormalisation::kFarthest, ScaleNormalisation::kMedian}) {
    EXPECT_EQ(ScaleNormalisationFromString(ToString(mode)), mode);
  }
  EXPECT_EQ(ToString(ScaleNormalisation::kFarthest), "farthest");
  EXPECT_EQ(ToString(ScaleNormalisation::kMedian), "median");
  EXPECT_ERROR_WITH(ScaleNormalisationFromString("mean"), "mean");
}

// ---------------------------------------------------------------------------------------
// Bad inputs

TEST(Preprocess, RejectsBadInputsWithOneClearLine) {
  EXPECT_ERROR_WITH(Preprocess(PointCloud()), "empty");

  PointCloud nan_only;
  nan_only.points.assign(500, Vector3f(kNan, 0.0f, 0.5f));
  nan_only.points.push_back(Vector3f(INFINITY, 0.0f, 0.5f));
  EXPECT_ERROR_WITH(Preprocess(nan_only), "none of the 501 input points is finite");

  PointCloud far_away;
  for (int i = 0; i < 300; ++i) far_away.points.emplace_back(0.001f * i, 0.0f, 5.0f);
  EXPECT_ERROR_WITH(Preprocess(far_away), "outside the range band");

  // A tiny cloud: 20 points of a plane, fewer than min_points = 50.
  PointCloud tiny;
  for (int i = 0; i < 20; ++i) tiny.points.emplace_back(0.01f * (i % 5), 0.01f * (i / 5), 0.5f);
  EXPECT_ERROR_WITH(Preprocess(tiny), "only 20 points left, fewer than min_points = 50");

  // A plane of 60 × 60 points 1 mm apart, thinned by a 2 cm voxel grid to 9 points: the
  // message names the stage.
  PointCloud thinned;
  for (int i = 0; i < 3600; ++i) {
    thinned.points.emplace_back(0.001f * (i % 60) + 0.0005f, 0.001f * (i / 60) + 0.0005f, 0.5f);
  }
  PreprocessOptions coarse;
  coarse.voxel_leaf = 0.02;
  EXPECT_ERROR_WITH(Preprocess(thinned, coarse), "3600 in range band → 9 after voxel grid");

  PointCloud mismatched = thinned;
  mismatched.normals.assign(10, Vector3f::UnitZ());
  EXPECT_THROW_WITH_MESSAGE(Preprocess(mismatched), Error, "10 normals for");

  PreprocessOptions invalid;
  invalid.normal_neighbours = 1;
  EXPECT_ERROR_WITH(Preprocess(thinned, invalid), "normal_neighbours");
}

// ---------------------------------------------------------------------------------------
// Range band

// A ramp: a strip of points going away from the camera from 1 cm to 3 m, plus NaNs.
PointCloud Ramp() {
  PointCloud ramp;
  for (int j = 0; j < 1500; ++j) {
    for (int i = 0; i < 20; ++i) {
      const float z = 0.01f + 0.002f * j;
      ramp.points.emplace_back(-0.02f + 0.002f * i + 0.0001f * j, 0.05f, z);
    }
    if (j % 100 == 0) ramp.points.emplace_back(kNan, kNan, kNan);
  }
  return ramp;
}

TEST(Preprocess, RangeBandKeepsExactlyThePointsInTheBand) {
  const PointCloud ramp = Ramp();
  PreprocessOptions options;
  options.min_range = 0.3;
  options.max_range = 1.7;
  options.voxel_leaf = 0.0;
  options.outlier_neighbours = 0;
  size_t expected = 0;
  for (const Vector3f& p : ramp.points) {
    const double r = p.cast<double>().norm();
    expected += std::isfinite(r) && r >= options.min_range && r <= options.max_range;
  }
  const PreprocessedCloud result = Preprocess(ramp, options);
  EXPECT_EQ(result.cloud.size(), expected);
  EXPECT_EQ(result.summary.input_points, static_cast<int64_t>(ramp.size()));
  EXPECT_EQ(result.summary.finite_points, static_cast<int64_t>(ramp.size()) - 15);
  EXPECT_EQ(result.summary.in_range_points, static_cast<int64_t>(expected));
  for (const Vector3f& p : result.cloud.points) {
    EXPECT_GE(p.norm(), options.min_range - 1e-6);
    EXPECT_LE(p.norm(), options.max_range + 1e-6);
  }

  // PCL's ConditionalRemoval with the quadratic condition ‖p‖² ∈ [min², max²] agrees.
  auto xyz = internal::ToPclXyz(ramp);
  auto condition = pcl::make_shared<pcl::ConditionAnd<pcl::PointXYZ>>();
  const Eigen::Matrix3f identity = Eigen::Matrix3f::Identity();
  const float min_sq = static_cast<float>(options.min_range * options.min_range);
  const float max_sq = static_cast<float>(options.max_range * options.max_range);
  condition->addComparison(pcl::make_shared<pcl::TfQuadraticXYZComparison<pcl::PointXYZ>>(
      pcl::ComparisonOps::GE, identity, Eigen::Vector3f::Zero(), -min_sq));
  condition->addComparison(pcl::make_shared<pcl::TfQuadraticXYZComparison<pcl::PointXYZ>>(
      pcl::ComparisonOps::LE, identity, Eigen::Vector3f::Zero(), -max_sq));
  pcl::ConditionalRemoval<pcl::PointXYZ> removal;
  removal.setCondition(condition);
  removal.setInputCloud(xyz);
  pcl::PointCloud<pcl::PointXYZ> kept;
  removal.filter(kept);
  EXPECT_EQ(kept.size(), expected);
}

// ---------------------------------------------------------------------------------------
// Voxel grid, neighbours, outlier removal, normals against PCL

TEST(VoxelGrid, MatchesPclVoxelGridIncludingOrder) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> uniform(-0.15f, 0.15f);
  std::vector<Vector3f> points;
  for (int i = 0; i < 20000; ++i)
    points.emplace_back(uniform(rng), uniform(rng), 0.6f + uniform(rng));
  for (float leaf : {0.004f, 0.007f, 0.03f}) {
    std::vector<uint32_t> counts;
    const std::vector<Vector3f> ours = internal::VoxelGridCentroids(points, leaf, &counts);
    PointCloud cloud;
    cloud.points = points;
    pcl::VoxelGrid<pcl::PointXYZ> grid;
    grid.setLeafSize(leaf, leaf, leaf);
    grid.setInputCloud(internal::ToPclXyz(cloud));
    pcl::PointCloud<pcl::PointXYZ> reference;
    grid.filter(reference);
    ASSERT_EQ(ours.size(), reference.size()) << "leaf " << leaf;
    double worst = 0.0;
    for (size_t i = 0; i < ours.size(); ++i) {
      worst = std::max(worst, (ours[i] - reference[i].getVector3fMap()).cast<double>().norm());
    }
    EXPECT_LT(worst, 1e-6) << "leaf " << leaf;
    uint64_t total = 0;
    for (uint32_t c : counts) total += c;
    EXPECT_EQ(total, points.size());
  }
  EXPECT_THROW_WITH_MESSAGE(internal::VoxelGridCentroids(points, 0.0f), Error, "leaf", "got 0");
}

// The band-filtered grid (Preprocess's one pass) gives the centroids and counts of the grid
// on the points filtered first, bit for bit, and counts the finite and in-band points.
TEST(VoxelGrid, InBandEqualsTheGridOfTheFilteredPoints) {
  std::mt19937 rng(8);
  std::uniform_real_distribution<float> uniform(-0.4f, 0.4f);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<Vector3f> points;
  for (int i = 0; i < 30000; ++i) {
    points.emplace_back(uniform(rng), uniform(rng), 0.7f + uniform(rng));
    if (i % 97 == 0) points.emplace_back(nan, 0.1f, 0.5f);
    if (i % 89 == 0) points.emplace_back(0.1f, std::numeric_limits<float>::infinity(), 0.5f);
  }
  const double min_range = 0.5, max_range = 0.9;
  std::vector<Vector3f> kept;
  int64_t finite = 0;
  for (const Vector3f& p : points) {
    if (!p.allFinite()) continue;
    ++finite;
    const double sq = p.cast<double>().squaredNorm();
    if (sq >= min_range * min_range && sq <= max_range * max_range) kept.push_back(p);
  }
  ASSERT_GT(kept.size(), 1000u);
  ASSERT_LT(kept.size(), static_cast<size_t>(finite));
  for (float leaf : {0.004f, 0.02f}) {
    std::vector<uint32_t> expected_counts, counts;
    const std::vector<Vector3f> expected =
        internal::VoxelGridCentroids(kept, leaf, &expected_counts);
    int64_t got_finite = -1, got_in_band = -1;
    const std::vector<Vector3f> got = internal::VoxelGridCentroidsInBand(
        points, leaf, min_range * min_range, max_range * max_range, &counts, &got_finite,
        &got_in_band);
    EXPECT_EQ(got, expected) << "leaf " << leaf;
    EXPECT_EQ(counts, expected_counts) << "leaf " << leaf;
    EXPECT_EQ(got_finite, finite);
    EXPECT_EQ(got_in_band, static_cast<int64_t>(kept.size()));
  }
}

// Points beyond the packed keys' reach (2^20 leaves from the origin) or not finite are an
// error where they would be gridded, and dropped silently where the band drops them.
TEST(VoxelGrid, PointsOutOfReachAreAnErrorUnlessTheBandDropsThem) {
  std::vector<Vector3f> points(3000, Vector3f(0.1f, 0.0f, 0.6f));
  for (size_t i = 0; i < points.size(); ++i) points[i].x() += 0.0001f * static_cast<float>(i);
  const float leaf = 0.004f;  // 2^20 leaves ≈ 4.2 km
  std::vector<Vector3f> far = points;
  far[2500] = Vector3f(0.1f, -5000.0f, 0.6f);
  EXPECT_THROW_WITH_MESSAGE(internal::VoxelGridCentroids(far, leaf), Error, "2^20 leaves",
                            "-5000");
  std::vector<Vector3f> not_finite = points;
  not_finite[1700].z() = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW_WITH_MESSAGE(internal::VoxelGridCentroids(not_finite, leaf), Error,
                            "2^20 leaves", "nan");
  // In a band of 0.5–2 m: the far point and the NaN are dropped; a point in the band but
  // out of reach (a leaf so small that 1 m is beyond 2^20 of them) is still an error.
  for (const auto& [input, dropped] : {std::pair(&far, 2500), std::pair(&not_finite, 1700)}) {
    std::vector<Vector3f> kept = points;
    kept.erase(kept.begin() + dropped);
    int64_t finite = 0, in_band = 0;
    const std::vector<Vector3f> centroids = internal::VoxelGridCentroidsInBand(
        *input, leaf, 0.25, 4.0, nullptr, &finite, &in_band);
    EXPECT_EQ(in_band, 2999);
    EXPECT_EQ(finite, input == &far ? 3000 : 2999);
    EXPECT_EQ(centroids, internal::VoxelGridCentroids(kept, leaf));
  }
  EXPECT_THROW_WITH_MESSAGE(
      internal::VoxelGridCentroidsInBand(points, 1e-7f, 0.25, 4.0, nullptr, nullptr, nullptr),
      Error, "2^20 leaves", "0.6");
}

TEST(NeighbourGrid, AllKNearestEqualsBruteForce) {
  std::mt19937 rng(11);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  std::uniform_real_distribution<float> uniform(0.0f, 1.0f);
  std::vector<std::pair<std::string, std::vector<Vector3f>>> clouds;
  {
    std::vector<Vector3f> shell;  // surface samples with noise
    for (int i = 0; i < 3000; ++i) {
      Vector3f d(normal(rng), normal(rng), normal(rng));
      shell.push_back(0.1f * d.normalized() + Vector3f(0.0f, 0.0f, 0.5f) +
                      0.0005f * Vector3f(normal(rng), normal(rng), normal(rng)));
    }
    clouds.emplace_back("shell", shell);
  }
  {
    std::vector<Vector3f> volume;
    for (int i = 0; i < 2000; ++i) volume.emplace_back(uniform(rng), uniform(rng), uniform(rng));
    clouds.emplace_back("volume", volume);
  }
  {
    std::vector<Vector3f> clustered;  // dense patch plus far isolated points (slow path)
    for (int i = 0; i < 1500; ++i)
      clustered.emplace_back(0.05f * uniform(rng), 0.05f * uniform(rng), 0.6f);
    for (int i = 0; i < 40; ++i)
      clustered.emplace_back(2.0f * uniform(rng) - 1.0f, uniform(rng), 2.0f * uniform(rng));
    clouds.emplace_back("clustered", clustered);
  }
  {
    std::vector<Vector3f> duplicates;  // coincident points: self must still come first
    for (int i = 0; i < 400; ++i) {
      const Vector3f p(0.01f * (i % 20), 0.01f * (i / 20), 0.5f);
      duplicates.push_back(p);
      if (i % 3 == 0) duplicates.push_back(p);
    }
    clouds.emplace_back("duplicates", duplicates);
  }
  for (const auto& [name, points] : clouds) {
    const internal::NeighbourGrid grid(points, 17);
    std::vector<std::vector<int32_t>> expected(points.size());
    for (size_t i = 0; i < points.size(); ++i) expected[i] = BruteForceKnn(points, i, 40);
    for (int k : {1, 2, 7, 17, 40}) {
      const internal::NeighbourTable table = grid.AllKNearest(k);
      ASSERT_EQ(table.size(), points.size());
      // Self first, then neighbours at the brute force's distances, rank by rank. Indices
      // may differ only between points at the same distance: the library and this file
      // may round a squared distance differently (FMA contraction differs between -O1 and
      // -O3), which reorders exact ties such as the duplicates' grid spacings.
      int mismatches = 0;
      for (size_t i = 0; i < points.size(); ++i) {
        const size_t count = std::min<size_t>(k, expected[i].size());
        bool same = static_cast<size_t>(table.count) == count && table.row(i)[0] == expected[i][0];
        for (size_t j = 1; same && j < count; ++j) {
          const double want = (points[expected[i][j]] - points[i]).cast<double>().norm();
          const double got = (points[table.row(i)[j]] - points[i]).cast<double>().norm();
          same = std::abs(got - want) <= 1e-6 * want + 1e-12;
        }
        mismatches += !same;
      }
      EXPECT_EQ(mismatches, 0) << name << " k = " << k;
    }
    // Arbitrary query points, inside and outside the cloud's box.
    std::vector<int32_t> indices;
    std::vector<float> distances;
    for (int q = 0; q < 200; ++q) {
      const Vector3f query(3.0f * uniform(rng) - 1.5f, 3.0f * uniform(rng) - 1.5f,
                           3.0f * uniform(rng) - 1.0f);
      grid.KNearest(query, 5, &indices, &distances);
      std::vector<std::pair<float, int32_t>> all;
      for (size_t j = 0; j < points.size(); ++j) {
        const Vector3f d = points[j] - query;
        all.emplace_back(d.x() * d.x() + d.y() * d.y() + d.z() * d.z(), static_cast<int32_t>(j));
      }
      std::sort(all.begin(), all.end());
      ASSERT_EQ(indices.size(), 5u);
      for (int j = 0; j < 5; ++j) EXPECT_EQ(indices[j], all[j].second) << name;
    }
  }
  // Fewer points than k.
  const std::vector<Vector3f> three = {Vector3f(0, 0, 0), Vector3f(1, 0, 0), Vector3f(0, 2, 0)};
  const internal::NeighbourTable small = internal::NeighbourGrid(three).AllKNearest(10);
  EXPECT_EQ(small.count, 3);
  EXPECT_EQ(std::vector<int32_t>(small.row(2), small.row(2) + 3), (std::vector<int32_t>{2, 0, 1}));
}

// Random samples of a wavy surface z = 0.6 + 0.02 sin(20x) cos(15y) with a little noise.
std::vector<Vector3f> WavySurface(int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> uniform(-0.1f, 0.1f);
  std::normal_distribution<float> noise(0.0f, 0.0003f);
  std::vector<Vector3f> points;
  for (int i = 0; i < n; ++i) {
    const float x = uniform(rng), y = uniform(rng);
    points.emplace_back(x, y,
                        0.6f + 0.02f * std::sin(20.0f * x) * std::cos(15.0f * y) + noise(rng));
  }
  return points;
}

TEST(StatisticalOutlierRemoval, MatchesPclAndRemovesInjectedOutliers) {
  std::vector<Vector3f> points = WavySurface(4000, 3);
  const size_t inliers = points.size();
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> uniform(-0.15f, 0.15f);
  for (int i = 0; i < 40; ++i) {  // 1 % outliers, ≥ 3 cm off the surface
    const float x = uniform(rng), y = uniform(rng);
    const float offset = (i % 2 ? 1.0f : -1.0f) * (0.03f + 0.1f * std::abs(uniform(rng)));
    points.emplace_back(x, y, 0.6f + offset);
  }
  for (double multiplier : {1.0, 2.0}) {
    const internal::NeighbourGrid grid(points, 17);
    const std::vector<uint8_t> keep =
        internal::StatisticalInlierMask(grid.AllKNearest(17), 16, multiplier);
    PointCloud cloud;
    cloud.points = points;
    pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
    sor.setMeanK(16);
    sor.setStddevMulThresh(multiplier);
    sor.setInputCloud(internal::ToPclXyz(cloud));
    pcl::Indices kept;
    sor.filter(kept);
    std::vector<uint8_t> reference(points.size(), 0);
    for (int index : kept) reference[index] = 1;
    EXPECT_EQ(keep, reference) << "σ multiplier " << multiplier;
    size_t kept_inliers = 0, kept_outliers = 0;
    for (size_t i = 0; i < points.size(); ++i)
      (i < inliers ? kept_inliers : kept_outliers) += keep[i];
    EXPECT_EQ(kept_outliers, 0u) << "σ multiplier " << multiplier;
    if (multiplier == 2.0) {
      EXPECT_GE(kept_inliers, 0.99 * inliers);
    }
  }
}

TEST(Normals, MatchPclNormalEstimation) {
  const std::vector<Vector3f> points = WavySurface(3000, 9);
  const internal::NeighbourTable table = internal::NeighbourGrid(points, 12).AllKNearest(12);
  PointCloud cloud;
  cloud.points = points;
  pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal> estimator;
  estimator.setSearchMethod(pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
  estimator.setKSearch(12);
  estimator.setViewPoint(0.0f, 0.0f, 0.0f);
  estimator.setInputCloud(internal::ToPclXyz(cloud));
  pcl::PointCloud<pcl::Normal> reference;
  estimator.compute(reference);
  double worst_angle = 0.0, worst_curvature = 0.0;
  for (size_t i = 0; i < points.size(); ++i) {
    Vector3f normal;
    float curvature;
    ASSERT_TRUE(internal::FitNormal(points, table.row(i), table.count, points[i], Vector3f::Zero(),
                                    &normal, &curvature));
    EXPECT_LT(normal.dot(points[i]), 0.0f);  // faces the sensor at the origin
    worst_angle = std::max(
        worst_angle,
        AngleBetween(normal.cast<double>(), reference[i].getNormalVector3fMap().cast<double>()));
    worst_curvature =
        std::max(worst_curvature, std::abs(double(curvature) - reference[i].curvature));
  }
  EXPECT_LT(worst_angle, 1e-3);  // radians; PCL accumulates in float
  EXPECT_LT(worst_curvature, 1e-4);
}

// The normal fit's eigen solver against Eigen's iterative one (QR, the accurate
// reference) on covariances of every shape a neighbourhood takes: planes from flat to
// thick, at scales from 0.1 mm to 1 m, lines (a double smallest eigenvalue: the fallback),
// isotropic blobs (a triple one), exact planes (smallest eigenvalue 0) and a zero matrix.
TEST(Normals, SmallestEigenpairMatchesEigenAcrossShapes) {
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  int newton_cases = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    const Eigen::Matrix3d rotation =
        Eigen::Quaterniond(Eigen::Vector4d(unit(rng), unit(rng), unit(rng), unit(rng)).normalized())
            .toRotationMatrix();
    const double scale = std::pow(10.0, -4.0 + 4.0 * (trial % 97) / 96.0);  // 0.1 mm … 1 m
    Eigen::Vector3d spread;
    switch (trial % 5) {
      case 0: spread = Vector3d(1.0, 0.6, std::pow(10.0, -1.0 - 5.0 * (trial % 11) / 10.0)); break;
      case 1: spread = Vector3d(1.0, 1e-7, 1e-7); break;  // a line
      case 2: spread = Vector3d(1.0, 1.0, 1.0); break;    // isotropic
      case 3: spread = Vector3d(1.0, 0.9, 0.0); break;    // an exact plane
      default: spread = Vector3d(1.0, 0.3 + 0.5 * std::abs(unit(rng)), 0.05); break;
    }
    const Eigen::Matrix3d covariance =
        scale * scale * rotation * spread.cwiseAbs2().asDiagonal() * rotation.transpose();
    double value = 0.0;
    Eigen::Vector3d vector;
    ASSERT_TRUE(internal::SmallestEigenpair(covariance, &value, &vector)) << "trial " << trial;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> reference(covariance);
    const double trace = covariance.trace();
    // Everywhere within Eigen's direct solver's accuracy (the fallback's, and what the
    // normals used before); where the smallest eigenvalue is well apart (Newton's case:
    // (λ1 − λ0)(λ2 − λ0) > 1e-4 of the trace², and where the direction is defined) to
    // 1e-12 of the trace, the direction to 1e-9.
    EXPECT_NEAR(value / trace, reference.eigenvalues()[0] / trace, 1e-8) << "trial " << trial;
    EXPECT_NEAR(vector.norm(), 1.0, 1e-12) << "trial " << trial;
    const Eigen::Vector3d e = reference.eigenvalues() / trace;
    if ((e[1] - e[0]) * (e[2] - e[0]) > 1e-3) {
      ++newton_cases;
      EXPECT_NEAR(value / trace, e[0], 1e-12) << "trial " << trial;
      const double sine = vector.cross(reference.eigenvectors().col(0)).norm();
      EXPECT_LT(sine, 1e-9) << "trial " << trial << ", eigenvalues " << e.transpose();
    }
  }
  EXPECT_GT(newton_cases, 2000);
  double value = 0.0;
  Eigen::Vector3d vector;
  EXPECT_FALSE(internal::SmallestEigenpair(Eigen::Matrix3d::Zero(), &value, &vector));
}

// ---------------------------------------------------------------------------------------
// Whole pipeline against geometry

TEST(Preprocess, SphereViewNormalsAreRadialAndFaceTheSensor) {
  const double radius = 0.08;
  const Vector3d centre(0.03, -0.02, 0.5);
  const PointCloud view =
      RenderView(MakeSphere(radius, 90, 180), Rigid3d(Eigen::Matrix3d::Identity(), centre));
  ASSERT_GT(view.size(), 20000u);
  const PreprocessedCloud result = Preprocess(view);
  ASSERT_GT(result.cloud.size(), 500u);
  std::vector<double> angles;
  for (size_t i = 0; i < result.cloud.size(); ++i) {
    const Vector3d p = result.cloud.points[i].cast<double>();
    const Vector3d n = result.cloud.normals[i].cast<double>();
    EXPECT_NEAR(n.norm(), 1.0, 1e-5);
    EXPECT_GT(n.dot(-p), 0.0);
    angles.push_back(AngleBetween(n, p - centre));
    EXPECT_NEAR((p - centre).norm(), radius, 0.002);  // voxel centroids sit just inside
  }
  std::sort(angles.begin(), angles.end());
  const double median = angles[angles.size() / 2] * 180.0 / kPi;
  const double p95 = angles[angles.size() * 95 / 100] * 180.0 / kPi;
  RecordProperty("normal_error_median_deg", std::to_string(median));
  RecordProperty("normal_error_p95_deg", std::to_string(p95));
  EXPECT_LT(median, 1.0);
  EXPECT_LT(p95, 3.0);
  // Normalised copy: centred, unit scale, same normals.
  ASSERT_EQ(result.normalised.size(), result.cloud.size());
  for (size_t i = 0; i < result.cloud.size(); i += 37) {
    const Vector3f expected = (result.cloud.points[i] - result.centroid) / result.radius;
    EXPECT_LT((result.normalised.points[i] - expected).norm(), 1e-5f);
    EXPECT_EQ(result.normalised.normals[i], result.cloud.normals[i]);
  }
  EXPECT_EQ(result.curvature.size(), result.cloud.size());
}

TEST(Preprocess, FarthestAndMedianRadiusOfAnAnalyticSphereCap) {
  const double rho = 0.1;
  const Vector3d centre(0.05, 0.02, 0.6);
  const double alpha = std::acos(rho / centre.norm());  // the visible cap
  const std::vector<Vector3f> cap = SphereCap(centre, rho, alpha, 40000);
  PointCloud cloud;
  cloud.points = cap;
  // Area-uniform cap: centroid at ρ(1 + cos α)/2 from the centre towards the sensor; the
  // distance from it grows with θ, and cos θ is uniform, so its q-quantile is at
  // cos θ = 1 − q(1 − cos α).
  const double z_bar = (1.0 + std::cos(alpha)) / 2.0;
  const Vector3d true_centroid = centre - rho * z_bar * centre.normalized();
  auto distance_at_quantile = [&](double q) {
    const double c = 1.0 - q * (1.0 - std::cos(alpha));
    return rho * std::sqrt(1.0 - 2.0 * z_bar * c + z_bar * z_bar);
  };
  for (bool thinned : {false, true}) {
    PreprocessOptions options;
    options.voxel_leaf = thinned ? 0.004 : 0.0;
    options.outlier_neighbours = thinned ? options.outlier_neighbours : 0;
    const double tolerance = thinned ? 0.01 : 0.001;  // relative
    options.normalisation = ScaleNormalisation::kFarthest;
    const PreprocessedCloud farthest = Preprocess(cloud, options);
    EXPECT_LT((farthest.centroid.cast<double>() - true_centroid).norm(), tolerance * rho)
        << thinned;
    EXPECT_NEAR(farthest.radius, distance_at_quantile(1.0), tolerance * rho) << thinned;
    for (const Vector3f& p : farthest.normalised.points) EXPECT_LE(p.norm(), 1.0f + 1e-5f);
    for (double fraction : {0.5, 0.8}) {
      options.normalisation = ScaleNormalisation::kMedian;
      options.median_fraction = fraction;
      const PreprocessedCloud median = Preprocess(cloud, options);
      EXPECT_NEAR(median.radius, distance_at_quantile((1.0 + fraction) / 2.0), tolerance * rho)
          << "thinned " << thinned << " fraction " << fraction;
    }
  }
}

TEST(Preprocess, RemovesInjectedOutliersAndKeepsTheSurface) {
  // A rendered mug view (≈ 30k points at 0.3 m) plus 1 % isolated outliers ≥ 3 cm off the
  // surface — after the voxel grid they are ≈ 20 % of the points.
  const Rigid3d cam_from_model(RotationFromEulerXYZ(-2.0, 0.0, 0.5), Vector3d(0.0, 0.04, 0.3));
  const PointCloud clean = RenderView(MakeObject(ObjectClass::kMug, 1), cam_from_model);
  ASSERT_GT(clean.size(), 20000u);
  const internal::NeighbourGrid clean_grid(clean.points, 2);
  Vector3f lo = clean.points[0], hi = lo;
  for (const Vector3f& p : clean.points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  PointCloud noisy = clean;
  noisy.normals.clear();
  std::mt19937 rng(17);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  const Vector3f margin = Vector3f::Constant(0.08f);
  std::vector<int32_t> nearest;
  std::vector<float> sq_distance;
  const size_t outliers = clean.size() / 100;
  while (noisy.size() < clean.size() + outliers) {
    const Vector3f p =
        (lo - margin) +
        (hi - lo + 2.0f * margin).cwiseProduct(Vector3f(unit(rng), unit(rng), unit(rng)));
    clean_grid.KNearest(p, 1, &nearest, &sq_distance);
    if (sq_distance[0] > 0.03f * 0.03f) noisy.points.push_back(p);
  }
  const PreprocessedCloud reference = Preprocess(clean);
  const PreprocessedCloud result = Preprocess(noisy);
  int survivors = 0;
  for (const Vector3f& p : result.cloud.points) {
    clean_grid.KNearest(p, 1, &nearest, &sq_distance);
    survivors += std::sqrt(sq_distance[0]) > 0.01f;
  }
  RecordProperty("outlier_voxels_before_removal",
                 std::to_string(result.summary.voxel_points - reference.summary.voxel_points));
  RecordProperty("clean_view_voxels", std::to_string(reference.summary.voxel_points));
  RecordProperty("clean_view_voxels_kept", std::to_string(reference.summary.inlier_points));
  RecordProperty("noisy_view_surface_points_kept", std::to_string(result.cloud.size() - survivors));
  EXPECT_EQ(survivors, 0);
  EXPECT_GE(static_cast<double>(result.cloud.size()), 0.99 * reference.cloud.size());
  // The clean view keeps ≥ 99 % of its voxels; PCL's rule alone (mean + 2σ, no floor) strips
  // its silhouette.
  EXPECT_GE(static_cast<double>(reference.summary.inlier_points),
            0.99 * reference.summary.voxel_points);
  PreprocessOptions pcl_rule;
  pcl_rule.outlier_min_ratio = 0.0;
  const PreprocessedCloud eroded = Preprocess(clean, pcl_rule);
  RecordProperty("clean_view_voxels_kept_without_floor",
                 std::to_string(eroded.summary.inlier_points));
  EXPECT_LT(static_cast<double>(eroded.summary.inlier_points), 0.97 * eroded.summary.voxel_points);
}

TEST(Preprocess, IsDeterministicAndIgnoresInputNormalsAndColours) {
  const PointCloud view =
      RenderView(MakeObject(ObjectClass::kBowl, 2),
                 Rigid3d(RotationFromEulerXYZ(-2.3, 0.1, 0.3), Vector3d(0.0, 0.0, 0.5)));
  const PreprocessedCloud a = Preprocess(view);
  PointCloud stripped = view;
  stripped.normals.clear();
  stripped.colors.assign(view.size(), Color3ub(10, 20, 30));
  const PreprocessedCloud b = Preprocess(stripped);
  ASSERT_EQ(a.cloud.size(), b.cloud.size());
  EXPECT_EQ(0, std::memcmp(a.cloud.points.data(), b.cloud.points.data(),
                           a.cloud.size() * sizeof(Vector3f)));
  EXPECT_EQ(0, std::memcmp(a.cloud.normals.data(), b.cloud.normals.data(),
                           a.cloud.size() * sizeof(Vector3f)));
  EXPECT_EQ(0, std::memcmp(a.normalised.points.data(), b.normalised.points.data(),
                           a.cloud.size() * sizeof(Vector3f)));
  EXPECT_EQ(a.radius, b.radius);
  EXPECT_EQ(a.centroid, b.centroid);
  EXPECT_FALSE(b.cloud.HasColors());
}

// Issue 13: 2,000,000 uniform random points in a cube (a volume: the 4 mm voxel grid keeps
// nearly all of them) made the neighbour stages super-linear (> 120 s). The voxel stage now
// hands on at most 100,000 points, coarsening its leaf; the result is still a valid,
// normalised cloud. A surface that thins below the bound is untouched (same voxel count as
// the plain grid).
TEST(Preprocess, BoundsTheWorkOnCloudsThatDoNotThin) {
  std::mt19937 rng(13);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  PointCloud noise;
  noise.points.reserve(2000000);
  for (int i = 0; i < 2000000; ++i) {
    noise.points.emplace_back(unit(rng) - 0.5f, unit(rng) - 0.5f, 0.5f + unit(rng));
  }
  PreprocessOptions options;
  const PreprocessedCloud out = Preprocess(noise, options);
  EXPECT_GT(out.summary.in_range_points, 1500000);
  EXPECT_LE(out.summary.voxel_points, 100000);
  EXPECT_GT(out.summary.voxel_points, 10000);  // coarsened, not emptied
  EXPECT_GE(out.summary.final_points, options.min_points);
  EXPECT_GT(out.radius, 0.1f);

  PointCloud plane;
  for (int i = 0; i < 300; ++i) {
    for (int j = 0; j < 300; ++j) plane.points.emplace_back(0.001f * i - 0.15f, 0.001f * j - 0.15f, 0.6f);
  }
  const PreprocessedCloud thin = Preprocess(plane, options);
  const std::vector<Eigen::Vector3f> grid =
      internal::VoxelGridCentroids(plane.points, static_cast<float>(options.voxel_leaf));
  EXPECT_EQ(thin.summary.voxel_points, static_cast<int64_t>(grid.size()));
}

}  // namespace
}  // namespace sope
