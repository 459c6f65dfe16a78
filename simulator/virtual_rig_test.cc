#include "simulator/virtual_rig.h"

#include <cmath>
#include <cstdlib>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/units.h"
#include "projector/patterns.h"
#include "simulator/osmesa_context.h"
#include "simulator/primitives.h"
#include "simulator/virtual_rig_internal.h"
#include "tests/test_support.h"

namespace sope {
namespace {


// No noise, no blur, linear response: captured grey levels are the model's linear values.
SensorOptions LinearNoiselessOptions() {
  SensorOptions options;
  options.read_noise = 0.0;
  options.shot_noise = 0.0;
  options.camera_blur_sigma_px = 0.0;
  options.defocus_sigma_px = 0.0;
  options.gamma = 1.0;
  return options;
}

// Plane whose model −z face (MakePlane's front) points along `normal_in_cam`, centred at
// `center_in_cam`.
SceneObject FacingPlane(const Eigen::Vector3d& center_in_cam, const Eigen::Vector3d& normal_in_cam,
                        double size = 2.0) {
  SceneObject object;
  object.mesh = MakePlane(size, size, 4);
  const Eigen::Vector3d z_axis = -normal_in_cam.normalized();
  const Eigen::Vector3d helper =
      std::abs(z_axis.y()) < 0.9 ? Eigen::Vector3d::UnitY() : Eigen::Vector3d::UnitX();
  const Eigen::Vector3d x_axis = helper.cross(z_axis).normalized();
  const Eigen::Vector3d y_axis = z_axis.cross(x_axis);
  Eigen::Matrix3d rotation;
  rotation << x_axis, y_axis, z_axis;
  object.cam_from_model = Rigid3d(rotation, center_in_cam);
  return object;
}

SceneObject SphereObject(const Eigen::Vector3d& center_in_cam, double radius, int rings,
                         int segments) {
  SceneObject object;
  object.mesh = MakeSphere(radius, rings, segments);
  object.cam_from_model = Rigid3d(Eigen::Matrix3d::Identity(), center_in_cam);
  return object;
}

Eigen::Vector3d ProjectorCenterInCam(const RigCalibration& calibration) {
  return calibration.proj_from_cam.Inverse().translation;
}

bool InsideImage(const CameraModel& device, const Eigen::Vector2d& pixel, double margin) {
  return pixel.x() >= -0.5 + margin && pixel.x() < device.width - 0.5 - margin &&
         pixel.y() >= -0.5 + margin && pixel.y() < device.height - 0.5 - margin;
}

bool OutsideImage(const CameraModel& device, const Eigen::Vector2d& pixel, double margin) {
  return pixel.x() < -0.5 - margin || pixel.x() >= device.width - 0.5 + margin ||
         pixel.y() < -0.5 - margin || pixel.y() >= device.height - 0.5 + margin;
}

// Distance from the ray through the origin along unit `ray` to `center`, and the entry
// distance of the ray into the sphere (NaN when it misses).
double RaySphereEntry(const Eigen::Vector3d& ray, const Eigen::Vector3d& center, double radius,
                      double* line_distance) {
  const double along = ray.dot(center);
  const double squared = center.squaredNorm() - along * along;
  *line_distance = std::sqrt(std::max(squared, 0.0));
  const double discriminant = radius * radius - squared;
  if (discriminant < 0.0) return std::numeric_limits<double>::quiet_NaN();
  return along - std::sqrt(discriminant);
}

// Distance from `point` to the segment a–b.
double SegmentDistance(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                       const Eigen::Vector3d& point) {
  const Eigen::Vector3d ab = b - a;
  const double s = std::clamp((point - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
  return (a + s * ab - point).norm();
}

// ---------------------------------------------------------------------------------------
// GL conventions.

TEST(IdRasteriser, ClipMatrixPutsOpenCvPixelsAtGlPixelCentres) {
  internal::PinholeView view;
  view.width = 640;
  view.height = 480;
  view.fx = 500.0;
  view.fy = 510.0;
  view.cx = 320.3;
  view.cy = 239.7;
  const double near = 0.1, far = 10.0;
  const Eigen::Matrix4d clip_from_device = internal::ClipFromDevice(view, near, far);
  for (const Eigen::Vector3d& point :
       {Eigen::Vector3d(0.1, -0.05, 1.3), Eigen::Vector3d(-0.4, 0.3, 0.7),
        Eigen::Vector3d(0.0, 0.0, 5.0)}) {
    const Eigen::Vector4d clip = clip_from_device * point.homogeneous();
    const Eigen::Vector3d ndc = clip.head<3>() / clip.w();
    const Eigen::Vector2d pixel = view.Project(point);
    // GL window coordinates: pixel (i, j) covers [i, i + 1) × [j, j + 1), centre i + ½.
    EXPECT_NEAR((ndc.x() + 1.0) * view.width / 2.0, pixel.x() + 0.5, 1e-9);
    EXPECT_NEAR((ndc.y() + 1.0) * view.height / 2.0, pixel.y() + 0.5, 1e-9);
  }
  Eigen::Vector4d clip = clip_from_device * Eigen::Vector4d(0.01, 0.02, near, 1.0);
  EXPECT_NEAR(clip.z() / clip.w(), -1.0, 1e-12);
  clip = clip_from_device * Eigen::Vector4d(0.01, 0.02, far, 1.0);
  EXPECT_NEAR(clip.z() / clip.w(), 1.0, 1e-12);
}

// Texel (i, j) must hold the triangle covering the ideal-image point (i, j) exactly: a
// half-pixel slip would flip a whole line of texels along every edge.
TEST(IdRasteriser, TexelIsTheTriangleCoveringItsPixelCentre) {
  internal::PinholeView view;
  view.width = 64;
  view.height = 48;
  view.fx = view.fy = 50.0;
  view.cx = 31.2;
  view.cy = 23.9;
  // Two triangles given in ideal-image pixels, the second in front where they overlap.
  const std::vector<Eigen::Vector2d> front = {{20.3, 5.7}, {60.6, 30.2}, {14.1, 44.9}};
  const std::vector<Eigen::Vector2d> back = {{2.2, 2.45}, {40.75, 3.1}, {5.5, 40.35}};
  const auto make_mesh = [&](const std::vector<Eigen::Vector2d>& corners, double depth) {
    TriangleMesh mesh;
    for (const Eigen::Vector2d& c : corners) {
      mesh.vertices.emplace_back((c.x() - view.cx) / view.fx * depth,
                                 (c.y() - view.cy) / view.fy * depth, depth);
    }
    mesh.faces.emplace_back(0, 1, 2);
    return mesh;
  };
  const TriangleMesh back_mesh = make_mesh(back, 2.0), front_mesh = make_mesh(front, 1.0);
  internal::IdRasteriser rasteriser;
  rasteriser.SetMeshes({&back_mesh, &front_mesh});
  cv::Mat ids;
  rasteriser.Render(view, {Rigid3d(), Rigid3d()}, 0.5, 3.0, &ids);
  ASSERT_EQ(ids.type(), CV_32SC1);
  ASSERT_EQ(ids.cols, view.width);
  ASSERT_EQ(ids.rows, view.height);

  // Signed distance of p inside the triangle (positive inside), pixels.
  const auto inside_distance = [](const std::vector<Eigen::Vector2d>& t, const Eigen::Vector2d& p) {
    double distance = std::numeric_limits<double>::infinity();
    const double orientation =
        (t[1] - t[0]).x() * (t[2] - t[0]).y() - (t[1] - t[0]).y() * (t[2] - t[0]).x();
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector2d a = t[k], b = t[(k + 1) % 3];
      const Eigen::Vector2d edge = b - a;
      const double cross = edge.x() * (p - a).y() - edge.y() * (p - a).x();
      distance = std::min(distance, (orientation > 0 ? cross : -cross) / edge.norm());
    }
    return distance;
  };
  int checked = 0, front_count = 0, back_count = 0;
  for (int j = 0; j < view.height; ++j) {
    for (int i = 0; i < view.width; ++i) {
      const Eigen::Vector2d p(i, j);
      const double in_front = inside_distance(front, p), in_back = inside_distance(back, p);
      if (std::abs(in_front) < 1e-3 || std::abs(in_back) < 1e-3) continue;
      const int expected = in_front > 0 ? 2 : (in_back > 0 ? 1 : 0);
      EXPECT_EQ(ids.at<int32_t>(j, i), expected) << "texel (" << i << ", " << j << ")";
      front_count += expected == 2;
      back_count += expected == 1;
      ++checked;
    }
  }
  EXPECT_GT(checked, view.width * view.height - 10);
  EXPECT_GT(front_count, 300);
  EXPECT_GT(back_count, 200);
}

TEST(IdRasteriser, CoveringViewContainsEveryPixelRay) {
  const RigCalibration calibration = DefaultRigCalibration();
  for (const CameraModel& device : {calibration.camera, calibration.projector}) {
    const internal::PinholeView view =
        internal::MakeCoveringView(device, internal::kIdealDensity, 16384);
    EXPECT_NEAR(view.fx, internal::kIdealDensity * device.fx(), 1e-9);
    for (int y = 0; y < device.height; y += 7) {
      for (int x : {0, 1, device.width / 2, device.width - 1}) {
        const Eigen::Vector2d texel = view.Project(device.RayFromImage(Eigen::Vector2d(x, y)));
        EXPECT_GE(texel.x(), internal::kIdealMarginTexels);
        EXPECT_GE(texel.y(), internal::kIdealMarginTexels);
        EXPECT_LE(texel.x(), view.width - 1 - internal::kIdealMarginTexels);
        EXPECT_LE(texel.y(), view.height - 1 - internal::kIdealMarginTexels);
      }
    }
  }
}

TEST(RayTable, MatchesExactUndistortionAtSubPixelPositions) {
  RigCalibration calibration = DefaultRigCalibration();
  CameraModel strong = calibration.camera;
  strong.distortion = {-0.3, 0.12, 0.002, -0.001, -0.02};  // a wide-angle lens
  for (const CameraModel& device : {calibration.camera, strong}) {
    internal::RayTable table;
    table.Build(device);
    cv::RNG rng(7);
    double max_error = 0.0;
    for (int i = 0; i < 20000; ++i) {
      const Eigen::Vector2d pixel(rng.uniform(-0.5, device.width - 0.5),
                                  rng.uniform(-0.5, device.height - 0.5));
      max_error = std::max(
          max_error,
          (table.CamFromImage(pixel) - device.CamFromImage(pixel)).lpNorm<Eigen::Infinity>());
    }
    EXPECT_LT(max_error, 1e-10);  // normalised plane: 0.1 nm at 1 m
    // Pixel centres are exact.
    EXPECT_EQ(table.CamFromImage(Eigen::Vector2d(17, 33)),
              device.CamFromImage(Eigen::Vector2d(17, 33)));
  }
}

// ---------------------------------------------------------------------------------------
// Default rig.

TEST(DefaultRig, ConvergesAtTheWorkingDistanceAndCoversAPlane) {
  const RigCalibration calibration = DefaultRigCalibration();
  EXPECT_NO_THROW(calibration.Check());
  EXPECT_EQ(calibration.camera.width, 1280);
  EXPECT_EQ(calibration.camera.height, 720);
  EXPECT_EQ(calibration.projector.width, 1024);
  EXPECT_EQ(calibration.projector.height, 768);
  EXPECT_NEAR(calibration.BaselineLength(), 0.2, 1e-12);
  const Eigen::Vector3d center = ProjectorCenterInCam(calibration);
  EXPECT_NEAR(center.x(), 0.2, 1e-12);  // to the camera's right
  EXPECT_NEAR(center.y(), 0.0, 1e-12);
  EXPECT_NEAR(center.z(), 0.0, 1e-12);
  const Eigen::Vector3d working_point(0.0, 0.0, kDefaultWorkingDistance);
  const Eigen::Vector2d in_projector =
      calibration.projector.ImageFromCam(calibration.proj_from_cam * working_point);
  EXPECT_NEAR(in_projector.x(), calibration.projector.cx(), 1e-9);
  EXPECT_NEAR(in_projector.y(), calibration.projector.cy(), 1e-9);

  // A fronto-parallel plane at the working distance: seen everywhere, mostly lit.
  VirtualRig rig(calibration, LinearNoiselessOptions());
  Scene scene;
  scene.objects.push_back(FacingPlane(working_point, Eigen::Vector3d(0, 0, -1), 3.0));
  rig.SetScene(scene);
  const GroundTruth& truth = rig.ground_truth();
  const double total = truth.depth.total();
  EXPECT_EQ(cv::countNonZero(truth.depth == truth.depth), total);  // no NaN
  const double lit_fraction = cv::countNonZero(truth.lit) / total;
  EXPECT_GT(lit_fraction, 0.75) << "lit fraction " << lit_fraction;
}

// ---------------------------------------------------------------------------------------
// Ground truth against analytic geometry.

TEST(VirtualRig, PlaneGroundTruthMatchesAnalyticRayPlane) {
  const RigCalibration calibration = DefaultRigCalibration();
  VirtualRig rig(calibration, LinearNoiselessOptions());
  Scene scene;
  SceneObject plane;
  plane.mesh = MakePlane(3.0, 3.0, 6);
  plane.cam_from_model =
      Rigid3d(RotationFromEulerXYZ(0.2, -0.3, 0.1), Eigen::Vector3d(0.02, -0.01, 0.65));
  scene.objects.push_back(plane);
  rig.SetScene(scene);
  const GroundTruth& truth = rig.ground_truth();
  ASSERT_EQ(truth.depth.type(), CV_32FC1);
  ASSERT_EQ(truth.proj_x.type(), CV_32FC1);
  ASSERT_EQ(truth.lit.type(), CV_8UC1);
  ASSERT_EQ(truth.object_id.type(), CV_32SC1);
  ASSERT_EQ(truth.depth.size(), cv::Size(1280, 720));

  const Eigen::Vector3d normal = plane.cam_from_model.rotation.col(2);
  const double offset = normal.dot(plane.cam_from_model.translation);
  const Eigen::Vector3d projector_center = ProjectorCenterInCam(calibration);
  double max_depth_error = 0.0, max_proj_error = 0.0;
  int lit_pixels = 0, unlit_pixels = 0;
  for (int y = 0; y < 720; ++y) {
    for (int x = 0; x < 1280; ++x) {
      const Eigen::Vector3d ray = calibration.camera.RayFromImage(Eigen::Vector2d(x, y));
      const Eigen::Vector3d point = offset / normal.dot(ray) * ray;
      const float depth = truth.depth.at<float>(y, x);
      ASSERT_TRUE(std::isfinite(depth)) << x << "," << y;
      max_depth_error = std::max(max_depth_error, std::abs(depth - point.z()));
      EXPECT_EQ(truth.object_id.at<int32_t>(y, x), 0);
      // Both devices see the same side of the plane.
      ASSERT_GT(normal.dot(point) * normal.dot(point - projector_center), 0.0);
      const Eigen::Vector2d proj =
          calibration.projector.ImageFromCam(calibration.proj_from_cam * point);
      const float proj_x = truth.proj_x.at<float>(y, x), proj_y = truth.proj_y.at<float>(y, x);
      if (InsideImage(calibration.projector, proj, 1e-3)) {
        ASSERT_TRUE(std::isfinite(proj_x) && std::isfinite(proj_y)) << x << "," << y;
        max_proj_error =
            std::max({max_proj_error, std::abs(proj_x - proj.x()), std::abs(proj_y - proj.y())});
        ++lit_pixels;
      } else if (OutsideImage(calibration.projector, proj, 1e-3)) {
        EXPECT_TRUE(std::isnan(proj_x) && std::isnan(proj_y)) << x << "," << y;
        EXPECT_EQ(truth.lit.at<uint8_t>(y, x), 0);
        ++unlit_pixels;
      }
      if (truth.lit.at<uint8_t>(y, x) != 0) {
        EXPECT_TRUE(std::isfinite(proj_x));
      }
    }
  }
  EXPECT_LT(max_depth_error, 1e-5);
  EXPECT_LT(max_proj_error, 1e-3);
  EXPECT_GT(lit_pixels, 100000);
  EXPECT_GT(unlit_pixels, 1000);
}

TEST(VirtualRig, SphereGroundTruthMatchesAnalyticRaySphere) {
  const RigCalibration calibration = DefaultRigCalibration();
  VirtualRig rig(calibration, LinearNoiselessOptions());
  const double radius = 0.08;
  const int rings = 180, segments = 360;
  const double gap = SphereTessellationGap(radius, rings, segments);
  const Eigen::Vector3d center(0.03, -0.02, 0.55);
  Scene scene;
  scene.objects.push_back(SphereObject(center, radius, rings, segments));
  rig.SetScene(scene);
  const GroundTruth& truth = rig.ground_truth();
  int inside = 0, checked_depth = 0;
  double max_excess = 0.0;
  for (int y = 0; y < 720; ++y) {
    for (int x = 0; x < 1280; ++x) {
      const Eigen::Vector3d ray = calibration.camera.RayFromImage(Eigen::Vector2d(x, y));
      double line_distance = 0.0;
      const double entry = RaySphereEntry(ray, center, radius, &line_distance);
      const float depth = truth.depth.at<float>(y, x);
      if (line_distance > radius + 1e-6) {
        EXPECT_TRUE(std::isnan(depth)) << x << "," << y;
        EXPECT_EQ(truth.object_id.at<int32_t>(y, x), -1);
        continue;
      }
      if (line_distance > radius - 2.0 * gap) continue;  // silhouette band of the polygon
      ++inside;
      ASSERT_TRUE(std::isfinite(depth)) << "hole at " << x << "," << y;
      const Eigen::Vector3d hit = entry * ray;
      const double cosine = -ray.dot((hit - center) / radius);
      // The mesh is inscribed: its surface is behind the sphere's by at most gap/cosine.
      const double analytic_depth = hit.z();
      EXPECT_GE(depth, analytic_depth - 1e-6) << x << "," << y;
      if (cosine > 0.3) {
        ++checked_depth;
        EXPECT_LE(depth - analytic_depth, 1.05 * gap / cosine * ray.z() + 1e-6) << x << "," << y;
        max_excess = std::max(max_excess, depth - analytic_depth);
      }
    }
  }
  EXPECT_GT(inside, 50000);
  EXPECT_GT(checked_depth, 40000);
  EXPECT_LT(max_excess, 1e-4);
}

TEST(VirtualRig, SmallObjectCastsAProjectorShadowOnThePlane) {
  const RigCalibration calibration = DefaultRigCalibration();
  const SensorOptions options = LinearNoiselessOptions();
  VirtualRig rig(calibration, options);
  const double plane_z = 0.7;
  const double radius = 0.04;
  const int rings = 90, segments = 180;
  const double gap = SphereTessellationGap(radius, rings, segments);
  const Eigen::Vector3d sphere_center(0.0, 0.0, 0.5);
  Scene scene;
  scene.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, plane_z), Eigen::Vector3d(0, 0, -1)));
  scene.objects.push_back(SphereObject(sphere_center, radius, rings, segments));
  rig.SetScene(scene);
  const GroundTruth& truth = rig.ground_truth();
  const cv::Mat white = rig.Capture(cv::Mat(768, 1024, CV_8UC1, cv::Scalar(255)));

