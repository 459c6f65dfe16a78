#include "recogniser/scene_recognition.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <unordered_map>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "core/error.h"
#include "core/stopwatch.h"

namespace sope {
namespace {

uint64_t VoxelKey(const Eigen::Vector3f& p, float inv_leaf) {
  const auto cx = static_cast<int64_t>(std::floor(p.x() * inv_leaf)) + (1 << 20);
  const auto cy = static_cast<int64_t>(std::floor(p.y() * inv_leaf)) + (1 << 20);
  const auto cz = static_cast<int64_t>(std::floor(p.z() * inv_leaf)) + (1 << 20);
  return (static_cast<uint64_t>(cx) << 42) ^ (static_cast<uint64_t>(cy) << 21) ^
         static_cast<uint64_t>(cz);
}

// Scene points to explain: the clusters' points thinned to one per voxel (the first), each
// raw cluster point knowing its thinned point.
struct ThinnedScene {
  PointCloud points;
  std::vector<int> cluster_of;        // per thinned point
  std::vector<int> thinned_of_input;  // per input point: its thinned point or −1
};

ThinnedScene ThinClusters(const PointCloud& cloud, const std::vector<ObjectCluster>& clusters,
                          double leaf) {
  ThinnedScene scene;
  scene.thinned_of_input.assign(cloud.size(), -1);
  const float inv_leaf = static_cast<float>(1.0 / leaf);
  std::unordered_map<uint64_t, int> voxel;
  for (size_t c = 0; c < clusters.size(); ++c) {
    for (const int i : clusters[c].indices) {
      auto [it, inserted] = voxel.emplace(VoxelKey(cloud.points[i], inv_leaf),
                                          static_cast<int>(scene.points.size()));
      if (inserted) {
        scene.points.points.push_back(cloud.points[i]);
        scene.cluster_of.push_back(static_cast<int>(c));
      }
      scene.thinned_of_input[i] = it->second;
    }
  }
  return scene;
}

struct Hypothesis {
  int cluster = 0;
  RecognitionResult recognition;  // the suggestion in front
  double snap = 0.0;
  bool flipped = false;
};

// Height of the model's surface centroid above the plane over the model's diameter (the
// stability prior: lower is more stable).
double CentreOfMassHeight(const PointCloud& surface, const Rigid3d& cam_from_model,
                          const TablePlane& plane, double diameter) {
  if (surface.empty() || !(diameter > 0)) return 0.0;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3f& p : surface.points) sum += p.cast<double>();
  const Eigen::Vector3d centroid = cam_from_model * (sum / static_cast<double>(surface.size()));
  return plane.Height(centroid.cast<float>()) / diameter;
}

// The class probability the recogniser gave `class_index` (0 when it gave none).
double ClassProbability(const RecognitionResult& recognition, int class_index) {
  for (const ClassScore& c : recognition.classes) {
    if (c.class_index == class_index) return c.probability;
  }
  return 0.0;
}

// What every step of one scene recognition reads: the inputs, the segmentation's plane and
// clusters, the thinned scene, and the recogniser's parts.
struct SceneContext {
  const SceneRecogniser& scene_recogniser;
  const Recogniser& recogniser;
  const Database& database;
  const PointCloud& cloud;
  const SceneRecognitionOptions& options;
  const TablePlane& plane;
  const std::vector<ObjectCluster>& clusters;
  const ThinnedScene& scene;
};

// The hypotheses gathered so far, each cluster's first recognition, and the time spent.
struct HypothesisPool {
  std::vector<Hypothesis> hypotheses;
  std::vector<RecognitionResult> cluster_results;  // per cluster
  double recognise_ms = 0.0;
  double verify_ms = 0.0;
};

// Height above the plane of the lowest point of `surface` posed at `cam_from_model`.
float LowestHeight(const PointCloud& surface, const Rigid3d& cam_from_model,
                   const TablePlane& plane) {
  const Eigen::Matrix3f rotation = cam_from_model.rotation.cast<float>();
  const Eigen::Vector3f translation = cam_from_model.translation.cast<float>();
  float lowest = std::numeric_limits<float>::max();
  for (const Eigen::Vector3f& p : surface.points) {
    lowest = std::min(lowest, plane.Height(rotation * p + translation));
  }
  return lowest;
}

// The recogniser's result for `points`, evenly subsampled to at most max_recognition_points;
// empty when too few points survive its pre-processing (a sliver).
RecognitionResult RecogniseCluster(const SceneContext& ctx, const PointCloud& points) {
  const SceneRecognitionOptions& options = ctx.options;
  RecognitionResult recognition;
  try {
    if (static_cast<int>(points.size()) > options.max_recognition_points) {
      // An even subsample: the recogniser thins to its voxel leaf anyway.
      PointCloud thinned;
      const double step = static_cast<double>(points.size()) / options.max_recognition_points;
      for (int k = 0; k < options.max_recognition_points; ++k) {
        thinned.points.push_back(points.points[static_cast<size_t>(k * step)]);
      }
      recognition = ctx.recogniser.Recognise(thinned, options.recognition);
    } else {
      recognition = ctx.recogniser.Recognise(points, options.recognition);
    }
  } catch (const Error&) {
    // Too few points after pre-processing (a sliver): nothing to hypothesise.
  }
  return recognition;
}

// Puts the hypothesis down on the table (when within max_snap); false when it floats above
// the table or sinks into it by more than max_float (not a resting object).
bool SnapToTable(const SceneContext& ctx, Hypothesis* h) {
  Suggestion& front = h->recognition.suggestions[0];
  const PointCloud& surface =
      ctx.scene_recogniser.ModelSurface(front.model, ctx.options.model_leaf);
  const float lowest = LowestHeight(surface, front.cam_from_model, ctx.plane);
  if (!std::isfinite(lowest) || std::abs(lowest) > ctx.options.max_float) return false;
  if (std::abs(lowest) <= ctx.options.max_snap) {
    front.cam_from_model.translation -=
        static_cast<double>(lowest) * ctx.plane.normal.cast<double>();
    h->snap = -lowest;
  }
  return true;
}

// The same hypothesis turned upside down (half a turn about a horizontal axis through its
// centre), put down on the table: objects whose visible side looks alike both ways up (a
// bottle with its top cut off by the image border) are then decided by the data and, on a
// tie, by the lower centre of mass (a resting object rests stably). Empty when the turned
// pose does not rest on the table.
std::optional<Hypothesis> FlippedHypothesis(const SceneContext& ctx, const Hypothesis& h) {
  const TablePlane& plane = ctx.plane;
  Hypothesis flipped = h;
  Suggestion& f = flipped.recognition.suggestions[0];
  const PointCloud& surface = ctx.scene_recogniser.ModelSurface(f.model, ctx.options.model_leaf);
  const Eigen::Vector3d centre = f.cam_from_model * ctx.database.model(f.model).center;
  Eigen::Vector3d axis =
      Eigen::Vector3d::UnitX() - plane.normal.cast<double>() * plane.normal.cast<double>().x();
  axis.normalize();
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(M_PI, axis).toRotationMatrix();
  f.cam_from_model.rotation = turn * f.cam_from_model.rotation;
  f.cam_from_model.translation = turn * (f.cam_from_model.translation - centre) + centre;
  const float lowest = LowestHeight(surface, f.cam_from_model, plane);
  if (!std::isfinite(lowest) || std::abs(lowest) > ctx.options.max_float) return std::nullopt;
  f.cam_from_model.translation -= static_cast<double>(lowest) * plane.normal.cast<double>();
  flipped.snap = -lowest;
  flipped.flipped = true;
  return flipped;
}

// Recognises `points` of `cluster` and adds up to hypotheses_per_cluster hypotheses (each
// posed suggestion scoring at least min_hypothesis_score, put down on the table, and its
// flipped twin) to the pool.
void AddClusterHypotheses(const SceneContext& ctx, int cluster, const PointCloud& points,
                          HypothesisPool* pool) {
  const SceneRecognitionOptions& options = ctx.options;
  const Stopwatch watch;
  const RecognitionResult recognition = RecogniseCluster(ctx, points);
  pool->recognise_ms += watch.WallMs();
  if (pool->cluster_results[cluster].empty()) pool->cluster_results[cluster] = recognition;
  const bool on_table = options.snap_to_plane && ctx.plane.found;
  int taken = 0;
  for (size_t s = 0; s < recognition.suggestions.size() && taken < options.hypotheses_per_cluster;
       ++s) {
    const Suggestion& suggestion = recognition.suggestions[s];
    if (!suggestion.posed || suggestion.score < options.min_hypothesis_score) continue;
    Hypothesis h;
    h.cluster = cluster;
    h.recognition = recognition;
    std::swap(h.recognition.suggestions[0], h.recognition.suggestions[s]);
    if (s != 0) {
      h.recognition.recognised = suggestion.score >= options.recognition.assembly.min_score;
    }
    if (on_table && !SnapToTable(ctx, &h)) continue;
    if (on_table && options.flip_hypotheses) {
      std::optional<Hypothesis> flipped = FlippedHypothesis(ctx, h);
      if (flipped) pool->hypotheses.push_back(std::move(*flipped));
    }
    pool->hypotheses.push_back(std::move(h));
    ++taken;
  }
}

// Verifies every hypothesis of the pool against the scene (VerifyHypotheses), each with its
// stability prior and class evidence.
std::vector<HypothesisEvidence> VerifyPool(const SceneContext& ctx, HypothesisPool* pool) {
  const SceneRecognitionOptions& options = ctx.options;
  const TablePlane& plane = ctx.plane;
  const Stopwatch watch;
  std::vector<SceneHypothesis> scene_hypotheses;
  for (const Hypothesis& h : pool->hypotheses) {
    const Suggestion& s = h.recognition.suggestions[0];
    const PointCloud& surface = ctx.scene_recogniser.ModelSurface(s.model, options.model_leaf);
    const double prior =
        plane.found ? options.stability_weight *
                          std::max(0.0, CentreOfMassHeight(surface, s.cam_from_model, plane,
                                                           ctx.database.model(s.model).diameter))
                    : 0.0;
    const std::vector<ClassScore>& classes = h.recognition.classes;
    const double class_probability =
        !classes.empty() && classes.front().class_index == s.class_index
            ? classes.front().probability
            : 0.0;
    scene_hypotheses.push_back({&surface, s.cam_from_model, prior, class_probability});
  }
  // The segmentation cut everything below min_height (+ the plane noise) away: model
  // points there have nothing to fit.
  const float cut = static_cast<float>(options.segmentation.min_height +
                                       options.segmentation.plane_distance);
  std::vector<HypothesisEvidence> evidence = VerifyHypotheses(
      ctx.scene.points, ctx.cloud, scene_hypotheses, options.verification,
      [&plane, cut](const Eigen::Vector3f& p) { return plane.found && plane.Height(p) < cut; });
  pool->verify_ms += watch.WallMs();
  return evidence;
}

// Per thinned scene point: 1 when an accepted hypothesis explains it.
std::vector<uint8_t> ExplainedMask(size_t num_scene_points,
                                   const std::vector<HypothesisEvidence>& evidence) {
  std::vector<uint8_t> explained(num_scene_points, 0);
  for (const HypothesisEvidence& e : evidence) {
    if (!e.accepted) continue;
    for (const int j : e.explained) explained[j] = 1;
  }
  return explained;
}

// Remainders: clusters the accepted hypotheses leave largely unexplained (at least
// remainder_fraction of their thinned points) are recognised again on what is left.
// True when that added hypotheses.
bool AddRemainderHypotheses(const SceneContext& ctx,
                            const std::vector<HypothesisEvidence>& evidence, HypothesisPool* pool) {
  const SceneRecognitionOptions& options = ctx.options;
  const std::vector<ObjectCluster>& clusters = ctx.clusters;
  const ThinnedScene& scene = ctx.scene;
  const std::vector<uint8_t> explained = ExplainedMask(scene.points.size(), evidence);
  std::vector<int> cluster_thinned(clusters.size(), 0), cluster_left(clusters.size(), 0);
  for (size_t j = 0; j < scene.points.size(); ++j) {
    ++cluster_thinned[scene.cluster_of[j]];
    if (!explained[j]) ++cluster_left[scene.cluster_of[j]];
  }
  bool added = false;
  for (size_t c = 0; c < clusters.size(); ++c) {
    bool any_accepted = false;
    for (size_t h = 0; h < pool->hypotheses.size(); ++h) {
      any_accepted |= evidence[h].accepted && pool->hypotheses[h].cluster == static_cast<int>(c);
    }
    if (!any_accepted) continue;  // nothing explained: the whole cluster was tried
    if (cluster_left[c] < options.remainder_fraction * cluster_thinned[c]) continue;
    PointCloud remainder;
    for (const int i : clusters[c].indices) {
      if (!explained[scene.thinned_of_input[i]]) remainder.points.push_back(ctx.cloud.points[i]);
    }
    if (static_cast<int>(remainder.size()) < options.segmentation.min_cluster_points) continue;
    const size_t before = pool->hypotheses.size();
    AddClusterHypotheses(ctx, static_cast<int>(c), remainder, pool);
    added |= pool->hypotheses.size() > before;
  }
  return added;
}

void LogHypotheses(const SceneContext& ctx, const HypothesisPool& pool,
                   const std::vector<HypothesisEvidence>& evidence) {
  if (!spdlog::should_log(spdlog::level::debug)) return;
  const std::vector<Hypothesis>& hypotheses = pool.hypotheses;
  for (size_t h = 0; h < hypotheses.size(); ++h) {
    const Suggestion& s = hypotheses[h].recognition.suggestions[0];
    const HypothesisEvidence& e = evidence[h];
    const Eigen::Vector3f& c = ctx.clusters[hypotheses[h].cluster].centroid;
    spdlog::debug("hypothesis cluster={} centroid=({:.4f},{:.4f},{:.4f}) class={} model={} "
                  "score={:.3f} class_p={:.3f} flipped={} fit={:.3f} local={:.3f} "
                  "viol={:.3f} visible={} explained={} passes={} accepted={} class_level={} "
                  "why={}",
                  hypotheses[h].cluster, c.x(), c.y(), c.z(), s.class_name, s.model_name,
                  s.score, ClassProbability(hypotheses[h].recognition, s.class_index),
                  hypotheses[h].flipped, e.model_fit, e.local_explained, e.violation_fraction,
                  e.visible, e.explained.size(), e.passes, e.accepted, e.class_level,
                  RejectionReason(e, ctx.options.verification));
  }
}

// Objects: the accepted hypotheses (moved out of the pool and `evidence`), each with the
// input points it explains first. `left` gets, per cluster, the points no object explains.
std::vector<RecognisedObject> AssembleObjects(const SceneContext& ctx, HypothesisPool* pool,
                                              std::vector<HypothesisEvidence>* evidence,
                                              std::vector<std::vector<int>>* left) {
  std::vector<Hypothesis>& hypotheses = pool->hypotheses;
  std::vector<HypothesisEvidence>& ev = *evidence;
  std::vector<int> owner(ctx.scene.points.size(), -1);
  for (size_t h = 0; h < hypotheses.size(); ++h) {
    if (!ev[h].accepted) continue;
    for (const int j : ev[h].explained) {
      if (owner[j] < 0) owner[j] = static_cast<int>(h);
    }
  }
  std::vector<RecognisedObject> objects;
  std::vector<int> object_of_hypothesis(hypotheses.size(), -1);
  for (size_t h = 0; h < hypotheses.size(); ++h) {
    if (!ev[h].accepted) continue;
    RecognisedObject object;
    object.recognition = std::move(hypotheses[h].recognition);
    object.recognition.recognised = true;
    object.cluster = hypotheses[h].cluster;
    object.snap_m = hypotheses[h].snap;
    object.visible_fraction = ev[h].visible_fraction;
    object.class_level = ev[h].class_level;
    object.evidence = std::move(ev[h]);
    object_of_hypothesis[h] = static_cast<int>(objects.size());
    objects.push_back(std::move(object));
  }
  left->assign(ctx.clusters.size(), {});
  for (size_t c = 0; c < ctx.clusters.size(); ++c) {
    for (const int i : ctx.clusters[c].indices) {
      const int j = ctx.scene.thinned_of_input[i];
      if (owner[j] >= 0) {
        objects[object_of_hypothesis[owner[j]]].indices.push_back(i);
      } else {
        (*left)[c].push_back(i);
      }
    }
  }
  return objects;
}

// Unknown: a cluster nothing explains, or a remainder large enough to be an object, with
// the recogniser's guess and the cluster's rejected hypothesis that came closest to passing.
std::vector<UnknownObject> CollectUnknown(const SceneContext& ctx, const HypothesisPool& pool,
                                          const std::vector<HypothesisEvidence>& evidence,
                                          const std::vector<RecognisedObject>& objects,
                                          std::vector<std::vector<int>>* left) {
  const SceneRecognitionOptions& options = ctx.options;
  const std::vector<ObjectCluster>& clusters = ctx.clusters;
  const std::vector<Hypothesis>& hypotheses = pool.hypotheses;
  std::vector<UnknownObject> unknowns;
  for (size_t c = 0; c < clusters.size(); ++c) {
    std::vector<int>& cluster_left = (*left)[c];
    if (static_cast<int>(cluster_left.size()) < options.segmentation.min_cluster_points) continue;
    bool any = false;
    for (const RecognisedObject& o : objects) any |= o.cluster == static_cast<int>(c);
    if (any && cluster_left.size() < options.remainder_fraction * clusters[c].indices.size()) {
      continue;
    }
    UnknownObject unknown;
    unknown.cluster = static_cast<int>(c);
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (const int i : cluster_left) sum += ctx.cloud.points[i].cast<double>();
    unknown.centroid = (sum / static_cast<double>(cluster_left.size())).cast<float>();
    unknown.indices = std::move(cluster_left);
    const RecognitionResult& guess = pool.cluster_results[c];
    if (!any && !guess.empty()) {
      unknown.guess_class = guess.best().class_name;
      unknown.guess_model = guess.best().model_name;
      unknown.guess_score = guess.best().score;
    }
    int closest = -1;  // the cluster's hypothesis that came closest to passing
    for (size_t h = 0; h < hypotheses.size(); ++h) {
      if (hypotheses[h].cluster != static_cast<int>(c) || evidence[h].accepted) continue;
      const auto merit = [&evidence](size_t k) {
        return std::min(evidence[k].model_fit, evidence[k].local_explained);
      };
      if (closest < 0 || merit(h) > merit(closest)) closest = static_cast<int>(h);
    }
    if (closest >= 0) {
      const HypothesisEvidence& e = evidence[closest];
      unknown.guess_model_fit = e.model_fit;
      unknown.guess_local_explained = e.local_explained;
      unknown.guess_violations = e.violation_fraction;
      unknown.rejected_by = RejectionReason(e, options.verification);
    }
    unknowns.push_back(std::move(unknown));
  }
  return unknowns;
}

}  // namespace

