// Composing virtual-rig scenes: placing a mesh of arbitrary units and origin in front of
// the camera, and a backdrop plane behind it.
#pragma once

#include <string>

#include "core/mesh.h"
#include "core/rigid3d.h"
#include "simulator/virtual_rig.h"

namespace sope {

struct Placement {
  // Orientation of the object and position of its bounding-box centre, camera frame
  // (metres): cam_from_model maps the box centre to `center_in_cam`.
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d center_in_cam = Eigen::Vector3d(0, 0, 0.6);
  // Bounding-box diagonal to scale the mesh to, metres; 0 keeps the mesh's own units.
  double size = 0.0;
};

// A scene object for `mesh` at `placement`. The mesh keeps its file's model frame scaled
// by `*applied_scale` (1 when placement.size is 0); cam_from_model includes the centring.
SceneObject PlaceObject(const TriangleMesh& mesh, const Placement& placement,
                        double* applied_scale = nullptr);

// The mesh named by `spec`: "builtin:NAME" for a procedural mesh (sphere, box, cylinder,
// torus, plane; metres, about 0.2 m across), "builtin:CLASS" or "builtin:CLASS:SEED" for a
// procedural household object (simulator/procedural_objects.h: mug, bottle, …; seed 0 by
// default; "builtin:box" stays the primitive, "builtin:box:0" is the procedural box),
// otherwise a mesh file read with ReadMesh. Throws sope::Error naming an unknown builtin
// (and listing the known ones) or a malformed seed.
TriangleMesh LoadMeshSpec(const std::string& spec);

// A flat matte backdrop facing the camera at depth `distance` (metres), `width`×`height`
// metres, centred on the optical axis.
SceneObject MakeBackdrop(double distance, double width, double height, double albedo = 0.6);

}  // namespace sope
