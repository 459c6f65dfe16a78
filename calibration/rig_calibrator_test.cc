// The calibrator on synthetic corner observations (exact projections of a known rig and
// board poses, optionally with noise, missing projector corners or a view that does not
// fit): initialisation + bundle adjustment must recover the rig; bad input is refused.
// Rendered end-to-end sequences are in tests/calibrate_e2e_test.cc.
#include "calibration/rig_calibrator.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "calibration/calibration_report.h"
#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace {

constexpr double kDegree = M_PI / 180.0;

RigCalibration TrueRig() {
  RigCalibration rig;
  rig.camera.width = 1280;
  rig.camera.height = 720;
  rig.camera.matrix << 1400.0, 0.0, 642.3, 0.0, 1398.0, 357.8, 0.0, 0.0, 1.0;
  rig.camera.distortion = {-0.08, 0.06, 4e-4, -3e-4, 0.0};
  rig.projector.width = 1024;
  rig.projector.height = 768;
  rig.projector.matrix << 1500.0, 0.0, 505.5, 0.0, 1500.0, 640.0, 0.0, 0.0, 1.0;  // offset lens
  rig.projector.distortion = {-0.01, 0.003, 0.0, 0.0, 0.0};
  const Eigen::Vector3d projector_center(0.2, -0.02, 0.01);
  rig.proj_from_cam.rotation = RotationFromEulerXYZ(0.12, -0.33, 0.01).transpose();
  rig.proj_from_cam.translation = -(rig.proj_from_cam.rotation * projector_center);
  return rig;
}

bool Inside(const CameraModel& device, const Eigen::Vector3d& point) {
  if (point.z() < 0.1) return false;
  const Eigen::Vector2d pixel = device.ImageFromCam(point);
  return pixel.x() > 5 && pixel.y() > 5 && pixel.x() < device.width - 6 &&
         pixel.y() < device.height - 6;
}

