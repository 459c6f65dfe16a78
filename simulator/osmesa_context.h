// Headless OpenGL for the simulator: an OSMesa core-profile context that rasterises, per
// pixel of an ideal (distortion-free) pinhole view, the id of the nearest triangle. The GL
// and OSMesa headers stay in osmesa_context.cc (STYLE.md §2).
#pragma once

#include <memory>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include "core/mesh.h"
#include "core/rigid3d.h"

namespace sope {
namespace internal {

// An ideal pinhole image (no distortion). Pixel convention is OpenCV's: the centre of the
// top-left pixel is (0, 0), x right, y down; the device looks along +z.
struct PinholeView {
  int width = 0;                                  // pixels
  int height = 0;                                 // pixels
  double fx = 1.0, fy = 1.0, cx = 0.0, cy = 0.0;  // pixels

  // u = fx·x/z + cx, v = fy·y/z + cy (point in the device frame, z > 0).
  Eigen::Vector2d Project(const Eigen::Vector3d& point_in_device) const {
    return Eigen::Vector2d(fx * point_in_device.x() / point_in_device.z() + cx,
                           fy * point_in_device.y() / point_in_device.z() + cy);
  }
};

// GL clip coordinates from device coordinates for `view` with clip distances near < far
// (metres along +z). GL window pixel centres sit at half-integers, so the OpenCV pixel
// (u, v) maps to window (u + ½, v + ½): window x_w = (x_c/w_c + 1)·width/2 = u + ½, and
// likewise y (no flip: GL row j of the framebuffer is image row j). z_ndc is −1 at near,
// +1 at far, w_c = z.
Eigen::Matrix4d ClipFromDevice(const PinholeView& view, double near, double far);

// Triangle-id rasteriser on its own OSMesa context (GL ≥ 3.3 core, llvmpipe). Every call
// makes its context current on the calling thread; one instance must not be used from two
// threads at once. Triangles are drawn two-sided with a 32-bit float depth test.
class IdRasteriser {
 public:
  // Throws sope::Error when OSMesa cannot create a core-profile context.
  IdRasteriser();
  ~IdRasteriser();
  IdRasteriser(const IdRasteriser&) = delete;
  IdRasteriser& operator=(const IdRasteriser&) = delete;

  // Uploads meshes, replacing the previous ones (the pointers are not kept). Triangle j of
  // mesh k gets the id first_id(k) + j with first_id(0) = 1 and first_id(k + 1) =
  // first_id(k) + faces of mesh k; 0 is background. Meshes must be valid (Check()).
  void SetMeshes(const std::vector<const TriangleMesh*>& meshes);
  // Rasterises `view` with mesh k posed by `device_from_model[k]` (one per mesh). `ids`
  // becomes CV_32SC1 view.height × view.width: ids(j, i) is the id of the nearest triangle
  // covering the ideal-image point (i, j), 0 for none. Throws sope::Error when the view is
  // larger than max_size() or the pose count is wrong.
  void Render(const PinholeView& view, const std::vector<Rigid3d>& device_from_model, double near,
              double far, cv::Mat* ids);
  // Largest framebuffer side the context supports, pixels.
  int max_size() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace internal
}  // namespace sope
