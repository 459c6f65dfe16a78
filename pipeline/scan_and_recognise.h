// The scan-and-recognise controller (DESIGN.md data flow, pipeline/): scan after scan from
// a ScanSource — decode + triangulate, cut the cloud down to the object with a range band,
// recognise it and estimate its pose (recogniser/tools/scan_recognition.h) — compare with
// the ground truth when the source has it (recogniser/pose_metrics.h ComparePoses), write
// the outputs, and report each scan to a callback. `sope scan-and-recognise`, the tests
// and the latency bench drive this one loop.
//
// A scan that finds nothing to recognise (nothing triangulated, nothing in the band) is a
// result with its status (ScanStatus), not an error: a continuous run goes on when the
// object is lifted away. Errors (an unreadable frame set, a lost camera, a full disk)
// throw sope::Error.
//
// Outputs (options.out_dir), per scan: scan_NNNN.ply (the full cloud), scan_NNNN_object.ply
// (the segmented cloud), scan_NNNN_overlay.png, and the scan's JSON line appended to
// results.jsonl — the clouds and the overlay first (each atomic), the line last, appended
// in one write. When the line cannot be written (a full disk) it is cut back and the
// scan's other files are removed: results.jsonl lists exactly the scans whose files exist.
#pragma once

#include <atomic>
#include <functional>
#include <optional>
#include <string>
#include <thread>

#include <opencv2/core/mat.hpp>

#include "calibration/scan.h"
#include "core/camera_model.h"
#include "pipeline/scan_source.h"
#include "recogniser/database.h"
#include "recogniser/pose_metrics.h"
#include "recogniser/recogniser.h"
#include "recogniser/scene_recognition.h"
#include "recogniser/tools/scan_recognition.h"

namespace sope {

struct ScanAndRecogniseOptions {
  ScanOptions scan;  // decoding and triangulation
  RecognitionOptions recognition;
  // The range band, metres from the camera centre. Unset: the source's band when it knows
  // one (single-object virtual scenes), else ObjectSegmentationOptions' defaults.
  std::optional<double> min_range;
  std::optional<double> max_range;
  // Scans to take; −1: until the source is exhausted or cancelled. A source of fewer scans
  // (frame-set directories) ends the run early.
  int max_scans = 1;
  // Per-scan files and results.jsonl go here; empty: none.
  std::string out_dir;
  // A scan with nothing to recognise (ScanStatus kNoPoints, kNothingInBand) throws
  // sope::Error (its message) before its outputs are written, instead of being reported:
  // for a single scan, where seeing nothing is a failure.
  bool fail_on_nothing_found = false;
  // Tabletop mode (`--table`; a source flagging its scans `tabletop` sets it per scan):
  // segment by the table plane and clusters, recognise every object, verify the scene
  // (recogniser/scene_recognition.h) instead of one object in the range band. The band
  // above (when set) still limits the points considered.
  bool tabletop = false;
  // Tabletop: build the scene recogniser's per-model caches on another thread from the
  // first capture on (SceneRecogniser::WarmUp). Off where a controller makes one scan only
  // (the tabletop evaluation: a controller per scene would build them all each time).
  bool warm_up = true;
  // Tabletop: a scene recogniser of the same database to use (and keep the per-model
  // caches of) instead of the controller's own, which dies with it; must outlive the
  // controller. The tabletop evaluation shares one across its scenes, so that a scene's
  // times are not those of building the caches of every model it meets (the answers are
  // the same either way).
  const SceneRecogniser* shared_scene_recogniser = nullptr;
  SceneRecognitionOptions scene;  // its `recognition` is replaced by `recognition` above
  // Checked between scans; when it becomes true the run ends after the current scan (a
  // capture under way is cancelled by the source's session, which watches the same flag).
  const std::atomic<bool>* cancel = nullptr;
  // Throws sope::Error naming the invalid value.
  void Check() const;
};

struct ScanFiles {
  std::string cloud, object_cloud, overlay;  // empty: not written
  // Tabletop: scan_NNNN_object_K.ply, the segment of each recognised object K (in the
  // order of "objects"), and scan_NNNN_unknown_K.ply of each unknown one.
  std::vector<std::string> object_clouds, unknown_clouds;
};

// A truth object of a tabletop scan and the recognised object matched to it (the nearest
// by bounding-box centre within half the truth's diameter, each detection used once;
// detections of the truth's own model first, then of its class, then any).
struct TableObjectMatch {
  int truth = -1;      // into ScanTruth::objects
  int detection = -1;  // into SceneRecognitionResult::objects, −1: missed / rejected
  bool model_correct = false;
  bool class_correct = false;
  std::optional<PoseComparison> pose_error;  // detected with the right class
  // Right: model right and ADD-S < 10% of the diameter (issue 12's detection criterion).
  bool correct = false;
};
// Matches a scene result against the truth objects (known and clutter).
std::vector<TableObjectMatch> MatchTableObjects(const SceneRecognitionResult& scene,
                                                const ScanTruth& truth, const Database& database);

struct ScanReport {
  int index = 0;
  std::string source;
  ScanStatus status = ScanStatus::kRecognised;
  std::string message;             // what happened, when the status is not kRecognised
  ScanRecognition result;          // the scan, the object cloud, the recognition, timings
  double capture_ms = 0.0;
  ObjectSegmentationOptions band;  // the band used
  std::optional<ScanTruth> truth;
  bool class_correct = false;      // truth known and the first suggestion's class is it
  std::optional<PoseComparison> pose_error;  // truth known and the class correct
  // Tabletop scans: every object, and the matches with the truth (when known).
  std::optional<SceneRecognitionResult> scene;
  std::vector<TableObjectMatch> matches;
  ScanFiles files;
  std::string json;                // the results line (no newline)
  // For the overlay: the camera's white frame (or its first frame) and the camera.
  cv::Mat image;
  CameraModel camera;
};

// Called after each scan, its outputs written.
using ScanCallback = std::function<void(const ScanReport&)>;

class ScanAndRecogniseController {
 public:
  // `source` and `database` must outlive the controller.
  ScanAndRecogniseController(const ScanAndRecogniseOptions& options, ScanSource* source,
                             const Database& database);
  ~ScanAndRecogniseController();
  ScanAndRecogniseController(const ScanAndRecogniseController&) = delete;
  ScanAndRecogniseController& operator=(const ScanAndRecogniseController&) = delete;
  // Runs the scans. Returns how many were done. An interruption (options.cancel) during a
  // capture ends the run quietly once at least one scan of a multi-scan run is done; else
  // it throws like any capture error.
  int Run(const ScanCallback& callback = {}, const CaptureProgress& progress = {});

