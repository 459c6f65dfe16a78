#include "core/camera_model.h"

#include <random>

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

#include "core/error.h"
#include "core/units.h"
#include "tests/test_support.h"

namespace sope {
namespace {

CameraModel Webcam(std::vector<double> distortion) {
  CameraModel model;
  model.width = 1280;
  model.height = 720;
  model.matrix << 1400, 0, 645.3, 0, 1395, 357.9, 0, 0, 1;
  model.distortion = std::move(distortion);
  return model;
}

TEST(CameraModel, ProjectionMatchesOpenCv) {
  for (const auto& distortion :
       {std::vector<double>{}, std::vector<double>{-0.08, 0.06, 0.001, -0.0005, 0.01},
        std::vector<double>{-0.2, 0.1, 0.002, 0.001, -0.02, 0.05, 0.01, -0.01}}) {
    const CameraModel model = Webcam(distortion);
    std::mt19937 random(7);
    std::uniform_real_distribution<double> lateral(-0.25, 0.25), depth(0.4, 1.2);
    std::vector<cv::Point3d> points;
    for (int i = 0; i < 200; ++i) points.emplace_back(lateral(random), lateral(random), depth(random));
    cv::Mat k;
    cv::eigen2cv(model.matrix, k);
    std::vector<cv::Point2d> expected;
    cv::projectPoints(points, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), k,
                      distortion.empty() ? cv::Mat() : cv::Mat(distortion), expected);
    for (size_t i = 0; i < points.size(); ++i) {
      const Eigen::Vector2d pixel =
          model.ImageFromCam(Eigen::Vector3d(points[i].x, points[i].y, points[i].z));
      EXPECT_NEAR(pixel.x(), expected[i].x, 1e-6);
      EXPECT_NEAR(pixel.y(), expected[i].y, 1e-6);
    }
  }
}

TEST(CameraModel, UndistortInvertsDistortToHighPrecision) {
  const CameraModel model = Webcam({-0.25, 0.12, 0.002, -0.001, -0.03});
  for (int y = 0; y < model.height; y += 37) {
    for (int x = 0; x < model.width; x += 41) {
      const Eigen::Vector2d pixel(x, y);
      const Eigen::Vector2d ray = model.CamFromImage(pixel);
      const Eigen::Vector2d back = model.ImageFromCam(ray.homogeneous());
      EXPECT_NEAR((back - pixel).norm(), 0.0, 1e-8) << "pixel " << x << "," << y;
    }
  }
}

TEST(CameraModel, RayIsUnitAndPointsThroughPixel) {
  const CameraModel model = Webcam({-0.08, 0.06, 0, 0, 0});
  const Eigen::Vector2d pixel(100.25, 600.5);
  const Eigen::Vector3d ray = model.RayFromImage(pixel);
  EXPECT_NEAR(ray.norm(), 1.0, 1e-12);
  EXPECT_NEAR((model.ImageFromCam(0.7 * ray) - pixel).norm(), 0.0, 1e-8);
}

TEST(CameraModel, CheckRejectsInvalidModels) {
  CameraModel model = Webcam({});
  EXPECT_NO_THROW(model.Check());
  model.width = 0;
  EXPECT_THROW_WITH_MESSAGE(model.Check(), Error, "image size 0x720");
  model = Webcam({0.1, 0.2, 0.3});
  EXPECT_THROW_WITH_MESSAGE(model.Check(), Error, "distortion", "got 3");
  model = Webcam({});
  model.matrix(0, 0) = -5;
  EXPECT_THROW_WITH_MESSAGE(model.Check(), Error, "fx=-5");
}

TEST(CameraModel, MakePinholeHasTheRequestedFieldOfView) {
  const CameraModel model = MakePinhole(640, 480, kPi / 2);
  EXPECT_NEAR(model.fx(), 320.0, 1e-9);
  EXPECT_NEAR(model.cx(), 319.5, 1e-9);
}

// Issue 13: a matrix whose bottom row is not 0 0 1 scanned with exit 0; a 999999×999999
// camera failed with std::bad_alloc later.
TEST(CameraModel, CheckRejectsABadBottomRowAndHugeImages) {
  CameraModel model = MakePinhole(320, 240, 1.0);
  EXPECT_NO_THROW(model.Check());
  CameraModel bad = model;
  bad.matrix.row(2) << 5, 7, 0;
  try {
    bad.Check();
    ADD_FAILURE() << "no exception";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bottom row must be 0 0 1"), std::string::npos)
        << e.what();
  }
  bad = model;
  bad.matrix(1, 0) = 0.3;
  EXPECT_THROW(bad.Check(), Error);
  bad = model;
  bad.width = bad.height = 999999;
  try {
    bad.Check();
    ADD_FAILURE() << "no exception";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("beyond the limit"), std::string::npos) << e.what();
  }
  bad = model;
  bad.width = kMaxImageSide;
  bad.height = kMaxImageSide;  // each side fine, the pixel count not
  EXPECT_THROW(bad.Check(), Error);
}

}  // namespace
}  // namespace sope
