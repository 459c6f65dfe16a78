#include "recogniser/tools/evaluation.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <random>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/camera_model.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/json.h"
#include "core/plots.h"
#include "core/statistics.h"
#include "core/units.h"
#include "recogniser/bop.h"
#include "recogniser/tools/database_builder.h"
#include "recogniser/tools/scan_recognition.h"
#include "recogniser/viewpoints.h"
#include "simulator/scene_builder.h"
#include "simulator/simulate_scan.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr int kAddsSamples = 2000;
// A query cloud needs this many points to be worth asking (fewer: the object was mostly
// outside the image or hidden; the query is drawn again).
constexpr int kMinQueryPoints = 300;
constexpr int kMaxQueryAttempts = 20;

EvalModel MakeEvalModel(TriangleMesh mesh, const std::string& name, const std::string& class_name,
                        const std::string& path, double scale, int db_model) {
  EvalModel model;
  model.name = name;
  model.class_name = class_name;
  model.path = path;
  model.db_model = db_model;
  if (scale != 1.0) mesh.Transform(scale, Eigen::Vector3d::Zero());
  PoseTruthModelOptions truth_options;
  truth_options.samples = kAddsSamples;
  truth_options.seed = 5;
  model.truth = MakePoseTruthModel(mesh, truth_options);
  for (const Eigen::Vector3f& v : mesh.vertices) {
    model.bounding_radius =
        std::max(model.bounding_radius, (v.cast<double>() - model.truth.center).norm());
  }
  model.mesh = std::move(mesh);
  return model;
}

// Angle between viewing directions (model frame) modulo the model's symmetries: a view
// from d looks the same as one from S·d.
double SymmetricViewpointErrorDeg(const Eigen::Vector3d& estimate, const Eigen::Vector3d& truth,
                                  const ModelSymmetry& symmetry) {
  double best = 180.0;
  for (const Eigen::Matrix3d& s : symmetry.rotations) {
    const Eigen::Vector3d d = s * estimate;
    double error;
    if (symmetry.continuous) {
      const double a = std::acos(std::clamp(d.dot(symmetry.axis), -1.0, 1.0));
      const double b = std::acos(std::clamp(truth.dot(symmetry.axis), -1.0, 1.0));
      error = std::abs(a - b) * kRadToDeg;
    } else {
      error = std::acos(std::clamp(d.dot(truth), -1.0, 1.0)) * kRadToDeg;
    }
    best = std::min(best, error);
  }
  return best;
}

std::vector<double> Defined(const std::vector<QueryOutcome>& outcomes,
                            double QueryOutcome::*field) {
  std::vector<double> values;
  for (const QueryOutcome& o : outcomes) {
    if (std::isfinite(o.*field)) values.push_back(o.*field);
  }
  return values;
}

template <typename Predicate>
double Fraction(const std::vector<QueryOutcome>& outcomes, Predicate predicate) {
  if (outcomes.empty()) return 0.0;
  int count = 0;
  for (const QueryOutcome& o : outcomes) count += predicate(o) ? 1 : 0;
  return static_cast<double>(count) / static_cast<double>(outcomes.size());
}

std::string Percent(double fraction) { return fmt::format("{:.1f}%", 100.0 * fraction); }
std::string Fixed(double value, int digits) {
  return std::isfinite(value) ? fmt::format("{:.{}f}", value, digits) : std::string("–");
}

// Horizontal field of view of a pinhole, radians.
double HorizontalFov(const CameraModel& camera) {
  return 2.0 * std::atan(0.5 * camera.width / camera.matrix(0, 0));
}

// BOP's MSSD (over the diameter) and MSPD (pixels) of `estimate` against `truth` on the
// model's ADD-S surface samples (at most 2000, evenly taken), modulo the model's
// symmetries about the samples' centroid; a continuous symmetry is discretised as
// bop_toolkit does (misc.get_symmetry_transformations, max_sym_disc_step 0.01: 315 turns).
void BopErrors(const Rigid3d& estimate, const Rigid3d& truth, const PoseTruthModel& model,
               const Eigen::Matrix3d& camera_matrix, double* mssd_over_diameter,
               double* mspd_px) {
  constexpr size_t kMaxPoints = 2000;
  const size_t stride = std::max<size_t>(1, model.samples.size() / kMaxPoints);
  std::vector<Eigen::Vector3d> points;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < model.samples.size(); i += stride) {
    points.push_back(model.samples[i].cast<double>());
    centroid += points.back();
  }
  SOPE_CHECK(!points.empty() && model.diameter > 0.0, "BOP errors: no model samples");
  centroid /= static_cast<double>(points.size());
  std::vector<Eigen::Matrix3d> discrete = {Eigen::Matrix3d::Identity()};
  for (const Eigen::Matrix3d& r : model.symmetry.rotations) discrete.push_back(r);
  std::vector<Eigen::Matrix3d> continuous = {Eigen::Matrix3d::Identity()};
  if (model.symmetry.continuous) {
    const int steps = static_cast<int>(std::ceil(kPi / 0.01));
    for (int k = 1; k < steps; ++k) {
      continuous.push_back(
          Eigen::AngleAxisd(2.0 * kPi * k / steps, model.symmetry.axis).toRotationMatrix());
    }
  }
  std::vector<Rigid3d> symmetries;
  for (const Eigen::Matrix3d& c : continuous) {
    for (const Eigen::Matrix3d& d : discrete) {
      const Eigen::Matrix3d rotation = c * d;
      symmetries.emplace_back(rotation, centroid - rotation * centroid);
    }
  }
  *mssd_over_diameter = Mssd(estimate, truth, points, symmetries) / model.diameter;
  *mspd_px = Mspd(estimate, truth, camera_matrix, points, symmetries);
}

