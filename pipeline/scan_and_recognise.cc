#include "pipeline/scan_and_recognise.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "core/error.h"
#include "core/file_util.h"
#include "core/json.h"
#include "core/plots.h"
#include "core/point_cloud.h"
#include "core/stopwatch.h"
#include "recogniser/tools/scan_recognition.h"
#include <opencv2/imgproc.hpp>

namespace sope {
namespace {

namespace fs = std::filesystem;

// The camera's white frame (or the first frame) for the overlay.
cv::Mat WhiteImage(const FrameSet& frames) {
  if (!frames.white_color.empty()) return frames.white_color;
  const std::optional<size_t> white = frames.manifest.Find(FrameRole::kWhite);
  return frames.images.at(white ? *white : 0);
}

nlohmann::json TruthJson(const ScanReport& report) {
  const ScanTruth& truth = *report.truth;
  nlohmann::json j = {{"class", truth.class_name},
                      {"instance_seed", truth.instance_seed},
                      {"pose", Rigid3dToJson(truth.cam_from_model)},
                      {"class_correct", report.class_correct}};
  if (report.pose_error) {
    const PoseComparison& error = *report.pose_error;
    j["rotation_error_deg"] = error.rotation_error_deg;
    j["center_error_m"] = error.center_error_m;
    j["adds_m"] = error.adds_m;
    j["diameter_m"] = error.diameter_m;
  }
  return j;
}

bool Cancelled(const std::atomic<bool>* cancel) { return cancel && cancel->load(); }

// Removes what a failed scan wrote.
void RemoveFiles(const ScanFiles& files) {
  std::error_code ignored;
  for (const std::string* path : {&files.cloud, &files.object_cloud, &files.overlay}) {
    if (!path->empty()) fs::remove(*path, ignored);
  }
  for (const auto* list : {&files.object_clouds, &files.unknown_clouds}) {
    for (const std::string& path : *list) fs::remove(path, ignored);
  }
}

}  // namespace

// The frame sink of the source: every captured frame goes into an IncrementalDecoder at
// once, so that after the last frame only its bit and the finish remain (8-bit Gray-code
// sets against inverses; others are decoded after the capture as before).
struct ScanAndRecogniseController::LiveDecode {
  DecoderOptions options;
  std::unique_ptr<IncrementalDecoder> decoder;
  std::string layout;      // the serialised manifest the decoder was made for
  size_t added = 0;        // frames of the current capture in the decoder
  size_t total = 0;
  double last_frame_ms = 0.0;  // AddFrame of the last frame (after it was grabbed)
  bool failed = false;     // the decoder refused a frame: decode after the capture

