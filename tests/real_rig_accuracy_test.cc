// Issue 11 on the virtual rig: sub-pixel Gray code in scans (a flat board far
// enough that one projector pixel spans several millimetres of depth) and
// coverage on dim, grazing surfaces (a sphere and a cylinder lit from the side,
// no inverse frames, noise on).
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "calibration/scan.h"
#include "core/error.h"
#include "core/mesh.h"
#include "decoder/code_consistency.h"
#include "simulator/primitives.h"
#include "simulator/scene_builder.h"
#include "simulator/simulate_scan.h"
#include "simulator/virtual_rig.h"
#include "tests/test_support.h"

namespace sope {
namespace {

// RMS distance of the points from their least-squares plane, metres.
double PlaneFitRms(const std::vector<Eigen::Vector3f>& points) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3f& p : points) mean += p.cast<double>();
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3f& p : points) {
    const Eigen::Vector3d d = p.cast<double>() - mean;
    scatter += d * d.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(scatter);
  return std::sqrt(solver.eigenvalues()(0) / static_cast<double>(points.size()));
}

// Points of the cloud whose pixel is inside the board, away from its rim (the
// rim's pixels mix board and background).
std::vector<Eigen::Vector3f> BoardPoints(const TriangulationResult& result, const cv::Mat& inner) {
  std::vector<Eigen::Vector3f> points;
  for (size_t i = 0; i < result.cloud.size(); ++i) {
    const cv::Point& pixel = result.pixels[i];
    if (inner.at<uint8_t>(pixel) && result.cloud.points[i].allFinite())
      points.push_back(result.cloud.points[i]);
  }
  return points;
}

TEST(GraySubpixel, FlatBoardFarAwayIsThreeTimesFlatter) {
  const RigCalibration calibration = DefaultRigCalibration();
  // Depth of one projector pixel at distance z: z² / (f_projector · baseline).
  const double distance = 1.0;
  const double baseline = calibration.proj_from_cam.translation.norm();
  const double depth_per_projector_px =
      distance * distance / (calibration.projector.matrix(0, 0) * baseline);
  ASSERT_GE(depth_per_projector_px, 3e-3);
  Scene scene;
  Placement placement;
  placement.center_in_cam = Eigen::Vector3d(0.0, 0.0, distance);
  placement.rotation = RotationFromEulerXYZ(0.25, -0.35, 0.1);
  scene.objects.push_back(PlaceObject(MakePlane(0.5, 0.4, 4), placement));
  PatternOptions patterns;
  patterns.projector_width = calibration.projector.width;
  patterns.projector_height = calibration.projector.height;
  VirtualRig rig(calibration);
  const SimulatedScan scan = SimulateScan(rig, scene, patterns);
  cv::Mat inner;
  cv::erode(scan.ground_truth.lit, inner, cv::Mat(), cv::Point(-1, -1), 4);

  ScanOptions integer, subpixel;
  integer.decoder.gray_subpixel = GraySubpixel::kOff;
  subpixel.decoder.gray_subpixel = GraySubpixel::kEdges;
  ASSERT_EQ(ScanOptions().decoder.gray_subpixel,
            GraySubpixel::kEdges);  // the default
  const ScanResult integer_scan = ScanFrameSet(scan.frames, calibration, integer);
  const ScanResult subpixel_scan = ScanFrameSet(scan.frames, calibration, subpixel);
  const std::vector<Eigen::Vector3f> integer_points =
      BoardPoints(integer_scan.triangulation, inner);
  const std::vector<Eigen::Vector3f> subpixel_points =
      BoardPoints(subpixel_scan.triangulation, inner);
  ASSERT_GT(integer_points.size(), 50000u);
  // Refining must not lose points.
  EXPECT_GE(subpixel_points.size(), integer_points.size() * 99 / 100);
  const double integer_rms = PlaneFitRms(integer_points);
  const double subpixel_rms = PlaneFitRms(subpixel_points);
  std::printf(
      "flat board at %.2f m (%.2f mm of depth per projector pixel): RMS "
      "flatness "
      "integer %.3f mm, sub-pixel %.3f mm (ratio %.2f), %zu / %zu points\n",
      distance, 1e3 * depth_per_projector_px, 1e3 * integer_rms, 1e3 * subpixel_rms,
      subpixel_rms / integer_rms, integer_points.size(), subpixel_points.size());
  EXPECT_LE(subpixel_rms, integer_rms / 3.0);
}

