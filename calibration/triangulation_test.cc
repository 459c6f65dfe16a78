#include "calibration/triangulation.h"

#include <cmath>
#include <cstdio>
#include <limits>

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// `vertical`: the projector sits above the camera instead of to its right (rows then
// carry the depth information, as a y-only pattern set needs).
// `wide`: a wide-angle projector with stronger distortion that lights the camera's corners
// (where the camera's own distortion is largest).
RigCalibration TestRig(bool vertical = false, bool wide = false) {
  RigCalibration rig;
  rig.camera.width = 320;
  rig.camera.height = 240;
  rig.camera.matrix << 350, 0, 161.2, 0, 351, 118.7, 0, 0, 1;
  rig.camera.distortion = {-0.08, 0.06, 0.001, -0.0015, 0.0};
  rig.projector.width = 256;
  rig.projector.height = 192;
  rig.projector.matrix << 380, 0, 128.5, 0, 380, 95.0, 0, 0, 1;
  rig.projector.distortion = {-0.03, 0.01, 0.0005, 0.0, 0.0};
  if (wide) {
    rig.camera.distortion = {-0.2, 0.08, 0.001, -0.0015, -0.01};
    rig.projector.matrix << 170, 0, 128.5, 0, 171, 95.0, 0, 0, 1;
    rig.projector.distortion = {-0.12, 0.03, 0.0005, -0.0004, 0.0};
  }
  // Projector 0.2 m to the camera's right (or above it), turned to look at (0, 0, 0.6).
  const Eigen::Vector3d projector_center =
      vertical ? Eigen::Vector3d(0.0, -0.2, 0.0) : Eigen::Vector3d(0.2, 0.0, 0.0);
  const double angle = std::atan2(0.2, 0.6);
  rig.proj_from_cam.rotation =
      (vertical ? RotationFromEulerXYZ(-angle, 0.0, 0.0) : RotationFromEulerXYZ(0.0, -angle, 0.0))
          .transpose();
  rig.proj_from_cam.translation = -(rig.proj_from_cam.rotation * projector_center);
  return rig;
}

// Camera rays meet the plane n·X = d; `truth` holds the points (NaN where missed) and the
// map holds their exact projector coordinates, optionally rounded to integers. `steps`:
// in a checkerboard of 40 × 30 pixel blocks, every other block sees the plane 0.15 m
// nearer (depth steps along rows and columns).
CorrespondenceMap PlaneMap(const RigCalibration& rig, bool x_axis, bool y_axis, bool round,
                           cv::Mat* truth, bool steps = false) {
  const Eigen::Vector3d normal = Eigen::Vector3d(0.1, -0.2, -1.0).normalized();
  const double far_offset = normal.dot(Eigen::Vector3d(0, 0, 0.6));
  const double near_offset = normal.dot(Eigen::Vector3d(0, 0, 0.45));
  CorrespondenceMap map;
  map.projector_width = rig.projector.width;
  map.projector_height = rig.projector.height;
  const cv::Size size(rig.camera.width, rig.camera.height);
  map.mask = cv::Mat::zeros(size, CV_8UC1);
  if (x_axis) map.proj_x = cv::Mat(size, CV_32FC1, cv::Scalar(kNaN));
  if (y_axis) map.proj_y = cv::Mat(size, CV_32FC1, cv::Scalar(kNaN));
  *truth = cv::Mat(size, CV_32FC3, cv::Scalar::all(kNaN));
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const Eigen::Vector3d ray = rig.camera.RayFromImage(Eigen::Vector2d(x, y));
      const double offset = steps && (x / 40 + y / 30) % 2 == 1 ? near_offset : far_offset;
      const Eigen::Vector3d point = ray * (offset / normal.dot(ray));
      const Eigen::Vector2d projected = rig.projector.ImageFromCam(rig.proj_from_cam * point);
      if (projected.x() < 0 || projected.y() < 0 || projected.x() > rig.projector.width - 1 ||
          projected.y() > rig.projector.height - 1) {
        continue;
      }
      Eigen::Vector2d coded = projected;
      if (round) coded = coded.array().round();
      if (x_axis) map.proj_x.at<float>(y, x) = static_cast<float>(coded.x());
      if (y_axis) map.proj_y.at<float>(y, x) = static_cast<float>(coded.y());
      map.mask.at<uint8_t>(y, x) = 255;
      truth->at<cv::Vec3f>(y, x) = cv::Vec3f(point.x(), point.y(), point.z());
    }
  }
  return map;
}

