#include "simulator/board_sequence.h"

#include <cmath>
#include <filesystem>
#include <random>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/json.h"
#include "simulator/primitives.h"

namespace sope {
namespace internal {
namespace {

constexpr const char* kTrueCalibrationFile = "calibration_true.yaml";
constexpr const char* kPosesFile = "gt_board_poses.json";
// Points sampled along each edge of the board outline for the in-image test (lens
// distortion bends the edges).
constexpr int kOutlineSamplesPerEdge = 12;

// The outline of the squares plus half the margin, board frame.
std::vector<Eigen::Vector3d> OutlineInBoard(const BoardSpec& board,
                                            const BoardSequenceOptions& options) {
  const double s = board.square_size, pad = 0.5 * options.margin_squares * s;
  const double x0 = -s - pad, x1 = board.cols * s + pad;
  const double y0 = -s - pad, y1 = board.rows * s + pad;
  std::vector<Eigen::Vector3d> outline;
  for (int i = 0; i < kOutlineSamplesPerEdge; ++i) {
    const double t = static_cast<double>(i) / kOutlineSamplesPerEdge;
    outline.emplace_back(x0 + t * (x1 - x0), y0, 0.0);
    outline.emplace_back(x1, y0 + t * (y1 - y0), 0.0);
    outline.emplace_back(x1 - t * (x1 - x0), y1, 0.0);
    outline.emplace_back(x0, y1 - t * (y1 - y0), 0.0);
  }
  return outline;
}

// Whether the board's front faces a device at `device_from_board` within max_view_angle
// of the ray to its centre.
bool Faces(const Rigid3d& device_from_board, const Eigen::Vector3d& center_in_board,
           const BoardSequenceOptions& options) {
  const Eigen::Vector3d center = device_from_board * center_in_board;
  const Eigen::Vector3d normal = device_from_board.rotation.col(2);  // away from the front
  return normal.dot(center.normalized()) >= std::cos(options.max_view_angle);
}

// Whether `point` (device frame) images inside the device with the border.
bool InImage(const CameraModel& device, const Eigen::Vector3d& point, double border) {
  if (point.z() <= 0.05) return false;
  // Far outside the field, distortion polynomials fold back: test the direction first.
  const double x = point.x() / point.z(), y = point.y() / point.z();
  if (std::abs(x) > 1.5 || std::abs(y) > 1.5) return false;
  const Eigen::Vector2d pixel = device.ImageFromCam(point);
  return pixel.x() >= border && pixel.y() >= border && pixel.x() <= device.width - 1 - border &&
         pixel.y() <= device.height - 1 - border;
}

// A partial view: both devices faced, the fraction of inner corners outside the camera
// image in [min_out_of_view, max_out_of_view], and every corner inside it also inside the
// projector's image.
bool SeesPart(const RigCalibration& calibration, const BoardSpec& board,
              const Rigid3d& cam_from_board, const Eigen::Vector3d& center_in_board,
              const BoardSequenceOptions& options) {
  const Rigid3d proj_from_board = calibration.proj_from_cam * cam_from_board;
  if (!Faces(cam_from_board, center_in_board, options) ||
      !Faces(proj_from_board, center_in_board, options)) {
    return false;
  }
  int outside = 0;
  for (const Eigen::Vector3d& corner : board.CornersInBoard()) {
    if (!InImage(calibration.camera, cam_from_board * corner, options.min_border_px)) {
      ++outside;
    } else if (!InImage(calibration.projector, proj_from_board * corner, options.min_border_px)) {
      return false;
    }
  }
  const double fraction = static_cast<double>(outside) / board.NumCorners();
  return fraction >= options.min_out_of_view && fraction <= options.max_out_of_view;
}

// Whether a device at `device_from_board` sees the whole outline inside its image with
// the border, and the board's front within max_view_angle of the ray to its centre.
bool Sees(const CameraModel& device, const Rigid3d& device_from_board,
          const std::vector<Eigen::Vector3d>& outline, const Eigen::Vector3d& center_in_board,
          const BoardSequenceOptions& options) {
  const Eigen::Vector3d center = device_from_board * center_in_board;
  const Eigen::Vector3d normal = device_from_board.rotation.col(2);  // away from the front
  // The device sees the front when the normal points away from it: normal · center > 0.
  const double cos_angle = normal.dot(center.normalized());
  if (cos_angle < std::cos(options.max_view_angle)) return false;
  const double border = options.min_border_px;
  for (const Eigen::Vector3d& point_in_board : outline) {
    const Eigen::Vector3d point = device_from_board * point_in_board;
    if (point.z() <= 0.05) return false;
    // Far outside the field, distortion polynomials fold back: test the direction first.
    const double x = point.x() / point.z(), y = point.y() / point.z();
    if (std::abs(x) > 2.0 || std::abs(y) > 2.0) return false;
    const Eigen::Vector2d pixel = device.ImageFromCam(point);
    if (!(pixel.x() >= border && pixel.y() >= border && pixel.x() <= device.width - 1 - border &&
          pixel.y() <= device.height - 1 - border)) {
      return false;
    }
  }
  return true;
}

}  // namespace
}  // namespace internal

void BoardSequenceOptions::Check() const {
  // A calibration uses 10–50 views; each is a whole frame set on disk.
  constexpr int kMaxViews = 1000;
  SOPE_CHECK(num_views >= 1 && num_views <= kMaxViews,
             "board sequence: num_views must be in [1, {}], got {}", kMaxViews, num_views);
  SOPE_CHECK(min_distance > 0 && max_distance >= min_distance,
             "board sequence: distance range [{}, {}] m is invalid", min_distance, max_distance);
  SOPE_CHECK(min_tilt >= 0 && max_tilt >= min_tilt && max_tilt < M_PI / 2,
             "board sequence: need 0 <= min_tilt <= max_tilt < 90 degrees, got [{}, {}]",
             min_tilt * 180.0 / M_PI, max_tilt * 180.0 / M_PI);
  SOPE_CHECK(max_roll >= 0 && max_roll <= M_PI,
             "board sequence: max_roll must be in [0, 180] "
             "degrees, got {}",
             max_roll * 180.0 / M_PI);
  SOPE_CHECK(max_view_angle > 0 && max_view_angle < M_PI / 2,
             "board sequence: max_view_angle must be in (0, 90) degrees");
  SOPE_CHECK(min_border_px >= 0, "board sequence: min_border_px must be >= 0");
  SOPE_CHECK(black_albedo >= 0 && white_albedo <= 1 && black_albedo < white_albedo,
             "board sequence: need 0 <= black_albedo < white_albedo <= 1, got {} and {}",
             black_albedo, white_albedo);
  SOPE_CHECK(margin_squares >= 0, "board sequence: margin_squares must be >= 0");
  SOPE_CHECK(partial_fraction >= 0 && partial_fraction <= 1,
             "board sequence: partial_fraction must be in [0, 1], got {}", partial_fraction);
  SOPE_CHECK(min_out_of_view > 0 && max_out_of_view >= min_out_of_view && max_out_of_view < 1,
             "board sequence: need 0 < min_out_of_view <= max_out_of_view < 1, got [{}, {}]",
             min_out_of_view, max_out_of_view);
  SOPE_CHECK(max_attempts_per_view >= 1, "board sequence: max_attempts_per_view must be >= 1");
  patterns.Check();
}

bool IsPartialBoardView(const BoardSequenceOptions& options, int index) {
  return std::floor((index + 1) * options.partial_fraction) >
         std::floor(index * options.partial_fraction);
}

SceneObject MakeCheckerboardObject(const BoardSpec& board, const Rigid3d& cam_from_board,
                                   const BoardSequenceOptions& options) {
  board.Check();
  const double s = board.square_size, margin = options.margin_squares * s;
  SceneObject object;
  // Faces point to −z (MakePlane): the printed front faces a camera looking along +z.
  object.mesh = MakePlane((board.cols + 1) * s + 2 * margin, (board.rows + 1) * s + 2 * margin, 4);
  object.mesh.Transform(
      1.0, Eigen::Vector3d(0.5 * (board.cols - 1) * s, 0.5 * (board.rows - 1) * s, 0.0));
  object.cam_from_model = cam_from_board;
  const int cols = board.cols, rows = board.rows;
  const double black = options.black_albedo, white = options.white_albedo;
  object.albedo_map = [s, cols, rows, black, white](const Eigen::Vector3d& point) {
    // Square (i, j), i in [0, cols], j in [0, rows]; square (0, 0) lies diagonally outside
    // corner 0 and is black.
    const int i = static_cast<int>(std::floor(point.x() / s)) + 1;
    const int j = static_cast<int>(std::floor(point.y() / s)) + 1;
    if (i < 0 || j < 0 || i > cols || j > rows) return white;
    return (i + j) % 2 == 0 ? black : white;
  };
  return object;
}

std::vector<Rigid3d> SampleBoardPoses(const RigCalibration& calibration, const BoardSpec& board,
                                      const BoardSequenceOptions& options) {
  calibration.Check();
  board.Check();
  options.Check();
  std::mt19937_64 engine(options.seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const auto uniform = [&](double lo, double hi) { return lo + (hi - lo) * unit(engine); };
  const CameraModel& camera = calibration.camera;
  // The camera's undistorted field (corners of the image, roughly).
  const double min_u = -camera.cx() / camera.fx(),
               max_u = (camera.width - camera.cx()) / camera.fx();
  const double min_v = -camera.cy() / camera.fy(),
               max_v = (camera.height - camera.cy()) / camera.fy();
  const Eigen::Vector3d center_in_board(0.5 * (board.cols - 1) * board.square_size,
                                        0.5 * (board.rows - 1) * board.square_size, 0.0);
  const std::vector<Eigen::Vector3d> outline = internal::OutlineInBoard(board, options);
  std::vector<Rigid3d> poses;
  for (int view = 0; view < options.num_views; ++view) {
    const bool partial = IsPartialBoardView(options, view);
    bool found = false;
    for (int attempt = 0; attempt < options.max_attempts_per_view && !found; ++attempt) {
      const double depth = uniform(options.min_distance, options.max_distance);
      // A partial view's centre may lie up to half the board beyond the field.
      const double reach_u =
          partial ? 0.5 * (board.cols + 1) * board.square_size / depth : 0.0;
      const double reach_v =
          partial ? 0.5 * (board.rows + 1) * board.square_size / depth : 0.0;
      const Eigen::Vector3d center_in_cam =
          depth * Eigen::Vector3d(uniform(min_u - reach_u, max_u + reach_u),
                                  uniform(min_v - reach_v, max_v + reach_v), 1.0);
      const double tilt = uniform(options.min_tilt, options.max_tilt);
      const double direction = uniform(-M_PI, M_PI);
      const Eigen::Matrix3d rotation =
          (Eigen::AngleAxisd(uniform(-options.max_roll, options.max_roll),
                             Eigen::Vector3d::UnitZ()) *
           Eigen::AngleAxisd(tilt, Eigen::Vector3d(std::cos(direction), std::sin(direction), 0)))
              .toRotationMatrix();
      const Rigid3d cam_from_board(rotation, center_in_cam - rotation * center_in_board);
      if (partial) {
        if (!internal::SeesPart(calibration, board, cam_from_board, center_in_board, options)) {
          continue;
        }
        poses.push_back(cam_from_board);
        found = true;
        continue;
      }
      if (!internal::Sees(camera, cam_from_board, outline, center_in_board, options)) continue;
      if (!internal::Sees(calibration.projector, calibration.proj_from_cam * cam_from_board,
                          outline, center_in_board, options)) {
        continue;
      }
      poses.push_back(cam_from_board);
      found = true;
    }
    SOPE_CHECK(found,
               "board sequence: no pose of a {} board fits both the camera and the "
               "projector after {} attempts (board too large for the rig, or distance range "
               "[{}, {}] m outside their shared field)",
               board.ToString(), options.max_attempts_per_view, options.min_distance,
               options.max_distance);
  }
  return poses;
}

FrameSet RenderBoardView(VirtualRig& rig, const BoardSpec& board, const Rigid3d& cam_from_board,
                         const BoardSequenceOptions& options) {
  const RigCalibration& calibration = rig.calibration();
  PatternOptions patterns = options.patterns;
  patterns.projector_width = calibration.projector.width;
  patterns.projector_height = calibration.projector.height;
  patterns.Check();
  Scene scene;
  scene.objects.push_back(MakeCheckerboardObject(board, cam_from_board, options));
  rig.SetScene(scene);
  FrameSet frames;
  frames.manifest =
      MakePatternManifest(patterns, calibration.camera.width, calibration.camera.height);
  for (const Pattern& pattern : GeneratePatterns(patterns)) {
    frames.images.push_back(rig.Capture(pattern.image));
  }
  frames.Check();
  return frames;
}

std::vector<Rigid3d> SimulateBoardSequence(VirtualRig& rig, const BoardSpec& board,
                                           const BoardSequenceOptions& options,
                                           const BoardViewSink& sink) {
  const std::vector<Rigid3d> poses = SampleBoardPoses(rig.calibration(), board, options);
  for (int v = 0; v < static_cast<int>(poses.size()); ++v) {
    sink(v, poses[v], RenderBoardView(rig, board, poses[v], options));
  }
  return poses;
}

std::string BoardViewName(int index) { return fmt::format("view_{:03d}", index); }

std::vector<Rigid3d> WriteBoardSequence(const std::string& directory, VirtualRig& rig,
                                        const BoardSpec& board, const BoardSequenceOptions& options,
                                        const std::function<void(int, int)>& progress) {
  StagedDirectory staged(directory, internal::kPosesFile);
  const std::string& out = staged.path();
  WriteRigCalibration(JoinPath(out, internal::kTrueCalibrationFile), rig.calibration());
  if (progress) progress(0, options.num_views);
  const std::vector<Rigid3d> poses =
      SimulateBoardSequence(rig, board, options, [&](int index, const Rigid3d&, FrameSet&& frames) {
        const std::string view_dir = JoinPath(out, BoardViewName(index));
        std::filesystem::create_directories(view_dir);
        frames.manifest.calibration = std::string("../") + internal::kTrueCalibrationFile;
        WriteFrameSetFiles(view_dir, frames);
        if (progress) progress(index + 1, options.num_views);
      });
  nlohmann::json views = nlohmann::json::array();
  for (int v = 0; v < static_cast<int>(poses.size()); ++v) {
    views.push_back({{"name", BoardViewName(v)}, {"cam_from_board", Rigid3dToJson(poses[v])}});
  }
  const nlohmann::json root = {
      {"format", "sope-gt-board-poses/1"},
      {"units",
       "metres; cam_from_board maps board to camera (X_cam = R X_board + t); board "
       "frame: origin at inner corner 0, x along a row of corners, z away from the "
       "printed front"},
      {"board", {{"cols", board.cols}, {"rows", board.rows}, {"square_size_m", board.square_size}}},
      {"calibration", internal::kTrueCalibrationFile},
      {"views", views}};
  WriteFileAtomic(JoinPath(out, internal::kPosesFile), root.dump(2) + "\n");
  staged.Commit();
  return poses;
}

}  // namespace sope