// Fills the outcome of one recognised query: the suggestions' ranks against the truth,
// the viewpoint error, and (instance protocol, right model) the pose error.
void ScoreOutcome(const Database& db, const EvalModel& model, const SyntheticQuery& query,
                  const EvalOptions& options, const Eigen::Matrix3d& camera_matrix,
                  const RecognitionResult& result, QueryOutcome* out) {
  QueryOutcome& outcome = *out;
  const Suggestion& best = result.best();
  outcome.predicted_model = best.model_name;
  outcome.predicted_class = best.class_name;
  outcome.predicted_model_index = best.model;
  outcome.estimated_cam_from_model = best.cam_from_model;
  outcome.refined = best.refined;
  outcome.score = best.score;
  outcome.flagged_fraction = result.flagged_fraction;
  outcome.timing = result.timing;
  outcome.classes = result.classes;
  for (const Suggestion& suggestion : result.suggestions) {
    outcome.suggestion_classes.emplace_back(suggestion.class_name, suggestion.score);
  }
  std::vector<std::string> classes_seen;  // distinct classes in suggestion order
  for (size_t s = 0; s < result.suggestions.size(); ++s) {
    const Suggestion& suggestion = result.suggestions[s];
    if (std::find(classes_seen.begin(), classes_seen.end(), suggestion.class_name) ==
        classes_seen.end()) {
      classes_seen.push_back(suggestion.class_name);
      if (classes_seen.size() <= 2 && suggestion.class_name == model.class_name) {
        outcome.class_top2 = true;
      }
    }
    const bool same_model = model.db_model >= 0 && suggestion.model == model.db_model;
    const bool same_class = suggestion.class_name == model.class_name;
    if (s == 0) {
      outcome.model_top1 = same_model;
      outcome.class_top1 = same_class;
    }
    outcome.model_topk |= same_model;
    outcome.class_topk |= same_class;
    const bool truth = options.protocol == EvalProtocol::kInstance ? same_model : same_class;
    if (truth && outcome.truth_rank < 0) {
      outcome.truth_rank = static_cast<int>(s);
      outcome.truth_score = suggestion.score;
    }
  }
  // Viewpoint: where the estimated pose puts the camera, seen from the suggested
  // model's centre, against the truth (modulo the query model's symmetries).
  const bool comparable = options.protocol == EvalProtocol::kInstance ? outcome.model_top1
                                                                      : outcome.class_top1;
  if (comparable) {
    const Eigen::Vector3d estimate =
        ViewpointFromPose(best.cam_from_model, db.model(best.model).center).Direction();
    outcome.viewpoint_error_deg =
        SymmetricViewpointErrorDeg(estimate, query.viewpoint.Direction(), model.truth.symmetry);
  }
  if (options.protocol == EvalProtocol::kInstance) {
    if (outcome.model_top1) {
      const PoseComparison error =
          ComparePoses(best.cam_from_model, query.cam_from_model, model.truth);
      outcome.rotation_error_deg = error.rotation_error_deg;
      outcome.translation_error_m = error.center_error_m;
      outcome.adds_m = error.adds_m;
      outcome.adds_over_diameter = error.adds_over_diameter();
      outcome.adds_ok = outcome.adds_over_diameter < options.adds_fraction;
      BopErrors(best.cam_from_model, query.cam_from_model, model.truth, camera_matrix,
                &outcome.mssd_over_diameter, &outcome.mspd_px);
    }
  }
}

}  // namespace

std::string ToString(EvalProtocol protocol) {
  return protocol == EvalProtocol::kInstance ? "instance" : "class";
}

EvalProtocol EvalProtocolFromString(const std::string& text) {
  if (text == "instance") return EvalProtocol::kInstance;
  if (text == "class") return EvalProtocol::kClass;
  throw Error(fmt::format("unknown evaluation protocol '{}' (instance or class)", text));
}

void EvalOptions::Check() const {
  SOPE_CHECK(queries_per_model >= 1, "queries per model must be ≥ 1, got {}", queries_per_model);
  SOPE_CHECK(camera_width >= 16 && camera_height >= 16, "query camera {}x{} is too small",
             camera_width, camera_height);
  SOPE_CHECK(camera_fov > 0.05 && camera_fov < 3.0, "query camera field of view {} rad is "
             "implausible", camera_fov);
  SOPE_CHECK(adds_fraction > 0.0, "ADD-S threshold must be positive, got {}", adds_fraction);
  query.Check();
  recognition.Check();
  if (through_scan) ScanPatterns(*this);  // checks the sequence on the rig's projector
}

