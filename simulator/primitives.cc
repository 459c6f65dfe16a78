#include "simulator/primitives.h"

#include <cmath>

#include "core/error.h"
#include "core/units.h"

namespace sope {
namespace {


void AddQuad(TriangleMesh* mesh, int a, int b, int c, int d) {
  mesh->faces.emplace_back(a, b, c);
  mesh->faces.emplace_back(a, c, d);
}

int AddVertex(TriangleMesh* mesh, double x, double y, double z) {
  mesh->vertices.emplace_back(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
  return static_cast<int>(mesh->vertices.size()) - 1;
}

}  // namespace

TriangleMesh MakePlane(double width, double height, int subdivisions) {
  SOPE_CHECK(width > 0.0 && height > 0.0, "MakePlane: size must be positive, got {}x{}", width,
             height);
  SOPE_CHECK(subdivisions >= 1, "MakePlane: subdivisions must be >= 1, got {}", subdivisions);
  TriangleMesh mesh;
  const int n = subdivisions;
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      AddVertex(&mesh, width * (static_cast<double>(i) / n - 0.5),
                height * (static_cast<double>(j) / n - 0.5), 0.0);
    }
  }
  const auto index = [n](int i, int j) { return j * (n + 1) + i; };
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      // (x, y) → (x, y + 1) → (x + 1, y + 1) → (x + 1, y) turns clockwise about +z.
      AddQuad(&mesh, index(i, j), index(i, j + 1), index(i + 1, j + 1), index(i + 1, j));
    }
  }
  return mesh;
}

double SphereTessellationGap(double radius, int rings, int segments) {
  const double step_theta = kPi / rings, step_phi = 2.0 * kPi / segments;
  return radius * (1.0 - std::cos(0.5 * std::hypot(step_theta, step_phi)));
}

TriangleMesh MakeSphere(double radius, int rings, int segments) {
  SOPE_CHECK(radius > 0.0, "MakeSphere: radius must be positive, got {}", radius);
  SOPE_CHECK(rings >= 2 && segments >= 3,
             "MakeSphere: need rings >= 2 and segments >= 3, got {} and {}", rings, segments);
  TriangleMesh mesh;
  const int north = AddVertex(&mesh, 0.0, 0.0, radius);
  for (int i = 1; i < rings; ++i) {
    const double theta = kPi * i / rings;
    for (int j = 0; j < segments; ++j) {
      const double phi = 2.0 * kPi * j / segments;
      AddVertex(&mesh, radius * std::sin(theta) * std::cos(phi),
                radius * std::sin(theta) * std::sin(phi), radius * std::cos(theta));
    }
  }
  const int south = AddVertex(&mesh, 0.0, 0.0, -radius);
  const auto ring = [segments](int i, int j) { return 1 + (i - 1) * segments + j % segments; };
  for (int j = 0; j < segments; ++j) {
    mesh.faces.emplace_back(north, ring(1, j), ring(1, j + 1));
    for (int i = 1; i + 1 < rings; ++i) {
      AddQuad(&mesh, ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1));
    }
    mesh.faces.emplace_back(ring(rings - 1, j), south, ring(rings - 1, j + 1));
  }
  return mesh;
}

TriangleMesh MakeBox(double size_x, double size_y, double size_z) {
  SOPE_CHECK(size_x > 0.0 && size_y > 0.0 && size_z > 0.0,
             "MakeBox: sizes must be positive, got {}x{}x{}", size_x, size_y, size_z);
  TriangleMesh mesh;
  // Corner c has x = ±size_x/2 by bit 0, y by bit 1, z by bit 2.
  for (int c = 0; c < 8; ++c) {
    AddVertex(&mesh, (c & 1 ? 0.5 : -0.5) * size_x, (c & 2 ? 0.5 : -0.5) * size_y,
              (c & 4 ? 0.5 : -0.5) * size_z);
  }
  AddQuad(&mesh, 0, 4, 6, 2);  // −x
  AddQuad(&mesh, 1, 3, 7, 5);  // +x
  AddQuad(&mesh, 0, 1, 5, 4);  // −y
  AddQuad(&mesh, 2, 6, 7, 3);  // +y
  AddQuad(&mesh, 0, 2, 3, 1);  // −z
  AddQuad(&mesh, 4, 5, 7, 6);  // +z
  return mesh;
}

TriangleMesh MakeCylinder(double radius, double height, int segments, bool capped) {
  SOPE_CHECK(radius > 0.0 && height > 0.0,
             "MakeCylinder: radius and height must be positive, got {} and {}", radius, height);
  SOPE_CHECK(segments >= 3, "MakeCylinder: segments must be >= 3, got {}", segments);
  TriangleMesh mesh;
  for (int j = 0; j < segments; ++j) {
    const double phi = 2.0 * kPi * j / segments;
    AddVertex(&mesh, radius * std::cos(phi), radius * std::sin(phi), -0.5 * height);
    AddVertex(&mesh, radius * std::cos(phi), radius * std::sin(phi), 0.5 * height);
  }
  const auto bottom = [segments](int j) { return 2 * (j % segments); };
  const auto top = [segments](int j) { return 2 * (j % segments) + 1; };
  for (int j = 0; j < segments; ++j) AddQuad(&mesh, bottom(j), bottom(j + 1), top(j + 1), top(j));
  if (capped) {
    const int bottom_center = AddVertex(&mesh, 0.0, 0.0, -0.5 * height);
    const int top_center = AddVertex(&mesh, 0.0, 0.0, 0.5 * height);
    for (int j = 0; j < segments; ++j) {
      mesh.faces.emplace_back(bottom_center, bottom(j + 1), bottom(j));
      mesh.faces.emplace_back(top_center, top(j), top(j + 1));
    }
  }
  return mesh;
}

TriangleMesh MakeTorus(double major_radius, double minor_radius, int major_segments,
                       int minor_segments) {
  SOPE_CHECK(minor_radius > 0.0 && major_radius > minor_radius,
             "MakeTorus: need major_radius > minor_radius > 0, got {} and {}", major_radius,
             minor_radius);
  SOPE_CHECK(major_segments >= 3 && minor_segments >= 3,
             "MakeTorus: segments must be >= 3, got {} and {}", major_segments, minor_segments);
  TriangleMesh mesh;
  for (int i = 0; i < major_segments; ++i) {
    const double phi = 2.0 * kPi * i / major_segments;
    for (int j = 0; j < minor_segments; ++j) {
      const double theta = 2.0 * kPi * j / minor_segments;
      const double distance_to_axis = major_radius + minor_radius * std::cos(theta);
      AddVertex(&mesh, distance_to_axis * std::cos(phi), distance_to_axis * std::sin(phi),
                minor_radius * std::sin(theta));
    }
  }
  const auto index = [&](int i, int j) {
    return (i % major_segments) * minor_segments + j % minor_segments;
  };
  for (int i = 0; i < major_segments; ++i) {
    for (int j = 0; j < minor_segments; ++j) {
      AddQuad(&mesh, index(i, j), index(i + 1, j), index(i + 1, j + 1), index(i, j + 1));
    }
  }
  return mesh;
}

}  // namespace sope