  const Eigen::Vector3d projector_center = ProjectorCenterInCam(calibration);
  const double plane_albedo = scene.objects[0].albedo;
  const double ambient_grey = options.exposure * plane_albedo * options.ambient;
  int shadow = 0, lit = 0;
  for (int y = 1; y < 719; ++y) {
    for (int x = 1; x < 1279; ++x) {
      if (truth.object_id.at<int32_t>(y, x) != 0) continue;
      const Eigen::Vector3d ray = calibration.camera.RayFromImage(Eigen::Vector2d(x, y));
      const Eigen::Vector3d point = plane_z / ray.z() * ray;
      EXPECT_NEAR(truth.depth.at<float>(y, x), plane_z, 1e-5);
      const Eigen::Vector2d proj =
          calibration.projector.ImageFromCam(calibration.proj_from_cam * point);
      if (!InsideImage(calibration.projector, proj, 1.0)) continue;
      const double clearance = SegmentDistance(projector_center, point, sphere_center);
      if (clearance < radius - gap - 1e-5) {
        EXPECT_TRUE(std::isnan(truth.proj_x.at<float>(y, x))) << x << "," << y;
        EXPECT_EQ(truth.lit.at<uint8_t>(y, x), 0);
        // Deep in the shadow (clear of its edge by a pixel footprint), plane only: ambient.
        const bool plane_only =
            cv::countNonZero(truth.object_id(cv::Rect(x - 1, y - 1, 3, 3)) != 0) == 0;
        if (clearance < radius - 2e-3 && plane_only) {
          EXPECT_NEAR(white.at<uint8_t>(y, x), ambient_grey, 1.0) << x << "," << y;
          ++shadow;
        }
      } else if (clearance > radius + 1e-5) {
        EXPECT_TRUE(std::isfinite(truth.proj_x.at<float>(y, x))) << x << "," << y;
        if (clearance > radius + 2e-3 && truth.lit.at<uint8_t>(y, x) == 255 &&
            InsideImage(calibration.projector, proj, 2.0)) {
          // Lambertian plane (normal −z) lit from the projector centre.
          const Eigen::Vector3d to_projector = projector_center - point;
          const double irradiance = -to_projector.normalized().z() *
                                    std::pow(options.reference_distance / to_projector.norm(), 2);
          EXPECT_NEAR(white.at<uint8_t>(y, x),
                      ambient_grey + options.exposure * plane_albedo * irradiance, 1.0)
              << x << "," << y;
          ++lit;
        }
      }
    }
  }
  EXPECT_GT(shadow, 2000);
  EXPECT_GT(lit, 100000);
}

