#include "simulator/scene_builder.h"

#include "core/error.h"
#include "simulator/primitives.h"
#include "simulator/procedural_objects.h"

namespace sope {

SceneObject PlaceObject(const TriangleMesh& mesh, const Placement& placement,
                        double* applied_scale) {
  mesh.Check();
  SOPE_CHECK(placement.size >= 0, "object size must be ≥ 0, got {}", placement.size);
  Eigen::Vector3f lo, hi;
  mesh.Bounds(&lo, &hi);
  const double diagonal = (hi - lo).norm();
  SOPE_CHECK(diagonal > 0, "mesh is degenerate (zero extent)");
  const double scale = placement.size > 0 ? placement.size / diagonal : 1.0;
  const Eigen::Vector3d center = 0.5 * (lo + hi).cast<double>();
  SceneObject object;
  object.mesh = mesh;
  object.mesh.Transform(scale, Eigen::Vector3d::Zero());
  // X_cam = R·(X_scaled − s·c) + p.
  object.cam_from_model.rotation = placement.rotation;
  object.cam_from_model.translation =
      placement.center_in_cam - placement.rotation * (scale * center);
  if (applied_scale != nullptr) *applied_scale = scale;
  return object;
}

TriangleMesh LoadMeshSpec(const std::string& spec) {
  const std::string prefix = "builtin:";
  if (spec.rfind(prefix, 0) != 0) return ReadMesh(spec);
  const std::string name = spec.substr(prefix.size());
  if (name == "sphere") return MakeSphere(0.1, 48, 96);
  if (name == "box") return MakeBox(0.16, 0.1, 0.06);
  if (name == "cylinder") return MakeCylinder(0.05, 0.16, 96, true);
  if (name == "torus") return MakeTorus(0.07, 0.025, 96, 48);
  if (name == "plane") return MakePlane(0.3, 0.2, 8);
  // Procedural household objects: "CLASS" (seed 0) or "CLASS:SEED".
  const size_t colon = name.find(':');
  const std::string class_name = name.substr(0, colon);
  std::string known;
  for (ObjectClass cls : AllObjectClasses()) {
    known += ", " + ToString(cls);
    if (class_name != ToString(cls)) continue;
    if (colon == std::string::npos) return MakeObject(cls, 0);
    const std::string seed = name.substr(colon + 1);
    SOPE_CHECK(!seed.empty() && seed.size() <= 19 &&
                   seed.find_first_not_of("0123456789") == std::string::npos,
               "builtin mesh '{}': seed '{}' must be a non-negative integer", name, seed);
    return MakeObject(cls, std::stoull(seed));
  }
  SOPE_THROW(
      "unknown builtin mesh '{}' (known: sphere, box, cylinder, torus, plane{}, each object "
      "class also as CLASS:SEED)",
      name, known);
}

SceneObject MakeBackdrop(double distance, double width, double height, double albedo) {
  SOPE_CHECK(distance > 0 && width > 0 && height > 0, "backdrop needs positive sizes");
  SceneObject backdrop;
  const float w = static_cast<float>(width / 2), h = static_cast<float>(height / 2);
  backdrop.mesh.vertices = {{-w, -h, 0}, {w, -h, 0}, {w, h, 0}, {-w, h, 0}};
  // Counter-clockwise seen from the camera (looking along +z, y down): normal −z.
  backdrop.mesh.faces = {{0, 2, 1}, {0, 3, 2}};
  backdrop.cam_from_model.translation = Eigen::Vector3d(0, 0, distance);
  backdrop.albedo = albedo;
  return backdrop;
}

}  // namespace sope
