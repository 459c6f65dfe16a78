// Evaluation protocol of the recogniser (`sope eval`): synthetic queries with ground truth,
// rendered off the database's viewpoint grid (recogniser/tools/synthetic_queries.h: random
// viewpoint, roll, distance and off-axis angle, depth noise, partial occlusion), recognised,
// and scored against the truth.
//
// Two protocols:
//  - instance: the queries are the database's own models (the object is known, its view
//    is not): top-1/top-k model and class accuracy, and for every query the pose error of
//    the first suggestion — rotation error modulo the model's symmetries, error of the
//    model centre, ADD-S; a query whose first model is wrong counts as a pose failure.
//  - class: the queries are held-out models (e.g. procedural instances of other seeds)
//    whose class is in the database: top-1/top-k class accuracy and the viewpoint error
//    of correctly classified queries (the instance differs, so no metric pose error).
// Viewpoint error: the angle between the estimated and the true direction of the camera
// from the model centre, modulo the symmetries of the query model (for a body of
// revolution: the difference of the angles to its axis).
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "core/mesh.h"
#include "projector/patterns.h"
#include "recogniser/database.h"
#include "recogniser/pose_metrics.h"
#include "recogniser/recogniser.h"
#include "recogniser/tools/synthetic_queries.h"

namespace sope {

enum class EvalProtocol { kInstance, kClass };
std::string ToString(EvalProtocol protocol);
EvalProtocol EvalProtocolFromString(const std::string& text);

// A model queries are rendered of: its mesh in metres (the database's size normalisation
// applied), with the samples and symmetries the scores need.
struct EvalModel {
  std::string name;
  std::string class_name;
  std::string path;
  int db_model = -1;  // index in the database (instance protocol), else −1
  TriangleMesh mesh;
  double bounding_radius = 0.0;  // about truth.center
  // Bounding-box centre, diameter, ADD-S samples, symmetry (recogniser/pose_metrics.h).
  PoseTruthModel truth;
};

// The database's models, read from their source meshes (which must still exist).
std::vector<EvalModel> InstanceModels(const Database& db);
// The meshes of `models_dir` (layout as for build-db) whose class the database knows, with
// the database's size normalisation. Unreadable meshes and unknown classes are listed in
// `skipped` ("path: reason"). Throws sope::Error when none is usable.
std::vector<EvalModel> HeldOutModels(const Database& db, const std::string& models_dir,
                                     std::vector<std::string>* skipped);

struct EvalOptions {
  EvalProtocol protocol = EvalProtocol::kInstance;
  int queries_per_model = 10;
  uint64_t seed = 1;
  // The query camera: an ideal pinhole of the virtual rig's camera (1280×720, 49° wide).
  int camera_width = 1280;
  int camera_height = 720;
  double camera_fov = 0.8562;  // radians, horizontal (2·atan(640/1400))
  SyntheticQueryOptions query;
  RecognitionOptions recognition;
  std::string method_name = "sope";  // for the report
  double adds_fraction = 0.1;        // ADD-S success threshold, fraction of the diameter
  double rotation_threshold_deg = 5.0;  // shown as a line on the error histogram
  // Through the full scan pipeline instead of a depth rendering: the model at the query's
  // pose before a backdrop on the virtual rig (DefaultRigCalibration: projector light,
  // shadows, lens distortion, defocus, noise, 8-bit), the scan_patterns sequence rendered,
  // decoded, triangulated and cut to the object by a range band in front of the backdrop
  // (recogniser/tools/scan_recognition.h). No occluder (query.max_occlusion is ignored); the
  // query camera is the rig's camera. ~1 s of rendering per query.
  bool through_scan = false;
  // With through_scan: the pattern sequence (Gray code, phase shift or Gray + phase; its
  // projector size is the rig's and is set by Evaluate). Default: Gray code x and y with
  // inverses and white/black frames.
  PatternOptions scan_patterns;
  // With through_scan: the query's occluder (query.max_occlusion, the same draws as the
  // depth-rendered protocol) hides its share of the scanned object's points (HideBeyondEdge:
  // the occluder segmented away, as a range band would). false: no occluder.
  bool occlude_scans = false;
  void Check() const;
};

// The pattern sequence of options.through_scan on the virtual rig's projector, checked.
PatternOptions ScanPatterns(const EvalOptions& options);

struct QueryOutcome {
  int query_model = 0;  // into the EvalModel list
  std::string truth_model;
  std::string truth_class;
  Viewpoint truth_viewpoint;
  double distance = 0.0;
  double occluded_fraction = 0.0;
  int cloud_points = 0;
  std::string error;  // recognition refused the query (counted as wrong)
  std::string predicted_model;
  std::string predicted_class;
  bool model_top1 = false, model_topk = false;
  bool class_top1 = false, class_topk = false;
  bool class_top2 = false;  // the truth class among the first two classes suggested
  bool refined = false;
  double score = 0.0;
  // The true model's (instance) or class's (class) first place among the suggestions
  // (0 = first, −1 = absent) and that suggestion's score: shows whether a miss was a
  // close call.
  int truth_rank = -1;
  double truth_score = 0.0;
  // NaN when not applicable (see the header comment).
  double viewpoint_error_deg;
  double rotation_error_deg;
  double translation_error_m;  // of the model centre
  double adds_m;
  double adds_over_diameter;
  bool adds_ok = false;
  // BOP 2019 pose errors of the first suggestion (recogniser/bop.h), NaN when the model is
  // wrong or the query refused (then a miss at every threshold): MSSD over the true
  // model's diameter, MSPD in pixels of the query camera.
  double mssd_over_diameter;
  double mspd_px;
  double flagged_fraction = 0.0;
  // The recogniser's class scores (RecognitionResult::classes, most probable first; empty
  // without class ranking) and each suggestion's class and score, in order: why a miss
  // was missed.
  std::vector<ClassScore> classes;
  std::vector<std::pair<std::string, double>> suggestion_classes;
  RecognitionTimings timing;
  // The best suggestion's database model (−1: none) and pose, and the query's true pose
  // (cam_from_model, metres): for BOP results files (recogniser/bop.h).
  int predicted_model_index = -1;
  Rigid3d estimated_cam_from_model;
  Rigid3d truth_cam_from_model;
};

struct EvalReport {
  EvalOptions options;
  std::string database_path;
  int database_views = 0;
  int database_models = 0;
  std::string hash;  // "itq 64"
  std::vector<std::string> labels;  // confusion-matrix labels: models (instance) or classes
  std::vector<QueryOutcome> outcomes;
  std::vector<std::string> skipped_models;
  int query_image_width = 0;  // the query camera's width (MSPD thresholds)

