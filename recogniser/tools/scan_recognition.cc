#include "recogniser/tools/scan_recognition.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/plots.h"
#include "core/split_mix.h"
#include "core/stopwatch.h"
#include "core/units.h"
#include "decoder/code_consistency.h"
#include "decoder/gray_refine.h"
#include "recogniser/segmentation.h"
#include "simulator/scene_builder.h"

namespace sope {
namespace {

// Uniform on SO(3) (Shoemake, "Uniform random rotations", Graphics Gems III).
Eigen::Matrix3d RandomRotation(SplitMix* rng) {
  const double u1 = rng->Uniform(), u2 = 2 * kPi * rng->Uniform(), u3 = 2 * kPi * rng->Uniform();
  const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
  const Eigen::Quaterniond q(b * std::cos(u3), a * std::sin(u2), a * std::cos(u2),
                             b * std::sin(u3));
  return q.normalized().toRotationMatrix();
}

cv::Mat ToBgr(const cv::Mat& image) {
  SOPE_CHECK(!image.empty(), "overlay: empty camera image");
  cv::Mat grey;
  if (image.type() == CV_8UC3) return image.clone();
  if (image.type() == CV_16UC1) {
    image.convertTo(grey, CV_8U, 1.0 / 257.0);
  } else {
    SOPE_CHECK(image.type() == CV_8UC1, "overlay: camera image must be 8/16-bit grey or BGR");
    grey = image;
  }
  cv::Mat bgr;
  cv::cvtColor(grey, bgr, cv::COLOR_GRAY2BGR);
  return bgr;
}

void DrawLabel(cv::Mat* image, const std::string& utf8_label) {
  const std::string label = HersheyText(utf8_label);
  const int font = cv::FONT_HERSHEY_SIMPLEX;
  const double scale = std::max(0.5, image->cols / 1400.0);
  const int thickness = std::max(1, static_cast<int>(std::lround(2 * scale)));
  int baseline = 0;
  const cv::Size size = cv::getTextSize(label, font, scale, thickness, &baseline);
  const cv::Point origin(10, 10 + size.height);
  cv::rectangle(*image, cv::Point(4, 4),
                cv::Point(16 + size.width, 16 + size.height + baseline), cv::Scalar(0, 0, 0),
                cv::FILLED);
  cv::putText(*image, label, origin, font, scale, cv::Scalar(0, 255, 255), thickness,
              cv::LINE_AA);
}

bool Project(const CameraModel& camera, const Rigid3d& cam_from_model, const Eigen::Vector3f& p,
             cv::Point* pixel) {
  const Eigen::Vector3d in_cam = cam_from_model * p.cast<double>();
  if (!(in_cam.z() > 1e-3)) return false;
  const Eigen::Vector2d uv = camera.ImageFromCam(in_cam);
  if (!uv.allFinite() || std::abs(uv.x()) > 1e5 || std::abs(uv.y()) > 1e5) return false;
  // 1/8-pixel fixed point for the drawing calls (shift 3).
  *pixel = cv::Point(static_cast<int>(std::lround(uv.x() * 8)),
                     static_cast<int>(std::lround(uv.y() * 8)));
  return true;
}

}  // namespace

void ObjectSegmentationOptions::Check() const {
  SOPE_CHECK(std::isfinite(min_range) && min_range >= 0.0,
             "segmentation: min range must be ≥ 0 m, got {}", min_range);
  SOPE_CHECK(std::isfinite(max_range) && max_range > min_range,
             "segmentation: max range must exceed the min range ({} m), got {}", min_range,
             max_range);
}

PointCloud SegmentByRange(const PointCloud& cloud, const ObjectSegmentationOptions& options) {
  options.Check();
  cloud.Check();
  PointCloud out;
  const double lo2 = options.min_range * options.min_range;
  const double hi2 = options.max_range * options.max_range;
  out.points.reserve(cloud.size() / 4);
  for (size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3f& p = cloud.points[i];
    if (!p.allFinite()) continue;
    const double r2 = p.cast<double>().squaredNorm();
    if (r2 < lo2 || r2 > hi2) continue;
    out.points.push_back(p);
    if (cloud.HasColors()) out.colors.push_back(cloud.colors[i]);
    if (cloud.HasNormals()) out.normals.push_back(cloud.normals[i]);
  }
  return out;
}

ScanRecognition RecogniseFrameSet(const FrameSet& frames, const RigCalibration& calibration,
                                  const ScanOptions& scan_options,
                                  const ObjectSegmentationOptions& segmentation,
                                  const Recogniser& recogniser,
                                  const RecognitionOptions& recognition_options) {
  scan_options.Check();
  return RecogniseFrameSet(frames, Triangulator(calibration, scan_options.triangulation),
                           scan_options.decoder, segmentation, recogniser, recognition_options);
}

ScanRecognition RecogniseFrameSet(const FrameSet& frames, const Triangulator& triangulator,
                                  const DecoderOptions& decoder_options,
                                  const ObjectSegmentationOptions& segmentation,
                                  const Recogniser& recogniser,
                                  const RecognitionOptions& recognition_options) {
  decoder_options.Check();
  return RecogniseScan(ScanFrameSet(frames, triangulator, decoder_options), segmentation,
                       recogniser, recognition_options);
}

DecoderOptions PlainTableDecoderOptions(const DecoderOptions& options) {
  DecoderOptions plain = options;
  plain.consistency.enabled = false;
  plain.gray_subpixel = GraySubpixel::kOff;
  return plain;
}

ScanResult ScanTableFrameSet(const FrameSet& frames, const Triangulator& triangulator,
                             const DecoderOptions& options,
                             const TableSegmentationOptions& segmentation,
                             CorrespondenceMap* plain, double plain_decode_ms) {
  options.Check();
  segmentation.Check();
  const bool edges = options.gray_subpixel == GraySubpixel::kEdges;
  Stopwatch watch;
  if (frames.manifest.HasPhase() || !options.consistency.enabled) {
    if (plain == nullptr) return ScanFrameSet(frames, triangulator, options);
    if (edges) RefineGraySubpixel(frames, plain);
    return ScanDecoded(frames, std::move(*plain), plain_decode_ms + watch.WallMs(), triangulator);
  }
  CorrespondenceMap map =
      plain != nullptr ? std::move(*plain) : Decode(frames, PlainTableDecoderOptions(options));
  double decode_ms = plain_decode_ms + watch.WallMs();
  // The plane and what stands on it, from the plain map's points.
  watch.Restart();
  const TriangulationResult first = triangulator.Triangulate(map, cv::Mat());
  const double first_ms = watch.WallMs();

  watch.Restart();
  // Where the consistency fills, and the pixels its fills grow from (empty: everywhere,
  // from every decoded pixel).
  cv::Mat region, off_table;
  const TablePlane plane = FindTablePlane(first.cloud, segmentation);
  if (plane.found) {
    off_table = cv::Mat::zeros(map.height(), map.width(), CV_8UC1);
    const std::vector<Eigen::Vector3f>& points = first.cloud.points;
    const float min_height = static_cast<float>(segmentation.min_height);
    const float max_height = static_cast<float>(segmentation.max_height);
    const float min_range2 = static_cast<float>(segmentation.min_range * segmentation.min_range);
    const float max_range2 = static_cast<float>(segmentation.max_range * segmentation.max_range);
    for (size_t i = 0; i < points.size(); ++i) {
      const float height = plane.Height(points[i]);
      const float range2 = points[i].squaredNorm();
      if (height > min_height && height <= max_height && range2 >= min_range2 &&
          range2 <= max_range2) {
        off_table.at<uint8_t>(first.pixels[i]) = 255;
      }
    }
    // The consistency's reach: each pass fills within its window of the pixels decoded
    // before it.
    const int reach = options.consistency.passes * options.consistency.window_radius;
    cv::dilate(off_table, region,
               cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * reach + 1, 2 * reach + 1)));
  }
  FillFromConsistentNeighbours(frames, options, &map, region, off_table);
  if (edges) RefineGraySubpixel(frames, &map);
  decode_ms += watch.WallMs();
  ScanResult result = ScanDecoded(frames, std::move(map), decode_ms, triangulator);
  result.triangulate_ms += first_ms;
  return result;
}