  void OnFrame(const FrameSetManifest& manifest, size_t index, const cv::Mat& image) {
    if (index == 0) {
      added = 0;
      total = manifest.frames.size();
      failed = false;
      try {
        const std::string serialised = SerializeFrameSetManifest(manifest);
        if (manifest.HasPhase()) {
          decoder.reset();
        } else if (!decoder || serialised != layout) {
          decoder = std::make_unique<IncrementalDecoder>(manifest, options);
          layout = serialised;
        } else {
          decoder->Reset();
        }
      } catch (const Error&) {
        decoder.reset();
      }
    }
    if (!decoder || failed) return;
    const auto start = std::chrono::steady_clock::now();
    try {
      decoder->AddFrame(index, image);
      ++added;
    } catch (const Error&) {
      failed = true;  // Decode after the capture reports what is wrong
    }
    last_frame_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
            .count();
  }
  // The map when every frame of `frames` went in; false: decode them as a batch.
  bool Finish(const FrameSet& frames, CorrespondenceMap* map, double* decode_ms) {
    if (!decoder || failed || added != total || frames.images.size() != total ||
        SerializeFrameSetManifest(frames.manifest) != layout) {
      return false;
    }
    const auto start = std::chrono::steady_clock::now();
    decoder->Finish(map);
    *decode_ms = last_frame_ms + std::chrono::duration<double, std::milli>(
                                     std::chrono::steady_clock::now() - start)
                                     .count();
    added = 0;
    return true;
  }
};

void ScanAndRecogniseOptions::Check() const {
  scan.Check();
  recognition.Check();
  SOPE_CHECK(!min_range || (std::isfinite(*min_range) && *min_range >= 0.0),
             "range band: the near end must be ≥ 0 m, got {}", min_range.value_or(0.0));
  SOPE_CHECK(!max_range || (std::isfinite(*max_range) && *max_range > 0.0),
             "range band: the far end must be > 0 m, got {}", max_range.value_or(0.0));
  SOPE_CHECK(!min_range || !max_range || *min_range < *max_range,
             "range band: the near end ({} m) must be below the far end ({} m)",
             min_range.value_or(0.0), max_range.value_or(0.0));
  SOPE_CHECK(max_scans >= 1 || max_scans == -1,
             "number of scans must be ≥ 1 (or −1: until the source ends), got {}", max_scans);
}

ScanAndRecogniseController::ScanAndRecogniseController(const ScanAndRecogniseOptions& options,
                                                       ScanSource* source,
                                                       const Database& database)
    : options_(options),
      source_(source),
      database_(database),
      recogniser_(database),
      scene_recogniser_(database) {
  options_.Check();
  SOPE_CHECK(source_ != nullptr, "scan and recognise: no scan source");
  SOPE_CHECK(options_.shared_scene_recogniser == nullptr ||
                 &options_.shared_scene_recogniser->database() == &database,
             "scan and recognise: the shared scene recogniser is of another database");
  live_decode_ = std::make_unique<LiveDecode>();
  // Tabletop scans finish the decode themselves: code consistency only near what is not
  // the table (ScanTableFrameSet).
  live_decode_->options = options_.tabletop ? PlainTableDecoderOptions(options_.scan.decoder)
                                            : options_.scan.decoder;
  LiveDecode* live = live_decode_.get();
  source_->SetFrameSink([live](const FrameSetManifest& manifest, size_t index,
                               const cv::Mat& image) { live->OnFrame(manifest, index, image); });
}

ScanAndRecogniseController::~ScanAndRecogniseController() {
  source_->SetFrameSink({});
  stop_warm_up_ = true;
  if (warm_up_.joinable()) warm_up_.join();
}

ScanReport ScanAndRecogniseController::Scan(int index, const CaptureProgress& progress) {
  if (options_.tabletop && options_.warm_up && !warm_up_.joinable()) {
    warm_up_ = std::thread([this] {
      try {
        SceneRecogniserInUse().WarmUp(options_.scene, &stop_warm_up_);
      } catch (const std::exception& e) {
        // The recognition builds what it needs itself (and reports its own errors).
        spdlog::debug("scene recogniser warm-up stopped: {}", e.what());
      }
    });
  }
  SourceScan in = source_->Next(index, progress);
  CheckCalibrationMatchesFrames(in.calibration, in.frames.manifest, in.calibration_source);
  ScanReport report;
  report.index = index;
  report.source = in.source;
  report.capture_ms = in.capture_ms;
  report.band = in.band.value_or(ObjectSegmentationOptions());
  if (options_.min_range) report.band.min_range = *options_.min_range;
  if (options_.max_range) report.band.max_range = *options_.max_range;
  if (!triangulator_ || !source_->fixed_calibration()) {
    triangulator_ = std::make_unique<Triangulator>(in.calibration, options_.scan.triangulation);
  }
  CorrespondenceMap decoded;
  double decode_ms = 0.0;
  // Decoded during the capture: only the last frame's bit and the finish were left.
  const bool live = live_decode_->Finish(in.frames, &decoded, &decode_ms);
  if (options_.tabletop || in.tabletop) {
    ScanTable(in.frames, live ? &decoded : nullptr, decode_ms, &report);
  } else if (live) {
    report.result = RecogniseScan(ScanDecoded(in.frames, std::move(decoded), decode_ms,
                                              *triangulator_),
                                  report.band, recogniser_, options_.recognition);
  } else {
    report.result = RecogniseFrameSet(in.frames, *triangulator_, options_.scan.decoder,
                                      report.band, recogniser_, options_.recognition);
  }
  report.status = report.result.status;
  report.message = report.result.message;
  report.truth = std::move(in.truth);
  const RecognitionResult& recognition = report.result.recognition;
  if (report.scene && report.truth) {
    report.matches = MatchTableObjects(*report.scene, *report.truth, database_);
  }
  if (report.truth && !recognition.empty()) {
    const Suggestion& best = recognition.best();
    report.class_correct = best.class_name == report.truth->class_name;
    if (report.class_correct) {
      report.pose_error =
          ComparePoses(best.cam_from_model, report.truth->cam_from_model, report.truth->mesh);
    }
  }
  report.image = WhiteImage(in.frames);
  report.camera = in.calibration.camera;
  report.json = ScanReportToJson(report);
  return report;
}

void ScanAndRecogniseController::ScanTable(const FrameSet& frames, CorrespondenceMap* decoded,
                                           double decode_ms, ScanReport* report) {
  const Stopwatch watch;
  // From the last frame, as the single-object path counts it: the live decoder's finish
  // (decode_ms, before this call) and everything here.
  const auto total_ms = [&] { return (decoded != nullptr ? decode_ms : 0.0) + watch.WallMs(); };
  ScanRecognition& out = report->result;
  SceneRecognitionOptions scene_options = options_.scene;
  scene_options.recognition = options_.recognition;
  scene_options.segmentation.min_range = report->band.min_range;
  scene_options.segmentation.max_range = report->band.max_range;
  // The live decoder ran without consistency and edges in tabletop mode (constructor); a
  // table scene from a source in single-object mode was decoded in full.
  out.scan = decoded != nullptr && !options_.tabletop
                 ? ScanDecoded(frames, std::move(*decoded), decode_ms, *triangulator_)
                 : ScanTableFrameSet(frames, *triangulator_, options_.scan.decoder,
                                     scene_options.segmentation, decoded, decode_ms);
  out.timing.decode = out.scan.decode_ms;
  out.timing.triangulate = out.scan.triangulate_ms;
  const PointCloud& cloud = out.scan.triangulation.cloud;
  if (cloud.size() < 3) {
    out.status = ScanStatus::kNoPoints;
    out.message = fmt::format("no points: {} point(s) triangulated (no projector light on the "
                              "scene, or a wrong calibration?)",
                              cloud.size());
    out.timing.total = total_ms();
    return;
  }
  SceneRecognitionResult scene = SceneRecogniserInUse().Recognise(cloud, scene_options);
  out.timing.segment = scene.timing.segment;
  // Everything after the segmentation: the clusters' recognitions and verification, and
  // the scene-level steps between them (second looks' refits, joins, rolled hypotheses,
  // assembly) — so that the stages add up to frame_to_result.
  out.timing.recognise = scene.timing.total - scene.timing.segment;
  if (scene.objects.empty()) {
    out.status = ScanStatus::kNoSuggestion;
    out.message = !scene.segmentation.message.empty()
                      ? scene.segmentation.message
                      : fmt::format("no known object on the table ({} cluster(s), {} unknown)",
                                    scene.segmentation.clusters.size(), scene.unknown.size());
  } else {
    out.status = ScanStatus::kRecognised;
    out.recognition = scene.objects.front().recognition;
    for (const int i : scene.objects.front().indices) out.object.points.push_back(cloud.points[i]);
  }
  report->scene = std::move(scene);
  out.timing.total = total_ms();
}

std::vector<TableObjectMatch> MatchTableObjects(const SceneRecognitionResult& scene,
                                                const ScanTruth& truth, const Database& database) {
  std::vector<TableObjectMatch> matches(truth.objects.size());
  std::vector<PoseTruthModel> models;
  std::vector<Eigen::Vector3d> centres;
  for (size_t t = 0; t < truth.objects.size(); ++t) {
    const ScanObjectTruth& object = truth.objects[t];
    models.push_back(MakePoseTruthModel(object.mesh, {2000, 1}));
    centres.push_back(object.cam_from_model * models.back().center);
    matches[t].truth = static_cast<int>(t);
  }
  // Passes: a detection of the truth's own model, then of its class, then any — so that a
  // right detection is not taken by a neighbouring truth object that happens to come first.
  std::vector<uint8_t> used(scene.objects.size(), 0);
  for (int pass = 0; pass < 3; ++pass) {
    for (size_t t = 0; t < truth.objects.size(); ++t) {
      const ScanObjectTruth& object = truth.objects[t];
      TableObjectMatch& match = matches[t];
      if (match.detection >= 0) continue;
      double nearest = 0.5 * models[t].diameter;
      for (size_t d = 0; d < scene.objects.size(); ++d) {
        if (used[d]) continue;
        const Suggestion& s = scene.objects[d].best();
        if (pass == 0 && !(object.known && s.model_name == object.model)) continue;
        if (pass == 1 && !(object.known && s.class_name == object.class_name)) continue;
        const Eigen::Vector3d detected = s.cam_from_model * database.model(s.model).center;
        const double distance = (detected - centres[t]).norm();
        if (distance < nearest) {
          nearest = distance;
          match.detection = static_cast<int>(d);
        }
      }
      if (match.detection < 0) continue;
      used[match.detection] = 1;
      const Suggestion& s = scene.objects[match.detection].best();
      match.model_correct = object.known && s.model_name == object.model;
      match.class_correct = object.known && s.class_name == object.class_name;
      if (match.class_correct) {
        match.pose_error = ComparePoses(s.cam_from_model, object.cam_from_model, models[t]);
        match.correct = match.model_correct && match.pose_error->adds_over_diameter() < 0.1;
      }
    }
  }
  return matches;
}

int ScanAndRecogniseController::Run(const ScanCallback& callback,
                                    const CaptureProgress& progress) {
  int done = 0;
  for (int index = 0; options_.max_scans < 0 || index < options_.max_scans; ++index) {
    if (source_->size() >= 0 && index >= source_->size()) break;
    if (Cancelled(options_.cancel)) break;
    ScanReport report;
    try {
      report = Scan(index, progress);
    } catch (const Error&) {
      // Ctrl-C during a capture ends a multi-scan run that has results.
      if (Cancelled(options_.cancel) && options_.max_scans != 1 && done > 0) break;
      throw;
    }
    if (options_.fail_on_nothing_found && (report.status == ScanStatus::kNoPoints ||
                                           report.status == ScanStatus::kNothingInBand)) {
      throw Error(report.message);
    }
    if (!options_.out_dir.empty()) WriteScanOutputs(options_.out_dir, database_, &report);
    if (callback) callback(report);
    ++done;
  }
  if (!options_.out_dir.empty()) spdlog::info("{} scan(s) -> {}", done, options_.out_dir);
  if (Cancelled(options_.cancel)) spdlog::info("stopped after {} scan(s) (interrupted)", done);
  return done;
}

void WriteScanOutputs(const std::string& out_dir, const Database& database, ScanReport* report) {
  const std::string stem = fmt::format("scan_{:04d}", report->index);
  const PointCloud& cloud = report->result.scan.triangulation.cloud;
  const PointCloud& object = report->result.object;
  ScanFiles& files = report->files;
  try {
    if (!cloud.empty()) {
      files.cloud = JoinPath(out_dir, stem + ".ply");
      WritePointCloud(files.cloud, cloud);
    }
    if (!object.empty()) {
      files.object_cloud = JoinPath(out_dir, stem + "_object.ply");
      WritePointCloud(files.object_cloud, object);
    }
    if (report->scene) {
      auto subset = [&cloud](const std::vector<int>& indices) {
        PointCloud part;
        for (const int i : indices) {
          part.points.push_back(cloud.points[i]);
          if (cloud.HasColors()) part.colors.push_back(cloud.colors[i]);
        }
        return part;
      };
      for (size_t k = 0; k < report->scene->objects.size(); ++k) {
        files.object_clouds.push_back(JoinPath(out_dir, fmt::format("{}_object_{}.ply", stem, k)));
        WritePointCloud(files.object_clouds.back(), subset(report->scene->objects[k].indices));
      }
      for (size_t k = 0; k < report->scene->unknown.size(); ++k) {
        files.unknown_clouds.push_back(
            JoinPath(out_dir, fmt::format("{}_unknown_{}.ply", stem, k)));
        WritePointCloud(files.unknown_clouds.back(), subset(report->scene->unknown[k].indices));
      }
    }
    files.overlay = JoinPath(out_dir, stem + "_overlay.png");
    WriteImageAtomic(files.overlay, DrawScanOverlay(*report, database));
    report->json = ScanReportToJson(*report);
    AppendLine(JoinPath(out_dir, "results.jsonl"), report->json);
  } catch (const Error&) {
    RemoveFiles(files);  // no files without their results line
    throw;
  }
}

std::string ScanReportToJson(const ScanReport& report) {
  const ScanRecognition& result = report.result;
  nlohmann::json j = nlohmann::json::parse(RecognitionResultToJson(result.recognition));
  j["status"] = ToString(report.status);
  nlohmann::json& timing = j["timing_ms"];
  timing["capture"] = report.capture_ms;
  timing["decode"] = result.timing.decode;
  timing["triangulate"] = result.timing.triangulate;
  timing["segment"] = result.timing.segment;
  timing["recognise"] = result.timing.recognise;
  timing["frame_to_result"] = result.timing.total;
  j["scan"] = {{"index", report.index},
               {"source", report.source},
               {"points", result.scan.triangulation.cloud.size()},
               {"object_points", result.object.size()},
               {"range_band_m", {report.band.min_range, report.band.max_range}}};
  if (report.status != ScanStatus::kRecognised) {
    j["message"] = report.message;
    j["objects"] = nlohmann::json::array();  // DESIGN.md: nothing recognised
  }
  if (report.scene) {
    // Tabletop: every object (DESIGN.md "objects"), the unknown ones, the table.
    const nlohmann::json scene = nlohmann::json::parse(SceneRecognitionResultToJson(*report.scene));
    for (const char* key : {"objects", "unknown", "table", "clusters", "background", "hypotheses",
                            "scene_ms"}) {
      j[key] = scene[key];
    }
    for (size_t k = 0; k < report.files.object_clouds.size() && k < j["objects"].size(); ++k) {
      j["objects"][k]["cloud"] = report.files.object_clouds[k];
    }
  }
  if (report.truth) {
    j["ground_truth"] = TruthJson(report);
    if (report.scene) {
      nlohmann::json truth_objects = nlohmann::json::array();
      for (const TableObjectMatch& m : report.matches) {
        const ScanObjectTruth& t = report.truth->objects[m.truth];
        nlohmann::json o = {{"model", t.model},
                            {"class", t.class_name},
                            {"known", t.known},
                            {"visible_fraction", t.visible_fraction},
                            {"pose", Rigid3dToJson(t.cam_from_model)},
                            {"detection", m.detection},
                            {"model_correct", m.model_correct},
                            {"class_correct", m.class_correct},
                            {"correct", m.correct}};
        if (m.pose_error) {
          o["rotation_error_deg"] = m.pose_error->rotation_error_deg;
          o["center_error_m"] = m.pose_error->center_error_m;
          o["adds_m"] = m.pose_error->adds_m;
          o["diameter_m"] = m.pose_error->diameter_m;
        }
        truth_objects.push_back(std::move(o));
      }
      j["ground_truth"]["objects"] = std::move(truth_objects);
    }
  }
  const ScanFiles& files = report.files;
  if (!files.overlay.empty()) {
    nlohmann::json f = {{"overlay", files.overlay}};
    if (!files.cloud.empty()) f["cloud"] = files.cloud;
    if (!files.object_cloud.empty()) f["object_cloud"] = files.object_cloud;
    j["files"] = f;
  }
  return j.dump();
}

std::string ScanReportToText(const ScanReport& report) {
  const ScanRecognition& result = report.result;
  std::string text;
  if (report.scene && report.status == ScanStatus::kRecognised) {
    text = fmt::format("scan {}:", report.index);
    for (const RecognisedObject& object : report.scene->objects) {
      text += fmt::format(" {} ({}, {:.2f}, {} points);", object.best().class_name,
                          object.best().model_name, object.best().score, object.indices.size());
    }
    text += fmt::format(" {} unknown; frame to result {:.0f} ms (decode {:.0f}, triangulate "
                        "{:.0f}, segment {:.0f}, recognise {:.0f})",
                        report.scene->unknown.size(), result.timing.total, result.timing.decode,
                        result.timing.triangulate, result.timing.segment, result.timing.recognise);
    if (report.truth) {
      int right = 0, known = 0;
      for (const TableObjectMatch& m : report.matches) {
        known += report.truth->objects[m.truth].known;
        right += m.correct;
      }
      text += fmt::format("; truth: {} of {} known objects right", right, known);
    }
    return text;
  }
  if (report.status == ScanStatus::kRecognised) {
    const Suggestion& best = result.recognition.best();
    text = fmt::format("scan {}: {} ({}), score {:.2f}, {} object points; frame to result "
                       "{:.0f} ms (decode {:.0f}, triangulate {:.0f}, segment {:.0f}, recognise "
                       "{:.0f})",
                       report.index, best.class_name, best.model_name, best.score,
                       result.object.size(), result.timing.total, result.timing.decode,
                       result.timing.triangulate, result.timing.segment, result.timing.recognise);
  } else if (report.status == ScanStatus::kNoSuggestion) {
    text = fmt::format("scan {}: no suggestion", report.index);
  } else {
    text = fmt::format("scan {}: {}: {}", report.index, ToString(report.status), report.message);
  }
  if (report.truth) {
    text += fmt::format("; truth {} (instance {})", report.truth->class_name,
                        report.truth->instance_seed);
    if (report.pose_error) {
      text += fmt::format(": rotation error {:.1f}° (mod symmetry), centre {:.1f} mm, ADD-S "
                          "{:.1f} mm",
                          report.pose_error->rotation_error_deg,
                          1e3 * report.pose_error->center_error_m, 1e3 * report.pose_error->adds_m);
    }
  }
  return text;
}

namespace {

// Every recognised object of a tabletop scan drawn over the image, each labelled at its
// projected centre; unknown clusters marked "unknown".
cv::Mat DrawTableOverlay(const ScanReport& report, const Database& database) {
  const SceneRecognitionResult& scene = *report.scene;
  const std::string title =
      scene.objects.empty()
          ? (report.message.empty() ? std::string("nothing recognised") : report.message)
          : fmt::format("{} object(s), {} unknown", scene.objects.size(), scene.unknown.size());
  cv::Mat image = DrawRecognitionOverlay(report.image, report.camera, std::vector<Eigen::Vector3f>{},
                                         Rigid3d(), title);
  std::vector<std::pair<cv::Point, std::string>> labels;
  for (const RecognisedObject& object : scene.objects) {
    const Suggestion& s = object.best();
    const ModelRecord& model = database.model(s.model);
    try {
      TriangleMesh mesh = ReadMesh(model.source_path);
      mesh.Transform(model.scale, Eigen::Vector3d::Zero());
      image = DrawRecognitionOverlay(image, report.camera, mesh, s.cam_from_model, title);
    } catch (const Error&) {
      image = DrawRecognitionOverlay(image, report.camera, database.ViewCloud(s.view).points,
                                     s.cam_from_model, title);
    }
    const Eigen::Vector2d uv = report.camera.ImageFromCam(s.cam_from_model * model.center);
    if (uv.allFinite()) {
      labels.emplace_back(cv::Point(static_cast<int>(uv.x()), static_cast<int>(uv.y())),
                          fmt::format("{} {:.2f}", s.model_name, s.score));
    }
  }
  for (const UnknownObject& unknown : scene.unknown) {
    const Eigen::Vector2d uv = report.camera.ImageFromCam(unknown.centroid.cast<double>());
    if (uv.allFinite()) {
      labels.emplace_back(cv::Point(static_cast<int>(uv.x()), static_cast<int>(uv.y())),
                          "unknown");
    }
  }
  const double scale = std::max(0.5, image.cols / 1800.0);
  for (const auto& [at, utf8_text] : labels) {
    const std::string text = HersheyText(utf8_text);
    int baseline = 0;
    const cv::Size size = cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, scale, 1, &baseline);
    const cv::Point origin(at.x - size.width / 2, at.y);
    cv::rectangle(image, origin + cv::Point(-3, baseline + 3),
                  origin + cv::Point(size.width + 3, -size.height - 3), cv::Scalar(0, 0, 0),
                  cv::FILLED);
    cv::putText(image, text, origin, cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(0, 255, 255), 1,
                cv::LINE_AA);
  }
  return image;
}

}  // namespace

