// BOP benchmark conventions (Hodaň et al., "BOP: Benchmark for 6D Object Pose Estimation",
// ECCV 2018; the BOP Challenge 2019+ rules and bop_toolkit's pose_error.py / inout.py):
// the results CSV and the MSSD / MSPD pose errors with their recall thresholds. Depends on
// core only.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/rigid3d.h"

namespace sope {

// One row of a BOP results file.
struct BopEstimate {
  int scene_id = 0;
  int im_id = 0;
  int obj_id = 0;
  double score = 0.0;
  // cam_from_model: X_cam = R·X_model + t, metres here (millimetres in the file).
  Rigid3d cam_from_model;
  // Seconds spent on the image (the same for every estimate of one image); < 0 unknown.
  double time_s = -1.0;
};

// The CSV text: header "scene_id,im_id,obj_id,score,R,t,time", then one line per estimate
// with R's nine elements row-major and t's three (millimetres) each separated by a space,
// time in seconds. Throws sope::Error on a non-finite value.
std::string FormatBopCsv(const std::vector<BopEstimate>& estimates);
// FormatBopCsv written atomically to `path`.
void WriteBopCsv(const std::string& path, const std::vector<BopEstimate>& estimates);
// Parses BOP results CSV by bop_toolkit's rules (inout.load_bop_results): the exact header,
// seven comma-separated columns, R nine and t three space-separated numbers. Translations
// come back in metres. Throws sope::Error naming `source`, the line and the problem.
std::vector<BopEstimate> ParseBopCsv(const std::string& text, const std::string& source);

// Maximum Symmetry-aware Surface Distance (BOP 2019): min over the symmetries S (model
// frame, S·X_model maps the model onto itself; the identity must be included, and is used
// when `symmetries` is empty) of max over the model points x of
// ‖est·x − (gt·S)·x‖, metres.
double Mssd(const Rigid3d& est_cam_from_model, const Rigid3d& gt_cam_from_model,
            const std::vector<Eigen::Vector3d>& model_points,
            const std::vector<Rigid3d>& symmetries = {});
// Maximum Symmetry-aware Projection Distance: the same with the points projected by the
// pinhole `camera_matrix` (no distortion, as bop_toolkit's misc.project_pts), pixels.
double Mspd(const Rigid3d& est_cam_from_model, const Rigid3d& gt_cam_from_model,
            const Eigen::Matrix3d& camera_matrix,
            const std::vector<Eigen::Vector3d>& model_points,
            const std::vector<Rigid3d>& symmetries = {});

// BOP's correctness thresholds: MSSD 0.05, 0.10, …, 0.50 × the object diameter (metres);
// MSPD 5, 10, …, 50 px × image_width / 640.
std::vector<double> MssdThresholds(double diameter);
std::vector<double> MspdThresholds(int image_width);
// Fraction of `errors` below `threshold` (strictly, as bop_toolkit), and its mean over the
// thresholds (the average recall BOP reports). 0 for no errors.
double RecallAt(const std::vector<double>& errors, double threshold);
double AverageRecall(const std::vector<double>& errors, const std::vector<double>& thresholds);

}  // namespace sope