// Coverage of a dim, grazing scene: of the pixels ground truth says are lit
// whose captured white − black is at least `min_contrast` grey levels, the
// fraction decoded and, of those, the fraction more than one projector pixel
// off the truth on a coded axis.
struct Coverage {
  size_t counted = 0;  // lit pixels with white − black ≥ min_contrast
  double decoded = 0.0;
  double wrong = 0.0;
  size_t dim = 0;  // of the counted, those with white − black < 10 (the old min_contrast)
  double dim_decoded = 0.0;
};

Coverage MeasureCoverage(const SimulatedScan& scan, const CorrespondenceMap& map,
                         double min_contrast) {
  const FrameSetManifest& manifest = scan.frames.manifest;
  const cv::Mat& white = scan.frames.Image(*manifest.Find(FrameRole::kWhite));
  const cv::Mat& black = scan.frames.Image(*manifest.Find(FrameRole::kBlack));
  const GroundTruth& truth = scan.ground_truth;
  size_t decoded = 0, wrong = 0, dim_decoded = 0;
  Coverage coverage;
  for (int y = 0; y < truth.lit.rows; ++y) {
    for (int x = 0; x < truth.lit.cols; ++x) {
      if (!truth.lit.at<uint8_t>(y, x)) continue;
      const int contrast = white.at<uint8_t>(y, x) - black.at<uint8_t>(y, x);
      if (contrast < min_contrast) continue;
      ++coverage.counted;
      const bool dim = contrast < 10;
      coverage.dim += dim;
      if (!map.mask.at<uint8_t>(y, x)) continue;
      ++decoded;
      dim_decoded += dim;
      const float dx = map.proj_x.at<float>(y, x) - truth.proj_x.at<float>(y, x);
      const float dy = map.proj_y.at<float>(y, x) - truth.proj_y.at<float>(y, x);
      wrong += !(std::abs(dx) <= 1.0f && std::abs(dy) <= 1.0f);
    }
  }
  coverage.decoded = static_cast<double>(decoded) / std::max<size_t>(coverage.counted, 1);
  coverage.wrong = static_cast<double>(wrong) / std::max<size_t>(decoded, 1);
  coverage.dim_decoded = static_cast<double>(dim_decoded) / std::max<size_t>(coverage.dim, 1);
  return coverage;
}

// A sphere and a cylinder to the camera's left, so that the projector (0.2 m to
// its right) lights them from the side: their far halves turn away from it and
// darken to grazing incidence; dark albedo; Gray code without inverse frames;
// default sensor noise.
SimulatedScan GrazingScene(const TriangleMesh& mesh, const Eigen::Vector3d& center, double albedo,
                           const Eigen::Matrix3d& rotation = Eigen::Matrix3d::Identity()) {
  const RigCalibration calibration = DefaultRigCalibration();
  Scene scene;
  Placement placement;
  placement.center_in_cam = center;
  placement.rotation = rotation;
  SceneObject object = PlaceObject(mesh, placement);
  object.albedo = albedo;
  scene.objects.push_back(object);
  PatternOptions patterns;
  patterns.projector_width = calibration.projector.width;
  patterns.projector_height = calibration.projector.height;
  patterns.inverted = false;
  VirtualRig rig(calibration);
  return SimulateScan(rig, scene, patterns);
}

void ReportCoverage(const char* name, const char* decoder, const Coverage& c) {
  std::printf(
      "[%s, %s] %zu lit pixels with white - black >= 4: decoded "
      "%.2f%%, wrong %.3f%% "
      "of decoded; %zu of them dim (< 10): decoded %.2f%%\n",
      name, decoder, c.counted, 100 * c.decoded, 100 * c.wrong, c.dim, 100 * c.dim_decoded);
}