cv::Mat DrawScanOverlay(const ScanReport& report, const Database& database) {
  if (report.scene) return DrawTableOverlay(report, database);
  const RecognitionResult& result = report.result.recognition;
  if (result.empty()) {
    const std::string label =
        report.status == ScanStatus::kNoSuggestion ? "no suggestion" : ToString(report.status);
    return DrawRecognitionOverlay(report.image, report.camera, std::vector<Eigen::Vector3f>{},
                                  Rigid3d(), label);
  }
  const Suggestion& best = result.best();
  std::string label = fmt::format("{} {} {:.2f}", best.class_name, best.model_name, best.score);
  if (!result.ambiguous_with.empty()) label += fmt::format(" (or {}?)", result.ambiguous_with);
  const ModelRecord& model = database.model(best.model);
  try {
    TriangleMesh mesh = ReadMesh(model.source_path);
    mesh.Transform(model.scale, Eigen::Vector3d::Zero());
    return DrawRecognitionOverlay(report.image, report.camera, mesh, best.cam_from_model, label);
  } catch (const Error& e) {
    spdlog::warn("overlay: {} — drawing the database view's points instead", e.what());
    return DrawRecognitionOverlay(report.image, report.camera,
                                  database.ViewCloud(best.view).points, best.cam_from_model,
                                  label);
  }
}

