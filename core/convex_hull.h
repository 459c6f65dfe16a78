// Convex hulls of 3-D points (qhull, merged coplanar facets), the centre of mass of a
// solid mesh, and the faces an object can rest on. A rigid object on a plane rests on a
// face of its convex hull; the face is statically stable when the centre of mass projects
// (along the face normal) into the face polygon (e.g. Moll & Erdmann, "Manipulation of pose
// distributions", IJRR 2002; the quasi-static probability of landing on a face is the solid
// angle the face subtends at the centre of mass, Wiegley et al. 1996). Used by the virtual
// rig's table scenes (simulator/table_scene.h) and the recogniser's plane prior
// (recogniser/scene_recognition.h).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"

namespace sope {

// A convex hull (qhull) of points: merged facets with outward unit normals.
struct HullFacet {
  Eigen::Vector3d normal;  // outward, unit
  double offset = 0.0;     // normal·x + offset = 0 on the facet, < 0 inside
  std::vector<Eigen::Vector3d> polygon;  // facet vertices in order around the normal
};
struct ConvexHull {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<HullFacet> facets;
  double volume = 0.0;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();  // of the solid hull
  // Signed distance of `point` outside the hull (max over facets of normal·x + offset).
  double Distance(const Eigen::Vector3d& point) const;
};
ConvexHull ComputeConvexHull(const std::vector<Eigen::Vector3d>& points);

// Centre of mass of the solid bounded by `mesh` (uniform density); falls back to the
// hull's centroid when the mesh is not a closed solid of positive volume close to it.
Eigen::Vector3d CenterOfMass(const TriangleMesh& mesh, const ConvexHull& hull);

struct RestingFace {
  int facet = -1;
  double probability = 0.0;  // solid angle / 4π
  double stability_margin = 0.0;  // distance of the projected centre inside the polygon, m
};
// The statically stable faces of `hull` for centre of mass `center`, most probable first.
std::vector<RestingFace> StableFaces(const ConvexHull& hull, const Eigen::Vector3d& center);

// 2-D convex hull (Andrew's monotone chain): counter-clockwise, collinear points dropped.
std::vector<Eigen::Vector2d> ConvexHull2d(std::vector<Eigen::Vector2d> points);

}  // namespace sope