// Max and median distance of triangulated points to the truth; fraction triangulated.
void Compare(const TriangulationResult& result, const cv::Mat& truth, const cv::Mat& mask,
             double* max_error,
             double* median_error, double* fraction) {
  std::vector<double> errors;
  for (size_t i = 0; i < result.cloud.size(); ++i) {
    const cv::Vec3f t = truth.at<cv::Vec3f>(result.pixels[i]);
    errors.push_back((result.cloud.points[i] - Eigen::Vector3f(t[0], t[1], t[2])).norm());
  }
  ASSERT_FALSE(errors.empty());
  std::sort(errors.begin(), errors.end());
  *max_error = errors.back();
  *median_error = errors[errors.size() / 2];
  *fraction = static_cast<double>(errors.size()) / cv::countNonZero(mask);
}

struct Case {
  bool x_axis, y_axis;
  TriangulationMethod method;
};

class ExactTriangulation : public ::testing::TestWithParam<Case> {};

TEST_P(ExactTriangulation, RecoversPlanePointsExactly) {
  const Case c = GetParam();
  const RigCalibration rig = TestRig(/*vertical=*/!c.x_axis);
  cv::Mat truth;
  const CorrespondenceMap map = PlaneMap(rig, c.x_axis, c.y_axis, false, &truth);
  TriangulationOptions options;
  options.method = c.method;
  const TriangulationResult result = Triangulate(map, rig, cv::Mat(), options);
  double max_error, median_error, fraction;
  Compare(result, truth, map.mask, &max_error, &median_error, &fraction);
  // Exact coordinates: only float rounding and the projector table interpolation remain.
  EXPECT_LT(max_error, 2e-5) << "metres";
  EXPECT_GT(fraction, 0.999);
  EXPECT_EQ(result.cloud.size() + result.rejected, static_cast<size_t>(cv::countNonZero(map.mask)));
  // The depth image carries the same z.
  const cv::Point pixel = result.pixels[result.pixels.size() / 2];
  EXPECT_NEAR(result.depth.at<float>(pixel), truth.at<cv::Vec3f>(pixel)[2], 2e-5);
}

INSTANTIATE_TEST_SUITE_P(
    Methods, ExactTriangulation,
    ::testing::Values(Case{true, true, TriangulationMethod::kMidpoint},
                      Case{true, true, TriangulationMethod::kLinear},
                      Case{true, false, TriangulationMethod::kMidpoint},
                      Case{false, true, TriangulationMethod::kMidpoint}));

TEST(Triangulation, IntegerCoordinatesGiveBoundedError) {
  const RigCalibration rig = TestRig();
  cv::Mat exact_truth, truth;
  const CorrespondenceMap exact = PlaneMap(rig, true, true, false, &exact_truth);
  const CorrespondenceMap rounded = PlaneMap(rig, true, true, true, &truth);
  const Triangulator triangulator(rig);
  const TriangulationResult result = triangulator.Triangulate(rounded, cv::Mat());
  ASSERT_GT(result.cloud.size(), 1000u);
  // Over ±0.5 px the point is close to linear in the projector coordinates, so the error
  // from rounding is bounded by the largest error at the four corners of that square.
  size_t checked = 0;
  for (size_t i = 0; i < result.cloud.size(); i += 97) {
    const cv::Point pixel = result.pixels[i];
    const cv::Vec3f t = truth.at<cv::Vec3f>(pixel);
    const Eigen::Vector3d true_point(t[0], t[1], t[2]);
    const double u = exact.proj_x.at<float>(pixel), v = exact.proj_y.at<float>(pixel);
    double corner_error = 0.0;
    for (double du : {-0.5, 0.5}) {
      for (double dv : {-0.5, 0.5}) {
        const auto corner = triangulator.TriangulatePixel(Eigen::Vector2d(pixel.x, pixel.y),
                                                          u + du, v + dv);
        ASSERT_TRUE(corner.has_value());
        corner_error = std::max(corner_error, (*corner - true_point).norm());
      }
    }
    const double error = (result.cloud.points[i].cast<double>() - true_point).norm();
    EXPECT_LE(error, 1.05 * corner_error + 1e-6) << "pixel " << pixel;
    ++checked;
  }
  EXPECT_GT(checked, 100u);
}

