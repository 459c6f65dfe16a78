#include "core/convex_hull.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include <Eigen/Geometry>

extern "C" {
#include <libqhull_r/qhull_ra.h>
}

#include "core/error.h"

namespace sope {
namespace {

// A stable face's projected centre of mass lies at least this far inside its polygon
// (metres): rounding-level balance points are not rests.
constexpr double kMinStabilityMargin = 1e-4;

// Solid angle of triangle (a, b, c) seen from the origin (Van Oosterom & Strackee 1983).
double TriangleSolidAngle(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                          const Eigen::Vector3d& c) {
  const double la = a.norm(), lb = b.norm(), lc = c.norm();
  const double numerator = std::abs(a.dot(b.cross(c)));
  const double denominator = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
  return 2.0 * std::atan2(numerator, denominator);
}

// An orthonormal basis (u, v) of the plane perpendicular to unit `normal`, u × v = normal.
void PlaneBasis(const Eigen::Vector3d& normal, Eigen::Vector3d* u, Eigen::Vector3d* v) {
  const Eigen::Vector3d helper =
      std::abs(normal.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  *u = normal.cross(helper).normalized();
  *v = normal.cross(*u);
}

// Signed distance of `p` inside the convex counter-clockwise polygon (> 0 inside).
double InsideDistance(const std::vector<Eigen::Vector2d>& polygon, const Eigen::Vector2d& p) {
  double inside = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < polygon.size(); ++i) {
    const Eigen::Vector2d& a = polygon[i];
    const Eigen::Vector2d& b = polygon[(i + 1) % polygon.size()];
    const Eigen::Vector2d edge = b - a;
    const double length = edge.norm();
    if (length <= 0) continue;
    // Left of a counter-clockwise edge is inside.
    inside = std::min(inside, (edge.x() * (p.y() - a.y()) - edge.y() * (p.x() - a.x())) / length);
  }
  return inside;
}

}  // namespace

double ConvexHull::Distance(const Eigen::Vector3d& point) const {
  double distance = -std::numeric_limits<double>::infinity();
  for (const HullFacet& facet : facets) {
    distance = std::max(distance, facet.normal.dot(point) + facet.offset);
  }
  return distance;
}

ConvexHull ComputeConvexHull(const std::vector<Eigen::Vector3d>& points) {
  SOPE_CHECK(points.size() >= 4, "convex hull needs at least 4 points, got {}", points.size());
  std::vector<coordT> coordinates;
  coordinates.reserve(3 * points.size());
  for (const Eigen::Vector3d& p : points) {
    SOPE_CHECK(p.allFinite(), "convex hull: a point is not finite");
    coordinates.insert(coordinates.end(), {p.x(), p.y(), p.z()});
  }
  // qhull reports trouble on a FILE: keep it off the terminal (the error below says it).
  FILE* errors = std::fopen("/dev/null", "w");
  qhT qh_storage;
  qhT* qh = &qh_storage;
  qh_zero(qh, errors);
  // Default precision handling merges coplanar facets (a lathed floor is one face).
  char flags[] = "qhull";
  const int code = qh_new_qhull(qh, 3, static_cast<int>(points.size()), coordinates.data(),
                                False, flags, nullptr, errors);
  ConvexHull hull;
  if (code == 0) {
    std::vector<int> index_of(points.size(), -1);
    vertexT* vertex;
    FORALLvertices {
      const int id = qh_pointid(qh, vertex->point);
      index_of[id] = static_cast<int>(hull.vertices.size());
      hull.vertices.push_back(points[id]);
    }
    facetT* facet;
    FORALLfacets {
      HullFacet out;
      out.normal = Eigen::Vector3d(facet->normal[0], facet->normal[1], facet->normal[2]);
      out.offset = facet->offset;
      vertexT** vertexp;
      FOREACHvertex_(facet->vertices) {
        out.polygon.push_back(points[qh_pointid(qh, vertex->point)]);
      }
      // Order the vertices counter-clockwise about the outward normal.
      Eigen::Vector3d u, v;
      PlaneBasis(out.normal, &u, &v);
      std::vector<Eigen::Vector2d> flat;
      for (const Eigen::Vector3d& p : out.polygon) flat.emplace_back(p.dot(u), p.dot(v));
      const std::vector<Eigen::Vector2d> ring = ConvexHull2d(flat);
      std::vector<Eigen::Vector3d> ordered;
      for (const Eigen::Vector2d& q : ring) {
        // Back to 3-D on the facet plane.
        ordered.push_back(q.x() * u + q.y() * v - out.offset * out.normal);
      }
      out.polygon = ordered;
      if (out.polygon.size() >= 3) hull.facets.push_back(std::move(out));
    }
  }
  qh_freeqhull(qh, !qh_ALL);
  int curlong = 0, totlong = 0;
  qh_memfreeshort(qh, &curlong, &totlong);
  if (errors != nullptr) std::fclose(errors);
  SOPE_CHECK(code == 0 && hull.facets.size() >= 4,
             "convex hull failed (qhull code {}): the mesh is flat or degenerate", code);
  // Centroid of the solid: tetrahedra from an interior point to each facet's fan.
  Eigen::Vector3d interior = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : hull.vertices) interior += p;
  interior /= static_cast<double>(hull.vertices.size());
  double volume = 0.0;
  Eigen::Vector3d moment = Eigen::Vector3d::Zero();
  for (const HullFacet& facet : hull.facets) {
    for (size_t i = 1; i + 1 < facet.polygon.size(); ++i) {
      const Eigen::Vector3d& a = facet.polygon[0];
      const Eigen::Vector3d& b = facet.polygon[i];
      const Eigen::Vector3d& c = facet.polygon[i + 1];
      const double tet = std::abs((a - interior).dot((b - interior).cross(c - interior))) / 6.0;
      volume += tet;
      moment += tet * (interior + a + b + c) / 4.0;
    }
  }
  hull.volume = volume;
  hull.centroid = volume > 0 ? Eigen::Vector3d(moment / volume) : interior;
  return hull;
}

