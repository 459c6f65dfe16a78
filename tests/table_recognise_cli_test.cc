// `sope recognise --table` on bad and empty input (issue 12): a cloud with no plane and a
// table with nothing on it are results ("objects": [], exit 0); a cloud with a NaN point
// or a single point is one clear error line and a non-zero exit. And a synthetic table
// with one known object standing on it: one object, segmented PLY written; the range band
// (--min-range, --max-range) leaves it out when it lies outside.
#include <cmath>
#include <filesystem>
#include <limits>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/camera_model.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"
#include "tests/test_support.h"

namespace sope {
namespace {
namespace fs = std::filesystem;

testing::CommandRun Sope(const std::string& arguments, const testing::ScratchDir& scratch) {
  return testing::RunCommand(SOPE_BINARY, arguments, scratch);
}

// A horizontal table (the plane y = 0.1 m below the camera axis… tilted: n·p + d = 0 with
// n = (0, −cos 40°, −sin 40°)), sampled on a 2 mm grid over 40 × 40 cm around (0, 0.1, 0.6).
PointCloud TablePoints(const Eigen::Vector3f& origin, const Eigen::Vector3f& u,
                       const Eigen::Vector3f& v) {
  PointCloud cloud;
  for (int i = -100; i < 100; ++i) {
    for (int k = -100; k < 100; ++k) cloud.points.push_back(origin + 0.002f * i * u + 0.002f * k * v);
  }
  return cloud;
}

class TableRecogniseCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir();
    const std::string models = scratch_->File("models");
    WriteMesh(models + "/mug/mug_0.obj", MakeObject(ObjectClass::kMug, 0));
    WriteMesh(models + "/bottle/bottle_0.obj", MakeObject(ObjectClass::kBottle, 0));
    const testing::CommandRun build = Sope(
        "build-db --models " + models + " --out " + scratch_->File("db.sopedb") + " --views 60",
        *scratch_);
    ASSERT_EQ(build.exit_code, 0) << build.err;
  }
  static void TearDownTestSuite() { delete scratch_; }
  static testing::ScratchDir* scratch_;
  std::string Db() const { return scratch_->File("db.sopedb"); }
};
testing::ScratchDir* TableRecogniseCli::scratch_ = nullptr;

const Eigen::Vector3f kOrigin(0.0f, 0.1f, 0.6f);
const Eigen::Vector3f kU(1.0f, 0.0f, 0.0f);
const Eigen::Vector3f kV(0.0f, std::sin(0.7f), -std::cos(0.7f));  // ⟂ the table normal

TEST_F(TableRecogniseCli, EmptyTableAndNoPlaneAreResults) {
  WritePointCloud(scratch_->File("empty_table.ply"), TablePoints(kOrigin, kU, kV));
  const testing::CommandRun empty =
      Sope("recognise --table --json --db " + Db() + " --cloud " + scratch_->File("empty_table.ply"),
           *scratch_);
  ASSERT_EQ(empty.exit_code, 0) << empty.err;
  const nlohmann::json j = nlohmann::json::parse(empty.out);
  EXPECT_EQ(j["objects"].size(), 0u);
  EXPECT_TRUE(j["table"]["found"].get<bool>());
  EXPECT_FALSE(j["recognised"].get<bool>());

  // A sphere shell: no plane holds 15% of it.
  PointCloud ball;
  for (int i = 0; i < 4000; ++i) {
    const double z = 1.0 - 2.0 * (i + 0.5) / 4000, phi = i * 2.399963;
    const double r = std::sqrt(1 - z * z);
    ball.points.emplace_back(0.05 * r * std::cos(phi), 0.05 * r * std::sin(phi), 0.6 + 0.05 * z);
  }
  WritePointCloud(scratch_->File("ball.ply"), ball);
  const testing::CommandRun no_plane = Sope(
      "recognise --table --json --db " + Db() + " --cloud " + scratch_->File("ball.ply"), *scratch_);
  ASSERT_EQ(no_plane.exit_code, 0) << no_plane.err;
  const nlohmann::json k = nlohmann::json::parse(no_plane.out);
  EXPECT_EQ(k["objects"].size(), 0u);
  EXPECT_FALSE(k["table"]["found"].get<bool>());
}

TEST_F(TableRecogniseCli, NanAndSinglePointAreOneLineErrors) {
  PointCloud nan_cloud = TablePoints(kOrigin, kU, kV);
  nan_cloud.points[5].y() = std::numeric_limits<float>::quiet_NaN();
  WritePointCloud(scratch_->File("nan.ply"), nan_cloud);
  testing::ExpectOneLineError(
      Sope("recognise --table --db " + Db() + " --cloud " + scratch_->File("nan.ply"), *scratch_),
      "recognise", "non-finite");
  PointCloud single;
  single.points.emplace_back(0.0f, 0.0f, 0.6f);
  WritePointCloud(scratch_->File("single.ply"), single);
  testing::ExpectOneLineError(
      Sope("recognise --table --db " + Db() + " --cloud " + scratch_->File("single.ply"), *scratch_),
      "recognise", "1 point");
}