TEST(Triangulation, ColoursComeFromTheWhiteImage) {
  const RigCalibration rig = TestRig();
  cv::Mat truth;
  const CorrespondenceMap map = PlaneMap(rig, true, true, false, &truth);
  cv::Mat white(rig.camera.height, rig.camera.width, CV_8UC3, cv::Scalar(10, 20, 30));
  const TriangulationResult result = Triangulate(map, rig, white);
  ASSERT_TRUE(result.cloud.HasColors());
  EXPECT_EQ(result.cloud.colors[0], Color3ub(30, 20, 10));  // RGB from BGR
}

TEST(Triangulation, ThreadsGiveIdenticalClouds) {
  const RigCalibration rig = TestRig();
  cv::Mat truth;
  const CorrespondenceMap map = PlaneMap(rig, true, true, false, &truth);
  TriangulationOptions threaded;
  threaded.num_threads = 2;
  const TriangulationResult one = Triangulate(map, rig, cv::Mat());
  const TriangulationResult two = Triangulate(map, rig, cv::Mat(), threaded);
  ASSERT_EQ(one.cloud.size(), two.cloud.size());
  EXPECT_EQ(one.cloud.points, two.cloud.points);
}

cv::Point result_pixel_near_centre(const CorrespondenceMap& map) {
  std::vector<cv::Point> valid;
  cv::findNonZero(map.mask, valid);
  return valid.at(valid.size() / 2);
}

TEST(Triangulation, DepthBandAndReprojectionRejectOutliers) {
  const RigCalibration rig = TestRig();
  cv::Mat truth;
  CorrespondenceMap map = PlaneMap(rig, true, true, false, &truth);
  // Corrupt one decoded row coordinate by 20 projector pixels: rays no longer meet.
  const cv::Point corrupted = result_pixel_near_centre(map);
  map.proj_y.at<float>(corrupted) += 20.0f;
  TriangulationResult result = Triangulate(map, rig, cv::Mat());
  EXPECT_TRUE(std::isnan(result.depth.at<float>(corrupted)));
  EXPECT_EQ(result.rejected, 1u);
  TriangulationOptions band;
  band.min_depth = 0.0;
  band.max_depth = 0.6;  // the plane spans both sides of 0.6 m
  result = Triangulate(map, rig, cv::Mat(), band);
  for (const Eigen::Vector3f& point : result.cloud.points) EXPECT_LE(point.z(), 0.6f);
  EXPECT_GT(result.rejected, 1000u);
}

TEST(Triangulation, MismatchedSizesAreClearErrors) {
  const RigCalibration rig = TestRig();
  cv::Mat truth;
  CorrespondenceMap map = PlaneMap(rig, true, true, false, &truth);
  RigCalibration other = rig;
  other.camera.width = 640;
  EXPECT_THROW_WITH_MESSAGE(Triangulate(map, other, cv::Mat()), Error, "320x240", "640x240");
  other = rig;
  other.projector.height = 100;
  EXPECT_THROW_WITH_MESSAGE(Triangulate(map, other, cv::Mat()), Error, "256x100");
  EXPECT_THROW_WITH_MESSAGE(Triangulate(map, rig, cv::Mat(10, 10, CV_8UC1)), Error,
                            "white image is 10x10");
  TriangulationOptions bad;
  bad.max_depth = -1;
  EXPECT_THROW_WITH_MESSAGE(Triangulate(map, rig, cv::Mat(), bad), Error, "depth band", "-1");
}