PatternOptions ScanPatterns(const EvalOptions& options) {
  const CameraModel projector = DefaultRigCalibration().projector;
  PatternOptions patterns = options.scan_patterns;
  patterns.projector_width = projector.width;
  patterns.projector_height = projector.height;
  patterns.Check();
  return patterns;
}

std::vector<EvalModel> InstanceModels(const Database& db) {
  std::vector<EvalModel> models;
  for (int m = 0; m < db.num_models(); ++m) {
    const ModelRecord& record = db.model(m);
    TriangleMesh mesh;
    try {
      mesh = ReadMesh(record.source_path);
    } catch (const Error& e) {
      throw Error(fmt::format("model {} of the database: its mesh {} is gone or unreadable ({}); "
                              "the instance protocol renders the database's own meshes",
                              record.name, record.source_path, e.what()));
    }
    models.push_back(
        MakeEvalModel(std::move(mesh), record.name, record.class_name, record.source_path,
                      record.scale, m));
  }
  return models;
}

std::vector<EvalModel> HeldOutModels(const Database& db, const std::string& models_dir,
                                     std::vector<std::string>* skipped) {
  const std::vector<std::string>& classes = db.classes();
  std::vector<EvalModel> models;
  for (const ModelSource& source : ListModels(models_dir)) {
    if (std::find(classes.begin(), classes.end(), source.class_name) == classes.end()) {
      if (skipped) skipped->push_back(source.path + ": class '" + source.class_name +
                                      "' is not in the database");
      continue;
    }
    TriangleMesh mesh;
    try {
      mesh = ReadMesh(source.path);
      mesh.Check();
    } catch (const Error& e) {
      if (skipped) skipped->push_back(source.path + ": " + e.what());
      continue;
    }
    const double scale = SizeNormalisationScale(mesh, db.options().size);
    models.push_back(
        MakeEvalModel(std::move(mesh), source.name, source.class_name, source.path, scale, -1));
  }
  SOPE_CHECK(!models.empty(), "no usable held-out model in {} (need meshes of the database's "
             "classes: {})", models_dir, fmt::join(classes, ", "));
  return models;
}

