// Triangle meshes and their files: OBJ, PLY, OFF, STL (ASCII and binary where the format
// has both). Polygons are fan-triangulated.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

namespace sope {

struct TriangleMesh {
  std::vector<Eigen::Vector3f> vertices;  // model units (metres for our meshes)
  std::vector<Eigen::Vector3i> faces;     // counter-clockwise vertex indices

  // Throws sope::Error on no faces, out-of-range indices or non-finite vertices.
  void Check() const;
  // Axis-aligned bounds of the vertices used by faces.
  void Bounds(Eigen::Vector3f* min_corner, Eigen::Vector3f* max_corner) const;
  // Largest distance between two vertices, approximated by the bounding-box diagonal.
  double BoundingDiagonal() const;
  // Area-weighted centroid of the surface.
  Eigen::Vector3d SurfaceCentroid() const;
  double SurfaceArea() const;
  // Applies x ↦ scale·x + offset to every vertex.
  void Transform(double scale, const Eigen::Vector3d& offset);
};

// Reads a mesh by extension (.obj .ply .off .stl, case-insensitive). Throws sope::Error
// naming the file and line/element on malformed input.
TriangleMesh ReadMesh(const std::string& path);
// Writes PLY (binary) or OBJ by extension, atomically.
void WriteMesh(const std::string& path, const TriangleMesh& mesh);

// Models directories (DIR/<class>/<model>.obj, DESIGN.md "Database"): a class directory
// holding a file of this name (any content) is a category, a folder of alike objects
// (different mugs) whose unseen instances the tabletop recogniser may take for the class.
// Without it a folder of several models is a set of instances (a dataset's unlike
// objects: only the models themselves are recognised). `sope objects` writes it.
inline constexpr const char* kCategoryMarker = "CATEGORY";

}  // namespace sope
