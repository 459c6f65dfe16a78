#include "calibration/triangulation.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include <Eigen/Dense>
#include <opencv2/core.hpp>

#include "calibration/triangulation_rows.h"
#include "core/cv_threads.h"
#include "core/error.h"

namespace sope {
namespace {

// A lens's distortion in locals (OpenCV order, 0 when absent), so that the per-pixel loops
// below are plain arithmetic the compiler vectorises.
struct Lens {
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0, k4 = 0, k5 = 0, k6 = 0;
  double fx = 1, fy = 1, cx = 0, cy = 0;
  explicit Lens(const CameraModel& model) {
    const auto coeff = [&](size_t i) {
      return i < model.distortion.size() ? model.distortion[i] : 0.0;
    };
    k1 = coeff(0), k2 = coeff(1), p1 = coeff(2), p2 = coeff(3);
    k3 = coeff(4), k4 = coeff(5), k5 = coeff(6), k6 = coeff(7);
    fx = model.fx(), fy = model.fy(), cx = model.cx(), cy = model.cy();
  }
  // Undistorted → distorted normalised coordinates (CameraModel::Distort).
  inline void Distort(double x, double y, double* xd, double* yd) const {
    const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
    const double radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6);
    *xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    *yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
  }
  // One Gauss–Newton step of Undistort towards the distorted target (tx, ty), with the
  // analytic Jacobian of CameraModel's DistortWithJacobian; returns the squared residual
  // before the step.
  inline double NewtonStep(double tx, double ty, double* x, double* y) const {
    const double u = *x, v = *y;
    const double r2 = u * u + v * v, r4 = r2 * r2, r6 = r4 * r2;
    const double num = 1.0 + k1 * r2 + k2 * r4 + k3 * r6;
    const double den = 1.0 + k4 * r2 + k5 * r4 + k6 * r6;
    const double radial = num / den;
    const double rx = u * radial + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u) - tx;
    const double ry = v * radial + p1 * (r2 + 2.0 * v * v) + 2.0 * p2 * u * v - ty;
    const double dnum = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4;
    const double dden = k4 + 2.0 * k5 * r2 + 3.0 * k6 * r4;
    const double dradial = (dnum * den - num * dden) / (den * den);
    const double j00 = radial + u * dradial * 2.0 * u + 2.0 * p1 * v + 6.0 * p2 * u;
    const double j01 = u * dradial * 2.0 * v + 2.0 * p1 * u + 2.0 * p2 * v;
    const double j10 = v * dradial * 2.0 * u + 2.0 * p1 * u + 2.0 * p2 * v;
    const double j11 = radial + v * dradial * 2.0 * v + 6.0 * p1 * v + 2.0 * p2 * u;
    const double det = j00 * j11 - j01 * j10;
    *x = u - (j11 * rx - j01 * ry) / det;
    *y = v - (j00 * ry - j10 * rx) / det;
    return rx * rx + ry * ry;
  }
};

// Undistorted normalised coordinates (CameraModel::CamFromImage) of the integer pixels
// (x0 + i, y0 + j), i < width, j < height, CV_32FC2 (pixels outside the image too: the
// projector's plane tables need rays a few pixels beyond its border).
//
// Rows are solved together: Gauss–Newton from the distorted point on the first row of each
// range, then warm-started from the row above (one pixel away: two steps reach 1e-14),
// then one more evaluation checks CameraModel::Undistort's tolerance; a pixel that misses
// it is solved by CameraModel::Undistort itself. Results equal the per-pixel solve to its
// 1e-14 tolerance.
cv::Mat UndistortedGrid(const CameraModel& model, int x0, int y0, int width, int height) {
  cv::Mat grid(height, width, CV_32FC2);
  const Lens lens(model);
  const bool distorted = model.HasDistortion();
  constexpr int kColdSteps = 12;
  constexpr int kWarmSteps = 2;
  constexpr double kTolerance = 1e-14;  // CameraModel::Undistort's
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    std::vector<double> target_x(width), estimate_x(width), estimate_y(width), residual(width);
    for (int i = 0; i < width; ++i) target_x[i] = ((x0 + i) - lens.cx) / lens.fx;
    double previous_target_y = 0.0;
    for (int j = rows.start; j < rows.end; ++j) {
      const double target_y = ((y0 + j) - lens.cy) / lens.fy;
      cv::Vec2f* row = grid.ptr<cv::Vec2f>(j);
      if (!distorted) {
        for (int i = 0; i < width; ++i) {
          row[i] = cv::Vec2f(static_cast<float>(target_x[i]), static_cast<float>(target_y));
        }
        continue;
      }
      const bool warm = j > rows.start;
      double* __restrict ex = estimate_x.data();
      double* __restrict ey = estimate_y.data();
      double* __restrict res = residual.data();
      const double* __restrict tx = target_x.data();
      if (warm) {
        const double shift = target_y - previous_target_y;
        for (int i = 0; i < width; ++i) ey[i] += shift;
      } else {
        for (int i = 0; i < width; ++i) {
          ex[i] = tx[i];
          ey[i] = target_y;
        }
      }
      const int steps = warm ? kWarmSteps : kColdSteps;
      for (int step = 0; step < steps; ++step) {
        for (int i = 0; i < width; ++i) lens.NewtonStep(tx[i], target_y, &ex[i], &ey[i]);
      }
      for (int i = 0; i < width; ++i) {
        double xd, yd;
        lens.Distort(ex[i], ey[i], &xd, &yd);
        res[i] = (xd - tx[i]) * (xd - tx[i]) + (yd - target_y) * (yd - target_y);
      }
      for (int i = 0; i < width; ++i) {
        if (!(res[i] < kTolerance * kTolerance)) {
          const Eigen::Vector2d exact = model.Undistort(Eigen::Vector2d(tx[i], target_y));
          ex[i] = exact.x();
          ey[i] = exact.y();
        }
        row[i] = cv::Vec2f(static_cast<float>(ex[i]), static_cast<float>(ey[i]));
      }
      previous_target_y = target_y;
    }
  });
  return grid;
}

cv::Mat UndistortedGrid(const CameraModel& model) {
  return UndistortedGrid(model, 0, 0, model.width, model.height);
}

// The light plane through the projector rays a = (x_a, y_a, 1) and b (n = a × b) as the
// plane tables store it: (n_y, n_z) / n_x for a column's plane, (n_x, n_z) / n_y for a
// row's.
Eigen::Vector2d PlaneRatios(double xa, double ya, double xb, double yb, bool columns) {
  const double nx = ya - yb, ny = xb - xa, nz = xa * yb - ya * xb;
  return columns ? Eigen::Vector2d(ny / nx, nz / nx) : Eigen::Vector2d(nx / ny, nz / ny);
}

// Light planes of one projector axis from the ray grid `extended` (undistorted normalised
// coordinates of the projector pixels shifted by `margin`, `margin` pixels beyond every
// border): for columns, the chord through column c at rows r ± margin, n = a × b with
// a = (x_a, y_a, 1) etc., stored as (n_y, n_z) / n_x; for rows, the chord through row r at
// columns c ± margin, stored as (n_x, n_z) / n_y. CV_32FC2, [row][column].
cv::Mat PlaneTable(const cv::Mat& extended, int margin, int width, int height, bool columns) {
  cv::Mat planes(height, width, CV_32FC2);
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int r = rows.start; r < rows.end; ++r) {
      cv::Vec2f* out = planes.ptr<cv::Vec2f>(r);
      const cv::Vec2f* above = extended.ptr<cv::Vec2f>(r + margin - (columns ? margin : 0));
      const cv::Vec2f* below = extended.ptr<cv::Vec2f>(r + margin + (columns ? margin : 0));
      for (int c = 0; c < width; ++c) {
        const cv::Vec2f a = columns ? above[c + margin] : above[c];
        const cv::Vec2f b = columns ? below[c + margin] : below[c + 2 * margin];
        const Eigen::Vector2d plane = PlaneRatios(a[0], a[1], b[0], b[1], columns);
        out[c] = cv::Vec2f(static_cast<float>(plane[0]), static_cast<float>(plane[1]));
      }
    }
  });
  return planes;
}

// How far the plane table's interpolated plane strays from the chord the exact path builds
// at the same sub-pixel (column, row) — through the bilinearly interpolated rays at the
// row ± margin (column ± margin) — in projector pixels along the coded axis: the coded
// coordinate where each plane meets the interpolated ray of that row (column), at the
// centres of cells 8 apart and of the last ones (the bilinear interpolation's error is
// largest at a cell's centre). Mild lenses give ~2e-5 px, about the float rounding of the
// grid itself; a strongly distorted wide-angle projector ~3e-4 px (the column surface
// curves within a cell).
double PlaneTableDeviationPx(const cv::Mat& extended, const cv::Mat& planes, int margin,
                             bool columns, double focal) {
  const auto bilinear = [](const cv::Mat& m, double u, double v) {
    const int x0 = std::min(static_cast<int>(u), m.cols - 2);
    const int y0 = std::min(static_cast<int>(v), m.rows - 2);
    const double fu = u - x0, fv = v - y0;
    const cv::Vec2f a = m.at<cv::Vec2f>(y0, x0), b = m.at<cv::Vec2f>(y0, x0 + 1);
    const cv::Vec2f c = m.at<cv::Vec2f>(y0 + 1, x0), d = m.at<cv::Vec2f>(y0 + 1, x0 + 1);
    Eigen::Vector2d out;
    for (int k = 0; k < 2; ++k) {
      out[k] = (1 - fv) * ((1 - fu) * a[k] + fu * b[k]) + fv * ((1 - fu) * c[k] + fu * d[k]);
    }
    return out;
  };
  // Every kStep-th cell and the last of each axis (the deviation varies smoothly with the
  // lens and is largest at the borders).
  constexpr int kStep = 8;
  const auto cells = [](int count) {
    std::vector<int> out;
    for (int k = 0; k < count; k += kStep) out.push_back(k);
    if (count > 0 && out.back() != count - 1) out.push_back(count - 1);
    return out;
  };
  const std::vector<int> cell_rows = cells(planes.rows - 1), cell_columns = cells(planes.cols - 1);
  std::vector<double> worst(cell_rows.size(), 0.0);
  cv::parallel_for_(cv::Range(0, static_cast<int>(cell_rows.size())), [&](const cv::Range& range) {
    for (int k = range.start; k < range.end; ++k) {
      const double v = cell_rows[k] + 0.5;
      for (const int c : cell_columns) {
        const double u = c + 0.5;
        const Eigen::Vector2d ray = bilinear(extended, u + margin, v + margin);
        const Eigen::Vector2d a = columns ? bilinear(extended, u + margin, v)
                                          : bilinear(extended, u, v + margin);
        const Eigen::Vector2d b = columns ? bilinear(extended, u + margin, v + 2 * margin)
                                          : bilinear(extended, u + 2 * margin, v + margin);
        const Eigen::Vector2d chord = PlaneRatios(a.x(), a.y(), b.x(), b.y(), columns);
        const Eigen::Vector2d table = bilinear(planes, u, v);
        // Columns: x = −(n_y·y + n_z) / n_x on the ray's y; rows: y = −(n_x·x + n_z) / n_y.
        const double deviation =
            (chord[0] - table[0]) * (columns ? ray.y() : ray.x()) + (chord[1] - table[1]);
        worst[k] = std::max(worst[k], std::abs(deviation) * focal);
      }
    }
  });
  return worst.empty() ? 0.0 : *std::max_element(worst.begin(), worst.end());
}

}  // namespace

