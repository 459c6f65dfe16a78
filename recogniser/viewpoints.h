// Viewpoints of the virtual camera around a model for database construction (thesis §4.4.2,
// Fig. 4.6–4.7): a camera on a sphere of radius r about the model's centre O, at declination
// θ ∈ [0, π] (from the model's +z, the north pole) and right ascension φ ∈ [0, 2π) (from +x
// towards +y), looking at O.
//
// Two layouts:
//  - the thesis's 18 viewpoints. Fig. 4.7 shows five declination rings; we read it as
//    θ = 0°, 45°, 90°, 135°, 180° holding 1, 4, 8, 4 and 1 cameras, evenly spaced in φ,
//    the 45° and 135° rings at φ = 0°, 90°, 180°, 270° and the equator every 45° from
//    φ = 0° (the figure gives no offsets; this reading is symmetric under the model's
//    quarter turns about z and its mirror z ↦ −z);
//  - any number N by even sphere sampling: the Fibonacci (golden-angle) lattice
//    z_i = 1 − (2i + 1)/N, φ_i = i·π(3 − √5) mod 2π (González 2010, "Measurement of areas
//    on a sphere using Fibonacci and latitude–longitude lattices"); neighbouring points are
//    ≈ √(4π/N) rad apart and the poles are never hit exactly.
//
// Camera convention (OpenCV): x right, y down, z forward. The camera's z axis points from
// its centre at O + r·d(θ, φ), d = (sinθ cosφ, sinθ sinφ, cosθ), to O. Up-vector: the
// model's +z appears "up" in the image, i.e. the camera's y axis is −(+z) made orthogonal
// to the viewing axis: y_cam ∝ −(e_z − (e_z·z_cam) z_cam), x_cam = y_cam × z_cam. At the poles
// (sinθ = 0) that is undefined; we use its limit along the meridian φ (y_cam = (cosφ,
// sinφ, 0) at θ = 0, −(cosφ, sinφ, 0) at θ = π), so the pose is continuous in θ along each
// meridian and the pole views differ in roll only through φ.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/enum_strings.h"
#include "core/rigid3d.h"

namespace sope {

enum class ViewpointLayout {
  kThesis18,   // "thesis": the 18 viewpoints on five declination rings
  kFibonacci,  // "fibonacci": N points of the golden-angle lattice
};
template <>
struct EnumTable<ViewpointLayout> {
  static constexpr const char* kWhat = "viewpoint layout";
  static constexpr EnumName<ViewpointLayout> kNames[] = {{ViewpointLayout::kThesis18, "thesis"},
                                                        {ViewpointLayout::kFibonacci, "fibonacci"}};
};
std::string ToString(ViewpointLayout layout);
// Accepts "thesis" / "fibonacci"; throws sope::Error naming the text otherwise.
ViewpointLayout ViewpointLayoutFromString(const std::string& text);

// A direction on the viewing sphere, radians: θ declination from +z, φ right ascension.
struct Viewpoint {
  double theta = 0.0;
  double phi = 0.0;
  // Unit vector from the sphere's centre to the camera, model frame.
  Eigen::Vector3d Direction() const;
};

// The viewpoints of `layout`; `count` is the number N for kFibonacci (≥ 1) and must be 18
// (or 0, meaning 18) for kThesis18. Throws sope::Error otherwise.
std::vector<Viewpoint> MakeViewpoints(ViewpointLayout layout, int count);
// The thesis's 18 (see the file comment), ring by ring from the north pole, φ ascending.
std::vector<Viewpoint> ThesisViewpoints();
// N points of the Fibonacci lattice, i = 0 … N−1 from the north to the south.
std::vector<Viewpoint> FibonacciViewpoints(int count);

// Pose of a camera at `distance` metres from `center_in_model` (model frame) in direction
// `viewpoint`, looking at the centre with the up-vector convention above: cam_from_model
// maps the centre to (0, 0, distance). Throws sope::Error unless distance > 0.
Rigid3d CameraPoseForViewpoint(const Viewpoint& viewpoint, double distance,
                               const Eigen::Vector3d& center_in_model);

// The viewpoint (θ, φ) of the direction from the model centre to the camera centre,
// for a cam_from_model pose: d = normalize(model_from_cam.translation − center_in_model).
Viewpoint ViewpointFromPose(const Rigid3d& cam_from_model, const Eigen::Vector3d& center_in_model);

// Great-circle angle between two viewpoints, radians in [0, π].
double AngleBetween(const Viewpoint& a, const Viewpoint& b);

}  // namespace sope