void AppendLine(const std::string& path, const std::string& line) {
  const fs::path parent = fs::path(path).parent_path();
  std::error_code error;
  if (!parent.empty()) fs::create_directories(parent, error);
  SOPE_CHECK(!error, "cannot create directory {}: {}", parent.string(), error.message());
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  SOPE_CHECK(fd >= 0, "cannot open {}: {}", path, std::strerror(errno));
  struct stat before {};
  const bool regular = ::fstat(fd, &before) == 0 && S_ISREG(before.st_mode);
  const std::string data = line + "\n";
  ssize_t written;
  do {
    written = ::write(fd, data.data(), data.size());
  } while (written < 0 && errno == EINTR);
  int failure = written < 0 ? errno : (static_cast<size_t>(written) != data.size() ? ENOSPC : 0);
  if (failure == 0 && ::fsync(fd) != 0 && errno != EINVAL && errno != EROFS) failure = errno;
  if (failure != 0) {
    if (regular && ::ftruncate(fd, before.st_size) != 0) {
      spdlog::warn("{}: could not cut back a partly written line: {}", path,
                   std::strerror(errno));
    }
    ::close(fd);
    SOPE_THROW("cannot append to {}: {}", path, std::strerror(failure));
  }
  SOPE_CHECK(::close(fd) == 0, "cannot append to {}: {}", path, std::strerror(errno));
}

}  // namespace sope
