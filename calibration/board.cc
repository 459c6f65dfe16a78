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
  SOPE_CHECK(min_partial_corner_fraction > 0 && min_partial_corner_fraction <= 1,
             "min_partial_corner_fraction must be in (0, 1], got {}", min_partial_corner_fraction);
  SOPE_CHECK(partial_edge_squares >= 0 && partial_edge_squares <= 2,
             "partial_edge_squares must be in [0, 2], got {}", partial_edge_squares);
  SOPE_CHECK(partial_corner_edge_squares >= 0 && partial_corner_edge_squares <= 2,
             "partial_corner_edge_squares must be in [0, 2], got {}", partial_corner_edge_squares);
}

namespace internal {
namespace {

cv::Mat ToGrey8(const cv::Mat& image, const char* caller) {
  SOPE_CHECK(!image.empty() && image.channels() == 1 &&
                 (image.depth() == CV_8U || image.depth() == CV_16U),
             "{}: expected a CV_8UC1 or CV_16UC1 image, got {}", caller,
             cv::typeToString(image.type()));
  cv::Mat grey = image;
  if (image.depth() == CV_16U) image.convertTo(grey, CV_8U, 1.0 / 257.0);
  return grey;
}

// Smallest and median distance between grid neighbours (cols × rows, row-major), pixels.
std::pair<double, double> Spacings(const std::vector<cv::Point2f>& corners, int cols, int rows) {
  std::vector<double> distances;
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const cv::Point2f& p = corners[r * cols + c];
      if (c + 1 < cols) distances.push_back(cv::norm(corners[r * cols + c + 1] - p));
      if (r + 1 < rows) distances.push_back(cv::norm(corners[(r + 1) * cols + c] - p));
    }
  }
  std::sort(distances.begin(), distances.end());
  return {distances.front(), distances[distances.size() / 2]};
}

void RefineCorners(const cv::Mat& grey, const BoardDetectionOptions& options, double smallest,
                   std::vector<cv::Point2f>* corners) {
  const int half = std::clamp(static_cast<int>(options.subpix_window_fraction * smallest), 2,
                              options.max_subpix_half_window_px);
  cv::cornerSubPix(grey, *corners, cv::Size(half, half), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
}

int SectorBasedFlags(const BoardDetectionOptions& options) {
  int flags = 0;
  if (options.normalize_image) flags |= cv::CALIB_CB_NORMALIZE_IMAGE;
  if (options.accuracy) flags |= cv::CALIB_CB_ACCURACY;
  if (options.exhaustive) flags |= cv::CALIB_CB_EXHAUSTIVE;
  return flags;
}

// The largest sub-grid (at least min_side corners along each side) of a grid (cols ×
// rows, row-major) without corners within `edge_squares` local squares of the image edge;
// `corners`, `cols` and `rows` become it. False when there is none.
bool TrimCornersAtTheBorder(cv::Size image, double edge_squares, int min_side,
                            std::vector<Eigen::Vector2d>* corners, int* cols, int* rows) {
  const int n_cols = *cols, n_rows = *rows;
  const auto at = [&](int c, int r) -> const Eigen::Vector2d& {
    return (*corners)[r * n_cols + c];
  };
  // near[r][c]: corner (c, r) within the margin, its square size from a grid neighbour.
  std::vector<std::vector<int>> near(n_rows, std::vector<int>(n_cols, 0));
  for (int r = 0; r < n_rows; ++r) {
    for (int c = 0; c < n_cols; ++c) {
      const Eigen::Vector2d& p = at(c, r);
      const Eigen::Vector2d& q = at(c + (c + 1 < n_cols ? 1 : -1), r);
      const double margin = edge_squares * (p - q).norm();
      near[r][c] = p.x() < margin || p.y() < margin || p.x() > image.width - 1 - margin ||
                   p.y() > image.height - 1 - margin;
    }
  }
  // Exhaustive over the sub-rectangles [c0, c1) × [r0, r1): boards have ~100 corners.
  int best_area = 0, best_c0 = 0, best_c1 = 0, best_r0 = 0, best_r1 = 0;
  for (int c0 = 0; c0 < n_cols; ++c0) {
    for (int c1 = c0 + min_side; c1 <= n_cols; ++c1) {
      for (int r0 = 0; r0 < n_rows; ++r0) {
        for (int r1 = r0 + min_side; r1 <= n_rows; ++r1) {
          const int area = (c1 - c0) * (r1 - r0);
          if (area <= best_area) continue;
          bool clean = true;
          for (int r = r0; r < r1 && clean; ++r) {
            for (int c = c0; c < c1 && clean; ++c) clean = !near[r][c];
          }
          if (!clean) continue;
          best_area = area;
          best_c0 = c0, best_c1 = c1, best_r0 = r0, best_r1 = r1;
        }
      }
    }
  }
  if (best_area == 0) return false;
  std::vector<Eigen::Vector2d> kept;
  for (int r = best_r0; r < best_r1; ++r) {
    for (int c = best_c0; c < best_c1; ++c) kept.push_back(at(c, r));
  }
  *corners = std::move(kept);
  *cols = best_c1 - best_c0;
  *rows = best_r1 - best_r0;
  return true;
}

// Whether a grid (cols × rows, row-major) is a lattice seen through a plane: a
// homography from its (c, r) fits every corner to within 0.15 of the median spacing (and
// 0.05 RMS). SB with CALIB_CB_LARGER can return a tangle of corners from the board's
// margin and squares; lens distortion over a board stays far below this.
bool IsPlaneLattice(const std::vector<cv::Point2f>& corners, int cols, int rows) {
  std::vector<cv::Point2f> grid;
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) grid.emplace_back(static_cast<float>(c), static_cast<float>(r));
  }
  const cv::Mat h = cv::findHomography(grid, corners, 0);
  if (h.empty()) return false;
  std::vector<cv::Point2f> mapped;
  cv::perspectiveTransform(grid, mapped, h);
  const double spacing = Spacings(corners, cols, rows).second;
  double sum = 0.0, worst = 0.0;
  for (size_t i = 0; i < corners.size(); ++i) {
    const double e = cv::norm(mapped[i] - corners[i]);
    sum += e * e;
    worst = std::max(worst, e);
  }
  return worst <= 0.15 * spacing && std::sqrt(sum / corners.size()) <= 0.05 * spacing;
}

