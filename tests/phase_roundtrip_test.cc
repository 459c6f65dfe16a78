// Phase shift end to end on the virtual rig (issue 10): the scenes of the Gray round trip
// (tilted plane, sphere before a backdrop, shared meshes) rendered with a projector of
// gamma 2.2 (linear camera, the default sensor noise), decoded and triangulated, against
// the simulator's ground truth and against the Gray code on the same scene and rig.
// Acceptance: ≥ 99% of the lit pixels decoded; median |projector coordinate − truth|
// ≤ 0.05 px for a 3-frequency 4-step set (all scenes); median depth error ≤ ⅓ of the Gray code's;
// ≤ 0.1% of the decoded pixels more than 1 px off. Gamma: the uncorrected 4-step phase
// error has its ripple at 4× the phase; with the response measured from a grey ramp the
// depth error's ripple component is ≤ ¼ of the uncorrected one.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "calibration/projector_response_calibration.h"
#include "calibration/scan.h"
#include "core/mesh.h"
#include "core/statistics.h"
#include "decoder/phase_decoder.h"
#include "projector/patterns.h"
#include "simulator/primitives.h"
#include "simulator/scene_builder.h"
#include "simulator/virtual_rig.h"
#include "tests/test_support.h"

namespace sope {
namespace {

constexpr double kTwoPi = 6.283185307179586476925286766559;
constexpr double kProjectorGamma = 2.2;
// The small rig's projector is 256×192: three frequencies, ratio 8 then 4.
const std::vector<double> kPeriods = {256, 32, 8};
// The gamma tests: a finest period well above the projector's blur, where the harmonics
// the response adds reach the camera undamped (see MeasuredResponseRemovesTheGammaRipple).
const std::vector<double> kRipplePeriods = {256, 32};

SensorOptions PhaseSensor() {
  SensorOptions options;  // default noise, defocus, blur, supersampling
  options.gamma = 1.0;    // a linear (machine-vision) camera: the projector's gamma shows
  options.projector_gamma = kProjectorGamma;
  return options;
}

FrameSet CaptureSequence(VirtualRig& rig, const PatternOptions& patterns) {
  const RigCalibration& calibration = rig.calibration();
  FrameSet frames;
  frames.manifest =
      MakePatternManifest(patterns, calibration.camera.width, calibration.camera.height);
  for (const Pattern& pattern : GeneratePatterns(patterns)) {
    frames.images.push_back(rig.Capture(pattern.image));
  }
  return frames;
}

PatternOptions PhasePatterns(const RigCalibration& calibration,
                             const std::vector<double>& periods = kPeriods) {
  PatternOptions patterns;
  patterns.projector_width = calibration.projector.width;
  patterns.projector_height = calibration.projector.height;
  patterns.family = PatternFamily::kPhase;
  patterns.periods = periods;
  patterns.steps = 4;
  patterns.white_black = false;  // the mask from the modulation
  return patterns;
}

PatternOptions GrayPatterns(const RigCalibration& calibration) {
  PatternOptions patterns;
  patterns.projector_width = calibration.projector.width;
  patterns.projector_height = calibration.projector.height;
  return patterns;
}

// The rig's response, measured once from a grey ramp on a white wall (the calibration
// step `sope calibrate-gamma` runs).
const ProjectorResponse& MeasuredResponse() {
  static const ProjectorResponse response = [] {
    VirtualRig rig(testing::SmallRig(), PhaseSensor());
    Scene wall;
    wall.objects.push_back(MakeBackdrop(0.6, 1.5, 1.0, 0.9));
    rig.SetScene(wall);
    ResponseCalibrationOptions options;
    std::vector<cv::Mat> captures;
    for (const cv::Mat& pattern : GreyRampPatterns(rig.calibration().projector.width,
                                                   rig.calibration().projector.height,
                                                   options.levels)) {
      captures.push_back(rig.Capture(pattern));
    }
    const ResponseCalibrationSummary summary = MeasureProjectorResponse(captures, options);
    std::printf("[ramp] %s\n", summary.BriefReport().c_str());
    return summary.response;
  }();
  return response;
}

struct Figures {
  size_t lit = 0;
  double decoded_fraction = 0;       // of the lit pixels
  double median_coordinate_error = 0;  // px, both axes pooled, decoded lit pixels
  double outlier_fraction = 0;       // of decoded lit pixels, > 1 px off on an axis
  double unlit_fraction = 0;         // of decoded pixels, not lit (edges, shadow borders)
  double median_depth_error = 0;     // metres
};

Figures Evaluate(const GroundTruth& truth, const ScanResult& result) {
  const CorrespondenceMap& map = result.correspondences;
  Figures figures;
  size_t decoded = 0, decoded_lit = 0, outliers = 0, unlit = 0;
  std::vector<double> coordinate_errors, depth_errors;
  for (int y = 0; y < truth.lit.rows; ++y) {
    for (int x = 0; x < truth.lit.cols; ++x) {
      const bool lit = truth.lit.at<uint8_t>(y, x) != 0;
      const bool valid = map.mask.at<uint8_t>(y, x) != 0;
      figures.lit += lit;
      if (!valid) continue;
      ++decoded;
      if (!lit) {
        ++unlit;
        continue;
      }
      const float true_x = truth.proj_x.at<float>(y, x), true_y = truth.proj_y.at<float>(y, x);
      bool off = false;
      for (const auto& [image, truth_value] : {std::pair{&map.proj_x, true_x}, {&map.proj_y, true_y}}) {
        if (image->empty() || !std::isfinite(truth_value)) continue;
        const double error = std::abs(image->at<float>(y, x) - truth_value);
        off = off || error > 1.0;
        coordinate_errors.push_back(error);
      }
      outliers += off;
      ++decoded_lit;
      const float depth = result.triangulation.depth.at<float>(y, x);
      if (std::isfinite(depth)) depth_errors.push_back(std::abs(depth - truth.depth.at<float>(y, x)));
    }
  }
  figures.decoded_fraction = figures.lit ? static_cast<double>(decoded_lit) / figures.lit : 0.0;
  figures.outlier_fraction = decoded_lit ? static_cast<double>(outliers) / decoded_lit : 1.0;
  figures.unlit_fraction = decoded ? static_cast<double>(unlit) / decoded : 0.0;
  figures.median_coordinate_error = Median(coordinate_errors);
  figures.median_depth_error = Median(depth_errors);
  return figures;
}

void Print(const std::string& name, const Figures& f) {
  std::printf("[%s] lit %zu, decoded %.3f%%, median |proj err| %.4f px, > 1 px %.4f%% (of "
              "decoded lit), decoded but not lit %.3f%%, median |dz| %.4f mm\n",
              name.c_str(), f.lit, 100 * f.decoded_fraction, f.median_coordinate_error,
              100 * f.outlier_fraction, 100 * f.unlit_fraction, 1e3 * f.median_depth_error);
}

// Phase (3 frequencies, 4 steps, measured response) and Gray code on one scene, the
// decoder's defaults (the edge-preserving 3×3 local fit of the coordinate included; see
// NoiseNotBiasLimitsThePerPixelCoordinate for why it is needed before the backdrops).
void RunScene(const Scene& scene, const std::string& name) {
  const RigCalibration calibration = testing::SmallRig();
  VirtualRig rig(calibration, PhaseSensor());
  rig.SetScene(scene);
  const GroundTruth& truth = rig.ground_truth();
  RigCalibration measured = calibration;
  measured.projector_response = MeasuredResponse();

  const FrameSet phase_frames = CaptureSequence(rig, PhasePatterns(calibration));
  const Figures phase = Evaluate(truth, ScanFrameSet(phase_frames, measured));
  // The reference of the ⅓ rule is the Gray code at its stripe centres (integer codes, as
  // when issue 10 set it); scans now refine Gray codes from the stripe edges by default
  // (issue 11), printed beside it.
  const FrameSet gray_frames = CaptureSequence(rig, GrayPatterns(calibration));
  ScanOptions integer_gray;
  integer_gray.decoder.gray_subpixel = GraySubpixel::kOff;
  const Figures gray = Evaluate(truth, ScanFrameSet(gray_frames, calibration, integer_gray));
  const Figures gray_subpixel = Evaluate(truth, ScanFrameSet(gray_frames, calibration));
  Print(name + " phase 256,32,8 x4", phase);
  Print(name + " gray (stripe centres)", gray);
  Print(name + " gray (sub-pixel edges)", gray_subpixel);
  ::testing::Test::RecordProperty(name + "_phase_median_px",
                                  std::to_string(phase.median_coordinate_error));
  ::testing::Test::RecordProperty(name + "_depth_ratio",
                                  std::to_string(phase.median_depth_error / gray.median_depth_error));
  EXPECT_GT(phase.lit, 5000u) << "scene barely visible: test would prove little";
  EXPECT_GE(phase.decoded_fraction, 0.99);
  EXPECT_LE(phase.median_coordinate_error, 0.05);
  EXPECT_LE(phase.outlier_fraction, 0.001);
  EXPECT_LE(phase.median_depth_error, gray.median_depth_error / 3.0);
}

TEST(PhaseRoundTrip, TiltedPlane) {
  Scene scene;
  Placement placement;
  placement.rotation = RotationFromEulerXYZ(0.3, -0.4, 0.1);
  scene.objects.push_back(PlaceObject(MakePlane(0.5, 0.4, 4), placement));
  RunScene(scene, "plane");
}

Scene SphereScene();

TEST(PhaseRoundTrip, SphereBeforeBackdrop) { RunScene(SphereScene(), "sphere"); }

TEST(PhaseRoundTrip, SharedMeshes) {
  SOPE_REQUIRE_SHARED_DATA(data);
  for (const char* name : {"ycb/MustardBottle.obj", "classic/spot.obj"}) {
    Scene scene;
    Placement placement;
    placement.rotation = RotationFromEulerXYZ(-1.2, 0.5, 0.2);
    placement.center_in_cam = Eigen::Vector3d(0.0, 0.0, 0.6);
    placement.size = 0.25;
    scene.objects.push_back(PlaceObject(ReadMesh(data + "/meshes/" + name), placement));
    scene.objects.push_back(MakeBackdrop(0.75, 1.5, 1.0));
    SCOPED_TRACE(name);
    RunScene(scene, name);
  }
}

Scene SphereScene() {
  Scene scene;
  Placement placement;
  placement.center_in_cam = Eigen::Vector3d(0.0, 0.0, 0.58);
  scene.objects.push_back(PlaceObject(MakeSphere(0.08, 48, 96), placement));
  scene.objects.push_back(MakeBackdrop(0.72, 1.5, 1.0));
  return scene;
}

// Why the scenes before a backdrop missed 0.05 px with per-pixel coordinates (0.060–0.065
// px against the plane's 0.043): not the curvature. Without sensor noise the per-pixel
// decode of the sphere scene is within 0.0085 px median of the truth at the pixel centre
// (low- and high-slope pixels alike: 0.010 / 0.013 px), so the truth is consistent with
// the rendering (footprint, blur, defocus) and the response correction works; with noise
// it is 0.060 px, on the backdrop (0.72 m, albedo 0.6: ~80% of the lit pixels) 0.063 px
// against 0.039 px on the brighter sphere — shot noise on a dimmer surface. Combining the
// frequencies by their variances gains ≈ 3% (the 32-px group's variance is 16× the 8-px
// one's); the edge-preserving local fit of the coordinate (PhaseDecoderOptions::
// local_fit_radius) averages the independent per-pixel noise: ~3× on plane patches. Its
// price, a bias ≈ (u_xx + u_yy)/3 on strongly curved patches (the sphere's rim: 0.04 px
// without noise), stays below the noise it removes there.
TEST(PhaseRoundTrip, NoiseNotBiasLimitsThePerPixelCoordinate) {
  const RigCalibration calibration = testing::SmallRig();
  RigCalibration measured = calibration;
  measured.projector_response = MeasuredResponse();
  ScanOptions per_pixel;
  per_pixel.decoder.phase.local_fit_radius = 0;
  const Scene scene = SphereScene();
  SensorOptions noiseless = PhaseSensor();
  noiseless.read_noise = 0;
  noiseless.shot_noise = 0;
  Figures figures[2][2];  // [noisy][fitted]
  for (int noisy = 0; noisy < 2; ++noisy) {
    VirtualRig rig(calibration, noisy ? PhaseSensor() : noiseless);
    rig.SetScene(scene);
    const FrameSet frames = CaptureSequence(rig, PhasePatterns(calibration));
    figures[noisy][0] = Evaluate(rig.ground_truth(), ScanFrameSet(frames, measured, per_pixel));
    figures[noisy][1] = Evaluate(rig.ground_truth(), ScanFrameSet(frames, measured));
    Print(std::string("sphere ") + (noisy ? "noisy" : "noiseless") + " per-pixel", figures[noisy][0]);
    Print(std::string("sphere ") + (noisy ? "noisy" : "noiseless") + " local fit", figures[noisy][1]);
  }
  EXPECT_LE(figures[0][0].median_coordinate_error, 0.015);  // the bias: small
  EXPECT_GE(figures[1][0].median_coordinate_error, 4 * figures[0][0].median_coordinate_error);
  EXPECT_LE(figures[1][1].median_coordinate_error, 0.5 * figures[1][0].median_coordinate_error);
  EXPECT_LE(figures[1][1].outlier_fraction, figures[1][0].outlier_fraction);
  EXPECT_GE(figures[1][1].decoded_fraction, figures[1][0].decoded_fraction);
}

// The gamma tests' scene: a plane tilted across the small rig's view.
Scene TiltedPlane() {
  Scene scene;
  Placement placement;
  placement.rotation = RotationFromEulerXYZ(0.1, -0.2, 0.0);
  scene.objects.push_back(PlaceObject(MakePlane(0.5, 0.4, 4), placement));
  return scene;
}

// The gamma ripple: depth error against the finest x phase, its component at 4φ.
// `rms` is the error's rms; the amplitude's standard error is rms·√(2/n) (`standard_error`).
double RippleAmplitude(const GroundTruth& truth, const ScanResult& result, double period,
                       double* rms, double* standard_error = nullptr) {
  double c = 0, s = 0, sum2 = 0;
  size_t n = 0;
  for (int y = 0; y < truth.lit.rows; ++y) {
    for (int x = 0; x < truth.lit.cols; ++x) {
      if (truth.lit.at<uint8_t>(y, x) == 0) continue;
      const float depth = result.triangulation.depth.at<float>(y, x);
      if (!std::isfinite(depth)) continue;
      const double error = depth - truth.depth.at<float>(y, x);
      const double phase = kTwoPi * truth.proj_x.at<float>(y, x) / period;
      c += error * std::cos(4 * phase);
      s += error * std::sin(4 * phase);
      sum2 += error * error;
      ++n;
    }
  }
  *rms = n ? std::sqrt(sum2 / n) : 0.0;
  if (standard_error != nullptr) *standard_error = n ? *rms * std::sqrt(2.0 / n) : 0.0;
  return n ? 2.0 * std::hypot(c, s) / n : 0.0;
}

// The 4-step phase error of a gamma-2.2 projector repeats at 4× the phase. The decoder's
// correction assumes the harmonics the response adds reach the camera as they are; at a
// period within a few projector blur widths (the 3-frequency set's 8 px, blur σ 0.5 px
// plus the camera footprint) they are mostly blurred away and so is the ripple (measured
// there: 0.01 mm against 0.20 mm of noise), and correcting over-corrects a little, harmless
// (ResponseCorrectionIsHarmlessAtFinePeriods); patterns can also be pre-distorted
// (PredistortedPatternsNeedNoCorrection). Measured at a finest period of 32 px, where the
// ripple is large.
TEST(PhaseRoundTrip, MeasuredResponseRemovesTheGammaRipple) {
  const RigCalibration calibration = testing::SmallRig();
  VirtualRig rig(calibration, PhaseSensor());
  rig.SetScene(TiltedPlane());
  // x only, ray–plane: the depth error follows the x phase alone.
  PatternOptions patterns = PhasePatterns(calibration, kRipplePeriods);
  patterns.axes = PatternAxes::kX;
  const FrameSet frames = CaptureSequence(rig, patterns);
  const ScanResult plain = ScanFrameSet(frames, calibration);
  RigCalibration measured = calibration;
  measured.projector_response = MeasuredResponse();
  const ScanResult corrected = ScanFrameSet(frames, measured);
  double plain_rms = 0, corrected_rms = 0, plain_se = 0, corrected_se = 0;
  const double fine = kRipplePeriods.back();
  const double plain_ripple =
      RippleAmplitude(rig.ground_truth(), plain, fine, &plain_rms, &plain_se);
  const double corrected_ripple =
      RippleAmplitude(rig.ground_truth(), corrected, fine, &corrected_rms, &corrected_se);
  std::printf("[gamma %.1f, periods 256/32] depth error ripple at 4φ: %.4f ± %.4f mm (rms "
              "%.4f mm) uncorrected, %.4f ± %.4f mm (rms %.4f mm) with the measured response "
              "(%.1f%%)\n",
              kProjectorGamma, 1e3 * plain_ripple, 1e3 * plain_se, 1e3 * plain_rms,
              1e3 * corrected_ripple, 1e3 * corrected_se, 1e3 * corrected_rms,
              100 * corrected_ripple / plain_ripple);
  ::testing::Test::RecordProperty("ripple_ratio", std::to_string(corrected_ripple / plain_ripple));
  EXPECT_GT(plain_ripple, 10 * plain_se);  // the ripple is there, far above the noise
  EXPECT_LE(corrected_ripple, 0.25 * plain_ripple);
  EXPECT_LT(corrected_rms, plain_rms);
}

// Pre-distorted patterns (PatternOptions::precompensate with the measured response)
// instead of the decoder's correction.
TEST(PhaseRoundTrip, PredistortedPatternsNeedNoCorrection) {
  const RigCalibration calibration = testing::SmallRig();
  VirtualRig rig(calibration, PhaseSensor());
  rig.SetScene(TiltedPlane());
  PatternOptions patterns = PhasePatterns(calibration, kRipplePeriods);
  patterns.axes = PatternAxes::kX;
  const ScanResult plain = ScanFrameSet(CaptureSequence(rig, patterns), calibration);
  patterns.precompensate = MeasuredResponse();
  const ScanResult predistorted = ScanFrameSet(CaptureSequence(rig, patterns), calibration);
  double plain_rms = 0, predistorted_rms = 0;
  const double plain_ripple =
      RippleAmplitude(rig.ground_truth(), plain, kRipplePeriods.back(), &plain_rms);
  const double predistorted_ripple =
      RippleAmplitude(rig.ground_truth(), predistorted, kRipplePeriods.back(), &predistorted_rms);
  std::printf("[pre-distorted, periods 256/32] ripple %.4f mm vs %.4f mm uncompensated\n",
              1e3 * predistorted_ripple, 1e3 * plain_ripple);
  EXPECT_LE(predistorted_ripple, 0.25 * plain_ripple);
}

// Fine periods (the 3-frequency set's 8 px, and 16 px): blur damps the harmonics the
// response adds, so the ripple is already small (measured 0.010 / 0.03 mm against 0.20 /
// 0.29 mm of noise) and the decoder's correction, which assumes them undamped, over-corrects
// at 8 px (0.020 mm). That must stay harmless: the corrected depth rms within 2% of the
// uncorrected one (measured +0.35% / +0.7%), so the correction can stay on for any set.
TEST(PhaseRoundTrip, ResponseCorrectionIsHarmlessAtFinePeriods) {
  const RigCalibration calibration = testing::SmallRig();
  VirtualRig rig(calibration, PhaseSensor());
  rig.SetScene(TiltedPlane());
  RigCalibration measured = calibration;
  measured.projector_response = MeasuredResponse();
  for (const std::vector<double>& periods :
       {kPeriods, std::vector<double>{256, 64, 16}}) {
    SCOPED_TRACE(periods.back());
    PatternOptions patterns = PhasePatterns(calibration, periods);
    patterns.axes = PatternAxes::kX;
    const FrameSet frames = CaptureSequence(rig, patterns);
    double plain_rms = 0, corrected_rms = 0;
    const double plain_ripple = RippleAmplitude(
        rig.ground_truth(), ScanFrameSet(frames, calibration), periods.back(), &plain_rms);
    const double corrected_ripple = RippleAmplitude(
        rig.ground_truth(), ScanFrameSet(frames, measured), periods.back(), &corrected_rms);
    std::printf("[finest period %g px] ripple %.4f mm uncorrected, %.4f mm corrected; depth rms "
                "%.4f / %.4f mm\n",
                periods.back(), 1e3 * plain_ripple, 1e3 * corrected_ripple, 1e3 * plain_rms,
                1e3 * corrected_rms);
    EXPECT_LT(plain_ripple, 0.25 * plain_rms);  // small beside the noise
    EXPECT_LE(corrected_rms, 1.02 * plain_rms);
  }
}

}  // namespace
}  // namespace sope
