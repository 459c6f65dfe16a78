#include "calibration/scan.h"

#include <chrono>

#include "core/error.h"
#include "core/file_util.h"
#include "decoder/phase_decoder.h"

namespace sope {
namespace {

double MillisecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

// Triangulates result->correspondences, coloured by the white frame (colour when
// available, else `texture`).
void Triangulate(const FrameSet& frames, const Triangulator& triangulator, const cv::Mat& texture,
                 ScanResult* result) {
  cv::Mat white = frames.white_color;
  if (white.empty()) {
    if (const auto index = frames.manifest.Find(FrameRole::kWhite)) white = frames.images[*index];
  }
  if (white.empty()) white = texture;
  const auto start = std::chrono::steady_clock::now();
  result->triangulation = triangulator.Triangulate(result->correspondences, white);
  result->triangulate_ms = MillisecondsSince(start);
}

}  // namespace

void CheckCalibrationMatchesFrames(const RigCalibration& calibration,
                                   const FrameSetManifest& manifest,
                                   const std::string& calibration_source) {
  SOPE_CHECK(calibration.camera.width == manifest.camera_width &&
                 calibration.camera.height == manifest.camera_height,
             "calibration {}: camera is {}x{} but the frames are {}x{}", calibration_source,
             calibration.camera.width, calibration.camera.height, manifest.camera_width,
             manifest.camera_height);
  SOPE_CHECK(calibration.projector.width == manifest.projector_width &&
                 calibration.projector.height == manifest.projector_height,
             "calibration {}: projector is {}x{} but the frames code a {}x{} projector",
             calibration_source, calibration.projector.width, calibration.projector.height,
             manifest.projector_width, manifest.projector_height);
}

RigCalibration ResolveCalibration(const FrameSet& frames, const std::string& calibration_path) {
  std::string path = calibration_path;
  if (path.empty()) {
    SOPE_CHECK(!frames.manifest.calibration.empty(),
               "no calibration: pass --calibration or name one in {}/frames.json",
               frames.directory);
    path = JoinPath(frames.directory, frames.manifest.calibration);
  }
  const RigCalibration calibration = ReadRigCalibration(path);
  CheckCalibrationMatchesFrames(calibration, frames.manifest, path);
  return calibration;
}

ScanResult ScanFrameSet(const FrameSet& frames, const Triangulator& triangulator,
                        const DecoderOptions& decoder_options) {
  CheckCalibrationMatchesFrames(triangulator.calibration(), frames.manifest, "(given)");
  ScanResult result;
  auto start = std::chrono::steady_clock::now();
  PhaseDecodeImages phase_images;  // phase sets: the texture when there is no white frame
  if (frames.manifest.HasPhase()) {
    DecoderOptions options = decoder_options;
    if (options.phase.use_calibration_response && options.phase.response.IsIdentity()) {
      options.phase.response = triangulator.calibration().projector_response;
    }
    DecodePhase(frames, options, &result.correspondences, &phase_images);
  } else {
    result.correspondences = Decode(frames, decoder_options);
  }
  result.decode_ms = MillisecondsSince(start);
  Triangulate(frames, triangulator, phase_images.texture, &result);
  return result;
}

ScanResult ScanDecoded(const FrameSet& frames, CorrespondenceMap correspondences,
                       double decode_ms, const Triangulator& triangulator) {
  CheckCalibrationMatchesFrames(triangulator.calibration(), frames.manifest, "(given)");
  ScanResult result;
  result.correspondences = std::move(correspondences);
  result.decode_ms = decode_ms;
  Triangulate(frames, triangulator, cv::Mat(), &result);
  return result;
}

ScanResult ScanFrameSet(const FrameSet& frames, const RigCalibration& calibration,
                        const ScanOptions& options) {
  options.Check();
  return ScanFrameSet(frames, Triangulator(calibration, options.triangulation), options.decoder);
}

}  // namespace sope
