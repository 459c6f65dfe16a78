#include "pipeline/scan_source.h"

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <system_error>
#include <utility>

#include <fmt/format.h>
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
    scan.truth = ScanTruth{"mug", 0, demo.objects[0].mesh, demo.objects[0].cam_from_model, {}, {}};
    scan.truth->objects.push_back({"mug_0", "mug", 0, true, demo.objects[0].mesh,
                                   demo.objects[0].cam_from_model, 1.0, 1});
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
                         scene_.cam_from_model, {}, {}};
  scan.truth->objects.push_back({fmt::format("{}_{}", ToString(scene_.object_class),
                                             scene_.instance_seed),
                                 ToString(scene_.object_class), scene_.instance_seed, true,
                                 scene_.mesh, scene_.cam_from_model, 1.0, 1});
  scan.band = scene_.segmentation;
  const double start = NowMs();
  scan.frames = session_->Capture(sequence_, SessionProgress(progress));
  scan.capture_ms = NowMs() - start;
  return scan;
}

void VirtualTableSourceOptions::Check() const {
  calibration.Check();
  SOPE_CHECK(objects >= 0 && objects <= kMaxTableObjects,
             "table scenes: objects per scene must be in [0, {}] (0 = 3-5), got {}",
             kMaxTableObjects, objects);
  SOPE_CHECK(instance_count >= 1, "table scenes: instance count must be ≥ 1, got {}",
             instance_count);
  TableSceneOptions check = table;
  TableObjectSpec placeholder;  // the procedural objects are drawn per scene
  placeholder.spec = "builtin:mug";
  if (check.objects.empty()) check.objects.resize(std::max(objects, 1), placeholder);
  check.Check();
  sensor.Check();
  CheckPatternSize(patterns, calibration);
  rig.Check();
  session.Check();
}

TableSceneOptions VirtualTableSource::SceneOptions(int index, int draw) const {
  TableSceneOptions table = options_.table;
  table.seed = options_.seed + static_cast<uint64_t>(index);
  if (!table.objects.empty()) return table;
  // Procedural objects drawn from the scene seed (SplitMix64 as everywhere in sope).
  uint64_t state = table.seed * 0xD1B54A32D192ED03ull + 0x0B1EC75 +
                   static_cast<uint64_t>(draw) * 0x9E3779B97F4A7C15ull;
  auto next = [&state] {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  };
  const std::vector<ObjectClass> classes =
      options_.classes.empty() ? AllObjectClasses() : options_.classes;
  const int count = options_.objects > 0 ? options_.objects : 3 + static_cast<int>(next() % 3);
  for (int k = 0; k < count; ++k) {
    const ObjectClass cls = classes[next() % classes.size()];
    const uint64_t instance =
        options_.instance_seed_base + next() % static_cast<uint64_t>(options_.instance_count);
    TableObjectSpec object;
    object.spec = fmt::format("builtin:{}:{}", ToString(cls), instance);
    table.objects.push_back(object);
  }
  return table;
}

ScanTruth TableSceneTruth(const TableScene& scene) {
  ScanTruth truth;
  truth.table_plane_in_cam = scene.table_plane_in_cam;
  const ScanObjectTruth* best = nullptr;
  int best_pixels = -1;
  for (const TableObjectTruth& object : scene.objects) {
    ScanObjectTruth out;
    out.model = object.model;
    out.class_name = object.class_name;
    const size_t colon = object.spec.rfind(':');
    if (object.spec.rfind("builtin:", 0) == 0 && colon > 8) {
      out.instance_seed = std::strtoull(object.spec.c_str() + colon + 1, nullptr, 10);
    }
    out.known = object.known;
    out.mesh = object.mesh;
    out.cam_from_model = object.cam_from_model;
    out.visible_fraction = object.visible_fraction;
    out.gt_object_id = object.scene_index + 1;
    truth.objects.push_back(std::move(out));
  }
  for (size_t i = 0; i < scene.objects.size(); ++i) {
    if (scene.objects[i].known && scene.objects[i].visible_pixels > best_pixels) {
      best_pixels = scene.objects[i].visible_pixels;
      best = &truth.objects[i];
    }
  }
  if (best != nullptr) {
    truth.class_name = best->class_name;
    truth.instance_seed = best->instance_seed;
    truth.mesh = best->mesh;
    truth.cam_from_model = best->cam_from_model;
  }
  return truth;
}