// Which acceptance rule a hypothesis failed ("" when accepted).
std::string RejectionReason(const HypothesisEvidence& e, const SceneVerificationOptions& options) {
  if (e.accepted) return "";
  std::string why;
  auto add = [&why](const std::string& part) { why += (why.empty() ? "" : ", ") + part; };
  if (e.explained.empty()) add("explains no scene point");
  if (e.model_fit < options.min_model_fit) {
    add(fmt::format("model fit {:.2f} < {:.2f}", e.model_fit, options.min_model_fit));
  }
  if (e.local_explained < options.min_local_explained) {
    add(fmt::format("local explained {:.2f} < {:.2f}", e.local_explained,
                    options.min_local_explained));
  }
  if (e.violation_fraction > options.max_violation_fraction) {
    add(fmt::format("free-space violations {:.2f} > {:.2f}", e.violation_fraction,
                    options.max_violation_fraction));
  }
  if (!why.empty()) why += " (instance level)";
  if (why.empty()) add("gain (points another hypothesis explains, violations, stability)");
  return why;
}

struct SceneRecogniser::Cache {
  std::mutex mutex;
  std::map<std::pair<int, double>, std::unique_ptr<PointCloud>> surfaces;
};

void SceneRecognitionOptions::Check() const {
  segmentation.Check();
  recognition.Check();
  verification.Check();
  SOPE_CHECK(hypotheses_per_cluster >= 1,
             "scene recognition: hypotheses per cluster must be ≥ 1, got {}",
             hypotheses_per_cluster);
  SOPE_CHECK(min_hypothesis_score >= 0 && min_hypothesis_score <= 1,
             "scene recognition: min hypothesis score must be in [0, 1], got {}",
             min_hypothesis_score);
  SOPE_CHECK(max_snap >= 0, "scene recognition: max snap must be ≥ 0 m, got {}", max_snap);
  SOPE_CHECK(max_float >= max_snap, "scene recognition: max float must be ≥ max snap ({} m), got {}",
             max_snap, max_float);
  SOPE_CHECK(max_recognition_points >= 100,
             "scene recognition: max recognition points must be ≥ 100, got {}",
             max_recognition_points);
  SOPE_CHECK(remainder_fraction >= 0 && remainder_fraction <= 1,
             "scene recognition: remainder fraction must be in [0, 1], got {}",
             remainder_fraction);
  SOPE_CHECK(stability_weight >= 0, "scene recognition: stability weight must be ≥ 0, got {}",
             stability_weight);
  SOPE_CHECK(scene_leaf > 0 && model_leaf > 0,
             "scene recognition: leaves must be > 0 m, got {} and {}", scene_leaf, model_leaf);
}

