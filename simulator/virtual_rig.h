// The virtual rig: a pinhole camera with OpenCV distortion and a pinhole projector that
// lights triangle-mesh scenes, rendered headless with OSMesa. It stands in for the
// hardware in tests and demos and gives ground truth the hardware cannot.
//
// Rendering is deferred: OSMesa rasterises triangle ids from the camera (supersampled) and
// from the projector (shadow map); every camera sample then gets its exact ray–triangle
// intersection, projector coordinate and shadow test. Each Capture() only samples the
// (defocused) projector image per sample, applies the sensor model and quantises, so a
// whole pattern sequence renders quickly once the scene is set.
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include "core/camera_model.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rig_calibration.h"
#include "core/rigid3d.h"

namespace sope {

struct SensorOptions {
  // Ambient irradiance relative to a white projector pixel at `reference_distance`.
  double ambient = 0.08;
  // Distance at which a white projector pixel gives irradiance 1 (inverse-square falloff
  // elsewhere), metres.
  double reference_distance = 0.6;
  // Linear grey level (before the camera response) of a white, fully lit Lambertian
  // surface of albedo 1 facing the projector at the reference distance.
  double exposure = 230.0;
  // Camera response: grey = 255 · (linear / 255)^(1/gamma).
  double gamma = 2.2;
  // Projector response: a pixel value v ∈ [0, 1] emits
  //   r(v) = black_level + (1 − black_level) · (min(v, saturation) / saturation)^gamma
  // of a white pixel's light (before the projector's defocus). The defaults are linear.
  double projector_gamma = 1.0;
  double projector_black_level = 0.0;  // in [0, 1)
  double projector_saturation = 1.0;   // in (0, 1]: values above it emit full white
  // Projector defocus, Gaussian σ in projector pixels (0 = sharp).
  double defocus_sigma_px = 0.5;
  // Camera optics blur, Gaussian σ in camera pixels (0 = none).
  double camera_blur_sigma_px = 0.3;
  // Sensor noise in grey levels (linear domain): σ² = read_noise² + shot_noise · signal.
  double read_noise = 1.0;
  double shot_noise = 0.3;
  // Samples per camera pixel side for the pixel footprint (1 = pixel centre only).
  int supersample = 3;
  // Seed of the noise generator; every Capture() draws fresh noise from it.
  uint64_t seed = 1;

  // Throws sope::Error naming the invalid value.
  void Check() const;
};

struct SceneObject {
  TriangleMesh mesh;       // model frame, metres
  Rigid3d cam_from_model;  // pose in the camera frame
  double albedo = 0.8;     // Lambertian reflectance in [0, 1]
  // Optional spatially varying albedo (e.g. a printed checkerboard), evaluated at the
  // surface point in model coordinates; overrides `albedo` when set. Called during
  // SetScene() only, from several threads at once (it must be thread-safe).
  std::function<double(const Eigen::Vector3d& point_in_model)> albedo_map;
};

struct Scene {
  std::vector<SceneObject> objects;
};

// Per camera pixel, for the scene last set.
struct GroundTruth {
  // z of the surface point seen through the pixel centre, camera frame, metres; NaN where
  // the ray hits nothing. CV_32FC1.
  cv::Mat depth;
  // True projector column/row of that surface point (CV_32FC1), NaN where it is not lit
  // (outside the projector image or in the projector's shadow).
  cv::Mat proj_x;
  cv::Mat proj_y;
  // CV_8UC1, 255 where every sample of the pixel footprint sees a lit surface of one
  // object: the pixels a decoder should decode.
  cv::Mat lit;
  // CV_32SC1: index of the scene object seen at the pixel centre, −1 for none.
  cv::Mat object_id;
};

class VirtualRig {
 public:
  // Creates the OSMesa context. Throws sope::Error when the calibration or options are
  // invalid or OSMesa cannot create a context.
  VirtualRig(const RigCalibration& calibration, const SensorOptions& options = {});
  ~VirtualRig();
  VirtualRig(const VirtualRig&) = delete;
  VirtualRig& operator=(const VirtualRig&) = delete;

  // Rasterises visibility from camera and projector and precomputes the per-sample
  // geometry. Throws sope::Error on an invalid mesh.
  void SetScene(const Scene& scene);
  // Camera image (CV_8UC1, camera size) of the scene lit by `projector_image` (CV_8UC1
  // or CV_32FC1 in [0,1], projector size; shown through the projector response of
  // SensorOptions) plus ambient light, with fresh noise.
  cv::Mat Capture(const cv::Mat& projector_image);
  const GroundTruth& ground_truth() const;
  const RigCalibration& calibration() const;
  const SensorOptions& options() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// A desktop rig like the thesis's: projector 1024×768, camera 1280×720 with mild webcam
// distortion, 0.2 m baseline, both converging on a point 0.6 m in front of the camera.
RigCalibration DefaultRigCalibration();
// Working distance of DefaultRigCalibration(), metres.
constexpr double kDefaultWorkingDistance = 0.6;

// Partial clouds of one mesh seen by an ideal depth camera, for database construction:
// one point per pixel whose centre ray hits the mesh (occlusion by the depth buffer, exact
// ray–triangle depth), camera frame, with unit normals facing the camera. OSMesa; no
// projector, no noise. The context and the uploaded mesh are reused across Render calls.
class DepthRenderer {
 public:
  explicit DepthRenderer(const CameraModel& camera);
  ~DepthRenderer();
  DepthRenderer(const DepthRenderer&) = delete;
  DepthRenderer& operator=(const DepthRenderer&) = delete;

  // Throws sope::Error on an invalid mesh.
  void SetMesh(const TriangleMesh& mesh);
  PointCloud Render(const Rigid3d& cam_from_model);
  // Depth image (CV_32FC1, metres, NaN = background) of the last Render.
  const cv::Mat& depth() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace sope
