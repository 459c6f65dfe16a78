#include "simulator/virtual_rig.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/split_mix.h"
#include "simulator/osmesa_context.h"
#include "simulator/sensor_noise.h"
#include "simulator/virtual_rig_internal.h"

namespace sope {
namespace internal {
namespace {

// Barycentric slack of the ray–triangle test: a ray through a shared edge hits both faces.
constexpr double kBarycentricTolerance = 1e-9;
// Hits closer than this to the ray origin are ignored, metres.
constexpr double kMinHitDistance = 1e-9;
// A shadow-ray hit counts as an occluder only this much before the lit point (relative
// and absolute, metres): coplanar neighbours at a shared edge must not shadow each other.
constexpr double kShadowRelativeTolerance = 1e-7;
constexpr double kShadowAbsoluteTolerance = 1e-9;
// Missed candidates whose plane the ray crosses this much (relative) before the hit or lit
// point seed a search for slivers of a nearer surface; smaller gaps are the hit's own
// curved surface.
constexpr double kSearchRelativeDepth = 1e-3;

constexpr int kMaxCandidates = 25;
// Bounds of the mesh search for triangles the rasteriser did not sample (CastRay, Occluded).
constexpr int kMaxFallbackRings = 8;
constexpr size_t kMaxFallbackTriangles = 1024;
// The search continues through faces within this many texels of the ray.
constexpr double kSearchTexels = 2.0;

// Distinct non-zero ids in the (2r+1)² window around (ci, cj), clamped to the image.
int GatherIds(const cv::Mat& ids, int ci, int cj, int radius, int* candidates) {
  int count = 0;
  int last = 0;  // runs of equal ids (the common case inside a triangle) skip the search
  for (int j = std::max(cj - radius, 0); j <= std::min(cj + radius, ids.rows - 1); ++j) {
    const int32_t* row = ids.ptr<int32_t>(j);
    for (int i = std::max(ci - radius, 0); i <= std::min(ci + radius, ids.cols - 1); ++i) {
      const int id = row[i];
      if (id == 0 || id == last) continue;
      last = id;
      bool seen = false;
      for (int k = 0; k < count && !seen; ++k) seen = candidates[k] == id;
      if (!seen) candidates[count++] = id;
    }
  }
  return count;
}

// Nearest-texel indices, or false when `texel` is not within one texel of the image.
bool NearestTexel(const cv::Mat& ids, const Eigen::Vector2d& texel, int* ci, int* cj) {
  if (!(texel.x() > -1.5 && texel.y() > -1.5 && texel.x() < ids.cols + 0.5 &&
        texel.y() < ids.rows + 0.5)) {
    return false;
  }
  *ci = static_cast<int>(std::floor(texel.x() + 0.5));
  *cj = static_cast<int>(std::floor(texel.y() + 0.5));
  return true;
}

// The smallest rectangle holding every non-zero id (empty when there is none).
cv::Rect IdBoundingBox(const cv::Mat& ids) {
  int min_x = ids.cols, max_x = -1, min_y = ids.rows, max_y = -1;
  for (int j = 0; j < ids.rows; ++j) {
    const int32_t* row = ids.ptr<int32_t>(j);
    int first = 0;
    while (first < ids.cols && row[first] == 0) ++first;
    if (first == ids.cols) continue;
    int last = ids.cols - 1;
    while (row[last] == 0) --last;
    min_x = std::min(min_x, first);
    max_x = std::max(max_x, last);
    min_y = std::min(min_y, j);
    max_y = j;
  }
  if (max_x < 0) return cv::Rect();
  return cv::Rect(min_x, min_y, max_x - min_x + 1, max_y - min_y + 1);
}

}  // namespace

FieldBounds UndistortedFieldBounds(const CameraModel& device) {
  FieldBounds bounds;
  bounds.min_x = bounds.min_y = std::numeric_limits<double>::infinity();
  bounds.max_x = bounds.max_y = -std::numeric_limits<double>::infinity();
  const auto include = [&](double x, double y) {
    const Eigen::Vector2d p = device.CamFromImage(Eigen::Vector2d(x, y));
    bounds.min_x = std::min(bounds.min_x, p.x());
    bounds.max_x = std::max(bounds.max_x, p.x());
    bounds.min_y = std::min(bounds.min_y, p.y());
    bounds.max_y = std::max(bounds.max_y, p.y());
  };
  // The image area's border, every half pixel, bounds the undistorted field of any lens
  // whose distortion is a bijection over the image (the interior maps inside).
  const double left = -0.5, top = -0.5, right = device.width - 0.5, bottom = device.height - 0.5;
  const int steps_x = 2 * device.width, steps_y = 2 * device.height;
  for (int i = 0; i <= steps_x; ++i) {
    const double x = left + (right - left) * i / steps_x;
    include(x, top);
    include(x, bottom);
  }
  for (int i = 0; i <= steps_y; ++i) {
    const double y = top + (bottom - top) * i / steps_y;
    include(left, y);
    include(right, y);
  }
  include(device.cx(), device.cy());
  return bounds;
}

PinholeView MakeCoveringView(const CameraModel& device, double density, int max_size) {
  const FieldBounds field = UndistortedFieldBounds(device);
  constexpr double kMinDensity = 0.5;
  for (;;) {
    PinholeView view;
    view.fx = density * device.fx();
    view.fy = density * device.fy();
    view.cx = kIdealMarginTexels - view.fx * field.min_x;
    view.cy = kIdealMarginTexels - view.fy * field.min_y;
    const double width =
        std::ceil(view.fx * (field.max_x - field.min_x)) + 2 * kIdealMarginTexels + 1;
    const double height =
        std::ceil(view.fy * (field.max_y - field.min_y)) + 2 * kIdealMarginTexels + 1;
    if (width <= max_size && height <= max_size) {
      view.width = static_cast<int>(width);
      view.height = static_cast<int>(height);
      return view;
    }
    density *= 0.99 * std::min(max_size / width, max_size / height);
    SOPE_CHECK(density >= kMinDensity,
               "the undistorted field of a {}x{} device (x/z in [{:.3f}, {:.3f}], y/z in "
               "[{:.3f}, {:.3f}]) is too wide for a {} px ideal view",
               device.width, device.height, field.min_x, field.max_x, field.min_y, field.max_y,
               max_size);
  }
}

bool ClipRange(const std::vector<Eigen::Vector3d>& centers_in_device,
               const std::vector<double>& radii, double* near, double* far) {
  double min_z = std::numeric_limits<double>::infinity();
  double max_z = -std::numeric_limits<double>::infinity();
  for (size_t k = 0; k < centers_in_device.size(); ++k) {
    min_z = std::min(min_z, centers_in_device[k].z() - radii[k]);
    max_z = std::max(max_z, centers_in_device[k].z() + radii[k]);
  }
  if (!(max_z > 0.0)) return false;
  // Margins keep the bounding sphere strictly inside the clip volume; the near plane of a
  // scene reaching behind the device stays at 1/1000 of the far plane for depth precision.
  *far = 1.01 * max_z + 1e-6;
  *near = std::max(0.99 * min_z, 1e-3 * *far);
  return true;
}

void RayTable::Build(const CameraModel& device) {
  device_ = device;
  distorted_ = device.HasDistortion();
  stride_ = device.width + 2;
  centers_.resize(static_cast<size_t>(stride_) * (device.height + 2));
  cv::parallel_for_(cv::Range(-1, device.height + 1), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      for (int x = -1; x <= device.width; ++x) {
        centers_[static_cast<size_t>(y + 1) * stride_ + x + 1] =
            device.CamFromImage(Eigen::Vector2d(x, y));
      }
    }
  });
}

