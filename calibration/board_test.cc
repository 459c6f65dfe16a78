// Board geometry, its text form, and corner detection on synthetic images whose corners
// are known exactly (a finely rendered checkerboard warped by a known homography).
#include "calibration/board.h"

#include <cmath>
#include <cstdio>

#include <Eigen/Dense>
#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace {

TEST(BoardSpec, ParsesInnerCornersAndSquareSize) {
  const BoardSpec board = BoardSpecFromString("9x6x0.025");
  EXPECT_EQ(board.cols, 9);
  EXPECT_EQ(board.rows, 6);
  EXPECT_DOUBLE_EQ(board.square_size, 0.025);
  EXPECT_EQ(board.NumCorners(), 54);
  EXPECT_EQ(board.ToString(), "9x6x0.025");
  EXPECT_EQ(board.PatternSizeString(), "9x6");
  EXPECT_EQ(BoardSpecFromString("11X8X0.02").cols, 11);
  // Corner k = r·cols + c at (c·s, r·s, 0).
  EXPECT_TRUE(board.CornerInBoard(0).isZero());
  EXPECT_TRUE(board.CornerInBoard(10).isApprox(Eigen::Vector3d(0.025, 0.025, 0.0)));
  EXPECT_TRUE(board.CornerInBoard(53).isApprox(Eigen::Vector3d(0.2, 0.125, 0.0)));
  EXPECT_EQ(board.CornersInBoard().size(), 54u);
}

TEST(BoardSpec, RejectsMalformedText) {
  for (const char* text : {"", "9x6", "9x6x", "axbx0.1", "9x6x0.02m", "9x6x-0.02", "1x6x0.02",
                           "9x6x0", "9x6x0.02x1"}) {
    EXPECT_THROW_WITH_MESSAGE(BoardSpecFromString(text), Error,
                              std::string("board '") + text + "'");
  }
  try {
    BoardSpecFromString("9x6");
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("COLSxROWSxSQUARE_M"), std::string::npos);
  }
}

TEST(CornerDetector, NamesRoundTrip) {
  for (CornerDetector detector : {CornerDetector::kSectorBased, CornerDetector::kClassic}) {
    EXPECT_EQ(CornerDetectorFromString(ToString(detector)), detector);
  }
  EXPECT_THROW_WITH_MESSAGE(CornerDetectorFromString("harris"), Error, "'harris'");
  BoardDetectionOptions options;
  options.subpix_window_fraction = 0.7;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "subpix_window_fraction", "got 0.7");
}

// A checkerboard image: the board (black square diagonally outside corner 0, white margin
// of one square) drawn at `pixels_per_square` in its own plane, then mapped into the image
// by image_from_board (board metres → pixels). Pixel centres at integers.
struct Synthetic {
  cv::Mat image;
  std::vector<Eigen::Vector2d> corners;  // true, in board-corner order
};

