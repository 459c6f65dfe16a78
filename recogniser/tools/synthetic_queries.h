// Synthetic recognition queries with ground truth, for tests and evaluation: a model seen by
// a depth camera from a random viewpoint that is *not* on any database grid, at a random
// distance, rolled about the line of sight and off the image centre, with depth noise and
// part of the object hidden by an occluder.
//
// Query camera (OpenCV axes): placed at `distance` from the model's centre in a direction
// drawn uniformly on the sphere, looking at the centre with the viewpoints' up-vector
// convention (recogniser/viewpoints.h), then rolled by a uniform angle about its optical
// axis and panned/tilted so that the centre appears up to `max_off_axis` away from the
// optical axis. Noise: Gaussian along each ray, σ = depth_noise · (range / 0.6 m)² (the
// quadratic growth of triangulation error). With keep_in_view the off-axis angle is limited
// so that the bounding sphere stays inside the image. Occlusion: an occluder edge of random
// direction across the object's image hides the fraction f ~ U[0, max_occlusion] of the
// points on one side (the occluder itself is segmented away, as a range-band filter
// would).
#pragma once

#include <cstdint>
#include <random>
#include <vector>

#include "core/camera_model.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rigid3d.h"
#include "recogniser/viewpoints.h"
#include "simulator/virtual_rig.h"

namespace sope {

struct SyntheticQueryOptions {
  double min_distance = 0.4;  // metres, camera to model centre
  double max_distance = 0.8;
  double max_off_axis = 0.2;   // radians between the optical axis and the model centre
  // Limit the off-axis angle so that the model's bounding sphere stays inside the image
  // (the whole object in view; occlusion is then the only partiality).
  bool keep_in_view = true;
  double depth_noise = 0.001;  // metres at 0.6 m range (σ along the ray)
  double max_occlusion = 0.25;  // largest fraction of the points hidden
  bool random_roll = true;
  void Check() const;
};

struct SyntheticQuery {
  PointCloud cloud;          // camera frame, metres (no normals)
  Rigid3d cam_from_model;    // ground truth
  Viewpoint viewpoint;       // direction of the camera from the model centre (model frame)
  double distance = 0.0;     // metres
  double roll = 0.0;         // radians
  double occluded_fraction = 0.0;
  double occluder_angle = 0.0;  // radians: direction of the occluder edge (when occluded)
};

// The points (camera frame) that an occluder edge across the image hides not: the edge's
// normal in the image plane at `edge_angle`, the `fraction` of the points farthest along
// it hidden (as RenderSyntheticQuery occludes; the scan protocol applies the same occluder
// to a scanned cloud).
std::vector<Eigen::Vector3f> HideBeyondEdge(const std::vector<Eigen::Vector3f>& points,
                                            double fraction, double edge_angle);

// A query of the mesh last given to `renderer` (SetMesh; model frame, metres, viewpoints
// around `center_in_model`, the model within `bounding_radius` metres of it), seen by
// `camera` (the renderer's camera). Throws sope::Error on invalid options. The cloud can be
// empty when the object falls outside the image (callers retry).
SyntheticQuery RenderSyntheticQuery(DepthRenderer* renderer, const CameraModel& camera,
                                    const Eigen::Vector3d& center_in_model, double bounding_radius,
                                    const SyntheticQueryOptions& options, std::mt19937_64* rng);

}  // namespace sope
