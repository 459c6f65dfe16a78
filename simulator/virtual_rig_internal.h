// Internals of the virtual rig shared with its tests: the ideal views that cover a
// distorted field of view, fast sub-pixel rays, and exact ray casting guided by a
// rasterised id image.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include "core/camera_model.h"
#include "core/mesh.h"
#include "core/rigid3d.h"
#include "simulator/osmesa_context.h"

namespace sope {
namespace internal {

// Ideal pinhole views are rasterised at this many texels per device pixel (per side).
constexpr double kIdealDensity = 2.0;
// Border of the ideal view beyond the undistorted device field, texels.
constexpr int kIdealMarginTexels = 4;

// An ideal (undistorted) pinhole view of `device` whose image contains the undistorted
// position of every point of the device's image area [−½, W − ½] × [−½, H − ½] with a
// margin of kIdealMarginTexels: focal lengths are density·fx, density·fy. When that exceeds
// `max_size` texels the density is lowered to fit; throws sope::Error when it would fall
// below 0.5 (a lens too wide for one pinhole view).
PinholeView MakeCoveringView(const CameraModel& device, double density, int max_size);

// Normalised-plane bounds (x/z, y/z, undistorted) of the device's image area.
struct FieldBounds {
  double min_x = 0, max_x = 0, min_y = 0, max_y = 0;
};
FieldBounds UndistortedFieldBounds(const CameraModel& device);

// Clip distances for rasterising objects with bounding spheres (centre in the device frame,
// radius), metres. Returns false when every object is behind the device.
bool ClipRange(const std::vector<Eigen::Vector3d>& centers_in_device,
               const std::vector<double>& radii, double* near, double* far);

// Rays through sub-pixel positions of a device, fast enough for millions of samples:
// exact (CameraModel::CamFromImage) at pixel centres; elsewhere the centres' undistorted
// positions are interpolated bilinearly and refined by one Newton step on
// CameraModel::Distort with the interpolated Jacobian (error ~1e-13 on the normalised plane
// for a webcam lens, ~1e-11 for a strong wide-angle one; tested < 1e-10).
class RayTable {
 public:
  void Build(const CameraModel& device);
  // Undistorted normalised-plane point (x/z, y/z) seen through `pixel`.
  Eigen::Vector2d CamFromImage(const Eigen::Vector2d& pixel) const;
  // Unit ray direction through `pixel`, device frame.
  Eigen::Vector3d RayFromImage(const Eigen::Vector2d& pixel) const {
    return CamFromImage(pixel).homogeneous().normalized();
  }

 private:
  CameraModel device_;
  bool distorted_ = false;
  int stride_ = 0;  // width + 2
  // Pixel centres (x, y) for x in [−1, width], y in [−1, height]: index (y+1)·stride + x+1.
  std::vector<Eigen::Vector2d> centers_;
};

// Triangles of several meshes in one frame, indexed like IdRasteriser ids minus one.
struct Triangle {
  Eigen::Vector3d v0, edge1, edge2;  // v1 = v0 + edge1, v2 = v0 + edge2
  Eigen::Vector3d normal;            // unit, along edge1 × edge2 (outward for CCW faces)
  Eigen::Vector3d centroid;
  double radius = 0.0;  // largest vertex distance from the centroid
};

struct RayHit {
  double distance = std::numeric_limits<double>::infinity();  // along the unit ray, metres
  int triangle = -1;                                          // −1: no hit
  bool valid() const { return triangle >= 0; }
};

class TriangleSet {
 public:
  // Triangles of mesh k mapped by frame_from_model[k] (the frame rays will be cast in).
  void Build(const std::vector<const TriangleMesh*>& meshes,
             const std::vector<Rigid3d>& frame_from_model);

  size_t size() const { return triangles_.size(); }
  const Triangle& triangle(int index) const { return triangles_[index]; }
  int object_of(int triangle_index) const { return object_of_[triangle_index]; }

  // Möller–Trumbore with a 1e-9 barycentric tolerance so that shared edges are watertight.
  // `direction` unit length. Returns the distance or +inf when the ray misses.
  double Intersect(int index, const Eigen::Vector3d& origin,
                   const Eigen::Vector3d& direction) const;

  // Exact first hit of the ray, with the candidates taken from the id image `ids`
  // (CV_32SC1, IdRasteriser ids of this set) around `texel` (the ray's position in the
  // ideal image, OpenCV convention): the distinct ids of the 3×3 neighbourhood. The ray
  // may meet a triangle that covers no texel centre nearby (a sliver seen at grazing
  // incidence, or one smaller than a texel): when none of the candidates is hit, or a
  // missed one lies clearly in front of the hit (a nearer surface's silhouette), the mesh
  // is searched outwards from them through shared vertices, following faces within two
  // texels of the ray; a ray still without a hit tries the 5×5 neighbourhood (unwelded
  // meshes). `texel_angle` is the ideal view's texel size per unit distance (1/fx).
  RayHit CastRay(const cv::Mat& ids, const Eigen::Vector2d& texel, const Eigen::Vector3d& origin,
                 const Eigen::Vector3d& direction, double texel_angle) const;

  // True when a triangle other than `own_triangle` crosses the ray strictly before
  // `distance` (shadow test along the ray from a light towards a surface point at
  // `distance`): the ids of the 3×3 neighbourhood of `texel` in the light's id image, and
  // when some of them lie clearly in front of the point without being hit, the faces
  // around them near the ray (occluder silhouettes seen at grazing incidence are slivers
  // that may cover no texel centre).
  bool Occluded(const cv::Mat& ids, const Eigen::Vector2d& texel, const Eigen::Vector3d& origin,
                const Eigen::Vector3d& direction, double texel_angle, double distance,
                int own_triangle) const;

 private:
  // Visits the triangles reached from `seeds` through shared vertices, ring by ring (at
  // most `max_rings` rings and about a thousand triangles; only faces NearRay() lead on),
  // until `visit(triangle)` or, after a ring, `done()` returns true; returns whether that
  // happened.
  template <typename Visit, typename Done>
  bool ExpandRings(const int* seeds, int seed_count, int max_rings, const Eigen::Vector3d& origin,
                   const Eigen::Vector3d& direction, double slope, Visit visit, Done done) const;
  // Distance along the ray to the triangle's plane, +inf when parallel or behind.
  double PlaneDistance(int index, const Eigen::Vector3d& origin,
                       const Eigen::Vector3d& direction) const;
  // Whether the triangle's bounding sphere comes within slope·(distance along the ray) of
  // the ray.
  bool NearRay(int index, const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
               double slope) const;

  std::vector<Triangle> triangles_;
  std::vector<int> object_of_;
  // Vertex → faces (CSR, global vertex numbering) for the neighbour search.
  std::vector<int> vertex_face_start_;
  std::vector<int> vertex_faces_;
  std::vector<Eigen::Vector3i> faces_;  // global vertex indices
};

}  // namespace internal
}  // namespace sope