EvalReport Evaluate(const Database& db, const std::vector<EvalModel>& models,
                    const EvalOptions& options, const EvalProgress& progress) {
  options.Check();
  SOPE_CHECK(!models.empty(), "evaluation: no models to query");
  for (const EvalModel& model : models) {
    SOPE_CHECK(options.protocol == EvalProtocol::kClass ||
                   (model.db_model >= 0 && model.db_model < db.num_models()),
               "instance protocol: model {} is not in the database", model.name);
  }
  EvalReport report;
  report.options = options;
  report.database_path = db.path();
  report.database_views = db.num_views();
  report.database_models = db.num_models();
  report.hash = fmt::format("{} {}", ToString(db.hasher().method()), db.hasher().bits());
  if (options.protocol == EvalProtocol::kInstance) {
    for (const EvalModel& model : models) report.labels.push_back(model.name);
  } else {
    report.labels = db.classes();
  }

  // The scan pipeline's rig, and a pinhole of its camera's size and field of view to draw
  // the query poses with (the same poses as the depth-rendered protocol would use).
  const RigCalibration rig_calibration = DefaultRigCalibration();
  std::unique_ptr<VirtualRig> rig;
  std::unique_ptr<Triangulator> triangulator;
  ScanOptions scan_options;
  PatternOptions patterns;
  CameraModel camera =
      MakePinhole(options.camera_width, options.camera_height, options.camera_fov);
  if (options.through_scan) {
    const CameraModel& rig_camera = rig_calibration.camera;
    camera = MakePinhole(rig_camera.width, rig_camera.height, HorizontalFov(rig_camera));
    rig = std::make_unique<VirtualRig>(rig_calibration);
    triangulator = std::make_unique<Triangulator>(rig_calibration, scan_options.triangulation);
    patterns = ScanPatterns(options);
  }
  report.query_image_width = camera.width;
  // Scanned queries get no occluder, or (occlude_scans) the same as depth-rendered ones
  // (same draws): the scanned object cloud loses the points beyond the occluder edge.
  SyntheticQueryOptions query_options = options.query;
  if (options.through_scan && !options.occlude_scans) query_options.max_occlusion = 0.0;
  DepthRenderer renderer(camera);
  const Recogniser recogniser(db);
  std::mt19937_64 rng(options.seed);
  const int total = static_cast<int>(models.size()) * options.queries_per_model;
  int done = 0;
  for (size_t m = 0; m < models.size(); ++m) {
    const EvalModel& model = models[m];
    renderer.SetMesh(model.mesh);
    for (int k = 0; k < options.queries_per_model; ++k) {
      SyntheticQuery query;
      for (int attempt = 0; attempt < kMaxQueryAttempts; ++attempt) {
        query = RenderSyntheticQuery(&renderer, camera, model.truth.center, model.bounding_radius,
                                     query_options, &rng);
        if (static_cast<int>(query.cloud.size()) >= kMinQueryPoints) break;
      }
      QueryOutcome outcome;
      outcome.query_model = static_cast<int>(m);
      outcome.truth_model = model.name;
      outcome.truth_class = model.class_name;
      outcome.truth_viewpoint = query.viewpoint;
      outcome.distance = query.distance;
      outcome.occluded_fraction = query.occluded_fraction;
      outcome.cloud_points = static_cast<int>(query.cloud.size());
      outcome.truth_cam_from_model = query.cam_from_model;
      outcome.viewpoint_error_deg = outcome.rotation_error_deg = outcome.translation_error_m =
          outcome.adds_m = outcome.adds_over_diameter = outcome.mssd_over_diameter =
              outcome.mspd_px = kNaN;
      RecognitionResult result;
      try {
        if (options.through_scan) {
          // The object before a backdrop beyond its farthest point; the band keeps the
          // object only.
          const double far =
              (query.cam_from_model * model.truth.center).norm() + model.bounding_radius;
          const double backdrop = far + 0.15;
          Scene scene;
          scene.objects.push_back({model.mesh, query.cam_from_model, 0.8, {}});
          const double extent = 2.0 * backdrop * std::tan(0.5 * HorizontalFov(camera)) * 1.5;
          scene.objects.push_back(MakeBackdrop(backdrop, extent, extent));
          const SimulatedScan scan = SimulateScan(*rig, scene, patterns);
          ObjectSegmentationOptions band;
          band.max_range = far + 0.075;
          const ScanRecognition scanned = RecogniseFrameSet(
              scan.frames, *triangulator, scan_options.decoder, band, recogniser,
              options.recognition);
          outcome.cloud_points = static_cast<int>(scanned.object.size());
          // Nothing triangulated or nothing in the band: refused, as the recogniser would.
          SOPE_CHECK(scanned.status == ScanStatus::kRecognised ||
                         scanned.status == ScanStatus::kNoSuggestion,
                     "{}", scanned.message);
          result = scanned.recognition;
          if (query.occluded_fraction > 0.0) {
            PointCloud occluded;
            occluded.points = HideBeyondEdge(scanned.object.points, query.occluded_fraction,
                                             query.occluder_angle);
            outcome.cloud_points = static_cast<int>(occluded.size());
            result = recogniser.Recognise(occluded, options.recognition);
          }
        } else {
          result = recogniser.Recognise(query.cloud, options.recognition);
        }
        SOPE_CHECK(!result.empty(), "no suggestion");
      } catch (const Error& e) {
        outcome.error = e.what();
        report.outcomes.push_back(std::move(outcome));
        if (progress) progress(++done, total);
        continue;
      }
      ScoreOutcome(db, model, query, options, camera.matrix, result, &outcome);
      report.outcomes.push_back(std::move(outcome));
      if (progress) progress(++done, total);
    }
  }
  return report;
}

namespace {

// BOP average recall of per-query errors (NaN = miss: counted as +∞).
double BopAverageRecall(const std::vector<QueryOutcome>& outcomes,
                        double QueryOutcome::*error, const std::vector<double>& thresholds) {
  std::vector<double> errors;
  for (const QueryOutcome& o : outcomes) {
    const double e = o.*error;
    errors.push_back(std::isnan(e) ? std::numeric_limits<double>::infinity() : e);
  }
  return AverageRecall(errors, thresholds);
}

}  // namespace

double EvalReport::MssdAverageRecall() const {
  return BopAverageRecall(outcomes, &QueryOutcome::mssd_over_diameter, MssdThresholds(1.0));
}
double EvalReport::MspdAverageRecall() const {
  return BopAverageRecall(outcomes, &QueryOutcome::mspd_px,
                          MspdThresholds(query_image_width > 0 ? query_image_width : 640));
}

double EvalReport::ClassTop2() const {
  return Fraction(outcomes, [](const QueryOutcome& o) { return o.class_top2; });
}

std::vector<std::pair<std::string, int>> EvalReport::ConfusablePairs() const {
  std::map<std::string, int> counts;
  for (const QueryOutcome& o : outcomes) {
    if (o.error.empty() && o.predicted_class != o.truth_class) {
      ++counts[o.truth_class + " → " + o.predicted_class];
    }
  }
  std::vector<std::pair<std::string, int>> pairs(counts.begin(), counts.end());
  std::stable_sort(pairs.begin(), pairs.end(),
                   [](const auto& a, const auto& b) { return a.second > b.second; });
  return pairs;
}