  // One scan of the source (no files written): what Run does per scan before the outputs.
  ScanReport Scan(int index, const CaptureProgress& progress = {});

 private:
  // Tabletop: decode, triangulate, SceneRecogniser; fills report->result and ->scene.
  // `decoded`: the map decoded during the capture (decode_ms its time), else nullptr.
  void ScanTable(const FrameSet& frames, CorrespondenceMap* decoded, double decode_ms,
                 ScanReport* report);
  // options_.shared_scene_recogniser when set, else the controller's own.
  const SceneRecogniser& SceneRecogniserInUse() const {
    return options_.shared_scene_recogniser != nullptr ? *options_.shared_scene_recogniser
                                                       : scene_recogniser_;
  }
  ScanAndRecogniseOptions options_;
  ScanSource* source_;
  const Database& database_;
  Recogniser recogniser_;
  SceneRecogniser scene_recogniser_;
  std::unique_ptr<Triangulator> triangulator_;  // per calibration (undistortion tables)
  RigCalibration triangulator_calibration_;
  // Decoding during the capture (sources that capture: the frame sink's IncrementalDecoder).
  struct LiveDecode;
  std::unique_ptr<LiveDecode> live_decode_;
  // Tabletop: the scene recogniser's per-model caches built on another thread during the
  // first capture (SceneRecogniser::WarmUp), so the first scan's results do not wait for
  // them; stopped and joined on destruction.
  std::thread warm_up_;
  std::atomic<bool> stop_warm_up_{false};
};

// The DESIGN.md recognition result of the scan (empty recognition: no "class"…) plus
// "status", "timing_ms" with the scan's stages (capture, decode, triangulate, segment,
// recognise, frame_to_result), "scan" {index, source, points, object_points,
// range_band_m}, "ground_truth" {class, instance_seed, pose, class_correct, and for the
// right class rotation_error_deg, center_error_m, adds_m, diameter_m} when known, "files"
// when written, and "objects": [] when nothing was recognised.
std::string ScanReportToJson(const ScanReport& report);

// One line for a terminal: the first suggestion (class, model, score), the object points
// and the frame-to-result time by stage, or the status; and the ground truth with the pose
// error when known.
std::string ScanReportToText(const ScanReport& report);

// report.image with the recognised model drawn on it (recogniser/tools/scan_recognition.h
// DrawRecognitionOverlay): the model's mesh when it can be read, else the database view's
// points; the status when nothing was recognised.
cv::Mat DrawScanOverlay(const ScanReport& report, const Database& database);

// Writes the scan's files into `out_dir` (see the header comment) and appends its line to
// out_dir/results.jsonl; fills report->files and report->json. On failure removes what it
// wrote for this scan and throws sope::Error.
void WriteScanOutputs(const std::string& out_dir, const Database& database, ScanReport* report);

// Appends `line` + '\n' to `path` (created if absent) in one write(2) and fsyncs it. When
// the write fails or is short, the file is cut back to its previous length and
// sope::Error names the file and the reason (e.g. "No space left on device").
void AppendLine(const std::string& path, const std::string& line);

}  // namespace sope
