#include "recogniser/viewpoints.h"

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "core/units.h"

namespace sope {
namespace {

constexpr double kDeg = kPi / 180.0;
// Below this sinθ the viewing axis is treated as parallel to the model's z axis.
constexpr double kPoleSin = 1e-9;

}  // namespace

std::string ToString(ViewpointLayout layout) { return EnumToString(layout); }

ViewpointLayout ViewpointLayoutFromString(const std::string& text) {
  return EnumFromString<ViewpointLayout>(text);
}

Eigen::Vector3d Viewpoint::Direction() const {
  return Eigen::Vector3d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi),
                         std::cos(theta));
}

std::vector<Viewpoint> ThesisViewpoints() {
  struct Ring {
    double theta_deg;
    int count;
  };
  constexpr Ring kRings[] = {{0, 1}, {45, 4}, {90, 8}, {135, 4}, {180, 1}};
  std::vector<Viewpoint> viewpoints;
  for (const Ring& ring : kRings) {
    for (int k = 0; k < ring.count; ++k) {
      viewpoints.push_back({ring.theta_deg * kDeg, 2.0 * kPi * k / ring.count});
    }
  }
  return viewpoints;
}

std::vector<Viewpoint> FibonacciViewpoints(int count) {
  SOPE_CHECK(count >= 1, "FibonacciViewpoints: count must be ≥ 1, got {}", count);
  const double golden_angle = kPi * (3.0 - std::sqrt(5.0));
  std::vector<Viewpoint> viewpoints(count);
  for (int i = 0; i < count; ++i) {
    const double z = 1.0 - (2.0 * i + 1.0) / count;
    viewpoints[i].theta = std::acos(std::clamp(z, -1.0, 1.0));
    viewpoints[i].phi = std::fmod(golden_angle * i, 2.0 * kPi);
  }
  return viewpoints;
}

std::vector<Viewpoint> MakeViewpoints(ViewpointLayout layout, int count) {
  switch (layout) {
    case ViewpointLayout::kThesis18:
      SOPE_CHECK(count == 0 || count == 18,
                 "the thesis viewpoint layout has 18 viewpoints, {} requested", count);
      return ThesisViewpoints();
    case ViewpointLayout::kFibonacci:
      return FibonacciViewpoints(count);
  }
  SOPE_THROW("MakeViewpoints: invalid layout");
}

Rigid3d CameraPoseForViewpoint(const Viewpoint& viewpoint, double distance,
                               const Eigen::Vector3d& center_in_model) {
  SOPE_CHECK(distance > 0.0 && std::isfinite(distance),
             "CameraPoseForViewpoint: distance must be > 0 m, got {}", distance);
  const Eigen::Vector3d direction = viewpoint.Direction();
  const Eigen::Vector3d z_cam = -direction;  // forward, model frame
  Eigen::Vector3d y_cam;                      // image down, model frame
  if (std::sin(viewpoint.theta) > kPoleSin) {
    const Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
    y_cam = -(up - up.dot(z_cam) * z_cam).normalized();
  } else {
    // Limit of the above along the meridian φ (see the header).
    const Eigen::Vector3d meridian(std::cos(viewpoint.phi), std::sin(viewpoint.phi), 0.0);
    y_cam = std::cos(viewpoint.theta) > 0.0 ? meridian : Eigen::Vector3d(-meridian);
  }
  const Eigen::Vector3d x_cam = y_cam.cross(z_cam);
  Eigen::Matrix3d model_from_cam_rotation;
  model_from_cam_rotation.col(0) = x_cam;
  model_from_cam_rotation.col(1) = y_cam;
  model_from_cam_rotation.col(2) = z_cam;
  const Eigen::Vector3d camera_in_model = center_in_model + distance * direction;
  return Rigid3d(model_from_cam_rotation, camera_in_model).Inverse();
}

Viewpoint ViewpointFromPose(const Rigid3d& cam_from_model, const Eigen::Vector3d& center_in_model) {
  const Eigen::Vector3d camera_in_model = cam_from_model.Inverse().translation;
  const Eigen::Vector3d direction = (camera_in_model - center_in_model).normalized();
  Viewpoint viewpoint;
  viewpoint.theta = std::acos(std::clamp(direction.z(), -1.0, 1.0));
  viewpoint.phi = std::atan2(direction.y(), direction.x());
  if (viewpoint.phi < 0.0) viewpoint.phi += 2.0 * kPi;
  return viewpoint;
}

double AngleBetween(const Viewpoint& a, const Viewpoint& b) {
  const double cosine = std::clamp(a.Direction().dot(b.Direction()), -1.0, 1.0);
  return std::acos(cosine);
}

}  // namespace sope