double EvalReport::ModelTop1() const {
  return Fraction(outcomes, [](const QueryOutcome& o) { return o.model_top1; });
}
double EvalReport::ModelTopK() const {
  return Fraction(outcomes, [](const QueryOutcome& o) { return o.model_topk; });
}
double EvalReport::ClassTop1() const {
  return Fraction(outcomes, [](const QueryOutcome& o) { return o.class_top1; });
}
double EvalReport::ClassTopK() const {
  return Fraction(outcomes, [](const QueryOutcome& o) { return o.class_topk; });
}
double EvalReport::AddsSuccess() const {
  return Fraction(outcomes, [](const QueryOutcome& o) { return o.adds_ok; });
}
double EvalReport::RotationSuccess() const {
  const double threshold = options.rotation_threshold_deg;
  return Fraction(outcomes, [threshold](const QueryOutcome& o) {
    return std::isfinite(o.rotation_error_deg) && o.rotation_error_deg < threshold;
  });
}
double EvalReport::MedianViewpointErrorDeg() const {
  return Median(Defined(outcomes, &QueryOutcome::viewpoint_error_deg));
}
double EvalReport::MedianRotationErrorDeg() const {
  return Median(Defined(outcomes, &QueryOutcome::rotation_error_deg));
}
double EvalReport::MedianTranslationErrorMm() const {
  return 1e3 * Median(Defined(outcomes, &QueryOutcome::translation_error_m));
}
double EvalReport::MedianAddsOverDiameter() const {
  return Median(Defined(outcomes, &QueryOutcome::adds_over_diameter));
}
double EvalReport::MeanFlaggedFraction() const {
  double sum = 0.0;
  int count = 0;
  for (const QueryOutcome& o : outcomes) {
    if (!o.error.empty()) continue;
    sum += o.flagged_fraction;
    ++count;
  }
  return count > 0 ? sum / count : kNaN;
}
double EvalReport::MaxFlaggedFraction() const {
  double worst = 0.0;
  for (const QueryOutcome& o : outcomes) worst = std::max(worst, o.flagged_fraction);
  return worst;
}

RecognitionTimings EvalReport::MedianTimings() const {
  RecognitionTimings median;
  auto stage = [&](double RecognitionTimings::*field) {
    std::vector<double> values;
    for (const QueryOutcome& o : outcomes) {
      if (o.error.empty()) values.push_back(o.timing.*field);
    }
    return Median(values);
  };
  median.preprocess = stage(&RecognitionTimings::preprocess);
  median.features = stage(&RecognitionTimings::features);
  median.coarse = stage(&RecognitionTimings::coarse);
  median.fine = stage(&RecognitionTimings::fine);
  median.pose = stage(&RecognitionTimings::pose);
  median.total = stage(&RecognitionTimings::total);
  median.preprocess_cpu = stage(&RecognitionTimings::preprocess_cpu);
  median.features_cpu = stage(&RecognitionTimings::features_cpu);
  median.coarse_cpu = stage(&RecognitionTimings::coarse_cpu);
  median.fine_cpu = stage(&RecognitionTimings::fine_cpu);
  median.pose_cpu = stage(&RecognitionTimings::pose_cpu);
  median.total_cpu = stage(&RecognitionTimings::total_cpu);
  return median;
}

double EvalReport::P95TotalMs() const {
  std::vector<double> values;
  for (const QueryOutcome& o : outcomes) {
    if (o.error.empty()) values.push_back(o.timing.total_cpu);
  }
  return Quantile(values, 0.95);
}

std::vector<std::vector<int>> EvalReport::Confusion(std::vector<std::string>* labels_out) const {
  std::vector<std::string> labels = this->labels;
  const bool any_refused = std::any_of(outcomes.begin(), outcomes.end(),
                                       [](const QueryOutcome& o) { return !o.error.empty(); });
  std::map<std::string, int> index;
  for (size_t i = 0; i < labels.size(); ++i) index[labels[i]] = static_cast<int>(i);
  // Predictions outside the labels (instance protocol: a database model that is not among
  // the queried ones cannot happen; kept general) get their own columns.
  const bool instance = options.protocol == EvalProtocol::kInstance;
  for (const QueryOutcome& o : outcomes) {
    const std::string& predicted = instance ? o.predicted_model : o.predicted_class;
    if (o.error.empty() && !index.count(predicted)) {
      index[predicted] = static_cast<int>(labels.size());
      labels.push_back(predicted);
    }
  }
  if (any_refused) labels.push_back("(none)");
  std::vector<std::vector<int>> counts(labels.size(), std::vector<int>(labels.size(), 0));
  for (const QueryOutcome& o : outcomes) {
    const int row = index.at(instance ? o.truth_model : o.truth_class);
    const int column = o.error.empty()
                           ? index.at(instance ? o.predicted_model : o.predicted_class)
                           : static_cast<int>(labels.size()) - 1;
    ++counts[row][column];
  }
  if (labels_out) *labels_out = labels;
  return counts;
}

