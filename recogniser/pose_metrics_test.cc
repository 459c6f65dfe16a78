#include "recogniser/pose_metrics.h"

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "core/error.h"
#include "core/units.h"
#include "simulator/primitives.h"
#include "simulator/procedural_objects.h"

namespace sope {
namespace {

Eigen::Matrix3d Turn(const Eigen::Vector3d& axis, double degrees) {
  return Eigen::AngleAxisd(DegToRad(degrees), axis.normalized()).toRotationMatrix();
}

TEST(PoseMetrics, RotationErrorAndAdd) {
  const Eigen::Matrix3d a = Turn(Eigen::Vector3d(1, 2, 3), 30);
  EXPECT_NEAR(RotationErrorDeg(a, a * Turn(Eigen::Vector3d::UnitX(), 7.5)), 7.5, 1e-9);
  const std::vector<Eigen::Vector3f> points = SampleSurface(MakeBox(0.2, 0.1, 0.05), 20000);
  const Rigid3d pose(a, Eigen::Vector3d(0.01, 0.02, 0.6));
  Rigid3d shifted = pose;
  shifted.translation.x() += 0.003;
  EXPECT_NEAR(AverageDistance(points, pose, shifted), 0.003, 1e-9);
  EXPECT_NEAR(AverageDistance(points, pose, pose), 0.0, 1e-12);
  // ADD-S never exceeds ADD, and is ~0 for a symmetry of the box.
  const Rigid3d turned(a * Turn(Eigen::Vector3d::UnitZ(), 180), pose.translation);
  EXPECT_GT(AverageDistance(points, pose, turned), 0.03);
  EXPECT_LT(AverageDistanceSymmetric(points, pose, turned), 0.002);
}

TEST(PoseMetrics, SamplesLieOnTheSurface) {
  const std::vector<Eigen::Vector3f> points = SampleSurface(MakeSphere(0.1, 64, 128), 3000, 7);
  ASSERT_EQ(points.size(), 3000u);
  for (const Eigen::Vector3f& p : points) {
    EXPECT_LE(p.norm(), 0.1f + 1e-6f);
    EXPECT_GE(p.norm(), 0.1f - SphereTessellationGap(0.1, 64, 128) - 1e-6f);
  }
  EXPECT_EQ(SampleSurface(MakeBox(1, 1, 1), 10, 3), SampleSurface(MakeBox(1, 1, 1), 10, 3));
}

TEST(PoseMetrics, DetectsTheSymmetriesOfKnownShapes) {
  // A capped cylinder: continuous about z, plus the half-turn that turns it upside down.
  const TriangleMesh cylinder = MakeCylinder(0.04, 0.15, 96, true);
  ModelSymmetry symmetry = DetectSymmetry(cylinder);
  EXPECT_TRUE(symmetry.continuous);
  EXPECT_NEAR(std::abs(symmetry.axis.z()), 1.0, 1e-3);
  EXPECT_EQ(symmetry.rotations.size(), 2u);
  // A box with three different edges: the four rotations of D2.
  const TriangleMesh box = MakeBox(0.2, 0.12, 0.06);
  symmetry = DetectSymmetry(box);
  EXPECT_FALSE(symmetry.continuous);
  EXPECT_EQ(symmetry.rotations.size(), 4u);
  // A mug: its handle leaves no rotation but the identity.
  const TriangleMesh mug = MakeObject(ObjectClass::kMug, 3);
  symmetry = DetectSymmetry(mug);
  EXPECT_FALSE(symmetry.continuous);
  EXPECT_EQ(symmetry.rotations.size(), 1u);
}

TEST(PoseMetrics, SymmetricRotationErrorIgnoresOnlyTheSymmetry) {
  const TriangleMesh cylinder = MakeCylinder(0.04, 0.15, 96, true);
  const ModelSymmetry symmetry =
      DetectSymmetry(cylinder);
  const Eigen::Matrix3d truth = Turn(Eigen::Vector3d(0.3, -1, 0.2), 40);
  // Any twist about the axis (model z) costs nothing; a tilt of the axis costs its angle.
  EXPECT_NEAR(SymmetricRotationErrorDeg(truth * Turn(Eigen::Vector3d::UnitZ(), 77), truth, symmetry),
              0.0, 0.2);
  EXPECT_NEAR(SymmetricRotationErrorDeg(truth * Turn(Eigen::Vector3d::UnitX(), 5), truth, symmetry),
              5.0, 0.3);
  // Upside down is a symmetry of the capped cylinder.
  EXPECT_NEAR(SymmetricRotationErrorDeg(truth * Turn(Eigen::Vector3d::UnitX(), 180), truth,
                                        symmetry),
              0.0, 0.3);
  // Without symmetry the plain error comes back.
  ModelSymmetry none;
  none.rotations = {Eigen::Matrix3d::Identity()};
  EXPECT_NEAR(SymmetricRotationErrorDeg(truth * Turn(Eigen::Vector3d::UnitZ(), 77), truth, none),
              77.0, 1e-6);
}

TEST(PoseMetrics, ComparePosesMeasuresRotationCentreAndAddS) {
  const TriangleMesh box = MakeBox(0.2, 0.1, 0.05);
  const Rigid3d truth(Turn(Eigen::Vector3d(1, -2, 0.5), 50), Eigen::Vector3d(0.02, -0.01, 0.6));
  const PoseTruthModel model = MakePoseTruthModel(box);
  EXPECT_NEAR(model.diameter, std::sqrt(0.2 * 0.2 + 0.1 * 0.1 + 0.05 * 0.05), 1e-6);
  // The truth itself: no error.
  PoseComparison c = ComparePoses(truth, truth, model);
  EXPECT_NEAR(c.rotation_error_deg, 0.0, 1e-6);
  EXPECT_NEAR(c.center_error_m, 0.0, 1e-12);
  EXPECT_NEAR(c.adds_m, 0.0, 1e-9);
  // Shifted 3 mm: the centre is 3 mm off, ADD-S at most that.
  Rigid3d shifted = truth;
  shifted.translation += truth.rotation * Eigen::Vector3d(0.003, 0, 0);
  c = ComparePoses(shifted, truth, model);
  EXPECT_NEAR(c.center_error_m, 0.003, 1e-9);
  EXPECT_NEAR(c.rotation_error_deg, 0.0, 1e-6);
  EXPECT_GT(c.adds_m, 0.0);
  EXPECT_LE(c.adds_m, 0.003 + 1e-9);
  // A half-turn about the box's own axis through its centre is a symmetry: no rotation
  // error, no centre error, ADD-S at the sampling floor; turned 10° about it is 10° off.
  const Rigid3d flipped(truth.rotation * Turn(Eigen::Vector3d::UnitZ(), 180), truth.translation);
  c = ComparePoses(flipped, truth, model);
  EXPECT_NEAR(c.rotation_error_deg, 0.0, 0.5);
  EXPECT_NEAR(c.center_error_m, 0.0, 1e-9);
  EXPECT_LT(c.adds_m, 0.002);
  const Rigid3d turned(truth.rotation * Turn(Eigen::Vector3d::UnitZ(), 10), truth.translation);
  EXPECT_NEAR(ComparePoses(turned, truth, model).rotation_error_deg, 10.0, 0.5);
  // The mesh overload is the default truth model; explicit samples give exactly the ADD-S
  // of those samples.
  EXPECT_EQ(ComparePoses(shifted, truth, box).adds_m, ComparePoses(shifted, truth, model).adds_m);
  PoseTruthModelOptions options;
  options.samples = 2000;
  options.seed = 5;
  EXPECT_EQ(ComparePoses(turned, truth, MakePoseTruthModel(box, options)).adds_m,
            AverageDistanceSymmetric(SampleSurface(box, 2000, 5), turned, truth));
  options.samples = 0;
  EXPECT_THROW(MakePoseTruthModel(box, options), Error);
}

}  // namespace
}  // namespace sope