// Whether a visible grid (cols × rows corners, row-major) missing `missing_cols` columns
// and `missing_rows` rows of its board can have lost them only to the image border: along
// each direction with corners missing, the grid extended by one square on at least one
// side reaches outside the image or within `edge_squares` local squares of its edge.
bool MissingPartOutsideImage(const std::vector<Eigen::Vector2d>& corners, int cols, int rows,
                             int missing_cols, int missing_rows, cv::Size image,
                             double edge_squares) {
  const auto at = [&](int c, int r) -> const Eigen::Vector2d& { return corners[r * cols + c]; };
  // Corner (c, r) of the grid's edge line and its neighbour (c + dc, r + dr) inward: the
  // corner one square beyond, extrapolated linearly (a homography of the whole grid
  // extrapolates wildly when the grid is a narrow strip), is outside the image or within
  // edge_squares of that square's size of its edge.
  const auto cut = [&](int c, int r, int dc, int dr) {
    const Eigen::Vector2d step = at(c, r) - at(c + dc, r + dr);
    const Eigen::Vector2d p = at(c, r) + step;
    const double margin = edge_squares * step.norm();
    return !(p.x() >= margin && p.y() >= margin && p.x() <= image.width - 1 - margin &&
             p.y() <= image.height - 1 - margin);
  };
  // `edge`: the grid's first or last column (along_columns) or row; `inward`: ±1 into it.
  const auto side_cut = [&](bool along_columns, int edge, int inward) {
    const int count = along_columns ? rows : cols;
    for (int i = 0; i < count; ++i) {
      if (along_columns ? cut(edge, i, inward, 0) : cut(i, edge, 0, inward)) return true;
    }
    return false;
  };
  if (missing_cols > 0 && !side_cut(true, 0, 1) && !side_cut(true, cols - 1, -1)) return false;
  if (missing_rows > 0 && !side_cut(false, 0, 1) && !side_cut(false, rows - 1, -1)) return false;
  return true;
}

}  // namespace
}  // namespace internal

std::optional<std::vector<Eigen::Vector2d>> DetectBoardCorners(
    const cv::Mat& image, const BoardSpec& board, const BoardDetectionOptions& options) {
  board.Check();
  options.Check();
  const cv::Mat grey = internal::ToGrey8(image, "DetectBoardCorners");
  const cv::Size pattern_size(board.cols, board.rows);
  std::vector<cv::Point2f> found;
  if (options.detector == CornerDetector::kSectorBased) {
    if (!cv::findChessboardCornersSB(grey, pattern_size, found,
                                     internal::SectorBasedFlags(options))) {
      return std::nullopt;
    }
    if (static_cast<int>(found.size()) != board.NumCorners()) return std::nullopt;
    const auto [smallest, median] = internal::Spacings(found, board.cols, board.rows);
    if (median < options.subpix_below_spacing_px)
      internal::RefineCorners(grey, options, smallest, &found);
  } else {
    const int flags = cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE;
    if (!cv::findChessboardCorners(grey, pattern_size, found, flags)) return std::nullopt;
    if (static_cast<int>(found.size()) != board.NumCorners()) return std::nullopt;
    internal::RefineCorners(grey, options, internal::Spacings(found, board.cols, board.rows).first,
                            &found);
  }
  if (static_cast<int>(found.size()) != board.NumCorners()) return std::nullopt;
  std::vector<Eigen::Vector2d> corners;
  corners.reserve(found.size());
  for (const cv::Point2f& p : found) corners.emplace_back(p.x, p.y);
  internal::CanonicaliseCornerOrder(grey, board, &corners);
  return corners;
}

BoardSpec BoardDetection::GridSpec(const BoardSpec& board) const {
  BoardSpec grid = board;
  grid.cols = grid_cols;
  grid.rows = grid_rows;
  return grid;
}