Eigen::Vector2d RayTable::CamFromImage(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d target((pixel.x() - device_.cx()) / device_.fx(),
                               (pixel.y() - device_.cy()) / device_.fy());
  if (!distorted_) return target;
  const int x0 = std::clamp(static_cast<int>(std::floor(pixel.x())), -1, device_.width - 1);
  const int y0 = std::clamp(static_cast<int>(std::floor(pixel.y())), -1, device_.height - 1);
  const double tx = pixel.x() - x0, ty = pixel.y() - y0;
  const Eigen::Vector2d* row = &centers_[static_cast<size_t>(y0 + 1) * stride_ + x0 + 1];
  const Eigen::Vector2d& c00 = row[0];
  const Eigen::Vector2d& c10 = row[1];
  const Eigen::Vector2d& c01 = row[stride_];
  const Eigen::Vector2d& c11 = row[stride_ + 1];
  if (tx == 0.0 && ty == 0.0) return c00;  // a pixel centre: exact
  Eigen::Vector2d estimate =
      (1 - ty) * ((1 - tx) * c00 + tx * c10) + ty * ((1 - tx) * c01 + tx * c11);
  // d(undistorted)/d(distorted normalised) from the interpolated pixel derivatives.
  Eigen::Matrix2d inverse_jacobian;
  inverse_jacobian.col(0) = ((1 - ty) * (c10 - c00) + ty * (c11 - c01)) * device_.fx();
  inverse_jacobian.col(1) = ((1 - tx) * (c01 - c00) + tx * (c11 - c10)) * device_.fy();
  estimate -= inverse_jacobian * (device_.Distort(estimate) - target);
  return estimate;
}

void TriangleSet::Build(const std::vector<const TriangleMesh*>& meshes,
                        const std::vector<Rigid3d>& frame_from_model) {
  triangles_.clear();
  object_of_.clear();
  faces_.clear();
  int vertex_count = 0;
  for (size_t k = 0; k < meshes.size(); ++k) {
    const TriangleMesh& mesh = *meshes[k];
    const Rigid3d& pose = frame_from_model[k];
    std::vector<Eigen::Vector3d> vertices(mesh.vertices.size());
    for (size_t v = 0; v < vertices.size(); ++v) {
      vertices[v] = pose * mesh.vertices[v].cast<double>();
    }
    for (const Eigen::Vector3i& face : mesh.faces) {
      Triangle triangle;
      triangle.v0 = vertices[face[0]];
      triangle.edge1 = vertices[face[1]] - triangle.v0;
      triangle.edge2 = vertices[face[2]] - triangle.v0;
      const Eigen::Vector3d normal = triangle.edge1.cross(triangle.edge2);
      const double norm = normal.norm();
      triangle.normal = norm > 0.0 ? Eigen::Vector3d(normal / norm) : Eigen::Vector3d::Zero();
      triangle.centroid = triangle.v0 + (triangle.edge1 + triangle.edge2) / 3.0;
      triangle.radius = std::max({(triangle.v0 - triangle.centroid).norm(),
                                  (vertices[face[1]] - triangle.centroid).norm(),
                                  (vertices[face[2]] - triangle.centroid).norm()});
      triangles_.push_back(triangle);
      object_of_.push_back(static_cast<int>(k));
      faces_.push_back(face + Eigen::Vector3i::Constant(vertex_count));
    }
    vertex_count += static_cast<int>(mesh.vertices.size());
  }
  vertex_face_start_.assign(vertex_count + 1, 0);
  for (const Eigen::Vector3i& face : faces_) {
    for (int c = 0; c < 3; ++c) ++vertex_face_start_[face[c] + 1];
  }
  for (int v = 0; v < vertex_count; ++v) vertex_face_start_[v + 1] += vertex_face_start_[v];
  vertex_faces_.resize(vertex_face_start_.back());
  std::vector<int> fill(vertex_face_start_.begin(), vertex_face_start_.end() - 1);
  for (size_t f = 0; f < faces_.size(); ++f) {
    for (int c = 0; c < 3; ++c) vertex_faces_[fill[faces_[f][c]]++] = static_cast<int>(f);
  }
}

double TriangleSet::Intersect(int index, const Eigen::Vector3d& origin,
                              const Eigen::Vector3d& direction) const {
  constexpr double kMiss = std::numeric_limits<double>::infinity();
  const Triangle& triangle = triangles_[index];
  const Eigen::Vector3d pvec = direction.cross(triangle.edge2);
  const double det = triangle.edge1.dot(pvec);
  if (det == 0.0) return kMiss;
  const double inv_det = 1.0 / det;
  const Eigen::Vector3d tvec = origin - triangle.v0;
  const double u = tvec.dot(pvec) * inv_det;
  if (u < -kBarycentricTolerance || u > 1.0 + kBarycentricTolerance) return kMiss;
  const Eigen::Vector3d qvec = tvec.cross(triangle.edge1);
  const double v = direction.dot(qvec) * inv_det;
  if (v < -kBarycentricTolerance || u + v > 1.0 + kBarycentricTolerance) return kMiss;
  const double t = triangle.edge2.dot(qvec) * inv_det;
  return t > kMinHitDistance ? t : kMiss;
}