std::string ToString(TriangulationMethod method) {
  return method == TriangulationMethod::kMidpoint ? "midpoint" : "linear";
}

TriangulationMethod TriangulationMethodFromString(const std::string& text) {
  if (text == "midpoint") return TriangulationMethod::kMidpoint;
  if (text == "linear") return TriangulationMethod::kLinear;
  SOPE_THROW("unknown triangulation method '{}' (expected midpoint or linear)", text);
}

void TriangulationOptions::Check() const {
  SOPE_CHECK(min_depth >= 0 && max_depth > min_depth,
             "depth band [{}, {}] m is empty or negative", min_depth, max_depth);
  SOPE_CHECK(num_threads >= 1, "num_threads must be ≥ 1, got {}", num_threads);
}

Triangulator::Triangulator(const RigCalibration& calibration,
                           const TriangulationOptions& options)
    : calibration_(calibration), options_(options) {
  calibration_.Check();
  options_.Check();
  cam_from_proj_rotation_ = calibration_.proj_from_cam.rotation.transpose();
  projector_center_in_cam_ = -(cam_from_proj_rotation_ * calibration_.proj_from_cam.translation);
  camera_rays_ = UndistortedGrid(calibration_.camera);
  // The projector grid reaches kPlaneHalfSpanPx beyond the border, for the chords of the
  // plane tables; projector_rays_ is its interior (the same values).
  const CameraModel& projector = calibration_.projector;
  constexpr int kMargin = static_cast<int>(kPlaneHalfSpanPx);
  static_assert(kMargin == kPlaneHalfSpanPx, "the chord spans whole pixels");
  projector_rays_with_margin_ = UndistortedGrid(projector, -kMargin, -kMargin,
                                                projector.width + 2 * kMargin,
                                                projector.height + 2 * kMargin);
  const cv::Mat& extended = projector_rays_with_margin_;
  projector_rays_ = extended(cv::Rect(kMargin, kMargin, projector.width, projector.height));
  column_planes_ = PlaneTable(extended, kMargin, projector.width, projector.height, true);
  row_planes_ = PlaneTable(extended, kMargin, projector.width, projector.height, false);
  fast_tables_ = projector.width >= 2 && projector.height >= 2;
  if (fast_tables_) {
    column_plane_deviation_px_ =
        PlaneTableDeviationPx(extended, column_planes_, kMargin, true, projector.matrix(0, 0));
    row_plane_deviation_px_ =
        PlaneTableDeviationPx(extended, row_planes_, kMargin, false, projector.matrix(1, 1));
  }
}

size_t Triangulator::TableBytes() const {
  const auto bytes = [](const cv::Mat& m) { return m.total() * m.elemSize(); };
  return bytes(camera_rays_) + bytes(projector_rays_with_margin_) + bytes(column_planes_) +
         bytes(row_planes_);
}


namespace {

// Candidates are processed in chunks of this many: the chunk's working arrays (~30 kB)
// stay in L1/L2 with the row arrays. 128 measured 2–3% faster than 64 on the midpoint (AMD
// EPYC VM; 256 no better): fewer per-chunk set-ups (the AVX-512 kernel broadcasts ~40
// constants per call).
constexpr int kChunk = 128;

}  // namespace

// Per-thread working arrays of the fast path: one camera row's candidate pixels with their
// rays and codes as contiguous arrays (triangulation_rows.h: SelectCandidates), and the
// structure-of-arrays of one chunk of them. Each stage is its own loop over the chunk:
// the table lookups of the interpolation are short scalar loops (AVX-512 gathers measured
// no faster on the 2-core machine), the geometry loops read and write only contiguous
// arrays and vectorise; the accepted points go out through triangulation_rows::EmitRow.
struct Triangulator::RowScratch {
  std::vector<int> xs;                           // candidate columns of the row
  std::vector<float> ray_x_row, ray_y_row;       // per candidate, its camera ray
  std::vector<float> coded_u_row, coded_v_row;   // per candidate, decoded (NaN: not coded)
  std::vector<float> point_x, point_y, point_z;  // per candidate, camera frame, metres
  std::vector<float> z_or_nan;                   // EmitRow's scratch
  // 1 accepted, 0 rejected; exact 1: left to the exact per-point path.
  std::vector<uint8_t> ok, exact;
  int count = 0;  // candidates of the row
  triangulation_rows::RowInputs inputs;  // the row they were picked from

  // One chunk: camera ray, decoded coordinates, interpolation state, intermediate results.
  alignas(64) double look_u[kChunk], look_v[kChunk];
  alignas(64) float look_uf[kChunk], look_vf[kChunk];  // the chord's lookups (in float)
  alignas(64) float frac_u[kChunk], frac_v[kChunk];
  alignas(64) int32_t index[kChunk];
  alignas(64) float top[4 * kChunk], bottom[4 * kChunk];  // (a, b) and (c, d) corner pairs
  alignas(64) double out0[kChunk], out1[kChunk], out2[kChunk];
  // Ray–plane: q = r·d_c; two-axis: the point before its tests.
  alignas(64) double q_x[kChunk], q_y[kChunk], q_z[kChunk];
  alignas(64) double landed[kChunk], next[kChunk], numerator[kChunk], denominator[kChunk];
  alignas(64) double chord[4 * kChunk];
  alignas(64) uint8_t inside[kChunk], valid[kChunk], good[kChunk], done[kChunk],
      to_exact[kChunk];
  // Ray–plane: per candidate the projector row (column) predicted from the rows above (NaN:
  // none) and the one its point landed on; the chunk's candidates the prediction failed,
  // compacted (index into the chunk; their inputs and results).
  alignas(64) double predicted[kChunk], landed_row[kChunk], redo_landed[kChunk];
  alignas(64) int32_t redo[kChunk];
  alignas(64) float redo_ray_x[kChunk], redo_ray_y[kChunk], redo_coded[kChunk];
  alignas(64) float redo_x[kChunk], redo_y[kChunk], redo_z[kChunk];
  alignas(64) uint8_t on_grid[kChunk], redo_ok[kChunk], redo_exact[kChunk];
  // Ray–plane, per camera column: the projector row (column) the accepted points of the
  // last two camera rows landed on (NaN: none), and those of the row being made;
  // history_y the camera row of landed_1.
  std::vector<float> landed_1, landed_2, landed_now;
  int history_y = std::numeric_limits<int>::min() / 2;

  // Room for a row of `width` candidates (and the slack of the row functions' 16-lane steps).
  void Resize(size_t width) {
    const size_t n = width + triangulation_rows::kSlack;
    if (xs.size() >= n) return;
    for (std::vector<float>* v : {&ray_x_row, &ray_y_row, &coded_u_row, &coded_v_row, &point_x,
                                  &point_y, &point_z, &z_or_nan}) {
      v->resize(n);
    }
    for (std::vector<uint8_t>* v : {&ok, &exact}) v->resize(n);
    xs.resize(n);
  }

  // Starts camera row y (`width` columns): the last two rows' landings become the history
  // (none unless they were rows y − 1 and y − 2); the new row's are NaN until recorded.
  void StartHistoryRow(int y, int width) {
    constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
    if (landed_now.size() != static_cast<size_t>(width)) {
      for (std::vector<float>* v : {&landed_1, &landed_2, &landed_now}) v->assign(width, kNaN);
    } else if (history_y == y - 1) {
      std::swap(landed_2, landed_1);    // row y − 2
      std::swap(landed_1, landed_now);  // row y − 1; now the oldest, cleared below
    } else {
      std::fill(landed_1.begin(), landed_1.end(), kNaN);
      std::fill(landed_2.begin(), landed_2.end(), kNaN);
    }
    std::fill(landed_now.begin(), landed_now.end(), kNaN);
    history_y = y;
  }
  // The candidates' predicted rows (columns): the landings of the same camera column one
  // and two rows above, extrapolated (NaN unless both are known).
  void Predict(const int* columns, int n, double* out) const {
    if (n > 0 && columns[n - 1] - columns[0] == n - 1) {  // consecutive columns (mostly)
      const float* __restrict l1 = landed_1.data() + columns[0];
      const float* __restrict l2 = landed_2.data() + columns[0];
      for (int i = 0; i < n; ++i) {
        out[i] = 2.0 * static_cast<double>(l1[i]) - static_cast<double>(l2[i]);
      }
      return;
    }
    const float* l1 = landed_1.data();
    const float* l2 = landed_2.data();
    for (int i = 0; i < n; ++i) {
      const int x = columns[i];
      out[i] = 2.0 * static_cast<double>(l1[x]) - static_cast<double>(l2[x]);
    }
  }
};

