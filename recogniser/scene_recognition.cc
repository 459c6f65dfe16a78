#include "recogniser/scene_recognition.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <deque>
#include <limits>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <tuple>
#include <unordered_map>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "core/convex_hull.h"
#include "core/error.h"
#include "core/run_jobs.h"
#include "core/stopwatch.h"
#include "recogniser/features.h"
#include "recogniser/pose.h"
#include "recogniser/preprocess.h"
#include "recogniser/stages.h"
#include "recogniser/voxel_key.h"

namespace sope {
namespace {

// The packed key of integer cell coordinates (recogniser/voxel_key.h).
uint64_t PackVoxel(const Eigen::Matrix<int64_t, 3, 1>& c) {
  return PackVoxelKey(c.x(), c.y(), c.z());
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
      auto [it, inserted] = voxel.emplace(VoxelKeyOf(cloud.points[i], inv_leaf),
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
  double lift = 0.0;  // height of its lowest point above the table when left where it was
  bool flipped = false;
  bool twin = false;  // a half-turn twin of another hypothesis, refined on its cluster
  bool rested = false;  // turned onto a resting face of its model (it did not rest)
  bool sibling = false;  // another model of the class in another hypothesis's pose, refined
  bool rolled = false;   // turned about its model's axis of near symmetry, refined
  bool upright = false;  // stood upright on the standing axis of its points
  // A model scaled per axis (its own surface sample, `scale` in the model frame about the
  // model's centre) to the cluster's size; null: the model's surface as it is.
  const PointCloud* surface = nullptr;
  Eigen::Vector3d scale = Eigen::Vector3d::Ones();
};

// The recogniser names the runner-up class when it comes within `margin` of its first; the
// scene may accept another class than the first. The doubt is then about the accepted
// class: the most probable other class, named when its probability is at least the
// accepted class's less `margin` (always, when the accepted class was not ranked first).
// Empty when nothing comes that near, or without class ranking.
std::string AmbiguousWith(const RecognitionResult& recognition, double margin) {
  const Suggestion& accepted = recognition.suggestions[0];
  double accepted_probability = 0.0;
  const ClassScore* other = nullptr;
  for (const ClassScore& c : recognition.classes) {
    if (c.class_index == accepted.class_index) {
      accepted_probability = c.probability;
    } else if (other == nullptr || c.probability > other->probability) {
      other = &c;
    }
  }
  if (other == nullptr || other->probability < accepted_probability - margin) return {};
  return other->class_name;
}

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

// Where the table seen ends, away from the camera: `far` the camera's viewing direction
// (+z) in the table plane, `edge` the 99th percentile of p·far over the points on the plane
// (within plane_distance of it). Not found without a plane or points on it.
struct TableFarEdge {
  bool found = false;
  Eigen::Vector3f far = Eigen::Vector3f::UnitZ();
  float edge = 0.0f;
};

TableFarEdge FarEdgeOf(const PointCloud& cloud, const TablePlane& plane, double plane_distance) {
  TableFarEdge out;
  if (!plane.found) return out;
  const Eigen::Vector3f z = Eigen::Vector3f::UnitZ();
  const Eigen::Vector3f far = z - z.dot(plane.normal) * plane.normal;
  if (!(far.norm() > 1e-3f)) return out;  // looking straight down: no far side
  out.far = far.normalized();
  const size_t step = std::max<size_t>(1, cloud.size() / 20000);  // an even subsample
  std::vector<float> along;
  for (size_t i = 0; i < cloud.size(); i += step) {
    const Eigen::Vector3f& p = cloud.points[i];
    if (p.allFinite() && std::abs(plane.Height(p)) <= plane_distance) {
      along.push_back(p.dot(out.far));
    }
  }
  if (along.empty()) return out;
  const size_t k = along.size() * 99 / 100;
  std::nth_element(along.begin(), along.begin() + k, along.end());
  out.edge = along[k];
  out.found = true;
  return out;
}

// True when `cluster` is one plane (backdrop_planar_fraction of its points within
// backdrop_plane_distance of its least-squares plane) that is a wall or backdrop, not an
// object on the table: longer than backdrop_extent_factor × `max_diameter` along its major
// axis, or standing upright (its normal within 15° of the table's) at the far edge of the
// table seen (`far_edge`: 95% of its points at most 1 cm before it) — the strip of a wall
// behind the table that the image border cuts short.
bool IsBackdrop(const ObjectCluster& cluster, double max_diameter, const TablePlane& plane,
                const TableFarEdge& far_edge, const SceneRecognitionOptions& options) {
  if (options.backdrop_planar_fraction <= 0 || cluster.cloud.size() < 3) return false;
  const std::vector<Eigen::Vector3f>& points = cluster.cloud.points;
  const size_t step = std::max<size_t>(1, points.size() / 5000);  // an even subsample
  std::vector<Eigen::Vector3f> sample;
  for (size_t i = 0; i < points.size(); i += step) sample.push_back(points[i]);
  Eigen::Vector3d mean;
  Eigen::Matrix3d axes;
  Eigen::Vector3d variances;
  internal::PrincipalAxes(sample, &mean, &axes, &variances);
  const Eigen::Vector3d major = axes.col(0);
  const Eigen::Vector3d normal = axes.col(2);
  double low = std::numeric_limits<double>::max(), high = -low;
  size_t on_plane = 0;
  for (const Eigen::Vector3f& p : sample) {
    const Eigen::Vector3d d = p.cast<double>() - mean;
    low = std::min(low, d.dot(major));
    high = std::max(high, d.dot(major));
    on_plane += std::abs(d.dot(normal)) <= options.backdrop_plane_distance;
  }
  const size_t n = sample.size();
  if (static_cast<double>(on_plane) < options.backdrop_planar_fraction * n) return false;
  if (high - low > options.backdrop_extent_factor * max_diameter) return true;
  if (!far_edge.found || std::abs(normal.cast<float>().dot(plane.normal)) > 0.26f) return false;
  size_t beyond = 0;  // points at most 1 cm before the far edge, or beyond it
  for (const Eigen::Vector3f& p : sample) beyond += p.dot(far_edge.far) >= far_edge.edge - 0.01f;
  return static_cast<double>(beyond) >= 0.95 * n;
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
  double max_diameter;  // of the database's largest model, metres
  // Per class: whether a cluster may be taken for an unseen instance of it (ClassLevels).
  const std::vector<uint8_t>& class_level;
};

// The hypotheses gathered so far, each cluster's first recognition, and the time spent.
struct HypothesisPool {
  std::vector<Hypothesis> hypotheses;
  std::vector<RecognitionResult> cluster_results;  // per cluster
  // Second looks taken: per cluster (remainder, twins, split) and per joined pair (a
  // cluster and another cluster, or num_clusters + the accepted hypothesis it joined).
  std::vector<uint8_t> remainder_tried, twins_tried, split_tried;
  bool size_looks_taken = false;  // siblings and scaled models (every cluster, once)
  bool other_classes_taken = false;  // AddOtherClassLooks (once)
  // Per cluster, [begin, end) of the hypotheses its size looks added (AddSizeHypotheses).
  std::vector<std::pair<size_t, size_t>> size_looks_of;
  // The surface samples of scaled hypotheses (Hypothesis::surface points into it).
  std::deque<PointCloud> scaled_surfaces;
  // Per cluster: its pose query (ClusterPoseQuery), built on first use.
  std::vector<std::optional<PoseQuery>> pose_queries;
  std::vector<uint8_t> pose_query_built;
  std::set<std::pair<int, int>> joined;
  // The verification of the hypotheses so far (they are only ever appended).
  VerificationCache verification;
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

// The surface sample a hypothesis is verified with: its scaled one, or its model's.
const PointCloud& SurfaceOf(const SceneContext& ctx, const Hypothesis& h) {
  if (h.surface != nullptr) return *h.surface;
  return ctx.scene_recogniser.ModelSurface(h.recognition.suggestions[0].model,
                                           ctx.options.model_leaf);
}

// The recogniser's result for `points`, evenly subsampled to at most max_recognition_points;
// empty when too few points survive its pre-processing (a sliver).
RecognitionResult RecogniseCluster(const SceneContext& ctx, const PointCloud& points) {
  const SceneRecognitionOptions& options = ctx.options;
  RecognitionOptions recognition_options = options.recognition;
  if (options.widen_every_batch) {
    recognition_options.widening.continue_below = recognition_options.widening.below_score;
    recognition_options.widening.screen_stop = 0.0;
  }
  RecognitionResult recognition;
  try {
    if (static_cast<int>(points.size()) > options.max_recognition_points) {
      // An even subsample: the recogniser thins to its voxel leaf anyway.
      PointCloud thinned;
      const double step = static_cast<double>(points.size()) / options.max_recognition_points;
      for (int k = 0; k < options.max_recognition_points; ++k) {
        thinned.points.push_back(points.points[static_cast<size_t>(k * step)]);
      }
      recognition = ctx.recogniser.Recognise(thinned, recognition_options);
    } else {
      recognition = ctx.recogniser.Recognise(points, recognition_options);
    }
  } catch (const Error&) {
    // Too few points after pre-processing (a sliver): nothing to hypothesise.
  }
  return recognition;
}

// job(context, k) for each k < count: side by side on recognition.threads threads when
// there are several (each job on one thread, with a context whose recognition.threads is
// 1: a job's answer is then the same for any thread count), else in order on the calling
// thread with `ctx`. True when they ran side by side.
bool SideBySide(const SceneContext& ctx, size_t count,
                const std::function<void(const SceneContext&, size_t)>& job) {
  const int threads = ctx.options.recognition.threads;
  if (threads <= 1 || count <= 1) {
    for (size_t k = 0; k < count; ++k) job(ctx, k);
    return false;
  }
  SceneRecognitionOptions one_thread = ctx.options;
  one_thread.recognition.threads = 1;
  const SceneContext ctx_one_thread{ctx.scene_recogniser, ctx.recogniser, ctx.database,
                                    ctx.cloud,            one_thread,     ctx.plane,
                                    ctx.clusters,         ctx.scene,      ctx.max_diameter,
                                    ctx.class_level};
  RunJobs(threads, count, [&](size_t k) { job(ctx_one_thread, k); });
  return true;
}

// RecogniseCluster of each of `clouds`, in order, side by side (SideBySide). The wall time
// goes to pool->recognise_ms.
std::vector<RecognitionResult> RecogniseSideBySide(const SceneContext& ctx,
                                                   const std::vector<const PointCloud*>& clouds,
                                                   HypothesisPool* pool) {
  const Stopwatch watch;
  std::vector<RecognitionResult> results(clouds.size());
  SideBySide(ctx, clouds.size(), [&](const SceneContext& c, size_t k) {
    results[k] = RecogniseCluster(c, *clouds[k]);
  });
  pool->recognise_ms += watch.WallMs();
  return results;
}

// The looks of `count` jobs (job(context, k, pool of its own)), side by side (SideBySide);
// then each job's hypotheses, with the scaled surfaces they point to, join `pool` in job
// order, and so does a cluster's first recognition a job set where `pool` has none — the
// same as the jobs one after another into `pool` (a job reads no other job's hypotheses,
// nor those first recognitions). Returns how many hypotheses each job added.
std::vector<size_t> LooksSideBySide(
    const SceneContext& ctx, size_t count, HypothesisPool* pool,
    const std::function<void(const SceneContext&, size_t, HypothesisPool*)>& job) {
  std::vector<HypothesisPool> looks(count);
  for (HypothesisPool& l : looks) l.cluster_results.resize(pool->cluster_results.size());
  const Stopwatch watch;
  const bool parallel =
      SideBySide(ctx, count, [&](const SceneContext& c, size_t k) { job(c, k, &looks[k]); });
  if (parallel) pool->recognise_ms += watch.WallMs();
  std::vector<size_t> added(count, 0);
  for (size_t k = 0; k < count; ++k) {
    HypothesisPool& l = looks[k];
    if (!parallel) pool->recognise_ms += l.recognise_ms;
    for (size_t c = 0; c < l.cluster_results.size(); ++c) {
      if (pool->cluster_results[c].empty() && !l.cluster_results[c].empty()) {
        pool->cluster_results[c] = std::move(l.cluster_results[c]);
      }
    }
    // The scaled surfaces move to the pool's deque (where they stay put), and the
    // hypotheses that point to them follow.
    std::map<const PointCloud*, const PointCloud*> moved;
    for (PointCloud& surface : l.scaled_surfaces) {
      const PointCloud* from = &surface;
      pool->scaled_surfaces.push_back(std::move(surface));
      moved[from] = &pool->scaled_surfaces.back();
    }
    added[k] = l.hypotheses.size();
    for (Hypothesis& h : l.hypotheses) {
      const auto to = moved.find(h.surface);
      if (to != moved.end()) h.surface = to->second;
      pool->hypotheses.push_back(std::move(h));
    }
  }
  return added;
}

// Whether a cluster's unexplained fraction `left` is a remainder worth recognising whole
// (SceneRecognitionOptions::remainder_fraction).
bool LargeRemainder(const SceneRecognitionOptions& options, double left) {
  return options.remainder_fraction > 0 && left >= options.remainder_fraction;
}

// The database models of class `class_index`, by index (an instance database has one per
// class: the object on the table is one of them, of its size).
std::vector<int> ModelsOfClass(const Database& database, int class_index) {
  std::vector<int> models;
  for (int m = 0; m < database.num_models(); ++m) {
    if (database.model(m).class_index == class_index) models.push_back(m);
  }
  return models;
}

// Per class, whether a cluster may be taken for an unseen instance of it (its size looks,
// class-level acceptance): the class is a category (Database::IsCategory), or its one model
// is the class (an instance database's class: a looser look at that model). A folder of
// several unlike models (a dataset's) is not: a stone is no unseen "ycb".
std::vector<uint8_t> ClassLevels(const Database& database) {
  std::vector<uint8_t> allowed(database.classes().size());
  for (size_t c = 0; c < allowed.size(); ++c) {
    const int class_index = static_cast<int>(c);
    allowed[c] = database.IsCategory(class_index) ||
                 ModelsOfClass(database, class_index).size() == 1;
  }
  return allowed;
}

// `recognition` with its best posed suggestion of class `class_index` first, as a
// hypothesis of `cluster`; nullopt when it posed none of that class — among its
// suggestions, or with `other_class_poses` also among those the cut to top_k left out
// (RecognitionResult::other_class_poses).
std::optional<Hypothesis> ClassSource(const RecognitionResult& recognition, int cluster,
                                      int class_index, bool other_class_poses = false) {
  const auto of_class = [&](const Suggestion& x) {
    return x.posed && x.class_index == class_index;
  };
  Hypothesis source;
  source.cluster = cluster;
  const auto s =
      std::find_if(recognition.suggestions.begin(), recognition.suggestions.end(), of_class);
  if (s != recognition.suggestions.end()) {
    source.recognition = recognition;
    std::iter_swap(source.recognition.suggestions.begin(),
                   source.recognition.suggestions.begin() + (s - recognition.suggestions.begin()));
    return source;
  }
  if (!other_class_poses) return std::nullopt;
  const std::vector<Suggestion>& others = recognition.other_class_poses;
  const auto o = std::find_if(others.begin(), others.end(), of_class);
  if (o == others.end()) return std::nullopt;
  source.recognition = recognition;
  source.recognition.suggestions.insert(source.recognition.suggestions.begin(), *o);
  return source;
}

// The best posed suggestion of the class `recognition` ranks first, when it ranks it so
// with at least verification.min_class_probability, as a hypothesis of `cluster` (the
// source of siblings and scaled models); *class_models receives that class's models.
std::optional<Hypothesis> FirstClassSource(const SceneContext& ctx,
                                           const RecognitionResult& recognition, int cluster,
                                           std::vector<int>* class_models) {
  if (recognition.classes.empty() ||
      recognition.classes.front().probability < ctx.options.verification.min_class_probability ||
      !ctx.class_level[recognition.classes.front().class_index]) {
    return std::nullopt;
  }
  const int first_class = recognition.classes.front().class_index;
  std::optional<Hypothesis> source = ClassSource(recognition, cluster, first_class);
  if (source) *class_models = ModelsOfClass(ctx.database, first_class);
  return source;
}

// Puts the hypothesis down on the table (when within max_snap); false when it floats above
// the table or sinks into it by more than max_float (not a resting object).
bool SnapToTable(const SceneContext& ctx, Hypothesis* h) {
  Suggestion& front = h->recognition.suggestions[0];
  const PointCloud& surface = SurfaceOf(ctx, *h);
  const float lowest = LowestHeight(surface, front.cam_from_model, ctx.plane);
  if (!std::isfinite(lowest) || std::abs(lowest) > ctx.options.max_float) {
    spdlog::debug("cluster {}: {} ({}, score {:.3f}) dropped: its lowest point {:.3f} m off "
                  "the table (> {:.3f})", h->cluster, ctx.database.model(front.model).name,
                  ctx.database.model(front.model).class_name, front.score, lowest,
                  ctx.options.max_float);
    return false;
  }
  if (std::abs(lowest) <= ctx.options.max_snap) {
    front.cam_from_model.translation -=
        static_cast<double>(lowest) * ctx.plane.normal.cast<double>();
    h->snap = -lowest;
    h->lift = 0.0;
  }
  return true;
}

// Puts the hypothesis, whose model surface is `surface`, down on the table along its
// normal (its lowest point onto the plane, `snap` the shift); false, leaving it unchanged,
// when that point is more than `max_lift` metres off the plane (or none was found).
bool PutDownOnTable(const SceneContext& ctx, const PointCloud& surface, double max_lift,
                    Hypothesis* h) {
  Suggestion& f = h->recognition.suggestions[0];
  const float lowest = LowestHeight(surface, f.cam_from_model, ctx.plane);
  if (!std::isfinite(lowest) || std::abs(lowest) > max_lift) return false;
  f.cam_from_model.translation -= static_cast<double>(lowest) * ctx.plane.normal.cast<double>();
  h->snap = -lowest;
  h->lift = 0.0;
  return true;
}

// Turns the hypothesis by `turn` about its model's centre and puts it down on the table
// (PutDownOnTable); false, leaving it half-changed, when its lowest point was more than
// `max_lift` metres off the plane (or none was found).
bool TurnOntoTable(const SceneContext& ctx, const Eigen::Matrix3d& turn, double max_lift,
                   Hypothesis* h) {
  Suggestion& f = h->recognition.suggestions[0];
  const Eigen::Vector3d centre = f.cam_from_model * ctx.database.model(f.model).center;
  f.cam_from_model.rotation = turn * f.cam_from_model.rotation;
  f.cam_from_model.translation = turn * (f.cam_from_model.translation - centre) + centre;
  return PutDownOnTable(ctx, SurfaceOf(ctx, *h), max_lift, h);
}

// The same hypothesis turned upside down (half a turn about a horizontal axis through its
// centre), put down on the table: objects whose visible side looks alike both ways up (a
// bottle with its top cut off by the image border) are then decided by the data and, on a
// tie, by the lower centre of mass (a resting object rests stably). Empty when the turned
// pose does not rest on the table.
std::optional<Hypothesis> FlippedHypothesis(const SceneContext& ctx, const Hypothesis& h) {
  const Eigen::Vector3d normal = ctx.plane.normal.cast<double>();
  const Eigen::Vector3d axis = (Eigen::Vector3d::UnitX() - normal * normal.x()).normalized();
  Hypothesis flipped = h;
  if (!TurnOntoTable(ctx, Eigen::AngleAxisd(M_PI, axis).toRotationMatrix(),
                     ctx.options.max_float, &flipped)) {
    return std::nullopt;
  }
  flipped.flipped = true;
  return flipped;
}

// The stable faces of the hull of `h`'s model (camera frame, outward normals) that a turn
// of at most max_turn_deg puts on the table, the least turn first.
std::vector<Eigen::Vector3d> RestingFacesWithin(const SceneContext& ctx, const Hypothesis& h,
                                                double max_turn_deg) {
  const Suggestion& s = h.recognition.suggestions[0];
  const Eigen::Vector3d down = -ctx.plane.normal.cast<double>();
  const double min_alignment = std::cos(max_turn_deg * M_PI / 180.0);
  std::vector<std::pair<double, Eigen::Vector3d>> faces;
  for (const Eigen::Vector3d& normal :
       ctx.scene_recogniser.RestingNormals(s.model, ctx.options.model_leaf)) {
    const Eigen::Vector3d face = s.cam_from_model.rotation * normal;
    const double alignment = face.dot(down);
    if (alignment >= min_alignment) faces.emplace_back(alignment, face);
  }
  std::stable_sort(faces.begin(), faces.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<Eigen::Vector3d> out;
  for (const auto& [alignment, face] : faces) out.push_back(face);
  return out;
}

// `h` turned onto `face` (camera frame, a stable face of its model's hull) about its model's
// centre and put down on the table whatever its height was; empty when no lowest point
// was found.
std::optional<Hypothesis> TurnedOntoFace(const SceneContext& ctx, const Hypothesis& h,
                                         const Eigen::Vector3d& face) {
  const Eigen::Vector3d down = -ctx.plane.normal.cast<double>();
  Hypothesis rested = h;
  if (!TurnOntoTable(ctx, Eigen::Quaterniond::FromTwoVectors(face, down).toRotationMatrix(),
                     std::numeric_limits<double>::infinity(), &rested)) {
    return std::nullopt;
  }
  rested.rested = true;
  return rested;
}

// The hypothesis turned the least that puts a stable face of its model's hull on the
// table (about the model's centre; at most max_rest_turn_deg), then put down on it. Empty
// when no resting face is that near.
std::optional<Hypothesis> RestedHypothesis(const SceneContext& ctx, const Hypothesis& h) {
  const SceneRecognitionOptions& options = ctx.options;
  if (options.max_rest_turn_deg <= 0) return std::nullopt;
  const std::vector<Eigen::Vector3d> faces = RestingFacesWithin(ctx, h, options.max_rest_turn_deg);
  if (faces.empty()) {
    spdlog::debug("{}: no resting face within {:.0f}° of its pose",
                  h.recognition.suggestions[0].model_name, options.max_rest_turn_deg);
    return std::nullopt;
  }
  return TurnedOntoFace(ctx, h, faces.front());
}

// Puts the hypothesis down on the table: snapped when it nearly rests on it, else turned
// onto its nearest resting face (RestedHypothesis); false when neither.
bool PutOnTable(const SceneContext& ctx, Hypothesis* h) {
  if (SnapToTable(ctx, h)) return true;
  std::optional<Hypothesis> rested = RestedHypothesis(ctx, *h);
  if (!rested) return false;
  *h = std::move(*rested);
  return true;
}

IcpResult RefineOnCluster(const SceneContext& ctx, const PoseQuery& query,
                          const PointCloud& surface, const Rigid3d& canonical_from_model,
                          Hypothesis* h, int iterations = 0);
void ScoreOnCluster(const SceneContext& ctx, const PoseQuery& query,
                    const Rigid3d& canonical_from_model, Hypothesis* h);

// `h` (snapped onto the table by a large shift: its recognised pose sank into the table or
// floated above it) turned onto each of its model's resting faces (the least turns first,
// at most rest_refit_faces; a lying object seen in part can be a quarter turn or more off
// about its long axis) and refined there on the points it was recognised from
// (`query_of`) with the table as a constraint: rounds of a short ICP (gate_iterations),
// each followed by turning the pose back onto its nearest resting face and putting it
// down (ICP alone turns a partly seen lying object back into the table); scored on those
// points: the best-scoring one. Empty when the model has no resting face or the points
// have no pose query.
std::optional<Hypothesis> RefitOnRestingFace(const SceneContext& ctx, const Hypothesis& h,
                                             const std::function<const PoseQuery*()>& query_of) {
  constexpr int kRounds = 3;
  std::vector<Eigen::Vector3d> faces = RestingFacesWithin(ctx, h, 180.0);
  if (faces.size() > static_cast<size_t>(ctx.options.rest_refit_faces)) {
    faces.resize(ctx.options.rest_refit_faces);
  }
  if (faces.empty()) return std::nullopt;
  const PoseQuery* query = query_of();
  if (query == nullptr) return std::nullopt;
  const Rigid3d canonical_from_cam =
      Rigid3d(query->cam_from_canonical, Eigen::Vector3d::Zero()).Inverse();
  const PointCloud& surface = ctx.scene_recogniser.ModelSurface(
      h.recognition.suggestions[0].model, ctx.options.model_leaf);
  const int iterations = ctx.options.recognition.pose.gate_iterations;
  std::optional<Hypothesis> best;
  for (const Eigen::Vector3d& face : faces) {
    std::optional<Hypothesis> rested = TurnedOntoFace(ctx, h, face);
    for (int round = 0; rested && round < kRounds; ++round) {
      RefineOnCluster(ctx, *query, surface,
                      canonical_from_cam * rested->recognition.suggestions[0].cam_from_model,
                      &*rested, iterations);
      const std::vector<Eigen::Vector3d> nearest = RestingFacesWithin(ctx, *rested, 90.0);
      rested = nearest.empty() ? std::nullopt : TurnedOntoFace(ctx, *rested, nearest.front());
    }
    if (!rested) continue;
    ScoreOnCluster(ctx, *query,
                   canonical_from_cam * rested->recognition.suggestions[0].cam_from_model,
                   &*rested);
    if (!best || rested->recognition.suggestions[0].score >
                     best->recognition.suggestions[0].score) {
      best = std::move(rested);
    }
  }
  return best;
}

// From `recognition` (RecogniseSideBySide) of points of `cluster`, adds up to
// hypotheses_per_cluster hypotheses (each posed suggestion scoring at least
// min_hypothesis_score, put down on the table, and its flipped twin) to the pool; with
// `query_of` (the pose query of the recognised points), a suggestion snapped by at least
// rest_refit_from also adds its refit on a resting face (RefitOnRestingFace).
void AddClusterHypotheses(const SceneContext& ctx, int cluster,
                          const RecognitionResult& recognition, HypothesisPool* pool,
                          const std::function<const PoseQuery*()>& query_of = {}) {
  const SceneRecognitionOptions& options = ctx.options;
  if (pool->cluster_results[cluster].empty()) pool->cluster_results[cluster] = recognition;
  const bool on_table = options.snap_to_plane && ctx.plane.found;
  int taken = 0;
  for (size_t s = 0; s < recognition.suggestions.size() && taken < options.hypotheses_per_cluster;
       ++s) {
    const Suggestion& suggestion = recognition.suggestions[s];
    if (!suggestion.posed || suggestion.score < options.min_hypothesis_score) {
      spdlog::debug("cluster {}: suggestion {} ({}) dropped: {}", cluster, s,
                    ctx.database.model(suggestion.model).name,
                    suggestion.posed ? fmt::format("score {:.3f} < {:.3f}", suggestion.score,
                                                   options.min_hypothesis_score)
                                     : std::string("not posed"));
      continue;
    }
    Hypothesis h;
    h.cluster = cluster;
    h.recognition = recognition;
    std::swap(h.recognition.suggestions[0], h.recognition.suggestions[s]);
    if (s != 0) {
      h.recognition.recognised = suggestion.score >= options.recognition.assembly.min_score;
    }
    // Where the recogniser put it, for a class of several models (see keep_unsnapped_from).
    std::optional<Hypothesis> unsnapped;
    if (on_table && options.keep_unsnapped_from > 0 &&
        ModelsOfClass(ctx.database, suggestion.class_index).size() >= 2) {
      unsnapped = h;
    }
    if (on_table && !PutOnTable(ctx, &h)) continue;
    if (on_table && query_of && options.rest_refit_from > 0 && !h.rested &&
        std::abs(h.snap) >= options.rest_refit_from &&
        ClassProbability(recognition, suggestion.class_index) >=
            options.rest_refit_min_class_probability) {
      std::optional<Hypothesis> refit = RefitOnRestingFace(ctx, h, query_of);
      if (refit && refit->recognition.suggestions[0].score >= options.rest_refit_min_score) {
        spdlog::debug("cluster {}: {} snapped {:.1f} mm, refit on a resting face: score {:.3f}, "
                      "snapped {:.1f} mm",
                      cluster, suggestion.model_name, 1e3 * h.snap,
                      refit->recognition.suggestions[0].score, 1e3 * refit->snap);
        pool->hypotheses.push_back(std::move(*refit));
      }
    }
    if (unsnapped && !h.rested && std::abs(h.snap) >= options.keep_unsnapped_from) {
      unsnapped->lift = -h.snap;
      pool->hypotheses.push_back(std::move(*unsnapped));
    }
    if (on_table && options.flip_hypotheses) {
      std::optional<Hypothesis> flipped = FlippedHypothesis(ctx, h);
      if (flipped) pool->hypotheses.push_back(std::move(*flipped));
    }
    pool->hypotheses.push_back(std::move(h));
    ++taken;
  }
}

// The cluster's points as the recogniser's pose stages see them (pre-processed with the
// database's options, canonical frame, projective grid); null when too few points
// survive. Built once per cluster (twins and siblings share it). PoseQueryOfPoints: the same
// for any points (nullopt when too few survive).
std::optional<PoseQuery> PoseQueryOfPoints(const SceneContext& ctx, const PointCloud& points) {
  try {
    const PreprocessedCloud preprocessed = Preprocess(points, ctx.database.options().preprocess);
    return PoseQueryOf(ctx.database, preprocessed, ctx.options.recognition.pose);
  } catch (const Error&) {
    return std::nullopt;
  }
}

const PoseQuery* ClusterPoseQuery(const SceneContext& ctx, int cluster, HypothesisPool* pool) {
  std::optional<PoseQuery>& query = pool->pose_queries[cluster];
  if (!pool->pose_query_built[cluster]) {
    pool->pose_query_built[cluster] = 1;
    query = PoseQueryOfPoints(ctx, ctx.clusters[cluster].cloud);
  }
  return query ? &*query : nullptr;
}

constexpr size_t kTwinIcpPoints = 1500;

// `surface` (model frame) ICP-refined on the cluster's pose `query` from
// `canonical_from_model` (the query's canonical frame): an even subsample of
// kTwinIcpPoints of its points fixes the pose (the scene verification then measures the
// fit on all of them). Sets `h`'s front suggestion's pose (camera frame) and ICP figures.
IcpResult RefineOnCluster(const SceneContext& ctx, const PoseQuery& query,
                        const PointCloud& surface, const Rigid3d& canonical_from_model,
                        Hypothesis* h, int iterations) {
  std::vector<Eigen::Vector3f> points, normals;
  const size_t stride = std::max<size_t>(1, surface.size() / kTwinIcpPoints);
  for (size_t i = 0; i < surface.size(); i += stride) {
    points.push_back(surface.points[i]);
    normals.push_back(surface.normals[i]);
  }
  const IcpResult icp =
      RefinePose(points, normals, query, canonical_from_model, ctx.options.recognition.pose,
                 iterations);
  const Rigid3d cam_from_canonical(query.cam_from_canonical, Eigen::Vector3d::Zero());
  Suggestion& front = h->recognition.suggestions[0];
  front.cam_from_model = cam_from_canonical * icp.canonical_from_model;
  front.icp_iterations = icp.iterations;
  front.icp_rms = icp.rms;
  h->snap = 0.0;
  return icp;
}

// Scores `h`'s front suggestion (its model at `canonical_from_model` on the cluster's pose
// `query`) as the recogniser scores a pose: against the model's database view nearest that
// pose, which becomes the suggestion's view.
void ScoreOnCluster(const SceneContext& ctx, const PoseQuery& query,
                    const Rigid3d& canonical_from_model, Hypothesis* h) {
  const Database& db = ctx.database;
  Suggestion& front = h->recognition.suggestions[0];
  front.view = NearestModelView(db, front.model, canonical_from_model);
  front.viewpoint = db.view(front.view).viewpoint;
  const PointCloud view_cloud = db.ViewCloud(front.view);
  front.alignment = ScoreAlignment(view_cloud.points, view_cloud.normals,
                                   db.view(front.view).cloud_spacing, query, canonical_from_model,
                                   ctx.options.recognition.pose);
  front.score = front.alignment.score;
}

// Twins of a cluster nothing explained: each of its first hypotheses turned half a turn
// about each principal axis of its model (through the model's centre) — the poses a
// view-based search confuses most (a drill on its side seen from its other side, a box
// end for end) — ICP-refined on the cluster's points and put down on the table. Adds
// them to the pool; false when it added none.
bool AddTwinHypotheses(const SceneContext& ctx, int cluster,
                       const std::vector<int>& sources, HypothesisPool* pool) {
  if (sources.empty()) return false;
  const Stopwatch watch;
  const PoseQuery* query = ClusterPoseQuery(ctx, cluster, pool);
  if (query == nullptr) return false;
  const Rigid3d canonical_from_cam =
      Rigid3d(query->cam_from_canonical, Eigen::Vector3d::Zero()).Inverse();
  const bool on_table = ctx.options.snap_to_plane && ctx.plane.found;
  bool added = false;
  for (const int source : sources) {
    const Hypothesis h = pool->hypotheses[source];  // a copy: the pool grows below
    const Suggestion& s = h.recognition.suggestions[0];
    const PointCloud& surface = ctx.scene_recogniser.ModelSurface(s.model, ctx.options.model_leaf);
    const Eigen::Vector3d centre = ctx.database.model(s.model).center;
    if (surface.empty()) continue;
    Eigen::Vector3d surface_centroid, variances;
    Eigen::Matrix3d axes;  // the model's principal axes, largest spread first
    internal::PrincipalAxes(surface.points, &surface_centroid, &axes, &variances);
    for (int k = 0; k < 3; ++k) {
      const Eigen::Matrix3d turn = Eigen::AngleAxisd(M_PI, axes.col(k)).toRotationMatrix();
      const Rigid3d model_turn(turn, centre - turn * centre);
      Hypothesis twin = h;
      twin.twin = true;
      twin.flipped = false;
      RefineOnCluster(ctx, *query, surface, canonical_from_cam * s.cam_from_model * model_turn,
                      &twin);
      if (on_table && !PutOnTable(ctx, &twin)) continue;
      pool->hypotheses.push_back(std::move(twin));
      added = true;
    }
  }
  pool->recognise_ms += watch.WallMs();
  return added;
}

// Pairs of labels (a < b) some of whose thinned points lie within `distance` of each
// other (a hash grid of cells `distance` wide: each point meets the points of its 27
// cells). `label` per thinned point, in [0, num_labels) or −1 (left out).
std::vector<std::pair<int, int>> NeighbouringLabels(const ThinnedScene& scene,
                                                    const std::vector<int>& label, int num_labels,
                                                    double distance) {
  const float inv_cell = static_cast<float>(1.0 / distance);
  const float distance2 = static_cast<float>(distance * distance);
  // Each cell's points and the range of their labels: a pair of cells is searched only
  // when the neighbour holds a label above the cell's least (most cells lie inside one
  // cluster and are skipped whole).
  struct Cell {
    Eigen::Matrix<int64_t, 3, 1> coords;
    std::vector<int> points;
    int min_label = std::numeric_limits<int>::max();
    int max_label = -1;
  };
  std::unordered_map<uint64_t, Cell> cells;
  for (size_t j = 0; j < scene.points.size(); ++j) {
    const int l = label[j];
    if (l < 0) continue;
    const Eigen::Matrix<int64_t, 3, 1> coords = VoxelCoords(scene.points.points[j], inv_cell);
    Cell& cell = cells[PackVoxel(coords)];
    cell.coords = coords;
    cell.points.push_back(static_cast<int>(j));
    cell.min_label = std::min(cell.min_label, l);
    cell.max_label = std::max(cell.max_label, l);
  }
  std::vector<uint8_t> near(static_cast<size_t>(num_labels) * num_labels, 0);
  for (const auto& entry : cells) {
    const Cell& cell = entry.second;
    for (int dx = -1; dx <= 1; ++dx) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dz = -1; dz <= 1; ++dz) {
          const Eigen::Matrix<int64_t, 3, 1> offset(dx, dy, dz);
          const auto it = cells.find(PackVoxel(cell.coords + offset));
          if (it == cells.end() || it->second.max_label <= cell.min_label) continue;
          const Cell& other = it->second;
          for (const int j : cell.points) {
            const int a = label[j];
            if (other.max_label <= a) continue;
            const Eigen::Vector3f& p = scene.points.points[j];
            for (const int k : other.points) {
              const int b = label[k];
              if (b <= a || near[a * num_labels + b]) continue;
              if ((scene.points.points[k] - p).squaredNorm() <= distance2) {
                near[a * num_labels + b] = 1;
              }
            }
          }
        }
      }
    }
  }
  std::vector<std::pair<int, int>> pairs;
  for (int a = 0; a < num_labels; ++a) {
    for (int b = a + 1; b < num_labels; ++b) {
      if (near[a * num_labels + b]) pairs.emplace_back(a, b);
    }
  }
  return pairs;
}

// Where the camera saw the scene: per cell of the normalised image plane (x/z, y/z; cells
// `cell` wide) the least depth of the cloud's points in it (∞ where it saw nothing: no
// decoded pixel, a shadow or a part too thin to scan).
class SightGrid {
 public:
  SightGrid(const PointCloud& cloud, float cell) : inv_cell_(1.0f / cell) {
    float u_min = std::numeric_limits<float>::max(), v_min = u_min, u_max = -u_min, v_max = -u_min;
    for (const Eigen::Vector3f& p : cloud.points) {
      if (!(p.z() > 0.0f)) continue;
      const float u = p.x() / p.z(), v = p.y() / p.z();
      u_min = std::min(u_min, u), u_max = std::max(u_max, u);
      v_min = std::min(v_min, v), v_max = std::max(v_max, v);
    }
    if (!(u_max >= u_min) || !(v_max >= v_min)) return;
    // At most kMaxCells cells (coarser cells for a very wide cloud).
    constexpr int64_t kMaxCells = 1 << 22;
    while ((static_cast<int64_t>((u_max - u_min) * inv_cell_) + 1) *
               (static_cast<int64_t>((v_max - v_min) * inv_cell_) + 1) >
           kMaxCells) {
      inv_cell_ *= 0.5f;
    }
    u0_ = u_min, v0_ = v_min;
    width_ = static_cast<int>((u_max - u_min) * inv_cell_) + 1;
    height_ = static_cast<int>((v_max - v_min) * inv_cell_) + 1;
    depth_.assign(static_cast<size_t>(width_) * height_, std::numeric_limits<float>::infinity());
    for (const Eigen::Vector3f& p : cloud.points) {
      const int k = CellOf(p);
      if (k >= 0) depth_[k] = std::min(depth_[k], p.z());
    }
  }
  // The least depth seen in the cell `point` projects to (∞: nothing seen there or outside).
  float SeenDepth(const Eigen::Vector3f& point) const {
    const int k = CellOf(point);
    return k < 0 ? std::numeric_limits<float>::infinity() : depth_[k];
  }

