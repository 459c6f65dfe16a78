// Local homographies on synthetic correspondence maps of a plane seen through distorted
// lenses, decoded values quantised to integers (as the Gray code gives them), with holes
// and wrong codes: the sub-pixel corner must come back far better than a pixel lookup.
#include "calibration/projector_corners.h"

#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/rig_calibration.h"
#include "projector/patterns.h"
#include "tests/test_support.h"

namespace sope {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

RigCalibration TestRig() {
  RigCalibration rig;
  rig.camera.width = 640;
  rig.camera.height = 480;
  rig.camera.matrix << 700, 0, 321.3, 0, 702, 238.9, 0, 0, 1;
  rig.camera.distortion = {-0.08, 0.06, 4e-4, -3e-4, 0.0};
  rig.projector.width = 800;
  rig.projector.height = 600;
  rig.projector.matrix << 1100, 0, 401.0, 0, 1100, 330.0, 0, 0, 1;
  rig.projector.distortion = {-0.02, 0.0, 0.0, 0.0, 0.0};
  const Eigen::Vector3d projector_center(0.2, 0.0, 0.0);
  const double angle = std::atan2(0.2, 0.6);
  rig.proj_from_cam.rotation = RotationFromEulerXYZ(0.0, -angle, 0.0).transpose();
  rig.proj_from_cam.translation = -(rig.proj_from_cam.rotation * projector_center);
  return rig;
}

// A tilted plane: the exact projector coordinates of every camera pixel (`exact`), and a
// map of them rounded to integers, with `outlier_fraction` of the pixels given random
// codes and `hole_fraction` left undecoded.
struct PlaneMaps {
  CorrespondenceMap map;
  cv::Mat exact_x, exact_y;
  Eigen::Vector3d normal;
  double offset = 0.0;
};

PlaneMaps MakePlaneMaps(const RigCalibration& rig, double outlier_fraction, double hole_fraction) {
  PlaneMaps maps;
  maps.normal = Eigen::Vector3d(0.3, -0.2, -1.0).normalized();
  maps.offset = maps.normal.dot(Eigen::Vector3d(0, 0, 0.6));
  const cv::Size size(rig.camera.width, rig.camera.height);
  CorrespondenceMap& map = maps.map;
  map.projector_width = rig.projector.width;
  map.projector_height = rig.projector.height;
  map.proj_x = cv::Mat(size, CV_32FC1, cv::Scalar(kNaN));
  map.proj_y = cv::Mat(size, CV_32FC1, cv::Scalar(kNaN));
  map.mask = cv::Mat::zeros(size, CV_8UC1);
  maps.exact_x = cv::Mat(size, CV_64FC1, cv::Scalar(std::nan("")));
  maps.exact_y = cv::Mat(size, CV_64FC1, cv::Scalar(std::nan("")));
  std::mt19937_64 engine(3);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const Eigen::Vector3d ray = rig.camera.RayFromImage(Eigen::Vector2d(x, y));
      const Eigen::Vector3d point = ray * (maps.offset / maps.normal.dot(ray));
      const Eigen::Vector2d projected = rig.projector.ImageFromCam(rig.proj_from_cam * point);
      maps.exact_x.at<double>(y, x) = projected.x();
      maps.exact_y.at<double>(y, x) = projected.y();
      if (unit(engine) < hole_fraction) continue;
      double px = std::round(projected.x()), py = std::round(projected.y());
      if (unit(engine) < outlier_fraction) {
        px = std::floor(unit(engine) * rig.projector.width);
        py = std::floor(unit(engine) * rig.projector.height);
      }
      map.proj_x.at<float>(y, x) = static_cast<float>(px);
      map.proj_y.at<float>(y, x) = static_cast<float>(py);
      map.mask.at<uint8_t>(y, x) = 255;
    }
  }
  return maps;
}