template <typename Visit, typename Done>
bool TriangleSet::ExpandRings(const int* seeds, int seed_count, int max_rings,
                              const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                              double slope, Visit visit, Done done) const {
  // Visited marks: one stamp per triangle, a fresh stamp value per search.
  thread_local std::vector<uint32_t> stamps;
  thread_local uint32_t stamp = 0;
  thread_local std::vector<int> frontier, next;
  if (stamps.size() < triangles_.size()) stamps.resize(triangles_.size(), 0);
  if (++stamp == 0) {
    std::fill(stamps.begin(), stamps.end(), 0);
    stamp = 1;
  }
  frontier.assign(seeds, seeds + seed_count);
  for (int triangle_index : frontier) stamps[triangle_index] = stamp;
  size_t visited = frontier.size();
  for (int ring = 0; ring < max_rings && visited < kMaxFallbackTriangles; ++ring) {
    next.clear();
    for (int triangle_index : frontier) {
      const Eigen::Vector3i& face = faces_[triangle_index];
      for (int c = 0; c < 3; ++c) {
        for (int n = vertex_face_start_[face[c]]; n < vertex_face_start_[face[c] + 1]; ++n) {
          const int neighbour = vertex_faces_[n];
          if (stamps[neighbour] == stamp) continue;
          stamps[neighbour] = stamp;
          next.push_back(neighbour);
        }
      }
    }
    if (next.empty()) return false;
    for (int triangle_index : next) {
      if (visit(triangle_index)) return true;
    }
    if (done()) return true;
    visited += next.size();
    // Only faces passing close to the ray lead on: the search follows the ray, not the mesh.
    frontier.clear();
    for (int triangle_index : next) {
      if (NearRay(triangle_index, origin, direction, slope)) frontier.push_back(triangle_index);
    }
  }
  return false;
}

double TriangleSet::PlaneDistance(int index, const Eigen::Vector3d& origin,
                                  const Eigen::Vector3d& direction) const {
  const Triangle& triangle = triangles_[index];
  const double along_normal = triangle.normal.dot(direction);
  if (along_normal == 0.0) return std::numeric_limits<double>::infinity();
  const double distance = triangle.normal.dot(triangle.v0 - origin) / along_normal;
  return distance > 0.0 ? distance : std::numeric_limits<double>::infinity();
}

bool TriangleSet::NearRay(int index, const Eigen::Vector3d& origin,
                          const Eigen::Vector3d& direction, double slope) const {
  const Triangle& triangle = triangles_[index];
  const Eigen::Vector3d relative = triangle.centroid - origin;
  const double along = relative.dot(direction);
  if (along < -triangle.radius) return false;
  const double reach = triangle.radius + slope * std::max(along, 0.0);
  return relative.squaredNorm() - along * along <= reach * reach;
}

RayHit TriangleSet::CastRay(const cv::Mat& ids, const Eigen::Vector2d& texel,
                            const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                            double texel_angle) const {
  RayHit best;
  int ci = 0, cj = 0;
  if (!NearestTexel(ids, texel, &ci, &cj)) return best;
  const auto consider = [&](int triangle_index) {
    const double t = Intersect(triangle_index, origin, direction);
    if (t < best.distance) {
      best.distance = t;
      best.triangle = triangle_index;
    }
  };
  std::array<int, kMaxCandidates> candidates;
  int count = GatherIds(ids, ci, cj, 1, candidates.data());
  for (int k = 0; k < count; ++k) consider(candidates[k] - 1);
  if (count == 0) return best;
  if (best.valid()) {
    // A missed candidate whose plane the ray crosses clearly before the hit belongs to a
    // nearer surface: the ray passes by its silhouette, where grazing slivers may cover no
    // texel centre. Search there for a nearer hit.
    const double search_limit = best.distance * (1.0 - kSearchRelativeDepth);
    std::array<int, kMaxCandidates> seeds;
    int seed_count = 0;
    for (int k = 0; k < count; ++k) {
      const int triangle_index = candidates[k] - 1;
      if (triangle_index != best.triangle &&
          PlaneDistance(triangle_index, origin, direction) < search_limit) {
        seeds[seed_count++] = triangle_index;
      }
    }
    if (seed_count > 0) {
      const double first_distance = best.distance;
      ExpandRings(
          seeds.data(), seed_count, kMaxFallbackRings, origin, direction,
          kSearchTexels * texel_angle,
          [&](int triangle_index) {
            consider(triangle_index);
            return false;
          },
          [&] { return best.distance < first_distance; });
    }
    return best;
  }
  // The ray passes through a triangle that covers no texel centre nearby (a sliver seen at
  // grazing incidence, or a triangle smaller than a texel): search the mesh outwards from
  // the candidates, then a wider window (for unwelded meshes).
  for (int k = 0; k < count; ++k) candidates[k] -= 1;
  if (ExpandRings(
          candidates.data(), count, kMaxFallbackRings, origin, direction,
          kSearchTexels * texel_angle,
          [&](int triangle_index) {
            consider(triangle_index);
            return false;  // finish the ring: the nearest of its hits
          },
          [&] { return best.valid(); })) {
    return best;
  }
  count = GatherIds(ids, ci, cj, 2, candidates.data());
  for (int k = 0; k < count; ++k) consider(candidates[k] - 1);
  return best;
}

bool TriangleSet::Occluded(const cv::Mat& ids, const Eigen::Vector2d& texel,
                           const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                           double texel_angle, double distance, int own_triangle) const {
  int ci = 0, cj = 0;
  if (!NearestTexel(ids, texel, &ci, &cj)) return false;
  std::array<int, kMaxCandidates> candidates;
  const int count = GatherIds(ids, ci, cj, 1, candidates.data());
  const double limit = distance * (1.0 - kShadowRelativeTolerance) - kShadowAbsoluteTolerance;
  const double search_limit = distance * (1.0 - kSearchRelativeDepth);
  std::array<int, kMaxCandidates> seeds;
  int seed_count = 0;
  for (int k = 0; k < count; ++k) {
    const int triangle_index = candidates[k] - 1;
    if (triangle_index == own_triangle) continue;
    if (Intersect(triangle_index, origin, direction) < limit) return true;
    // A missed candidate clearly in front of the point: an occluder's silhouette is near,
    // and its grazing slivers may cover no texel centre.
    if (PlaneDistance(triangle_index, origin, direction) < search_limit) {
      seeds[seed_count++] = triangle_index;
    }
  }
  if (seed_count == 0) return false;
  bool occluded = false;
  ExpandRings(
      seeds.data(), seed_count, kMaxFallbackRings, origin, direction, kSearchTexels * texel_angle,
      [&](int triangle_index) {
        occluded =
            triangle_index != own_triangle && Intersect(triangle_index, origin, direction) < limit;
        return occluded;
      },
      [&] { return occluded; });
  return occluded;
}

}  // namespace internal

