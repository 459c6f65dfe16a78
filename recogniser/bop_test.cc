// BOP conventions: the results CSV read back by bop_toolkit's column rules, and MSSD / MSPD
// on poses whose errors are computed by hand.
#include "recogniser/bop.h"

#include <cmath>
#include <iterator>
#include <sstream>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "core/error.h"
#include "core/units.h"

namespace sope {
namespace {


Eigen::Matrix3d Rz(double angle) {
  return Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

std::vector<Eigen::Vector3d> CubeCorners(double half) {
  std::vector<Eigen::Vector3d> corners;
  for (int i = 0; i < 8; ++i) {
    corners.emplace_back(i & 1 ? half : -half, i & 2 ? half : -half, i & 4 ? half : -half);
  }
  return corners;
}

TEST(BopCsv, ParsedBackByTheBopColumnRules) {
  std::vector<BopEstimate> estimates(2);
  estimates[0] = {1, 3, 5, 0.875,
                  Rigid3d(Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized())
                              .toRotationMatrix(),
                          Eigen::Vector3d(0.0123, -0.045, 0.6)),
                  0.25};
  estimates[1] = {1, 4, 2, 0.5, Rigid3d(Rz(1.0), Eigen::Vector3d(0.1, 0.2, 0.7)), 0.125};
  const std::string text = FormatBopCsv(estimates);

  // bop_toolkit inout.load_bop_results: the header line, then per line
  // elems = line.split(','), len(elems) == 7, R = 9 floats of elems[4].split(),
  // t = 3 floats of elems[5].split() (millimetres), time = float(elems[6]).
  std::istringstream stream(text);
  std::string line;
  std::getline(stream, line);
  EXPECT_EQ(line, "scene_id,im_id,obj_id,score,R,t,time");
  for (const BopEstimate& expected : estimates) {
    ASSERT_TRUE(std::getline(stream, line));
    std::vector<std::string> elems;
    std::stringstream columns(line);
    for (std::string elem; std::getline(columns, elem, ',');) elems.push_back(elem);
    ASSERT_EQ(elems.size(), 7u) << line;
    EXPECT_EQ(std::stoi(elems[0]), expected.scene_id);
    EXPECT_EQ(std::stoi(elems[1]), expected.im_id);
    EXPECT_EQ(std::stoi(elems[2]), expected.obj_id);
    EXPECT_DOUBLE_EQ(std::stod(elems[3]), expected.score);
    std::istringstream r_text(elems[4]), t_text(elems[5]);
    std::vector<double> r((std::istream_iterator<double>(r_text)), std::istream_iterator<double>());
    std::vector<double> t((std::istream_iterator<double>(t_text)), std::istream_iterator<double>());
    ASSERT_EQ(r.size(), 9u);
    ASSERT_EQ(t.size(), 3u);
    for (int i = 0; i < 9; ++i) {
      EXPECT_DOUBLE_EQ(r[i], expected.cam_from_model.rotation(i / 3, i % 3)) << i;  // row-major
    }
    for (int i = 0; i < 3; ++i) {
      EXPECT_NEAR(t[i], 1000.0 * expected.cam_from_model.translation[i], 1e-9) << i;  // mm
    }
    EXPECT_DOUBLE_EQ(std::stod(elems[6]), expected.time_s);  // seconds
  }
  EXPECT_FALSE(std::getline(stream, line));

  const std::vector<BopEstimate> parsed = ParseBopCsv(text, "results.csv");
  ASSERT_EQ(parsed.size(), 2u);
  EXPECT_EQ(parsed[1].im_id, 4);
  EXPECT_LT((parsed[0].cam_from_model.rotation - estimates[0].cam_from_model.rotation).norm(),
            1e-15);
  EXPECT_LT((parsed[0].cam_from_model.translation - estimates[0].cam_from_model.translation)
                .norm(),
            1e-15);
}

TEST(BopCsv, MalformedFilesAreRefused) {
  const std::string header = "scene_id,im_id,obj_id,score,R,t,time\n";
  const std::string good = "1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 500,0.1\n";
  EXPECT_NO_THROW(ParseBopCsv(header + good, "ok.csv"));
  for (const std::string& bad :
       {std::string("scene_id,im_id,obj_id,score,R,t\n") + good,
        header + "1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 500\n",
        header + "1,2,3,0.5,1 0 0 0 1 0 0 0,0 0 500,0.1\n",
        header + "1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 x,0.1\n",
        header + "1.5,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 500,0.1\n"}) {
    EXPECT_THROW(ParseBopCsv(bad, "bad.csv"), Error) << bad;
  }
}

TEST(BopErrors, MssdAndMspdEqualHandComputedValues) {
  const std::vector<Eigen::Vector3d> cube = CubeCorners(0.05);
  const Rigid3d gt(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 0.5));