TableScene VirtualTableSource::MakeScene(int index) const {
  // Procedural objects that do not fit together (two shoe boxes and a saucepan) are drawn
  // again; given meshes that do not fit are the caller's error.
  const int draws = options_.table.objects.empty() ? kProceduralDraws : 1;
  for (int draw = 0;; ++draw) {
    try {
      return MakeTableScene(SceneOptions(index, draw), options_.calibration);
    } catch (const Error& e) {
      if (draw + 1 >= draws) throw;
      spdlog::debug("table scene {}: {}; drawing other objects", index, e.what());
    }
  }
}

VirtualTableSource::VirtualTableSource(const VirtualTableSourceOptions& options)
    : options_(options) {
  options_.Check();
  sequence_ = GeneratePatterns(options_.patterns);
  scene_ = MakeScene(0);
  VirtualCameraOptions camera;
  camera.delay_frames = options_.rig.virtual_delay_frames;
  camera.readout_jitter = options_.rig.virtual_jitter * camera.frame_period;
  rig_.virtual_rig = MakeVirtualLiveRig(options_.calibration, scene_.scene, options_.sensor, camera);
  session_ = std::make_unique<RigSession>(rig_.GetDisplay(), rig_.GetCamera(), options_.session);
}

SourceScan VirtualTableSource::Next(int index, const CaptureProgress& progress) {
  SOPE_CHECK(index >= 0, "scan index must be ≥ 0, got {}", index);
  if (index > 0) {
    scene_ = MakeScene(index);
    rig_.virtual_rig.rig->SetScene(scene_.scene);
  }
  ComputeVisibleFractions(rig_.virtual_rig.rig->ground_truth().object_id,
                          options_.calibration.camera, &scene_);
  std::string names;
  for (const TableObjectTruth& object : scene_.objects) {
    names += fmt::format("{}{} ({:.0f}% visible)", names.empty() ? "" : ", ",
                         object.known ? object.model : object.model + ", unknown",
                         100 * object.visible_fraction);
  }
  spdlog::info("scan {}: table scene {}: camera {:.0f}° down, {}", index,
               options_.seed + static_cast<uint64_t>(index), scene_.camera_tilt_deg, names);
  for (const TableObjectTruth& object : scene_.objects) {
    const Eigen::Vector3d& t = object.cam_from_model.translation;
    const Eigen::Vector3d z = object.cam_from_model.rotation.col(2);
    spdlog::debug("scan {}: truth {}: model origin ({:.4f}, {:.4f}, {:.4f}), model z axis "
                  "({:.3f}, {:.3f}, {:.3f})", index, object.model, t.x(), t.y(), t.z(), z.x(),
                  z.y(), z.z());
  }
  SourceScan scan;
  scan.calibration = options_.calibration;
  scan.source = "virtual table";
  scan.truth = TableSceneTruth(scene_);
  scan.tabletop = true;
  // No range band from the truth: the tabletop path segments by the table itself.
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

void NameAsInDatabase(const Database& database, TableObjectSpec* spec) {
  if (!spec->model.empty() || !spec->class_name.empty()) return;
  for (const ModelRecord& model : database.models()) {
    std::error_code error;
    const bool same = model.source_path == spec->spec ||
                      (!model.source_path.empty() && !spec->spec.empty() &&
                       std::filesystem::equivalent(model.source_path, spec->spec, error) &&
                       !error);
    if (!same) continue;
    spec->model = model.name;
    spec->class_name = model.class_name;
    return;
  }
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
