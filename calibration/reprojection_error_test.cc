// The templated lens model of the bundle adjustment against core's CameraModel, and the
// cost functors' automatic derivatives against numeric ones (ceres::GradientChecker).
#include "calibration/reprojection_error.h"

#include <random>
#include <vector>

#include <ceres/autodiff_cost_function.h>
#include <ceres/gradient_checker.h>
#include <gtest/gtest.h>

#include "core/camera_model.h"
#include "core/rigid3d.h"

namespace sope {
namespace internal {
namespace {

CameraModel RandomModel(std::mt19937_64* engine, int num_coefficients) {
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  CameraModel model;
  model.width = 1280;
  model.height = 720;
  model.matrix << 1400 + 50 * unit(*engine), 0, 640 + 20 * unit(*engine), 0,
      1390 + 50 * unit(*engine), 360 + 20 * unit(*engine), 0, 0, 1;
  const double scales[8] = {0.2, 0.1, 2e-3, 2e-3, 0.05, 0.05, 0.02, 0.01};
  for (int i = 0; i < num_coefficients; ++i) model.distortion.push_back(scales[i] * unit(*engine));
  return model;
}

template <int kNumCoefficients>
void ExpectDistortionMatchesCore() {
  std::mt19937_64 engine(kNumCoefficients);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    const CameraModel model = RandomModel(&engine, kNumCoefficients);
    const Eigen::Vector2d point(0.6 * unit(engine), 0.45 * unit(engine));
    Eigen::Vector2d distorted;
    DistortOpenCv<kNumCoefficients>(model.distortion.data(), point.x(), point.y(), &distorted.x(),
                                    &distorted.y());
    const Eigen::Vector2d expected = model.Distort(point);
    ASSERT_NEAR(distorted.x(), expected.x(), 1e-12) << "trial " << trial;
    ASSERT_NEAR(distorted.y(), expected.y(), 1e-12) << "trial " << trial;
  }
}

TEST(DistortOpenCv, MatchesCoreCameraModelFor4And5And8Coefficients) {
  ExpectDistortionMatchesCore<4>();
  ExpectDistortionMatchesCore<5>();
  ExpectDistortionMatchesCore<8>();
}

TEST(ImageFromDevice, MatchesCameraModelImageFromCamTo1e9Pixels) {
  std::mt19937_64 engine(7);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  double largest_error = 0.0;
  for (int trial = 0; trial < 1000; ++trial) {
    const CameraModel model = RandomModel(&engine, 5);
    const double intrinsics[4] = {model.fx(), model.fy(), model.cx(), model.cy()};
    const Eigen::Vector3d point(0.3 * unit(engine), 0.2 * unit(engine),
                                0.5 + 0.4 * (unit(engine) + 1));
    Eigen::Vector2d pixel;
    ImageFromDevice(intrinsics, model.distortion.data(), point.data(), pixel.data());
    largest_error = std::max(largest_error, (pixel - model.ImageFromCam(point)).norm());
  }
  EXPECT_LT(largest_error, 1e-9);
}

TEST(TransformPoint, MatchesRigid3dFromTheSameAngleAxis) {
  const Eigen::Vector3d axis_angle(0.3, -0.2, 0.5);
  const double block[6] = {axis_angle.x(), axis_angle.y(), axis_angle.z(), 0.1, -0.05, 0.7};
  const Rigid3d b_from_a(
      Eigen::AngleAxisd(axis_angle.norm(), axis_angle.normalized()).toRotationMatrix(),
      Eigen::Vector3d(0.1, -0.05, 0.7));
  const Eigen::Vector3d point_in_a(0.02, 0.3, -0.1);
  Eigen::Vector3d point_in_b;
  TransformPoint(block, point_in_a.data(), point_in_b.data());
  EXPECT_LT((point_in_b - b_from_a * point_in_a).norm(), 1e-14);
}

TEST(ReprojectionErrors, ZeroAtTheTruthAndMatchingNumericDerivatives) {
  const double camera_intrinsics[4] = {1400, 1401, 642.3, 357.8};
  const double camera_distortion[5] = {-0.08, 0.06, 4e-4, -3e-4, 0.01};
  const double projector_intrinsics[4] = {1500, 1500, 511.5, 383.5};
  const double projector_distortion[5] = {-0.01, 0.002, 1e-4, 0, 0};
  const double proj_from_cam[6] = {0.01, -0.32, 0.005, -0.19, 0.001, 0.063};
  const double cam_from_board[6] = {0.3, -0.2, 0.1, -0.1, -0.06, 0.6};
  const double corner[3] = {0.05, 0.075, 0.0};

  double point_in_cam[3], point_in_proj[3], camera_pixel[2], projector_pixel[2];
  TransformPoint(cam_from_board, corner, point_in_cam);
  TransformPoint(proj_from_cam, point_in_cam, point_in_proj);
  ImageFromDevice(camera_intrinsics, camera_distortion, point_in_cam, camera_pixel);
  ImageFromDevice(projector_intrinsics, projector_distortion, point_in_proj, projector_pixel);

  const CameraReprojectionError camera_error(corner, camera_pixel);
  const ProjectorReprojectionError projector_error(corner, projector_pixel);
  double residual[2];
  ASSERT_TRUE(camera_error(camera_intrinsics, camera_distortion, cam_from_board, residual));
  EXPECT_NEAR(residual[0], 0.0, 1e-12);
  EXPECT_NEAR(residual[1], 0.0, 1e-12);
  ASSERT_TRUE(projector_error(projector_intrinsics, projector_distortion, proj_from_cam,
                              cam_from_board, residual));
  EXPECT_NEAR(residual[0], 0.0, 1e-12);
  EXPECT_NEAR(residual[1], 0.0, 1e-12);

  // Automatic derivatives against central differences, away from the optimum.
  const double observed[2] = {600.0, 400.0};
  ceres::AutoDiffCostFunction<ProjectorReprojectionError, 2, 4, 5, 6, 6> projector_cost(
      new ProjectorReprojectionError(corner, observed));
  ceres::NumericDiffOptions numeric_options;
  numeric_options.relative_step_size = 1e-7;
  const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
  ceres::GradientChecker checker(&projector_cost, no_manifolds, numeric_options);
  std::vector<const double*> parameters = {projector_intrinsics, projector_distortion,
                                           proj_from_cam, cam_from_board};
  // ProbeResults holds Eigen matrices whose layout depends on the compiler flags (we build
  // with -march=native, the system Ceres without), so no results are requested.
  EXPECT_TRUE(checker.Probe(parameters.data(), 1e-5, nullptr));

  ceres::AutoDiffCostFunction<CameraReprojectionError, 2, 4, 5, 6> camera_cost(
      new CameraReprojectionError(corner, observed));
  ceres::GradientChecker camera_checker(&camera_cost, no_manifolds, numeric_options);
  parameters = {camera_intrinsics, camera_distortion, cam_from_board};
  EXPECT_TRUE(camera_checker.Probe(parameters.data(), 1e-5, nullptr));
}

}  // namespace
}  // namespace internal
}  // namespace sope