namespace {

// std::bit_cast of C++20.
template <typename To, typename From>
To BitCast(const From& from) {
  static_assert(sizeof(To) == sizeof(From), "same size");
  To to;
  std::memcpy(&to, &from, sizeof(To));
  return to;
}

using internal::PinholeView;
using internal::RayHit;
using internal::TriangleSet;

// Bounding sphere of a mesh in its model frame: box centre and half diagonal.
void ModelBoundingSphere(const TriangleMesh& mesh, Eigen::Vector3d* center, double* radius) {
  Eigen::Vector3f lo, hi;
  mesh.Bounds(&lo, &hi);
  *center = 0.5 * (lo + hi).cast<double>();
  *radius = 0.5 * (hi - lo).cast<double>().norm() + 1e-6;
}

// Rasterises the ids of the posed meshes for `view`, or clears them when nothing can be in
// front of the device.
void RenderIds(internal::IdRasteriser* rasteriser, const PinholeView& view,
               const std::vector<Rigid3d>& device_from_model,
               const std::vector<Eigen::Vector3d>& model_centers, const std::vector<double>& radii,
               cv::Mat* ids) {
  std::vector<Eigen::Vector3d> centers(model_centers.size());
  for (size_t k = 0; k < centers.size(); ++k) centers[k] = device_from_model[k] * model_centers[k];
  double near = 0, far = 0;
  if (!internal::ClipRange(centers, radii, &near, &far)) {
    ids->create(view.height, view.width, CV_32SC1);
    ids->setTo(cv::Scalar(0));
    return;
  }
  rasteriser->Render(view, device_from_model, near, far, ids);
}

// One lit camera sample: its bilinear footprint in the projector image and its weight
// (linear grey levels per unit of projector intensity).
struct LitSample {
  uint32_t index;   // projector pixel (x0, y0): y0·width + x0
  uint16_t frac_x;  // (u − x0)·65535
  uint16_t frac_y;  // (v − y0)·65535
  float weight;
};

struct SampleResult {
  bool hit = false;
  bool lit = false;
  int object = -1;
  double depth = 0.0;    // camera z, metres
  Eigen::Vector2d proj;  // projector pixel
  double albedo = 0.0;
  double shading = 0.0;  // albedo·cos·(reference/distance)²
};

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

}  // namespace

void SensorOptions::Check() const {
  SOPE_CHECK(std::isfinite(ambient) && ambient >= 0.0,
             "SensorOptions: ambient must be >= 0, got {}", ambient);
  SOPE_CHECK(std::isfinite(reference_distance) && reference_distance > 0.0,
             "SensorOptions: reference_distance must be > 0 m, got {}", reference_distance);
  SOPE_CHECK(std::isfinite(exposure) && exposure > 0.0,
             "SensorOptions: exposure must be > 0, got {}", exposure);
  SOPE_CHECK(std::isfinite(gamma) && gamma > 0.0, "SensorOptions: gamma must be > 0, got {}",
             gamma);
  // Blur work grows with σ (kernel ≈ 6σ wide per pass); beyond 25 px every stripe finer
  // than ≈ 50 px is washed out anyway.
  constexpr double kMaxBlurSigmaPx = 25.0;
  SOPE_CHECK(std::isfinite(defocus_sigma_px) && defocus_sigma_px >= 0.0 &&
                 defocus_sigma_px <= kMaxBlurSigmaPx,
             "SensorOptions: defocus_sigma_px must be in [0, {}] px, got {}", kMaxBlurSigmaPx,
             defocus_sigma_px);
  SOPE_CHECK(std::isfinite(camera_blur_sigma_px) && camera_blur_sigma_px >= 0.0 &&
                 camera_blur_sigma_px <= kMaxBlurSigmaPx,
             "SensorOptions: camera_blur_sigma_px must be in [0, {}] px, got {}",
             kMaxBlurSigmaPx, camera_blur_sigma_px);
  SOPE_CHECK(std::isfinite(read_noise) && read_noise >= 0.0,
             "SensorOptions: read_noise must be >= 0, got {}", read_noise);
  SOPE_CHECK(std::isfinite(shot_noise) && shot_noise >= 0.0,
             "SensorOptions: shot_noise must be >= 0, got {}", shot_noise);
  SOPE_CHECK(std::isfinite(projector_gamma) && projector_gamma > 0.0 && projector_gamma <= 10.0,
             "SensorOptions: projector_gamma must be in (0, 10], got {}", projector_gamma);
  SOPE_CHECK(std::isfinite(projector_black_level) && projector_black_level >= 0.0 &&
                 projector_black_level < 1.0,
             "SensorOptions: projector_black_level must be in [0, 1), got {}",
             projector_black_level);
  SOPE_CHECK(std::isfinite(projector_saturation) && projector_saturation > 0.0 &&
                 projector_saturation <= 1.0,
             "SensorOptions: projector_saturation must be in (0, 1], got {}", projector_saturation);
  SOPE_CHECK(supersample >= 1 && supersample <= 8,
             "SensorOptions: supersample must be in [1, 8], got {}", supersample);
}

struct VirtualRig::Impl {
  RigCalibration calibration;
  SensorOptions options;
  internal::IdRasteriser rasteriser;
  internal::RayTable camera_rays;
  PinholeView camera_view;
  PinholeView projector_view;
  internal::FieldBounds projector_field;  // widened by a margin
  Eigen::Vector3d projector_center_in_cam;
  std::vector<Eigen::Vector2d> sample_offsets;  // camera pixels, stratified
  int center_sample = -1;                       // index of offset (0, 0), −1 if absent
  // Grey-level thresholds of the response: output k ≥ 1 iff linear ≥ thresholds[k − 1].
  std::array<float, 255> response_thresholds{};
  // The same lookup in O(1): std::upper_bound over response_thresholds (the grey level of
  // a linear value) starts from the count at the lower edge of the value's bin and walks
  // at most a step or two — the identical result (the walk is exact from any start). The
  // bins are the top bits of the positive float (8 mantissa bits: 0.4% of the value wide),
  // so they are as fine for the dark levels of a gamma curve as for the bright ones.
  static constexpr int kResponseBinShift = 15;
  std::vector<uint8_t> response_bin_count;
  uint32_t response_first_bin = 0;
  // Scratch of Capture, kept so that a sequence of captures does not fault in fresh pages.
  // The blurs write to scratch of their own rather than in place (the same values).
  cv::Mat capture_pattern, capture_linear, capture_pattern_blurred, capture_linear_blurred;
  void BuildResponseBins();
  uint8_t Quantise(float value) const;
  std::mt19937_64 noise_engine;