ScanRecognition RecogniseScan(ScanResult scan, const ObjectSegmentationOptions& segmentation,
                              const Recogniser& recogniser,
                              const RecognitionOptions& recognition_options) {
  segmentation.Check();
  ScanRecognition out;
  // The clock started when decoding did (after the last frame).
  const double decoded_ms = scan.decode_ms + scan.triangulate_ms;
  const Stopwatch since_decoded;
  const auto total_ms = [&] { return decoded_ms + since_decoded.WallMs(); };
  out.scan = std::move(scan);
  out.timing.decode = out.scan.decode_ms;
  out.timing.triangulate = out.scan.triangulate_ms;
  const PointCloud& cloud = out.scan.triangulation.cloud;
  if (cloud.empty()) {
    out.status = ScanStatus::kNoPoints;
    out.message = fmt::format("no points: {} pixels decoded, none triangulated (no projector "
                              "light on the scene, or a wrong calibration?)",
                              out.scan.correspondences.CountValid());
    out.timing.total = total_ms();
    return out;
  }
  const Stopwatch segment;
  out.object = SegmentByRange(cloud, segmentation);
  out.timing.segment = segment.WallMs();
  if (out.object.size() < kMinObjectPoints) {
    out.status = ScanStatus::kNothingInBand;
    out.message = fmt::format("segmentation left {} of {} points in the range band [{}, {}] m "
                              "(nothing in front of the rig?)",
                              out.object.size(), cloud.size(), segmentation.min_range,
                              segmentation.max_range);
    out.timing.total = total_ms();
    return out;
  }
  const Stopwatch recognise;
  out.recognition = recogniser.Recognise(out.object, recognition_options);
  out.timing.recognise = recognise.WallMs();
  out.timing.total = total_ms();
  if (out.recognition.empty()) {
    out.status = ScanStatus::kNoSuggestion;
    out.message = "no suggestion (the database has no comparable view)";
  }
  return out;
}

