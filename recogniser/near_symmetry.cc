#include "recogniser/near_symmetry.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <random>
#include <unordered_set>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "recogniser/features.h"
#include "recogniser/voxel_key.h"

namespace sope {
namespace {

// Circle through three 2-D points; false when they are (nearly) collinear.
bool Circumcircle(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c,
                  Eigen::Vector2d* centre, double* radius) {
  const double d = 2.0 * (a.x() * (b.y() - c.y()) + b.x() * (c.y() - a.y()) + c.x() * (a.y() - b.y()));
  if (std::abs(d) < 1e-12) return false;
  const double a2 = a.squaredNorm(), b2 = b.squaredNorm(), c2 = c.squaredNorm();
  *centre = Eigen::Vector2d((a2 * (b.y() - c.y()) + b2 * (c.y() - a.y()) + c2 * (a.y() - b.y())) / d,
                            (a2 * (c.x() - b.x()) + b2 * (a.x() - c.x()) + c2 * (b.x() - a.x())) / d);
  *radius = (a - *centre).norm();
  return std::isfinite(*radius);
}

// Occupied cells (`cell` wide) of a point set: "is there a point within about a cell".
class OccupancyGrid {
 public:
  OccupancyGrid(const std::vector<Eigen::Vector3f>& points, double cell) : inv_cell_(1.0 / cell) {
    cells_.reserve(points.size());
    for (const Eigen::Vector3f& p : points) cells_.insert(Key(Cell(p.cast<double>())));
  }
  // A point of the set lies in the cell of `p` or one of the 26 around it.
  bool Near(const Eigen::Vector3d& p) const {
    const Eigen::Vector3i c = Cell(p);
    for (int dx = -1; dx <= 1; ++dx) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dz = -1; dz <= 1; ++dz) {
          if (cells_.count(Key(c + Eigen::Vector3i(dx, dy, dz)))) return true;
        }
      }
    }
    return false;
  }

 private:
  Eigen::Vector3i Cell(const Eigen::Vector3d& p) const {
    return (p * inv_cell_).array().floor().cast<int>();
  }
  static uint64_t Key(const Eigen::Vector3i& c) { return PackVoxelKey(c.x(), c.y(), c.z()); }
  double inv_cell_;
  std::unordered_set<uint64_t> cells_;
};

}  // namespace

NearSymmetryAxis FindNearSymmetryAxis(const std::vector<Eigen::Vector3f>& points, double tolerance,
                                      double min_wall_fraction, double max_asymmetric_fraction) {
  NearSymmetryAxis best;
  if (points.size() < 10 || !(tolerance > 0)) return best;
  Eigen::Vector3d centroid, variances;
  Eigen::Matrix3d axes;
  internal::PrincipalAxes(points, &centroid, &axes, &variances);
  // At most ~3000 points take part (an even subsample); the grid holds them all.
  const size_t stride = std::max<size_t>(1, points.size() / 3000);
  std::vector<Eigen::Vector3d> sample;
  for (size_t i = 0; i < points.size(); i += stride) sample.push_back(points[i].cast<double>());
  const OccupancyGrid grid(points, tolerance);
  std::mt19937 rng(12345);
  std::uniform_int_distribution<size_t> pick(0, sample.size() - 1);
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d direction = axes.col(k).normalized();
    const Eigen::Vector3d u = direction.unitOrthogonal(), v = direction.cross(u);
    std::vector<Eigen::Vector2d> flat(sample.size());
    for (size_t i = 0; i < sample.size(); ++i) {
      const Eigen::Vector3d d = sample[i] - centroid;
      flat[i] = Eigen::Vector2d(d.dot(u), d.dot(v));
    }
    // RANSAC circle: the most points within the tolerance of it.
    Eigen::Vector2d circle_centre = Eigen::Vector2d::Zero();
    size_t circle_inliers = 0;
    for (int iteration = 0; iteration < 300; ++iteration) {
      Eigen::Vector2d centre;
      double radius = 0.0;
      if (!Circumcircle(flat[pick(rng)], flat[pick(rng)], flat[pick(rng)], &centre, &radius) ||
          radius < 2.0 * tolerance) {
        continue;
      }
      size_t inliers = 0;
      for (const Eigen::Vector2d& q : flat) inliers += std::abs((q - centre).norm() - radius) <= tolerance;
      if (inliers > circle_inliers) circle_inliers = inliers, circle_centre = centre;
    }
    const double wall_fraction = static_cast<double>(circle_inliers) / sample.size();
    if (wall_fraction < min_wall_fraction) continue;
    const Eigen::Vector3d on_axis = centroid + circle_centre.x() * u + circle_centre.y() * v;
    double moved = 0.0;
    for (const double degrees : {60.0, 120.0, 180.0}) {
      const Eigen::Matrix3d turn = Eigen::AngleAxisd(degrees * M_PI / 180.0, direction).toRotationMatrix();
      size_t off = 0;
      for (const Eigen::Vector3d& p : sample) off += !grid.Near(turn * (p - on_axis) + on_axis);
      moved += static_cast<double>(off) / sample.size() / 3.0;
    }
    if (moved < best.asymmetric_fraction) {
      best.point = on_axis;
      best.direction = direction;
      best.asymmetric_fraction = moved;
      best.wall_fraction = wall_fraction;
    }
  }
  best.found = best.asymmetric_fraction <= max_asymmetric_fraction;
  return best;
}