namespace {

// A projected row (column) further than this from the one the ray–plane's second step
// linearised at leaves the pixel to the exact path, which iterates on. Closer, the chord's
// error is second order in the distance (the plane's curvature times its square): well
// below 1e-6 m of depth for real lenses (calibration_test).
constexpr double kRayPlaneMaxRowShiftPx = 1.0;
// A chord through a predicted row (RayPlaneChunk) is kept when its point lands closer than
// this to that row: its error, second order in the distance, then stays within 1e-6 m of
// the exact path's depth even with a wide-angle projector's distortion (calibration_test;
// at 1 px it reached 4e-6 m there).
constexpr double kPredictedMaxRowShiftPx = 0.1;
// Predictions come only from rows of the same band of this many camera rows (the bands'
// first two rows start from the centre): the rows of a band are one thread's work, so the
// points do not depend on the thread count.
constexpr int kPredictionBandRows = 64;
// Ray–plane steps: the plane at the projector's centre row (column), then at the rows
// (columns) where the previous step's point lands; the plane tables (interpolated
// normals) for all but the last, which takes the exact path's chord from the ray grid.
constexpr int kRayPlaneSteps = 3;

// Free functions with __restrict arrays and every constant in a local: inside a member
// function, stores to the output arrays could alias the tables' cv::Mat headers and GCC
// reloads them per point (and does not vectorise).
struct Pose {
  // proj_from_cam: X_proj = r·X_cam + t (row-major), and r⁻¹ = rᵀ.
  double r[9];
  double t[3];
  double center_in_cam[3];  // −rᵀ·t
};

// A CV_32FC2 table as a plain array: entry (c, r) at data[r·stride + 2c]; width, height ≥ 2.
struct Grid {
  const float* data = nullptr;
  int32_t stride = 0;  // floats per row
  int width = 0, height = 0;
  double max_u = 0, max_v = 0;  // width − 1, height − 1
  explicit Grid(const cv::Mat& table)
      : data(table.ptr<float>(0)),
        stride(static_cast<int32_t>(table.step1())),
        width(table.cols),
        height(table.rows),
        max_u(table.cols - 1),
        max_v(table.rows - 1) {}
};

// Bilinear interpolation in `grid` (the exact path's formula, (1 − f_v)((1 − f_u)a +
// f_u·b) + f_v((1 − f_u)c + f_u·d), in float like the table: twice the lanes, and a
// rounding of ~1e-7 of the normalised coordinate, ~1e-7 m of depth at 1 m) at
// (u[i], v[i]): inside[i] whether the point is on the grid ([0, w − 1] × [0, h − 1],
// false for NaN); off it the value is that at (0, 0) (the caller sends such points to
// the exact path or ignores them).
template <typename T>
void Interpolate(const Grid& grid_in, int n, const T* __restrict u_in,
                 const T* __restrict v_in, Triangulator::RowScratch* w,
                 double* __restrict out0, double* __restrict out1, uint8_t* __restrict inside) {
  const Grid grid = grid_in;
  float* __restrict fu = w->frac_u;
  float* __restrict fv = w->frac_v;
  int32_t* __restrict index = w->index;
  const int last_x = grid.width - 2, last_y = grid.height - 2;
  // In T (float coordinates: twice the lanes; u − ⌊u⌋ is exact in float).
  const T max_u = static_cast<T>(grid.max_u), max_v = static_cast<T>(grid.max_v);
  for (int i = 0; i < n; ++i) {
    const T u0 = u_in[i], v0 = v_in[i];
    const bool in = (u0 >= 0) & (v0 >= 0) & (u0 <= max_u) & (v0 <= max_v);
    const T u = in ? u0 : T(0), v = in ? v0 : T(0);
    const int32_t x0 = std::min(static_cast<int32_t>(u), last_x);
    const int32_t y0 = std::min(static_cast<int32_t>(v), last_y);
    fu[i] = static_cast<float>(u - static_cast<T>(x0));
    fv[i] = static_cast<float>(v - static_cast<T>(y0));
    index[i] = y0 * grid.stride + 2 * x0;
    inside[i] = in;
  }
  float* __restrict top = w->top;
  float* __restrict bottom = w->bottom;
  const float* data = grid.data;
  const int32_t stride = grid.stride;
  // The grid rows the next two camera rows will look up (a camera row moves about one
  // projector row, either way): the bottom-row loads wait on the cache otherwise (without
  // these the path is ~15% slower; two rows ahead instead of one, 2–4% faster).
  for (int i = 0; i < n; i += 4) {
    __builtin_prefetch(data + index[i] + 2 * stride, 0, 3);
    __builtin_prefetch(data + index[i] + 3 * stride, 0, 3);
    __builtin_prefetch(data + index[i] - stride, 0, 3);
    __builtin_prefetch(data + index[i] - 2 * stride, 0, 3);
  }
  for (int i = 0; i < n; ++i) {
    std::memcpy(top + 4 * i, data + index[i], 4 * sizeof(float));
    std::memcpy(bottom + 4 * i, data + index[i] + stride, 4 * sizeof(float));
  }
  for (int i = 0; i < n; ++i) {
    const float a = fu[i], b = fv[i];
    out0[i] = (1 - b) * ((1 - a) * top[4 * i] + a * top[4 * i + 2]) +
              b * ((1 - a) * bottom[4 * i] + a * bottom[4 * i + 2]);
    out1[i] = (1 - b) * ((1 - a) * top[4 * i + 1] + a * top[4 * i + 3]) +
              b * ((1 - a) * bottom[4 * i + 1] + a * bottom[4 * i + 3]);
  }
}

// Undistorted → distorted (Lens::Distort); kRational: k4–k6 present (else the divisor is
// exactly 1 and skipped: the same result).
template <bool kRational>
inline void DistortPoint(const Lens& lens, double x, double y, double* xd, double* yd) {
  const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
  double radial = 1.0 + lens.k1 * r2 + lens.k2 * r4 + lens.k3 * r6;
  if constexpr (kRational) radial /= 1.0 + lens.k4 * r2 + lens.k5 * r4 + lens.k6 * r6;
  *xd = x * radial + 2.0 * lens.p1 * x * y + lens.p2 * (r2 + 2.0 * x * x);
  *yd = y * radial + lens.p1 * (r2 + 2.0 * y * y) + 2.0 * lens.p2 * x * y;
}

// The closest approach of the camera ray X = s·d_c, d_c = (x, y, 1), and the projector ray
// X = C_p + u·d_p, d_p = rᵀ·(ux, uy, 1) (r the projector-from-camera rotation, row-major;
// C_p the projector centre in the camera frame): d_p, a = d_c·d_c, b = d_c·d_p,
// e = d_p·d_p, the denominator D = a·e − b² and the numerators of s = S / D and u = U / D.
struct RayPairConstants {
  double r00, r01, r02, r10, r11, r12, r20, r21, r22;
  double c0, c1, c2;
};
struct ClosestApproach {
  double dpx, dpy, dpz, a, e, denominator, s, u;
  inline ClosestApproach(const RayPairConstants& k, double dcx, double dcy, double ux,
                         double uy) {
    dpx = k.r00 * ux + k.r10 * uy + k.r20;
    dpy = k.r01 * ux + k.r11 * uy + k.r21;
    dpz = k.r02 * ux + k.r12 * uy + k.r22;
    a = dcx * dcx + dcy * dcy + 1.0;
    const double b = dcx * dpx + dcy * dpy + dpz;
    e = dpx * dpx + dpy * dpy + dpz * dpz;
    denominator = a * e - b * b;
    const double dc = dcx * k.c0 + dcy * k.c1 + k.c2;
    const double dp = dpx * k.c0 + dpy * k.c1 + dpz * k.c2;
    s = dc * e - b * dp;
    u = b * dc - a * dp;
  }
};

#if SOPE_TRIANGULATION_AVX512
// TwoAxisKernel's midpoint with the reprojection test, eight points per step in AVX-512
// registers (GCC's vectorisation of that loop spills, re-broadcasts its constants and
// divides; the loop is bound by its ~70 multiplications per step). The same formulas, with
// - e = d_p·d_p = ux² + uy² + 1 and d_p·C_p = −(ux·t_x + uy·t_y + t_z) (r orthonormal);
// - the point doubled, P = 2X' = S·d_c + D·C_p + U·d_p: the projector's homogeneous
//   coordinates are r·P + 2D·t, and with q = 1/(2D·z') the point is X = P·z'·q and the
//   normalised projector coordinates (r·P + 2D·t)·2D·q;
// - q from the 14-bit reciprocal and one Newton step: relative error below 2^-28 (4e-9),
//   under the float output's rounding (6e-8) and ~1e-6 px in the reprojection test;
// - the distortion's r² + 2x² as 3x² + y² (x², y² computed once).
template <bool kRational>
void MidpointReprojectAvx512(int n, const float* __restrict ray_x, const float* __restrict ray_y,
                             const float* __restrict coded_u, const float* __restrict coded_v,
                             const double* __restrict proj_ray_x,
                             const double* __restrict proj_ray_y, const Pose& pose,
                             const Lens& lens, double max_px, double min_depth, double max_depth,
                             float* __restrict out_x, float* __restrict out_y,
                             float* __restrict out_z, uint8_t* __restrict ok) {
  const auto set = [](double v) { return _mm512_set1_pd(v); };
  const __m512d r00 = set(pose.r[0]), r01 = set(pose.r[1]), r02 = set(pose.r[2]);
  const __m512d r10 = set(pose.r[3]), r11 = set(pose.r[4]), r12 = set(pose.r[5]);
  const __m512d r20 = set(pose.r[6]), r21 = set(pose.r[7]), r22 = set(pose.r[8]);
  const __m512d tx = set(pose.t[0]), ty = set(pose.t[1]), tz = set(pose.t[2]);
  const __m512d c0 = set(pose.center_in_cam[0]), c1 = set(pose.center_in_cam[1]),
                c2 = set(pose.center_in_cam[2]);
  const __m512d k1 = set(lens.k1), k2 = set(lens.k2), k3 = set(lens.k3);
  const __m512d k4 = set(lens.k4), k5 = set(lens.k5), k6 = set(lens.k6);
  const __m512d p1 = set(lens.p1), p2 = set(lens.p2), p1x2 = set(2.0 * lens.p1),
                p2x2 = set(2.0 * lens.p2), p1x3 = set(3.0 * lens.p1), p2x3 = set(3.0 * lens.p2);
  const __m512d fx = set(lens.fx), fy = set(lens.fy), cx = set(lens.cx), cy = set(lens.cy);
  const __m512d one = set(1.0), tiny = set(1e-12);
  const __m512d max_px2 = set(max_px * max_px), lo = set(min_depth), hi = set(max_depth);
  const __m128i ones = _mm_set1_epi8(1);
  for (int i = 0; i < n; i += 8) {
    const __mmask8 tail = static_cast<__mmask8>(n - i >= 8 ? 0xFFu : (1u << (n - i)) - 1u);
    const __m512d dcx = _mm512_cvtps_pd(_mm256_maskz_loadu_ps(tail, ray_x + i));
    const __m512d dcy = _mm512_cvtps_pd(_mm256_maskz_loadu_ps(tail, ray_y + i));
    const __m512d ux = _mm512_maskz_loadu_pd(tail, proj_ray_x + i);
    const __m512d uy = _mm512_maskz_loadu_pd(tail, proj_ray_y + i);
    // d_p = rᵀ·(ux, uy, 1); a, b, e, D; the numerators S, U (−d_p·C_p = ux·t_x + …).
    const __m512d dpx = _mm512_fmadd_pd(r00, ux, _mm512_fmadd_pd(r10, uy, r20));
    const __m512d dpy = _mm512_fmadd_pd(r01, ux, _mm512_fmadd_pd(r11, uy, r21));
    const __m512d dpz = _mm512_fmadd_pd(r02, ux, _mm512_fmadd_pd(r12, uy, r22));
    const __m512d a = _mm512_fmadd_pd(dcx, dcx, _mm512_fmadd_pd(dcy, dcy, one));
    const __m512d b = _mm512_fmadd_pd(dcx, dpx, _mm512_fmadd_pd(dcy, dpy, dpz));
    const __m512d e = _mm512_fmadd_pd(ux, ux, _mm512_fmadd_pd(uy, uy, one));
    const __m512d ae = _mm512_mul_pd(a, e);
    const __m512d d = _mm512_fnmadd_pd(b, b, ae);
    const __m512d dc = _mm512_fmadd_pd(dcx, c0, _mm512_fmadd_pd(dcy, c1, c2));
    const __m512d minus_dp = _mm512_fmadd_pd(ux, tx, _mm512_fmadd_pd(uy, ty, tz));
    const __m512d sn = _mm512_fmadd_pd(dc, e, _mm512_mul_pd(b, minus_dp));
    const __m512d un = _mm512_fmadd_pd(b, dc, _mm512_mul_pd(a, minus_dp));
    // P = S·d_c + D·C_p + U·d_p; the projector's r·P + 2D·t.
    const __m512d px = _mm512_fmadd_pd(sn, dcx, _mm512_fmadd_pd(d, c0, _mm512_mul_pd(un, dpx)));
    const __m512d py = _mm512_fmadd_pd(sn, dcy, _mm512_fmadd_pd(d, c1, _mm512_mul_pd(un, dpy)));
    const __m512d pz = _mm512_fmadd_pd(d, c2, _mm512_fmadd_pd(un, dpz, sn));
    const __m512d d2 = _mm512_add_pd(d, d);
    const __m512d xq = _mm512_fmadd_pd(
        r00, px, _mm512_fmadd_pd(r01, py, _mm512_fmadd_pd(r02, pz, _mm512_mul_pd(d2, tx))));
    const __m512d yq = _mm512_fmadd_pd(
        r10, px, _mm512_fmadd_pd(r11, py, _mm512_fmadd_pd(r12, pz, _mm512_mul_pd(d2, ty))));
    const __m512d zq = _mm512_fmadd_pd(
        r20, px, _mm512_fmadd_pd(r21, py, _mm512_fmadd_pd(r22, pz, _mm512_mul_pd(d2, tz))));
    // q = 1/(2D·z'): X = P/(2D) = P·z'·q, normalised projector coordinates (r·P + 2D·t)·2D·q.
    const __m512d dz = _mm512_mul_pd(d2, zq);
    __m512d q = _mm512_rcp14_pd(dz);
    q = _mm512_fmadd_pd(q, _mm512_fnmadd_pd(dz, q, one), q);
    const __m512d to_point = _mm512_mul_pd(zq, q);
    const __m512d to_normalised = _mm512_mul_pd(d2, q);
    const __m512d x = _mm512_mul_pd(xq, to_normalised), y = _mm512_mul_pd(yq, to_normalised);
    // Distortion (DistortPoint, with r² + 2x² = 3x² + y²) and the reprojection error.
    const __m512d xx = _mm512_mul_pd(x, x), yy = _mm512_mul_pd(y, y), xy = _mm512_mul_pd(x, y);
    const __m512d r2 = _mm512_add_pd(xx, yy);
    const __m512d r4 = _mm512_mul_pd(r2, r2), r6 = _mm512_mul_pd(r4, r2);
    __m512d radial =
        _mm512_fmadd_pd(k3, r6, _mm512_fmadd_pd(k2, r4, _mm512_fmadd_pd(k1, r2, one)));
    if constexpr (kRational) {
      radial = _mm512_div_pd(
          radial, _mm512_fmadd_pd(k6, r6, _mm512_fmadd_pd(k5, r4, _mm512_fmadd_pd(k4, r2, one))));
    }
    const __m512d xd = _mm512_fmadd_pd(
        x, radial, _mm512_fmadd_pd(p1x2, xy, _mm512_fmadd_pd(p2x3, xx, _mm512_mul_pd(p2, yy))));
    const __m512d yd = _mm512_fmadd_pd(
        y, radial, _mm512_fmadd_pd(p2x2, xy, _mm512_fmadd_pd(p1x3, yy, _mm512_mul_pd(p1, xx))));
    const __m512d cu = _mm512_cvtps_pd(_mm256_maskz_loadu_ps(tail, coded_u + i));
    const __m512d cv = _mm512_cvtps_pd(_mm256_maskz_loadu_ps(tail, coded_v + i));
    const __m512d ex = _mm512_fmadd_pd(fx, xd, _mm512_sub_pd(cx, cu));
    const __m512d ey = _mm512_fmadd_pd(fy, yd, _mm512_sub_pd(cy, cv));
    const __m512d error2 = _mm512_fmadd_pd(ex, ex, _mm512_mul_pd(ey, ey));
    const __m512d z = _mm512_mul_pd(pz, to_point);
    // As the scalar kernel: |D| ≥ 1e-12·a·e, in front of the projector, the squared error
    // not above max_px² (NaN passes, as there), z in the depth band.
    __mmask8 accept =
        _mm512_mask_cmp_pd_mask(tail, _mm512_abs_pd(d), _mm512_mul_pd(tiny, ae), _CMP_GE_OQ);
    accept = _mm512_mask_cmp_pd_mask(accept, dz, _mm512_setzero_pd(), _CMP_GT_OQ);
    accept = _mm512_mask_cmp_pd_mask(accept, error2, max_px2, _CMP_NGT_UQ);
    accept = _mm512_mask_cmp_pd_mask(accept, z, lo, _CMP_GE_OQ);
    accept = _mm512_mask_cmp_pd_mask(accept, z, hi, _CMP_LE_OQ);
    _mm256_mask_storeu_ps(out_x + i, tail, _mm512_cvtpd_ps(_mm512_mul_pd(px, to_point)));
    _mm256_mask_storeu_ps(out_y + i, tail, _mm512_cvtpd_ps(_mm512_mul_pd(py, to_point)));
    _mm256_mask_storeu_ps(out_z + i, tail, _mm512_cvtpd_ps(z));
    _mm_mask_storeu_epi8(ok + i, tail, _mm_maskz_mov_epi8(accept, ones));
  }
}
#endif

// Both axes coded: the point from the camera ray d_c = (x, y, 1) and the projector ray
// (ux, uy) by the midpoint of closest approach (X = ½(s·d_c + C_p + u·d_p),
// d_p = rᵀ·(ux, uy, 1)) or by the 3×3 normal equations of the linear method (thesis eq.
// 4.1: rows (−1, 0, x_c), (0, −1, y_c), x_p·r₃ − r₁, y_p·r₃ − r₂, b = (0, 0,
// t_x − x_p·t_z, t_y − y_p·t_z), Cramer's rule), then the reprojection test (kReproject:
// in front of the projector, within max_px of the decoded coordinates) and the depth band.
template <bool kLinear, bool kReproject, bool kRational>
void TwoAxisKernel(int n, const float* __restrict ray_x, const float* __restrict ray_y,
                   const float* __restrict coded_u, const float* __restrict coded_v,
                   const double* __restrict proj_ray_x, const double* __restrict proj_ray_y,
                   const Pose& pose, const Lens& lens_in, double max_px, double min_depth,
                   double max_depth, Triangulator::RowScratch* w, float* __restrict out_x,
                   float* __restrict out_y, float* __restrict out_z, uint8_t* __restrict ok) {
  const double r00 = pose.r[0], r01 = pose.r[1], r02 = pose.r[2];
  const double r10 = pose.r[3], r11 = pose.r[4], r12 = pose.r[5];
  const double r20 = pose.r[6], r21 = pose.r[7], r22 = pose.r[8];
  const double tx = pose.t[0], ty = pose.t[1], tz = pose.t[2];
  // Two loops (the point; then the tests), each with few enough live constants to stay in
  // registers.
  double* __restrict point_x = w->q_x;
  double* __restrict point_y = w->q_y;
  double* __restrict point_z = w->q_z;
  uint8_t* __restrict good = w->good;
  if constexpr (!kLinear && kReproject) {
#if SOPE_TRIANGULATION_AVX512
    MidpointReprojectAvx512<kRational>(n, ray_x, ray_y, coded_u, coded_v, proj_ray_x, proj_ray_y,
                                       pose, lens_in, max_px, min_depth, max_depth, out_x, out_y,
                                       out_z, ok);
#else
    // The midpoint and its reprojection in one loop, with one division: the point scaled
    // by the denominator D = a·e − b² is X' = ½(S·d_c + D·C_p + U·d_p) (S, U the
    // numerators of s, u) and its projector depth z' = r₃·X' + D·t_z = D·z_p; with
    // q = 1/(D·z'), 1/D = z'·q and 1/z' = D·q, so X = X'·z'·q and the normalised
    // projector coordinates are (r₁·X' + D·t_x)·D·q etc. (z_p > 0 ⇔ D·z' > 0).
    const double c0 = pose.center_in_cam[0], c1 = pose.center_in_cam[1],
                 c2 = pose.center_in_cam[2];
    const RayPairConstants rays{r00, r01, r02, r10, r11, r12, r20, r21, r22, c0, c1, c2};
    const Lens lens = lens_in;
    const double max_px2 = max_px * max_px;
    for (int i = 0; i < n; ++i) {
      const double dcx = ray_x[i], dcy = ray_y[i];
      const ClosestApproach m(rays, dcx, dcy, proj_ray_x[i], proj_ray_y[i]);
      const double denominator = m.denominator, a = m.a, e = m.e;
      const double px = 0.5 * (m.s * dcx + (denominator * c0 + m.u * m.dpx));
      const double py = 0.5 * (m.s * dcy + (denominator * c1 + m.u * m.dpy));
      const double pz = 0.5 * (m.s + (denominator * c2 + m.u * m.dpz));
      const double xq = r00 * px + r01 * py + r02 * pz + tx * denominator;
      const double yq = r10 * px + r11 * py + r12 * pz + ty * denominator;
      const double zq = r20 * px + r21 * py + r22 * pz + tz * denominator;
      const double dz = denominator * zq;
      const double q = 1.0 / dz;
      const double to_point = zq * q, to_normalised = denominator * q;
      double xd, yd;
      DistortPoint<kRational>(lens, xq * to_normalised, yq * to_normalised, &xd, &yd);
      const double ex = lens.fx * xd + lens.cx - coded_u[i];
      const double ey = lens.fy * yd + lens.cy - coded_v[i];
      const double z = pz * to_point;
      const bool accept = (std::abs(denominator) >= 1e-12 * a * e) & (dz > 0) &
                          !(ex * ex + ey * ey > max_px2);
      out_x[i] = static_cast<float>(px * to_point);
      out_y[i] = static_cast<float>(py * to_point);
      out_z[i] = static_cast<float>(z);
      ok[i] = accept & (z >= min_depth) & (z <= max_depth);
    }
#endif
    return;
  } else if constexpr (!kLinear) {
    const double c0 = pose.center_in_cam[0], c1 = pose.center_in_cam[1],
                 c2 = pose.center_in_cam[2];
    const RayPairConstants rays{r00, r01, r02, r10, r11, r12, r20, r21, r22, c0, c1, c2};
    for (int i = 0; i < n; ++i) {
      const double dcx = ray_x[i], dcy = ray_y[i];
      const ClosestApproach m(rays, dcx, dcy, proj_ray_x[i], proj_ray_y[i]);
      const double inverse = 1.0 / m.denominator;
      const double s = m.s * inverse, u = m.u * inverse;
      point_x[i] = 0.5 * (s * dcx + (c0 + u * m.dpx));
      point_y[i] = 0.5 * (s * dcy + (c1 + u * m.dpy));
      point_z[i] = 0.5 * (s + (c2 + u * m.dpz));
      good[i] = std::abs(m.denominator) >= 1e-12 * m.a * m.e;
    }
  } else {
    for (int i = 0; i < n; ++i) {
      const double dcx = ray_x[i], dcy = ray_y[i];
      const double ux = proj_ray_x[i], uy = proj_ray_y[i];
      const double a20 = ux * r20 - r00, a21 = ux * r21 - r01, a22 = ux * r22 - r02;
      const double a30 = uy * r20 - r10, a31 = uy * r21 - r11, a32 = uy * r22 - r12;
      const double b2 = tx - ux * tz, b3 = ty - uy * tz;
      const double n00 = 1.0 + a20 * a20 + a30 * a30;
      const double n01 = a20 * a21 + a30 * a31;
      const double n02 = -dcx + a20 * a22 + a30 * a32;
      const double n11 = 1.0 + a21 * a21 + a31 * a31;
      const double n12 = -dcy + a21 * a22 + a31 * a32;
      const double n22 = dcx * dcx + dcy * dcy + a22 * a22 + a32 * a32;
      const double g0 = a20 * b2 + a30 * b3, g1 = a21 * b2 + a31 * b3, g2 = a22 * b2 + a32 * b3;
      const double m00 = n11 * n22 - n12 * n12, m01 = n02 * n12 - n01 * n22,
                   m02 = n01 * n12 - n02 * n11;
      const double m11 = n00 * n22 - n02 * n02, m12 = n01 * n02 - n00 * n12,
                   m22 = n00 * n11 - n01 * n01;
      const double inverse = 1.0 / (n00 * m00 + n01 * m01 + n02 * m02);
      point_x[i] = (m00 * g0 + m01 * g1 + m02 * g2) * inverse;
      point_y[i] = (m01 * g0 + m11 * g1 + m12 * g2) * inverse;
      point_z[i] = (m02 * g0 + m12 * g1 + m22 * g2) * inverse;
      good[i] = 1;
    }
  }
  const Lens lens = lens_in;
  const double max_px2 = max_px * max_px;
  for (int i = 0; i < n; ++i) {
    const double px = point_x[i], py = point_y[i], pz = point_z[i];
    bool accept = good[i] != 0;
    if constexpr (kReproject) {
      const double xp = r00 * px + r01 * py + r02 * pz + tx;
      const double yp = r10 * px + r11 * py + r12 * pz + ty;
      const double zp = r20 * px + r21 * py + r22 * pz + tz;
      const double inverse_z = 1.0 / zp;
      double xd, yd;
      DistortPoint<kRational>(lens, xp * inverse_z, yp * inverse_z, &xd, &yd);
      const double ex = lens.fx * xd + lens.cx - coded_u[i];
      const double ey = lens.fy * yd + lens.cy - coded_v[i];
      accept = accept & (zp > 0) & !(ex * ex + ey * ey > max_px2);
    }
    out_x[i] = static_cast<float>(px);
    out_y[i] = static_cast<float>(py);
    out_z[i] = static_cast<float>(pz);
    ok[i] = accept & (pz >= min_depth) & (pz <= max_depth);
  }
}

// One ray–plane step per candidate: the camera ray X_proj = s·q + t (q = r·d_c) meets the
// plane n·X_proj = 0, s = N / D with N = −n·t, D = n·q; the point lands at
// (N·q + D·t) / (N·q_z + D·t_z) (one division), `landed` its projector row (kColumns) or
// column. Valid: the plane is not parallel to the ray, the point is in front of the
// projector, the landing is finite.
template <bool kColumns, bool kRational>
void RayPlaneStep(int n, const Pose& pose, const Lens& lens_in, const double* __restrict qx,
                  const double* __restrict qy, const double* __restrict qz,
                  const double* __restrict nx_in, const double* __restrict ny_in,
                  const double* __restrict nz_in, double* __restrict numerator,
                  double* __restrict denominator, double* __restrict landed,
                  uint8_t* __restrict valid) {
  const Lens lens = lens_in;
  const double tx = pose.t[0], ty = pose.t[1], tz = pose.t[2];
  for (int i = 0; i < n; ++i) {
    const double nx = nx_in[i], ny = ny_in[i], nz = nz_in[i];
    const double d = nx * qx[i] + ny * qy[i] + nz * qz[i];
    const double num = -(nx * tx + ny * ty + nz * tz);
    const double z = num * qz[i] + d * tz;
    const double inverse_z = 1.0 / z;
    double xd, yd;
    DistortPoint<kRational>(lens, (num * qx[i] + d * tx) * inverse_z,
                            (num * qy[i] + d * ty) * inverse_z, &xd, &yd);
    const double l = kColumns ? lens.fy * yd + lens.cy : lens.fx * xd + lens.cx;
    numerator[i] = num;
    denominator[i] = d;
    landed[i] = l;
    valid[i] = (d * d >= 1e-24 * (nx * nx + ny * ny + nz * nz)) & (z * d > 0) &
               (std::abs(l) <= std::numeric_limits<double>::max());
  }
}

// (coded, other) as (u, v) of the tables: u the column, v the row.
template <bool kColumns>
void PlaneTableCoordinates(int n, const float* __restrict coded, const double* __restrict other,
                           double* __restrict u, double* __restrict v) {
  for (int i = 0; i < n; ++i) {
    u[i] = kColumns ? coded[i] : other[i];
    v[i] = kColumns ? other[i] : coded[i];
  }
}

// The plane-table normal from the interpolated (first, second): (1, first, second) for
// columns, (first, 1, second) for rows; into (n0, n1, n2).
template <bool kColumns>
void TableNormal(int n, const double* __restrict first, const double* __restrict second,
                 double* __restrict n0, double* __restrict n1, double* __restrict n2) {
  for (int i = 0; i < n; ++i) {
    const double f = first[i], s = second[i];
    n0[i] = kColumns ? 1.0 : f;
    n1[i] = kColumns ? f : 1.0;
    n2[i] = s;
  }
}

// The plane-table step: the plane at (coded, landed[i]) (column, row for columns) from the
// plane table `planes`, met by the camera rays q (w->q_x …): RayPlaneStep's w->numerator,
// w->denominator, w->next (the row the point lands on) and w->valid; on_grid[i] whether
// (coded, landed) was on the table. The chord step's result within the table's deviation
// from the chord (Triangulator::kPlaneTableMaxDeviationPx), from one lookup instead of two.
template <bool kColumns, bool kRational>
void PlaneStep(int n, const Pose& pose, const Lens& lens, const Grid& planes,
               const float* __restrict coded, const double* __restrict landed,
               Triangulator::RowScratch* w, uint8_t* __restrict on_grid) {
  float* __restrict look_u = w->look_uf;
  float* __restrict look_v = w->look_vf;
  for (int i = 0; i < n; ++i) {
    const float l = static_cast<float>(landed[i]);
    look_u[i] = kColumns ? coded[i] : l;
    look_v[i] = kColumns ? l : coded[i];
  }
  Interpolate(planes, n, look_u, look_v, w, w->chord, w->chord + kChunk, on_grid);
  TableNormal<kColumns>(n, w->chord, w->chord + kChunk, w->out0, w->out1, w->out2);
  RayPlaneStep<kColumns, kRational>(n, pose, lens, w->q_x, w->q_y, w->q_z, w->out0, w->out1,
                                    w->out2, w->numerator, w->denominator, w->next, w->valid);
}

// The chord step: the plane through the projector rays at (coded, landed[i] ± kHalf)
// (rows ± kHalf for columns, columns for rows) from the ray grid with its margin, met by
// the camera rays q (w->q_x …): RayPlaneStep's w->numerator, w->denominator, w->next (the
// row the point lands on) and w->valid; on_grid[i] whether both rays were on the grid.
template <bool kColumns, bool kRational>
void ChordStep(int n, const Pose& pose, const Lens& lens, const Grid& grid,
               const float* __restrict coded, const double* __restrict landed,
               Triangulator::RowScratch* w, uint8_t* __restrict on_grid) {
  // The lookups in float (as the two-axis grid's: twice the lanes): the decoded coordinate
  // and kHalf are exact in it, and rounding the landed row by ~1e-4 px moves the point by
  // the chord's second-order error of that distance, nothing.
  constexpr float kHalf = static_cast<float>(Triangulator::kPlaneHalfSpanPx);
  float* __restrict look_u = w->look_uf;
  float* __restrict look_v = w->look_vf;
  for (int i = 0; i < n; ++i) {
    const float l = static_cast<float>(landed[i]);
    const float u = kColumns ? coded[i] : l, v = kColumns ? l : coded[i];
    look_u[i] = (kColumns ? u : u - kHalf) + kHalf;
    look_v[i] = (kColumns ? v - kHalf : v) + kHalf;
  }
  double* __restrict xa = w->chord;
  double* __restrict ya = w->chord + kChunk;
  double* __restrict xb = w->chord + 2 * kChunk;
  double* __restrict yb = w->chord + 3 * kChunk;
  uint8_t* __restrict inside_a = w->valid;
  uint8_t* __restrict inside_b = w->inside;
  Interpolate(grid, n, look_u, look_v, w, xa, ya, inside_a);
  for (int i = 0; i < n; ++i) {
    const float l = static_cast<float>(landed[i]);
    const float u = kColumns ? coded[i] : l, v = kColumns ? l : coded[i];
    look_u[i] = (kColumns ? u : u + kHalf) + kHalf;
    look_v[i] = (kColumns ? v + kHalf : v) + kHalf;
  }
  Interpolate(grid, n, look_u, look_v, w, xb, yb, inside_b);
  double* __restrict n0 = w->out0;
  double* __restrict n1 = w->out1;
  double* __restrict n2 = w->out2;
  for (int i = 0; i < n; ++i) {
    on_grid[i] = (inside_a[i] != 0) & (inside_b[i] != 0);
    n0[i] = ya[i] - yb[i];
    n1[i] = xb[i] - xa[i];
    n2[i] = xa[i] * yb[i] - ya[i] * xb[i];
  }
  RayPlaneStep<kColumns, kRational>(n, pose, lens, w->q_x, w->q_y, w->q_z, n0, n1, n2,
                                    w->numerator, w->denominator, w->next, w->valid);
}

// Ray–plane's last step (the predicted one, or the last from the centre): PlaneStep on the
// plane table `planes` when `plane_step` (Triangulator::kPlaneTableMaxDeviationPx), else
// ChordStep on the ray grid `grid`.
template <bool kColumns, bool kRational>
void LastStep(int n, const Pose& pose, const Lens& lens, const Grid& planes, const Grid& grid,
              bool plane_step, const float* __restrict coded, const double* __restrict landed,
              Triangulator::RowScratch* w) {
  if (plane_step) {
    PlaneStep<kColumns, kRational>(n, pose, lens, planes, coded, landed, w, w->on_grid);
  } else {
    ChordStep<kColumns, kRational>(n, pose, lens, grid, coded, landed, w, w->on_grid);
  }
}

// The camera rays in the projector's frame, q = r·d_c, into w->q_x, q_y, q_z.
void ProjectorFrameRays(int n, const Pose& pose, const float* __restrict ray_x,
                        const float* __restrict ray_y, Triangulator::RowScratch* w) {
  double* __restrict qx = w->q_x;
  double* __restrict qy = w->q_y;
  double* __restrict qz = w->q_z;
  const double r00 = pose.r[0], r01 = pose.r[1], r02 = pose.r[2];
  const double r10 = pose.r[3], r11 = pose.r[4], r12 = pose.r[5];
  const double r20 = pose.r[6], r21 = pose.r[7], r22 = pose.r[8];
  for (int i = 0; i < n; ++i) {
    const double x = ray_x[i], y = ray_y[i];
    qx[i] = r00 * x + r01 * y + r02;
    qy[i] = r10 * x + r11 * y + r12;
    qz[i] = r20 * x + r21 * y + r22;
  }
}

// One axis coded (kColumns: x): ray–plane as the exact path's re-linearisation — the plane
// at the projector's centre row (column) from the plane table, then at the row where that
// point lands (plane table again, unless it moved < 1e-3 px), then the exact path's chord
// through the row it stopped at, from the ray grid with its margin. Coordinates off the
// tables, and a row still moving ≥ kRayPlaneMaxRowShiftPx after the last step, go to the
// exact path (exact = 1).
template <bool kColumns, bool kRational>
void RayPlaneFromCentre(int n, const Pose& pose, const Lens& lens, const Grid& planes,
                        const Grid& grid, bool plane_step, double min_depth, double max_depth,
                        const float* __restrict ray_x, const float* __restrict ray_y,
                        const float* __restrict coded, Triangulator::RowScratch* w,
                        float* __restrict out_x, float* __restrict out_y,
                        float* __restrict out_z, uint8_t* __restrict ok,
                        uint8_t* __restrict exact, double* __restrict landed_row) {
  static_assert(kRayPlaneSteps == 3, "three steps below");
  const double* __restrict qx = w->q_x;
  const double* __restrict qy = w->q_y;
  const double* __restrict qz = w->q_z;
  double* __restrict landed = w->landed;
  double* __restrict next = w->next;
  double* __restrict n0 = w->out0;
  double* __restrict n1 = w->out1;
  double* __restrict n2 = w->out2;
  uint8_t* __restrict inside = w->inside;
  uint8_t* __restrict valid = w->valid;
  uint8_t* __restrict good = w->good;
  uint8_t* __restrict done = w->done;
  uint8_t* __restrict to_exact = w->to_exact;
  ProjectorFrameRays(n, pose, ray_x, ray_y, w);
  const double start = kColumns ? lens.cy : lens.cx;
  for (int i = 0; i < n; ++i) landed[i] = start;
  // Step 1: the plane table at the centre row.
  PlaneTableCoordinates<kColumns>(n, coded, landed, w->look_u, w->look_v);
  Interpolate(planes, n, w->look_u, w->look_v, w, w->chord, w->chord + kChunk, inside);
  TableNormal<kColumns>(n, w->chord, w->chord + kChunk, n0, n1, n2);
  RayPlaneStep<kColumns, kRational>(n, pose, lens, qx, qy, qz, n0, n1, n2, w->numerator,
                                    w->denominator, next, valid);
  for (int i = 0; i < n; ++i) {
    const bool active = inside[i] != 0;
    const bool v = valid[i] != 0;
    to_exact[i] = !active;
    good[i] = !active | v;
    const bool moved = !(std::abs(next[i] - landed[i]) < 1e-3);
    done[i] = active & v & !moved;
    landed[i] = (active & v & moved) ? next[i] : landed[i];
  }
  // Step 2: the plane table at the landed row, for those still moving.
  PlaneTableCoordinates<kColumns>(n, coded, landed, w->look_u, w->look_v);
  Interpolate(planes, n, w->look_u, w->look_v, w, w->chord, w->chord + kChunk, inside);
  TableNormal<kColumns>(n, w->chord, w->chord + kChunk, n0, n1, n2);
  RayPlaneStep<kColumns, kRational>(n, pose, lens, qx, qy, qz, n0, n1, n2, w->numerator,
                                    w->denominator, next, valid);
  for (int i = 0; i < n; ++i) {
    const bool g = good[i] != 0, d = done[i] != 0, v = valid[i] != 0;
    const bool e = (to_exact[i] != 0) | (g & !d & (inside[i] == 0));
    const bool active = g & !d & !e;
    to_exact[i] = e;
    good[i] = g & (!active | v);
    const bool moved = !(std::abs(next[i] - landed[i]) < 1e-3);
    done[i] = d | (active & v & !moved);
    landed[i] = (active & v & moved) ? next[i] : landed[i];
  }
  // Step 3: the chord through the row it stopped at (the plane table's plane there).
  LastStep<kColumns, kRational>(n, pose, lens, planes, grid, plane_step, coded, landed, w);
  for (int i = 0; i < n; ++i) {
    to_exact[i] = (to_exact[i] != 0) | ((good[i] != 0) & (w->on_grid[i] == 0));
  }
  const double* __restrict num = w->numerator;
  const double* __restrict den = w->denominator;
  for (int i = 0; i < n; ++i) {
    const bool g = good[i] != 0, v = valid[i] != 0, e = to_exact[i] != 0;
    const bool active = g & !e;
    const bool kept = g & (!active | v);
    const bool still_moving =
        active & v & (done[i] == 0) & !(std::abs(next[i] - landed[i]) < kRayPlaneMaxRowShiftPx);
    const double s = num[i] / den[i];
    out_x[i] = static_cast<float>(s * ray_x[i]);
    out_y[i] = static_cast<float>(s * ray_y[i]);
    out_z[i] = static_cast<float>(s);
    ok[i] = kept & (s >= min_depth) & (s <= max_depth);
    exact[i] = e | still_moving;
    landed_row[i] = next[i];
  }
}

// One axis coded, with predicted rows (columns): where the rows above give a prediction
// (`predicted`, NaN: none), the chord through the predicted row at once (`plane_step`: the
// plane table's plane there, PlaneStep) — kept when its point lands within
// kPredictedMaxRowShiftPx of it (the chord's error is second order in that distance) — and
// RayPlaneFromCentre for the others. landed_row: the row each point landed on.
template <bool kColumns, bool kRational>
void RayPlaneChunk(int n, const Pose& pose, const Lens& lens, const Grid& planes,
                   const Grid& grid, bool plane_step, double min_depth, double max_depth,
                   const float* __restrict ray_x, const float* __restrict ray_y,
                   const float* __restrict coded, const double* __restrict predicted,
                   Triangulator::RowScratch* w, float* __restrict out_x,
                   float* __restrict out_y, float* __restrict out_z, uint8_t* __restrict ok,
                   uint8_t* __restrict exact, double* __restrict landed_row) {
  double* __restrict landed = w->landed;
  const double fallback = kColumns ? lens.cy : lens.cx;
  int predictions = 0;
  for (int i = 0; i < n; ++i) {
    const bool known = std::abs(predicted[i]) <= std::numeric_limits<double>::max();
    landed[i] = known ? predicted[i] : fallback;
    predictions += known;
  }
  int32_t* __restrict redo = w->redo;
  int redo_count = 0;
  if (predictions > 0) {
    ProjectorFrameRays(n, pose, ray_x, ray_y, w);
    LastStep<kColumns, kRational>(n, pose, lens, planes, grid, plane_step, coded, landed, w);
    const double* __restrict num = w->numerator;
    const double* __restrict den = w->denominator;
    const double* __restrict next = w->next;
    const uint8_t* __restrict valid = w->valid;
    const uint8_t* __restrict on_grid = w->on_grid;
    uint8_t* __restrict fine = w->good;
    for (int i = 0; i < n; ++i) {
      const bool known = std::abs(predicted[i]) <= std::numeric_limits<double>::max();
      const bool f = known & (valid[i] != 0) & (on_grid[i] != 0) &
                     (std::abs(next[i] - landed[i]) < kPredictedMaxRowShiftPx);
      const double s = num[i] / den[i];
      out_x[i] = static_cast<float>(s * ray_x[i]);
      out_y[i] = static_cast<float>(s * ray_y[i]);
      out_z[i] = static_cast<float>(s);
      ok[i] = f & (s >= min_depth) & (s <= max_depth);
      exact[i] = 0;
      landed_row[i] = next[i];
      fine[i] = f;
    }
    if (std::memchr(fine, 0, static_cast<size_t>(n)) != nullptr) {
      for (int i = 0; i < n; ++i) {
        redo[redo_count] = i;
        redo_count += fine[i] == 0;
      }
    }
  } else {
    for (int i = 0; i < n; ++i) redo[i] = i;
    redo_count = n;
  }
  if (redo_count == 0) return;
  if (redo_count == n) {
    RayPlaneFromCentre<kColumns, kRational>(n, pose, lens, planes, grid, plane_step, min_depth,
                                            max_depth, ray_x, ray_y, coded, w, out_x, out_y,
                                            out_z, ok, exact, landed_row);
    return;
  }
  for (int j = 0; j < redo_count; ++j) {
    const int i = redo[j];
    w->redo_ray_x[j] = ray_x[i];
    w->redo_ray_y[j] = ray_y[i];
    w->redo_coded[j] = coded[i];
  }
  RayPlaneFromCentre<kColumns, kRational>(redo_count, pose, lens, planes, grid, plane_step,
                                          min_depth, max_depth, w->redo_ray_x, w->redo_ray_y,
                                          w->redo_coded, w, w->redo_x, w->redo_y, w->redo_z,
                                          w->redo_ok, w->redo_exact, w->redo_landed);
  for (int j = 0; j < redo_count; ++j) {
    const int i = redo[j];
    out_x[i] = w->redo_x[j];
    out_y[i] = w->redo_y[j];
    out_z[i] = w->redo_z[j];
    ok[i] = w->redo_ok[j];
    exact[i] = w->redo_exact[j];
    landed_row[i] = w->redo_landed[j];
  }
}

// Colours of the accepted candidates of camera row y into `out` (grey or BGR → RGB).
void GatherColors(const cv::Mat& white, int y, const int* xs, const uint8_t* ok, int n,
                  Color3ub* out) {
  size_t k = 0;
  if (white.type() == CV_8UC3) {
    const cv::Vec3b* row = white.ptr<cv::Vec3b>(y);
    for (int i = 0; i < n; ++i) {
      const cv::Vec3b bgr = row[xs[i]];
      out[k] = Color3ub(bgr[2], bgr[1], bgr[0]);
      k += ok[i];
    }
  } else if (white.type() == CV_16UC1) {
    const uint16_t* row = white.ptr<uint16_t>(y);
    for (int i = 0; i < n; ++i) {
      const uint8_t grey = static_cast<uint8_t>(row[xs[i]] >> 8);
      out[k] = Color3ub(grey, grey, grey);
      k += ok[i];
    }
  } else {
    const uint8_t* row = white.ptr<uint8_t>(y);
    for (int i = 0; i < n; ++i) {
      const uint8_t grey = row[xs[i]];
      out[k] = Color3ub(grey, grey, grey);
      k += ok[i];
    }
  }
}

}  // namespace