// The exact projector coordinates of a sub-pixel camera point on the plane.
Eigen::Vector2d ExactProjector(const RigCalibration& rig, const PlaneMaps& maps,
                               const Eigen::Vector2d& camera_point) {
  const Eigen::Vector3d ray = rig.camera.RayFromImage(camera_point);
  const Eigen::Vector3d point = ray * (maps.offset / maps.normal.dot(ray));
  return rig.projector.ImageFromCam(rig.proj_from_cam * point);
}

struct CornerErrors {
  double homography_rms = 0.0;
  double lookup_rms = 0.0;  // nearest decoded pixel, for comparison
  double homography_max = 0.0;
  int found = 0;
};

CornerErrors Measure(const RigCalibration& rig, const PlaneMaps& maps, int half_window,
               const LocalHomographyOptions& options) {
  std::mt19937_64 engine(11);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  CornerErrors errors;
  double sum = 0.0, lookup_sum = 0.0;
  constexpr int kTrials = 60;
  for (int trial = 0; trial < kTrials; ++trial) {
    const Eigen::Vector2d corner(120 + 400 * unit(engine), 90 + 300 * unit(engine));
    const auto found = ProjectorPointFromLocalHomography(maps.map, corner, half_window, options);
    if (!found) continue;
    const Eigen::Vector2d truth = ExactProjector(rig, maps, corner);
    const double error = (*found - truth).norm();
    sum += error * error;
    errors.homography_max = std::max(errors.homography_max, error);
    const int x = static_cast<int>(std::lround(corner.x())),
              y = static_cast<int>(std::lround(corner.y()));
    lookup_sum += (Eigen::Vector2d(std::round(maps.exact_x.at<double>(y, x)),
                                   std::round(maps.exact_y.at<double>(y, x))) -
                   truth)
                      .squaredNorm();
    ++errors.found;
  }
  errors.homography_rms = std::sqrt(sum / std::max(errors.found, 1));
  errors.lookup_rms = std::sqrt(lookup_sum / std::max(errors.found, 1));
  return errors;
}

TEST(LocalHomography, RecoversSubPixelProjectorCoordinatesFromQuantisedCodes) {
  const RigCalibration rig = TestRig();
  const PlaneMaps maps = MakePlaneMaps(rig, 0.0, 0.0);
  const CornerErrors errors = Measure(rig, maps, 20, {});
  std::printf("clean: local homography rms %.4f px (max %.4f), pixel lookup rms %.4f px\n",
              errors.homography_rms, errors.homography_max, errors.lookup_rms);
  EXPECT_EQ(errors.found, 60);
  EXPECT_LT(errors.homography_rms, 0.03);
  EXPECT_LT(errors.homography_max, 0.1);
  EXPECT_GT(errors.lookup_rms, 5 * errors.homography_rms);
}

TEST(LocalHomography, IsRobustToWrongCodesAndHoles) {
  const RigCalibration rig = TestRig();
  const PlaneMaps maps = MakePlaneMaps(rig, 0.15, 0.2);
  const CornerErrors errors = Measure(rig, maps, 20, {});
  std::printf("15%% wrong codes, 20%% holes: rms %.4f px (max %.4f)\n", errors.homography_rms,
              errors.homography_max);
  EXPECT_EQ(errors.found, 60);
  EXPECT_LT(errors.homography_rms, 0.05);
  EXPECT_LT(errors.homography_max, 0.15);
}