// The mug rendered by an ideal depth camera from 45° above, standing on the table plane
// (model z up along the table normal), plus the table points; `cam_from_model` gets its pose.
PointCloud MugOnTheTable(Rigid3d* cam_from_model_out) {
  const Eigen::Vector3f up = kU.cross(kV).normalized() * (kU.cross(kV).dot(-kOrigin) > 0 ? 1.0f : -1.0f);
  Rigid3d cam_from_model;
  cam_from_model.rotation.col(0) = kU.cast<double>();
  cam_from_model.rotation.col(2) = up.cast<double>();
  cam_from_model.rotation.col(1) = up.cast<double>().cross(kU.cast<double>());
  cam_from_model.translation = kOrigin.cast<double>();
  // Turned about the vertical so that the handle shows beside the body.
  cam_from_model.rotation =
      cam_from_model.rotation * Eigen::AngleAxisd(-0.6, Eigen::Vector3d::UnitZ()).matrix();
  const TriangleMesh mug = MakeObject(ObjectClass::kMug, 0);
  DepthRenderer renderer(MakePinhole(1280, 960, 1.0));
  renderer.SetMesh(mug);
  PointCloud scene = renderer.Render(cam_from_model);
  // Table points not hidden behind the mug: keep those whose ray misses the mug's cloud
  // bounding box (coarse, enough for the test: the hidden strip is small).
  const PointCloud table = TablePoints(kOrigin, kU, kV);
  Eigen::Vector2f lo(1e9f, 1e9f), hi(-1e9f, -1e9f);
  for (const Eigen::Vector3f& p : scene.points) {
    lo = lo.cwiseMin(p.head<2>() / p.z());
    hi = hi.cwiseMax(p.head<2>() / p.z());
  }
  for (const Eigen::Vector3f& p : table.points) {
    const Eigen::Vector2f uv = p.head<2>() / p.z();
    if ((uv.array() >= lo.array()).all() && (uv.array() <= hi.array()).all()) continue;
    scene.points.push_back(p);
  }
  scene.normals.clear();
  *cam_from_model_out = cam_from_model;
  return scene;
}

TEST_F(TableRecogniseCli, FindsTheMugOnTheTableAndWritesItsSegment) {
  Rigid3d cam_from_model;
  const PointCloud scene = MugOnTheTable(&cam_from_model);
  ASSERT_GT(scene.size(), 2000u);
  const TriangleMesh mug = MakeObject(ObjectClass::kMug, 0);
  WritePointCloud(scratch_->File("mug_table.ply"), scene);
  const testing::CommandRun run =
      Sope("recognise --table --json --db " + Db() + " --cloud " + scratch_->File("mug_table.ply") +
               " --object-clouds " + scratch_->File("segments"),
           *scratch_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const nlohmann::json j = nlohmann::json::parse(run.out);
  ASSERT_EQ(j["objects"].size(), 1u) << run.out;
  EXPECT_EQ(j["class"], "mug");
  EXPECT_EQ(j["objects"][0]["class"], "mug");
  EXPECT_TRUE(j["objects"][0]["verified"].get<bool>());
  // Centre of the mug's bounding box within 5 mm of the truth.
  Eigen::Vector3f box_lo, box_hi;
  mug.Bounds(&box_lo, &box_hi);
  const Eigen::Vector3d centre = cam_from_model * (0.5 * (box_lo + box_hi)).cast<double>();
  Eigen::Matrix3d rotation;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) rotation(r, c) = j["pose"]["rotation"][r][c].get<double>();
  }
  const Eigen::Vector3d t(j["pose"]["translation"][0].get<double>(),
                          j["pose"]["translation"][1].get<double>(),
                          j["pose"]["translation"][2].get<double>());
  const Eigen::Vector3d estimate = rotation * (0.5 * (box_lo + box_hi)).cast<double>() + t;
  EXPECT_LT((estimate - centre).norm(), 0.005) << run.out.substr(0, 900);
  const PointCloud segment = ReadPointCloud(scratch_->File("segments/object_0.ply"));
  EXPECT_EQ(static_cast<int>(segment.size()), j["objects"][0]["points"].get<int>());
  EXPECT_GT(segment.size(), 1000u);
}

// --min-range / --max-range: the segmentation's range band (what scan-and-recognise reports
// as scan.range_band_m), so that a saved scan is recognised again as the scan was. The mug
// stands 0.6 m from the camera: a band ending at 0.5 m or starting at 0.75 m leaves it out.
TEST_F(TableRecogniseCli, TheRangeBandLeavesOutWhatLiesOutsideIt) {
  Rigid3d cam_from_model;
  WritePointCloud(scratch_->File("mug_band.ply"), MugOnTheTable(&cam_from_model));
  const std::string base =
      "recognise --table --json --db " + Db() + " --cloud " + scratch_->File("mug_band.ply");
  const testing::CommandRun inside = Sope(base + " --min-range 0.3 --max-range 0.9", *scratch_);
  ASSERT_EQ(inside.exit_code, 0) << inside.err;
  const nlohmann::json in = nlohmann::json::parse(inside.out);
  ASSERT_EQ(in["objects"].size(), 1u) << inside.out.substr(0, 600);
  EXPECT_EQ(in["objects"][0]["class"], "mug");
  for (const char* band : {" --max-range 0.5", " --min-range 0.75"}) {
    const testing::CommandRun outside = Sope(base + band, *scratch_);
    ASSERT_EQ(outside.exit_code, 0) << band << ": " << outside.err;
    const nlohmann::json out = nlohmann::json::parse(outside.out);
    EXPECT_EQ(out["objects"].size(), 0u) << band << ": " << outside.out.substr(0, 600);
  }
  testing::ExpectOneLineError(Sope(base + " --min-range 0.9 --max-range 0.5", *scratch_),
                              "recognise", "range");
  testing::ExpectOneLineError(
      Sope("recognise --db " + Db() + " --cloud " + scratch_->File("mug_band.ply") +
               " --max-range 0.9",
           *scratch_),
      "recognise", "--table");
}

}  // namespace
}  // namespace sope