Eigen::Vector3d CenterOfMass(const TriangleMesh& mesh, const ConvexHull& hull) {
  double volume = 0.0;
  Eigen::Vector3d moment = Eigen::Vector3d::Zero();
  const Eigen::Vector3d origin = hull.centroid;
  for (const Eigen::Vector3i& face : mesh.faces) {
    const Eigen::Vector3d a = mesh.vertices[face[0]].cast<double>() - origin;
    const Eigen::Vector3d b = mesh.vertices[face[1]].cast<double>() - origin;
    const Eigen::Vector3d c = mesh.vertices[face[2]].cast<double>() - origin;
    const double tet = a.dot(b.cross(c)) / 6.0;
    volume += tet;
    moment += tet * (a + b + c) / 4.0;
  }
  // A closed positive solid has at most the hull's volume; open or inverted meshes do not
  // give a meaningful centroid.
  if (!(volume > 0.02 * hull.volume && volume < 1.01 * hull.volume)) return hull.centroid;
  const Eigen::Vector3d center = origin + moment / volume;
  return hull.Distance(center) < 0 ? center : hull.centroid;
}

std::vector<RestingFace> StableFaces(const ConvexHull& hull, const Eigen::Vector3d& center) {
  std::vector<RestingFace> faces;
  for (size_t f = 0; f < hull.facets.size(); ++f) {
    const HullFacet& facet = hull.facets[f];
    Eigen::Vector3d u, v;
    PlaneBasis(facet.normal, &u, &v);
    std::vector<Eigen::Vector2d> polygon;
    for (const Eigen::Vector3d& p : facet.polygon) polygon.emplace_back(p.dot(u), p.dot(v));
    const double margin = InsideDistance(polygon, Eigen::Vector2d(center.dot(u), center.dot(v)));
    if (margin < kMinStabilityMargin) continue;
    double solid_angle = 0.0;
    for (size_t i = 1; i + 1 < facet.polygon.size(); ++i) {
      solid_angle += TriangleSolidAngle(facet.polygon[0] - center, facet.polygon[i] - center,
                                        facet.polygon[i + 1] - center);
    }
    faces.push_back({static_cast<int>(f), solid_angle / (4 * M_PI), margin});
  }
  std::sort(faces.begin(), faces.end(), [](const RestingFace& a, const RestingFace& b) {
    return a.probability > b.probability;
  });
  return faces;
}

std::vector<Eigen::Vector2d> ConvexHull2d(std::vector<Eigen::Vector2d> points) {
  // Andrew's monotone chain; counter-clockwise, collinear points dropped.
  std::sort(points.begin(), points.end(), [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  points.erase(std::unique(points.begin(), points.end()), points.end());
  if (points.size() < 3) return points;
  auto cross = [](const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
  };
  std::vector<Eigen::Vector2d> hull(2 * points.size());
  size_t k = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    while (k >= 2 && cross(hull[k - 2], hull[k - 1], points[i]) <= 0) --k;
    hull[k++] = points[i];
  }
  for (size_t i = points.size() - 1, lower = k + 1; i > 0; --i) {
    while (k >= lower && cross(hull[k - 2], hull[k - 1], points[i - 1]) <= 0) --k;
    hull[k++] = points[i - 1];
  }
  hull.resize(k - 1);
  return hull;
}

}  // namespace sope
