// A model's axis of near rotational symmetry (issue 12): the body of a mug, a jug or a
// saucepan is a surface of revolution and the handle stands off it. A view-based pose
// search fits the body and leaves the handle's turn about the body's axis to chance: on a
// table the handle then lands where the scan saw free space, or the body fits equally at
// any turn when the handle is out of sight. Knowing the axis, the scene recogniser tries
// the model turned about it (SceneRecognitionOptions::roll_steps).
//
// Method: for each principal axis direction of the surface, the points projected onto the
// plane across it; a RANSAC circle among them (a body of revolution about that direction
// puts its walls on one circle); the circle's centre fixes the axis. The candidate axis
// whose turns (60°, 120°, 180°) move the fewest points off the surface is the axis; its
// `asymmetric_fraction` is that share of points (0: fully symmetric — a glass, a can —
// turning changes nothing; a mug ~0.05–0.2). No PCL in this header.
#pragma once

#include <optional>
#include <vector>

#include <Eigen/Core>

namespace sope {

struct NearSymmetryAxis {
  bool found = false;
  Eigen::Vector3d point = Eigen::Vector3d::Zero();      // on the axis (model frame)
  Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();  // unit
  // Share of the surface points farther than the tolerance from the surface after a turn
  // about the axis (mean over 60°, 120° and 180°).
  double asymmetric_fraction = 1.0;
  // Share of the points within the tolerance of the fitted circle (walls of revolution).
  double wall_fraction = 0.0;
};

// `points`: a surface sample (model frame, metres, e.g. voxel-thinned at `tolerance` / 1.5).
// found when some principal direction has a circle holding at least min_wall_fraction of
// the points and turning about it moves at most max_asymmetric_fraction of them off the
// surface. Deterministic (fixed RANSAC seed).
NearSymmetryAxis FindNearSymmetryAxis(const std::vector<Eigen::Vector3f>& points, double tolerance,
                                      double min_wall_fraction = 0.2,
                                      double max_asymmetric_fraction = 0.35);

// The standing axis of a surface seen on a table: the line along the table's normal `up`
// (unit, camera frame; the table is up·x + offset = 0) nearest, in least squares, to the
// lines through each point along its normal projected onto the table — each weighted by the
// square of its normal's horizontal share, those under 0.2 left out —, solved three times,
// the second and third on the lines within max(3 × the median distance, 5 mm) of the
// previous solution. For a standing body of revolution, its axis (every normal meets it);
// for a standing box, the crossing of its visible sides' centre lines. `points` and
// `normals` in a frame `cam_from_points` turns into the camera's. Returns the axis's point
// on the table plane (camera frame); empty when the normals do not pin a point (all
// parallel, or fewer than 20 lines).
std::optional<Eigen::Vector3d> StandingAxisPoint(const std::vector<Eigen::Vector3f>& points,
                                                 const std::vector<Eigen::Vector3f>& normals,
                                                 const Eigen::Matrix3d& cam_from_points,
                                                 const Eigen::Vector3d& up, double offset);

}  // namespace sope