void Triangulator::TriangulateRow(const CorrespondenceMap& map, const uint8_t* region_row,
                                  int x_begin, int x_end, int y, RowScratch* scratch) const {
  RowScratch& w = *scratch;
  const uint8_t* mask = map.mask.ptr<uint8_t>(y);
  const float* map_x = map.HasX() ? map.proj_x.ptr<float>(y) : nullptr;
  const float* map_y = map.HasY() ? map.proj_y.ptr<float>(y) : nullptr;
  const float* rays = camera_rays_.ptr<float>(y);
  w.Resize(static_cast<size_t>(camera_rays_.cols));
  triangulation_rows::RowInputs& inputs = w.inputs;
  inputs.mask = mask;
  inputs.region = region_row;
  inputs.rays = rays;
  inputs.map_x = map_x;
  inputs.map_y = map_y;
  inputs.x_begin = x_begin;
  inputs.x_end = x_end;
  const bool last_row = y + 1 >= map.mask.rows;
  inputs.next_mask = last_row ? nullptr : map.mask.ptr<uint8_t>(y + 1);
  inputs.next_rays = last_row ? nullptr : camera_rays_.ptr<float>(y + 1);
  inputs.next_map_x = last_row || map_x == nullptr ? nullptr : map.proj_x.ptr<float>(y + 1);
  inputs.next_map_y = last_row || map_y == nullptr ? nullptr : map.proj_y.ptr<float>(y + 1);
  if ((map_x == nullptr) != (map_y == nullptr)) w.StartHistoryRow(y, camera_rays_.cols);
  const int n = triangulation_rows::SelectCandidates(inputs, w.xs.data(), w.ray_x_row.data(),
                                                     w.ray_y_row.data(), w.coded_u_row.data(),
                                                     w.coded_v_row.data());
  w.count = n;
  if (n == 0) return;
  if (!fast_tables_) {
    // Tables too small to interpolate in (a projector 1 pixel wide): all exact.
    std::fill(w.exact.begin(), w.exact.begin() + n, uint8_t{1});
    return;
  }

  Pose pose;
  for (int k = 0; k < 9; ++k) pose.r[k] = calibration_.proj_from_cam.rotation(k / 3, k % 3);
  for (int k = 0; k < 3; ++k) {
    pose.t[k] = calibration_.proj_from_cam.translation[k];
    pose.center_in_cam[k] = projector_center_in_cam_[k];
  }
  const Lens lens(calibration_.projector);
  const bool rational = lens.k4 != 0.0 || lens.k5 != 0.0 || lens.k6 != 0.0;
  const double min_depth = options_.min_depth, max_depth = options_.max_depth;
  const double max_px = options_.max_reprojection_px;
  const bool linear = options_.method == TriangulationMethod::kLinear;
  const bool reproject = max_px > 0;
  const bool two_axes = map_x != nullptr && map_y != nullptr;
  const bool columns = map_x != nullptr;
  const Grid projector_grid(projector_rays_);
  const Grid planes(columns ? column_planes_ : row_planes_);
  const Grid margin_grid(projector_rays_with_margin_);
  const bool plane_step = (columns ? column_plane_deviation_px_ : row_plane_deviation_px_) <=
                          kPlaneTableMaxDeviationPx;
  for (int begin = 0; begin < n; begin += kChunk) {
    const int m = std::min(kChunk, n - begin);
    // The chunk's camera rays and decoded coordinates.
    const float* ray_x = w.ray_x_row.data() + begin;
    const float* ray_y = w.ray_y_row.data() + begin;
    const float* coded_u = w.coded_u_row.data() + begin;
    const float* coded_v = w.coded_v_row.data() + begin;
    float* px = w.point_x.data() + begin;
    float* py = w.point_y.data() + begin;
    float* pz = w.point_z.data() + begin;
    uint8_t* ok = w.ok.data() + begin;
    uint8_t* exact = w.exact.data() + begin;
    if (two_axes) {
      // The projector ray, bilinear in the grid; coordinates off it to the exact path.
      Interpolate(projector_grid, m, coded_u, coded_v, &w, w.out0, w.out1, w.inside);
      for (int i = 0; i < m; ++i) exact[i] = w.inside[i] == 0;
#define SOPE_TWO_AXIS(L, R, Q)                                                                \
  TwoAxisKernel<L, R, Q>(m, ray_x, ray_y, coded_u, coded_v, w.out0, w.out1, pose,            \
                         lens, max_px, min_depth, max_depth, &w, px, py, pz, ok)
      if (linear) {
        if (!reproject) SOPE_TWO_AXIS(true, false, false);
        else if (rational) SOPE_TWO_AXIS(true, true, true);
        else SOPE_TWO_AXIS(true, true, false);
      } else {
        if (!reproject) SOPE_TWO_AXIS(false, false, false);
        else if (rational) SOPE_TWO_AXIS(false, true, true);
        else SOPE_TWO_AXIS(false, true, false);
      }
#undef SOPE_TWO_AXIS
      continue;
    }
    if (y % kPredictionBandRows >= 2) {
      w.Predict(w.xs.data() + begin, m, w.predicted);
    } else {
      std::fill(w.predicted, w.predicted + m, std::numeric_limits<double>::quiet_NaN());
    }
#define SOPE_RAY_PLANE(C, R)                                                                 \
  RayPlaneChunk<C, R>(m, pose, lens, planes, margin_grid, plane_step, min_depth, max_depth,  \
                      ray_x, ray_y, columns ? coded_u : coded_v, w.predicted, &w, px, py,    \
                      pz, ok, exact, w.landed_row)
    if (columns) {
      if (rational) SOPE_RAY_PLANE(true, true);
      else SOPE_RAY_PLANE(true, false);
    } else {
      if (rational) SOPE_RAY_PLANE(false, true);
      else SOPE_RAY_PLANE(false, false);
    }
#undef SOPE_RAY_PLANE
    // The landings of the accepted points for the rows below (each column once per row;
    // the row's entries start NaN). Mostly the chunk's columns are consecutive.
    const int* columns_of = w.xs.data() + begin;
    const double* landed_row = w.landed_row;
    constexpr float kNaNf = std::numeric_limits<float>::quiet_NaN();
    if (columns_of[m - 1] - columns_of[0] == m - 1) {
      float* __restrict to = w.landed_now.data() + columns_of[0];
      for (int i = 0; i < m; ++i) {
        to[i] = (ok[i] != 0) & (exact[i] == 0) ? static_cast<float>(landed_row[i]) : kNaNf;
      }
    } else {
      float* landed_now = w.landed_now.data();
      for (int i = 0; i < m; ++i) {
        landed_now[columns_of[i]] =
            (ok[i] != 0) & (exact[i] == 0) ? static_cast<float>(landed_row[i]) : kNaNf;
      }
    }
  }
}