 private:
  int CellOf(const Eigen::Vector3f& p) const {
    if (!(p.z() > 0.0f) || width_ == 0) return -1;
    const float x = (p.x() / p.z() - u0_) * inv_cell_, y = (p.y() / p.z() - v0_) * inv_cell_;
    if (!(x >= 0.0f && y >= 0.0f && x < width_ && y < height_)) return -1;
    return static_cast<int>(y) * width_ + static_cast<int>(x);
  }
  float inv_cell_;
  float u0_ = 0.0f, v0_ = 0.0f;
  int width_ = 0, height_ = 0;
  std::vector<float> depth_;
};

// Segments across a gap that UnseenGapLabels looks along at most.
constexpr int kGapSegments = 6;

// Pairs of labels (a < b, as NeighbouringLabels; a a cluster, below num_clusters) whose
// thinned points come within join_gap of each other but not within join_distance, that one
// object could span (no two of their points farther apart than max_scale × the largest
// model's diameter), and across whose gap the camera did not see: along the segment
// between their nearest points (on a grid of 3 scene leaves; or along one of the next
// shortest segments, within a grid cell of its length) at most join_max_seen of the
// samples have the cloud's nearest point in their line of sight more than a scene leaf
// behind them — samples whose line of sight meets a point of the two parts themselves not
// counted, and fewer than three others counting as unseen. Two objects apart on the table
// show the table through the gap; the parts of one object that a shadow or a part too thin
// to scan (a wine glass's stem, a bottle's shoulder at a grazing angle) cut apart show
// nothing there, or the object itself (a lying wine glass: the line between its bowl and
// its foot passes over its stem).
std::vector<std::pair<int, int>> UnseenGapLabels(const SceneContext& ctx,
                                                 const std::vector<int>& label,
                                                 int num_clusters, int num_labels) {
  const SceneRecognitionOptions& options = ctx.options;
  const ThinnedScene& scene = ctx.scene;
  if (options.join_gap <= options.join_distance || num_labels < 2) return {};
  // Each label's points on a coarse grid (the first per cell) and bounding box.
  const float coarse = static_cast<float>(3.0 * options.scene_leaf);
  std::vector<std::vector<Eigen::Vector3f>> sample(num_labels);
  std::vector<Eigen::AlignedBox3f> box(num_labels);
  std::unordered_map<uint64_t, uint8_t> taken;
  for (size_t j = 0; j < scene.points.size(); ++j) {
    const int l = label[j];
    if (l < 0) continue;
    const Eigen::Vector3f& p = scene.points.points[j];
    box[l].extend(p);
    const uint64_t key = VoxelKeyOf(p, 1.0f / coarse) * 1000003u + static_cast<uint64_t>(l);
    if (taken.emplace(key, 0).second) sample[l].push_back(p);
  }
  const float gap2 = static_cast<float>(options.join_gap * options.join_gap);
  const float near2 = static_cast<float>(options.join_distance * options.join_distance);
  const double reach = std::max(1.0, options.max_scale) * ctx.max_diameter;
  std::unique_ptr<SightGrid> sight;
  std::vector<std::pair<int, int>> pairs;
  // `a` a cluster (two accepted objects have nothing unexplained to join).
  for (int a = 0; a < std::min(num_clusters, num_labels); ++a) {
    if (sample[a].empty()) continue;
    for (int b = a + 1; b < num_labels; ++b) {
      if (sample[b].empty()) continue;
      if (box[a].exteriorDistance(box[b]) > options.join_gap) continue;
      // The longest side of their joint box is a lower bound of their joint extent.
      if (box[a].merged(box[b]).sizes().maxCoeff() > reach) continue;
      // The pairs of their samples nearest each other: the nearest, and the next ones within
      // a coarse cell of its length (kGapSegments at most, each endpoint once).
      struct Segment {
        float d2;
        int p, q;
      };
      float best = std::numeric_limits<float>::max();
      for (const Eigen::Vector3f& p : sample[a]) {
        for (const Eigen::Vector3f& q : sample[b]) best = std::min(best, (p - q).squaredNorm());
      }
      // Nearer than join_distance: NeighbouringLabels pairs them (the coarse sample may
      // miss the nearest points by up to a cell: a pair that near is left to it).
      if (best > gap2 || best <= near2) continue;
      // Both within one model's reach: the largest distance between their points.
      std::vector<Eigen::Vector3f> both = sample[a];
      both.insert(both.end(), sample[b].begin(), sample[b].end());
      float extent2 = 0.0f;
      for (size_t k = 0; k < both.size(); ++k) {
        for (size_t m = k + 1; m < both.size(); ++m) {
          extent2 = std::max(extent2, (both[k] - both[m]).squaredNorm());
        }
      }
      if (std::sqrt(extent2) > reach) continue;
      if (!sight) {
        double depth = 0.0;
        for (const Eigen::Vector3f& p : scene.points.points) depth += p.z();
        depth /= static_cast<double>(scene.points.size());
        sight = std::make_unique<SightGrid>(
            ctx.cloud, static_cast<float>(0.5 * options.scene_leaf / std::max(depth, 1e-3)));
      }
      // A sample whose line of sight meets a point of the pair itself (within a coarse
      // cell of their samples) tells nothing: the camera sees a part of the same object
      // there (a lying wine glass's stem below the line between its bowl and its foot).
      const auto of_the_pair = [&](const Eigen::Vector3f& point) {
        for (const std::vector<Eigen::Vector3f>* part : {&sample[a], &sample[b]}) {
          for (const Eigen::Vector3f& q : *part) {
            if ((q - point).squaredNorm() < coarse * coarse) return true;
          }
        }
        return false;
      };
      // The samples of the segment pa → pb that tell anything, and those of them behind
      // which the camera saw the scene (more than a scene leaf farther).
      const auto look_across = [&](const Eigen::Vector3f& pa, const Eigen::Vector3f& pb,
                                   int* samples, int* seen) {
        const int steps = static_cast<int>((pb - pa).norm() / options.scene_leaf);
        *samples = *seen = 0;
        for (int k = 1; k < steps; ++k) {
          const float t = static_cast<float>(k) / steps;
          const Eigen::Vector3f s = pa + t * (pb - pa);
          const float seen_depth = sight->SeenDepth(s);  // ∞: nothing seen there
          if (std::isfinite(seen_depth) && s.z() > 0.0f &&
              of_the_pair(s * (seen_depth / s.z()))) {
            continue;
          }
          ++*samples;
          *seen += std::isfinite(seen_depth) &&
                   seen_depth > s.z() + static_cast<float>(options.scene_leaf);
        }
      };
      // Fewer than kMinGapSamples samples that tell anything: nothing to judge the gap by
      // (a lying wine glass whose bowl hides most of the line to its foot), so the two
      // are tried joined — the scene verification judges what that explains.
      constexpr int kMinGapSamples = 3;
      const auto unseen_gap = [&](int samples, int seen) {
        return samples < kMinGapSamples || seen <= options.join_max_seen * samples;
      };
      // The gap is unseen when the nearest points' segment is, or one of the next shortest
      // shows no sample seen through: the nearest points may lie beside where the parts
      // meet (a lying wine glass's stem ends in a shadow short of its bowl, whose nearest
      // point is off to the side, over the table). Stricter for the others, looked at only
      // because the first failed: a clutter stone whose shadow falls between it and the
      // object beside it shows one sample of five seen through along one of them.
      const float within = std::sqrt(best) + coarse;
      std::vector<Segment> near_pairs;
      for (size_t i = 0; i < sample[a].size(); ++i) {
        for (size_t j = 0; j < sample[b].size(); ++j) {
          const float d2 = (sample[a][i] - sample[b][j]).squaredNorm();
          if (d2 <= within * within) {
            near_pairs.push_back({d2, static_cast<int>(i), static_cast<int>(j)});
          }
        }
      }
      // Ties broken by sample order: the first is the nearest pair in the samples' order.
      std::sort(near_pairs.begin(), near_pairs.end(), [](const Segment& x, const Segment& y) {
        return std::tie(x.d2, x.p, x.q) < std::tie(y.d2, y.p, y.q);
      });
      std::vector<uint8_t> used_a(sample[a].size(), 0), used_b(sample[b].size(), 0);
      int tried = 0, samples = 0, seen = 0;
      bool unseen = false;
      float length = std::sqrt(best);
      for (const Segment& segment : near_pairs) {
        if (tried == kGapSegments) break;
        if (used_a[segment.p] || used_b[segment.q]) continue;
        used_a[segment.p] = used_b[segment.q] = 1;
        int segment_samples = 0, segment_seen = 0;
        look_across(sample[a][segment.p], sample[b][segment.q], &segment_samples, &segment_seen);
        const bool first = tried++ == 0;
        unseen = first ? unseen_gap(segment_samples, segment_seen)
                       : segment_samples < kMinGapSamples || segment_seen == 0;
        if (first || unseen) {
          samples = segment_samples;
          seen = segment_seen;
          length = std::sqrt(segment.d2);
        }
        if (unseen) break;
      }
      spdlog::debug("labels {} and {}: {:.0f} mm apart, {} of {} samples of the gap seen "
                    "through{} ({} segment(s) looked across)",
                    a, b, 1e3 * length, seen, samples, unseen ? ": joined" : "", tried);
      if (unseen) pairs.emplace_back(a, b);
    }
  }
  return pairs;
}

// `source` (its first suggestion posed) turned about its model's axis of near symmetry
// `axis` in roll_steps equal steps (the turns other than none), each ICP-refined on
// `query`, scored on it and put down on the table: the turns that stay on it, in turn
// order (refined side by side on recognition.threads threads).
std::vector<Hypothesis> RolledTurns(const SceneContext& ctx, const Hypothesis& source,
                                    const NearSymmetryAxis& axis, const PoseQuery& query) {
  const SceneRecognitionOptions& options = ctx.options;
  const bool on_table = options.snap_to_plane && ctx.plane.found;
  const Suggestion& s = source.recognition.suggestions[0];
  const Rigid3d canonical_from_cam =
      Rigid3d(query.cam_from_canonical, Eigen::Vector3d::Zero()).Inverse();
  const PointCloud& surface = ctx.scene_recogniser.ModelSurface(s.model, options.model_leaf);
  std::vector<std::optional<Hypothesis>> turned(std::max(0, options.roll_steps - 1));
  RunJobs(options.recognition.threads, turned.size(), [&](size_t j) {
    const int k = static_cast<int>(j) + 1;
    const Eigen::Matrix3d turn =
        Eigen::AngleAxisd(2.0 * M_PI * k / options.roll_steps, axis.direction).toRotationMatrix();
    const Rigid3d model_turn(turn, axis.point - turn * axis.point);
    Hypothesis rolled = source;
    rolled.rolled = true;
    const Rigid3d canonical_from_model =
        RefineOnCluster(ctx, query, surface, canonical_from_cam * s.cam_from_model * model_turn,
                        &rolled)
            .canonical_from_model;
    ScoreOnCluster(ctx, query, canonical_from_model, &rolled);
    if (on_table && !PutOnTable(ctx, &rolled)) return;
    turned[j] = std::move(rolled);
  });
  std::vector<Hypothesis> out;
  for (size_t j = 0; j < turned.size(); ++j) {
    if (!turned[j]) continue;
    spdlog::debug("cluster {}: {} turned {}° about its axis, score {:.3f}", source.cluster,
                  s.model_name, 360 * static_cast<int>(j + 1) / options.roll_steps,
                  turned[j]->recognition.suggestions[0].score);
    out.push_back(std::move(*turned[j]));
  }
  return out;
}

// The axis about which the model of `h`'s first suggestion is turned (roll_steps > 1 and
// at least roll_min_asymmetry of its surface moves), or null.
const NearSymmetryAxis* RollAxis(const SceneContext& ctx, const Hypothesis& h) {
  if (ctx.options.roll_steps <= 1) return nullptr;
  const NearSymmetryAxis& axis = ctx.scene_recogniser.SymmetryAxis(
      h.recognition.suggestions[0].model, ctx.options.model_leaf);
  if (!axis.found || axis.asymmetric_fraction < ctx.options.roll_min_asymmetry) return nullptr;
  return &axis;
}

// The best posed suggestion of each class `recognition` (of `cluster`'s points, or of them
// joined with a neighbour's) gives at least roll_min_class_probability, turned about its
// model's axis of near symmetry (SceneRecognitionOptions::roll_steps) — in the pose the
// recogniser found, before the plane prior moved it —, each turn ICP-refined on the pose
// query of the same points (`query_of`, called when first needed; null: nothing to refine
// on) and put down on the table; classes in `skip` are left out. True when that added
// hypotheses.
bool AddRolledOf(const SceneContext& ctx, const RecognitionResult& recognition, int cluster,
                 const std::function<const PoseQuery*()>& query_of, HypothesisPool* pool,
                 const std::set<int>& skip = {}) {
  bool added = false;
  for (const ClassScore& class_score : recognition.classes) {
    if (class_score.probability < ctx.options.roll_min_class_probability ||
        skip.count(class_score.class_index)) {
      continue;
    }
    const std::optional<Hypothesis> source =
        ClassSource(recognition, cluster, class_score.class_index);
    if (!source) continue;
    const NearSymmetryAxis* axis = RollAxis(ctx, *source);
    if (axis == nullptr) continue;
    const PoseQuery* query = query_of();
    if (query == nullptr) return added;
    for (Hypothesis& turned : RolledTurns(ctx, *source, *axis, *query)) {
      pool->hypotheses.push_back(std::move(turned));
      added = true;
    }
  }
  return added;
}

bool AddSiblingsOf(const SceneContext& ctx, const Hypothesis& h,
                   const std::vector<int>& class_models, const PointCloud& points,
                   const std::function<const PoseQuery*()>& pose_query, HypothesisPool* pool);
bool AddScaledHypothesis(const SceneContext& ctx, const Hypothesis& h, size_t class_models,
                         const PointCloud& cluster,
                         const std::function<const PoseQuery*()>& pose_query,
                         HypothesisPool* pool);
std::pair<double, double> RobustRange(std::vector<double> values);
void ScaleSurface(const PointCloud& surface, const Eigen::Vector3d& scale,
                  const Eigen::Vector3d& centre, PointCloud* scaled);

// The pose query of `points` (a part of a cluster, or two joined), built when first asked
// for (the looks that need it may not be taken); Getter() for the looks' `query_of`.
class LazyPoseQuery {
 public:
  LazyPoseQuery(const SceneContext& ctx, const PointCloud& points) : ctx_(ctx), points_(points) {}
  const PoseQuery* Get() {
    if (!built_) query_ = PoseQueryOfPoints(ctx_, points_), built_ = true;
    return query_ ? &*query_ : nullptr;
  }
  std::function<const PoseQuery*()> Getter() {
    return [this] { return Get(); };
  }