TEST(LocalHomography, DropsCornersWithTooFewDecodedPixels) {
  const RigCalibration rig = TestRig();
  PlaneMaps maps = MakePlaneMaps(rig, 0.0, 0.0);
  const Eigen::Vector2d corner(300.4, 200.7);
  ASSERT_TRUE(ProjectorPointFromLocalHomography(maps.map, corner, 10));
  // Shadow over 70% of the window: dropped (min_decoded_fraction 0.4).
  maps.map.proj_x(cv::Rect(290, 190, 21, 15)).setTo(cv::Scalar(kNaN));
  EXPECT_FALSE(ProjectorPointFromLocalHomography(maps.map, corner, 10));
  // Window over the image border, non-finite points.
  EXPECT_FALSE(ProjectorPointFromLocalHomography(maps.map, Eigen::Vector2d(3.0, 100.0), 10));
  EXPECT_FALSE(
      ProjectorPointFromLocalHomography(maps.map, Eigen::Vector2d(std::nan(""), 100.0), 10));
  // Leaving out bands along the printed edges through the corner: still found; bands as
  // wide as the window leave nothing.
  LocalHomographyOptions banded;
  banded.edge_band_px = 2.0;
  const auto with_bands = ProjectorPointFromLocalHomography(maps.map, Eigen::Vector2d(400.2, 300.6),
                                                            10, banded, {{1, 0.1}, {-0.1, 1}});
  ASSERT_TRUE(with_bands.has_value());
  EXPECT_LT((*with_bands - ExactProjector(rig, maps, Eigen::Vector2d(400.2, 300.6))).norm(), 0.1);
  banded.edge_band_px = 12.0;
  EXPECT_FALSE(ProjectorPointFromLocalHomography(maps.map, Eigen::Vector2d(400.2, 300.6), 10,
                                                 banded, {{1, 0.1}, {-0.1, 1}}));
  // Mostly wrong codes: no consensus, dropped rather than guessed.
  PlaneMaps noisy = MakePlaneMaps(rig, 0.7, 0.0);
  EXPECT_FALSE(ProjectorPointFromLocalHomography(noisy.map, corner, 10));
}

TEST(LocalHomography, NeedsBothAxesAndMatchingCornerCounts) {
  const RigCalibration rig = TestRig();
  PlaneMaps maps = MakePlaneMaps(rig, 0.0, 0.0);
  const BoardSpec board = BoardSpecFromString("3x2x0.02");
  const std::vector<Eigen::Vector2d> corners = {{200, 200}, {230, 200}, {260, 200},
                                                {200, 230}, {230, 230}, {260, 230}};
  const auto found = FindProjectorCorners(maps.map, board, corners);
  ASSERT_EQ(found.size(), 6u);
  for (size_t k = 0; k < found.size(); ++k) {
    ASSERT_TRUE(found[k].has_value()) << k;
    EXPECT_LT((*found[k] - ExactProjector(rig, maps, corners[k])).norm(), 0.08) << k;
  }
  EXPECT_THROW_WITH_MESSAGE(FindProjectorCorners(maps.map, board, {corners[0]}), Error,
                            "1 camera corners", "3x2 board");
  CorrespondenceMap x_only = maps.map;
  x_only.proj_y = cv::Mat();
  EXPECT_THROW_WITH_MESSAGE(FindProjectorCorners(x_only, board, corners), Error,
                            "both projector axes");
  LocalHomographyOptions options;
  options.window_fraction = 0.0;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "window_fraction", "got 0");
  options = {};
  options.min_half_window_px = 10;
  options.max_half_window_px = 5;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "half window", "[10, 5]");
}

// A camera that sees the projector image through p = scale·(x, y) + offset (projector
// pixels per camera pixel), with projector defocus and sensor noise: a Gray-code frame set
// whose true projector coordinates are known at every pixel.
FrameSet AffineGrayCodeFrames(int camera_width, int camera_height, const Eigen::Vector2d& scale,
                              const Eigen::Vector2d& offset, PatternCode code, int skip_low_bits) {
  PatternOptions patterns;
  patterns.projector_width = 512;
  patterns.projector_height = 384;
  patterns.code = code;
  patterns.skip_low_bits = skip_low_bits;
  FrameSet frames;
  frames.manifest = MakePatternManifest(patterns, camera_width, camera_height);
  cv::Mat map_x(camera_height, camera_width, CV_32FC1),
      map_y(camera_height, camera_width, CV_32FC1);
  for (int y = 0; y < camera_height; ++y) {
    for (int x = 0; x < camera_width; ++x) {
      map_x.at<float>(y, x) = static_cast<float>(scale.x() * x + offset.x());
      map_y.at<float>(y, x) = static_cast<float>(scale.y() * y + offset.y());
    }
  }
  cv::RNG rng(7);
  for (const Pattern& pattern : GeneratePatterns(patterns)) {
    cv::Mat light, seen;
    pattern.image.convertTo(light, CV_32F, 1.0 / 255.0);
    cv::GaussianBlur(light, light, cv::Size(), 0.6);  // defocus, projector pixels
    cv::remap(light, seen, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    cv::Mat noise(seen.size(), CV_32F);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, 1.0);
    cv::Mat image;
    cv::Mat(20.0f + 180.0f * seen + noise).convertTo(image, CV_8U);
    frames.images.push_back(image);
  }
  frames.Check();
  return frames;
}

