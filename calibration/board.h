// Checkerboard calibration targets: their geometry (the board frame) and the detection of
// their inner corners in a camera image.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

namespace sope {

// A printed checkerboard of (cols + 1) × (rows + 1) squares. `cols` × `rows` counts the
// INNER corners (where four squares meet), as OpenCV's `patternSize` does: a board of
// 10 × 7 squares is 9x6.
//
// Board frame: origin at inner corner 0, x along a row of corners (index c), y along a
// column (index r), z = x × y into the board (away from a camera that sees its front);
// corner k = r·cols + c lies at (c·square_size, r·square_size, 0). The square diagonally
// outside corner 0 (x, y < 0) is the black one when the colours tell the ends apart (see
// DetectBoardCorners).
struct BoardSpec {
  int cols = 9;                // inner corners per row (patternSize.width)
  int rows = 6;                // inner corners per column (patternSize.height)
  double square_size = 0.025;  // side of a square, metres

  // Throws sope::Error unless cols, rows ≥ 2 and square_size > 0. (A square grid,
  // cols = rows, works but its board frame is defined only up to a quarter turn.)
  void Check() const;
  int NumCorners() const { return cols * rows; }
  // Corner `index` (r·cols + c) in the board frame, metres.
  Eigen::Vector3d CornerInBoard(int index) const;
  std::vector<Eigen::Vector3d> CornersInBoard() const;
  // "COLSxROWSxSQUARE_M", e.g. "9x6x0.025".
  std::string ToString() const;
  // "COLSxROWS", e.g. "9x6".
  std::string PatternSizeString() const;
};

// Parses "COLSxROWSxSQUARE_M" (inner corners, square side in metres), e.g. "9x6x0.025".
// Throws sope::Error naming the text.
BoardSpec BoardSpecFromString(const std::string& text);

enum class CornerDetector {
  // cv::findChessboardCornersSB (Duda & Frese 2018, "Accurate detection and localization
  // of checkerboard corners for calibration"): localized Radon transform, sub-pixel.
  kSectorBased,
  // cv::findChessboardCorners + cv::cornerSubPix (Förstner-style gradient refinement).
  kClassic,
};
std::string ToString(CornerDetector detector);
CornerDetector CornerDetectorFromString(const std::string& text);  // "sb", "classic"

struct BoardDetectionOptions {
  CornerDetector detector = CornerDetector::kSectorBased;
  // kSectorBased: CALIB_CB_ACCURACY (up-sampled refinement), CALIB_CB_EXHAUSTIVE and
  // CALIB_CB_NORMALIZE_IMAGE (histogram equalisation first: it amplifies the noise of a
  // dark background until the board is lost, so off by default; the classic detector
  // always normalises).
  bool accuracy = true;
  bool exhaustive = false;
  bool normalize_image = false;
  // kSectorBased: when the median corner spacing in the image is below this many pixels,
  // the corners are refined with cornerSubPix as well (0 = never). Measured on the virtual
  // rig: with squares of ~20 px SB's corners carry a bias that cost 1.6% of the focal
  // length (0.2% after cornerSubPix); with squares of 35–60 px SB alone is better (corner
  // RMS 0.055 px against 0.09 px with cornerSubPix).
  double subpix_below_spacing_px = 30.0;
  // cornerSubPix half window as a fraction of the smallest corner spacing in the image
  // (so the window never reaches a neighbouring corner), clamped to
  // [2, max_subpix_half_window_px] pixels.
  double subpix_window_fraction = 0.35;
  int max_subpix_half_window_px = 15;

  // DetectBoard: when the whole board is not found, accept the largest visible grid of
  // its corners (cv::findChessboardCornersSB with CALIB_CB_LARGER; whatever `detector`)
  // provided the missing part plausibly lies outside the image (see DetectBoard) and the
  // grid has at least 3 corners along each side and min_partial_corner_fraction of the
  // board's corners.
  bool partial = true;
  double min_partial_corner_fraction = 0.3;
  // A side of the visible grid counts as cut by the image border when a corner of the
  // grid extended by one square on that side lies outside the image or closer to its
  // edge than this many local squares (its squares are cut, so no detector finds it).
  double partial_edge_squares = 0.5;
  // Corners of a partial grid closer to the image edge than this many local squares are
  // left out (the largest sub-grid without them is kept): their squares are cut, and SB
  // places them worse (on synthetic boards 0.2–0.45 px off at 0.25–0.6 squares from the
  // edge, against < 0.1 px inside).
  double partial_corner_edge_squares = 1.0;

  // Throws sope::Error naming an invalid value.
  void Check() const;
};

// Finds all inner corners of `board` in a grey image (CV_8UC1 or CV_16UC1; a white or
// otherwise evenly lit frame). Returns nullopt when the board is not found (an expected
// failure). Corner k of the result is the image of BoardSpec::CornerInBoard(k), pixels,
// OpenCV's centre convention. The order is made canonical: the board frame is right-handed
// with z pointing away from the camera, and when cols + rows is odd (the two end squares
// differ in colour) corner 0 is the one whose outer diagonal square is black; otherwise
// corner 0 is the end nearer the image's top-left.
std::optional<std::vector<Eigen::Vector2d>> DetectBoardCorners(
    const cv::Mat& image, const BoardSpec& board, const BoardDetectionOptions& options = {});

// The corners of a board found in an image, all of them or a part.
struct BoardDetection {
  // Row-major over the visible grid (grid_cols per row): camera pixels.
  std::vector<Eigen::Vector2d> corners;
  // The BoardSpec corner index (r·cols + c) each entry is labelled with.
  std::vector<int> indices;
  int grid_cols = 0;
  int grid_rows = 0;
  // True when only part of the board was visible. Its labelling is then the board's up to
  // a shift by whole squares and a quarter turn in the board plane (which corner of the
  // board is corner 0 of the visible grid cannot be told): a right-handed grid with z away
  // from the camera and the true square size, so every view still gives a valid board
  // pose in a frame of its own.
  bool partial = false;
  // The visible grid as a board of its own (grid_cols × grid_rows, the same squares).
  BoardSpec GridSpec(const BoardSpec& board) const;
};

// DetectBoardCorners, and when the whole board is not found (options.partial) its largest
// visible grid (SB with CALIB_CB_LARGER on the image padded with its mean grey, so that a
// grid may run up to the edge). The grid is accepted when it fits inside the board
// (either way round) and every direction along which corners are missing has a side cut
// by the image border: a corner one square beyond it, extrapolated from the last two, is
// outside the image or within options.partial_edge_squares squares of its edge. A board
// fully in view with fewer corners than `board` is thereby not taken for a part of it.
// Then the largest sub-grid without corners within options.partial_corner_edge_squares
// of the edge is kept; it must have at least 3 × 3 corners and
// options.min_partial_corner_fraction of the board's. Returns nullopt when neither is
// found.
std::optional<BoardDetection> DetectBoard(const cv::Mat& image, const BoardSpec& board,
                                          const BoardDetectionOptions& options = {});

}  // namespace sope
