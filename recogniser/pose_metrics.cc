#include "recogniser/pose_metrics.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_types.h>

#include "core/error.h"
#include "core/units.h"

namespace sope {
namespace {


pcl::PointCloud<pcl::PointXYZ>::Ptr ToPcl(const std::vector<Eigen::Vector3f>& points) {
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  cloud->resize(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    (*cloud)[i].x = points[i].x();
    (*cloud)[i].y = points[i].y();
    (*cloud)[i].z = points[i].z();
  }
  return cloud;
}

// Distance from `p` to its nearest neighbour in `tree` (0 when the tree finds none);
// `index` and `squared` are the search's scratch (one entry each).
double NearestDistance(const pcl::KdTreeFLANN<pcl::PointXYZ>& tree, const Eigen::Vector3f& p,
                       std::vector<int>* index, std::vector<float>* squared) {
  pcl::PointXYZ point;
  point.x = p.x();
  point.y = p.y();
  point.z = p.z();
  return tree.nearestKSearch(point, 1, *index, *squared) > 0 ? std::sqrt((*squared)[0]) : 0.0;
}

// Mean distance from each of `query` to its nearest neighbour in `tree`.
double MeanClosestDistance(const pcl::KdTreeFLANN<pcl::PointXYZ>& tree,
                           const std::vector<Eigen::Vector3f>& query) {
  if (query.empty()) return 0.0;
  std::vector<int> index(1);
  std::vector<float> squared(1);
  double sum = 0.0;
  for (const Eigen::Vector3f& p : query) sum += NearestDistance(tree, p, &index, &squared);
  return sum / static_cast<double>(query.size());
}

// Whether the mean distance from each of `query`, turned by (rotation, translation), to its
// nearest neighbour in `tree` is below `limit`: the same answer as comparing
// MeanClosestDistance of the transformed points, but it stops as soon as the partial sum
// settles it (the terms are non-negative, so the sum only grows) — a turn that is not a
// symmetry is usually decided after a few dozen of the points.
bool MeanClosestDistanceBelow(const pcl::KdTreeFLANN<pcl::PointXYZ>& tree,
                              const std::vector<Eigen::Vector3f>& query,
                              const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                              double limit) {
  if (query.empty()) return 0.0 < limit;
  const double count = static_cast<double>(query.size());
  std::vector<int> index(1);
  std::vector<float> squared(1);
  double sum = 0.0;
  for (const Eigen::Vector3f& p : query) {
    const Eigen::Vector3f q = (rotation * p.cast<double>() + translation).cast<float>();
    sum += NearestDistance(tree, q, &index, &squared);
    if (!(sum / count < limit)) return false;
  }
  return sum / count < limit;
}

std::vector<Eigen::Vector3f> Transformed(const std::vector<Eigen::Vector3f>& points,
                                         const Eigen::Matrix3d& rotation,
                                         const Eigen::Vector3d& translation) {
  std::vector<Eigen::Vector3f> out(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    out[i] = (rotation * points[i].cast<double>() + translation).cast<float>();
  }
  return out;
}

bool SameRotation(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return RotationErrorDeg(a, b) < 1e-3;
}

}  // namespace

std::vector<Eigen::Vector3f> SampleSurface(const TriangleMesh& mesh, int count, uint64_t seed) {
  mesh.Check();
  SOPE_CHECK(count > 0, "SampleSurface: count must be positive, got {}", count);
  std::vector<double> cumulative(mesh.faces.size());
  double total = 0.0;
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    const Eigen::Vector3i& face = mesh.faces[f];
    const Eigen::Vector3d a = mesh.vertices[face[0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[face[1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[face[2]].cast<double>();
    total += 0.5 * (b - a).cross(c - a).norm();
    cumulative[f] = total;
  }
  SOPE_CHECK(total > 0, "SampleSurface: mesh has zero area");
  std::mt19937_64 engine(seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::vector<Eigen::Vector3f> points;
  points.reserve(count);
  for (int i = 0; i < count; ++i) {
    const double pick = uniform(engine) * total;
    const size_t f = std::min<size_t>(
        std::lower_bound(cumulative.begin(), cumulative.end(), pick) - cumulative.begin(),
        mesh.faces.size() - 1);
    const Eigen::Vector3i& face = mesh.faces[f];
    // Uniform point in the triangle: √r1 trick.
    const double r1 = std::sqrt(uniform(engine)), r2 = uniform(engine);
    const Eigen::Vector3d a = mesh.vertices[face[0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[face[1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[face[2]].cast<double>();
    points.push_back(((1 - r1) * a + r1 * (1 - r2) * b + r1 * r2 * c).cast<float>());
  }
  return points;
}

double RotationErrorDeg(const Eigen::Matrix3d& rotation_a, const Eigen::Matrix3d& rotation_b) {
  return RotationAngleBetween(rotation_a, rotation_b) * kRadToDeg;
}

double AverageDistance(const std::vector<Eigen::Vector3f>& model_points,
                       const Rigid3d& cam_from_model_a, const Rigid3d& cam_from_model_b) {
  SOPE_CHECK(!model_points.empty(), "ADD: no model points");
  double sum = 0.0;
  for (const Eigen::Vector3f& p : model_points) {
    const Eigen::Vector3d point = p.cast<double>();
    sum += (cam_from_model_a * point - cam_from_model_b * point).norm();
  }
  return sum / static_cast<double>(model_points.size());
}

double AverageDistanceSymmetric(const std::vector<Eigen::Vector3f>& model_points,
                                const Rigid3d& cam_from_model_a,
                                const Rigid3d& cam_from_model_b) {
  SOPE_CHECK(!model_points.empty(), "ADD-S: no model points");
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setInputCloud(ToPcl(Transformed(model_points, cam_from_model_b.rotation,
                                       cam_from_model_b.translation)));
  return MeanClosestDistance(
      tree, Transformed(model_points, cam_from_model_a.rotation, cam_from_model_a.translation));
}

ModelSymmetry DetectSymmetry(const TriangleMesh& mesh, double tolerance_fraction) {
  const double diameter = mesh.BoundingDiagonal();
  SOPE_CHECK(diameter > 0 && tolerance_fraction > 0, "DetectSymmetry: invalid diameter {} or "
             "tolerance {}", diameter, tolerance_fraction);
  constexpr int kDenseSamples = 30000, kQuerySamples = 3000;
  const std::vector<Eigen::Vector3f> model_points = SampleSurface(mesh, kDenseSamples, 11);
  const std::vector<Eigen::Vector3f> query_points = SampleSurface(mesh, kQuerySamples, 12);
  // Exact surface moments of the triangles (not of the samples, whose noise would tilt the
  // axes): ∫x dA = A·s/3 and ∫x·xᵀ dA = A/12·(aaᵀ + bbᵀ + ccᵀ + ssᵀ), s = a + b + c.
  double area = 0.0;
  Eigen::Vector3d first = Eigen::Vector3d::Zero();
  Eigen::Matrix3d second = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3i& face : mesh.faces) {
    const Eigen::Vector3d a = mesh.vertices[face[0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[face[1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[face[2]].cast<double>();
    const Eigen::Vector3d sum = a + b + c;
    const double face_area = 0.5 * (b - a).cross(c - a).norm();
    area += face_area;
    first += face_area / 3.0 * sum;
    second += face_area / 12.0 *
              (a * a.transpose() + b * b.transpose() + c * c.transpose() + sum * sum.transpose());
  }
  const Eigen::Vector3d centroid = first / area;
  const Eigen::Matrix3d covariance = second / area - centroid * centroid.transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
  const Eigen::Matrix3d axes = solver.eigenvectors();

  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setInputCloud(ToPcl(model_points));
  // Independent samples lie this far from the dense sample even without a turn.
  const double floor = MeanClosestDistance(tree, query_points);
  const double tolerance = floor + tolerance_fraction * diameter;
  // Is the turn `rotation` about the centroid a symmetry of the surface?
  auto is_symmetry = [&](const Eigen::Matrix3d& rotation) {
    const Eigen::Vector3d translation = centroid - rotation * centroid;
    return MeanClosestDistanceBelow(tree, query_points, rotation, translation, tolerance);
  };
  auto turn = [](const Eigen::Vector3d& axis, double degrees) {
    return Eigen::AngleAxisd(degrees / kRadToDeg, axis).toRotationMatrix();
  };

  ModelSymmetry symmetry;
  std::vector<Eigen::Matrix3d> generators;
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d axis = axes.col(k);
    bool continuous = !symmetry.continuous;
    for (int degrees = 10; continuous && degrees < 360; degrees += 10) {
      continuous = is_symmetry(turn(axis, degrees));
    }
    if (continuous) {
      symmetry.continuous = true;
      symmetry.axis = axis;
      continue;
    }
    for (int fold : {2, 3, 4, 6}) {
      const Eigen::Matrix3d rotation = turn(axis, 360.0 / fold);
      if (is_symmetry(rotation)) generators.push_back(rotation);
    }
  }
  if (symmetry.continuous) {
    // Half-turns about axes perpendicular to the symmetry axis (e.g. a can upside down).
    const Eigen::Vector3d perpendicular = symmetry.axis.unitOrthogonal();
    const Eigen::Matrix3d flip = turn(perpendicular, 180.0);
    // The discrete part of a body of revolution is at most that flip; turns about the
    // other principal axes (degenerate there) are not separate symmetries.
    generators.clear();
    if (is_symmetry(flip)) generators.push_back(flip);
  }
  // Close the group under products (small: at most the 24 rotations of a cube).
  symmetry.rotations = {Eigen::Matrix3d::Identity()};
  constexpr size_t kMaxGroupSize = 48;
  for (bool grew = true; grew && symmetry.rotations.size() < kMaxGroupSize;) {
    grew = false;
    const std::vector<Eigen::Matrix3d> current = symmetry.rotations;
    for (const Eigen::Matrix3d& a : current) {
      for (const Eigen::Matrix3d& g : generators) {
        const Eigen::Matrix3d product = a * g;
        const bool known = std::any_of(symmetry.rotations.begin(), symmetry.rotations.end(),
                                       [&](const Eigen::Matrix3d& r) { return SameRotation(r, product); });
        if (!known && symmetry.rotations.size() < kMaxGroupSize) {
          symmetry.rotations.push_back(product);
          grew = true;
        }
      }
    }
  }
  return symmetry;
}

double SymmetricRotationErrorDeg(const Eigen::Matrix3d& rotation_estimate,
                                 const Eigen::Matrix3d& rotation_truth,
                                 const ModelSymmetry& symmetry) {
  double best = 180.0;
  for (const Eigen::Matrix3d& s : symmetry.rotations) {
    const Eigen::Matrix3d truth = rotation_truth * s;
    double error;
    if (symmetry.continuous) {
      // Any twist about the axis is free: compare where the axis ends up.
      const double cosine =
          std::clamp((rotation_estimate * symmetry.axis).dot(truth * symmetry.axis), -1.0, 1.0);
      error = std::acos(cosine) * kRadToDeg;
    } else {
      error = RotationErrorDeg(rotation_estimate, truth);
    }
    best = std::min(best, error);
  }
  return best;
}

void PoseTruthModelOptions::Check() const {
  SOPE_CHECK(samples >= 1, "pose comparison: the number of surface samples must be ≥ 1, got {}",
             samples);
}

PoseTruthModel MakePoseTruthModel(const TriangleMesh& mesh,
                                  const PoseTruthModelOptions& options) {
  options.Check();
  PoseTruthModel model;
  model.samples = SampleSurface(mesh, options.samples, options.seed);
  Eigen::Vector3f lo, hi;
  mesh.Bounds(&lo, &hi);
  model.center = (0.5 * (lo + hi)).cast<double>();
  model.diameter = mesh.BoundingDiagonal();
  model.symmetry = DetectSymmetry(mesh);
  return model;
}

PoseComparison ComparePoses(const Rigid3d& estimate, const Rigid3d& truth,
                            const PoseTruthModel& model) {
  PoseComparison out;
  out.rotation_error_deg =
      SymmetricRotationErrorDeg(estimate.rotation, truth.rotation, model.symmetry);
  out.center_error_m = (estimate * model.center - truth * model.center).norm();
  out.adds_m = AverageDistanceSymmetric(model.samples, estimate, truth);
  out.diameter_m = model.diameter;
  return out;
}

PoseComparison ComparePoses(const Rigid3d& estimate, const Rigid3d& truth,
                            const TriangleMesh& mesh) {
  return ComparePoses(estimate, truth, MakePoseTruthModel(mesh));
}

}  // namespace sope