struct MapErrors {
  double rms = 0.0;
  double worst_region_bias = 0.0;  // largest |mean error| over 16×16 pixel regions
};

MapErrors CompareWithAffine(const cv::Mat& coordinates, double scale, double offset, bool along_x) {
  MapErrors errors;
  double sum = 0.0;
  int count = 0;
  for (int ry = 0; ry + 16 <= coordinates.rows; ry += 16) {
    for (int rx = 0; rx + 16 <= coordinates.cols; rx += 16) {
      double region = 0.0;
      int region_count = 0;
      for (int y = ry; y < ry + 16; ++y) {
        for (int x = rx; x < rx + 16; ++x) {
          const float value = coordinates.at<float>(y, x);
          if (!std::isfinite(value)) continue;
          const double error = value - (scale * (along_x ? x : y) + offset);
          sum += error * error;
          region += error;
          ++count;
          ++region_count;
        }
      }
      if (region_count > 128) {
        errors.worst_region_bias =
            std::max(errors.worst_region_bias, std::abs(region / region_count));
      }
    }
  }
  errors.rms = std::sqrt(sum / std::max(count, 1));
  return errors;
}

TEST(RefineGrayCodeSubpixel, RemovesTheQuantisationOfCommensurateGrids) {
  // Nearly 1:1 in x (the Moiré case) and 1.07:1 in y.
  const Eigen::Vector2d scale(1.002, 1.07), offset(40.3, 30.7);
  const FrameSet frames = AffineGrayCodeFrames(320, 240, scale, offset, PatternCode::kGray, 0);
  const CorrespondenceMap decoded = Decode(frames);
  const CorrespondenceMap refined = RefineGrayCodeSubpixel(frames, decoded);
  const MapErrors decoded_x = CompareWithAffine(decoded.proj_x, scale.x(), offset.x(), true);
  const MapErrors refined_x = CompareWithAffine(refined.proj_x, scale.x(), offset.x(), true);
  const MapErrors decoded_y = CompareWithAffine(decoded.proj_y, scale.y(), offset.y(), false);
  const MapErrors refined_y = CompareWithAffine(refined.proj_y, scale.y(), offset.y(), false);
  std::printf(
      "x: decoded rms %.3f (worst region bias %.3f), refined rms %.3f (%.3f); y: decoded "
      "%.3f (%.3f), refined %.3f (%.3f)\n",
      decoded_x.rms, decoded_x.worst_region_bias, refined_x.rms, refined_x.worst_region_bias,
      decoded_y.rms, decoded_y.worst_region_bias, refined_y.rms, refined_y.worst_region_bias);
  EXPECT_GT(decoded_x.worst_region_bias, 0.2);  // integer codes: the fraction never averages out
  EXPECT_LT(refined_x.worst_region_bias, 0.1);
  EXPECT_LT(refined_x.rms, 0.5 * decoded_x.rms);
  EXPECT_LT(refined_y.worst_region_bias, 0.05);
  EXPECT_LT(refined_y.rms, 0.5 * decoded_y.rms);
  // So the local homography gives the sub-pixel point even on the commensurate axis.
  const Eigen::Vector2d corner(160.4, 120.8);
  const auto from_decoded = ProjectorPointFromLocalHomography(decoded, corner, 12);
  const auto from_refined = ProjectorPointFromLocalHomography(refined, corner, 12);
  ASSERT_TRUE(from_decoded && from_refined);
  const Eigen::Vector2d truth = scale.cwiseProduct(corner) + offset;
  std::printf("corner: decoded error %.3f px, refined %.3f px\n", (*from_decoded - truth).norm(),
              (*from_refined - truth).norm());
  EXPECT_LT((*from_refined - truth).norm(), 0.08);
  EXPECT_GT((*from_decoded - truth).norm(), 0.1);
}