SceneRecogniser::SceneRecogniser(const Database& database)
    : database_(database), recogniser_(database), cache_(std::make_unique<Cache>()) {}
SceneRecogniser::~SceneRecogniser() = default;

const PointCloud& SceneRecogniser::ModelSurface(int model, double leaf) const {
  SOPE_CHECK(model >= 0 && model < database_.num_models(),
             "scene recognition: model {} out of range (database of {})", model,
             database_.num_models());
  std::lock_guard<std::mutex> lock(cache_->mutex);
  std::unique_ptr<PointCloud>& slot = cache_->surfaces[{model, leaf}];
  if (slot) return *slot;
  auto surface = std::make_unique<PointCloud>();
  const ModelRecord& record = database_.model(model);
  const float inv_leaf = static_cast<float>(1.0 / leaf);
  std::unordered_map<uint64_t, int> voxel;
  PointCloud view;
  for (int v = record.first_view; v < record.first_view + record.num_views; ++v) {
    database_.ViewCloud(v, &view);
    for (size_t i = 0; i < view.size(); ++i) {
      if (!voxel.emplace(VoxelKey(view.points[i], inv_leaf), 0).second) continue;
      surface->points.push_back(view.points[i]);
      surface->normals.push_back(view.HasNormals() ? view.normals[i]
                                                   : Eigen::Vector3f::UnitZ().eval());
    }
  }
  slot = std::move(surface);
  return *slot;
}