  bool scene_set = false;
  GroundTruth ground_truth;
  cv::Mat ambient;                               // CV_32FC1: linear grey level from ambient light
  std::vector<std::vector<uint32_t>> row_start;  // per row: width + 1 sample offsets
  std::vector<std::vector<LitSample>> row_samples;

  // Scene state used while precomputing samples.
  TriangleSet triangles;
  cv::Mat camera_ids, projector_ids;
  std::vector<Rigid3d> model_from_cam;
  const Scene* scene = nullptr;

  SampleResult EvaluateSample(const Eigen::Vector2d& pixel) const;
};

void VirtualRig::Impl::BuildResponseBins() {
  const float* thresholds = response_thresholds.data();
  const float first = std::max(thresholds[0], std::numeric_limits<float>::min());
  const float last = std::max(thresholds[254], first);
  response_first_bin = BitCast<uint32_t>(first) >> kResponseBinShift;
  const uint32_t last_bin = BitCast<uint32_t>(last) >> kResponseBinShift;
  response_bin_count.resize(last_bin - response_first_bin + 1);
  for (uint32_t bin = response_first_bin; bin <= last_bin; ++bin) {
    const float edge = BitCast<float>(bin << kResponseBinShift);
    response_bin_count[bin - response_first_bin] =
        static_cast<uint8_t>(std::upper_bound(thresholds, thresholds + 255, edge) - thresholds);
  }
}

inline uint8_t VirtualRig::Impl::Quantise(float value) const {
  const float* thresholds = response_thresholds.data();
  // Exactly std::upper_bound's answer: the first k with value < thresholds[k], 255 if none
  // (also for NaN).
  if (value < thresholds[0]) return 0;
  if (!(value < thresholds[254])) return 255;
  // thresholds[0] ≤ value < thresholds[254]: positive unless thresholds[0] ≤ 0.
  const uint32_t bits = BitCast<uint32_t>(std::max(value, std::numeric_limits<float>::min()));
  uint32_t bin = (bits >> kResponseBinShift) - response_first_bin;
  bin = std::min<uint32_t>(bin, static_cast<uint32_t>(response_bin_count.size() - 1));
  int k = response_bin_count[bin];
  while (k > 0 && value < thresholds[k - 1]) --k;
  while (k < 255 && !(value < thresholds[k])) ++k;
  return static_cast<uint8_t>(k);
}

SampleResult VirtualRig::Impl::EvaluateSample(const Eigen::Vector2d& pixel) const {
  SampleResult result;
  const Eigen::Vector3d ray = camera_rays.RayFromImage(pixel);
  const RayHit hit = triangles.CastRay(camera_ids, camera_view.Project(ray),
                                       Eigen::Vector3d::Zero(), ray, 1.0 / camera_view.fx);
  if (!hit.valid()) return result;
  result.hit = true;
  const Eigen::Vector3d point = hit.distance * ray;
  result.depth = point.z();
  result.object = triangles.object_of(hit.triangle);
  const SceneObject& object = scene->objects[result.object];
  result.albedo =
      object.albedo_map ? object.albedo_map(model_from_cam[result.object] * point) : object.albedo;

  Eigen::Vector3d normal = triangles.triangle(hit.triangle).normal;
  if (normal.dot(ray) > 0.0) normal = -normal;  // the side the camera sees
  const Eigen::Vector3d point_in_proj = calibration.proj_from_cam * point;
  if (!(point_in_proj.z() > 0.0)) return result;
  const double nx = point_in_proj.x() / point_in_proj.z();
  const double ny = point_in_proj.y() / point_in_proj.z();
  if (!(nx >= projector_field.min_x && nx <= projector_field.max_x && ny >= projector_field.min_y &&
        ny <= projector_field.max_y)) {
    return result;
  }
  const Eigen::Vector2d proj = calibration.projector.ImageFromCam(point_in_proj);
  const CameraModel& projector = calibration.projector;
  if (!(proj.x() >= -0.5 && proj.x() < projector.width - 0.5 && proj.y() >= -0.5 &&
        proj.y() < projector.height - 0.5)) {
    return result;
  }
  const Eigen::Vector3d to_projector = projector_center_in_cam - point;
  const double distance = to_projector.norm();
  const Eigen::Vector3d light = to_projector / distance;
  const double cosine = normal.dot(light);
  if (!(cosine > 0.0)) return result;
  if (triangles.Occluded(projector_ids, projector_view.Project(point_in_proj),
                         projector_center_in_cam, -light, 1.0 / projector_view.fx, distance,
                         hit.triangle)) {
    return result;
  }
  result.lit = true;
  result.proj = proj;
  const double falloff = options.reference_distance / distance;
  result.shading = result.albedo * cosine * falloff * falloff;
  return result;
}

VirtualRig::VirtualRig(const RigCalibration& calibration, const SensorOptions& options)
    : impl_(nullptr) {
  calibration.Check();
  options.Check();
  SOPE_CHECK(calibration.projector.width >= 2 && calibration.projector.height >= 2,
             "VirtualRig: projector must be at least 2x2 pixels, got {}x{}",
             calibration.projector.width, calibration.projector.height);
  impl_ = std::make_unique<Impl>();
  Impl& d = *impl_;
  d.calibration = calibration;
  d.options = options;
  d.camera_rays.Build(calibration.camera);
  d.camera_view = internal::MakeCoveringView(calibration.camera, internal::kIdealDensity,
                                             d.rasteriser.max_size());
  d.projector_view = internal::MakeCoveringView(calibration.projector, internal::kIdealDensity,
                                                d.rasteriser.max_size());
  d.projector_field = internal::UndistortedFieldBounds(calibration.projector);
  const double margin_x = 0.01 * (d.projector_field.max_x - d.projector_field.min_x);
  const double margin_y = 0.01 * (d.projector_field.max_y - d.projector_field.min_y);
  d.projector_field.min_x -= margin_x;
  d.projector_field.max_x += margin_x;
  d.projector_field.min_y -= margin_y;
  d.projector_field.max_y += margin_y;
  d.projector_center_in_cam = calibration.proj_from_cam.Inverse().translation;

  const int s = options.supersample;
  for (int j = 0; j < s; ++j) {
    for (int i = 0; i < s; ++i) {
      if (2 * i + 1 == s && 2 * j + 1 == s)
        d.center_sample = static_cast<int>(d.sample_offsets.size());
      d.sample_offsets.emplace_back((i + 0.5) / s - 0.5, (j + 0.5) / s - 0.5);
    }
  }
  for (int k = 1; k <= 255; ++k) {
    d.response_thresholds[k - 1] =
        static_cast<float>(255.0 * std::pow((k - 0.5) / 255.0, options.gamma));
  }
  d.BuildResponseBins();
  d.noise_engine.seed(options.seed);
}

