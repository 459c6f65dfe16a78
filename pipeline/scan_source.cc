#include "pipeline/scan_source.h"

#include <utility>

#include <spdlog/spdlog.h>

#include "calibration/scan.h"
#include "core/error.h"
#include "core/stopwatch.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

double NowMs() { return Stopwatch::NowMs(CLOCK_MONOTONIC); }  // core/stopwatch.h

RigSession::Progress SessionProgress(const CaptureProgress& progress) {
  if (!progress) return {};
  return [progress](size_t done, size_t total) { progress(done, total); };
}

void CheckPatternSize(const PatternOptions& patterns, const RigCalibration& calibration) {
  patterns.Check();
  SOPE_CHECK(patterns.projector_width == calibration.projector.width &&
                 patterns.projector_height == calibration.projector.height,
             "patterns for a {}x{} projector, but the calibration's projector is {}x{}",
             patterns.projector_width, patterns.projector_height, calibration.projector.width,
             calibration.projector.height);
}

}  // namespace

FrameSetDirectorySource::FrameSetDirectorySource(std::vector<std::string> directories,
                                                 std::string calibration_path)
    : directories_(std::move(directories)), calibration_path_(std::move(calibration_path)) {
  SOPE_CHECK(!directories_.empty(), "no frame-set directory given");
}

SourceScan FrameSetDirectorySource::Next(int index, const CaptureProgress&) {
  SOPE_CHECK(index >= 0 && index < size(), "frame set {} of {} asked for", index, size());
  SourceScan scan;
  const double start = NowMs();
  scan.frames = LoadFrameSet(directories_[index]);
  scan.calibration = ResolveCalibration(scan.frames, calibration_path_);
  scan.capture_ms = NowMs() - start;
  scan.calibration_source = calibration_path_.empty() ? "the calibration" : calibration_path_;
  scan.source = directories_[index];
  return scan;
}

void LiveRigSourceOptions::Check() const {
  SOPE_CHECK(!spec.empty(), "live rig: no camera given");
  calibration.Check();
  CheckPatternSize(patterns, calibration);
  rig.Check();
  session.Check();
}

LiveRigSource::LiveRigSource(const LiveRigSourceOptions& options) : options_(options) {
  options_.Check();
  sequence_ = GeneratePatterns(options_.patterns);
  rig_ = OpenLiveRig(options_.spec, options_.calibration, options_.rig);
  session_ = std::make_unique<RigSession>(rig_.GetDisplay(), rig_.GetCamera(), options_.session);
}

SourceScan LiveRigSource::Next(int index, const CaptureProgress& progress) {
  SOPE_CHECK(size() < 0 || index < size(), "a recording holds one scan; scan {} asked for",
             index);
  SourceScan scan;
  scan.calibration = options_.calibration;
  scan.calibration_source = options_.calibration_source;
  scan.source = options_.spec;
  if (rig_.is_virtual()) {
    // The built-in scene: the mug of seed 0 before a backdrop 0.15 m behind its centre.
    const Scene demo = MakeDemoScene();
    scan.truth = ScanTruth{"mug", 0, demo.objects[0].mesh, demo.objects[0].cam_from_model};
    ObjectSegmentationOptions band;
    band.max_range = kDefaultWorkingDistance + 0.1;
    scan.band = band;
  }
  const double start = NowMs();
  if (options_.record_directory.empty()) {
    scan.frames = session_->Capture(sequence_, SessionProgress(progress));
  } else {
    scan.frames = session_->Record(sequence_, options_.record_directory, &options_.calibration,
                                   SessionProgress(progress));
    spdlog::info("recorded {} frames -> {}", scan.frames.images.size(),
                 options_.record_directory);
  }
  scan.capture_ms = NowMs() - start;
  return scan;
}

void VirtualSceneSourceOptions::Check() const {
  calibration.Check();
  scenes.Check();
  CheckPatternSize(patterns, calibration);
  rig.Check();
  session.Check();
}

VirtualSceneSource::VirtualSceneSource(const VirtualSceneSourceOptions& options)
    : options_(options) {
  options_.Check();
  sequence_ = GeneratePatterns(options_.patterns);
  scene_ = MakeRecognitionScene(options_.seed, options_.calibration.camera, options_.scenes);
  rig_ = OpenLiveRig("virtual", options_.calibration, options_.rig, &scene_.scene);
  session_ = std::make_unique<RigSession>(rig_.GetDisplay(), rig_.GetCamera(), options_.session);
}

SourceScan VirtualSceneSource::Next(int index, const CaptureProgress& progress) {
  SOPE_CHECK(index >= 0, "scan index must be ≥ 0, got {}", index);
  const uint64_t seed = options_.seed + static_cast<uint64_t>(index);
  if (index > 0) {
    scene_ = MakeRecognitionScene(seed, options_.calibration.camera, options_.scenes);
    rig_.virtual_rig.rig->SetScene(scene_.scene);
  }
  spdlog::info("scan {}: virtual scene {}: {} at {:.2f} m", index, seed, scene_.Description(),
               scene_.cam_from_model.translation.norm());
  SourceScan scan;
  scan.calibration = options_.calibration;
  scan.source = "virtual";
  scan.truth = ScanTruth{ToString(scene_.object_class), scene_.instance_seed, scene_.mesh,
                         scene_.cam_from_model};
  scan.band = scene_.segmentation;
  const double start = NowMs();
  scan.frames = session_->Capture(sequence_, SessionProgress(progress));
  scan.capture_ms = NowMs() - start;
  return scan;
}

std::vector<ObjectClass> ProceduralClassesIn(const Database& database) {
  std::vector<ObjectClass> classes;
  for (const std::string& name : database.classes()) {
    for (ObjectClass cls : AllObjectClasses()) {
      if (ToString(cls) == name) classes.push_back(cls);
    }
  }
  return classes;
}

void RestrictScenesToObject(const std::string& spec, RecognitionSceneOptions* scenes) {
  const size_t colon = spec.find(':');
  scenes->classes = {ObjectClassFromString(spec.substr(0, colon))};
  if (colon == std::string::npos) return;
  const std::string seed = spec.substr(colon + 1);
  size_t used = 0;
  try {
    scenes->instance_seed_base = std::stoull(seed, &used);
  } catch (const std::exception&) {
    used = std::string::npos;
  }
  SOPE_CHECK(used == seed.size() && !seed.empty() && seed[0] != '-',
             "object {}: the seed must be a number", spec);
  scenes->instance_count = 1;
}

}  // namespace sope