SceneRecognitionResult SceneRecogniser::Recognise(const PointCloud& cloud,
                                                  const SceneRecognitionOptions& options) const {
  options.Check();
  const Stopwatch total;
  SceneRecognitionResult result;
  result.segmentation = SegmentTable(cloud, options.segmentation);
  result.timing.segment = result.segmentation.ms;
  const std::vector<ObjectCluster>& clusters = result.segmentation.clusters;
  if (clusters.empty()) {
    result.timing.total = total.WallMs();
    return result;
  }
  const ThinnedScene scene = ThinClusters(cloud, clusters, options.scene_leaf);
  const SceneContext ctx{*this, recogniser_, database_, cloud, options,
                         result.segmentation.plane, clusters, scene};

  HypothesisPool pool;
  pool.cluster_results.resize(clusters.size());
  for (size_t c = 0; c < clusters.size(); ++c) {
    AddClusterHypotheses(ctx, static_cast<int>(c), clusters[c].cloud, &pool);
  }
  std::vector<HypothesisEvidence> evidence = VerifyPool(ctx, &pool);
  if (options.remainder_fraction > 0 && AddRemainderHypotheses(ctx, evidence, &pool)) {
    evidence = VerifyPool(ctx, &pool);
  }
  result.hypotheses = static_cast<int>(pool.hypotheses.size());
  LogHypotheses(ctx, pool, evidence);

  std::vector<std::vector<int>> left;
  result.objects = AssembleObjects(ctx, &pool, &evidence, &left);
  result.unknown = CollectUnknown(ctx, pool, evidence, result.objects, &left);
  std::stable_sort(result.objects.begin(), result.objects.end(),
                   [](const RecognisedObject& a, const RecognisedObject& b) {
                     return a.best().score > b.best().score;
                   });
  result.timing.recognise = pool.recognise_ms;
  result.timing.verify = pool.verify_ms;
  result.timing.total = total.WallMs();
  return result;
}