// Board poses whose corners all lie inside both images: depth 0.45–0.8 m, tilts of
// 15–40° in random directions, some roll.
std::vector<Rigid3d> MakePoses(const RigCalibration& rig, const BoardSpec& board, int count,
                               uint64_t seed) {
  std::mt19937_64 engine(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const Eigen::Vector3d center((board.cols - 1) * board.square_size / 2,
                               (board.rows - 1) * board.square_size / 2, 0.0);
  std::vector<Rigid3d> poses;
  while (static_cast<int>(poses.size()) < count) {
    const double depth = 0.45 + 0.35 * unit(engine);
    const Eigen::Vector3d position(depth * (unit(engine) - 0.5) * 0.8,
                                   depth * (unit(engine) - 0.5) * 0.5 - 0.05, depth);
    const double direction = 2 * M_PI * unit(engine);
    const Eigen::Matrix3d rotation =
        (Eigen::AngleAxisd((unit(engine) - 0.5) * 0.4, Eigen::Vector3d::UnitZ()) *
         Eigen::AngleAxisd((15 + 25 * unit(engine)) * kDegree,
                           Eigen::Vector3d(std::cos(direction), std::sin(direction), 0)))
            .toRotationMatrix();
    const Rigid3d pose(rotation, position - rotation * center);
    bool visible = true;
    for (const Eigen::Vector3d& corner : board.CornersInBoard()) {
      const Eigen::Vector3d point = pose * corner;
      visible =
          visible && Inside(rig.camera, point) && Inside(rig.projector, rig.proj_from_cam * point);
    }
    if (visible) poses.push_back(pose);
  }
  return poses;
}

BoardObservation Observe(const RigCalibration& rig, const BoardSpec& board, const Rigid3d& pose,
                         double sigma_px, std::mt19937_64* engine, const std::string& name) {
  std::normal_distribution<double> noise(0.0, sigma_px);
  BoardObservation observation;
  observation.name = name;
  for (const Eigen::Vector3d& corner : board.CornersInBoard()) {
    const Eigen::Vector3d point = pose * corner;
    observation.camera_corners.push_back(rig.camera.ImageFromCam(point) +
                                         Eigen::Vector2d(noise(*engine), noise(*engine)));
    observation.projector_corners.push_back(rig.projector.ImageFromCam(rig.proj_from_cam * point) +
                                            Eigen::Vector2d(noise(*engine), noise(*engine)));
  }
  return observation;
}

DeviceSizes Sizes(const RigCalibration& rig) {
  return {rig.camera.width, rig.camera.height, rig.projector.width, rig.projector.height};
}

struct Errors {
  double focal = 0.0;            // worst relative focal error (both devices, x and y)
  double principal_point = 0.0;  // worst, pixels
  double baseline = 0.0;         // relative
  double rotation = 0.0;         // radians
};

Errors Compare(const RigCalibration& recovered, const RigCalibration& truth) {
  Errors errors;
  for (const auto& [a, b] : {std::pair{&recovered.camera, &truth.camera},
                             std::pair{&recovered.projector, &truth.projector}}) {
    errors.focal =
        std::max({errors.focal, std::abs(a->fx() / b->fx() - 1), std::abs(a->fy() / b->fy() - 1)});
    errors.principal_point = std::max(
        {errors.principal_point, std::abs(a->cx() - b->cx()), std::abs(a->cy() - b->cy())});
  }
  errors.baseline = std::abs(recovered.BaselineLength() / truth.BaselineLength() - 1);
  errors.rotation =
      RotationAngleBetween(recovered.proj_from_cam.rotation, truth.proj_from_cam.rotation);
  return errors;
}

TEST(RigCalibrator, ExactObservationsGiveTheExactRig) {
  const RigCalibration truth = TrueRig();
  const BoardSpec board = BoardSpecFromString("9x6x0.025");
  const std::vector<Rigid3d> poses = MakePoses(truth, board, 8, 1);
  std::mt19937_64 engine(1);
  for (RobustLoss loss : {RobustLoss::kNone, RobustLoss::kHuber, RobustLoss::kCauchy}) {
    CalibrationOptions options;
    options.loss = loss;
    RigCalibrator calibrator(board, options);
    for (size_t v = 0; v < poses.size(); ++v) {
      calibrator.AddObservation(
          Observe(truth, board, poses[v], 0.0, &engine, "v" + std::to_string(v)), Sizes(truth));
    }
    const CalibrationSummary summary = calibrator.Calibrate();
    const Errors errors = Compare(summary.calibration, truth);
    SCOPED_TRACE(ToString(loss));
    EXPECT_LT(errors.focal, 1e-8);
    EXPECT_LT(errors.principal_point, 1e-5);
    EXPECT_LT(errors.baseline, 1e-8);
    EXPECT_LT(errors.rotation, 1e-9);
    for (size_t i = 0; i < 5; ++i) {
      EXPECT_NEAR(summary.calibration.camera.distortion[i], truth.camera.distortion[i], 1e-8);
    }
    EXPECT_NEAR(summary.calibration.projector.distortion[0], -0.01, 1e-8);
    EXPECT_EQ(summary.calibration.projector.distortion[4], 0.0);  // k3 fixed by default
    EXPECT_LT(summary.calibration.rms_stereo_px, 1e-6);
    EXPECT_EQ(summary.num_views_used, 8);
    EXPECT_EQ(summary.num_camera_corners, 8 * 54);
    EXPECT_EQ(summary.num_projector_corners, 8 * 54);
    ASSERT_EQ(summary.views.size(), 8u);
    for (size_t v = 0; v < poses.size(); ++v) {
      EXPECT_TRUE(summary.views[v].used);
      EXPECT_EQ(summary.views[v].status, "used");
      EXPECT_LT(RotationAngleBetween(summary.views[v].cam_from_board.rotation, poses[v].rotation),
                1e-9);
      EXPECT_LT((summary.views[v].cam_from_board.translation - poses[v].translation).norm(), 1e-9);
    }
  }
}

TEST(RigCalibrator, NoisyObservationsGiveTheRigWithinTheirUncertainty) {
  const RigCalibration truth = TrueRig();
  const BoardSpec board = BoardSpecFromString("11x8x0.02");
  const std::vector<Rigid3d> poses = MakePoses(truth, board, 24, 2);
  std::mt19937_64 engine(2);
  constexpr double kSigma = 0.05;  // px per axis
  RigCalibrator calibrator(board);
  for (size_t v = 0; v < poses.size(); ++v) {
    calibrator.AddObservation(
        Observe(truth, board, poses[v], kSigma, &engine, "v" + std::to_string(v)), Sizes(truth));
  }
  const CalibrationSummary summary = calibrator.Calibrate();
  const Errors errors = Compare(summary.calibration, truth);
  std::printf(
      "sigma %.2f px: focal %.4f%%, principal point %.3f px, baseline %.4f%%, rotation "
      "%.4f deg\n",
      kSigma, 100 * errors.focal, errors.principal_point, 100 * errors.baseline,
      errors.rotation / kDegree);
  EXPECT_LT(errors.focal, 0.001);
  EXPECT_LT(errors.principal_point, 1.0);
  EXPECT_LT(errors.baseline, 0.002);
  EXPECT_LT(errors.rotation, 0.05 * kDegree);
  // RMS of 2D residuals ≈ σ·√2 (less the fitted parameters' share).
  EXPECT_NEAR(summary.calibration.rms_camera_px, kSigma * std::sqrt(2.0), 0.01);
  EXPECT_NEAR(summary.calibration.rms_projector_px, kSigma * std::sqrt(2.0), 0.01);
  EXPECT_NEAR(summary.calibration.rms_stereo_px, kSigma * std::sqrt(2.0), 0.01);
  EXPECT_EQ(summary.solver_termination, "CONVERGENCE");
  EXPECT_NE(summary.BriefReport().find("24 used, 0 dropped"), std::string::npos);
}

TEST(RigCalibrator, MissingProjectorCornersAndAViewThatDoesNotFit) {
  const RigCalibration truth = TrueRig();
  const BoardSpec board = BoardSpecFromString("9x6x0.025");
  const std::vector<Rigid3d> poses = MakePoses(truth, board, 10, 3);
  std::mt19937_64 engine(3);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  RigCalibrator calibrator(board);
  int projector_corners = 0;
  for (size_t v = 0; v < poses.size(); ++v) {
    BoardObservation observation =
        Observe(truth, board, poses[v], 0.03, &engine, "v" + std::to_string(v));
    if (v == 4) {
      // The board moved between the white frame and the codes: the projector saw it 1 cm
      // further right.
      const Rigid3d moved(poses[v].rotation, poses[v].translation + Eigen::Vector3d(0.01, 0, 0));
      observation.projector_corners =
          Observe(truth, board, moved, 0.03, &engine, "").projector_corners;
    } else if (v == 6) {
      for (auto& corner : observation.projector_corners) corner.reset();  // projector off
    } else {
      for (auto& corner : observation.projector_corners) {
        if (unit(engine) < 0.2) corner.reset();  // shadowed or undecodable
      }
    }
    if (v != 4) projector_corners += observation.NumProjectorCorners();
    calibrator.AddObservation(observation, Sizes(truth));
  }
  const CalibrationSummary summary = calibrator.Calibrate();
  EXPECT_EQ(summary.num_views_used, 9);
  EXPECT_EQ(summary.num_views_dropped, 1);
  const CalibrationViewReport& moved = summary.views[4];
  EXPECT_FALSE(moved.used);
  EXPECT_TRUE(moved.board_found);
  EXPECT_EQ(moved.status.rfind("dropped: RMS", 0), 0u) << moved.status;
  EXPECT_GT(moved.rms_projector_px, 2.0);
  EXPECT_LT(summary.views[6].rms_camera_px, 0.1);
  EXPECT_EQ(summary.views[6].projector_corners, 0);
  EXPECT_TRUE(std::isnan(summary.views[6].rms_projector_px));
  EXPECT_EQ(summary.num_projector_corners, projector_corners);
  const Errors errors = Compare(summary.calibration, truth);
  EXPECT_LT(errors.focal, 0.002);
  EXPECT_LT(errors.principal_point, 2.0);
  EXPECT_LT(errors.rotation, 0.1 * kDegree);
  EXPECT_LT(summary.calibration.rms_projector_px, 0.1);
  EXPECT_NE(summary.BriefReport().find("v4: dropped: RMS"), std::string::npos);

  // Without dropping, the moved view spoils the fit.
  CalibrationOptions keep_all;
  keep_all.max_drop_rounds = 0;
  RigCalibrator stubborn(board, keep_all);
  engine.seed(3);
  for (size_t v = 0; v < poses.size(); ++v) {
    BoardObservation observation = Observe(truth, board, poses[v], 0.03, &engine, "");
    if (v == 4) {
      const Rigid3d moved_pose(poses[v].rotation,
                               poses[v].translation + Eigen::Vector3d(0.01, 0, 0));
      observation.projector_corners =
          Observe(truth, board, moved_pose, 0.03, &engine, "").projector_corners;
    }
    stubborn.AddObservation(observation, Sizes(truth));
  }
  EXPECT_GT(stubborn.Calibrate().calibration.rms_projector_px, 1.0);
}

TEST(RigCalibrator, DistortionTermsLeftOutStayZero) {
  const RigCalibration truth = TrueRig();
  const BoardSpec board = BoardSpecFromString("9x6x0.025");
  const std::vector<Rigid3d> poses = MakePoses(truth, board, 6, 4);
  std::mt19937_64 engine(4);
  CalibrationOptions options;
  options.camera_distortion = DistortionTermsFromString("k1,k2");
  options.projector_distortion = DistortionTerms::None();
  RigCalibrator calibrator(board, options);
  for (const Rigid3d& pose : poses) {
    calibrator.AddObservation(Observe(truth, board, pose, 0.0, &engine, "v"), Sizes(truth));
  }
  const CalibrationSummary summary = calibrator.Calibrate();
  const std::vector<double>& camera = summary.calibration.camera.distortion;
  const std::vector<double>& projector = summary.calibration.projector.distortion;
  ASSERT_EQ(camera.size(), 5u);
  EXPECT_NE(camera[0], 0.0);
  EXPECT_NE(camera[1], 0.0);
  EXPECT_EQ(camera[2], 0.0);
  EXPECT_EQ(camera[3], 0.0);
  EXPECT_EQ(camera[4], 0.0);
  for (double c : projector) EXPECT_EQ(c, 0.0);
  // The model is wrong (the truth has tangential and projector distortion): it shows in the
  // residuals of these exact observations.
  EXPECT_GT(summary.calibration.rms_stereo_px, 1e-3);
}

TEST(RigCalibrator, RefusesTooFewViewsAndMismatchedInput) {
  const RigCalibration truth = TrueRig();
  const BoardSpec board = BoardSpecFromString("9x6x0.025");
  const std::vector<Rigid3d> poses = MakePoses(truth, board, 3, 5);
  std::mt19937_64 engine(5);
  RigCalibrator calibrator(board);
  EXPECT_THROW_WITH_MESSAGE(calibrator.Calibrate(), Error, "no views");  // no views
  calibrator.AddObservation(Observe(truth, board, poses[0], 0.0, &engine, "a"), Sizes(truth));
  calibrator.AddObservation(Observe(truth, board, poses[1], 0.0, &engine, "b"), Sizes(truth));
  try {
    calibrator.Calibrate();
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("only 2 usable views"), std::string::npos) << e.what();
  }
  DeviceSizes other = Sizes(truth);
  other.projector_width = 800;
  try {
    calibrator.AddObservation(Observe(truth, board, poses[2], 0.0, &engine, "c"), other);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("view c has a 1280x720 camera and a 800x768 projector "
                                         "but view a has 1280x720 and 1024x768"),
              std::string::npos)
        << e.what();
  }
  BoardObservation short_view = Observe(truth, board, poses[2], 0.0, &engine, "d");
  short_view.camera_corners.pop_back();
  EXPECT_THROW_WITH_MESSAGE(calibrator.AddObservation(short_view, Sizes(truth)), Error, "view d",
                            "53 camera and 54 projector corners");
  // The projector must see the board in at least three views.
  BoardObservation dark = Observe(truth, board, poses[2], 0.0, &engine, "e");
  for (auto& corner : dark.projector_corners) corner.reset();
  calibrator.AddObservation(dark, Sizes(truth));
  try {
    calibrator.Calibrate();
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("the projector saw"), std::string::npos) << e.what();
  }
}