// Fast path (tables, closed form) against the exact per-point path on the same map: the
// same pixels accepted, points within 1e-6 m.
void ExpectSameAsExact(const Triangulator& triangulator, const CorrespondenceMap& map,
                       double tolerance_m, size_t* compared_in_corners = nullptr) {
  const TriangulationResult fast = triangulator.Triangulate(map, cv::Mat());
  const TriangulationResult exact = triangulator.TriangulateExact(map, cv::Mat());
  ASSERT_GT(exact.cloud.size(), 0u);
  ASSERT_EQ(fast.cloud.size(), exact.cloud.size());
  EXPECT_EQ(fast.rejected, exact.rejected);
  ASSERT_EQ(fast.pixels, exact.pixels);
  double max_depth_error = 0.0, max_point_error = 0.0;
  size_t corners = 0;
  const int width = map.width(), height = map.height();
  constexpr int kCornerPx = 24;
  for (size_t i = 0; i < fast.cloud.size(); ++i) {
    const cv::Point p = fast.pixels[i];
    const double dz = std::abs(fast.depth.at<float>(p) - exact.depth.at<float>(p));
    max_depth_error = std::max<double>(max_depth_error, dz);
    max_point_error = std::max<double>(
        max_point_error, (fast.cloud.points[i] - exact.cloud.points[i]).norm());
    const bool corner = (p.x < kCornerPx || p.x >= width - kCornerPx) &&
                        (p.y < kCornerPx || p.y >= height - kCornerPx);
    corners += corner;
  }
  EXPECT_LE(max_depth_error, tolerance_m) << "metres";
  EXPECT_LE(max_point_error, tolerance_m) << "metres";
  ::testing::Test::RecordProperty("max_depth_error_nm", static_cast<int>(max_depth_error * 1e9));
  if (compared_in_corners != nullptr) *compared_in_corners = corners;
}

struct FastCase {
  bool x_axis, y_axis;
  TriangulationMethod method;
  bool wide;
};

class FastTriangulation : public ::testing::TestWithParam<FastCase> {};

TEST_P(FastTriangulation, MatchesTheExactPathWithin1e6Metres) {
  const FastCase c = GetParam();
  const RigCalibration rig = TestRig(/*vertical=*/!c.x_axis, c.wide);
  TriangulationOptions options;
  options.method = c.method;
  const Triangulator triangulator(rig, options);
  cv::Mat truth;
  // Sub-pixel coordinates (as phase-shift decoding gives), integer ones (Gray code), and
  // sub-pixel ones with noise (some rejected by the reprojection test).
  CorrespondenceMap map = PlaneMap(rig, c.x_axis, c.y_axis, false, &truth);
  size_t corners = 0;
  ExpectSameAsExact(triangulator, map, 1e-6, &corners);
  if (c.wide) {
    EXPECT_GT(corners, 1000u) << "the wide rig must light the camera's corners";
  }
  ExpectSameAsExact(triangulator, PlaneMap(rig, c.x_axis, c.y_axis, true, &truth), 1e-6);
  cv::RNG rng(7);
  for (cv::Mat* axis : {&map.proj_x, &map.proj_y}) {
    if (axis->empty()) continue;
    cv::Mat noise(axis->size(), CV_32FC1);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, 1.5);
    *axis += noise;
  }
  ExpectSameAsExact(triangulator, map, 1e-6);
}

INSTANTIATE_TEST_SUITE_P(
    Methods, FastTriangulation,
    ::testing::Values(FastCase{true, true, TriangulationMethod::kMidpoint, false},
                      FastCase{true, true, TriangulationMethod::kLinear, false},
                      FastCase{true, false, TriangulationMethod::kMidpoint, false},
                      FastCase{false, true, TriangulationMethod::kMidpoint, false},
                      FastCase{true, true, TriangulationMethod::kMidpoint, true},
                      FastCase{true, true, TriangulationMethod::kLinear, true},
                      FastCase{true, false, TriangulationMethod::kMidpoint, true},
                      FastCase{false, true, TriangulationMethod::kMidpoint, true}));