Synthetic RenderBoard(const BoardSpec& board, const Eigen::Matrix3d& image_from_board,
                      cv::Size size) {
  // Board texture: x_t = (x_board + 2 s) · k − 0.5 for k texture pixels per metre.
  const double s = board.square_size;
  const int per_square = 160;
  const double k = per_square / s;
  const int width = (board.cols + 3) * per_square, height = (board.rows + 3) * per_square;
  cv::Mat texture(height, width, CV_8UC1, cv::Scalar(220));
  for (int j = 0; j <= board.rows; ++j) {
    for (int i = 0; i <= board.cols; ++i) {
      if ((i + j) % 2 != 0) continue;
      texture(cv::Rect((i + 1) * per_square, (j + 1) * per_square, per_square, per_square))
          .setTo(cv::Scalar(25));
    }
  }
  Eigen::Matrix3d texture_from_board;
  texture_from_board << k, 0, 2 * s * k - 0.5, 0, k, 2 * s * k - 0.5, 0, 0, 1;
  // Rendered 4× larger and area-averaged down: fine pixel U = 4u + 1.5 for image pixel u.
  constexpr int kOversample = 4;
  Eigen::Matrix3d fine_from_image;
  fine_from_image << kOversample, 0, 1.5, 0, kOversample, 1.5, 0, 0, 1;
  const Eigen::Matrix3d image_from_texture =
      fine_from_image * image_from_board * texture_from_board.inverse();
  cv::Mat homography(3, 3, CV_64F);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) homography.at<double>(r, c) = image_from_texture(r, c);
  }
  Synthetic synthetic;
  cv::Mat fine;
  cv::warpPerspective(texture, fine, homography, size * kOversample, cv::INTER_LINEAR,
                      cv::BORDER_CONSTANT, cv::Scalar(10));
  cv::resize(fine, synthetic.image, size, 0, 0, cv::INTER_AREA);
  cv::GaussianBlur(synthetic.image, synthetic.image, cv::Size(), 0.6);
  for (const Eigen::Vector3d& corner : board.CornersInBoard()) {
    synthetic.corners.push_back(
        (image_from_board * Eigen::Vector3d(corner.x(), corner.y(), 1.0)).hnormalized());
  }
  return synthetic;
}

// image_from_board for a board at cam_from_board seen by a pinhole camera.
Eigen::Matrix3d ImageFromBoard(const Eigen::Matrix3d& rotation,
                               const Eigen::Vector3d& translation) {
  Eigen::Matrix3d camera;
  camera << 900, 0, 319.5, 0, 900, 239.5, 0, 0, 1;
  Eigen::Matrix3d plane;
  plane << rotation.col(0), rotation.col(1), translation;
  return camera * plane;
}

double MaxError(const std::vector<Eigen::Vector2d>& found,
                const std::vector<Eigen::Vector2d>& truth) {
  double worst = 0.0;
  for (size_t i = 0; i < found.size(); ++i) worst = std::max(worst, (found[i] - truth[i]).norm());
  return worst;
}

TEST(DetectBoardCorners, FindsCornersInCanonicalOrderWithBothDetectors) {
  const BoardSpec board = BoardSpecFromString("7x4x0.03");
  const Eigen::Vector3d center(0.09, 0.045, 0.0);
  // Facing the camera, tilted, and turned half a turn (corner 0 then at the bottom right
  // of the image): the canonical order must follow the black square, not the image.
  for (double roll : {0.0, 0.4, M_PI}) {
    const Eigen::Matrix3d rotation = (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) *
                                      Eigen::AngleAxisd(0.35, Eigen::Vector3d(0.6, 0.8, 0.0)))
                                         .toRotationMatrix();
    const Eigen::Vector3d translation = Eigen::Vector3d(0.0, 0.0, 0.75) - rotation * center;
    const Synthetic synthetic =
        RenderBoard(board, ImageFromBoard(rotation, translation), cv::Size(640, 480));
    for (CornerDetector detector : {CornerDetector::kSectorBased, CornerDetector::kClassic}) {
      BoardDetectionOptions options;
      options.detector = detector;
      const auto corners = DetectBoardCorners(synthetic.image, board, options);
      ASSERT_TRUE(corners.has_value()) << ToString(detector) << " roll " << roll;
      ASSERT_EQ(corners->size(), 28u);
      EXPECT_LT(MaxError(*corners, synthetic.corners), 0.1)
          << ToString(detector) << " roll " << roll;
    }
  }
}

