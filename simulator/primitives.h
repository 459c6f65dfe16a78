// Procedural triangle meshes for tests and demos: model frame, metres, faces
// counter-clockwise seen from outside (edge1 × edge2 points outward). The closed shapes are
// watertight (every edge shared by exactly two faces, vertices welded).
#pragma once

#include "core/mesh.h"

namespace sope {

// Rectangle in the plane z = 0, x in [−width/2, width/2], y in [−height/2, height/2],
// split into `subdivisions` × `subdivisions` cells of two triangles. Its faces point to −z:
// posed with cam_from_model = (I, (0, 0, d)), d > 0, it faces the camera. Open (not
// watertight). Throws sope::Error unless width, height > 0 and subdivisions ≥ 1.
TriangleMesh MakePlane(double width, double height, int subdivisions = 1);

// Sphere of `radius` centred at the origin: poles on ±z, `rings` latitude bands (≥ 2) and
// `segments` longitudes (≥ 3). The vertices lie on the sphere, the faces inside it: every
// surface point is within radius·(1 − cos(½·√(Δθ² + Δφ²))) of it, Δθ = π/rings,
// Δφ = 2π/segments (SphereTessellationGap()).
TriangleMesh MakeSphere(double radius, int rings = 32, int segments = 64);

// That bound, metres.
double SphereTessellationGap(double radius, int rings, int segments);

// Axis-aligned box centred at the origin with full edge lengths size_x, size_y, size_z
// (8 vertices, 12 triangles).
TriangleMesh MakeBox(double size_x, double size_y, double size_z);

// Cylinder around the z axis, z in [−height/2, height/2], `segments` (≥ 3) side quads;
// with `capped` the two discs close it (watertight), otherwise it is an open tube.
TriangleMesh MakeCylinder(double radius, double height, int segments = 64, bool capped = true);

// Torus around the z axis: tube of `minor_radius` around the circle of `major_radius`
// (> minor_radius) in the plane z = 0; `major_segments`, `minor_segments` ≥ 3.
TriangleMesh MakeTorus(double major_radius, double minor_radius, int major_segments = 64,
                       int minor_segments = 32);

}  // namespace sope