// A projector lens with the rational model's k4–k6 (the two-axis kernels' other
// distortion variant, with its division): both two-axis methods match the exact path on
// the wide rig, with exact, sub-pixel and noisy coordinates.
TEST(FastTriangulation, RationalProjectorLensMatchesTheExactPath) {
  RigCalibration rig = TestRig(/*vertical=*/false, /*wide=*/true);
  rig.projector.distortion = {-0.12, 0.03, 0.0005, -0.0004, 0.0, 0.05, -0.01, 0.002};
  for (const TriangulationMethod method :
       {TriangulationMethod::kMidpoint, TriangulationMethod::kLinear}) {
    TriangulationOptions options;
    options.method = method;
    const Triangulator triangulator(rig, options);
    cv::Mat truth;
    CorrespondenceMap map = PlaneMap(rig, true, true, false, &truth);
    ExpectSameAsExact(triangulator, map, 1e-6);
    ExpectSameAsExact(triangulator, PlaneMap(rig, true, true, true, &truth), 1e-6);
    cv::RNG rng(11);
    for (cv::Mat* axis : {&map.proj_x, &map.proj_y}) {
      cv::Mat noise(axis->size(), CV_32FC1);
      rng.fill(noise, cv::RNG::NORMAL, 0.0, 1.5);
      *axis += noise;
    }
    const TriangulationResult noisy = triangulator.Triangulate(map, cv::Mat());
    EXPECT_GT(noisy.rejected, 0u) << "the noise must put some points past the reprojection test";
    ExpectSameAsExact(triangulator, map, 1e-6);
  }
}

// Ray–plane predicts each point's projector row (column) from the two camera rows above:
// across depth steps the prediction fails and the point takes the steps from the centre;
// either way the exact path's points within 1e-6 m, on the wide-angle rig too.
TEST(FastTriangulation, RayPlaneMatchesTheExactPathAcrossDepthSteps) {
  for (const bool wide : {false, true}) {
    for (const bool x_axis : {true, false}) {
      const RigCalibration rig = TestRig(/*vertical=*/!x_axis, wide);
      const Triangulator triangulator(rig);
      cv::Mat truth;
      const CorrespondenceMap map = PlaneMap(rig, x_axis, !x_axis, false, &truth, true);
      ExpectSameAsExact(triangulator, map, 1e-6);
      // Nothing lost at the steps: every decoded pixel triangulated.
      double max_error = 0.0, median_error = 0.0, fraction = 0.0;
      Compare(triangulator.Triangulate(map, cv::Mat()), truth, map.mask, &max_error,
              &median_error, &fraction);
      EXPECT_EQ(fraction, 1.0) << "wide " << wide << ", x " << x_axis;
    }
  }
}

// A region of `map`'s camera: `roi` and a disc of `radius` pixels about (150, 110).
TriangulationRegion DiscRegion(const CorrespondenceMap& map, const cv::Rect& roi, int radius) {
  TriangulationRegion region;
  region.roi = roi;
  region.mask = cv::Mat::zeros(map.mask.size(), CV_8UC1);
  cv::circle(region.mask, cv::Point(150, 110), radius, cv::Scalar(255), cv::FILLED);
  return region;
}