// Ground truth (depth, lit or not, projector coordinate) of an object in front of a plane
// against an exhaustive search over all triangles, at pixel centres.
struct BruteForceComparison {
  int depth_mismatches = 0;
  int light_mismatches = 0;  // lit where shadowed or the reverse, or a wrong proj_x
  int checked_lit = 0;
  int checked_shadow = 0;
};

BruteForceComparison CompareWithBruteForce(const SceneObject& object) {
  BruteForceComparison result;
  const RigCalibration calibration = DefaultRigCalibration();
  SensorOptions options = LinearNoiselessOptions();
  options.supersample = 1;
  VirtualRig rig(calibration, options);
  Scene scene;
  scene.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.65), Eigen::Vector3d(0, 0, -1)));
  scene.objects.push_back(object);
  rig.SetScene(scene);
  const GroundTruth& truth = rig.ground_truth();
  internal::TriangleSet all;
  all.Build({&scene.objects[0].mesh, &scene.objects[1].mesh},
            {scene.objects[0].cam_from_model, scene.objects[1].cam_from_model});
  const Eigen::Vector3d projector_center = ProjectorCenterInCam(calibration);
  const auto first_hit = [&](const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                             int* triangle) {
    double nearest = std::numeric_limits<double>::infinity();
    for (size_t t = 0; t < all.size(); ++t) {
      const double distance = all.Intersect(static_cast<int>(t), origin, direction);
      if (distance < nearest) {
        nearest = distance;
        *triangle = static_cast<int>(t);
      }
    }
    return nearest;
  };
  const Eigen::Vector2d center = calibration.camera.ImageFromCam(object.cam_from_model.translation);
  cv::RNG rng(11);
  for (int i = 0; i < 3000; ++i) {
    const int x = std::clamp(static_cast<int>(center.x() + rng.gaussian(150.0)), 0, 1279);
    const int y = std::clamp(static_cast<int>(center.y() + rng.gaussian(150.0)), 0, 719);
    const Eigen::Vector3d ray = calibration.camera.RayFromImage(Eigen::Vector2d(x, y));
    int triangle = -1;
    const double distance = first_hit(Eigen::Vector3d::Zero(), ray, &triangle);
    if (!(std::abs(truth.depth.at<float>(y, x) - distance * ray.z()) < 1e-6)) {
      ++result.depth_mismatches;
      continue;
    }
    const Eigen::Vector3d point = distance * ray;
    Eigen::Vector3d normal = all.triangle(triangle).normal;
    if (normal.dot(ray) > 0) normal = -normal;
    const Eigen::Vector2d proj =
        calibration.projector.ImageFromCam(calibration.proj_from_cam * point);
    const Eigen::Vector3d to_point = point - projector_center;
    const double light_distance = to_point.norm();
    bool lit = InsideImage(calibration.projector, proj, 0.0) && normal.dot(-to_point) > 0.0;
    if (lit) {
      // Occluded when anything but the point's own face is hit first.
      for (size_t t = 0; t < all.size() && lit; ++t) {
        if (static_cast<int>(t) == triangle) continue;
        lit = !(all.Intersect(static_cast<int>(t), projector_center, to_point / light_distance) <
                light_distance * (1 - 1e-7) - 1e-9);
      }
    }
    const float proj_x = truth.proj_x.at<float>(y, x);
    if (lit) {
      ++result.checked_lit;
      result.light_mismatches += !(std::abs(proj_x - proj.x()) < 1e-3);
    } else if (std::isfinite(truth.depth.at<float>(y, x))) {
      ++result.checked_shadow;
      result.light_mismatches += !std::isnan(proj_x);
    }
  }
  return result;
}