  // Aggregates (fractions of all queries unless said otherwise).
  int queries() const { return static_cast<int>(outcomes.size()); }
  double ModelTop1() const;
  double ModelTopK() const;
  double ClassTop1() const;
  double ClassTopK() const;
  double ClassTop2() const;
  // The off-diagonal cells of the class confusion (truth → first suggestion), most frequent
  // first: "truth → predicted" with their counts.
  std::vector<std::pair<std::string, int>> ConfusablePairs() const;
  double AddsSuccess() const;
  // instance: rotation error (modulo symmetry) < rotation_threshold_deg (wrong model = fail).
  double RotationSuccess() const;  // instance: ADD-S < adds_fraction · diameter (wrong model = fail)
  // Medians over the queries where the value is defined.
  double MedianViewpointErrorDeg() const;
  double MedianRotationErrorDeg() const;
  double MedianTranslationErrorMm() const;
  double MedianAddsOverDiameter() const;
  // BOP's average recalls (instance protocol; wrong model or refused = miss): MSSD over the
  // thresholds 0.05…0.5 × diameter, MSPD over 5…50 px × 640 / query_image_width.
  double MssdAverageRecall() const;
  double MspdAverageRecall() const;
  double MeanFlaggedFraction() const;
  double MaxFlaggedFraction() const;
  // Per stage, CPU milliseconds: median and 95th percentile over the queries.
  RecognitionTimings MedianTimings() const;
  double P95TotalMs() const;
  // Rows truth, columns first suggestion, over `labels`; refused queries in an extra
  // last column "(none)" when there are any.
  std::vector<std::vector<int>> Confusion(std::vector<std::string>* labels) const;

  std::string ToMarkdown() const;
  std::string ToJson() const;  // aggregates + one object per query
  std::string BriefReport() const;  // a few lines for the terminal
};

using EvalProgress = std::function<void(int done, int total)>;

// Renders the queries (queries_per_model of each model, deterministic for the seed),
// recognises them one by one (single thread) and scores them.
EvalReport Evaluate(const Database& db, const std::vector<EvalModel>& models,
                    const EvalOptions& options, const EvalProgress& progress = {});

// DIR/report.md, DIR/report.json, DIR/confusion.png, DIR/pose_errors.png (rotation error
// for the instance protocol, viewpoint error for the class protocol), all atomic.
void WriteEvalReport(const EvalReport& report, const std::string& out_dir);

}  // namespace sope