VirtualRig::~VirtualRig() = default;

const GroundTruth& VirtualRig::ground_truth() const { return impl_->ground_truth; }
const RigCalibration& VirtualRig::calibration() const { return impl_->calibration; }
const SensorOptions& VirtualRig::options() const { return impl_->options; }

void VirtualRig::SetScene(const Scene& scene) {
  Impl& d = *impl_;
  d.scene_set = false;
  const size_t object_count = scene.objects.size();
  std::vector<const TriangleMesh*> meshes;
  std::vector<Rigid3d> cam_from_model, proj_from_model;
  std::vector<Eigen::Vector3d> model_centers(object_count);
  std::vector<double> radii(object_count);
  d.model_from_cam.clear();
  for (size_t k = 0; k < object_count; ++k) {
    const SceneObject& object = scene.objects[k];
    try {
      object.mesh.Check();
    } catch (const Error& e) {
      SOPE_THROW("scene object {}: {}", k, e.what());
    }
    SOPE_CHECK(object.albedo_map ||
                   (std::isfinite(object.albedo) && object.albedo >= 0.0 && object.albedo <= 1.0),
               "scene object {}: albedo must be in [0, 1], got {}", k, object.albedo);
    SOPE_CHECK(
        object.cam_from_model.rotation.allFinite() && object.cam_from_model.translation.allFinite(),
        "scene object {}: pose is not finite", k);
    meshes.push_back(&object.mesh);
    cam_from_model.push_back(object.cam_from_model);
    proj_from_model.push_back(d.calibration.proj_from_cam * object.cam_from_model);
    d.model_from_cam.push_back(object.cam_from_model.Inverse());
    ModelBoundingSphere(object.mesh, &model_centers[k], &radii[k]);
  }

  d.rasteriser.SetMeshes(meshes);
  RenderIds(&d.rasteriser, d.camera_view, cam_from_model, model_centers, radii, &d.camera_ids);
  RenderIds(&d.rasteriser, d.projector_view, proj_from_model, model_centers, radii,
            &d.projector_ids);
  d.triangles.Build(meshes, cam_from_model);
  d.scene = &scene;

  const int width = d.calibration.camera.width, height = d.calibration.camera.height;
  const int projector_width = d.calibration.projector.width;
  const int projector_height = d.calibration.projector.height;
  // Fresh buffers: copies of the previous ground truth (cv::Mat shares data) stay valid.
  GroundTruth& truth = d.ground_truth;
  truth.depth = cv::Mat(height, width, CV_32FC1);
  truth.proj_x = cv::Mat(height, width, CV_32FC1);
  truth.proj_y = cv::Mat(height, width, CV_32FC1);
  truth.lit = cv::Mat(height, width, CV_8UC1);
  truth.object_id = cv::Mat(height, width, CV_32SC1);
  d.ambient.create(height, width, CV_32FC1);
  d.row_start.resize(height);
  d.row_samples.resize(height);

  const double sample_weight = d.options.exposure / d.sample_offsets.size();
  const double ambient_weight = d.options.ambient * sample_weight;
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      std::vector<uint32_t>& start = d.row_start[y];
      std::vector<LitSample>& samples = d.row_samples[y];
      start.assign(width + 1, 0);
      samples.clear();
      float* depth = truth.depth.ptr<float>(y);
      float* proj_x = truth.proj_x.ptr<float>(y);
      float* proj_y = truth.proj_y.ptr<float>(y);
      uint8_t* lit = truth.lit.ptr<uint8_t>(y);
      int32_t* object_id = truth.object_id.ptr<int32_t>(y);
      float* ambient = d.ambient.ptr<float>(y);
      for (int x = 0; x < width; ++x) {
        start[x] = static_cast<uint32_t>(samples.size());
        const Eigen::Vector2d pixel(x, y);
        double albedo_sum = 0.0;
        bool all_lit = true;
        int footprint_object = -1;
        SampleResult center;
        for (size_t s = 0; s < d.sample_offsets.size(); ++s) {
          const SampleResult sample = d.EvaluateSample(pixel + d.sample_offsets[s]);
          if (static_cast<int>(s) == d.center_sample) center = sample;
          if (!sample.hit) {
            all_lit = false;
            continue;
          }
          albedo_sum += sample.albedo;
          if (footprint_object < 0) footprint_object = sample.object;
          all_lit = all_lit && sample.lit && sample.object == footprint_object;
          if (!sample.lit) continue;
          // Bilinear footprint, clamped to the border pixels (replicated border).
          const double u = std::clamp(sample.proj.x(), 0.0, projector_width - 1.0);
          const double v = std::clamp(sample.proj.y(), 0.0, projector_height - 1.0);
          const int x0 = std::min(static_cast<int>(u), projector_width - 2);
          const int y0 = std::min(static_cast<int>(v), projector_height - 2);
          LitSample lit_sample;
          lit_sample.index = static_cast<uint32_t>(y0 * projector_width + x0);
          lit_sample.frac_x = static_cast<uint16_t>(std::lround((u - x0) * 65535.0));
          lit_sample.frac_y = static_cast<uint16_t>(std::lround((v - y0) * 65535.0));
          lit_sample.weight = static_cast<float>(sample_weight * sample.shading);
          samples.push_back(lit_sample);
        }
        if (d.center_sample < 0) center = d.EvaluateSample(pixel);
        ambient[x] = static_cast<float>(ambient_weight * albedo_sum);
        lit[x] = all_lit ? 255 : 0;
        depth[x] = center.hit ? static_cast<float>(center.depth) : kNaN;
        object_id[x] = center.hit ? center.object : -1;
        proj_x[x] = center.lit ? static_cast<float>(center.proj.x()) : kNaN;
        proj_y[x] = center.lit ? static_cast<float>(center.proj.y()) : kNaN;
      }
      start[width] = static_cast<uint32_t>(samples.size());
    }
  });
  d.scene = nullptr;
  d.scene_set = true;
}