TEST(GrazingCoverage, SphereAndCylinderLitFromTheSide) {
  constexpr double kMinContrast = 4.0;
  struct Case {
    const char* name;
    TriangleMesh mesh;
    Eigen::Vector3d center;
    Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  };
  std::vector<Case> cases;
  cases.push_back({"sphere", MakeSphere(0.09, 64, 128), Eigen::Vector3d(-0.12, 0.0, 0.62)});
  // Axis vertical (the model's z turned onto the camera's y).
  cases.push_back({"cylinder", MakeCylinder(0.07, 0.25, 128), Eigen::Vector3d(-0.12, 0.0, 0.62),
                   RotationFromEulerXYZ(M_PI / 2, 0.0, 0.0)});
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const SimulatedScan scan = GrazingScene(c.mesh, c.center, 0.4, c.rotation);
    // The per-pixel decode (DecoderOptions' defaults) against the scan's (ScanOptions:
    // sub-pixel and spatial code consistency).
    const Coverage per_pixel = MeasureCoverage(scan, Decode(scan.frames), kMinContrast);
    ReportCoverage(c.name, "per-pixel", per_pixel);
    const DecoderOptions scan_decoder = ScanOptions().decoder;
    ASSERT_TRUE(scan_decoder.consistency.enabled);  // the scans' default
    const Coverage coverage =
        MeasureCoverage(scan, Decode(scan.frames, scan_decoder), kMinContrast);
    ReportCoverage(c.name, "scan", coverage);
    EXPECT_GT(coverage.counted, 100000u);
    // Issue 11: ≥ 97 %. What stays undecoded is mostly the sphere's camera silhouette, where
    // the stripes compress beyond 1.5 projector px per camera pixel.
    EXPECT_GE(coverage.decoded, 0.97);
    EXPECT_GE(coverage.decoded, per_pixel.decoded + 0.03);
    EXPECT_LE(coverage.wrong, 0.005);
  }
}

// The grazing sphere decoded without code consistency (`plain`) and with it over the whole
// image (`whole`), no sub-pixel edges: the fills' coordinates compare exactly.
struct GrazingSphereFills {
  SimulatedScan scan =
      GrazingScene(MakeSphere(0.09, 64, 128), Eigen::Vector3d(-0.12, 0.0, 0.62), 0.4);
  DecoderOptions options = [] {
    DecoderOptions o;
    o.consistency.enabled = true;
    return o;
  }();
  DecoderOptions plain_options = [this] {
    DecoderOptions o = options;
    o.consistency.enabled = false;
    return o;
  }();
  CorrespondenceMap plain = Decode(scan.frames, plain_options);
  CorrespondenceMap whole = Decode(scan.frames, options);
};

// FillFromConsistentNeighbours' region (tabletop scans fill only near what stands on the
// table): on the grazing sphere, a region of every pixel gives the whole image's fills
// exactly; the left half of the image fills there as the whole-image pass does away from
// the region's edge (within the consistency's reach of it: 8 passes × radius 3) and
// nowhere else.
TEST(GrazingCoverage, ConsistencyFillsOnlyInsideItsRegion) {
  const GrazingSphereFills sphere;
  const auto& [scan, options, plain_options, plain, whole] = sphere;
  const int rows = plain.height(), cols = plain.width();

  CorrespondenceMap everywhere = Decode(scan.frames, plain_options);
  FillFromConsistentNeighbours(scan.frames, options, &everywhere,
                               cv::Mat(rows, cols, CV_8UC1, cv::Scalar(255)));
  EXPECT_EQ(cv::countNonZero(everywhere.mask != whole.mask), 0);
  EXPECT_EQ(cv::countNonZero((everywhere.proj_x != whole.proj_x) & whole.mask), 0);
  EXPECT_EQ(cv::countNonZero((everywhere.proj_y != whole.proj_y) & whole.mask), 0);

  // The sphere's centre is left of the image centre: half of it is in the left half.
  const int half = cols / 2;
  cv::Mat left = cv::Mat::zeros(rows, cols, CV_8UC1);
  left.colRange(0, half).setTo(255);
  CorrespondenceMap inside = Decode(scan.frames, plain_options);
  FillFromConsistentNeighbours(scan.frames, options, &inside, left);
  const int reach = options.consistency.passes * options.consistency.window_radius;
  int filled_outside = 0, filled_inside = 0, whole_inside = 0, differ_away_from_edge = 0;
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      const bool was = plain.mask.at<uint8_t>(y, x) != 0;
      const bool now = inside.mask.at<uint8_t>(y, x) != 0;
      const bool filled_whole = !was && whole.mask.at<uint8_t>(y, x) != 0;
      if (x >= half) {
        filled_outside += now != was;
        continue;
      }
      filled_inside += now && !was;
      whole_inside += filled_whole;
      if (x < half - reach) differ_away_from_edge += now != (was || filled_whole);
    }
  }
  std::printf("fills: whole image %d in the left half; with the region %d there, %d outside\n",
              whole_inside, filled_inside, filled_outside);
  EXPECT_GT(whole_inside, 1000);
  EXPECT_EQ(filled_outside, 0);
  EXPECT_EQ(differ_away_from_edge, 0);
  EXPECT_GE(filled_inside, 0.9 * whole_inside);
  // A region of the wrong size is refused.
  CorrespondenceMap refused = Decode(scan.frames, plain_options);
  EXPECT_THROW_WITH_MESSAGE(
      FillFromConsistentNeighbours(scan.frames, options, &refused, cv::Mat::zeros(3, 3, CV_8UC1)),
      Error, "the region must be empty or 8-bit");
}

