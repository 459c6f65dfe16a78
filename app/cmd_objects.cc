// sope objects --instances N --seed S --out DIR
// sope objects --instances N --seed S --contact-sheet DIR
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "core/camera_model.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/units.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr double kDegree = kDegToRad;

// Normal-shaded view (colour = 128 + 127·normal, camera frame) of `mesh` from `elevation`,
// `azimuth` (radians) at `distance` metres (0: by the object's size), cropped to the
// object and resized to 320×320 unless `crop` is false.
cv::Mat ShadedView(DepthRenderer* renderer, const CameraModel& camera, const TriangleMesh& mesh,
                   double elevation, double azimuth, double distance = 0.0, bool crop = true) {
  Eigen::Vector3f lo, hi;
  mesh.Bounds(&lo, &hi);
  const Vector3d center = 0.5 * (lo + hi).cast<double>();
  if (distance <= 0) distance = std::max(0.45, 1.7 * (hi - lo).cast<double>().norm());
  const Vector3d eye =
      center + distance * Vector3d(std::cos(elevation) * std::cos(azimuth),
                                   std::cos(elevation) * std::sin(azimuth), std::sin(elevation));
  const Vector3d forward = (center - eye).normalized();
  const Vector3d right = forward.cross(Vector3d::UnitZ()).normalized();
  const Vector3d down = forward.cross(right);
  Eigen::Matrix3d rotation;
  rotation.row(0) = right;
  rotation.row(1) = down;
  rotation.row(2) = forward;
  renderer->SetMesh(mesh);
  const PointCloud cloud = renderer->Render(Rigid3d(rotation, -rotation * eye));
  cv::Mat image(camera.height, camera.width, CV_8UC3, cv::Scalar(40, 40, 40));
  cv::Rect used;
  for (size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector2d pixel = camera.ImageFromCam(cloud.points[i].cast<double>());
    const int x = static_cast<int>(std::lround(pixel.x())),
              y = static_cast<int>(std::lround(pixel.y()));
    if (x < 0 || y < 0 || x >= camera.width || y >= camera.height) continue;
    const Eigen::Vector3f& n = cloud.normals[i];
    image.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(128 - 127 * n.z()),
                                          cv::saturate_cast<uchar>(128 + 127 * n.y()),
                                          cv::saturate_cast<uchar>(128 + 127 * n.x()));
    used |= cv::Rect(x, y, 1, 1);
  }
  if (!crop) return image;
  // A square crop around the object, so small objects show their detail.
  const int side = std::max(used.width, used.height) + 20;
  const cv::Point middle = (used.tl() + used.br()) / 2;
  const cv::Rect window = cv::Rect(middle.x - side / 2, middle.y - side / 2, side, side) &
                          cv::Rect(0, 0, camera.width, camera.height);
  cv::Mat tile;
  cv::resize(image(window), tile, cv::Size(320, 320), 0, 0, cv::INTER_AREA);
  return tile;
}

// The lathe profile (r, z) mirrored about the axis, filled, on white.
cv::Mat ProfileView(const std::vector<Vector2d>& profile, int size) {
  cv::Mat image(size, size, CV_8UC3, cv::Scalar(255, 255, 255));
  if (profile.empty()) return image;
  double r_max = 0, z_max = 0;
  for (const Vector2d& p : profile) {
    r_max = std::max(r_max, p.x());
    z_max = std::max(z_max, p.y());
  }
  const double scale = 0.9 * size / std::max(2 * r_max, z_max);
  std::vector<cv::Point> left, right;
  for (const Vector2d& p : profile) {
    const int y = static_cast<int>(0.95 * size - scale * p.y());
    right.emplace_back(static_cast<int>(size / 2 + scale * p.x()), y);
    left.emplace_back(static_cast<int>(size / 2 - scale * p.x()), y);
  }
  cv::fillPoly(image, std::vector<std::vector<cv::Point>>{right}, cv::Scalar(200, 120, 60));
  cv::fillPoly(image, std::vector<std::vector<cv::Point>>{left}, cv::Scalar(200, 120, 60));
  return image;
}