std::string EvalReport::BriefReport() const {
  const RecognitionTimings t = MedianTimings();
  std::string text = fmt::format(
      "{} protocol{}, method {}: {} queries, database {} models / {} views ({})\n",
      ToString(options.protocol), options.through_scan ? " through the scan pipeline" : "",
      options.method_name, queries(), database_models, database_views, hash);
  if (options.protocol == EvalProtocol::kInstance) {
    text += fmt::format(
        "  model top-1 {}, top-{} {}; class top-1 {}, top-{} {}\n"
        "  pose (first suggestion): median rotation error {}° (modulo symmetry), centre {} mm, "
        "ADD-S median {}% of the diameter, ADD-S@{:.0f}% {}, rotation < {:.0f}° {}\n"
        "  BOP average recall: MSSD {}, MSPD {}\n",
        Percent(ModelTop1()), options.recognition.top_k, Percent(ModelTopK()),
        Percent(ClassTop1()), options.recognition.top_k, Percent(ClassTopK()),
        Fixed(MedianRotationErrorDeg(), 2), Fixed(MedianTranslationErrorMm(), 2),
        Fixed(100.0 * MedianAddsOverDiameter(), 2), 100.0 * options.adds_fraction,
        Percent(AddsSuccess()), options.rotation_threshold_deg, Percent(RotationSuccess()),
        Percent(MssdAverageRecall()), Percent(MspdAverageRecall()));
  } else {
    text += fmt::format("  class top-1 {}, top-2 {}, top-{} {}\n", Percent(ClassTop1()),
                        Percent(ClassTop2()), options.recognition.top_k, Percent(ClassTopK()));
    std::string pairs;
    for (const auto& [pair, count] : ConfusablePairs()) {
      if (!pairs.empty()) pairs += ", ";
      pairs += fmt::format("{} ×{}", pair, count);
    }
    if (!pairs.empty()) text += "  confusions: " + pairs + "\n";
  }
  text += fmt::format(
      "  median viewpoint error {}°; flagged {} of the database (mean, max {})\n"
      "  CPU ms per query (median): preprocess {:.2f}, features {:.2f}, coarse {:.2f}, fine "
      "{:.2f}, pose {:.2f}, total {:.2f} (p95 {:.2f})",
      Fixed(MedianViewpointErrorDeg(), 2), Percent(MeanFlaggedFraction()),
      Percent(MaxFlaggedFraction()), t.preprocess_cpu, t.features_cpu, t.coarse_cpu, t.fine_cpu,
      t.pose_cpu, t.total_cpu, P95TotalMs());
  return text;
}