std::string SceneRecognitionResultToJson(const SceneRecognitionResult& result) {
  nlohmann::json j;
  if (!result.objects.empty()) {
    j = nlohmann::json::parse(RecognitionResultToJson(result.objects.front().recognition));
  } else {
    j["recognised"] = false;
  }
  nlohmann::json objects = nlohmann::json::array();
  for (const RecognisedObject& object : result.objects) {
    nlohmann::json o = nlohmann::json::parse(RecognitionResultToJson(object.recognition));
    o["points"] = object.indices.size();
    o["visible_fraction"] = object.visible_fraction;
    o["verified"] = object.verified;
    // "instance": the database model explains the scan; "class": an instance of the class
    // the recogniser ranked first, not fitting any database model exactly ("model" is then
    // the nearest database instance, whose pose is given).
    o["match_level"] = object.class_level ? "class" : "instance";
    o["cluster"] = object.cluster;
    o["snap_m"] = object.snap_m;
    o["model_fit_scene"] = object.evidence.model_fit;
    o["local_explained"] = object.evidence.local_explained;
    objects.push_back(std::move(o));
  }
  j["objects"] = std::move(objects);
  nlohmann::json unknown = nlohmann::json::array();
  for (const UnknownObject& u : result.unknown) {
    nlohmann::json o = {{"points", u.indices.size()},
                        {"cluster", u.cluster},
                        {"centroid", {u.centroid.x(), u.centroid.y(), u.centroid.z()}}};
    if (!u.guess_model.empty()) {
      o["guess"] = {{"class", u.guess_class}, {"model", u.guess_model}, {"score", u.guess_score}};
    }
    if (!u.rejected_by.empty()) {
      o["rejected_by"] = u.rejected_by;
      o["model_fit_scene"] = u.guess_model_fit;
      o["local_explained"] = u.guess_local_explained;
      o["violation_fraction"] = u.guess_violations;
    }
    unknown.push_back(std::move(o));
  }
  j["unknown"] = std::move(unknown);
  const TablePlane& plane = result.segmentation.plane;
  j["table"] = {{"found", plane.found},
                {"normal", {plane.normal.x(), plane.normal.y(), plane.normal.z()}},
                {"offset_m", plane.offset},
                {"inliers", plane.inliers}};
  if (!result.segmentation.message.empty()) j["table"]["message"] = result.segmentation.message;
  j["clusters"] = result.segmentation.clusters.size();
  j["hypotheses"] = result.hypotheses;
  j["scene_ms"] = {{"segment", result.timing.segment},
                   {"recognise", result.timing.recognise},
                   {"verify", result.timing.verify},
                   {"total", result.timing.total}};
  return j.dump();
}

