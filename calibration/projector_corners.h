// Board corners seen by the projector: sub-pixel projector coordinates of camera corners
// from decoded structured-light correspondences, by local homographies.
#pragma once

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "calibration/board.h"
#include "core/frame_set.h"
#include "decoder/decoder.h"

namespace sope {

struct LocalHomographyOptions {
  // Half-size of the square window of decoded camera pixels around a corner, as a fraction
  // of the board square's side in camera pixels near that corner (the window then spans
  // parts of the four squares meeting there, all on the board plane).
  double window_fraction = 0.5;
  // Bounds of that half-size, camera pixels.
  int min_half_window_px = 4;
  int max_half_window_px = 60;
  // A corner is kept for the projector only when at least this fraction of its window's
  // pixels decoded on both axes.
  double min_decoded_fraction = 0.4;
  // RANSAC inlier threshold, projector pixels. Decoded coordinates are quantised to the
  // code step (1 px with all bits), so a correct pixel is within ~step/2 of the fit.
  double ransac_threshold_px = 1.5;
  // ... and at least this fraction of the decoded pixels must be inliers of the fit.
  double min_inlier_fraction = 0.6;
  // Pixels within this distance (camera pixels) of the printed edges through the corner
  // are left out of the fit: their footprint mixes a dark and a bright square, so their
  // decoded coordinate leans to the bright part. Off by default: on the virtual rig
  // (camera blur 0.3 px) 1.5 px changed no figure measurably; blurrier optics may differ.
  double edge_band_px = 0.0;

  // Throws sope::Error naming an invalid value.
  void Check() const;
};

// Sub-pixel projector coordinates from a Gray-code frame set and its decoded map. A pixel
// decoded to block k (the integer coordinate when no low bits are omitted) sees a projector
// point between the two stripe edges that bound k; in a Gray code each edge is where one
// single bit flips, and that bit's pattern − inverse difference, signed to be positive
// inside k, grows with the distance from its edge. With m₋ and m₊ the margins of the lower
// and upper edge's bits, the coordinate becomes
//   q + (step/2)·(m₋ − m₊)/(m₋ + m₊),
// exact for margins proportional to the distance and otherwise monotone and symmetric.
// This removes most of the quantisation error that no local fit can average away where the
// camera and projector pixel grids are nearly commensurate (their Moiré beat then spans
// the whole window and biases the fit by up to half a projector pixel). Axes coded in
// binary, pixels the decoder already put on a boundary (k + ½) and pixels whose bracketing
// edge is missing (the ends of the code range) keep their decoded value. Without inverse
// frames the threshold (white + black)/2 is used. Throws sope::Error when `map` does not
// belong to `frames` (size).
CorrespondenceMap RefineGrayCodeSubpixel(const FrameSet& frames, const CorrespondenceMap& map);

// The projector coordinates of `camera_point` (pixels, OpenCV centre convention) by a
// local homography (Moreno & Taubin 2012, "Simple, accurate, and robust projector-camera
// calibration", §3.2): over the decoded pixels of the (2·half_window_px + 1)² window
// centred on the point, fit a homography camera → projector robustly (RANSAC with
// `options.ransac_threshold_px`, then Levenberg–Marquardt on the inliers) and map the
// sub-pixel point through it. The fit averages the integer quantisation and the noise of
// the decoded values over the window, so they do not move the point; it is exact for a
// plane seen through undistorted lenses and a close approximation for mild distortion
// over a small window. Needs both axes decoded. Returns nullopt when too few pixels
// decoded or fit (an expected failure: shadow, the board's edge, a dark square).
// `edge_directions`: directions (camera pixels, any length) of the printed edges through
// the point, whose band of options.edge_band_px is left out; empty to use every pixel.
std::optional<Eigen::Vector2d> ProjectorPointFromLocalHomography(
    const CorrespondenceMap& map, const Eigen::Vector2d& camera_point, int half_window_px,
    const LocalHomographyOptions& options = {},
    const std::vector<Eigen::Vector2d>& edge_directions = {});

// The projector coordinates of every detected corner of one board view, in the corners'
// order; nullopt for corners the projector did not see well enough. The window of each
// corner scales with the mean distance to its grid neighbours (the local square size in
// camera pixels); the printed edges through it run towards those neighbours. Throws sope::Error
// when the map lacks an axis or `camera_corners` does not have board.NumCorners() entries.
std::vector<std::optional<Eigen::Vector2d>> FindProjectorCorners(
    const CorrespondenceMap& map, const BoardSpec& board,
    const std::vector<Eigen::Vector2d>& camera_corners, const LocalHomographyOptions& options = {});

}  // namespace sope