TEST(DetectBoardCorners, SixteenBitImagesAndAbsentBoards) {
  const BoardSpec board = BoardSpecFromString("7x4x0.03");
  const Synthetic synthetic = RenderBoard(
      board, ImageFromBoard(Eigen::Matrix3d::Identity(), Eigen::Vector3d(-0.09, -0.045, 0.7)),
      cv::Size(640, 480));
  cv::Mat wide;
  synthetic.image.convertTo(wide, CV_16UC1, 257.0);
  const auto corners = DetectBoardCorners(wide, board);
  ASSERT_TRUE(corners.has_value());
  EXPECT_LT(MaxError(*corners, synthetic.corners), 0.1);
  // A wrong size (larger or smaller) and an empty scene find nothing.
  EXPECT_FALSE(DetectBoardCorners(synthetic.image, BoardSpecFromString("8x4x0.03")));
  EXPECT_FALSE(DetectBoardCorners(synthetic.image, BoardSpecFromString("6x4x0.03")));
  EXPECT_FALSE(DetectBoardCorners(cv::Mat(480, 640, CV_8UC1, cv::Scalar(90)), board));
  EXPECT_THROW_WITH_MESSAGE(DetectBoardCorners(cv::Mat(480, 640, CV_32FC1), board), Error,
                            "got CV_32FC1");
}

// The true grid position (column, row) of every found corner, by the nearest true corner;
// fails unless each is within 0.15 px of one.
std::vector<Eigen::Vector2i> TrueGridPositions(const BoardSpec& board,
                                               const std::vector<Eigen::Vector2d>& found,
                                               const std::vector<Eigen::Vector2d>& truth) {
  std::vector<Eigen::Vector2i> positions;
  for (const Eigen::Vector2d& p : found) {
    int best = 0;
    for (int k = 1; k < board.NumCorners(); ++k) {
      if ((truth[k] - p).norm() < (truth[best] - p).norm()) best = k;
    }
    EXPECT_LT((truth[best] - p).norm(), 0.15) << p.transpose();
    positions.emplace_back(best % board.cols, best / board.cols);
  }
  return positions;
}

// A partial detection labels its grid as the board up to a quarter turn and a shift by
// whole squares: true (C, R) = M·(c, r) + offset with M a rotation (det +1, not a mirror).
void ExpectProperLabelling(const BoardSpec& board, const BoardDetection& detection,
                           const std::vector<Eigen::Vector2d>& truth) {
  ASSERT_EQ(detection.corners.size(), detection.indices.size());
  const std::vector<Eigen::Vector2i> positions =
      TrueGridPositions(board, detection.corners, truth);
  const auto labelled = [&](size_t i) {
    return Eigen::Vector2i(detection.indices[i] % board.cols, detection.indices[i] / board.cols);
  };
  // The labels' grid neighbours of entry 0: entries 1 (c + 1) and grid_cols (r + 1).
  Eigen::Matrix2i m;
  m.col(0) = positions[1] - positions[0];
  m.col(1) = positions[detection.grid_cols] - positions[0];
  EXPECT_EQ(m.determinant(), 1) << m;
  EXPECT_EQ(m.cwiseAbs().sum(), 2) << m;
  const Eigen::Vector2i offset = positions[0] - m * labelled(0);
  for (size_t i = 0; i < positions.size(); ++i) {
    EXPECT_EQ(positions[i], m * labelled(i) + offset) << "entry " << i;
  }
}

