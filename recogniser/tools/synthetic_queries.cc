#include "recogniser/tools/synthetic_queries.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>

#include "core/error.h"
#include "core/units.h"

namespace sope {
namespace {
constexpr double kReferenceRange = 0.6;  // metres, where depth_noise applies
}  // namespace

void SyntheticQueryOptions::Check() const {
  SOPE_CHECK(min_distance > 0.0 && max_distance >= min_distance,
             "synthetic query: need 0 < min_distance ≤ max_distance, got {} and {}", min_distance,
             max_distance);
  SOPE_CHECK(max_off_axis >= 0.0 && max_off_axis < 1.2,
             "synthetic query: max_off_axis must be in [0, 1.2) rad, got {}", max_off_axis);
  SOPE_CHECK(depth_noise >= 0.0, "synthetic query: depth_noise must be ≥ 0, got {}", depth_noise);
  SOPE_CHECK(max_occlusion >= 0.0 && max_occlusion < 1.0,
             "synthetic query: max_occlusion must be in [0, 1), got {}", max_occlusion);
}

SyntheticQuery RenderSyntheticQuery(DepthRenderer* renderer, const CameraModel& camera,
                                    const Eigen::Vector3d& center_in_model, double bounding_radius,
                                    const SyntheticQueryOptions& options, std::mt19937_64* rng) {
  options.Check();
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::normal_distribution<double> gaussian(0.0, 1.0);
  SyntheticQuery query;
  query.viewpoint.theta = std::acos(std::clamp(1.0 - 2.0 * uniform(*rng), -1.0, 1.0));
  query.viewpoint.phi = 2.0 * kPi * uniform(*rng);
  query.distance = options.min_distance + (options.max_distance - options.min_distance) * uniform(*rng);
  query.roll = options.random_roll ? 2.0 * kPi * uniform(*rng) : 0.0;
  // Off-axis: the centre's direction in the camera, uniform over a disc of angles.
  double max_off_axis = options.max_off_axis;
  if (options.keep_in_view) {
    // Half field of view of the narrower image side, minus the sphere's angular radius.
    const double half_fov = std::min(std::atan(0.5 * camera.width / camera.fx()),
                                     std::atan(0.5 * camera.height / camera.fy()));
    const double sphere = std::asin(std::min(1.0, bounding_radius / query.distance));
    max_off_axis = std::clamp(half_fov - sphere, 0.0, max_off_axis);
  }
  const double off_angle = max_off_axis * std::sqrt(uniform(*rng));
  const double off_direction = 2.0 * kPi * uniform(*rng);
  const Eigen::Vector3d center_direction(std::sin(off_angle) * std::cos(off_direction),
                                         std::sin(off_angle) * std::sin(off_direction),
                                         std::cos(off_angle));
  const Eigen::Matrix3d pan = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(),
                                                                  center_direction)
                                  .toRotationMatrix();
  const Rigid3d look = CameraPoseForViewpoint(query.viewpoint, query.distance, center_in_model);
  const Eigen::Matrix3d roll = Eigen::AngleAxisd(query.roll, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  query.cam_from_model = Rigid3d(pan * roll, Eigen::Vector3d::Zero()) * look;

  PointCloud rendered = renderer->Render(query.cam_from_model);
  // Depth noise along the rays.
  for (Eigen::Vector3f& p : rendered.points) {
    const double range = p.norm();
    const double sigma = options.depth_noise * (range / kReferenceRange) * (range / kReferenceRange);
    p *= static_cast<float>((range + sigma * gaussian(*rng)) / range);
  }
  // Occluder: hide the points beyond a random edge in the image.
  const size_t n = rendered.size();
  query.occluded_fraction = options.max_occlusion * uniform(*rng);
  if (n > 0 && query.occluded_fraction > 0.0) {
    const double edge_angle = 2.0 * kPi * uniform(*rng);
    const Eigen::Vector2f edge(static_cast<float>(std::cos(edge_angle)),
                               static_cast<float>(std::sin(edge_angle)));
    std::vector<float> along(n);
    for (size_t i = 0; i < n; ++i) {
      const Eigen::Vector3f& p = rendered.points[i];
      along[i] = edge.dot(Eigen::Vector2f(p.x() / p.z(), p.y() / p.z()));
    }
    std::vector<float> sorted = along;
    const size_t keep = n - static_cast<size_t>(query.occluded_fraction * n);
    std::nth_element(sorted.begin(), sorted.begin() + std::min(keep, n - 1), sorted.end());
    const float threshold = sorted[std::min(keep, n - 1)];
    for (size_t i = 0; i < n; ++i) {
      if (along[i] < threshold || keep == n) query.cloud.points.push_back(rendered.points[i]);
    }
    query.occluded_fraction = 1.0 - static_cast<double>(query.cloud.size()) / n;
  } else {
    query.cloud.points = std::move(rendered.points);
  }
  return query;
}

}  // namespace sope