std::optional<Eigen::Vector3d> StandingAxisPoint(const std::vector<Eigen::Vector3f>& points,
                                                 const std::vector<Eigen::Vector3f>& normals,
                                                 const Eigen::Matrix3d& cam_from_points,
                                                 const Eigen::Vector3d& up, double offset) {
  const Eigen::Vector3d u = up.unitOrthogonal(), v = up.cross(u);
  struct Line {
    Eigen::Vector2d point, direction;
    double weight;
  };
  std::vector<Line> lines;
  lines.reserve(points.size());
  for (size_t i = 0; i < points.size() && i < normals.size(); ++i) {
    const Eigen::Vector3d p = cam_from_points * points[i].cast<double>();
    const Eigen::Vector3d m = cam_from_points * normals[i].cast<double>();
    const Eigen::Vector2d d(u.dot(m), v.dot(m));
    const double weight = d.squaredNorm();
    if (!(weight >= 0.04) || !p.allFinite()) continue;
    lines.push_back({Eigen::Vector2d(u.dot(p), v.dot(p)), d / std::sqrt(weight), weight});
  }
  constexpr int kMinLines = 20;
  std::optional<Eigen::Vector2d> centre;
  std::vector<double> distances(lines.size());
  double keep = std::numeric_limits<double>::infinity();
  for (int round = 0; round < 3; ++round) {
    Eigen::Matrix2d a = Eigen::Matrix2d::Zero();
    Eigen::Vector2d b = Eigen::Vector2d::Zero();
    int used = 0;
    for (size_t i = 0; i < lines.size(); ++i) {
      if (centre && distances[i] > keep) continue;
      const Eigen::Matrix2d across =
          Eigen::Matrix2d::Identity() - lines[i].direction * lines[i].direction.transpose();
      a += lines[i].weight * across;
      b += lines[i].weight * across * lines[i].point;
      ++used;
    }
    // Both eigenvalues of `a` well away from 0: the lines cross, not all parallel.
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> solver(a);
    if (used < kMinLines || !(solver.eigenvalues()[0] > 0.05 * a.trace())) return std::nullopt;
    centre = a.ldlt().solve(b);
    for (size_t i = 0; i < lines.size(); ++i) {
      const Eigen::Vector2d off = *centre - lines[i].point;
      distances[i] = (off - lines[i].direction * lines[i].direction.dot(off)).norm();
    }
    std::vector<double> sorted = distances;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    keep = std::max(3.0 * sorted[sorted.size() / 2], 0.005);
  }
  return centre->x() * u + centre->y() * v - offset * up;
}

}  // namespace sope