cv::Mat VirtualRig::Capture(const cv::Mat& projector_image) {
  Impl& d = *impl_;
  SOPE_CHECK(d.scene_set, "VirtualRig::Capture: SetScene() has not been called");
  const CameraModel& projector = d.calibration.projector;
  SOPE_CHECK(!projector_image.empty() && projector_image.cols == projector.width &&
                 projector_image.rows == projector.height,
             "VirtualRig::Capture: projector image is {}x{}, the projector is {}x{}",
             projector_image.cols, projector_image.rows, projector.width, projector.height);
  SOPE_CHECK(projector_image.type() == CV_8UC1 || projector_image.type() == CV_32FC1,
             "VirtualRig::Capture: projector image must be CV_8UC1 or CV_32FC1, got {}",
             cv::typeToString(projector_image.type()));
  const SensorOptions& o = d.options;
  const bool response =
      o.projector_gamma != 1.0 || o.projector_black_level != 0.0 || o.projector_saturation != 1.0;
  const float black = static_cast<float>(o.projector_black_level);
  const float saturation = static_cast<float>(o.projector_saturation);
  const float gamma = static_cast<float>(o.projector_gamma);
  const auto shown = [&](float value) {
    const float v = std::min(value, saturation) / saturation;
    return black + (1.0f - black) * std::pow(std::max(v, 0.0f), gamma);
  };
  cv::Mat& pattern = d.capture_pattern;
  if (projector_image.type() == CV_8UC1) {
    // 256 levels: the conversion and the projector response, as convertTo and the float
    // arithmetic below give them per pixel, as a table.
    cv::Mat levels(1, 256, CV_8UC1), table;
    for (int level = 0; level < 256; ++level) {
      levels.at<uint8_t>(level) = static_cast<uint8_t>(level);
    }
    levels.convertTo(table, CV_32F, 1.0 / 255.0);
    if (response) table.forEach<float>([&](float& value, const int*) { value = shown(value); });
    cv::LUT(projector_image, table, pattern);
  } else {
    cv::Point bad_position;
    SOPE_CHECK(cv::checkRange(projector_image, true, &bad_position, 0.0, 1.0 + 1e-6),
               "VirtualRig::Capture: CV_32FC1 projector image must be in [0, 1], pixel ({}, {}) "
               "is {}",
               bad_position.x, bad_position.y,
               projector_image.at<float>(bad_position.y, bad_position.x));
    projector_image.copyTo(pattern);
    if (response) pattern.forEach<float>([&](float& value, const int*) { value = shown(value); });
  }
  const cv::Mat* shown_pattern = &pattern;
  if (d.options.defocus_sigma_px > 0.0) {
    cv::GaussianBlur(pattern, d.capture_pattern_blurred, cv::Size(), d.options.defocus_sigma_px,
                     d.options.defocus_sigma_px, cv::BORDER_REPLICATE);
    shown_pattern = &d.capture_pattern_blurred;
  }
  const int width = d.calibration.camera.width, height = d.calibration.camera.height;
  cv::Mat& sampled = d.capture_linear;
  sampled.create(height, width, CV_32FC1);
  const float* pattern_data = shown_pattern->ptr<float>(0);
  const int stride = projector.width;
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    constexpr float kFraction = 1.0f / 65535.0f;
    for (int y = rows.start; y < rows.end; ++y) {
      const std::vector<uint32_t>& start = d.row_start[y];
      const LitSample* samples = d.row_samples[y].data();
      const float* ambient = d.ambient.ptr<float>(y);
      float* out = sampled.ptr<float>(y);
      for (int x = 0; x < width; ++x) {
        float sum = ambient[x];
        for (uint32_t s = start[x]; s < start[x + 1]; ++s) {
          const LitSample& sample = samples[s];
          const float* p = pattern_data + sample.index;
          const float fx = sample.frac_x * kFraction, fy = sample.frac_y * kFraction;
          const float top = p[0] + fx * (p[1] - p[0]);
          const float bottom = p[stride] + fx * (p[stride + 1] - p[stride]);
          sum += sample.weight * (top + fy * (bottom - top));
        }
        out[x] = sum;
      }
    }
  });
  const cv::Mat* linear_image = &sampled;
  if (d.options.camera_blur_sigma_px > 0.0) {
    cv::GaussianBlur(sampled, d.capture_linear_blurred, cv::Size(), d.options.camera_blur_sigma_px,
                     d.options.camera_blur_sigma_px, cv::BORDER_REPLICATE);
    linear_image = &d.capture_linear_blurred;
  }
  const cv::Mat& linear = *linear_image;

  const uint64_t call_seed = d.noise_engine();
  const bool noisy = d.options.read_noise > 0.0 || d.options.shot_noise > 0.0;
  const float read_variance = static_cast<float>(d.options.read_noise * d.options.read_noise);
  const float shot_noise = static_cast<float>(d.options.shot_noise);
  cv::Mat image(height, width, CV_8UC1);
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    std::vector<float> noisy_row(noisy ? width : 0);
    for (int y = rows.start; y < rows.end; ++y) {
      const float* in = linear.ptr<float>(y);
      uint8_t* out = image.ptr<uint8_t>(y);
      if (noisy) {
        // A row's deviates depend on the call's seed and the row only (any thread order):
        // decorrelated per-row seeds by one SplitMix64 step.
        internal::AddSensorNoise(SplitMix{call_seed ^ static_cast<uint64_t>(y)}.Next(), in,
                                 width, read_variance, shot_noise, noisy_row.data());
        in = noisy_row.data();
      }
      for (int x = 0; x < width; ++x) out[x] = d.Quantise(in[x]);
    }
  });
  return image;
}