TEST(DetectBoard, TakesAPartCutByTheImageBorderWithAProperLabelling) {
  const BoardSpec board = BoardSpecFromString("9x6x0.03");
  const Eigen::Vector3d center(0.12, 0.075, 0.0);
  // Off the left edge, off the bottom (rolled and tilted), off a corner.
  const std::vector<std::pair<Eigen::Vector3d, double>> placements = {
      {Eigen::Vector3d(-0.2, 0.0, 0.75), 0.0},
      {Eigen::Vector3d(0.0, 0.11, 0.75), 0.3},
      {Eigen::Vector3d(0.17, -0.1, 0.75), M_PI}};
  for (const auto& [where, roll] : placements) {
    SCOPED_TRACE(::testing::Message() << "board centre " << where.transpose() << " roll " << roll);
    const Eigen::Matrix3d rotation = (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) *
                                      Eigen::AngleAxisd(0.3, Eigen::Vector3d(0.6, 0.8, 0.0)))
                                         .toRotationMatrix();
    const Synthetic synthetic = RenderBoard(
        board, ImageFromBoard(rotation, where - rotation * center), cv::Size(640, 480));
    // The whole board is not in view ...
    ASSERT_FALSE(DetectBoardCorners(synthetic.image, board));
    BoardDetectionOptions whole_only;
    whole_only.partial = false;
    EXPECT_FALSE(DetectBoard(synthetic.image, board, whole_only));
    // ... a part is.
    const auto detection = DetectBoard(synthetic.image, board);
    ASSERT_TRUE(detection.has_value());
    EXPECT_TRUE(detection->partial);
    EXPECT_LT(detection->corners.size(), 54u);
    EXPECT_GE(detection->corners.size(), 0.3 * 54);
    EXPECT_EQ(static_cast<int>(detection->corners.size()),
              detection->grid_cols * detection->grid_rows);
    EXPECT_LE(detection->grid_cols, 9);
    EXPECT_LE(detection->grid_rows, 6);
    std::printf("[partial] %dx%d of 9x6 in view\n", detection->grid_cols, detection->grid_rows);
    ExpectProperLabelling(board, *detection, synthetic.corners);
  }
}

TEST(DetectBoard, WholeBoardsAndPartsNotCutByTheBorder) {
  const BoardSpec board = BoardSpecFromString("9x6x0.03");
  const Eigen::Matrix3d rotation =
      Eigen::AngleAxisd(0.3, Eigen::Vector3d(0.6, 0.8, 0.0)).toRotationMatrix();
  const Synthetic synthetic =
      RenderBoard(board, ImageFromBoard(rotation, Eigen::Vector3d(-0.12, -0.075, 0.75)),
                  cv::Size(640, 480));
  // In full view: the whole board, canonical, not partial.
  const auto whole = DetectBoard(synthetic.image, board);
  ASSERT_TRUE(whole.has_value());
  EXPECT_FALSE(whole->partial);
  ASSERT_EQ(whole->indices.size(), 54u);
  EXPECT_EQ(whole->indices[53], 53);
  EXPECT_LT(MaxError(whole->corners, synthetic.corners), 0.1);
  // Told a larger board than the one in full view: not a part of it (the grid extended by
  // a square stays well inside the image, on the white margin).
  for (const char* larger : {"10x6x0.03", "9x7x0.03", "12x8x0.03", "7x9x0.03"}) {
    EXPECT_FALSE(DetectBoard(synthetic.image, BoardSpecFromString(larger))) << larger;
  }
  // Told a smaller one: the grid in view does not fit it.
  EXPECT_FALSE(DetectBoard(synthetic.image, BoardSpecFromString("8x6x0.03")));
  // Two columns hidden inside the image (a dark patch over them): missing, but not cut by
  // the border, so refused.
  cv::Mat occluded = synthetic.image.clone();
  cv::Point2f lo(1e9f, 1e9f), hi(-1e9f, -1e9f);
  for (int r = 0; r < 6; ++r) {
    for (int c = 7; c < 9; ++c) {
      const Eigen::Vector2d& p = synthetic.corners[r * 9 + c];
      lo = cv::Point2f(std::min<float>(lo.x, p.x()), std::min<float>(lo.y, p.y()));
      hi = cv::Point2f(std::max<float>(hi.x, p.x()), std::max<float>(hi.y, p.y()));
    }
  }
  const float pad = 30.0f;
  cv::rectangle(occluded, cv::Point2f(lo.x - 0.4f * pad, lo.y - 2 * pad),
                cv::Point2f(hi.x + 2 * pad, hi.y + 2 * pad), cv::Scalar(120), cv::FILLED);
  EXPECT_FALSE(DetectBoardCorners(occluded, board));
  EXPECT_FALSE(DetectBoard(occluded, board));
  BoardDetectionOptions options;
  options.min_partial_corner_fraction = 1.5;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "min_partial_corner_fraction", "1.5");
}

}  // namespace
}  // namespace sope