  // Shifted 10 mm along x: every point moves 10 mm.
  const Rigid3d shifted(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.01, 0, 0.5));
  EXPECT_NEAR(Mssd(shifted, gt, cube), 0.01, 1e-12);
  // MSPD with f = 500 px: a shift of 0.01 m at depth z moves a point 500·0.01/z px; the
  // nearest corners (z = 0.45 m) move most: 11.111… px.
  Eigen::Matrix3d camera;
  camera << 500, 0, 320, 0, 500, 240, 0, 0, 1;
  EXPECT_NEAR(Mspd(shifted, gt, camera, cube), 500.0 * 0.01 / 0.45, 1e-9);

  // Turned 90° about the model z axis: a corner at (±a, ±a) moves 2·sin(45°)·a·√2 = 2a.
  const Rigid3d turned(Rz(kPi / 2), Eigen::Vector3d(0, 0, 0.5));
  EXPECT_NEAR(Mssd(turned, gt, cube), 0.1, 1e-12);
  // With the cube's 4-fold symmetry about z the turn is no error at all …
  std::vector<Rigid3d> symmetries;
  for (int i = 0; i < 4; ++i) symmetries.emplace_back(Rz(i * kPi / 2), Eigen::Vector3d::Zero());
  EXPECT_NEAR(Mssd(turned, gt, cube, symmetries), 0.0, 1e-12);
  EXPECT_NEAR(Mspd(turned, gt, camera, cube, symmetries), 0.0, 1e-9);
  // … and a 100° turn is 10° from the nearest symmetric pose: 2·sin(5°)·a·√2.
  const Rigid3d turned100(Rz(kPi * 100 / 180), Eigen::Vector3d(0, 0, 0.5));
  EXPECT_NEAR(Mssd(turned100, gt, cube, symmetries),
              2.0 * std::sin(kPi * 5 / 180) * 0.05 * std::sqrt(2.0), 1e-12);
  // Without the identity in the set, the identity pose is not free.
  EXPECT_NEAR(Mssd(gt, gt, cube, {Rigid3d(Rz(kPi / 2), Eigen::Vector3d::Zero())}), 0.1, 1e-12);
}

TEST(BopErrors, RecallOverTheBopThresholds) {
  const std::vector<double> mssd = MssdThresholds(0.2);
  ASSERT_EQ(mssd.size(), 10u);
  EXPECT_NEAR(mssd.front(), 0.01, 1e-15);
  EXPECT_NEAR(mssd.back(), 0.1, 1e-15);
  const std::vector<double> mspd = MspdThresholds(1280);  // 5..50 px × 1280/640
  EXPECT_DOUBLE_EQ(mspd.front(), 10.0);
  EXPECT_DOUBLE_EQ(mspd.back(), 100.0);
  // 0.005 is below all ten thresholds, 0.012 below nine (not 0.01), 0.3 below none.
  const std::vector<double> errors = {0.005, 0.012, 0.3};
  EXPECT_NEAR(RecallAt(errors, 0.01), 1.0 / 3.0, 1e-15);
  EXPECT_NEAR(AverageRecall(errors, mssd), (10.0 + 9.0 + 0.0) / 30.0, 1e-12);
  // Strictly below: an error equal to a threshold does not count.
  EXPECT_EQ(RecallAt({10.0}, 10.0), 0.0);
  EXPECT_EQ(AverageRecall({}, mspd), 0.0);
  EXPECT_THROW(MssdThresholds(0.0), Error);
  EXPECT_THROW(MspdThresholds(0), Error);
}

}  // namespace
}  // namespace sope