TEST(CalibrationOptions, NamesAndChecks) {
  EXPECT_EQ(DistortionTerms().ToString(), "k1,k2,p1,p2,k3");
  EXPECT_EQ(DistortionTerms::None().ToString(), "none");
  EXPECT_EQ(DistortionTermsFromString("k3,k1").ToString(), "k1,k3");
  EXPECT_EQ(DistortionTermsFromString("k1,k2,p1,p2").FixedIndices(), std::vector<int>{4});
  EXPECT_THROW_WITH_MESSAGE(DistortionTermsFromString("k4"), Error, "'k4'");
  EXPECT_THROW_WITH_MESSAGE(DistortionTermsFromString(""), Error, "distortion terms ''");
  for (RobustLoss loss : {RobustLoss::kNone, RobustLoss::kHuber, RobustLoss::kCauchy}) {
    EXPECT_EQ(RobustLossFromString(ToString(loss)), loss);
  }
  EXPECT_THROW_WITH_MESSAGE(RobustLossFromString("tukey"), Error, "'tukey'");
  EXPECT_NO_THROW(CalibrationOptions().Check());
  // Each invalid option is named in the message, with its value.
  const auto expect_invalid = [](auto change, const char* key, const char* value) {
    CalibrationOptions options;
    change(&options);
    EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, key, value);
  };
  expect_invalid([](CalibrationOptions* o) { o->loss_scale_px = 0; }, "loss_scale_px", "got 0");
  expect_invalid([](CalibrationOptions* o) { o->max_view_rms_ratio = 1.0; }, "max_view_rms_ratio",
                 "got 1");
  expect_invalid([](CalibrationOptions* o) { o->min_views = 2; }, "min_views", "got 2");
  expect_invalid([](CalibrationOptions* o) { o->num_threads = 0; }, "num_threads", "got 0");
  expect_invalid([](CalibrationOptions* o) { o->min_projector_corner_fraction = 0; },
                 "min_projector_corner_fraction", "got 0");
  expect_invalid([](CalibrationOptions* o) { o->local_homography.ransac_threshold_px = -1; },
                 "ransac_threshold_px", "got -1");
  EXPECT_THROW_WITH_MESSAGE(RigCalibrator(BoardSpec{1, 6, 0.02}), Error, "board 1x6", "2x2");
}