TEST(RefineGrayCodeSubpixel, OmittedLowBitsAndBinaryCodes) {
  const Eigen::Vector2d scale(0.53, 0.61), offset(20.2, 10.9);
  // Two low bits omitted: blocks of 4 projector pixels. Only pixels within about the blur
  // of a block edge gain (inside, both edge bits are saturated), but the error drops.
  const FrameSet coarse = AffineGrayCodeFrames(320, 240, scale, offset, PatternCode::kGray, 2);
  const CorrespondenceMap decoded = Decode(coarse);
  ASSERT_EQ(decoded.step_x, 4.0f);
  const CorrespondenceMap refined = RefineGrayCodeSubpixel(coarse, decoded);
  EXPECT_LT(CompareWithAffine(refined.proj_x, scale.x(), offset.x(), true).rms,
            0.75 * CompareWithAffine(decoded.proj_x, scale.x(), offset.x(), true).rms);
  // Binary codes have no single-bit edges: left as decoded.
  const FrameSet binary = AffineGrayCodeFrames(320, 240, scale, offset, PatternCode::kBinary, 0);
  const CorrespondenceMap binary_decoded = Decode(binary);
  const CorrespondenceMap binary_refined = RefineGrayCodeSubpixel(binary, binary_decoded);
  int changed = 0;
  for (int y = 0; y < binary_decoded.proj_x.rows; ++y) {
    for (int x = 0; x < binary_decoded.proj_x.cols; ++x) {
      const float a = binary_decoded.proj_x.at<float>(y, x),
                  b = binary_refined.proj_x.at<float>(y, x);
      changed += !(a == b || (std::isnan(a) && std::isnan(b)));
    }
  }
  EXPECT_EQ(changed, 0);
  // A map of another size is refused.
  CorrespondenceMap other = decoded;
  other.mask = cv::Mat::zeros(10, 10, CV_8UC1);
  EXPECT_THROW_WITH_MESSAGE(RefineGrayCodeSubpixel(coarse, other), Error, "map is 10x10",
                            "frames are 320x240");
}

// Decode's kEdges is this refinement, and refining a refined map changes nothing.
TEST(RefineGrayCodeSubpixel, IsDecodesEdgeModeAndIdempotent) {
  const Eigen::Vector2d scale(1.002, 1.07), offset(40.3, 30.7);
  const FrameSet frames = AffineGrayCodeFrames(320, 240, scale, offset, PatternCode::kGray, 0);
  const CorrespondenceMap refined = RefineGrayCodeSubpixel(frames, Decode(frames));
  DecoderOptions edges;
  edges.gray_subpixel = GraySubpixel::kEdges;
  const CorrespondenceMap decoded = Decode(frames, edges);
  const CorrespondenceMap twice = RefineGrayCodeSubpixel(frames, decoded);
  const auto differing = [](const cv::Mat& a, const cv::Mat& b) {
    int count = 0;
    for (int y = 0; y < a.rows; ++y) {
      for (int x = 0; x < a.cols; ++x) {
        const float u = a.at<float>(y, x), v = b.at<float>(y, x);
        count += !(u == v || (std::isnan(u) && std::isnan(v)));
      }
    }
    return count;
  };
  EXPECT_GT(differing(refined.proj_x, Decode(frames).proj_x), 1000);  // it does refine
  EXPECT_EQ(differing(decoded.proj_x, refined.proj_x), 0);
  EXPECT_EQ(differing(decoded.proj_y, refined.proj_y), 0);
  EXPECT_EQ(differing(twice.proj_x, decoded.proj_x), 0);
  EXPECT_EQ(differing(twice.proj_y, decoded.proj_y), 0);
}

}  // namespace
}  // namespace sope