TEST(VirtualRig, GroundTruthMatchesBruteForceRayCasting) {
  SceneObject torus;
  torus.mesh = MakeTorus(0.06, 0.025, 96, 48);
  torus.cam_from_model =
      Rigid3d(RotationFromEulerXYZ(0.9, 0.4, 0.3), Eigen::Vector3d(0.0, 0.01, 0.55));
  const BruteForceComparison comparison = CompareWithBruteForce(torus);
  EXPECT_EQ(comparison.depth_mismatches, 0);
  EXPECT_EQ(comparison.light_mismatches, 0);
  EXPECT_GT(comparison.checked_lit, 1000);
  EXPECT_GT(comparison.checked_shadow, 200);
}

TEST(VirtualRig, GroundTruthMatchesBruteForceOnAScannedMesh) {
  SOPE_REQUIRE_SHARED_DATA(data);
  SceneObject drill;
  drill.mesh = ReadMesh(JoinPath(data, "meshes/ycb/PowerDrill.obj"));
  drill.mesh.Transform(1.0, -drill.mesh.SurfaceCentroid());
  drill.cam_from_model =
      Rigid3d(RotationFromEulerXYZ(0.5, -0.8, 0.3), Eigen::Vector3d(0.0, 0.0, 0.5));
  const BruteForceComparison comparison = CompareWithBruteForce(drill);
  EXPECT_EQ(comparison.depth_mismatches, 0);
  // Known limit: an occluder thinner than a shadow-map texel with no rasterised face in
  // the 3×3 window can be missed (about 1 sample in 30000 on this mesh).
  EXPECT_LE(comparison.light_mismatches,
            0.001 * (comparison.checked_lit + comparison.checked_shadow));
  EXPECT_GT(comparison.checked_lit, 1000);
  EXPECT_GT(comparison.checked_shadow, 200);
}

// ---------------------------------------------------------------------------------------
// Radiometry and the sensor.