// DIR/<class>.png per class (`instances` instances seeded seed…seed+instances−1 in columns,
// from 35°, 75° and 5° elevation, then their profiles) and DIR/overview.png (every class at
// one scale, 0.8 m away, 35° up). Each file is written atomically. Returns the files.
std::vector<std::string> WriteContactSheets(const std::string& dir, int instances, uint64_t seed) {
  const CameraModel camera = MakePinhole(640, 480, 50.0 * kDegree);
  DepthRenderer renderer(camera);
  std::vector<std::string> written;
  for (ObjectClass cls : AllObjectClasses()) {
    std::vector<cv::Mat> rows;
    for (const double elevation_deg : {35.0, 75.0, 5.0}) {
      std::vector<cv::Mat> tiles;
      for (int k = 0; k < instances; ++k) {
        const double azimuth = (-70.0 + 35.0 * k) * kDegree;
        cv::Mat tile = ShadedView(&renderer, camera, MakeObject(cls, seed + k),
                                  elevation_deg * kDegree, azimuth);
        cv::putText(tile, fmt::format("{} {} el {}", ToString(cls), seed + k, elevation_deg),
                    {6, 20}, cv::FONT_HERSHEY_SIMPLEX, 0.55, cv::Scalar(255, 255, 255), 1);
        tiles.push_back(tile);
      }
      cv::Mat row;
      cv::hconcat(tiles, row);
      rows.push_back(row);
    }
    std::vector<cv::Mat> profiles;
    for (int k = 0; k < instances; ++k) {
      profiles.push_back(ProfileView(internal::MakeObjectParts(cls, seed + k, {}).profile, 320));
    }
    cv::Mat profile_row;
    cv::hconcat(profiles, profile_row);
    rows.push_back(profile_row);
    cv::Mat sheet;
    cv::vconcat(rows, sheet);
    written.push_back(JoinPath(dir, ToString(cls) + ".png"));
    WriteImageAtomic(written.back(), sheet);
  }
  // All classes at one scale: 0.8 m away, 35° up, the central 400×400 pixels, five a row.
  const int per_row = 5;
  const int num_classes = static_cast<int>(AllObjectClasses().size());
  std::vector<cv::Mat> rows((num_classes + per_row - 1) / per_row);
  for (int i = 0; i < num_classes; ++i) {
    const ObjectClass cls = AllObjectClasses()[i];
    cv::Mat tile = ShadedView(&renderer, camera, MakeObject(cls, seed), 35.0 * kDegree,
                              -30.0 * kDegree, 0.8, false)(cv::Rect(120, 40, 400, 400))
                       .clone();
    cv::putText(tile, ToString(cls), {6, 20}, cv::FONT_HERSHEY_SIMPLEX, 0.6,
                cv::Scalar(255, 255, 255), 1);
    cv::Mat& row = rows[i / per_row];
    if (row.empty()) {
      row = tile;
    } else {
      cv::hconcat(row, tile, row);
    }
  }
  // A short last row is padded with background so the rows stack.
  for (cv::Mat& row : rows) {
    if (row.cols < rows.front().cols) {
      cv::copyMakeBorder(row, row, 0, 0, 0, rows.front().cols - row.cols, cv::BORDER_CONSTANT,
                         cv::Scalar(40, 40, 40));
    }
  }
  cv::Mat overview;
  cv::vconcat(rows, overview);
  written.push_back(JoinPath(dir, "overview.png"));
  WriteImageAtomic(written.back(), overview);
  return written;
}

}  // namespace

int RunObjects(int argc, char** argv) {
  CLI::App app{
      "Write procedural household objects (mug, bottle, bowl, box, can, glass, plate, "
      "vase, wine glass, saucepan) as a models directory for sope build-db / sope "
      "eval: DIR/<class>/<class>_<k>.obj, instance k drawn from seed S + k, and "
      "DIR/<class>/CATEGORY (each class is a category: sope build-db records it, and "
      "unseen instances are recognised as the class). Seeds S and S' >= S + N give "
      "disjoint instances (training vs held-out). With "
      "--contact-sheet, also (or instead) render the same instances into PNG contact "
      "sheets to look at.",
      "sope objects"};
  std::string out, contact_sheet;
  int instances = 3;
  uint64_t seed = 1;
  cli::LoggingFlags logging;
  app.add_option("--out", out, "Models directory to write");
  app.add_option("--contact-sheet", contact_sheet,
                 "Directory for contact sheets: DIR/<class>.png (the instances in columns, "
                 "depth-rendered normal-shaded from 35°, 75° and 5° elevation, and their "
                 "profiles) and DIR/overview.png (every class at one scale)");
  app.add_option("--instances", instances, "Instances per class")->capture_default_str();
  // CLI11 would wrap "-1" into 2^64 − 1 for the unsigned seed: refuse a sign.
  app.add_option("--seed", seed, "Seed of the first instance")
      ->check(CLI::Validator(
          [](std::string& text) {
            return text.find('-') != std::string::npos ? "must be ≥ 0, got " + text
                                                       : std::string();
          },
          "UINT", "non-negative"))
      ->capture_default_str();
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();
  SOPE_CHECK(!out.empty() || !contact_sheet.empty(),
             "give --out DIR (models) and/or --contact-sheet DIR (pictures)");
  SOPE_CHECK(instances >= 1 && instances <= kMaxInstancesPerClass,
             "--instances must be in [1, {}], got {}", kMaxInstancesPerClass, instances);
  if (!out.empty()) {
    const std::vector<std::string> written = WriteProceduralModels(out, instances, seed);
    spdlog::info("wrote {} meshes ({} per class, seeds {}–{}) to {}", written.size(), instances,
                 seed, seed + instances - 1, out);
  }
  if (!contact_sheet.empty()) {
    const std::vector<std::string> written = WriteContactSheets(contact_sheet, instances, seed);
    spdlog::info("wrote {} contact sheets (seeds {}–{}) to {}", written.size(), seed,
                 seed + instances - 1, contact_sheet);
  }
  return 0;
}

}  // namespace sope