// Seeds (the decoded pixels the fills grow from; a tabletop scan's are those standing on
// the table): with the decoded pixels left of the column that halves the whole image's
// fills as seeds, the fills there are those of the whole image away from that column, and
// they spread only a few pixels right of it, where the whole-image consistency fills as
// much.
TEST(GrazingCoverage, ConsistencyFillsGrowFromTheSeedsOnly) {
  const GrazingSphereFills sphere;
  const auto& [scan, options, plain_options, plain, whole] = sphere;
  const int rows = plain.height(), cols = plain.width();
  std::vector<int> filled_columns;
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      if (!plain.mask.at<uint8_t>(y, x) && whole.mask.at<uint8_t>(y, x)) {
        filled_columns.push_back(x);
      }
    }
  }
  ASSERT_FALSE(filled_columns.empty());
  std::nth_element(filled_columns.begin(), filled_columns.begin() + filled_columns.size() / 2,
                   filled_columns.end());
  const int half = filled_columns[filled_columns.size() / 2];
  cv::Mat seeds = cv::Mat::zeros(rows, cols, CV_8UC1);
  plain.mask.colRange(0, half).copyTo(seeds.colRange(0, half));
  CorrespondenceMap seeded = Decode(scan.frames, plain_options);
  FillFromConsistentNeighbours(scan.frames, options, &seeded, cv::Mat(), seeds);
  const int reach = options.consistency.passes * options.consistency.window_radius;
  int whole_left = 0, whole_right = 0, seeded_right = 0, differ_away_from_edge = 0;
  int right_beyond_a_window = 0;
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      const bool was = plain.mask.at<uint8_t>(y, x) != 0;
      const bool now = seeded.mask.at<uint8_t>(y, x) != 0;
      const bool filled_whole = !was && whole.mask.at<uint8_t>(y, x) != 0;
      if (x >= half) {
        whole_right += filled_whole;
        seeded_right += now && !was;
        right_beyond_a_window += now && !was && x >= half + 2 * options.consistency.window_radius;
        continue;
      }
      whole_left += filled_whole;
      if (x < half - reach) differ_away_from_edge += now != (was || filled_whole);
    }
  }
  std::printf("fills of the whole image: %d left, %d right; grown from the seeds on the left: "
              "%d right (%d beyond a window)\n",
              whole_left, whole_right, seeded_right, right_beyond_a_window);
  ASSERT_GT(whole_left, 1000);
  ASSERT_GT(whole_right, 1000);
  EXPECT_EQ(differ_away_from_edge, 0);
  EXPECT_LT(seeded_right, 0.1 * whole_right);
  EXPECT_LT(right_beyond_a_window, 0.01 * whole_right);
  // Seeds of the wrong size are refused.
  CorrespondenceMap refused = Decode(scan.frames, plain_options);
  EXPECT_THROW_WITH_MESSAGE(FillFromConsistentNeighbours(scan.frames, options, &refused,
                                                         cv::Mat(), cv::Mat::zeros(3, 3, CV_8UC1)),
                            Error, "the seeds must be empty or 8-bit");
}

}  // namespace
}  // namespace sope