TEST(VirtualRig, WhiteMinusBlackIsTheLambertianIrradianceAtTheReferenceDistance) {
  const RigCalibration calibration = DefaultRigCalibration();
  const Eigen::Vector3d working_point(0.0, 0.0, kDefaultWorkingDistance);
  const Eigen::Vector3d projector_center = ProjectorCenterInCam(calibration);
  SensorOptions options = LinearNoiselessOptions();
  options.exposure = 200.0;
  options.reference_distance = (projector_center - working_point).norm();
  VirtualRig rig(calibration, options);
  Scene scene;
  // Facing the projector: at the working point the irradiance is exactly 1.
  scene.objects.push_back(FacingPlane(working_point, projector_center - working_point));
  scene.objects[0].albedo = 0.7;
  rig.SetScene(scene);
  const cv::Mat white = rig.Capture(cv::Mat(768, 1024, CV_8UC1, cv::Scalar(255)));
  const cv::Mat black = rig.Capture(cv::Mat(768, 1024, CV_32FC1, cv::Scalar(0.0)));
  const Eigen::Vector2d center = calibration.camera.ImageFromCam(working_point);
  const int cx = static_cast<int>(std::lround(center.x()));
  const int cy = static_cast<int>(std::lround(center.y()));
  const Eigen::Vector3d normal = (projector_center - working_point).normalized();
  for (int y = cy - 10; y <= cy + 10; ++y) {
    for (int x = cx - 10; x <= cx + 10; ++x) {
      const Eigen::Vector3d ray = calibration.camera.RayFromImage(Eigen::Vector2d(x, y));
      const Eigen::Vector3d point = normal.dot(working_point) / normal.dot(ray) * ray;
      const Eigen::Vector3d to_projector = projector_center - point;
      const double irradiance = normal.dot(to_projector.normalized()) *
                                std::pow(options.reference_distance / to_projector.norm(), 2);
      const double expected_black = options.exposure * 0.7 * options.ambient;
      const double expected_white = expected_black + options.exposure * 0.7 * irradiance;
      EXPECT_NEAR(black.at<uint8_t>(y, x), expected_black, 0.51);
      EXPECT_NEAR(white.at<uint8_t>(y, x), expected_white, 0.51);
    }
  }
  EXPECT_NEAR(white.at<uint8_t>(cy, cx) - black.at<uint8_t>(cy, cx), 200.0 * 0.7, 1.0);
}

TEST(VirtualRig, NoiseFollowsTheSensorModelAndIsFreshPerCapture) {
  const RigCalibration calibration = DefaultRigCalibration();
  SensorOptions options = LinearNoiselessOptions();
  options.read_noise = 2.0;
  options.shot_noise = 0.5;
  options.exposure = 150.0;
  options.seed = 42;
  VirtualRig rig(calibration, options);
  Scene scene;
  scene.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.6), Eigen::Vector3d(0, 0, -1)));
  rig.SetScene(scene);
  const cv::Mat grey(768, 1024, CV_32FC1, cv::Scalar(0.6));
  constexpr int kCaptures = 30;
  const cv::Rect region(540, 260, 200, 200);
  cv::Mat sum = cv::Mat::zeros(region.size(), CV_64FC1);
  cv::Mat sum_squares = cv::Mat::zeros(region.size(), CV_64FC1);
  cv::Mat first;
  for (int i = 0; i < kCaptures; ++i) {
    const cv::Mat image = rig.Capture(grey);
    if (i == 0) first = image.clone();
    if (i == 1) {
      EXPECT_GT(cv::norm(image, first, cv::NORM_L1), 1000.0);  // fresh noise
    }
    cv::Mat value;
    image(region).convertTo(value, CV_64F);
    sum += value;
    sum_squares += value.mul(value);
  }
  double measured_variance = 0.0, predicted_variance = 0.0;
  for (int y = 0; y < region.height; ++y) {
    for (int x = 0; x < region.width; ++x) {
      const double mean = sum.at<double>(y, x) / kCaptures;
      measured_variance +=
          (sum_squares.at<double>(y, x) - kCaptures * mean * mean) / (kCaptures - 1);
      // σ² = read² + shot·signal, plus the uniform quantisation error's 1/12.
      predicted_variance +=
          options.read_noise * options.read_noise + options.shot_noise * mean + 1.0 / 12.0;
    }
  }
  const double ratio = std::sqrt(measured_variance / predicted_variance);
  EXPECT_NEAR(ratio, 1.0, 0.15) << "measured/predicted sigma";
  EXPECT_GT(sum.at<double>(100, 100) / kCaptures, 60.0);  // a mid-grey, unclipped signal

  // Same seed, same noise sequence.
  VirtualRig twin(calibration, options);
  twin.SetScene(scene);
  EXPECT_EQ(cv::norm(twin.Capture(grey), first, cv::NORM_INF), 0.0);
}

TEST(VirtualRig, OutputIs8BitSaturatesAndAppliesTheGammaResponse) {
  const RigCalibration calibration = DefaultRigCalibration();
  SensorOptions options = LinearNoiselessOptions();
  options.exposure = 2000.0;
  VirtualRig bright(calibration, options);
  Scene scene;
  scene.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.6), Eigen::Vector3d(0, 0, -1)));
  bright.SetScene(scene);
  const cv::Mat white = bright.Capture(cv::Mat(768, 1024, CV_8UC1, cv::Scalar(255)));
  ASSERT_EQ(white.type(), CV_8UC1);
  ASSERT_EQ(white.size(), cv::Size(1280, 720));
  EXPECT_EQ(white.at<uint8_t>(360, 640), 255);  // clamped, not wrapped
  EXPECT_EQ(cv::countNonZero(white(cv::Rect(500, 300, 200, 100)) != 255), 0);

  // gamma 2.2: grey = 255·(linear/255)^(1/2.2).
  options.exposure = 100.0;
  options.gamma = 2.2;
  VirtualRig curved(calibration, options);
  curved.SetScene(scene);
  options.gamma = 1.0;
  VirtualRig linear(calibration, options);
  linear.SetScene(scene);
  const cv::Mat half(768, 1024, CV_8UC1, cv::Scalar(128));
  const cv::Mat curved_image = curved.Capture(half);
  const cv::Mat linear_image = linear.Capture(half);
  for (int x = 600; x < 700; x += 10) {
    const double linear_value = linear_image.at<uint8_t>(360, x);
    EXPECT_NEAR(curved_image.at<uint8_t>(360, x), 255.0 * std::pow(linear_value / 255.0, 1 / 2.2),
                2.0);
  }

  // Nothing in front: black up to read noise.
  SensorOptions dark_options;
  VirtualRig dark(calibration, dark_options);
  dark.SetScene(Scene{});
  double max_value = 0.0;
  cv::minMaxLoc(dark.Capture(cv::Mat(768, 1024, CV_8UC1, cv::Scalar(255))), nullptr, &max_value);
  EXPECT_LE(max_value, 64.0);  // read noise 1 grey level through gamma 2.2 near black
  const GroundTruth& truth = dark.ground_truth();
  EXPECT_EQ(cv::countNonZero(truth.depth == truth.depth), 0);
  EXPECT_EQ(cv::countNonZero(truth.lit), 0);
  EXPECT_EQ(cv::countNonZero(truth.object_id != -1), 0);
}