std::string EvalReport::ToMarkdown() const {
  const RecognitionTimings t = MedianTimings();
  const int k = options.recognition.top_k;
  std::string md = fmt::format("# Recognition evaluation: {} protocol, method `{}`\n\n",
                               ToString(options.protocol), options.method_name);
  md += fmt::format(
      "Database `{}`: {} models, {} views, {} codes. {} queries ({} per model, seed {}), "
      "rendered off the database grid: distance {:.2f}–{:.2f} m, off-axis ≤ {:.2f} rad, "
      "{} roll, depth noise σ {:.1f} mm at 0.6 m, up to {} occluded; query camera {}×{}, "
      "{:.1f}° wide.\n\n",
      database_path, database_models, database_views, hash, queries(), options.queries_per_model,
      options.seed, options.query.min_distance, options.query.max_distance,
      options.query.max_off_axis, options.query.random_roll ? "random" : "no",
      1e3 * options.query.depth_noise, Percent(options.query.max_occlusion),
      options.camera_width, options.camera_height, options.camera_fov * kRadToDeg);
  if (options.through_scan) {
    md += fmt::format("Queries scanned through the full pipeline: the model before a backdrop "
                      "on the virtual rig, patterns ({}) rendered, decoded, triangulated, cut to "
                      "the object by a range band",
                      DescribePatterns(ScanPatterns(options)));
    md += options.occlude_scans ? "; then the query's occluder hides its share of the scanned "
                                  "points.\n\n"
                                : " (no occluder).\n\n";
  }
  md += "| measure | value |\n|---|---|\n";
  if (options.protocol == EvalProtocol::kInstance) {
    md += fmt::format("| model top-1 | {} |\n| model top-{} | {} |\n", Percent(ModelTop1()), k,
                      Percent(ModelTopK()));
  }
  md += fmt::format("| class top-1 | {} |\n| class top-2 (first two classes suggested) | {} "
                    "|\n| class top-{} | {} |\n",
                    Percent(ClassTop1()), Percent(ClassTop2()), k, Percent(ClassTopK()));
  md += fmt::format("| median viewpoint error (correct {}) | {}° |\n",
                    options.protocol == EvalProtocol::kInstance ? "model" : "class",
                    Fixed(MedianViewpointErrorDeg(), 2));
  if (options.protocol == EvalProtocol::kInstance) {
    md += fmt::format(
        "| median rotation error, modulo symmetry (correct model) | {}° |\n"
        "| median centre error (correct model) | {} mm |\n"
        "| median ADD-S (correct model) | {}% of the diameter |\n"
        "| ADD-S < {:.0f}% of the diameter (all queries) | {} |\n"
        "| rotation error < {:.0f}°, modulo symmetry (all queries) | {} |\n"
        "| BOP MSSD average recall (0.05–0.5 × diameter, all queries) | {} |\n"
        "| BOP MSPD average recall (5–50 px × 640/{}, all queries) | {} |\n",
        Fixed(MedianRotationErrorDeg(), 2), Fixed(MedianTranslationErrorMm(), 2),
        Fixed(100.0 * MedianAddsOverDiameter(), 2), 100.0 * options.adds_fraction,
        Percent(AddsSuccess()), options.rotation_threshold_deg, Percent(RotationSuccess()),
        Percent(MssdAverageRecall()), query_image_width, Percent(MspdAverageRecall()));
  }
  md += fmt::format("| database flagged by the coarse search | {} mean, {} max |\n",
                    Percent(MeanFlaggedFraction()), Percent(MaxFlaggedFraction()));
  const int refused = static_cast<int>(std::count_if(
      outcomes.begin(), outcomes.end(), [](const QueryOutcome& o) { return !o.error.empty(); }));
  md += fmt::format("| queries refused | {} |\n\n", refused);
  md += "CPU milliseconds per query (median; one thread):\n\n"
        "| preprocess | features | coarse | fine | pose | total | total p95 |\n"
        "|---|---|---|---|---|---|---|\n";
  md += fmt::format("| {:.2f} | {:.2f} | {:.2f} | {:.2f} | {:.2f} | {:.2f} | {:.2f} |\n\n",
                    t.preprocess_cpu, t.features_cpu, t.coarse_cpu, t.fine_cpu, t.pose_cpu,
                    t.total_cpu, P95TotalMs());
  // Per label accuracy.
  md += fmt::format("| {} | queries | top-1 | top-{} |\n|---|---|---|---|\n",
                    options.protocol == EvalProtocol::kInstance ? "model" : "class", k);
  const bool instance = options.protocol == EvalProtocol::kInstance;
  for (const std::string& label : labels) {
    int n = 0, top1 = 0, topk = 0;
    for (const QueryOutcome& o : outcomes) {
      if ((instance ? o.truth_model : o.truth_class) != label) continue;
      ++n;
      top1 += instance ? o.model_top1 : o.class_top1;
      topk += instance ? o.model_topk : o.class_topk;
    }
    if (n > 0) md += fmt::format("| {} | {} | {} | {} |\n", label, n, top1, topk);
  }
  const std::vector<std::pair<std::string, int>> pairs = ConfusablePairs();
  if (!pairs.empty()) {
    md += "\nConfusable classes (truth → first suggestion, queries):\n\n";
    for (const auto& [pair, count] : pairs) md += fmt::format("- {}: {}\n", pair, count);
  }
  if (!skipped_models.empty()) {
    md += "\nSkipped models:\n\n";
    for (const std::string& s : skipped_models) md += "- " + s + "\n";
  }
  md += "\nPictures: `confusion.png` (rows truth, columns first suggestion), `pose_errors.png`.\n";
  return md;
}