// With one axis coded, a region's points are the full image's within 1e-6 m (ray–plane
// predicts from the rows above, which a region may leave out: the last bits can differ),
// and the same pixels.
TEST(FastTriangulation, RayPlaneRegionMatchesTheFullCloud) {
  for (const bool x_axis : {true, false}) {
    const RigCalibration rig = TestRig(/*vertical=*/!x_axis, /*wide=*/true);
    cv::Mat truth;
    const CorrespondenceMap map = PlaneMap(rig, x_axis, !x_axis, false, &truth, true);
    const Triangulator triangulator(rig);
    const TriangulationResult full = triangulator.Triangulate(map, cv::Mat());
    TriangulationRegion region = DiscRegion(map, cv::Rect(37, 29, 211, 151), 70);
    for (int y = 0; y < map.height(); y += 5) region.mask.row(y).setTo(0);  // gaps in rows
    const TriangulationResult part = triangulator.Triangulate(map, cv::Mat(), region);
    size_t k = 0;
    double max_difference = 0.0;
    for (size_t i = 0; i < full.cloud.size(); ++i) {
      const cv::Point p = full.pixels[i];
      if (!region.roi.contains(p) || region.mask.at<uint8_t>(p) == 0) continue;
      ASSERT_LT(k, part.cloud.size());
      ASSERT_EQ(part.pixels[k], p);
      max_difference = std::max<double>(
          max_difference, (part.cloud.points[k] - full.cloud.points[i]).norm());
      ++k;
    }
    EXPECT_EQ(k, part.cloud.size());
    EXPECT_GT(k, 5000u);
    EXPECT_LE(max_difference, 1e-6) << "x " << x_axis;
  }
}

TEST(FastTriangulation, CoordinatesOffTheTablesTakeTheExactPath) {
  for (const bool two_axes : {true, false}) {
    const RigCalibration rig = TestRig();
    cv::Mat truth;
    CorrespondenceMap map = PlaneMap(rig, true, two_axes, false, &truth);
    // Push a band of columns just off the projector (−0.4 px): still triangulated, by
    // the exact path's direct undistortion.
    int pushed = 0;
    for (int y = 0; y < map.height(); y += 3) {
      for (int x = 0; x < map.width(); x += 5) {
        if (map.mask.at<uint8_t>(y, x) == 0) continue;
        map.proj_x.at<float>(y, x) = -0.4f;
        ++pushed;
      }
    }
    ASSERT_GT(pushed, 100);
    TriangulationOptions options;
    options.max_reprojection_px = 0.0;  // keep the moved points
    const Triangulator triangulator(rig, options);
    ExpectSameAsExact(triangulator, map, 1e-6);
  }
}

TEST(FastTriangulation, RegionRestrictsToItsPixels) {
  const RigCalibration rig = TestRig();
  cv::Mat truth;
  const CorrespondenceMap map = PlaneMap(rig, true, true, false, &truth);
  const Triangulator triangulator(rig);
  const TriangulationResult full = triangulator.Triangulate(map, cv::Mat());
  TriangulationRegion region = DiscRegion(map, cv::Rect(40, 30, 200, 150), 60);
  const TriangulationResult part = triangulator.Triangulate(map, cv::Mat(), region);
  size_t expected = 0, expected_rejected = 0;
  for (size_t i = 0; i < full.cloud.size(); ++i) {
    const cv::Point p = full.pixels[i];
    if (!region.roi.contains(p) || region.mask.at<uint8_t>(p) == 0) continue;
    ASSERT_LT(expected, part.cloud.size());
    EXPECT_EQ(part.pixels[expected], p);
    EXPECT_EQ(part.cloud.points[expected], full.cloud.points[i]);
    ++expected;
  }
  EXPECT_EQ(part.cloud.size(), expected);
  EXPECT_GT(expected, 5000u);
  for (int y = 0; y < map.height(); ++y) {
    for (int x = 0; x < map.width(); ++x) {
      const bool inside = region.roi.contains(cv::Point(x, y)) && region.mask.at<uint8_t>(y, x);
      if (!inside) {
        EXPECT_TRUE(std::isnan(part.depth.at<float>(y, x)));
      } else if (map.mask.at<uint8_t>(y, x) != 0 && std::isnan(full.depth.at<float>(y, x))) {
        ++expected_rejected;
      }
    }
  }
  EXPECT_EQ(part.rejected, expected_rejected);
  // A wrong-sized mask is a clear error.
  region.mask = cv::Mat::zeros(10, 10, CV_8UC1);
  EXPECT_THROW_WITH_MESSAGE(triangulator.Triangulate(map, cv::Mat(), region), Error,
                            "region mask", "320x240");
}