std::string ToString(ScanStatus status) {
  switch (status) {
    case ScanStatus::kRecognised: return "recognised";
    case ScanStatus::kNoSuggestion: return "no suggestion";
    case ScanStatus::kNoPoints: return "no points";
    case ScanStatus::kNothingInBand: return "nothing in band";
  }
  return "unknown";
}

void RecognitionSceneOptions::Check() const {
  SOPE_CHECK(instance_count >= 1, "scene: instance count must be ≥ 1, got {}", instance_count);
  SOPE_CHECK(min_distance > 0 && max_distance >= min_distance,
             "scene: distances must satisfy 0 < min ≤ max, got [{}, {}]", min_distance,
             max_distance);
  SOPE_CHECK(fit_margin >= 1.0, "scene: fit margin must be ≥ 1, got {}", fit_margin);
  SOPE_CHECK(max_lateral_offset >= 0, "scene: lateral offset must be ≥ 0, got {}",
             max_lateral_offset);
  SOPE_CHECK(backdrop_gap > 0, "scene: backdrop gap must be > 0, got {}", backdrop_gap);
}

std::string RecognitionScene::Description() const {
  return fmt::format("{} (instance {})", ToString(object_class), instance_seed);
}

RecognitionScene MakeRecognitionScene(uint64_t seed, const CameraModel& camera,
                                      const RecognitionSceneOptions& options) {
  options.Check();
  camera.Check();
  SplitMix rng{seed * 0x2545F4914F6CDD1Dull + 0x5EED};
  const std::vector<ObjectClass> classes =
      options.classes.empty() ? AllObjectClasses() : options.classes;
  RecognitionScene out;
  out.object_class = classes[rng.Next() % classes.size()];
  out.instance_seed =
      options.instance_seed_base + rng.Next() % static_cast<uint64_t>(options.instance_count);
  out.mesh = MakeObject(out.object_class, out.instance_seed);

  // Bounding sphere of the box about its centre.
  Eigen::Vector3f lo, hi;
  out.mesh.Bounds(&lo, &hi);
  const double radius = 0.5 * (hi - lo).cast<double>().norm();
  // Half of the smaller field of view, from the principal point to the nearest edge.
  const double half_fov = std::min(
      {std::atan(camera.cx() / camera.fx()), std::atan((camera.width - camera.cx()) / camera.fx()),
       std::atan(camera.cy() / camera.fy()),
       std::atan((camera.height - camera.cy()) / camera.fy())});
  const double fit_distance = options.fit_margin * radius / std::sin(half_fov);
  double distance = rng.Uniform(options.min_distance, options.max_distance);
  distance = std::max(distance, fit_distance);
  const double off = options.max_lateral_offset;
  const Eigen::Vector3d center(rng.Uniform(-off, off), rng.Uniform(-off, off), 0.0);

  Placement placement;
  placement.rotation = RandomRotation(&rng);
  placement.center_in_cam = Eigen::Vector3d(center.x(), center.y(), distance);
  out.scene.objects.push_back(PlaceObject(out.mesh, placement));
  out.cam_from_model = out.scene.objects[0].cam_from_model;

  const double farthest = placement.center_in_cam.norm() + radius;
  out.segmentation.min_range = 0.05;
  out.segmentation.max_range = farthest + 0.5 * options.backdrop_gap;
  if (options.backdrop) {
    out.backdrop_distance = farthest + options.backdrop_gap;
    // Wide enough to fill the camera's view at that distance.
    const double half_width = out.backdrop_distance *
                              std::max(camera.cx(), camera.width - camera.cx()) / camera.fx();
    const double half_height = out.backdrop_distance *
                               std::max(camera.cy(), camera.height - camera.cy()) / camera.fy();
    out.scene.objects.push_back(
        MakeBackdrop(out.backdrop_distance, 2.4 * half_width, 2.4 * half_height));
  }
  return out;
}