RigCalibration DefaultRigCalibration() {
  RigCalibration calibration;
  CameraModel& camera = calibration.camera;
  camera.width = 1280;
  camera.height = 720;
  camera.matrix << 1400.0, 0.0, 642.3, 0.0, 1400.0, 357.8, 0.0, 0.0, 1.0;
  camera.distortion = {-0.08, 0.06, 4e-4, -3e-4, 0.0};
  CameraModel& projector = calibration.projector;
  projector.width = 1024;
  projector.height = 768;
  projector.matrix << 1500.0, 0.0, 511.5, 0.0, 1500.0, 383.5, 0.0, 0.0, 1.0;
  projector.distortion = {-0.01, 0.0, 0.0, 0.0, 0.0};
  // Projector centre 0.2 m to the camera's right; its optical axis through the camera's
  // working point, its y axis along the camera's (rows stay horizontal).
  const Eigen::Vector3d projector_center_in_cam(0.2, 0.0, 0.0);
  const Eigen::Vector3d working_point_in_cam(0.0, 0.0, kDefaultWorkingDistance);
  const Eigen::Vector3d z_axis = (working_point_in_cam - projector_center_in_cam).normalized();
  const Eigen::Vector3d y_axis = Eigen::Vector3d::UnitY();
  const Eigen::Vector3d x_axis = y_axis.cross(z_axis);
  Eigen::Matrix3d cam_from_proj_rotation;
  cam_from_proj_rotation << x_axis, y_axis, z_axis;
  calibration.proj_from_cam = Rigid3d(cam_from_proj_rotation, projector_center_in_cam).Inverse();
  return calibration;
}

struct DepthRenderer::Impl {
  CameraModel camera;
  internal::IdRasteriser rasteriser;
  PinholeView view;
  std::vector<Eigen::Vector3d> rays;    // unit, camera frame, per pixel centre
  std::vector<Eigen::Vector2d> texels;  // the rays' positions in the ideal view
  TriangleSet triangles;                // model frame
  Eigen::Vector3d model_center = Eigen::Vector3d::Zero();
  double model_radius = 0.0;
  bool has_mesh = false;
  cv::Mat ids;
  cv::Mat depth;    // CV_32FC1
  cv::Mat points;   // CV_32FC3, camera frame
  cv::Mat normals;  // CV_32FC3, camera frame
};

DepthRenderer::DepthRenderer(const CameraModel& camera) : impl_(nullptr) {
  camera.Check();
  impl_ = std::make_unique<Impl>();
  Impl& d = *impl_;
  d.camera = camera;
  d.view = internal::MakeCoveringView(camera, internal::kIdealDensity, d.rasteriser.max_size());
  d.rays.resize(static_cast<size_t>(camera.width) * camera.height);
  d.texels.resize(d.rays.size());
  cv::parallel_for_(cv::Range(0, camera.height), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        const size_t i = static_cast<size_t>(y) * camera.width + x;
        d.rays[i] = camera.RayFromImage(Eigen::Vector2d(x, y));
        d.texels[i] = d.view.Project(d.rays[i]);
      }
    }
  });
  d.depth.create(camera.height, camera.width, CV_32FC1);
  d.depth.setTo(cv::Scalar(kNaN));
  d.points.create(camera.height, camera.width, CV_32FC3);
  d.normals.create(camera.height, camera.width, CV_32FC3);
}

DepthRenderer::~DepthRenderer() = default;

void DepthRenderer::SetMesh(const TriangleMesh& mesh) {
  Impl& d = *impl_;
  d.has_mesh = false;
  try {
    mesh.Check();
  } catch (const Error& e) {
    SOPE_THROW("DepthRenderer::SetMesh: {}", e.what());
  }
  d.rasteriser.SetMeshes({&mesh});
  d.triangles.Build({&mesh}, {Rigid3d()});
  ModelBoundingSphere(mesh, &d.model_center, &d.model_radius);
  d.has_mesh = true;
}

PointCloud DepthRenderer::Render(const Rigid3d& cam_from_model) {
  Impl& d = *impl_;
  SOPE_CHECK(d.has_mesh, "DepthRenderer::Render: SetMesh() has not been called");
  SOPE_CHECK(cam_from_model.rotation.allFinite() && cam_from_model.translation.allFinite(),
             "DepthRenderer::Render: pose is not finite");
  // A fresh buffer: copies of the previous depth image (cv::Mat shares data) stay valid.
  d.depth = cv::Mat(d.camera.height, d.camera.width, CV_32FC1, cv::Scalar(kNaN));
  PointCloud cloud;
  RenderIds(&d.rasteriser, d.view, {cam_from_model}, {d.model_center}, {d.model_radius}, &d.ids);
  const Rigid3d model_from_cam = cam_from_model.Inverse();
  const int width = d.camera.width;
  // CastRay finds no hit for a pixel whose nearest texel's 3×3 window holds no id: those
  // outside the ids' bounding box (most of a view) are skipped before the ray is turned.
  const cv::Rect box = internal::IdBoundingBox(d.ids);
  if (box.empty()) return cloud;
  cv::parallel_for_(cv::Range(0, d.camera.height), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      float* depth = d.depth.ptr<float>(y);
      cv::Vec3f* points = d.points.ptr<cv::Vec3f>(y);
      cv::Vec3f* normals = d.normals.ptr<cv::Vec3f>(y);
      for (int x = 0; x < width; ++x) {
        const size_t i = static_cast<size_t>(y) * width + x;
        int ci = 0, cj = 0;
        if (!internal::NearestTexel(d.ids, d.texels[i], &ci, &cj) || ci + 1 < box.x ||
            ci - 1 >= box.x + box.width || cj + 1 < box.y || cj - 1 >= box.y + box.height) {
          continue;
        }
        const Eigen::Vector3d& ray = d.rays[i];
        const RayHit hit = d.triangles.CastRay(d.ids, d.texels[i], model_from_cam.translation,
                                               model_from_cam.rotation * ray, 1.0 / d.view.fx);
        if (!hit.valid()) continue;
        const Eigen::Vector3d point = hit.distance * ray;
        Eigen::Vector3d normal =
            cam_from_model.rotation * d.triangles.triangle(hit.triangle).normal;
        if (normal.dot(ray) > 0.0) normal = -normal;
        depth[x] = static_cast<float>(point.z());
        points[x] = cv::Vec3f(point.x(), point.y(), point.z());
        normals[x] = cv::Vec3f(normal.x(), normal.y(), normal.z());
      }
    }
  });
  for (int y = 0; y < d.camera.height; ++y) {
    const float* depth = d.depth.ptr<float>(y);
    const cv::Vec3f* points = d.points.ptr<cv::Vec3f>(y);
    const cv::Vec3f* normals = d.normals.ptr<cv::Vec3f>(y);
    for (int x = 0; x < width; ++x) {
      if (std::isnan(depth[x])) continue;
      cloud.points.emplace_back(points[x][0], points[x][1], points[x][2]);
      cloud.normals.emplace_back(normals[x][0], normals[x][1], normals[x][2]);
    }
  }
  return cloud;
}

const cv::Mat& DepthRenderer::depth() const { return impl_->depth; }

}  // namespace sope