std::string SceneBriefReport(const SceneRecognitionResult& result) {
  std::string report;
  const TableSegmentation& seg = result.segmentation;
  if (!seg.plane.found || seg.clusters.empty()) {
    report += seg.message + "\n";
  } else {
    report += fmt::format("table: {} plane points, {} cluster(s), {} hypotheses\n",
                          seg.plane.inliers, seg.clusters.size(), result.hypotheses);
  }
  for (size_t i = 0; i < result.objects.size(); ++i) {
    const RecognisedObject& o = result.objects[i];
    const Suggestion& s = o.best();
    report += fmt::format("{}. {:<12} {:<20} score {:.3f}  {} points  t = ({:.3f}, {:.3f}, "
                          "{:.3f}) m{}\n",
                          i + 1, s.class_name, s.model_name, s.score, o.indices.size(),
                          s.cam_from_model.translation.x(), s.cam_from_model.translation.y(),
                          s.cam_from_model.translation.z(),
                          o.class_level ? "  (class level: an instance not in the database)" : "");
  }
  for (const UnknownObject& u : result.unknown) {
    report += fmt::format("unknown object: {} points at ({:.3f}, {:.3f}, {:.3f}) m{}\n",
                          u.indices.size(), u.centroid.x(), u.centroid.y(), u.centroid.z(),
                          u.guess_model.empty()
                              ? std::string()
                              : fmt::format(" (nearest {} {}, rejected)", u.guess_class,
                                            u.guess_model));
  }
  report += fmt::format("times: segment {:.1f} ms, recognise {:.1f} ms, verify {:.1f} ms, total "
                        "{:.1f} ms",
                        result.timing.segment, result.timing.recognise, result.timing.verify,
                        result.timing.total);
  return report;
}

}  // namespace sope