cv::Mat DrawRecognitionOverlay(const cv::Mat& image, const CameraModel& camera,
                               const TriangleMesh& mesh, const Rigid3d& cam_from_model,
                               const std::string& label) {
  cv::Mat out = ToBgr(image);
  std::vector<cv::Point> pixels(mesh.vertices.size());
  std::vector<uint8_t> ok(mesh.vertices.size());
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    ok[i] = Project(camera, cam_from_model, mesh.vertices[i], &pixels[i]);
  }
  cv::Mat mask = cv::Mat::zeros(out.size(), CV_8UC1);
  for (const Eigen::Vector3i& face : mesh.faces) {
    if (!ok[face[0]] || !ok[face[1]] || !ok[face[2]]) continue;
    const cv::Point triangle[3] = {pixels[face[0]], pixels[face[1]], pixels[face[2]]};
    cv::fillConvexPoly(mask, triangle, 3, cv::Scalar(255), cv::LINE_8, 3);
  }
  cv::Mat tinted = out.clone();
  tinted.setTo(cv::Scalar(60, 200, 60), mask);
  cv::addWeighted(out, 0.55, tinted, 0.45, 0.0, out);
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(mask, contours, cv::RETR_LIST, cv::CHAIN_APPROX_SIMPLE);
  cv::drawContours(out, contours, -1, cv::Scalar(0, 255, 0), 2, cv::LINE_AA);
  DrawLabel(&out, label);
  return out;
}

cv::Mat DrawRecognitionOverlay(const cv::Mat& image, const CameraModel& camera,
                               const std::vector<Eigen::Vector3f>& points_in_model,
                               const Rigid3d& cam_from_model, const std::string& label) {
  cv::Mat out = ToBgr(image);
  for (const Eigen::Vector3f& p : points_in_model) {
    cv::Point pixel;
    if (!Project(camera, cam_from_model, p, &pixel)) continue;
    cv::circle(out, pixel, 2 * 8, cv::Scalar(0, 255, 0), cv::FILLED, cv::LINE_AA, 3);
  }
  DrawLabel(&out, label);
  return out;
}

}  // namespace sope