// A small bright disc printed on a plane at a known 3D point: its intensity centroid in the
// image is the point's projection (OpenCV convention, pixel (0, 0) at the top-left centre).
TEST(VirtualRig, CameraPixelCentreConventionFromAProjectedPoint) {
  const RigCalibration calibration = DefaultRigCalibration();
  SensorOptions options = LinearNoiselessOptions();
  options.ambient = 0.0;
  options.supersample = 5;
  options.exposure = 250.0;
  VirtualRig rig(calibration, options);
  const Eigen::Vector3d working_point(0.0, 0.0, kDefaultWorkingDistance);
  const Eigen::Vector3d projector_center = ProjectorCenterInCam(calibration);
  SceneObject plane = FacingPlane(working_point, projector_center - working_point, 0.3);
  for (const Eigen::Vector2d& target :
       {Eigen::Vector2d(600.37, 340.81), Eigen::Vector2d(700.0, 400.5)}) {
    const Eigen::Vector3d ray = calibration.camera.RayFromImage(target);
    const Eigen::Vector3d normal = plane.cam_from_model.rotation.col(2);
    const Eigen::Vector3d point_in_cam =
        normal.dot(plane.cam_from_model.translation) / normal.dot(ray) * ray;
    const Eigen::Vector3d point_in_model = plane.cam_from_model.Inverse() * point_in_cam;
    const double disc_radius = 0.003;  // ≈ 7 px
    plane.albedo_map = [point_in_model, disc_radius](const Eigen::Vector3d& p) {
      return (p - point_in_model).norm() < disc_radius ? 1.0 : 0.0;
    };
    Scene scene;
    scene.objects.push_back(plane);
    rig.SetScene(scene);
    const cv::Mat image = rig.Capture(cv::Mat(768, 1024, CV_8UC1, cv::Scalar(255)));
    double sum = 0.0, sum_x = 0.0, sum_y = 0.0;
    for (int y = static_cast<int>(target.y()) - 15; y <= static_cast<int>(target.y()) + 15; ++y) {
      for (int x = static_cast<int>(target.x()) - 15; x <= static_cast<int>(target.x()) + 15; ++x) {
        const double value = image.at<uint8_t>(y, x);
        sum += value;
        sum_x += value * x;
        sum_y += value * y;
      }
    }
    ASSERT_GT(sum, 1000.0);
    EXPECT_NEAR(sum_x / sum, target.x(), 0.05);
    EXPECT_NEAR(sum_y / sum, target.y(), 0.05);
  }
}

// One lit projector column c: the light lands where the true projector coordinate is c, so
// the intensity-weighted mean of the ground-truth proj_x is c (projector convention).
TEST(VirtualRig, ProjectorColumnLightsItsTrueCoordinate) {
  const RigCalibration calibration = DefaultRigCalibration();
  SensorOptions options = LinearNoiselessOptions();
  options.ambient = 0.0;
  VirtualRig rig(calibration, options);
  Scene scene;
  scene.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.6), Eigen::Vector3d(0, 0, -1)));
  rig.SetScene(scene);
  for (const int column : {300, 517}) {
    cv::Mat pattern(768, 1024, CV_32FC1, cv::Scalar(0.0));
    pattern.col(column).setTo(cv::Scalar(1.0));
    const cv::Mat image = rig.Capture(pattern);
    const cv::Mat white = rig.Capture(cv::Mat(768, 1024, CV_32FC1, cv::Scalar(1.0)));
    const GroundTruth& truth = rig.ground_truth();
    double sum = 0.0, sum_x = 0.0;
    int dark_violations = 0;
    for (int y = 200; y < 500; ++y) {
      for (int x = 0; x < 1280; ++x) {
        const float proj_x = truth.proj_x.at<float>(y, x);
        if (!std::isfinite(proj_x) || truth.lit.at<uint8_t>(y, x) == 0) continue;
        const double relative = image.at<uint8_t>(y, x) / double(white.at<uint8_t>(y, x));
        if (std::abs(proj_x - column) > 2.0) {
          dark_violations += image.at<uint8_t>(y, x) > 0;
          continue;
        }
        sum += relative;
        sum_x += relative * proj_x;
      }
    }
    EXPECT_EQ(dark_violations, 0);
    ASSERT_GT(sum, 100.0);
    EXPECT_NEAR(sum_x / sum, column, 0.05);
  }
}

// A mid-frequency Gray-code bit and its inverse decide the bit of the true projector column
// wherever no stripe edge is within reach of the pixel footprint.
TEST(VirtualRig, GrayCodeStripesFollowTheTrueProjectorColumn) {
  const RigCalibration calibration = DefaultRigCalibration();
  VirtualRig rig(calibration);  // default sensor: noise, blur, gamma
  Scene scene;
  scene.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.7), Eigen::Vector3d(0, 0, -1)));
  scene.objects.push_back(SphereObject(Eigen::Vector3d(-0.03, 0.0, 0.58), 0.07, 90, 180));
  rig.SetScene(scene);
  FrameInfo frame;
  frame.role = FrameRole::kCode;
  frame.axis = PatternAxis::kX;
  frame.code = PatternCode::kGray;
  frame.bits = BitsForSize(1024);
  frame.bit = 4;
  const cv::Mat pattern_image = RenderPattern(frame, 1024, 768);
  const cv::Mat image = rig.Capture(pattern_image);
  frame.inverted = true;
  const cv::Mat inverse_image = rig.Capture(RenderPattern(frame, 1024, 768));
  const GroundTruth& truth = rig.ground_truth();
  int checked = 0, correct = 0, on_sphere = 0;
  for (int y = 0; y < 720; ++y) {
    for (int x = 0; x < 1280; ++x) {
      if (truth.lit.at<uint8_t>(y, x) == 0) continue;
      const double proj_x = truth.proj_x.at<float>(y, x);
      const auto bit_at = [&](double u) {
        const int column = std::clamp(static_cast<int>(std::lround(u)), 0, 1023);
        return PatternBit(PatternCode::kGray, column, frame.bit);
      };
      const bool bit = bit_at(proj_x);
      if (bit_at(proj_x - 1.5) != bit || bit_at(proj_x + 1.5) != bit) continue;
      ++checked;
      on_sphere += truth.object_id.at<int32_t>(y, x) == 1;
      correct += (image.at<uint8_t>(y, x) > inverse_image.at<uint8_t>(y, x)) == bit;
    }
  }
  EXPECT_GT(checked, 300000);
  EXPECT_GT(on_sphere, 20000);
  EXPECT_GE(correct, 0.995 * checked) << correct << " of " << checked;

  // Visual check on request: SOPE_SIMULATOR_PREVIEW_DIR=/some/dir writes the frames.
  if (const char* directory = std::getenv("SOPE_SIMULATOR_PREVIEW_DIR")) {
    WriteImageAtomic(JoinPath(directory, "gray_bit4.png"), image);
    frame.bit = 6;
    frame.inverted = false;
    WriteImageAtomic(JoinPath(directory, "gray_bit6.png"),
                     rig.Capture(RenderPattern(frame, 1024, 768)));
    cv::Mat lit_mask = truth.lit.clone();
    WriteImageAtomic(JoinPath(directory, "lit.png"), lit_mask);
  }
}

// ---------------------------------------------------------------------------------------
// Depth renderer.

