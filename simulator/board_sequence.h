// Checkerboard calibration sequences on the virtual rig: a printed board on a plane in
// varied poses, each captured with the full structured-light sequence, plus the ground
// truth (the rig's calibration and every cam_from_board). `sope simulate --board`.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "calibration/board.h"
#include "core/frame_set.h"
#include "core/rig_calibration.h"
#include "core/rigid3d.h"
#include "projector/patterns.h"
#include "simulator/virtual_rig.h"

namespace sope {

struct BoardSequenceOptions {
  int num_views = 12;
  // Seed of the pose generator (the sensor noise has its own, SensorOptions::seed).
  uint64_t seed = 1;
  // Board centre depth range, camera frame, metres.
  double min_distance = 0.45;
  double max_distance = 0.8;
  // Tilt of the board away from facing the camera: an angle drawn uniformly in
  // [min_tilt, max_tilt] about an axis in the board plane of uniformly random direction
  // (strong tilts in all directions fix the principal points, Zhang 2000); and the largest
  // roll about the board normal; radians.
  double min_tilt = 15.0 * M_PI / 180.0;
  double max_tilt = 40.0 * M_PI / 180.0;
  double max_roll = 20.0 * M_PI / 180.0;
  // A pose is rejected when, in either device, the angle between the board normal and the
  // ray to the board centre exceeds this (radians), or when any part of the squares (plus
  // half the margin) falls within `min_border_px` of an image edge.
  double max_view_angle = 60.0 * M_PI / 180.0;
  double min_border_px = 8.0;
  // Printed board: albedo of the black and white squares; white margin around the squares,
  // in squares (OpenCV's detectors want about one).
  double black_albedo = 0.05;
  double white_albedo = 0.85;
  double margin_squares = 1.0;
  // Views with the board partly outside the camera image (common on real rigs): this
  // fraction of the views (view i is one when IsPartialBoardView(options, i)), each with a
  // fraction of the board's inner corners in [min_out_of_view, max_out_of_view] outside
  // the camera image; the projector still sees every corner the camera sees. 0 (the
  // default): every board wholly in view.
  double partial_fraction = 0.0;
  double min_out_of_view = 0.1;
  double max_out_of_view = 0.4;
  // Random poses tried per accepted view before giving up.
  int max_attempts_per_view = 2000;
  // The pattern sequence (projector size is taken from the rig). Defaults: white, black,
  // Gray code in x and y with inverses.
  PatternOptions patterns;

  // Throws sope::Error naming an invalid value.
  void Check() const;
};

// Whether view `index` of a sequence has the board partly out of the camera image:
// ⌊(index + 1)·partial_fraction⌋ > ⌊index·partial_fraction⌋ (evenly spread, e.g. every
// third view for 1/3).
bool IsPartialBoardView(const BoardSequenceOptions& options, int index);

// The board as a scene object: a plane in the board frame (BoardSpec: origin at inner
// corner 0, z away from its printed front) with the checker printed as an albedo map;
// the square diagonally outside corner 0 is black. cam_from_model = cam_from_board.
SceneObject MakeCheckerboardObject(const BoardSpec& board, const Rigid3d& cam_from_board,
                                   const BoardSequenceOptions& options = {});

// `options.num_views` random cam_from_board poses (reproducible from options.seed): depth,
// tilts, roll and position over the shared field of camera and projector drawn uniformly,
// each kept only when the whole board is inside both images and not too oblique to either
// device (for the partial views of options.partial_fraction: the stated part of its
// corners outside the camera image, the rest inside both). Throws sope::Error when no acceptable pose is found (board too large for the rig).
std::vector<Rigid3d> SampleBoardPoses(const RigCalibration& calibration, const BoardSpec& board,
                                      const BoardSequenceOptions& options);

// Renders one view: the board at `cam_from_board`, every pattern of `options.patterns`.
// The manifest names no calibration.
FrameSet RenderBoardView(VirtualRig& rig, const BoardSpec& board, const Rigid3d& cam_from_board,
                         const BoardSequenceOptions& options);

// Called after each rendered view with (index, cam_from_board, frames).
using BoardViewSink = std::function<void(int, const Rigid3d&, FrameSet&&)>;

// Samples the poses and renders each view in turn, handing it to `sink` (frames are not
// kept: a view of 42 frames of a 1280×720 camera is ~40 MB). Returns the poses.
std::vector<Rigid3d> SimulateBoardSequence(VirtualRig& rig, const BoardSpec& board,
                                           const BoardSequenceOptions& options,
                                           const BoardViewSink& sink);

// Renders the sequence into `directory`, atomically as a whole (StagedDirectory):
// view_000/ … (frame sets whose frames.json names ../calibration_true.yaml),
// calibration_true.yaml (the rig's true calibration) and gt_board_poses.json (the board
// and every view's cam_from_board: rotation 3×3, translation metres). `progress`, when
// set, is called with (views done, views total).
std::vector<Rigid3d> WriteBoardSequence(const std::string& directory, VirtualRig& rig,
                                        const BoardSpec& board, const BoardSequenceOptions& options,
                                        const std::function<void(int, int)>& progress = {});

// The view directory name of view `index`: "view_000".
std::string BoardViewName(int index);

}  // namespace sope
