#include "recogniser/viewpoints.h"

#include <cmath>

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/units.h"
#include "tests/test_support.h"

namespace sope {
namespace {

constexpr double kDeg = kPi / 180.0;

// Every pose must be a proper rotation, put the centre on the optical axis at `distance`
// and have the model's +z pointing up in the image (−y_cam) wherever that is defined.
void ExpectLooksAtCentre(const Viewpoint& viewpoint, double distance,
                         const Eigen::Vector3d& center) {
  const Rigid3d cam_from_model = CameraPoseForViewpoint(viewpoint, distance, center);
  const Eigen::Matrix3d& rotation = cam_from_model.rotation;
  EXPECT_NEAR((rotation.transpose() * rotation - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
  EXPECT_NEAR(rotation.determinant(), 1.0, 1e-12);
  const Eigen::Vector3d center_in_cam = cam_from_model * center;
  EXPECT_NEAR(center_in_cam.x(), 0.0, 1e-12);
  EXPECT_NEAR(center_in_cam.y(), 0.0, 1e-12);
  EXPECT_NEAR(center_in_cam.z(), distance, 1e-12);
  // The camera sits in direction d from the centre.
  const Eigen::Vector3d camera_in_model = cam_from_model.Inverse().translation;
  EXPECT_NEAR((camera_in_model - (center + distance * viewpoint.Direction())).norm(), 0.0, 1e-12);
  // Up-vector: the model's +z projects to image-up (negative y_cam), never down.
  const Eigen::Vector3d up_in_cam = rotation * Eigen::Vector3d::UnitZ();
  if (std::sin(viewpoint.theta) > 1e-6) {
    EXPECT_NEAR(up_in_cam.x(), 0.0, 1e-12);  // no sideways tilt
    EXPECT_LT(up_in_cam.y(), 0.0);
  }
  // The round trip recovers the viewpoint.
  const Viewpoint back = ViewpointFromPose(cam_from_model, center);
  EXPECT_NEAR(AngleBetween(back, viewpoint), 0.0, 1e-6);
}

TEST(Viewpoints, ThesisLayoutHas18OnFiveRings) {
  const std::vector<Viewpoint> viewpoints = ThesisViewpoints();
  ASSERT_EQ(viewpoints.size(), 18u);
  std::map<int, int> per_ring;
  for (const Viewpoint& v : viewpoints) ++per_ring[static_cast<int>(std::lround(v.theta / kDeg))];
  EXPECT_EQ(per_ring, (std::map<int, int>{{0, 1}, {45, 4}, {90, 8}, {135, 4}, {180, 1}}));
  // Evenly spaced in φ on each ring: the 8 equatorial cameras 45° apart.
  for (size_t i = 0; i < viewpoints.size(); ++i) {
    for (size_t j = i + 1; j < viewpoints.size(); ++j) {
      EXPECT_GT(AngleBetween(viewpoints[i], viewpoints[j]), 44.9 * kDeg) << i << " " << j;
    }
  }
  EXPECT_EQ(MakeViewpoints(ViewpointLayout::kThesis18, 18).size(), 18u);
  EXPECT_THROW_WITH_MESSAGE(MakeViewpoints(ViewpointLayout::kThesis18, 20), Error, "18 viewpoints",
                            "20 requested");
}

TEST(Viewpoints, FibonacciCoversTheSphereEvenly) {
  for (int n : {1, 2, 18, 100, 500, 2000}) {
    const std::vector<Viewpoint> viewpoints = FibonacciViewpoints(n);
    ASSERT_EQ(static_cast<int>(viewpoints.size()), n);
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const Viewpoint& v : viewpoints) {
      EXPECT_NEAR(v.Direction().norm(), 1.0, 1e-12);
      EXPECT_GE(v.theta, 0.0);
      EXPECT_LE(v.theta, kPi);
      EXPECT_GE(v.phi, 0.0);
      EXPECT_LT(v.phi, 2.0 * kPi);
      mean += v.Direction();
    }
    if (n < 18) continue;
    // Balanced (the mean direction is near zero) and even: every direction on the sphere
    // lies within ~ the lattice spacing of a viewpoint, and no two viewpoints crowd.
    EXPECT_LT((mean / n).norm(), 0.05) << n;
    const double spacing = std::sqrt(4.0 * kPi / n);
    double min_pair = kPi;
    for (int i = 0; i < n; ++i) {
      for (int j = i + 1; j < n; ++j) {
        min_pair = std::min(min_pair, AngleBetween(viewpoints[i], viewpoints[j]));
      }
    }
    EXPECT_GT(min_pair, 0.5 * spacing) << n;
    const std::vector<Viewpoint> probes = FibonacciViewpoints(997);
    double worst = 0.0;
    for (const Viewpoint& probe : probes) {
      double nearest = kPi;
      for (const Viewpoint& v : viewpoints) nearest = std::min(nearest, AngleBetween(probe, v));
      worst = std::max(worst, nearest);
    }
    EXPECT_LT(worst, 0.9 * spacing) << n;
  }
  EXPECT_THROW_WITH_MESSAGE(FibonacciViewpoints(0), Error, "count", "got 0");
}

TEST(Viewpoints, PosesLookAtTheCentre) {
  const Eigen::Vector3d center(0.01, -0.02, 0.07);
  for (const Viewpoint& v : ThesisViewpoints()) ExpectLooksAtCentre(v, 0.6, center);
  for (const Viewpoint& v : FibonacciViewpoints(300)) ExpectLooksAtCentre(v, 0.45, center);
  EXPECT_THROW_WITH_MESSAGE(CameraPoseForViewpoint(Viewpoint{1.0, 1.0}, 0.0, center), Error,
                            "distance", "got 0");
}

TEST(Viewpoints, PolesAreContinuousAlongTheMeridian) {
  const Eigen::Vector3d center = Eigen::Vector3d::Zero();
  for (double phi : {0.0, 0.7, 2.0, 4.5}) {
    for (double pole : {0.0, kPi}) {
      const Viewpoint at_pole{pole, phi};
      ExpectLooksAtCentre(at_pole, 0.6, center);
      const double epsilon = 1e-5;
      const Viewpoint near_pole{pole == 0.0 ? epsilon : kPi - epsilon, phi};
      const Rigid3d a = CameraPoseForViewpoint(at_pole, 0.6, center);
      const Rigid3d b = CameraPoseForViewpoint(near_pole, 0.6, center);
      EXPECT_LT(RotationAngleBetween(a.rotation, b.rotation), 1e-4) << phi << " " << pole;
    }
  }
  // At the north pole the camera looks straight down (-z) and image-down is +meridian.
  const Rigid3d north = CameraPoseForViewpoint(Viewpoint{0.0, 0.0}, 0.6, center);
  EXPECT_NEAR((north.rotation.transpose() * Eigen::Vector3d::UnitZ() -
               Eigen::Vector3d(0, 0, -1)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((north.rotation.transpose() * Eigen::Vector3d::UnitY() -
               Eigen::Vector3d(1, 0, 0)).norm(), 0.0, 1e-12);
}

TEST(Viewpoints, LayoutNames) {
  EXPECT_EQ(ViewpointLayoutFromString(ToString(ViewpointLayout::kThesis18)),
            ViewpointLayout::kThesis18);
  EXPECT_EQ(ViewpointLayoutFromString("fibonacci"), ViewpointLayout::kFibonacci);
  EXPECT_THROW_WITH_MESSAGE(ViewpointLayoutFromString("grid"), Error, "'grid'");
}

}  // namespace
}  // namespace sope
