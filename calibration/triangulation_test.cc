#include "calibration/triangulation.h"

#include <cmath>
#include <limits>

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// `vertical`: the projector sits above the camera instead of to its right (rows then
// carry the depth information, as a y-only pattern set needs).
RigCalibration TestRig(bool vertical = false) {
  RigCalibration rig;
  rig.camera.width = 320;
  rig.camera.height = 240;
  rig.camera.matrix << 350, 0, 161.2, 0, 351, 118.7, 0, 0, 1;
  rig.camera.distortion = {-0.08, 0.06, 0.001, -0.0015, 0.0};
  rig.projector.width = 256;
  rig.projector.height = 192;
  rig.projector.matrix << 380, 0, 128.5, 0, 380, 95.0, 0, 0, 1;
  rig.projector.distortion = {-0.03, 0.01, 0.0005, 0.0, 0.0};
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
// map holds their exact projector coordinates, optionally rounded to integers.
CorrespondenceMap PlaneMap(const RigCalibration& rig, bool x_axis, bool y_axis, bool round,
                           cv::Mat* truth) {
  const Eigen::Vector3d normal = Eigen::Vector3d(0.1, -0.2, -1.0).normalized();
  const double offset = normal.dot(Eigen::Vector3d(0, 0, 0.6));
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

}  // namespace
}  // namespace sope