std::string EvalReport::ToJson() const {
  const RecognitionTimings t = MedianTimings();
  nlohmann::json j;
  j["protocol"] = ToString(options.protocol);
  j["method"] = options.method_name;
  j["through_scan"] = options.through_scan;
  j["occlude_scans"] = options.occlude_scans;
  if (options.through_scan) j["scan_patterns"] = DescribePatterns(ScanPatterns(options));
  j["database"] = {{"path", database_path},
                   {"models", database_models},
                   {"views", database_views},
                   {"hash", hash}};
  j["queries"] = queries();
  j["queries_per_model"] = options.queries_per_model;
  j["seed"] = options.seed;
  j["top_k"] = options.recognition.top_k;
  j["query"] = {{"min_distance", options.query.min_distance},
                {"max_distance", options.query.max_distance},
                {"max_off_axis", options.query.max_off_axis},
                {"depth_noise", options.query.depth_noise},
                {"max_occlusion", options.query.max_occlusion},
                {"random_roll", options.query.random_roll}};
  j["model_top1"] = ModelTop1();
  j["model_topk"] = ModelTopK();
  j["class_top1"] = ClassTop1();
  j["class_topk"] = ClassTopK();
  j["class_top2"] = ClassTop2();
  nlohmann::json pairs = nlohmann::json::array();
  for (const auto& [pair, count] : ConfusablePairs()) pairs.push_back({{"pair", pair}, {"queries", count}});
  j["confusable_pairs"] = pairs;
  j["median_viewpoint_error_deg"] = JsonNumber(MedianViewpointErrorDeg());
  j["median_rotation_error_deg"] = JsonNumber(MedianRotationErrorDeg());
  j["median_translation_error_mm"] = JsonNumber(MedianTranslationErrorMm());
  j["median_adds_over_diameter"] = JsonNumber(MedianAddsOverDiameter());
  j["adds_threshold"] = options.adds_fraction;
  j["adds_success"] = AddsSuccess();
  j["rotation_threshold_deg"] = options.rotation_threshold_deg;
  j["rotation_success"] = RotationSuccess();
  j["bop_mssd_average_recall"] = MssdAverageRecall();
  j["bop_mspd_average_recall"] = MspdAverageRecall();
  j["query_image_width"] = query_image_width;
  j["flagged_fraction_mean"] = JsonNumber(MeanFlaggedFraction());
  j["flagged_fraction_max"] = MaxFlaggedFraction();
  j["timing_ms_median_cpu"] = {{"preprocess", t.preprocess_cpu}, {"features", t.features_cpu},
                               {"coarse", t.coarse_cpu},         {"fine", t.fine_cpu},
                               {"pose", t.pose_cpu},             {"total", t.total_cpu}};
  j["timing_ms_p95_total_cpu"] = JsonNumber(P95TotalMs());
  j["skipped_models"] = skipped_models;
  nlohmann::json list = nlohmann::json::array();
  for (const QueryOutcome& o : outcomes) {
    nlohmann::json q;
    q["truth_model"] = o.truth_model;
    q["truth_class"] = o.truth_class;
    q["truth_view_deg"] = {{"theta", o.truth_viewpoint.theta * kRadToDeg},
                           {"phi", o.truth_viewpoint.phi * kRadToDeg}};
    q["distance"] = o.distance;
    q["occluded_fraction"] = o.occluded_fraction;
    q["points"] = o.cloud_points;
    if (!o.error.empty()) q["error"] = o.error;
    q["model"] = o.predicted_model;
    q["class"] = o.predicted_class;
    q["model_top1"] = o.model_top1;
    q["model_topk"] = o.model_topk;
    q["class_top1"] = o.class_top1;
    q["class_topk"] = o.class_topk;
    q["class_top2"] = o.class_top2;
    q["refined"] = o.refined;
    q["score"] = o.score;
    q["truth_rank"] = o.truth_rank;
    q["truth_score"] = o.truth_score;
    q["viewpoint_error_deg"] = JsonNumber(o.viewpoint_error_deg);
    q["rotation_error_deg"] = JsonNumber(o.rotation_error_deg);
    q["translation_error_m"] = JsonNumber(o.translation_error_m);
    q["adds_over_diameter"] = JsonNumber(o.adds_over_diameter);
    q["mssd_over_diameter"] = JsonNumber(o.mssd_over_diameter);
    q["mspd_px"] = JsonNumber(o.mspd_px);
    q["flagged_fraction"] = o.flagged_fraction;
    nlohmann::json classes = nlohmann::json::array();
    for (const ClassScore& c : o.classes) {
      classes.push_back({{"class", c.class_name},
                         {"probability", c.probability},
                         {"verification", c.verification},
                         {"vote", c.vote},
                         {"fit", c.fit},
                         {"coverage", c.coverage},
                         {"rms_mm", 1e3 * c.rms}});
    }
    q["classes"] = std::move(classes);
    nlohmann::json suggested = nlohmann::json::array();
    for (const auto& [name, score] : o.suggestion_classes) {
      suggested.push_back({{"class", name}, {"score", score}});
    }
    q["suggestions"] = std::move(suggested);
    q["total_ms_cpu"] = o.timing.total_cpu;
    q["stage_ms_cpu"] = {{"preprocess", o.timing.preprocess_cpu},
                         {"features", o.timing.features_cpu},
                         {"coarse", o.timing.coarse_cpu},
                         {"fine", o.timing.fine_cpu},
                         {"pose", o.timing.pose_cpu}};
    list.push_back(std::move(q));
  }
  j["outcomes"] = std::move(list);
  return j.dump(1);
}

void WriteEvalReport(const EvalReport& report, const std::string& out_dir) {
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  SOPE_CHECK(!ec, "cannot create {}: {}", out_dir, ec.message());
  WriteFileAtomic(out_dir + "/report.md", report.ToMarkdown());
  WriteFileAtomic(out_dir + "/report.json", report.ToJson() + "\n");
  std::vector<std::string> labels;
  const std::vector<std::vector<int>> counts = report.Confusion(&labels);
  const bool instance = report.options.protocol == EvalProtocol::kInstance;
  WriteImageAtomic(out_dir + "/confusion.png",
                   DrawConfusionMatrix(counts, labels,
                                       fmt::format("{} protocol, {}: {} top-1 {}",
                                                   ToString(report.options.protocol),
                                                   report.options.method_name,
                                                   instance ? "model" : "class",
                                                   Percent(instance ? report.ModelTop1()
                                                                    : report.ClassTop1()))));
  std::vector<double> errors = Defined(report.outcomes, instance
                                                            ? &QueryOutcome::rotation_error_deg
                                                            : &QueryOutcome::viewpoint_error_deg);
  WriteImageAtomic(
      out_dir + "/pose_errors.png",
      DrawHistogram(errors, 0.0, 30.0, 30,
                    fmt::format("{} error of the first suggestion ({}, {} queries)",
                                instance ? "rotation" : "viewpoint", report.options.method_name,
                                errors.size()),
                    instance ? "rotation error modulo symmetry (deg)" : "viewpoint error (deg)",
                    report.options.rotation_threshold_deg));
}

}  // namespace sope