TriangulationResult Triangulator::Triangulate(const CorrespondenceMap& map,
                                              const cv::Mat& white) const {
  return Triangulate(map, white, TriangulationRegion());
}

TriangulationResult Triangulator::Triangulate(const CorrespondenceMap& map, const cv::Mat& white,
                                              const TriangulationRegion& region) const {
  triangulation_rows::CheckInputs(calibration_, map, white);
  const CameraModel& camera = calibration_.camera;
  const int height = camera.height, width = camera.width;
  SOPE_CHECK(region.mask.empty() || (region.mask.type() == CV_8UC1 &&
                                     region.mask.cols == width && region.mask.rows == height),
             "triangulation region mask must be CV_8UC1 {}x{} (the camera size)", width, height);
  const cv::Rect image(0, 0, width, height);
  const cv::Rect roi = region.roi.empty() ? image : (region.roi & image);
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  TriangulationResult result;
  result.depth.create(height, width, CV_32FC1);
  if (roi.empty()) {
    result.depth.setTo(cv::Scalar(kNaN));
    return result;
  }
  // Rows outside the region's rows: no points (its rows are filled by the blocks).
  if (roi.y > 0) result.depth.rowRange(0, roi.y).setTo(cv::Scalar(kNaN));
  if (roi.y + roi.height < height) {
    result.depth.rowRange(roi.y + roi.height, height).setTo(cv::Scalar(kNaN));
  }

  // Rows are split into contiguous blocks (in parallel when asked). Each block writes its
  // points straight into the output from an offset: the decoded pixels of the rows before
  // it (an upper bound of their points); the gaps that rejected pixels leave are closed
  // afterwards, so the output is in row order and the same for any thread count.
  const int num_blocks = options_.num_threads > 1 ? std::min(roi.height, 2 * options_.num_threads)
                                                  : 1;
  std::vector<int> block_begin(num_blocks + 1);
  for (int b = 0; b <= num_blocks; ++b) {
    block_begin[b] = roi.y + static_cast<int>(static_cast<int64_t>(roi.height) * b / num_blocks);
    // Inner boundaries on the ray–plane prediction's bands (its rows predict from the rows
    // above in the same band: a band is one block's).
    if (b > 0 && b < num_blocks) {
      block_begin[b] = std::max(roi.y, block_begin[b] / kPredictionBandRows * kPredictionBandRows);
    }
  }
  std::vector<size_t> offset(num_blocks + 1, 0), accepted(num_blocks, 0),
      rejected(num_blocks, 0);
  for (int b = 0; b < num_blocks; ++b) {
    const cv::Rect rows(roi.x, block_begin[b], roi.width, block_begin[b + 1] - block_begin[b]);
    offset[b + 1] =
        offset[b] + (rows.empty() ? 0 : static_cast<size_t>(cv::countNonZero(map.mask(rows))));
  }
  const size_t capacity = offset[num_blocks];
  result.cloud.points.resize(capacity);
  result.pixels.resize(capacity);
  const bool colour = !white.empty();
  if (colour) result.cloud.colors.resize(capacity);
  Eigen::Vector3f* points = result.cloud.points.data();
  cv::Point* pixels = result.pixels.data();
  Color3ub* colors = colour ? result.cloud.colors.data() : nullptr;

  const auto run_blocks = [&](const cv::Range& range) {
    RowScratch w;
    for (int b = range.start; b < range.end; ++b) {
      size_t k = offset[b];
      for (int y = block_begin[b]; y < block_begin[b + 1]; ++y) {
        const uint8_t* region_row = region.mask.empty() ? nullptr : region.mask.ptr<uint8_t>(y);
        float* depth = result.depth.ptr<float>(y);
        std::fill(depth, depth + roi.x, kNaN);
        std::fill(depth + roi.x + roi.width, depth + width, kNaN);
        TriangulateRow(map, region_row, roi.x, roi.x + roi.width, y, &w);
        const int n = w.count;
        const int* xs = w.xs.data();
        float* px = w.point_x.data();
        float* py = w.point_y.data();
        float* pz = w.point_z.data();
        uint8_t* ok = w.ok.data();
        // The rare candidates left to the exact path.
        const uint8_t* exact = w.exact.data();
        const float* map_x = w.inputs.map_x;  // the row's codes (nullptr: axis not coded)
        const float* map_y = w.inputs.map_y;
        const void* first_exact = n > 0 ? std::memchr(exact, 1, static_cast<size_t>(n)) : nullptr;
        const int exact_from =
            first_exact ? static_cast<int>(static_cast<const uint8_t*>(first_exact) - exact) : n;
        for (int i = exact_from; i < n; ++i) {
          if (exact[i] == 0) continue;
          const int x = xs[i];
          const std::optional<Eigen::Vector3d> point =
              Intersect(CameraRay(x, y), map_x ? map_x[x] : kNaN, map_y ? map_y[x] : kNaN);
          ok[i] = point.has_value();
          if (point) {
            px[i] = static_cast<float>(point->x());
            py[i] = static_cast<float>(point->y());
            pz[i] = static_cast<float>(point->z());
          }
        }
        if (colour) GatherColors(white, y, xs, ok, n, colors + k);
        const int kept = triangulation_rows::EmitRow(w.inputs, y, xs, px, py, pz, ok, n,
                                                     w.z_or_nan.data(), points + k, pixels + k,
                                                     depth);
        rejected[b] += static_cast<size_t>(n - kept);
        k += static_cast<size_t>(kept);
      }
      accepted[b] = k - offset[b];
    }
  };
  if (num_blocks > 1) {
    const ScopedCvThreads threads(options_.num_threads);
    cv::parallel_for_(cv::Range(0, num_blocks), run_blocks);
  } else {
    run_blocks(cv::Range(0, 1));
  }
  size_t total = 0;
  for (int b = 0; b < num_blocks; ++b) {
    if (offset[b] != total && accepted[b] > 0) {
      // Moves down (total < offset[b]): std::copy is right for the overlap.
      std::copy(points + offset[b], points + offset[b] + accepted[b], points + total);
      std::copy(pixels + offset[b], pixels + offset[b] + accepted[b], pixels + total);
      if (colour) std::copy(colors + offset[b], colors + offset[b] + accepted[b], colors + total);
    }
    total += accepted[b];
    result.rejected += rejected[b];
  }
  result.cloud.points.resize(total);
  result.pixels.resize(total);
  if (colour) result.cloud.colors.resize(total);
  return result;
}

TriangulationResult Triangulate(const CorrespondenceMap& map,
                                const RigCalibration& calibration, const cv::Mat& white,
                                const TriangulationOptions& options) {
  return Triangulator(calibration, options).Triangulate(map, white);
}

}  // namespace sope
