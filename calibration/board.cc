#include "calibration/board.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <fmt/format.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"

namespace sope {
namespace internal {
namespace {

double Cross2d(const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return a.x() * b.y() - a.y() * b.x();
}

// Mean grey level in a disc of `radius` pixels around `center` (clamped to the image),
// NaN when the disc is outside.
double MeanAround(const cv::Mat& image, const Eigen::Vector2d& center, double radius) {
  const int r = std::max(1, static_cast<int>(radius));
  const int cx = static_cast<int>(std::lround(center.x()));
  const int cy = static_cast<int>(std::lround(center.y()));
  double sum = 0.0;
  int count = 0;
  for (int y = std::max(0, cy - r); y <= std::min(image.rows - 1, cy + r); ++y) {
    for (int x = std::max(0, cx - r); x <= std::min(image.cols - 1, cx + r); ++x) {
      if ((x - cx) * (x - cx) + (y - cy) * (y - cy) > r * r) continue;
      sum += image.depth() == CV_16U ? image.at<uint16_t>(y, x) / 257.0 : image.at<uint8_t>(y, x);
      ++count;
    }
  }
  return count > 0 ? sum / count : std::numeric_limits<double>::quiet_NaN();
}

// Puts `corners` (row-major, board.cols per row) in the canonical order of
// DetectBoardCorners.
void CanonicaliseCornerOrder(const cv::Mat& image, const BoardSpec& board,
                             std::vector<Eigen::Vector2d>* corners) {
  const int cols = board.cols, rows = board.rows;
  auto at = [&](int c, int r) -> Eigen::Vector2d& { return (*corners)[r * cols + c]; };
  // Right-handed with z away from the camera: x × y points into the image (positive in
  // image coordinates, y down). Otherwise mirror the rows.
  if (Cross2d(at(1, 0) - at(0, 0), at(0, 1) - at(0, 0)) < 0) {
    for (int r = 0; r < rows; ++r) {
      std::reverse(corners->begin() + r * cols, corners->begin() + (r + 1) * cols);
    }
  }
  bool rotate = false;
  if ((cols + rows) % 2 == 1) {
    // Centres of the outer squares diagonal to the two end corners (affine estimate).
    const Eigen::Vector2d first = at(0, 0) - 0.5 * (at(1, 1) - at(0, 0));
    const Eigen::Vector2d last =
        at(cols - 1, rows - 1) - 0.5 * (at(cols - 2, rows - 2) - at(cols - 1, rows - 1));
    const double radius = 0.15 * (at(1, 1) - at(0, 0)).norm();
    const double first_grey = MeanAround(image, first, radius);
    const double last_grey = MeanAround(image, last, radius);
    if (std::isfinite(first_grey) && std::isfinite(last_grey)) rotate = first_grey > last_grey;
  } else {
    rotate = at(0, 0).sum() > at(cols - 1, rows - 1).sum();
  }
  if (rotate) std::reverse(corners->begin(), corners->end());
}

}  // namespace
}  // namespace internal

void BoardSpec::Check() const {
  SOPE_CHECK(cols >= 2 && rows >= 2, "board {}x{}: needs at least 2x2 inner corners", cols, rows);
  SOPE_CHECK(std::isfinite(square_size) && square_size > 0,
             "board square size must be > 0 metres, got {}", square_size);
}

Eigen::Vector3d BoardSpec::CornerInBoard(int index) const {
  return Eigen::Vector3d((index % cols) * square_size, (index / cols) * square_size, 0.0);
}

std::vector<Eigen::Vector3d> BoardSpec::CornersInBoard() const {
  std::vector<Eigen::Vector3d> corners;
  corners.reserve(NumCorners());
  for (int k = 0; k < NumCorners(); ++k) corners.push_back(CornerInBoard(k));
  return corners;
}

std::string BoardSpec::ToString() const {
  return fmt::format("{}x{}x{:g}", cols, rows, square_size);
}

std::string BoardSpec::PatternSizeString() const { return fmt::format("{}x{}", cols, rows); }

BoardSpec BoardSpecFromString(const std::string& text) {
  const auto fail = [&]() {
    SOPE_THROW(
        "board '{}': expected COLSxROWSxSQUARE_M (inner corners, square side in "
        "metres), e.g. 9x6x0.025",
        text);
  };
  const size_t first = text.find_first_of("xX");
  const size_t second = first == std::string::npos ? first : text.find_first_of("xX", first + 1);
  if (second == std::string::npos) fail();
  BoardSpec board;
  try {
    size_t used_cols = 0, used_rows = 0, used_size = 0;
    const std::string cols = text.substr(0, first);
    const std::string rows = text.substr(first + 1, second - first - 1);
    const std::string size = text.substr(second + 1);
    board.cols = std::stoi(cols, &used_cols);
    board.rows = std::stoi(rows, &used_rows);
    board.square_size = std::stod(size, &used_size);
    if (used_cols != cols.size() || used_rows != rows.size() || used_size != size.size()) fail();
  } catch (const std::logic_error&) {
    fail();
  }
  try {
    board.Check();
  } catch (const Error& e) {
    SOPE_THROW("board '{}': {}", text, e.what());
  }
  return board;
}

std::string ToString(CornerDetector detector) {
  switch (detector) {
    case CornerDetector::kSectorBased:
      return "sb";
    case CornerDetector::kClassic:
      return "classic";
  }
  return "?";
}

CornerDetector CornerDetectorFromString(const std::string& text) {
  if (text == "sb") return CornerDetector::kSectorBased;
  if (text == "classic") return CornerDetector::kClassic;
  SOPE_THROW("unknown corner detector '{}' (known: sb, classic)", text);
}

void BoardDetectionOptions::Check() const {
  SOPE_CHECK(subpix_window_fraction > 0 && subpix_window_fraction < 0.5,
             "subpix_window_fraction must be in (0, 0.5), got {}", subpix_window_fraction);
  SOPE_CHECK(max_subpix_half_window_px >= 2, "max_subpix_half_window_px must be >= 2, got {}",
             max_subpix_half_window_px);
  SOPE_CHECK(subpix_below_spacing_px >= 0, "subpix_below_spacing_px must be >= 0, got {}",
             subpix_below_spacing_px);
}

std::optional<std::vector<Eigen::Vector2d>> DetectBoardCorners(
    const cv::Mat& image, const BoardSpec& board, const BoardDetectionOptions& options) {
  board.Check();
  options.Check();
  SOPE_CHECK(!image.empty() && image.channels() == 1 &&
                 (image.depth() == CV_8U || image.depth() == CV_16U),
             "DetectBoardCorners: expected a CV_8UC1 or CV_16UC1 image, got {}",
             cv::typeToString(image.type()));
  cv::Mat grey = image;
  if (image.depth() == CV_16U) image.convertTo(grey, CV_8U, 1.0 / 257.0);
  const cv::Size pattern_size(board.cols, board.rows);
  std::vector<cv::Point2f> found;
  // Smallest and median distance between grid neighbours, pixels.
  const auto spacings = [&](const std::vector<cv::Point2f>& corners) {
    std::vector<double> distances;
    for (int r = 0; r < board.rows; ++r) {
      for (int c = 0; c < board.cols; ++c) {
        const cv::Point2f& p = corners[r * board.cols + c];
        if (c + 1 < board.cols) distances.push_back(cv::norm(corners[r * board.cols + c + 1] - p));
        if (r + 1 < board.rows)
          distances.push_back(cv::norm(corners[(r + 1) * board.cols + c] - p));
      }
    }
    std::sort(distances.begin(), distances.end());
    return std::pair{distances.front(), distances[distances.size() / 2]};
  };
  const auto refine = [&](std::vector<cv::Point2f>* corners, double smallest) {
    const int half = std::clamp(static_cast<int>(options.subpix_window_fraction * smallest), 2,
                                options.max_subpix_half_window_px);
    cv::cornerSubPix(grey, *corners, cv::Size(half, half), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
  };
  if (options.detector == CornerDetector::kSectorBased) {
    int flags = 0;
    if (options.normalize_image) flags |= cv::CALIB_CB_NORMALIZE_IMAGE;
    if (options.accuracy) flags |= cv::CALIB_CB_ACCURACY;
    if (options.exhaustive) flags |= cv::CALIB_CB_EXHAUSTIVE;
    if (!cv::findChessboardCornersSB(grey, pattern_size, found, flags)) return std::nullopt;
    if (static_cast<int>(found.size()) != board.NumCorners()) return std::nullopt;
    const auto [smallest, median] = spacings(found);
    if (median < options.subpix_below_spacing_px) refine(&found, smallest);
  } else {
    const int flags = cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE;
    if (!cv::findChessboardCorners(grey, pattern_size, found, flags)) return std::nullopt;
    if (static_cast<int>(found.size()) != board.NumCorners()) return std::nullopt;
    refine(&found, spacings(found).first);
  }
  if (static_cast<int>(found.size()) != board.NumCorners()) return std::nullopt;
  std::vector<Eigen::Vector2d> corners;
  corners.reserve(found.size());
  for (const cv::Point2f& p : found) corners.emplace_back(p.x, p.y);
  internal::CanonicaliseCornerOrder(grey, board, &corners);
  return corners;
}

}  // namespace sope