TEST(DepthRenderer, SphereCloudMatchesAnalyticSphereAcrossPoses) {
  const CameraModel camera = MakePinhole(640, 480, 60.0 * kPi / 180.0);
  DepthRenderer renderer(camera);
  const double radius = 0.1;
  const int rings = 120, segments = 240;
  const double gap = SphereTessellationGap(radius, rings, segments);
  renderer.SetMesh(MakeSphere(radius, rings, segments));
  for (const Eigen::Vector3d& center :
       {Eigen::Vector3d(0.0, 0.0, 0.5), Eigen::Vector3d(0.1, -0.05, 0.8),
        Eigen::Vector3d(-0.2, 0.1, 1.2)}) {
    const Rigid3d cam_from_model(RotationFromEulerXYZ(0.3, 0.2, -0.5), center);
    const PointCloud cloud = renderer.Render(cam_from_model);
    ASSERT_TRUE(cloud.HasNormals());
    ASSERT_FALSE(cloud.HasColors());
    const cv::Mat& depth = renderer.depth();
    ASSERT_EQ(depth.type(), CV_32FC1);
    EXPECT_EQ(static_cast<size_t>(cv::countNonZero(depth == depth)), cloud.size());
    for (size_t i = 0; i < cloud.size(); ++i) {
      const Eigen::Vector3d point = cloud.points[i].cast<double>();
      const Eigen::Vector3d normal = cloud.normals[i].cast<double>();
      const double distance = (point - center).norm();
      EXPECT_LE(distance, radius + 1e-6);
      EXPECT_GE(distance, radius - gap - 1e-6);
      EXPECT_NEAR(normal.norm(), 1.0, 1e-5);
      EXPECT_LT(normal.dot(point), 0.0);  // faces the camera
      EXPECT_GT(normal.dot((point - center).normalized()), std::cos(2.0 * kPi / segments));
    }
    int expected_hits = 0, holes = 0;
    for (int y = 0; y < 480; ++y) {
      for (int x = 0; x < 640; ++x) {
        double line_distance = 0.0;
        RaySphereEntry(camera.RayFromImage(Eigen::Vector2d(x, y)), center, radius, &line_distance);
        if (line_distance > radius + 1e-6) {
          EXPECT_TRUE(std::isnan(depth.at<float>(y, x)));
        } else if (line_distance < radius - 2.0 * gap) {
          ++expected_hits;
          holes += std::isnan(depth.at<float>(y, x));
        }
      }
    }
    EXPECT_GT(expected_hits, 3000);
    EXPECT_EQ(holes, 0);
  }
}

TEST(DepthRenderer, PlaneDepthMatchesAnalyticWithDistortion) {
  CameraModel camera = MakePinhole(640, 480, 55.0 * kPi / 180.0);
  camera.distortion = {-0.1, 0.05, 0.001, -0.0005, 0.0};
  DepthRenderer renderer(camera);
  renderer.SetMesh(MakePlane(4.0, 4.0, 3));
  const Rigid3d cam_from_model(RotationFromEulerXYZ(-0.25, 0.35, 0.2),
                               Eigen::Vector3d(0.05, 0.02, 0.9));
  const PointCloud cloud = renderer.Render(cam_from_model);
  EXPECT_EQ(cloud.size(), 640u * 480u);
  const Eigen::Vector3d normal = cam_from_model.rotation.col(2);
  const double offset = normal.dot(cam_from_model.translation);
  double max_error = 0.0;
  for (int y = 0; y < 480; ++y) {
    for (int x = 0; x < 640; ++x) {
      const Eigen::Vector3d ray = camera.RayFromImage(Eigen::Vector2d(x, y));
      const double analytic = (offset / normal.dot(ray) * ray).z();
      max_error = std::max(max_error, std::abs(renderer.depth().at<float>(y, x) - analytic));
    }
  }
  EXPECT_LT(max_error, 1e-5);
  const Eigen::Vector3f facing =
      (normal.dot(Eigen::Vector3d(0, 0, 1)) > 0 ? -normal : normal).cast<float>();
  for (size_t i = 0; i < cloud.size(); i += 97) {
    EXPECT_NEAR(cloud.normals[i].dot(facing), 1.0f, 1e-5f);
    EXPECT_NEAR(normal.dot(cloud.points[i].cast<double>()), offset, 1e-5);
  }
}

// Triangles far smaller than a pixel (a dense sphere far away) leave no holes.
TEST(DepthRenderer, SubPixelTrianglesLeaveNoHoles) {
  const CameraModel camera = MakePinhole(640, 480, 60.0 * kPi / 180.0);
  DepthRenderer renderer(camera);
  const double radius = 0.1;
  const int rings = 256, segments = 512;
  const double gap = SphereTessellationGap(radius, rings, segments);
  renderer.SetMesh(MakeSphere(radius, rings, segments));
  const Eigen::Vector3d center(0.05, 0.02, 2.0);
  renderer.Render(Rigid3d(Eigen::Matrix3d::Identity(), center));
  int expected_hits = 0, holes = 0;
  for (int y = 0; y < 480; ++y) {
    for (int x = 0; x < 640; ++x) {
      const Eigen::Vector3d ray = camera.RayFromImage(Eigen::Vector2d(x, y));
      double line_distance = 0.0;
      const double entry = RaySphereEntry(ray, center, radius, &line_distance);
      if (line_distance < radius - 2.0 * gap) {
        ++expected_hits;
        const float depth = renderer.depth().at<float>(y, x);
        holes += std::isnan(depth);
        if (std::isfinite(depth)) {
          EXPECT_NEAR(depth, (entry * ray).z(), 1e-3);
        }
      }
    }
  }
  EXPECT_GT(expected_hits, 1000);
  EXPECT_EQ(holes, 0);
}

// The id-guided search must find exactly the first hit of an exhaustive search over all
// triangles, including at silhouettes and on meshes with slivers and tiny faces.
void ExpectFirstHitsMatchBruteForce(const TriangleMesh& mesh, const Rigid3d& cam_from_model) {
  const CameraModel camera = MakePinhole(640, 480, 50.0 * kPi / 180.0);
  DepthRenderer renderer(camera);
  renderer.SetMesh(mesh);
  renderer.Render(cam_from_model);
  internal::TriangleSet brute_force;
  brute_force.Build({&mesh}, {cam_from_model});
  int hits = 0, mismatches = 0;
  cv::RNG rng(3);
  for (int i = 0; i < 6000; ++i) {
    // Half the samples near the object's image, where silhouettes are.
    const Eigen::Vector2d center = camera.ImageFromCam(cam_from_model.translation);
    const int x = i % 2 ? rng.uniform(0, 640)
                        : std::clamp(static_cast<int>(center.x() + rng.gaussian(60.0)), 0, 639);
    const int y = i % 2 ? rng.uniform(0, 480)
                        : std::clamp(static_cast<int>(center.y() + rng.gaussian(60.0)), 0, 479);
    const Eigen::Vector3d ray = camera.RayFromImage(Eigen::Vector2d(x, y));
    double nearest = std::numeric_limits<double>::infinity();
    for (size_t t = 0; t < brute_force.size(); ++t) {
      nearest = std::min(nearest,
                         brute_force.Intersect(static_cast<int>(t), Eigen::Vector3d::Zero(), ray));
    }
    const float depth = renderer.depth().at<float>(y, x);
    if (std::isinf(nearest)) {
      mismatches += !std::isnan(depth);
    } else {
      ++hits;
      mismatches += !(std::abs(depth - nearest * ray.z()) < 1e-6);
    }
  }
  EXPECT_GT(hits, 1000);
  EXPECT_EQ(mismatches, 0);
}

TEST(DepthRenderer, FirstHitsMatchBruteForceOnProceduralMeshes) {
  ExpectFirstHitsMatchBruteForce(
      MakeTorus(0.08, 0.03, 96, 48),
      Rigid3d(RotationFromEulerXYZ(1.2, 0.3, 0.4), Eigen::Vector3d(0.01, -0.02, 0.45)));
  // Slivers: a cylinder of long thin side faces seen almost along its axis.
  ExpectFirstHitsMatchBruteForce(
      MakeCylinder(0.05, 0.3, 400),
      Rigid3d(RotationFromEulerXYZ(0.15, 0.1, 0.0), Eigen::Vector3d(0.0, 0.0, 0.6)));
}