 private:
  const SceneContext& ctx_;
  const PointCloud& points_;
  std::optional<PoseQuery> query_;
  bool built_ = false;
};

// `h` stood upright (SceneRecognitionOptions::upright_max_tilt_deg): its model's axis of
// near symmetry (`axis`) turned onto the table normal (or its opposite, whichever is
// nearer), moved along the table onto the standing axis through `standing` (a point on the
// table) and put down on the table.
std::optional<Hypothesis> UprightHypothesis(const SceneContext& ctx, const Hypothesis& h,
                                            const NearSymmetryAxis& axis,
                                            const Eigen::Vector3d& standing) {
  const Suggestion& s = h.recognition.suggestions[0];
  const Eigen::Vector3d n = ctx.plane.normal.cast<double>();
  const Eigen::Vector3d direction = s.cam_from_model.rotation * axis.direction;
  const double cosine = direction.dot(n);
  Hypothesis upright = h;
  upright.flipped = upright.twin = upright.rested = upright.sibling = upright.rolled = false;
  upright.upright = true;
  Suggestion& f = upright.recognition.suggestions[0];
  const Eigen::Vector3d axis_point = s.cam_from_model * axis.point;
  f.cam_from_model.rotation =
      Eigen::Quaterniond::FromTwoVectors(direction, cosine > 0 ? n : -n).toRotationMatrix() *
      s.cam_from_model.rotation;
  const Eigen::Vector3d shift = standing - axis_point;
  f.cam_from_model.translation =
      axis_point - f.cam_from_model.rotation * axis.point + shift - n * n.dot(shift);
  if (!PutDownOnTable(ctx, SurfaceOf(ctx, upright), std::numeric_limits<double>::infinity(),
                      &upright)) {
    return std::nullopt;
  }
  return upright;
}

// The upright looks' scaled models (SceneRecognitionOptions::upright_max_tilt_deg): the
// models of the class of `upright` (its source stood on the standing axis through `foot`,
// a point on the table) whose axis of near symmetry is the model axis `k` (the class
// shares one frame), in the pose of `upright`, each scaled along that axis to the points'
// height above the table and across it to their radii about the standing axis (the median
// ratio over kProfileBins height bins of the 90th percentile radii, where both have
// points), its axis on the standing axis and put down on the table — no ICP: the axis and
// the table fix the pose of a standing body of revolution. The sibling_hypotheses + 1
// whose scaled radius profiles fit the points' best are added. True when that added
// hypotheses.
constexpr int kProfileBins = 8;

bool AddUprightScaled(const SceneContext& ctx, const Hypothesis& upright, int k,
                      const std::vector<int>& class_models, const PointCloud& points,
                      const Eigen::Vector3d& foot, HypothesisPool* pool) {
  const SceneRecognitionOptions& options = ctx.options;
  if (!(options.max_scale > 1.0) || class_models.size() < 2 || points.size() < 50) return false;
  const Eigen::Vector3d n = ctx.plane.normal.cast<double>();
  const Rigid3d& pose = upright.recognition.suggestions[0].cam_from_model;
  // The model's +k axis up (1) or down (−1).
  const double up = pose.rotation.col(k).dot(n) > 0 ? 1.0 : -1.0;
  // The points' heights above the table and radii about the standing axis; height bins.
  std::vector<double> heights(points.size()), radii(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d d = points.points[i].cast<double>() - foot;
    heights[i] = n.dot(d);
    radii[i] = (d - n * heights[i]).norm();
  }
  // Not a structured binding: the lambda below uses `low`, and C++17 cannot capture one
  // (clang refuses; the fuzzing build is clang's).
  const std::pair<double, double> range = RobustRange(heights);
  const double low = range.first, top = range.second;
  if (!(top > 0.01) || !(top > low)) return false;
  const double bin_height = (top - low) / kProfileBins;
  auto profile = [&](const std::vector<double>& h, const std::vector<double>& r) {
    std::array<std::vector<double>, kProfileBins> bins;
    for (size_t i = 0; i < h.size(); ++i) {
      const int b = static_cast<int>(std::floor((h[i] - low) / bin_height));
      if (b >= 0 && b < kProfileBins) bins[b].push_back(r[i]);
    }
    std::array<double, kProfileBins> out;
    for (int b = 0; b < kProfileBins; ++b) {
      out[b] = std::numeric_limits<double>::quiet_NaN();
      if (bins[b].size() < 5) continue;
      const size_t q = bins[b].size() * 9 / 10;
      std::nth_element(bins[b].begin(), bins[b].begin() + q, bins[b].end());
      out[b] = bins[b][q];
    }
    return out;
  };
  const std::array<double, kProfileBins> seen = profile(heights, radii);
  struct Candidate {
    double misfit;
    int model;
    Eigen::Vector3d scale;
  };
  std::vector<Candidate> candidates;
  for (const int m : class_models) {
    const NearSymmetryAxis& axis = ctx.scene_recogniser.SymmetryAxis(m, options.model_leaf);
    if (!axis.found || std::abs(axis.direction[k]) < 0.996) continue;
    const PointCloud& surface = ctx.scene_recogniser.ModelSurface(m, options.model_leaf);
    if (surface.size() < 50) continue;
    std::vector<double> h(surface.size()), r(surface.size());
    for (size_t i = 0; i < surface.size(); ++i) {
      Eigen::Vector3d d = surface.points[i].cast<double>() - axis.point;
      h[i] = up * d[k];
      d[k] = 0.0;
      r[i] = d.norm();
    }
    const auto [model_low, model_high] = RobustRange(h);
    if (!(model_high - model_low > 1e-3)) continue;
    const double vertical =
        std::clamp(top / (model_high - model_low), 1.0 / options.max_scale, options.max_scale);
    // The model's heights above the table once scaled and put down.
    for (double& x : h) x = vertical * (x - model_low);
    const std::array<double, kProfileBins> model = profile(h, r);
    std::vector<double> ratios;
    for (int b = 0; b < kProfileBins; ++b) {
      if (std::isfinite(seen[b]) && std::isfinite(model[b]) && model[b] > 1e-3) {
        ratios.push_back(seen[b] / model[b]);
      }
    }
    if (ratios.size() < 2) continue;
    std::nth_element(ratios.begin(), ratios.begin() + ratios.size() / 2, ratios.end());
    const double across =
        std::clamp(ratios[ratios.size() / 2], 1.0 / options.max_scale, options.max_scale);
    double misfit = 0.0, total = 0.0;
    for (int b = 0; b < kProfileBins; ++b) {
      if (std::isfinite(seen[b]) && std::isfinite(model[b])) {
        misfit += std::abs(seen[b] - across * model[b]);
        total += seen[b];
      }
    }
    Eigen::Vector3d scale = Eigen::Vector3d::Constant(across);
    scale[k] = vertical;
    candidates.push_back({misfit / std::max(total, 1e-6), m, scale});
  }
  std::sort(candidates.begin(), candidates.end(),
            [](const Candidate& a, const Candidate& b) { return a.misfit < b.misfit; });
  if (static_cast<int>(candidates.size()) > options.sibling_hypotheses + 1) {
    candidates.resize(options.sibling_hypotheses + 1);
  }
  bool added = false;
  for (const Candidate& c : candidates) {
    const ModelRecord& record = ctx.database.model(c.model);
    const NearSymmetryAxis& axis = ctx.scene_recogniser.SymmetryAxis(c.model, options.model_leaf);
    PointCloud scaled;
    ScaleSurface(ctx.scene_recogniser.ModelSurface(c.model, options.model_leaf), c.scale,
                 record.center, &scaled);
    Hypothesis out = upright;
    out.sibling = c.model != upright.recognition.suggestions[0].model;
    Suggestion& f = out.recognition.suggestions[0];
    f.model = c.model;
    f.model_name = record.name;
    // The scaled model's axis onto the standing axis, then down onto the table.
    const Eigen::Vector3d shift =
        foot - pose * (record.center + c.scale.cwiseProduct(axis.point - record.center));
    f.cam_from_model.translation = pose.translation + shift - n * n.dot(shift);
    if (!PutDownOnTable(ctx, scaled, std::numeric_limits<double>::infinity(), &out)) continue;
    pool->scaled_surfaces.push_back(std::move(scaled));
    out.surface = &pool->scaled_surfaces.back();
    out.scale = c.scale;
    spdlog::debug("cluster {}: {} stood upright scaled by ({:.2f}, {:.2f}, {:.2f}), profile "
                  "misfit {:.3f}", upright.cluster, record.name, c.scale.x(), c.scale.y(),
                  c.scale.z(), c.misfit);
    pool->hypotheses.push_back(std::move(out));
    added = true;
  }
  return added;
}

// The upright looks of `source` (SceneRecognitionOptions::upright_max_tilt_deg) on
// `points`, when its class has several database models (an instance's own views fit it)
// and its model's axis of near symmetry is a model axis posed within
// upright_max_tilt_deg of the table normal: the model stood upright on the standing axis
// of the points (StandingAxisPoint on their pose query, `query_of`) and the scaled models
// of AddUprightScaled. True when that added hypotheses.
bool AddUprightLooks(const SceneContext& ctx, const Hypothesis& source,
                     const std::vector<int>& class_models, const PointCloud& points,
                     const std::function<const PoseQuery*()>& query_of, HypothesisPool* pool) {
  const SceneRecognitionOptions& options = ctx.options;
  if (class_models.size() < 2) return false;  // an instance: its own views fit it
  const Suggestion& s = source.recognition.suggestions[0];
  const NearSymmetryAxis& axis = ctx.scene_recogniser.SymmetryAxis(s.model, options.model_leaf);
  int k = 0;
  if (!axis.found || axis.direction.cwiseAbs().maxCoeff(&k) < 0.996) return false;
  const Eigen::Vector3d n = ctx.plane.normal.cast<double>();
  if (std::abs(s.cam_from_model.rotation.col(k).dot(n)) <
      std::cos(options.upright_max_tilt_deg * M_PI / 180.0)) {
    return false;
  }
  const PoseQuery* query = query_of();
  if (query == nullptr) return false;
  const std::optional<Eigen::Vector3d> foot = StandingAxisPoint(
      query->points, query->normals, query->cam_from_canonical, n, ctx.plane.offset);
  if (!foot) return false;
  std::optional<Hypothesis> upright = UprightHypothesis(ctx, source, axis, *foot);
  if (!upright) return false;
  AddUprightScaled(ctx, *upright, k, class_models, points, *foot, pool);
  const Rigid3d canonical_from_cam =
      Rigid3d(query->cam_from_canonical, Eigen::Vector3d::Zero()).Inverse();
  ScoreOnCluster(ctx, *query, canonical_from_cam * upright->recognition.suggestions[0].cam_from_model,
                 &*upright);
  spdlog::debug("cluster {}: {} stood upright, score {:.3f}", source.cluster,
                upright->recognition.suggestions[0].model_name,
                upright->recognition.suggestions[0].score);
  pool->hypotheses.push_back(std::move(*upright));
  return true;
}

// The size looks (siblings and the scaled model) of the class `recognition` ranks first,
// on `points` (a cluster, a part of one, or two joined) attributed to `cluster`, refined on
// their pose query (`query_of`, called when first needed). True when that added
// hypotheses.
bool AddSizeLooksOn(const SceneContext& ctx, const RecognitionResult& recognition, int cluster,
                    const PointCloud& points, const std::function<const PoseQuery*()>& query_of,
                    HypothesisPool* pool) {
  if (ctx.options.sibling_hypotheses <= 0 && !(ctx.options.max_scale > 1.0)) return false;
  std::vector<int> class_models;
  const std::optional<Hypothesis> source =
      FirstClassSource(ctx, recognition, cluster, &class_models);
  if (!source) return false;
  bool added = AddSiblingsOf(ctx, *source, class_models, points, query_of, pool);
  added |= AddScaledHypothesis(ctx, *source, class_models.size(), points, query_of, pool);
  if (ctx.options.upright_max_tilt_deg > 0 && ctx.options.snap_to_plane && ctx.plane.found) {
    added |= AddUprightLooks(ctx, *source, class_models, points, query_of, pool);
  }
  return added;
}

// Each cluster nothing explains, recognised joined with what lies within join_distance of
// it: another such cluster, the points of an accepted hypothesis (an object whose part the
// shadow cut off — its pose, found without that part, may be wrong), or the unexplained
// remainder (at least remainder_fraction, `left`) of a cluster partly explained (an object
// touching another, whose other part the shadow cut off). The hypotheses go to the larger
// cluster. True when that added hypotheses.
bool AddJoinedHypotheses(const SceneContext& ctx, const std::vector<HypothesisEvidence>& evidence,
                         const std::vector<bool>& unexplained, const std::vector<double>& left,
                         HypothesisPool* pool) {
  const SceneRecognitionOptions& options = ctx.options;
  const ThinnedScene& scene = ctx.scene;
  const int num_clusters = static_cast<int>(ctx.clusters.size());
  if (options.join_distance <= 0 || num_clusters < 2) return false;
  // Labels: 0 … num_clusters − 1 the points of clusters nothing explains; num_clusters + k
  // the points the k-th accepted hypothesis explains (first come, first owned); then
  // num_clusters + accepted + r the unexplained points of the r-th partly explained
  // cluster with a remainder.
  std::vector<int> accepted;
  for (size_t h = 0; h < evidence.size(); ++h) {
    if (evidence[h].accepted) accepted.push_back(static_cast<int>(h));
  }
  std::vector<int> label(scene.points.size(), -1);
  for (size_t k = 0; k < accepted.size(); ++k) {
    for (const int j : evidence[accepted[k]].explained) {
      if (label[j] < 0) label[j] = num_clusters + static_cast<int>(k);
    }
  }
  const int first_remainder = num_clusters + static_cast<int>(accepted.size());
  std::vector<int> remainder_label(num_clusters, -1), remainder_cluster;
  for (int c = 0; c < num_clusters; ++c) {
    if (!options.join_remainders || unexplained[c] || !LargeRemainder(options, left[c])) {
      continue;
    }
    remainder_label[c] = first_remainder + static_cast<int>(remainder_cluster.size());
    remainder_cluster.push_back(c);
  }
  for (size_t j = 0; j < scene.points.size(); ++j) {
    const int c = scene.cluster_of[j];
    if (unexplained[c]) {
      label[j] = c;
    } else if (label[j] < 0 && remainder_label[c] >= 0) {
      label[j] = remainder_label[c];
    }
  }
  const int num_labels = first_remainder + static_cast<int>(remainder_cluster.size());
  // The raw points of a label: its cluster's, or those whose thinned point the object owns
  // or its remainder holds.
  auto points_of = [&](int l, PointCloud* out) -> int {
    if (l < num_clusters) {
      const PointCloud& c = ctx.clusters[l].cloud;
      out->points.insert(out->points.end(), c.points.begin(), c.points.end());
      return l;
    }
    const int c = l < first_remainder ? pool->hypotheses[accepted[l - num_clusters]].cluster
                                      : remainder_cluster[l - first_remainder];
    for (const int i : ctx.clusters[c].indices) {
      if (label[scene.thinned_of_input[i]] == l) out->points.push_back(ctx.cloud.points[i]);
    }
    return c;
  };
  std::vector<std::pair<int, int>> pairs =
      NeighbouringLabels(scene, label, num_labels, options.join_distance);
  for (const auto& pair : UnseenGapLabels(ctx, label, num_clusters, num_labels)) {
    pairs.push_back(pair);
  }
  // The pairs to join and their points; then their recognitions (side by side with several
  // threads); then each pair's hypotheses and looks, in pair order.
  struct Join {
    bool partner_is_cluster = false;
    int cluster_a = 0, cluster_b = 0, owner = 0;
    int object_class = -1;  // the accepted object's class (partner an object)
    PointCloud joined;
  };
  std::vector<Join> joins;
  for (const auto& [a, b] : pairs) {
    if (a >= num_clusters) continue;  // two objects: nothing unexplained to join
    // Partners: a cluster; num_clusters + an accepted hypothesis's index; a remainder's
    // cluster c as −1 − c.
    const int partner = b < num_clusters     ? b
                        : b < first_remainder ? num_clusters + accepted[b - num_clusters]
                                              : -1 - remainder_cluster[b - first_remainder];
    if (!pool->joined.emplace(a, partner).second) continue;  // joined in an earlier round
    Join join;
    join.partner_is_cluster = b < num_clusters || b >= first_remainder;
    if (!join.partner_is_cluster) {
      const Hypothesis& object = pool->hypotheses[accepted[b - num_clusters]];
      join.object_class = object.recognition.suggestions[0].class_index;
    }
    join.cluster_a = points_of(a, &join.joined);
    const size_t size_a = join.joined.size();
    join.cluster_b = points_of(b, &join.joined);
    join.owner = size_a >= join.joined.size() - size_a ? join.cluster_a : join.cluster_b;
    joins.push_back(std::move(join));
  }
  std::vector<const PointCloud*> clouds;
  for (const Join& join : joins) clouds.push_back(&join.joined);
  const std::vector<RecognitionResult> recognised = RecogniseSideBySide(ctx, clouds, pool);
  const std::vector<size_t> added = LooksSideBySide(
      ctx, joins.size(), pool, [&](const SceneContext& c, size_t k, HypothesisPool* looks) {
        const PointCloud& joined = joins[k].joined;
        const int owner = joins[k].owner;
        const RecognitionResult& recognition = recognised[k];
        LazyPoseQuery joined_query(c, joined);
        AddClusterHypotheses(c, owner, recognition, looks, joined_query.Getter());
        // A handle the shadow cut off the body: turned about the body's axis and refined on
        // both parts, the model can put it where it was seen.
        if (c.options.roll_steps > 1) {
          AddRolledOf(c, recognition, owner, joined_query.Getter(), looks);
        }
        // An unseen instance two unexplained clusters make up: the size looks of the class
        // ranked first, sized to the joined points (SceneRecognitionOptions::join_size_looks).
        // With an accepted object's points, when the joined points rank another class
        // first than the object's (object_join_size_looks).
        const bool new_class = !recognition.classes.empty() &&
                               recognition.classes.front().class_index != joins[k].object_class;
        if (c.options.join_size_looks &&
            (joins[k].partner_is_cluster || (c.options.object_join_size_looks && new_class))) {
          AddSizeLooksOn(c, recognition, owner, joined, joined_query.Getter(), looks);
        }
      });
  for (size_t k = 0; k < joins.size(); ++k) {
    spdlog::debug("{} {} and cluster {} joined ({} points): {} hypotheses",
                  joins[k].partner_is_cluster ? "cluster" : "the object of cluster",
                  joins[k].cluster_b, joins[k].cluster_a, joins[k].joined.size(), added[k]);
  }
  return std::any_of(added.begin(), added.end(), [](size_t n) { return n > 0; });
}

// Parts of clusters (convex segments, unexplained remainders), each recognised alone: the
// recognitions side by side with several threads, then in order each part's hypotheses
// and, with part_size_looks, its size looks. Returns how many hypotheses each part added.
std::vector<size_t> AddPartHypotheses(const SceneContext& ctx,
                                      const std::vector<std::pair<int, PointCloud>>& parts,
                                      HypothesisPool* pool) {
  std::vector<const PointCloud*> clouds;
  for (const auto& [cluster, part] : parts) clouds.push_back(&part);
  const std::vector<RecognitionResult> recognised = RecogniseSideBySide(ctx, clouds, pool);
  return LooksSideBySide(
      ctx, parts.size(), pool, [&](const SceneContext& c, size_t k, HypothesisPool* looks) {
        const auto& [cluster, part] = parts[k];
        LazyPoseQuery part_query(c, part);
        AddClusterHypotheses(c, cluster, recognised[k], looks, part_query.Getter());
        if (c.options.part_size_looks) {
          AddSizeLooksOn(c, recognised[k], cluster, part, part_query.Getter(), looks);
        }
      });
}

// Clusters `to_split` (each once) split along their concave seams: each of the
// split_segments largest segments (of at least min_cluster_points points, and not the
// whole cluster) is recognised alone and adds its hypotheses (in cluster and segment
// order). True when that added hypotheses.
bool AddSplitHypotheses(const SceneContext& ctx, const std::vector<bool>& to_split,
                        HypothesisPool* pool) {
  const SceneRecognitionOptions& options = ctx.options;
  if (options.split_segments <= 0) return false;
  std::vector<std::pair<int, PointCloud>> parts;  // (cluster, the segment's points)
  for (size_t c = 0; c < ctx.clusters.size(); ++c) {
    if (!to_split[c] || pool->split_tried[c]) continue;
    pool->split_tried[c] = 1;
    const PointCloud& points = ctx.clusters[c].cloud;
    const Stopwatch watch;
    const std::vector<std::vector<int>> segments = ConvexSegments(points, options.split);
    pool->recognise_ms += watch.WallMs();
    spdlog::debug("cluster {}: {} convex segments ({} points, largest {})", c, segments.size(),
                  points.size(), segments.empty() ? 0 : segments[0].size());
    if (segments.size() < 2) continue;
    const auto add_part = [&](const std::vector<int>& indices) {
      parts.emplace_back();
      parts.back().first = static_cast<int>(c);
      PointCloud& part = parts.back().second;
      part.points.reserve(indices.size());
      for (const int i : indices) part.points.push_back(points.points[i]);
    };
    uint32_t added_segments = 0;  // a bit each
    for (size_t k = 0; k < segments.size() && static_cast<int>(k) < options.split_segments; ++k) {
      const std::vector<int>& segment = segments[k];
      if (static_cast<int>(segment.size()) < options.segmentation.min_cluster_points) break;
      if (segment.size() > 0.9 * points.size()) continue;  // the cluster was tried whole
      add_part(segment);
      if (k < 32) added_segments |= 1u << k;
    }
    if (options.seam_split_fraction > 0.0 && segments.size() >= 3) {
      const int min_points =
          std::max(options.segmentation.min_cluster_points,
                   static_cast<int>(std::ceil(options.seam_split_fraction * points.size())));
      const SeamSplit seam =
          WeakestSeamSplit(points, segments, options.split.voxel_resolution, min_points);
      for (int side = 0; side < 2; ++side) {
        const uint32_t group = seam.segments[side];
        if (group == 0 || (__builtin_popcount(group) == 1 && (group & added_segments))) continue;
        add_part(seam.parts[side]);
      }
      if (seam.segments[0] != 0) {
        spdlog::debug("cluster {}: weakest seam ({} cell pairs) splits it {} + {} points", c,
                      seam.contact, seam.parts[0].size(), seam.parts[1].size());
      }
    }
  }
  bool added = false;
  for (const size_t count : AddPartHypotheses(ctx, parts, pool)) added |= count > 0;
  return added;
}

// Clusters the accepted hypotheses leave unexplained altogether get the twins of their
// best few hypotheses (SceneRecognitionOptions::twin_hypotheses, by model fit). True
// when that added hypotheses.
bool AddTwinsOfUnexplained(const SceneContext& ctx, const std::vector<HypothesisEvidence>& evidence,
                           const std::vector<bool>& unexplained, HypothesisPool* pool) {
  const int per_cluster = ctx.options.twin_hypotheses;
  if (per_cluster <= 0) return false;
  bool added = false;
  const size_t before = evidence.size();  // the verified hypotheses
  for (size_t c = 0; c < ctx.clusters.size(); ++c) {
    if (!unexplained[c] || pool->twins_tried[c]) continue;
    pool->twins_tried[c] = 1;
    std::vector<int> candidates;
    for (size_t h = 0; h < before; ++h) {
      const Hypothesis& hypothesis = pool->hypotheses[h];
      if (hypothesis.cluster != static_cast<int>(c)) continue;
      if (!hypothesis.flipped && !hypothesis.twin && !hypothesis.sibling) {
        candidates.push_back(static_cast<int>(h));
      }
    }
    if (candidates.empty()) continue;
    std::stable_sort(candidates.begin(), candidates.end(), [&evidence](int a, int b) {
      return evidence[a].model_fit > evidence[b].model_fit;
    });
    if (static_cast<int>(candidates.size()) > per_cluster) candidates.resize(per_cluster);
    added |= AddTwinHypotheses(ctx, static_cast<int>(c), candidates, pool);
  }
  return added;
}

// Size of points along the table: the height of the highest above the lowest (or above
// the plane: `from_plane`) and the extents along the two principal axes of their
// projection onto the plane, largest first.
Eigen::Vector3d SizeAlongTable(const std::vector<Eigen::Vector3f>& points,
                               const Eigen::Matrix3d& rotation, const TablePlane& plane,
                               bool from_plane) {
  const Eigen::Vector3d n = plane.normal.cast<double>();
  const Eigen::Vector3d u = n.unitOrthogonal(), v = n.cross(u);
  double low = std::numeric_limits<double>::max(), high = -low;
  std::vector<Eigen::Vector2d> flat;
  flat.reserve(points.size());
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const Eigen::Vector3f& p : points) {
    const Eigen::Vector3d q = rotation * p.cast<double>();
    const double h = n.dot(q);
    low = std::min(low, h);
    high = std::max(high, h);
    flat.emplace_back(u.dot(q), v.dot(q));
    mean += flat.back();
  }
  if (flat.empty()) return Eigen::Vector3d::Zero();
  mean /= static_cast<double>(flat.size());
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();
  for (const Eigen::Vector2d& f : flat) covariance += (f - mean) * (f - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> solver(covariance);
  const Eigen::Vector2d major = solver.eigenvectors().col(1), minor = solver.eigenvectors().col(0);
  double a0 = std::numeric_limits<double>::max(), a1 = -a0, b0 = a0, b1 = -a0;
  for (const Eigen::Vector2d& f : flat) {
    a0 = std::min(a0, major.dot(f));
    a1 = std::max(a1, major.dot(f));
    b0 = std::min(b0, minor.dot(f));
    b1 = std::max(b1, minor.dot(f));
  }
  const double height = from_plane ? high + plane.offset : high - low;
  return Eigen::Vector3d(height, a1 - a0, b1 - b0);
}

// Siblings of the hypothesis `h` (AddSizeHypotheses, and joins): the other models of its
// class (`class_models`, the class's database models) nearest `points` (its cluster's, or
// two parts joined) in size, in the pose of `h`, ICP-refined on those points' pose query
// (`pose_query`, called once), scored against them as the recogniser scores a pose, and
// put down on the table. Adds them to the pool; false when it added none.
bool AddSiblingsOf(const SceneContext& ctx, const Hypothesis& h,
                   const std::vector<int>& class_models, const PointCloud& points,
                   const std::function<const PoseQuery*()>& pose_query, HypothesisPool* pool) {
  if (ctx.options.sibling_hypotheses <= 0) return false;
  const Database& db = ctx.database;
  const Suggestion& s = h.recognition.suggestions[0];
  const Eigen::Vector3d cluster_size =
      SizeAlongTable(points.points, Eigen::Matrix3d::Identity(), ctx.plane, true);
  std::vector<std::pair<double, int>> by_size;
  for (const int m : class_models) {
    if (m == s.model) continue;
    const PointCloud& surface = ctx.scene_recogniser.ModelSurface(m, ctx.options.model_leaf);
    if (surface.empty()) continue;
    const Eigen::Vector3d size =
        SizeAlongTable(surface.points, s.cam_from_model.rotation, ctx.plane, false);
    by_size.emplace_back((size - cluster_size).cwiseAbs().sum(), m);
  }
  if (by_size.empty()) return false;
  std::sort(by_size.begin(), by_size.end());
  if (static_cast<int>(by_size.size()) > ctx.options.sibling_hypotheses) {
    by_size.resize(ctx.options.sibling_hypotheses);
  }
  const Stopwatch watch;
  const PoseQuery* query = pose_query();
  if (query == nullptr) return false;
  const Rigid3d canonical_from_cam =
      Rigid3d(query->cam_from_canonical, Eigen::Vector3d::Zero()).Inverse();
  const bool on_table = ctx.options.snap_to_plane && ctx.plane.found;
  bool added = false;
  for (const auto& [distance, m] : by_size) {
    const PointCloud& surface = ctx.scene_recogniser.ModelSurface(m, ctx.options.model_leaf);
    Hypothesis sibling = h;
    sibling.sibling = true;
    sibling.flipped = sibling.twin = sibling.rested = false;
    Suggestion& front = sibling.recognition.suggestions[0];
    const ModelRecord& model = db.model(m);
    front.model = m;
    front.model_name = model.name;
    const Rigid3d canonical_from_model =
        RefineOnCluster(ctx, *query, surface, canonical_from_cam * s.cam_from_model, &sibling)
            .canonical_from_model;
    ScoreOnCluster(ctx, *query, canonical_from_model, &sibling);
    if (on_table && !PutOnTable(ctx, &sibling)) continue;
    spdlog::debug("cluster {}: sibling {} of {} (size distance {:.3f} m), score {:.3f}",
                  h.cluster, model.name, s.model_name, distance, front.score);
    pool->hypotheses.push_back(std::move(sibling));
    added = true;
  }
  pool->recognise_ms += watch.WallMs();
  return added;
}

// Robust extent of `values` (the 2nd to the 98th percentile): its low and high ends.
std::pair<double, double> RobustRange(std::vector<double> values) {
  const size_t n = values.size();
  const size_t lo = n / 50, hi = n - 1 - n / 50;
  std::nth_element(values.begin(), values.begin() + lo, values.end());
  const double low = values[lo];
  std::nth_element(values.begin(), values.begin() + hi, values.end());
  return {low, values[hi]};
}

// The per-axis scale (model frame) of a model whose robust extents along its axes are
// `model_ranges` that matches the cluster's points seen at `cam_from_model` — the robust
// extent of the points along each model axis; along the axis nearest the table normal,
// when it is within 26° of it, their height above the table (`cluster_height`) —, each
// factor within [1/max_scale, max_scale]; and the shift (model frame, 0 along that axis)
// that centres the model on them. False when the extents are degenerate.
bool ScaleToCluster(const SceneContext& ctx,
                    const std::array<std::pair<double, double>, 3>& model_ranges,
                    double cluster_height, const PointCloud& cluster,
                    const Rigid3d& cam_from_model, const Eigen::Vector3d& centre,
                    Eigen::Vector3d* scale, Eigen::Vector3d* shift) {
  const double max_scale = ctx.options.max_scale;
  const Rigid3d model_from_cam = cam_from_model.Inverse();
  const Eigen::Vector3d up = cam_from_model.rotation.transpose() * ctx.plane.normal.cast<double>();
  int vertical = -1;
  up.cwiseAbs().maxCoeff(&vertical);
  const bool upright = std::abs(up[vertical]) > 0.9 && ctx.plane.found;
  for (int a = 0; a < 3; ++a) {
    std::vector<double> seen(cluster.size());
    for (size_t i = 0; i < cluster.size(); ++i) {
      seen[i] = (model_from_cam * cluster.points[i].cast<double>())[a];
    }
    const auto [seen_low, seen_high] = RobustRange(std::move(seen));
    const auto [model_low, model_high] = model_ranges[a];
    double extent = seen_high - seen_low;
    (*shift)[a] = 0.5 * (seen_low + seen_high) - centre[a];
    if (a == vertical && upright) {
      extent = cluster_height;  // from the table up
      (*shift)[a] = 0.0;  // the height: put down on the table
    }
    if (!(model_high - model_low > 1e-3) || !(extent > 0)) return false;
    (*scale)[a] = std::clamp(extent / (model_high - model_low), 1.0 / max_scale, max_scale);
  }
  return true;
}

// `surface` scaled by `scale` (per axis, about `centre`), normals transformed alike.
void ScaleSurface(const PointCloud& surface, const Eigen::Vector3d& scale,
                  const Eigen::Vector3d& centre, PointCloud* scaled) {
  scaled->points.clear();
  scaled->normals.clear();
  scaled->points.reserve(surface.size());
  scaled->normals.reserve(surface.size());
  const Eigen::Vector3f scale_f = scale.cast<float>(), centre_f = centre.cast<float>();
  const Eigen::Vector3f inverse_f = scale_f.cwiseInverse();
  for (size_t i = 0; i < surface.size(); ++i) {
    scaled->points.push_back(centre_f + scale_f.cwiseProduct(surface.points[i] - centre_f));
    scaled->normals.push_back(inverse_f.cwiseProduct(surface.normals[i]).normalized());
  }
}

constexpr int kScaleRounds = 3;

// The hypothesis `h` with its model scaled per axis (model frame, about the model's
// centre) to the cluster (ScaleToCluster), ICP-refined on the cluster; scale and pose
// estimated again from the refined pose, kScaleRounds times; then put down on the table.
// Added to the pool when some axis changed by 5% or more; false when nothing was added,
// and for a class of one database model (`class_models`: its number of models), an
// instance whose size is known.
bool AddScaledHypothesis(const SceneContext& ctx, const Hypothesis& h, size_t class_models,
                         const PointCloud& cluster,
                         const std::function<const PoseQuery*()>& pose_query,
                         HypothesisPool* pool) {
  if (!(ctx.options.max_scale > 1.0) || class_models < 2) return false;
  const Suggestion& s = h.recognition.suggestions[0];
  const PointCloud& surface = ctx.scene_recogniser.ModelSurface(s.model, ctx.options.model_leaf);
  if (surface.empty() || cluster.size() < 10) return false;
  // What the rounds below do not change: the model's extents, the cluster's height.
  std::array<std::pair<double, double>, 3> model_ranges;
  for (int a = 0; a < 3; ++a) {
    std::vector<double> model(surface.size());
    for (size_t i = 0; i < surface.size(); ++i) model[i] = surface.points[i][a];
    model_ranges[a] = RobustRange(std::move(model));
  }
  std::vector<double> heights(cluster.size());
  for (size_t i = 0; i < cluster.size(); ++i) heights[i] = ctx.plane.Height(cluster.points[i]);
  const double cluster_height = RobustRange(std::move(heights)).second;
  const PoseQuery* query = pose_query();
  if (query == nullptr) return false;
  const Rigid3d cam_from_canonical(query->cam_from_canonical, Eigen::Vector3d::Zero());
  const Eigen::Vector3d centre = ctx.database.model(s.model).center;
  Hypothesis out = h;
  out.flipped = out.twin = out.rested = out.sibling = false;
  Rigid3d pose = s.cam_from_model;
  Eigen::Vector3d scale = Eigen::Vector3d::Ones();
  PointCloud scaled;
  for (int round = 0; round < kScaleRounds; ++round) {
    Eigen::Vector3d shift = Eigen::Vector3d::Zero();
    if (!ScaleToCluster(ctx, model_ranges, cluster_height, cluster, pose, centre, &scale,
                        &shift)) {
      return false;
    }
    if (round == 0 && (scale.array() - 1.0).abs().maxCoeff() < 0.05) return false;
    ScaleSurface(surface, scale, centre, &scaled);
    pose.translation += pose.rotation * shift;
    RefineOnCluster(ctx, *query, scaled, cam_from_canonical.Inverse() * pose, &out);
    pose = out.recognition.suggestions[0].cam_from_model;
  }
  pool->scaled_surfaces.push_back(std::move(scaled));
  out.surface = &pool->scaled_surfaces.back();
  out.scale = scale;
  if (ctx.options.snap_to_plane && ctx.plane.found && !SnapToTable(ctx, &out)) return false;
  spdlog::debug("cluster {}: {} scaled by ({:.2f}, {:.2f}, {:.2f})", h.cluster, s.model_name,
                scale.x(), scale.y(), scale.z());
  pool->hypotheses.push_back(std::move(out));
  return true;
}

// Every cluster gets, once, the siblings (SceneRecognitionOptions::sibling_hypotheses) and
// the scaled model (max_scale) of its first recognition's best posed suggestion of the
// class it ranks first, when that class has at least the class-level probability — in
// the pose the recogniser found, before the plane prior moved it (a hypothesis of the
// wrong size does not rest on the table; turned onto a resting face it no longer fits
// either). Clusters already explained
// get them too: an unseen instance may pass the instance-level tests with a database
// instance of another size (a bowl 13 cm wide posed as one of 12 cm) that a sibling fits
// better. True when that added hypotheses.
bool AddSizeHypotheses(const SceneContext& ctx, HypothesisPool* pool) {
  if (pool->size_looks_taken) return false;
  pool->size_looks_taken = true;
  // Each cluster's looks read its points, its first recognition and its pose query (its
  // own slot of the pool, built on first use): side by side.
  size_t begin = pool->hypotheses.size();
  const std::vector<size_t> added = LooksSideBySide(
      ctx, ctx.clusters.size(), pool,
      [pool](const SceneContext& c, size_t k, HypothesisPool* looks) {
        const int cluster = static_cast<int>(k);
        AddSizeLooksOn(c, pool->cluster_results[k], cluster, c.clusters[k].cloud,
                       [&c, cluster, pool] { return ClusterPoseQuery(c, cluster, pool); },
                       looks);
      });
  for (const size_t n : added) {
    pool->size_looks_of.emplace_back(begin, begin + n);
    begin += n;
  }
  return std::any_of(added.begin(), added.end(), [](size_t n) { return n > 0; });
}

// What each cluster's accepted hypotheses are: their classes, and the best score on the
// cluster among them (0: none accepted).
struct AcceptedOnClusters {
  std::vector<std::set<int>> classes;
  std::vector<double> best_score;
};
AcceptedOnClusters AcceptedOn(size_t num_clusters, const std::vector<HypothesisEvidence>& evidence,
                              const HypothesisPool& pool) {
  AcceptedOnClusters out{std::vector<std::set<int>>(num_clusters),
                         std::vector<double>(num_clusters, 0.0)};
  for (size_t h = 0; h < evidence.size(); ++h) {
    if (!evidence[h].accepted) continue;
    const Hypothesis& hypothesis = pool.hypotheses[h];
    const Suggestion& s = hypothesis.recognition.suggestions[0];
    out.classes[hypothesis.cluster].insert(s.class_index);
    out.best_score[hypothesis.cluster] = std::max(out.best_score[hypothesis.cluster], s.score);
  }
  return out;
}

// Every cluster's first recognition gets its rolled hypotheses (AddRolledOf), once, for
// the classes none of its hypotheses was accepted as in `evidence` (a mug already found
// needs no other turn to be a mug) — but a cluster the class ranked first explains (less
// than other_class_remainder of it left, `left`) none unless roll_explained_clusters. True
// when that added hypotheses.
bool AddRolledHypotheses(const SceneContext& ctx, const std::vector<HypothesisEvidence>& evidence,
                         const std::vector<double>& left, HypothesisPool* pool) {
  if (ctx.options.roll_steps <= 1) return false;
  const Stopwatch watch;
  const std::vector<std::set<int>> accepted_classes =
      AcceptedOn(ctx.clusters.size(), evidence, *pool).classes;
  bool added = false;
  for (size_t c = 0; c < ctx.clusters.size(); ++c) {
    const int cluster = static_cast<int>(c);
    const std::vector<ClassScore>& ranked = pool->cluster_results[c].classes;
    if (!ctx.options.roll_explained_clusters && left[c] < ctx.options.other_class_remainder &&
        !ranked.empty() && accepted_classes[c].count(ranked.front().class_index)) {
      continue;  // explained by the class ranked first
    }
    added |= AddRolledOf(
        ctx, pool->cluster_results[c], cluster,
        [&ctx, cluster, pool] { return ClusterPoseQuery(ctx, cluster, pool); }, pool,
        accepted_classes[c]);
  }
  pool->recognise_ms += watch.WallMs();
  return added;
}

// A cluster whose accepted hypotheses leave at least other_class_remainder of its points
// unexplained (a mug's handle beside a glass fitted to its body) gets, once, the looks of
// each other class its first recognition posed with a verification within
// other_class_margin of the first class's: that class's best posed suggestion and its
// siblings, each turned about its axis of near symmetry (the handle put where it was
// seen), and the best of those scaled to the cluster (an unseen mug of another size). The
// class evidence of every hypothesis of such a cluster is then that of its best looks:
// each class's verification raised to the best score of its hypotheses on the cluster,
// the probabilities again the recogniser's softmax. True when that added hypotheses.
bool AddOtherClassLooks(const SceneContext& ctx, const std::vector<HypothesisEvidence>& evidence,
                        const std::vector<double>& left, HypothesisPool* pool) {
  const SceneRecognitionOptions& options = ctx.options;
  if (!(options.other_class_remainder > 0) || pool->other_classes_taken) return false;
  pool->other_classes_taken = true;
  const size_t num_clusters = ctx.clusters.size();
  const AcceptedOnClusters accepted = AcceptedOn(num_clusters, evidence, *pool);
  const std::vector<std::set<int>>& accepted_classes = accepted.classes;
  const std::vector<double>& accepted_score = accepted.best_score;
  std::vector<bool> looked(num_clusters, false);
  for (size_t k = 0; k < num_clusters; ++k) {
    // An accepted score of 1 − other_class_remainder or more explains its query (the
    // points it was recognised from) all but that much: what is left lies beside them.
    looked[k] = !accepted_classes[k].empty() && left[k] >= options.other_class_remainder &&
                accepted_score[k] < 1.0 - options.other_class_remainder &&
                !pool->cluster_results[k].classes.empty();
  }
  // Each class's looks: its source and siblings with their turns, then the best scaled.
  const auto class_looks = [&](const SceneContext& c, int cluster, const ClassScore& class_score,
                               const PoseQuery& query, HypothesisPool* looks) {
    const RecognitionResult& recognition = pool->cluster_results[cluster];
    const std::optional<Hypothesis> source =
        ClassSource(recognition, cluster, class_score.class_index, true);
    if (!source) return;
    const auto query_of = [&query] { return &query; };
    const std::vector<int> class_models = ModelsOfClass(c.database, class_score.class_index);
    const PointCloud& points = c.clusters[cluster].cloud;
    std::vector<Hypothesis> bodies{*source};
    HypothesisPool siblings;
    // Siblings and the scaled look only for a class an unseen instance may be taken for.
    const bool class_level = c.class_level[class_score.class_index] != 0;
    if (class_level) AddSiblingsOf(c, *source, class_models, points, query_of, &siblings);
    for (Hypothesis& sibling : siblings.hypotheses) bodies.push_back(std::move(sibling));
    looks->recognise_ms += siblings.recognise_ms;
    // The source's turns are in the pool already when its class is that probable
    // (AddRolledHypotheses); a body scoring other_class_roll_within or more below what was
    // accepted is not turned (its turns did not come near it).
    const bool source_rolled = class_score.probability >= c.options.roll_min_class_probability;
    const double roll_from = accepted_score[cluster] - c.options.other_class_roll_within;
    const Suggestion& s = source->recognition.suggestions[0];
    const Hypothesis* best = &bodies.front();
    if (source_rolled) {
      for (const Hypothesis& h : pool->hypotheses) {
        const Suggestion& t = h.recognition.suggestions[0];
        if (h.cluster == cluster && h.rolled && t.model == s.model &&
            t.score > best->recognition.suggestions[0].score) {
          best = &h;
        }
      }
    }
    const size_t first = looks->hypotheses.size();
    for (size_t b = 0; b < bodies.size(); ++b) {
      if (b > 0) looks->hypotheses.push_back(bodies[b]);
      if ((b == 0 && source_rolled) || bodies[b].recognition.suggestions[0].score < roll_from) {
        continue;
      }
      const NearSymmetryAxis* axis = RollAxis(c, bodies[b]);
      if (axis == nullptr) continue;
      for (Hypothesis& turned : RolledTurns(c, bodies[b], *axis, query)) {
        looks->hypotheses.push_back(std::move(turned));
      }
    }
    for (size_t j = first; j < looks->hypotheses.size(); ++j) {
      const Hypothesis& h = looks->hypotheses[j];
      if (h.recognition.suggestions[0].score > best->recognition.suggestions[0].score) best = &h;
    }
    const Suggestion& top = best->recognition.suggestions[0];
    const bool better = top.score > accepted_score[cluster];
    spdlog::debug("cluster {}: {:.0f}% unexplained, looks of class {}: best {} (score {:.3f}{})",
                  cluster, 100 * left[cluster], class_score.class_name, top.model_name, top.score,
                  better ? ""
                         : fmt::format(" ≤ {:.3f} accepted: dropped", accepted_score[cluster]));
    // Looks that fit the cluster no better than what was accepted there are not kept.
    if (!better) {
      looks->hypotheses.resize(first);
      return;
    }
    const Hypothesis scale_source = *best;
    if (class_level) {
      AddScaledHypothesis(c, scale_source, class_models.size(), points, query_of, looks);
    }
  };
  const size_t begin = pool->hypotheses.size();
  const std::vector<size_t> added = LooksSideBySide(
      ctx, num_clusters, pool, [&](const SceneContext& c, size_t k, HypothesisPool* looks) {
        if (!looked[k]) return;
        const int cluster = static_cast<int>(k);
        const std::vector<ClassScore>& classes = pool->cluster_results[k].classes;
        const double first = classes.front().verification;
        const PoseQuery* query = nullptr;
        for (const ClassScore& class_score : classes) {
          if (accepted_classes[k].count(class_score.class_index) ||
              class_score.verification < first - options.other_class_margin) {
            continue;
          }
          if (query == nullptr) query = ClusterPoseQuery(c, cluster, pool);
          if (query == nullptr) return;
          class_looks(c, cluster, class_score, *query, looks);
        }
      });
  // The class evidence of the clusters looked at, from their best looks on the whole
  // cluster: these and its size looks (scored on its pose query as the recogniser's are;
  // the hypotheses of its parts are scored on theirs).
  for (size_t k = 0, look = begin; k < num_clusters; look += added[k], ++k) {
    if (!looked[k] || added[k] == 0) continue;
    std::vector<ClassScore> classes = pool->cluster_results[k].classes;
    const auto raise = [&](size_t first, size_t end) {
      for (size_t j = first; j < end; ++j) {
        const Suggestion& s = pool->hypotheses[j].recognition.suggestions[0];
        for (ClassScore& class_score : classes) {
          if (s.class_index == class_score.class_index) {
            class_score.verification = std::max(class_score.verification, s.score);
          }
        }
      }
    };
    raise(look, look + added[k]);
    if (k < pool->size_looks_of.size()) {
      raise(pool->size_looks_of[k].first, pool->size_looks_of[k].second);
    }
    ClassProbabilities(options.recognition.assembly, &classes);
    for (Hypothesis& h : pool->hypotheses) {
      if (h.cluster == static_cast<int>(k)) h.recognition.classes = classes;
    }
  }
  return std::any_of(added.begin(), added.end(), [](size_t n) { return n > 0; });
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
    const PointCloud& surface = SurfaceOf(ctx, h);
    const double diameter = ctx.database.model(s.model).diameter;
    const double stability =
        plane.found ? options.stability_weight *
                          std::max(0.0, CentreOfMassHeight(surface, s.cam_from_model, plane,
                                                           diameter))
                    : 0.0;
    const double lift = diameter > 0 ? options.float_weight * std::abs(h.lift) / diameter : 0.0;
    const double prior =
        stability + lift +
        options.class_weight * (1.0 - ClassProbability(h.recognition, s.class_index));
    const std::vector<ClassScore>& classes = h.recognition.classes;
    const double class_probability =
        !classes.empty() && classes.front().class_index == s.class_index &&
                ctx.class_level[s.class_index]
            ? classes.front().probability
            : 0.0;
    scene_hypotheses.push_back(
        {&surface, s.cam_from_model, prior, class_probability, h.surface != nullptr});
  }
  // The segmentation cut everything below min_height (+ the plane noise) away: model
  // points there have nothing to fit.
  const float cut = static_cast<float>(options.segmentation.min_height +
                                       options.segmentation.plane_distance);
  std::vector<HypothesisEvidence> evidence = VerifyHypotheses(
      ctx.scene.points, ctx.cloud, scene_hypotheses, options.verification,
      [&plane, cut](const Eigen::Vector3f& p) { return plane.found && plane.Height(p) < cut; },
      &pool->verification, options.recognition.threads);
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

// Per cluster, the fraction of its thinned points `explained` (ExplainedMask) leaves out.
std::vector<double> UnexplainedFractions(const SceneContext& ctx,
                                         const std::vector<uint8_t>& explained) {
  const ThinnedScene& scene = ctx.scene;
  std::vector<int> thinned(ctx.clusters.size(), 0), left(ctx.clusters.size(), 0);
  for (size_t j = 0; j < scene.points.size(); ++j) {
    ++thinned[scene.cluster_of[j]];
    if (!explained[j]) ++left[scene.cluster_of[j]];
  }
  std::vector<double> fractions(ctx.clusters.size(), 1.0);
  for (size_t c = 0; c < fractions.size(); ++c) {
    if (thinned[c] > 0) fractions[c] = static_cast<double>(left[c]) / thinned[c];
  }
  return fractions;
}

// Remainders: a cluster with an accepted hypothesis is recognised again, once, on what the
// accepted hypotheses leave unexplained (`left`: UnexplainedFractions of `explained`) — on
// the whole remainder when it is at least remainder_fraction of the cluster's thinned
// points, and on each connected part of it (the segmentation's clustering distance) that
// holds at least remainder_part_fraction of the cluster's points, unless that part is
// nearly the whole remainder already tried. True when that added hypotheses.
bool AddRemainderHypotheses(const SceneContext& ctx, const std::vector<uint8_t>& explained,
                            const std::vector<double>& left, const std::vector<bool>& has_accepted,
                            HypothesisPool* pool) {
  const SceneRecognitionOptions& options = ctx.options;
  if (options.remainder_fraction <= 0 && options.remainder_part_fraction <= 0) return false;
  const std::vector<ObjectCluster>& clusters = ctx.clusters;
  const ThinnedScene& scene = ctx.scene;
  const double tolerance = options.segmentation.ClusterTolerance();
  std::vector<std::pair<int, PointCloud>> remainders;  // (cluster, unexplained points)
  for (size_t c = 0; c < clusters.size(); ++c) {
    // No accepted hypothesis: the whole cluster was tried.
    if (!has_accepted[c] || pool->remainder_tried[c]) continue;
    const bool whole = LargeRemainder(options, left[c]);
    const bool parts =
        options.remainder_part_fraction > 0 && left[c] >= options.remainder_part_fraction;
    if (!whole && !parts) continue;
    PointCloud remainder;
    for (const int i : clusters[c].indices) {
      if (!explained[scene.thinned_of_input[i]]) remainder.points.push_back(ctx.cloud.points[i]);
    }
    if (static_cast<int>(remainder.size()) < options.segmentation.min_cluster_points) continue;
    std::vector<PointCloud> pieces;
    if (parts) {
      const double min_part =
          std::max<double>(options.segmentation.min_cluster_points,
                           options.remainder_part_fraction * clusters[c].indices.size());
      for (const std::vector<int>& part : GridEuclideanClusters(remainder.points, tolerance)) {
        if (part.size() < min_part || (whole && part.size() >= 0.9 * remainder.size())) continue;
        PointCloud piece;
        piece.points.reserve(part.size());
        for (const int i : part) piece.points.push_back(remainder.points[i]);
        pieces.push_back(std::move(piece));
      }
    }
    // Nothing tried: a later round may find the remainder grown.
    if (!whole && pieces.empty()) continue;
    pool->remainder_tried[c] = 1;
    if (whole) remainders.emplace_back(static_cast<int>(c), std::move(remainder));
    for (PointCloud& piece : pieces) remainders.emplace_back(static_cast<int>(c), std::move(piece));
  }
  const std::vector<size_t> counts = AddPartHypotheses(ctx, remainders, pool);
  bool added = false;
  for (size_t k = 0; k < remainders.size(); ++k) {
    const auto& [c, remainder] = remainders[k];
    spdlog::debug("cluster {}: {:.0f}% unexplained, a remainder of {} points gave {} hypotheses",
                  c, 100 * left[c], remainder.size(), counts[k]);
    added |= counts[k] > 0;
  }
  return added;
}

void LogHypotheses(const SceneContext& ctx, const HypothesisPool& pool,
                   const std::vector<HypothesisEvidence>& evidence) {
  if (!spdlog::should_log(spdlog::level::debug)) return;
  const std::vector<Hypothesis>& hypotheses = pool.hypotheses;
  std::map<int, int> explained_by;  // scene point → accepted hypothesis explaining it
  for (size_t h = 0; h < hypotheses.size(); ++h) {
    if (!evidence[h].accepted) continue;
    for (const int j : evidence[h].explained) explained_by.emplace(j, static_cast<int>(h));
  }
  for (size_t h = 0; h < hypotheses.size(); ++h) {
    const Suggestion& s = hypotheses[h].recognition.suggestions[0];
    // Which accepted hypotheses explain its points (the duplicates its gain paid for).
    std::map<int, int> taken_by;  // accepted hypothesis → points of this one it explains
    for (const int j : evidence[h].explained) {
      const auto it = explained_by.find(j);
      if (it != explained_by.end() && it->second != static_cast<int>(h)) ++taken_by[it->second];
    }
    std::string taken;
    for (const auto& [g, n] : taken_by) taken += fmt::format(" {}:{}", g, n);
    spdlog::debug("hypothesis {}: its explained points that accepted ones explain:{}{}", h,
                  taken.empty() ? " none" : taken,
                  evidence[h].overlapping ? "; fills an accepted one's space" : "");
    const HypothesisEvidence& e = evidence[h];
    const Eigen::Vector3f& c = ctx.clusters[hypotheses[h].cluster].centroid;
    spdlog::debug("hypothesis cluster={} centroid=({:.4f},{:.4f},{:.4f}) class={} model={} "
                  "score={:.3f} class_p={:.3f} flipped={} twin={} rested={} sibling={} rolled={} upright={} "
                  "lift={:.3f} fit={:.3f} "
                  "local={:.3f} "
                  "viol={:.3f} visible={} explained={} duplicates={} violations={} passes={} "
                  "accepted={} class_level={} why={}",
                  hypotheses[h].cluster, c.x(), c.y(), c.z(), s.class_name, s.model_name,
                  s.score, ClassProbability(hypotheses[h].recognition, s.class_index),
                  hypotheses[h].flipped, hypotheses[h].twin, hypotheses[h].rested,
                  hypotheses[h].sibling, hypotheses[h].rolled, hypotheses[h].upright, hypotheses[h].lift, e.model_fit,
                  e.local_explained,
                  e.violation_fraction,
                  e.visible, e.explained.size(), e.duplicates, e.violations, e.passes,
                  e.accepted, e.class_level,
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
    object.recognition.ambiguous_with =
        AmbiguousWith(object.recognition, ctx.options.recognition.assembly.ambiguity_margin);
    object.cluster = hypotheses[h].cluster;
    object.snap_m = hypotheses[h].snap;
    object.scale = hypotheses[h].scale;
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
  if (why.empty() && e.visible_fraction < options.min_visible_fraction) {
    add(fmt::format("visible fraction {:.2f} < {:.2f}", e.visible_fraction,
                    options.min_visible_fraction));
  }
  if (why.empty() && e.overlapping) add("its model fills the space of an accepted object's");
  if (why.empty()) add("gain (points another hypothesis explains, violations, stability)");
  return why;
}

struct SceneRecogniser::Cache {
  std::mutex mutex;
  std::map<std::pair<int, double>, std::unique_ptr<PointCloud>> surfaces;
  std::map<std::pair<int, double>, std::unique_ptr<std::vector<Eigen::Vector3d>>> resting;
  std::map<std::pair<int, double>, std::unique_ptr<NearSymmetryAxis>> axes;
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
  SOPE_CHECK(max_rest_turn_deg >= 0 && max_rest_turn_deg <= 180,
             "scene recognition: max rest turn must be in [0, 180] degrees, got {}",
             max_rest_turn_deg);
  SOPE_CHECK(rest_refit_from >= 0 && rest_refit_faces >= 1 &&
                 rest_refit_min_class_probability >= 0 && rest_refit_min_class_probability <= 1 &&
                 rest_refit_min_score >= 0 && rest_refit_min_score <= 1,
             "scene recognition: need rest refit from ≥ 0 m, rest refit faces ≥ 1 and its "
             "min class probability and min score in [0, 1], got {}, {}, {} and {}",
             rest_refit_from, rest_refit_faces, rest_refit_min_class_probability,
             rest_refit_min_score);
  SOPE_CHECK(upright_max_tilt_deg >= 0 && upright_max_tilt_deg < 45,
             "scene recognition: upright max tilt must be in [0, 45) degrees, got {}",
             upright_max_tilt_deg);
  SOPE_CHECK(keep_unsnapped_from >= 0 && float_weight >= 0,
             "scene recognition: keep unsnapped from and float weight must be ≥ 0, got {} and {}",
             keep_unsnapped_from, float_weight);
  SOPE_CHECK(max_float >= max_snap, "scene recognition: max float must be ≥ max snap ({} m), got {}",
             max_snap, max_float);
  SOPE_CHECK(max_recognition_points >= 100,
             "scene recognition: max recognition points must be ≥ 100, got {}",
             max_recognition_points);
  SOPE_CHECK(remainder_part_fraction >= 0 && remainder_part_fraction <= 1,
             "scene recognition: remainder part fraction must be in [0, 1], got {}",
             remainder_part_fraction);
  SOPE_CHECK(remainder_fraction >= 0 && remainder_fraction <= 1,
             "scene recognition: remainder fraction must be in [0, 1], got {}",
             remainder_fraction);
  split.Check();
  SOPE_CHECK(split_segments >= 0, "scene recognition: split segments must be ≥ 0, got {}",
             split_segments);
  SOPE_CHECK(seam_split_fraction >= 0 && seam_split_fraction <= 0.5,
             "scene recognition: seam split fraction must be in [0, 0.5], got {}",
             seam_split_fraction);
  SOPE_CHECK(backdrop_planar_fraction >= 0 && backdrop_planar_fraction <= 1,
             "scene recognition: backdrop planar fraction must be in [0, 1], got {}",
             backdrop_planar_fraction);
  SOPE_CHECK(backdrop_extent_factor > 0 && backdrop_plane_distance > 0,
             "scene recognition: backdrop extent factor and plane distance must be > 0, got {} "
             "and {}",
             backdrop_extent_factor, backdrop_plane_distance);
  SOPE_CHECK(second_look_rounds >= 0,
             "scene recognition: second look rounds must be ≥ 0, got {}", second_look_rounds);
  SOPE_CHECK(join_distance >= 0, "scene recognition: join distance must be ≥ 0 m, got {}",
             join_distance);
  SOPE_CHECK(join_gap >= 0, "scene recognition: join gap must be ≥ 0 m, got {}", join_gap);
  SOPE_CHECK(join_max_seen >= 0 && join_max_seen <= 1,
             "scene recognition: join max seen must be in [0, 1], got {}", join_max_seen);
  SOPE_CHECK(twin_hypotheses >= 0, "scene recognition: twin hypotheses must be ≥ 0, got {}",
             twin_hypotheses);
  SOPE_CHECK(std::isfinite(max_scale) && max_scale >= 0,
             "scene recognition: max scale must be finite and ≥ 0 (≤ 1: no scaled hypotheses), "
             "got {}",
             max_scale);
  SOPE_CHECK(sibling_hypotheses >= 0,
             "scene recognition: sibling hypotheses must be ≥ 0, got {}", sibling_hypotheses);
  SOPE_CHECK(roll_steps >= 0, "scene recognition: roll steps must be ≥ 0, got {}", roll_steps);
  SOPE_CHECK(roll_min_class_probability >= 0 && roll_min_class_probability <= 1,
             "scene recognition: roll min class probability must be in [0, 1], got {}",
             roll_min_class_probability);
  SOPE_CHECK(roll_min_asymmetry >= 0 && roll_min_asymmetry <= 1,
             "scene recognition: roll min asymmetry must be in [0, 1], got {}", roll_min_asymmetry);
  SOPE_CHECK(stability_weight >= 0, "scene recognition: stability weight must be ≥ 0, got {}",
             stability_weight);
  SOPE_CHECK(class_weight >= 0 && class_weight <= 1,
             "scene recognition: class weight must be in [0, 1], got {}", class_weight);
  SOPE_CHECK(other_class_remainder >= 0 && other_class_remainder <= 1,
             "scene recognition: other class remainder must be in [0, 1], got {}",
             other_class_remainder);
  SOPE_CHECK(other_class_margin >= 0 && other_class_margin <= 1,
             "scene recognition: other class margin must be in [0, 1], got {}",
             other_class_margin);
  SOPE_CHECK(other_class_roll_within >= 0 && other_class_roll_within <= 1,
             "scene recognition: other class roll within must be in [0, 1], got {}",
             other_class_roll_within);
  SOPE_CHECK(scene_leaf > 0 && model_leaf > 0,
             "scene recognition: leaves must be > 0 m, got {} and {}", scene_leaf, model_leaf);
}

SceneRecogniser::SceneRecogniser(const Database& database)
    : database_(database), recogniser_(database), cache_(std::make_unique<Cache>()) {}
SceneRecogniser::~SceneRecogniser() = default;

// The cache's entry of `key` in `slots`, built by `build` when missing — outside the lock,
// so that a warm-up on another thread holds up no recognition for longer than a look-up
// (two threads may both build a missing entry; the first stored is kept).
namespace {
template <class T, class Build>
const T& CachedEntry(std::mutex& mutex, std::map<std::pair<int, double>, std::unique_ptr<T>>& slots,
                     const std::pair<int, double>& key, const Build& build) {
  {
    std::lock_guard<std::mutex> lock(mutex);
    const auto it = slots.find(key);
    if (it != slots.end()) return *it->second;
  }
  std::unique_ptr<T> built = build();
  std::lock_guard<std::mutex> lock(mutex);
  std::unique_ptr<T>& slot = slots[key];
  if (!slot) slot = std::move(built);
  return *slot;
}
}  // namespace

const PointCloud& SceneRecogniser::ModelSurface(int model, double leaf) const {
  SOPE_CHECK(model >= 0 && model < database_.num_models(),
             "scene recognition: model {} out of range (database of {})", model,
             database_.num_models());
  return CachedEntry(cache_->mutex, cache_->surfaces, {model, leaf}, [&] {
    auto surface = std::make_unique<PointCloud>();
    const ModelRecord& record = database_.model(model);
    const float inv_leaf = static_cast<float>(1.0 / leaf);
    std::unordered_map<uint64_t, int> voxel;
    PointCloud view;
    for (int v = record.first_view; v < record.first_view + record.num_views; ++v) {
      database_.ViewCloud(v, &view);
      for (size_t i = 0; i < view.size(); ++i) {
        if (!voxel.emplace(VoxelKeyOf(view.points[i], inv_leaf), 0).second) continue;
        surface->points.push_back(view.points[i]);
        surface->normals.push_back(view.HasNormals() ? view.normals[i]
                                                     : Eigen::Vector3f::UnitZ().eval());
      }
    }
    return surface;
  });
}

const std::vector<Eigen::Vector3d>& SceneRecogniser::RestingNormals(int model,
                                                                    double leaf) const {
  const PointCloud& surface = ModelSurface(model, leaf);
  return CachedEntry(cache_->mutex, cache_->resting, {model, leaf}, [&] {
    auto normals = std::make_unique<std::vector<Eigen::Vector3d>>();
    std::vector<Eigen::Vector3d> points;
    points.reserve(surface.size());
    for (const Eigen::Vector3f& p : surface.points) points.push_back(p.cast<double>());
    try {
      const ConvexHull hull = ComputeConvexHull(points);
      for (const RestingFace& face : StableFaces(hull, hull.centroid)) {
        normals->push_back(hull.facets[face.facet].normal);
      }
    } catch (const Error& e) {
      spdlog::debug("model {}: no resting faces ({})", database_.model(model).name, e.what());
    }
    return normals;
  });
}

const NearSymmetryAxis& SceneRecogniser::SymmetryAxis(int model, double leaf) const {
  const PointCloud& surface = ModelSurface(model, leaf);
  return CachedEntry(cache_->mutex, cache_->axes, {model, leaf}, [&] {
    auto axis = std::make_unique<NearSymmetryAxis>(FindNearSymmetryAxis(surface.points, 1.5 * leaf));
    spdlog::debug("model {}: {} axis of near symmetry (walls {:.2f}, turning moves {:.3f})",
                  database_.model(model).name, axis->found ? "an" : "no", axis->wall_fraction,
                  axis->asymmetric_fraction);
    return axis;
  });
}

void SceneRecogniser::WarmUp(const SceneRecognitionOptions& options,
                             const std::atomic<bool>* stop) const {
  for (int m = 0; m < database_.num_models(); ++m) {
    if (stop != nullptr && stop->load()) return;
    RestingNormals(m, options.model_leaf);
    if (options.roll_steps > 1) SymmetryAxis(m, options.model_leaf);
  }
}

SceneRecognitionResult SceneRecogniser::Recognise(const PointCloud& cloud,
                                                  const SceneRecognitionOptions& options) const {
  options.Check();
  const Stopwatch total;
  SceneRecognitionResult result;
  result.segmentation = SegmentTable(cloud, options.segmentation);
  result.timing.segment = result.segmentation.ms;
  double max_diameter = 0.0;  // SceneContext::max_diameter
  for (int m = 0; m < database_.num_models(); ++m) {
    max_diameter = std::max(max_diameter, database_.model(m).diameter);
  }
  std::vector<ObjectCluster>& all_clusters = result.segmentation.clusters;
  const TablePlane& table = result.segmentation.plane;
  const TableFarEdge far_edge = all_clusters.empty()
                                    ? TableFarEdge()
                                    : FarEdgeOf(cloud, table, options.segmentation.plane_distance);
  const auto backdrop_end = std::stable_partition(
      all_clusters.begin(), all_clusters.end(), [&](const ObjectCluster& c) {
        return !IsBackdrop(c, max_diameter, table, far_edge, options);
      });
  result.background.assign(std::make_move_iterator(backdrop_end),
                           std::make_move_iterator(all_clusters.end()));
  all_clusters.erase(backdrop_end, all_clusters.end());
  if (all_clusters.empty() && !result.background.empty()) {
    result.segmentation.message =
        fmt::format("nothing on the table but a backdrop ({} planar cluster(s) larger than any "
                    "model)",
                    result.background.size());
  }
  const std::vector<ObjectCluster>& clusters = all_clusters;
  if (clusters.empty()) {
    result.timing.total = total.WallMs();
    return result;
  }
  const ThinnedScene scene = ThinClusters(cloud, clusters, options.scene_leaf);
  const std::vector<uint8_t> class_level = ClassLevels(database_);
  const SceneContext ctx{*this,    recogniser_, database_, cloud,       options,
                         result.segmentation.plane, clusters,   scene,   max_diameter,
                         class_level};

  HypothesisPool pool;
  pool.cluster_results.resize(clusters.size());
  pool.remainder_tried.assign(clusters.size(), 0);
  pool.twins_tried.assign(clusters.size(), 0);
  pool.pose_queries.resize(clusters.size());
  pool.pose_query_built.assign(clusters.size(), 0);
  pool.split_tried.assign(clusters.size(), 0);
  {
    // The first looks, one recognition per cluster, independent of each other (side by
    // side with several threads), their hypotheses added in cluster order.
    std::vector<const PointCloud*> clouds;
    for (const ObjectCluster& c : clusters) clouds.push_back(&c.cloud);
    const std::vector<RecognitionResult> first_looks = RecogniseSideBySide(ctx, clouds, &pool);
    // Each cluster's hypotheses (their pose queries in the pool's own slots) side by side.
    LooksSideBySide(ctx, clusters.size(), &pool,
                    [&](const SceneContext& c, size_t k, HypothesisPool* looks) {
                      const int cluster = static_cast<int>(k);
                      AddClusterHypotheses(
                          c, cluster, first_looks[k], looks,
                          [&c, cluster, &pool] { return ClusterPoseQuery(c, cluster, &pool); });
                    });
  }
  std::vector<HypothesisEvidence> evidence = VerifyPool(ctx, &pool);
  // Second looks, in rounds while they add hypotheses (each look at most once per cluster
  // or pair): the remainders of clusters partly explained; for clusters nothing explained,
  // the twins of their hypotheses and the joins with what is near them; the convex
  // segments of both kinds (touching objects).
  for (int round = 0; round < options.second_look_rounds; ++round) {
    const std::vector<uint8_t> explained = ExplainedMask(ctx.scene.points.size(), evidence);
    const std::vector<double> left = UnexplainedFractions(ctx, explained);
    std::vector<bool> has_accepted(clusters.size(), false);
    for (size_t h = 0; h < evidence.size(); ++h) {
      if (evidence[h].accepted) has_accepted[pool.hypotheses[h].cluster] = true;
    }
    // Unexplained: no accepted hypothesis of its own and most of its points unexplained
    // (not, say, a handle a joined hypothesis of its neighbour explains). Split: those, and
    // the clusters whose remainder is large.
    std::vector<bool> unexplained(clusters.size()), to_split(clusters.size());
    for (size_t c = 0; c < clusters.size(); ++c) {
      unexplained[c] = !has_accepted[c] && left[c] > 0.5;
      to_split[c] = unexplained[c] || LargeRemainder(options, left[c]);
    }
    const Stopwatch look;
    bool added = AddRemainderHypotheses(ctx, explained, left, has_accepted, &pool);
    const double t_remainder = look.WallMs();
    added |= AddTwinsOfUnexplained(ctx, evidence, unexplained, &pool);
    const double t_twins = look.WallMs();
    const bool first_size_look = !pool.size_looks_taken;
    added |= AddSizeHypotheses(ctx, &pool);
    const double t_sizes = look.WallMs();
    if (first_size_look) added |= AddRolledHypotheses(ctx, evidence, left, &pool);
    added |= AddOtherClassLooks(ctx, evidence, left, &pool);
    const double t_rolled = look.WallMs();
    added |= AddSplitHypotheses(ctx, to_split, &pool);
    const double t_split = look.WallMs();
    added |= AddJoinedHypotheses(ctx, evidence, unexplained, left, &pool);
    const double t_join = look.WallMs();
    if (!added) break;
    evidence = VerifyPool(ctx, &pool);
    spdlog::debug("second looks, round {}: remainders {:.1f} ms, twins {:.1f} ms, sizes {:.1f} "
                  "ms, rolled {:.1f} ms, splits {:.1f} ms, joins {:.1f} ms, verification {:.1f} "
                  "ms; {} hypotheses",
                  round, t_remainder, t_twins - t_remainder, t_sizes - t_twins,
                  t_rolled - t_sizes, t_split - t_rolled, t_join - t_split, look.WallMs() - t_join,
                  pool.hypotheses.size());
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
    if (object.scale != Eigen::Vector3d::Ones()) {
      o["scale"] = {object.scale.x(), object.scale.y(), object.scale.z()};
    }
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
  nlohmann::json background = nlohmann::json::array();
  for (const ObjectCluster& c : result.background) {
    background.push_back({{"points", c.indices.size()},
                          {"centroid", {c.centroid.x(), c.centroid.y(), c.centroid.z()}}});
  }
  j["background"] = std::move(background);
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