TEST(FastTriangulation, ThreadsGiveIdenticalClouds) {
  for (const bool two_axes : {true, false}) {
    const RigCalibration rig = TestRig();
    cv::Mat truth;
    const CorrespondenceMap map = PlaneMap(rig, true, two_axes, false, &truth);
    TriangulationOptions threaded;
    threaded.num_threads = 3;
    const TriangulationResult one = Triangulator(rig).Triangulate(map, cv::Mat());
    const TriangulationResult three = Triangulator(rig, threaded).Triangulate(map, cv::Mat());
    ASSERT_EQ(one.cloud.size(), three.cloud.size());
    EXPECT_EQ(one.cloud.points, three.cloud.points);
    EXPECT_EQ(one.pixels, three.pixels);
    EXPECT_EQ(one.rejected, three.rejected);
  }
}

TEST(FastTriangulation, RayTablesMatchPerPixelUndistortion) {
  // The tables' rays against CameraModel::CamFromImage at pixels all over the image
  // (corners included), through TriangulatePixel (which undistorts per call) and the
  // table path on a one-pixel map.
  const RigCalibration rig = TestRig(false, true);
  TriangulationOptions options;
  options.max_reprojection_px = 0.0;
  const Triangulator triangulator(rig, options);
  CorrespondenceMap map;
  map.projector_width = rig.projector.width;
  map.projector_height = rig.projector.height;
  const cv::Size size(rig.camera.width, rig.camera.height);
  map.mask = cv::Mat::zeros(size, CV_8UC1);
  map.proj_x = cv::Mat(size, CV_32FC1, cv::Scalar(100.25f));
  map.proj_y = cv::Mat(size, CV_32FC1, cv::Scalar(90.5f));
  for (int y = 0; y < size.height; y += 7) {
    for (int x = 0; x < size.width; x += 7) map.mask.at<uint8_t>(y, x) = 255;
  }
  const TriangulationResult result = triangulator.Triangulate(map, cv::Mat());
  ASSERT_GT(result.cloud.size(), 1000u);
  double max_error = 0.0;
  for (size_t i = 0; i < result.cloud.size(); ++i) {
    const cv::Point p = result.pixels[i];
    const auto point = triangulator.TriangulatePixel(Eigen::Vector2d(p.x, p.y), 100.25, 90.5);
    ASSERT_TRUE(point.has_value());
    max_error = std::max(max_error, (result.cloud.points[i].cast<double>() - *point).norm());
  }
  // Float rays (8 bytes per pixel): ~1e-7 relative.
  EXPECT_LT(max_error, 5e-6) << "metres";
}

// Ray–plane's predicted step takes the plane table's plane where it strays from the chord
// by no more than the ray grid's own rounding: the mild test rig does (so the tests above
// compare that path with the exact one), the wide-angle one keeps the chords.
TEST(FastTriangulation, PlaneTablesStandInForChordsOnlyWithMildLenses) {
  const Triangulator mild(TestRig(false, false));
  const Triangulator wide(TestRig(false, true));
  for (const bool columns : {true, false}) {
    SCOPED_TRACE(::testing::Message() << "columns " << columns);
    EXPECT_GT(mild.PlaneTableDeviation(columns), 0.0);
    EXPECT_LE(mild.PlaneTableDeviation(columns), Triangulator::kPlaneTableMaxDeviationPx);
    EXPECT_GT(wide.PlaneTableDeviation(columns), Triangulator::kPlaneTableMaxDeviationPx);
    std::printf("plane table deviation (columns %d): mild %.3g px, wide %.3g px\n", columns,
                mild.PlaneTableDeviation(columns), wide.PlaneTableDeviation(columns));
  }
}

TEST(FastTriangulation, TablesAreCompact) {
  const RigCalibration rig = TestRig();
  const Triangulator triangulator(rig);
  // Float pairs: camera rays, projector rays (+ margin), two plane tables.
  const size_t camera = 320 * 240, projector = 256 * 192, margin = (256 + 16) * (192 + 16);
  EXPECT_EQ(triangulator.TableBytes(), 8 * (camera + margin + 2 * projector));
}

}  // namespace
}  // namespace sope