TEST(DepthRenderer, FirstHitsMatchBruteForceOnScannedMeshes) {
  SOPE_REQUIRE_SHARED_DATA(data);
  for (const char* name : {"meshes/ycb/PowerDrill.obj", "meshes/classic/rocker-arm.obj"}) {
    TriangleMesh mesh = ReadMesh(JoinPath(data, name));
    // Centre and scale to a 0.2 m object.
    const double scale = 0.2 / mesh.BoundingDiagonal();
    mesh.Transform(scale, -scale * mesh.SurfaceCentroid());
    SCOPED_TRACE(name);
    ExpectFirstHitsMatchBruteForce(
        mesh, Rigid3d(RotationFromEulerXYZ(0.4, -0.7, 0.2), Eigen::Vector3d(0.0, 0.0, 0.4)));
  }
}

TEST(DepthRenderer, ObjectBehindTheCameraGivesAnEmptyCloud) {
  DepthRenderer renderer(MakePinhole(320, 240, 1.0));
  renderer.SetMesh(MakeBox(0.1, 0.1, 0.1));
  const PointCloud cloud =
      renderer.Render(Rigid3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, -0.5)));
  EXPECT_TRUE(cloud.empty());
  EXPECT_EQ(cv::countNonZero(renderer.depth() == renderer.depth()), 0);
}

TEST(VirtualRig, GroundTruthCopiesSurviveTheNextScene) {
  SensorOptions options;
  options.supersample = 1;
  VirtualRig rig(DefaultRigCalibration(), options);
  Scene near_scene, far_scene;
  near_scene.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.5), Eigen::Vector3d(0, 0, -1)));
  far_scene.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.8), Eigen::Vector3d(0, 0, -1)));
  rig.SetScene(near_scene);
  const GroundTruth near_truth = rig.ground_truth();
  rig.SetScene(far_scene);
  EXPECT_NEAR(near_truth.depth.at<float>(360, 640), 0.5, 1e-6);
  EXPECT_NEAR(rig.ground_truth().depth.at<float>(360, 640), 0.8, 1e-6);

  DepthRenderer renderer(MakePinhole(320, 240, 1.0));
  renderer.SetMesh(MakePlane(2.0, 2.0));
  renderer.Render(Rigid3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 0.5)));
  const cv::Mat near_depth = renderer.depth();
  renderer.Render(Rigid3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 0.8)));
  EXPECT_NEAR(near_depth.at<float>(120, 160), 0.5, 1e-6);
  EXPECT_NEAR(renderer.depth().at<float>(120, 160), 0.8, 1e-6);
}

// ---------------------------------------------------------------------------------------
// Caller mistakes.

TEST(VirtualRig, BadInputsThrow) {
  const RigCalibration calibration = DefaultRigCalibration();
  SensorOptions bad_options;
  bad_options.supersample = 0;
  EXPECT_THROW_WITH_MESSAGE(VirtualRig(calibration, bad_options), Error, "supersample", "got 0");
  bad_options = SensorOptions();
  bad_options.read_noise = -1.0;
  EXPECT_THROW_WITH_MESSAGE(VirtualRig(calibration, bad_options), Error, "read_noise", "got -1");
  RigCalibration bad_calibration = calibration;
  bad_calibration.camera.matrix(0, 0) = 0.0;
  EXPECT_THROW_WITH_MESSAGE(VirtualRig rig(bad_calibration), Error, "fx=0");

  SensorOptions options;
  options.supersample = 1;
  VirtualRig rig(calibration, options);
  EXPECT_THROW_WITH_MESSAGE(rig.Capture(cv::Mat(768, 1024, CV_8UC1, cv::Scalar(0))), Error,
                            "SetScene() has not been called");  // no scene

  Scene empty_mesh;
  empty_mesh.objects.emplace_back();
  EXPECT_THROW_WITH_MESSAGE(rig.SetScene(empty_mesh), Error, "scene object 0", "no faces");
  Scene bad_index;
  bad_index.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.6), Eigen::Vector3d(0, 0, -1)));
  bad_index.objects[0].mesh.faces.emplace_back(0, 1, 1000);
  EXPECT_THROW_WITH_MESSAGE(rig.SetScene(bad_index), Error, "scene object 0",
                            "face index out of range");
  Scene bad_albedo;
  bad_albedo.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.6), Eigen::Vector3d(0, 0, -1)));
  bad_albedo.objects[0].albedo = 1.5;
  EXPECT_THROW_WITH_MESSAGE(rig.SetScene(bad_albedo), Error, "scene object 0", "albedo", "got 1.5");

  Scene good;
  good.objects.push_back(FacingPlane(Eigen::Vector3d(0, 0, 0.6), Eigen::Vector3d(0, 0, -1)));
  rig.SetScene(good);
  EXPECT_THROW_WITH_MESSAGE(rig.Capture(cv::Mat()), Error, "projector image is 0x0", "1024x768");
  EXPECT_THROW_WITH_MESSAGE(rig.Capture(cv::Mat(768, 1023, CV_8UC1, cv::Scalar(0))), Error,
                            "projector image is 1023x768");
  EXPECT_THROW_WITH_MESSAGE(rig.Capture(cv::Mat(720, 1280, CV_8UC1, cv::Scalar(0))), Error,
                            "projector image is 1280x720");
  EXPECT_THROW_WITH_MESSAGE(rig.Capture(cv::Mat(768, 1024, CV_8UC3, cv::Scalar(0))), Error,
                            "got CV_8UC3");
  EXPECT_THROW_WITH_MESSAGE(rig.Capture(cv::Mat(768, 1024, CV_16UC1, cv::Scalar(0))), Error,
                            "got CV_16UC1");
  EXPECT_THROW_WITH_MESSAGE(rig.Capture(cv::Mat(768, 1024, CV_32FC1, cv::Scalar(2.0))), Error,
                            "pixel (0, 0) is 2");
  const cv::Mat ok = rig.Capture(cv::Mat(768, 1024, CV_8UC1, cv::Scalar(0)));
  EXPECT_EQ(ok.type(), CV_8UC1);
}

TEST(DepthRenderer, BadInputsThrow) {
  CameraModel bad_camera = MakePinhole(320, 240, 1.0);
  bad_camera.width = 0;
  EXPECT_THROW_WITH_MESSAGE(DepthRenderer renderer(bad_camera), Error, "image size 0x240");
  DepthRenderer renderer(MakePinhole(320, 240, 1.0));
  EXPECT_THROW_WITH_MESSAGE(renderer.Render(Rigid3d()), Error,
                            "SetMesh() has not been called");  // no mesh
  EXPECT_THROW_WITH_MESSAGE(renderer.SetMesh(TriangleMesh()), Error, "SetMesh", "no faces");
  TriangleMesh non_finite = MakeBox(0.1, 0.1, 0.1);
  non_finite.vertices[3].x() = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW_WITH_MESSAGE(renderer.SetMesh(non_finite), Error, "SetMesh", "non-finite vertex");
}

}  // namespace
}  // namespace sope