TEST(CalibrationReport, JsonPlotAndSidecarNames) {
  const RigCalibration truth = TrueRig();
  const BoardSpec board = BoardSpecFromString("9x6x0.025");
  const std::vector<Rigid3d> poses = MakePoses(truth, board, 5, 6);
  std::mt19937_64 engine(6);
  RigCalibrator calibrator(board);
  for (size_t v = 0; v < poses.size(); ++v) {
    calibrator.AddObservation(
        Observe(truth, board, poses[v], 0.05, &engine, "dir/view_" + std::to_string(v)),
        Sizes(truth));
  }
  const CalibrationSummary summary = calibrator.Calibrate();
  const nlohmann::json report = nlohmann::json::parse(CalibrationReportJson(summary));
  EXPECT_EQ(report["format"], "sope-calibration-report/1");
  EXPECT_EQ(report["board"]["cols"], 9);
  EXPECT_EQ(report["views"].size(), 5u);
  EXPECT_EQ(report["views"][0]["name"], "dir/view_0");
  EXPECT_EQ(report["views"][0]["camera_corners"], 54);
  EXPECT_NEAR(report["views"][2]["rms_camera_px"].get<double>(), summary.views[2].rms_camera_px,
              1e-12);
  EXPECT_EQ(report["views"][1]["cam_from_board"]["rotation"].size(), 3u);
  EXPECT_NEAR(report["baseline_m"].get<double>(), summary.calibration.BaselineLength(), 1e-12);
  const cv::Mat plot = DrawResidualPlot(summary);
  EXPECT_EQ(plot.type(), CV_8UC3);
  EXPECT_GT(plot.cols, 800);
  EXPECT_EQ(CalibrationSidecarPath("out/cal.yaml", ".report.json"), "out/cal.report.json");
  EXPECT_EQ(CalibrationSidecarPath("cal", ".residuals.png"), "cal.residuals.png");
  EXPECT_EQ(CalibrationSidecarPath("a.b/cal", ".x"), "a.b/cal.x");
  EXPECT_EQ(CalibrationSidecarPath("dir/.hidden", ".x"), "dir/.hidden.x");
}

}  // namespace
}  // namespace sope