std::optional<BoardDetection> DetectBoard(const cv::Mat& image, const BoardSpec& board,
                                          const BoardDetectionOptions& options) {
  BoardDetection detection;
  if (auto corners = DetectBoardCorners(image, board, options)) {
    detection.corners = std::move(*corners);
    detection.grid_cols = board.cols;
    detection.grid_rows = board.rows;
    for (int k = 0; k < board.NumCorners(); ++k) detection.indices.push_back(k);
    return detection;
  }
  if (!options.partial) return std::nullopt;
  const cv::Mat grey = internal::ToGrey8(image, "DetectBoard");
  // The smallest grid SB accepts; CALIB_CB_LARGER grows it to the largest one in view.
  constexpr int kMinGridSide = 3;
  // SB discards a grown grid whose outline comes within 5 px of the image edge, which a
  // board running out of the image always does: it searches a copy padded with the mean
  // grey instead (no corners there, so the grid still ends at the image's edge).
  const int pad = std::max(32, std::max(grey.cols, grey.rows) / 20);
  cv::Mat padded;
  cv::copyMakeBorder(grey, padded, pad, pad, pad, pad, cv::BORDER_CONSTANT,
                     cv::Scalar(cv::mean(grey)[0]));
  std::vector<cv::Point2f> found;
  cv::Mat meta;
  if (!cv::findChessboardCornersSB(padded, cv::Size(kMinGridSide, kMinGridSide), found,
                                   internal::SectorBasedFlags(options) | cv::CALIB_CB_LARGER,
                                   meta)) {
    return std::nullopt;
  }
  for (cv::Point2f& p : found) p -= cv::Point2f(static_cast<float>(pad), static_cast<float>(pad));
  int cols = meta.cols, rows = meta.rows;
  if (cols < kMinGridSide || rows < kMinGridSide ||
      static_cast<int>(found.size()) != cols * rows) {
    return std::nullopt;
  }
  std::vector<Eigen::Vector2d> corners;
  for (const cv::Point2f& p : found) corners.emplace_back(p.x, p.y);
  // The grid's columns along the board's rows of corners, or (transposed) along its
  // columns: the first way round whose missing part can lie outside the image.
  std::optional<bool> transpose;
  for (const bool t : {false, true}) {
    const int board_cols = t ? board.rows : board.cols;
    const int board_rows = t ? board.cols : board.rows;
    if (cols > board_cols || rows > board_rows) continue;
    if (internal::MissingPartOutsideImage(corners, cols, rows, board_cols - cols,
                                          board_rows - rows, grey.size(),
                                          options.partial_edge_squares)) {
      transpose = t;
      break;
    }
  }
  if (!transpose) return std::nullopt;
  // Corners whose squares the border cuts are placed less well: the largest sub-grid
  // without them is kept.
  if (!internal::TrimCornersAtTheBorder(grey.size(), options.partial_corner_edge_squares,
                                        kMinGridSide,
                                        &corners, &cols, &rows)) {
    return std::nullopt;
  }
  const int min_corners = std::max(
      kMinGridSide * kMinGridSide,
      static_cast<int>(std::ceil(options.min_partial_corner_fraction * board.NumCorners())));
  if (cols * rows < min_corners) return std::nullopt;
  {
    found.clear();
    for (const Eigen::Vector2d& p : corners)
      found.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
    // (Checked on the kept corners: those at the edge may sit a few pixels off.)
    if (!internal::IsPlaneLattice(found, cols, rows)) return std::nullopt;
    const auto [smallest, median] = internal::Spacings(found, cols, rows);
    if (options.detector == CornerDetector::kClassic || median < options.subpix_below_spacing_px) {
      internal::RefineCorners(grey, options, smallest, &found);
      for (size_t i = 0; i < found.size(); ++i) corners[i] = Eigen::Vector2d(found[i].x, found[i].y);
    }
  }
  if (*transpose) {
    std::vector<Eigen::Vector2d> transposed(corners.size());
    for (int r = 0; r < cols; ++r) {
      for (int c = 0; c < rows; ++c) transposed[r * rows + c] = corners[c * cols + r];
    }
    corners = std::move(transposed);
    std::swap(cols, rows);
  }
  // Right-handed with z away from the camera, as DetectBoardCorners: mirror the rows
  // otherwise.
  const auto at = [&](int c, int r) -> const Eigen::Vector2d& { return corners[r * cols + c]; };
  if (internal::Cross2d(at(1, 0) - at(0, 0), at(0, 1) - at(0, 0)) < 0) {
    for (int r = 0; r < rows; ++r) {
      std::reverse(corners.begin() + r * cols, corners.begin() + (r + 1) * cols);
    }
  }
  detection.grid_cols = cols;
  detection.grid_rows = rows;
  if (cols == board.cols && rows == board.rows) {
    // The whole board after all (found by growing): its canonical order.
    internal::CanonicaliseCornerOrder(grey, board, &corners);
  } else {
    detection.partial = true;
  }
  detection.corners = std::move(corners);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) detection.indices.push_back(r * board.cols + c);
  }
  return detection;
}

}  // namespace sope
