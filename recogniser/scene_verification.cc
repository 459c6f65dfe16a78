#include "recogniser/scene_verification.h"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <utility>

#include "core/convex_hull.h"
#include "core/error.h"
#include "core/run_jobs.h"
#include "recogniser/pose.h"

namespace sope {
namespace {

// Nearest observed depth (z) per cell of normalised image coordinates: the surface the
// camera saw along each ray.
class DepthGrid {
 public:
  DepthGrid(const PointCloud& observed, double cell) : inv_cell_(1.0 / cell) {
    float u_min = std::numeric_limits<float>::max(), v_min = u_min, u_max = -u_min, v_max = -u_min;
    for (const Eigen::Vector3f& p : observed.points) {
      if (!(p.z() > 0.0f)) continue;
      u_min = std::min(u_min, p.x() / p.z());
      u_max = std::max(u_max, p.x() / p.z());
      v_min = std::min(v_min, p.y() / p.z());
      v_max = std::max(v_max, p.y() / p.z());
    }
    if (u_min > u_max) return;
    u0_ = u_min;
    v0_ = v_min;
    width_ = static_cast<int>((u_max - u_min) * inv_cell_) + 1;
    height_ = static_cast<int>((v_max - v_min) * inv_cell_) + 1;
    SOPE_CHECK(static_cast<int64_t>(width_) * height_ < (int64_t{1} << 26),
               "scene verification: field of view too wide for a {} depth grid", cell);
    depth_.assign(static_cast<size_t>(width_) * height_, std::numeric_limits<float>::infinity());
    for (const Eigen::Vector3f& p : observed.points) {
      if (!(p.z() > 0.0f)) continue;
      float& d = depth_[Index(p)];
      d = std::min(d, p.z());
    }
  }
  // Observed depth on the ray of `p`; +∞ when nothing was seen there or outside the grid.
  float At(const Eigen::Vector3f& p) const {
    if (depth_.empty() || !(p.z() > 0.0f)) return std::numeric_limits<float>::infinity();
    const int cx = static_cast<int>(std::floor((p.x() / p.z() - u0_) * inv_cell_));
    const int cy = static_cast<int>(std::floor((p.y() / p.z() - v0_) * inv_cell_));
    if (cx < 0 || cy < 0 || cx >= width_ || cy >= height_) {
      return std::numeric_limits<float>::infinity();
    }
    return depth_[static_cast<size_t>(cy) * width_ + cx];
  }

 private:
  size_t Index(const Eigen::Vector3f& p) const {
    const int cx = std::clamp(static_cast<int>((p.x() / p.z() - u0_) * inv_cell_), 0, width_ - 1);
    const int cy = std::clamp(static_cast<int>((p.y() / p.z() - v0_) * inv_cell_), 0, height_ - 1);
    return static_cast<size_t>(cy) * width_ + cx;
  }
  double inv_cell_;
  float u0_ = 0, v0_ = 0;
  int width_ = 0, height_ = 0;
  std::vector<float> depth_;
};

// A hypothesis's model points in the camera frame: those facing the camera that agree
// with the observed depth, and the model's bounding box (model frame, with the margin).
struct VisibleModel {
  std::vector<Eigen::Vector3f> points_in_cam;
  Eigen::Vector3f box_min_in_model;
  Eigen::Vector3f box_max_in_model;
};

// Classifies the model points facing the camera along their rays (counts into `e`:
// visible, empty, violations, occluded) and keeps those on the observed surface.
VisibleModel ClassifyAlongRays(const PointCloud& model, const Eigen::Matrix3f& rotation,
                               const Eigen::Vector3f& translation, const DepthGrid& depth,
                               const SceneVerificationOptions& options,
                               const std::function<bool(const Eigen::Vector3f&)>& ignore,
                               HypothesisEvidence* e) {
  const float violation = static_cast<float>(options.violation_distance);
  VisibleModel visible;
  Eigen::Vector3f box_min = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  Eigen::Vector3f box_max = -box_min;
  for (size_t i = 0; i < model.size(); ++i) {
    box_min = box_min.cwiseMin(model.points[i]);
    box_max = box_max.cwiseMax(model.points[i]);
    const Eigen::Vector3f p = rotation * model.points[i] + translation;
    const Eigen::Vector3f n = rotation * model.normals[i];
    if (!(p.z() > 0.0f) || n.dot(p) >= 0.0f) continue;
    if (ignore && ignore(p)) continue;
    ++e->visible;
    const float seen = depth.At(p);
    if (!std::isfinite(seen)) {
      ++e->empty;
    } else if (seen > p.z() + violation) {
      ++e->violations;
    } else if (seen < p.z() - violation) {
      ++e->occluded;
    } else {
      visible.points_in_cam.push_back(p);
    }
  }
  const Eigen::Vector3f margin = Eigen::Vector3f::Constant(static_cast<float>(options.box_margin));
  visible.box_min_in_model = box_min - margin;
  visible.box_max_in_model = box_max + margin;
  return visible;
}

// Scene points in the box within `distance` of a visible model point (explained), the
// visible model points some such scene point is near (fitting) and the scene points in
// the box (local).
struct Explanation {
  std::vector<int> explained;
  std::vector<int> local_points;  // increasing; `explained` is a subset
  int fitting = 0;
  int local = 0;
};

// Uses a grid whose window of one cell spans `distance`.
Explanation ExplainScene(const PointCloud& scene, const VisibleModel& visible,
                         const Eigen::Matrix3f& rotation, const Eigen::Vector3f& translation,
                         const SceneVerificationOptions& options, double distance) {
  const Eigen::Matrix3f model_from_cam = rotation.transpose();
  const float cell = static_cast<float>(options.ray_cell * distance / options.inlier_distance);
  const ProjectiveGrid model_grid(visible.points_in_cam, {}, cell);
  const float distance2 = static_cast<float>(distance * distance);
  std::vector<uint8_t> fits(visible.points_in_cam.size(), 0);
  Explanation explanation;
  for (size_t j = 0; j < scene.size(); ++j) {
    const Eigen::Vector3f q = model_from_cam * (scene.points[j] - translation);
    const bool in_box = (q.array() >= visible.box_min_in_model.array()).all() &&
                        (q.array() <= visible.box_max_in_model.array()).all();
    if (!in_box) continue;
    ++explanation.local;
    explanation.local_points.push_back(static_cast<int>(j));
    float d2 = 0;
    const int nearest =
        model_grid.Nearest(scene.points[j], Eigen::Vector3f::Zero(), 0.0f, 1, distance2, &d2);
    if (nearest >= 0) {
      explanation.explained.push_back(static_cast<int>(j));
      fits[nearest] = 1;
    }
  }
  // Counted from the scene side only (a visible point fits when a scene point in the box
  // is near it), to stay symmetric with `explained`.
  for (const uint8_t f : fits) explanation.fitting += f;
  return explanation;
}

// What a hypothesis's fit tests need again when other hypotheses have been accepted: its
// explanation at each level computed (instance; class when it was allowed one).
struct LevelExplanations {
  Explanation instance;
  Explanation class_level;
  bool class_allowed = false;  // class_level was computed (it failed at instance level)
  double class_min_fit = 0.0;  // the class-level fit test's threshold for this hypothesis
  double class_fit = 0.0;
};

// The fit tests at one level with local_explained counted over the box's scene points
// that no other accepted hypothesis explains (`taken`: explained by an accepted one); the
// plain test when `taken` is empty. Only local_explained depends on `taken`: a level that
// fails the other tests fails whatever is taken, and its local_explained is then the plain
// one (the box's points not walked).
bool PassesLevel(const Explanation& explanation, double fit, double violation_fraction,
                 double min_fit, double min_local, double max_violations,
                 const std::vector<uint8_t>& taken, double* local_explained) {
  const bool other_tests = fit >= min_fit && violation_fraction <= max_violations &&
                           !explanation.explained.empty();
  int others = 0;
  if (other_tests && !taken.empty()) {
    size_t k = 0;  // both lists increase
    for (const int j : explanation.local_points) {
      while (k < explanation.explained.size() && explanation.explained[k] < j) ++k;
      const bool mine = k < explanation.explained.size() && explanation.explained[k] == j;
      others += !mine && taken[j];
    }
  }
  const int local = explanation.local - others;
  *local_explained =
      local > 0 ? static_cast<double>(explanation.explained.size()) / local : 0.0;
  return other_tests && *local_explained >= min_local;
}

// The fraction of e's camera-facing model points that fit at a level (`fitting` of them).
double VisibleFraction(int fitting, const HypothesisEvidence& e) {
  return e.visible > 0 ? static_cast<double>(fitting) / e.visible : 0.0;
}

// The level a hypothesis is judged at (Judge) and its figures there.
struct Verdict {
  const Explanation* explanation = nullptr;
  double fit = 0.0;
  double local_explained = 0.0;
  bool class_level = false;
  bool passes = false;
};

// The verdict on `e` at instance level and, failing that, at class level (`taken` as in
// PassesLevel): the instance level's figures unless the class level passes.
Verdict Decide(const LevelExplanations& levels, const SceneVerificationOptions& options,
               const std::vector<uint8_t>& taken, const HypothesisEvidence& e) {
  const int unoccluded = std::max(1, e.visible - e.occluded - e.empty);
  Verdict v;
  v.explanation = &levels.instance;
  v.fit = std::min(1.0, static_cast<double>(levels.instance.fitting) / unoccluded);
  const bool instance =
      PassesLevel(levels.instance, v.fit, e.violation_fraction, options.min_model_fit,
                  options.min_local_explained, options.max_violation_fraction, taken,
                  &v.local_explained);
  if (!instance && levels.class_allowed) {
    double class_local = 0.0;
    if (PassesLevel(levels.class_level, levels.class_fit, e.violation_fraction,
                    levels.class_min_fit, options.class_min_local_explained,
                    options.class_max_violation_fraction, taken, &class_local)) {
      v.explanation = &levels.class_level;
      v.fit = levels.class_fit;
      v.local_explained = class_local;
      v.class_level = true;
    }
  }
  v.passes = (instance || v.class_level) &&
             VisibleFraction(v.explanation->fitting, e) >= options.min_visible_fraction;
  return v;
}

// Sets e's fit figures from the verdict (the level the hypothesis is judged at).
void Apply(const Verdict& v, HypothesisEvidence* e) {
  e->class_level = v.class_level;
  e->model_fit = v.fit;
  e->local_explained = v.local_explained;
  e->fitting = v.explanation->fitting;
  e->local = v.explanation->local;
  e->visible_fraction = VisibleFraction(v.explanation->fitting, *e);
  e->explained = v.explanation->explained;
  e->passes = v.passes;
}

// Judges `e` on its own (no point taken by another hypothesis) at instance level and,
// failing that, at class level; sets e->passes and the figures of the level it is judged at.
void Judge(const LevelExplanations& levels, const SceneVerificationOptions& options,
           HypothesisEvidence* e) {
  Apply(Decide(levels, options, {}, *e), e);
}

// The evidence for one hypothesis, at instance level and, failing that, at class level;
// `levels` keeps the explanations for a second look.
HypothesisEvidence EvaluateHypothesis(const PointCloud& scene, const SceneHypothesis& hypothesis,
                                      const DepthGrid& depth,
                                      const SceneVerificationOptions& options,
                                      const std::function<bool(const Eigen::Vector3f&)>& ignore,
                                      LevelExplanations* levels) {
  const PointCloud& model = *hypothesis.model_cloud;
  const Eigen::Matrix3f rotation = hypothesis.cam_from_model.rotation.cast<float>();
  const Eigen::Vector3f translation = hypothesis.cam_from_model.translation.cast<float>();
  HypothesisEvidence e;
  // Model points facing the camera, classified along their rays.
  const VisibleModel visible =
      ClassifyAlongRays(model, rotation, translation, depth, options, ignore, &e);
  // Scene points near the model's visible surface: explained; model points near the
  // scene: fitting.
  levels->instance =
      ExplainScene(scene, visible, rotation, translation, options, options.inlier_distance);
  const int unoccluded = std::max(1, e.visible - e.occluded - e.empty);
  e.violation_fraction = static_cast<double>(e.violations) / unoccluded;
  levels->class_allowed = false;
  Judge(*levels, options, &e);
  // Class level, for a hypothesis that fails at instance level: the same tests at the class
  // inlier distance (another instance's surface lies some millimetres off the database
  // model's), with their own thresholds.
  if (!e.passes && hypothesis.class_probability >= options.min_class_probability &&
      e.violation_fraction <= options.class_max_violation_fraction) {
    levels->class_allowed = true;
    levels->class_min_fit =
        hypothesis.scaled ? std::max(options.class_min_model_fit, options.scaled_min_model_fit)
                          : options.class_min_model_fit;
    levels->class_level = ExplainScene(scene, visible, rotation, translation, options,
                                       options.class_inlier_distance);
    levels->class_fit =
        std::min(1.0, static_cast<double>(levels->class_level.fitting) / unoccluded);
    Judge(*levels, options, &e);
  }
  return e;
}

// A model cloud's sample (≤ kOverlapSamplePoints, model frame), its convex hull (none:
// flat or degenerate) and bounding sphere, for the overlap test; `size` and `first` the
// cloud's, to tell a cached shape's cloud from another at the same address.
struct OverlapShape {
  size_t size = 0;
  Eigen::Vector3f first = Eigen::Vector3f::Zero();
  std::vector<Eigen::Vector3d> sample;
  std::optional<ConvexHull> hull;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double radius = 0.0;
};
using OverlapShapes = std::map<const PointCloud*, std::unique_ptr<OverlapShape>>;
// The overlap test's answers by pair of hypotheses (indices: a verification cache's
// hypotheses stay the same from call to call, new ones appended).
using OverlapPairs = std::map<std::pair<int, int>, bool>;
constexpr size_t kOverlapSamplePoints = 400;

// Whether two hypotheses' models fill the same space (max_mutual_overlap): each model's
// surface sample, at its pose, against the other's convex hull. The shapes and the pairs'
// answers are computed when first needed and kept in `shapes` and `pairs` (a verification
// cache's: every call on one scene).
class OverlapTest {
 public:
  OverlapTest(const std::vector<SceneHypothesis>& hypotheses,
              const SceneVerificationOptions& options, OverlapShapes* shapes,
              OverlapPairs* pairs)
      : hypotheses_(hypotheses), options_(options), shapes_(*shapes), pairs_(*pairs) {}

  bool Overlap(int a, int b) {
    if (options_.max_mutual_overlap <= 0) return false;
    const auto key = std::minmax(a, b);
    const auto found = pairs_.find(key);
    if (found != pairs_.end()) return found->second;
    const OverlapShape& shape_a = ShapeOf(hypotheses_[a].model_cloud);
    const OverlapShape& shape_b = ShapeOf(hypotheses_[b].model_cloud);
    const Rigid3d& pose_a = hypotheses_[a].cam_from_model;
    const Rigid3d& pose_b = hypotheses_[b].cam_from_model;
    bool overlap = false;
    if (shape_a.hull && shape_b.hull &&
        (pose_a * shape_a.centre - pose_b * shape_b.centre).norm() <
            shape_a.radius + shape_b.radius) {
      overlap = InsideFraction(shape_a, pose_a, shape_b, pose_b) >= options_.max_mutual_overlap &&
                InsideFraction(shape_b, pose_b, shape_a, pose_a) >= options_.max_mutual_overlap;
    }
    pairs_.emplace(key, overlap);
    return overlap;
  }

 private:
  const OverlapShape& ShapeOf(const PointCloud* cloud) {
    std::unique_ptr<OverlapShape>& slot = shapes_[cloud];
    const size_t n = cloud->size();
    if (slot && slot->size == n && (n == 0 || slot->first == cloud->points[0])) return *slot;
    slot = std::make_unique<OverlapShape>();
    slot->size = n;
    if (n > 0) slot->first = cloud->points[0];
    const size_t step = std::max<size_t>(1, n / kOverlapSamplePoints);
    for (size_t i = 0; i < n; i += step) slot->sample.push_back(cloud->points[i].cast<double>());
    if (slot->sample.size() < 4) return *slot;
    for (const Eigen::Vector3d& p : slot->sample) slot->centre += p;
    slot->centre /= static_cast<double>(slot->sample.size());
    for (const Eigen::Vector3d& p : slot->sample) {
      slot->radius = std::max(slot->radius, (p - slot->centre).norm());
    }
    try {
      slot->hull = ComputeConvexHull(slot->sample);
    } catch (const Error&) {
      slot->hull.reset();  // flat or degenerate: no volume to overlap
    }
    return *slot;
  }

  // The fraction of `points`' sample (at pose_points) inside `hull`'s hull (at pose_hull)
  // deeper than overlap_margin.
  double InsideFraction(const OverlapShape& hull, const Rigid3d& pose_hull,
                        const OverlapShape& points, const Rigid3d& pose_points) const {
    const Rigid3d hull_from_points = pose_hull.Inverse() * pose_points;
    int inside = 0;
    for (const Eigen::Vector3d& p : points.sample) {
      inside += hull.hull->Distance(hull_from_points * p) < -options_.overlap_margin;
    }
    return static_cast<double>(inside) / static_cast<double>(points.sample.size());
  }

  const std::vector<SceneHypothesis>& hypotheses_;
  const SceneVerificationOptions& options_;
  OverlapShapes& shapes_;
  OverlapPairs& pairs_;
};

// Greedy global selection: repeatedly accepts the passing hypothesis of the largest gain
// (fresh points less duplicates, violations and the prior) until none gains enough; one
// whose model fills the space of an accepted one's (`overlap`) is left out instead.
// `taken` (per scene point: explained by an accepted hypothesis) and `done` (per
// hypothesis) carry over between calls.
void SelectGreedily(const std::vector<SceneHypothesis>& hypotheses,
                    const SceneVerificationOptions& options, OverlapTest* overlap,
                    std::vector<HypothesisEvidence>* evidence,
                    std::vector<uint8_t>* taken_points, std::vector<uint8_t>* done_hypotheses) {
  std::vector<HypothesisEvidence>& out = *evidence;
  std::vector<uint8_t>& taken = *taken_points;
  std::vector<uint8_t>& done = *done_hypotheses;
  // The candidates (passing, not done), each with its explained points already taken; and
  // per scene point not taken, the candidates explaining it (CSR), so that accepting one
  // updates the others' counts instead of recounting them every round. The same gains,
  // hence the same choices, as counting afresh.
  std::vector<int> candidates;
  for (size_t h = 0; h < hypotheses.size(); ++h) {
    if (!done[h] && out[h].passes) candidates.push_back(static_cast<int>(h));
  }
  std::vector<int> duplicates(hypotheses.size(), 0);
  std::vector<int> start(taken.size() + 1, 0);
  for (const int h : candidates) {
    for (const int j : out[h].explained) {
      if (taken[j]) {
        ++duplicates[h];
      } else {
        ++start[j + 1];
      }
    }
  }
  for (size_t j = 0; j < taken.size(); ++j) start[j + 1] += start[j];
  std::vector<int> holders(start.back());
  {
    std::vector<int> fill(start.begin(), start.end() - 1);
    for (const int h : candidates) {
      for (const int j : out[h].explained) {
        if (!taken[j]) holders[fill[j]++] = h;
      }
    }
  }
  while (true) {
    int best = -1;
    double best_gain = 0.0;
    for (const int h : candidates) {
      if (done[h]) continue;
      const int explained = static_cast<int>(out[h].explained.size());
      const int fresh = explained - duplicates[h];
      const double gain = fresh - options.duplicate_weight * duplicates[h] -
                          options.violation_weight * out[h].violations -
                          hypotheses[h].prior_penalty * explained;
      if (gain < options.min_gain_fraction * explained) continue;
      if (best < 0 || gain > best_gain) {
        best = h;
        best_gain = gain;
      }
    }
    if (best < 0) {
      for (const int h : candidates) {
        if (!done[h]) out[h].duplicates = duplicates[h];
      }
      break;
    }
    done[best] = 1;
    bool fills_another = false;
    for (size_t g = 0; g < hypotheses.size() && !fills_another; ++g) {
      fills_another = out[g].accepted && overlap->Overlap(best, static_cast<int>(g));
    }
    if (fills_another) {
      out[best].overlapping = true;
      continue;
    }
    out[best].accepted = true;
    out[best].duplicates = duplicates[best];
    for (const int j : out[best].explained) {
      if (taken[j]) continue;
      taken[j] = 1;
      for (int k = start[j]; k < start[j + 1]; ++k) ++duplicates[holders[k]];
    }
  }
}

// The greedy selection from the state (`taken`, `done`) on, then its second looks: scene
// points in a hypothesis's box that an accepted hypothesis explains (a touching object) no
// longer count against its local_explained; the hypotheses that pass then join the
// selection, until none does.
void CompleteSelection(const std::vector<SceneHypothesis>& hypotheses,
                       const std::vector<LevelExplanations>& levels,
                       const SceneVerificationOptions& options, OverlapTest* overlap,
                       std::vector<HypothesisEvidence>* evidence, std::vector<uint8_t>* taken,
                       std::vector<uint8_t>* done) {
  std::vector<HypothesisEvidence>& out = *evidence;
  SelectGreedily(hypotheses, options, overlap, &out, taken, done);
  for (int round = 0; round < options.relook_rounds; ++round) {
    bool more = false;
    for (size_t h = 0; h < hypotheses.size(); ++h) {
      if ((*done)[h] || out[h].passes) continue;
      // Its figures change only when it now passes.
      const Verdict relook = Decide(levels[h], options, *taken, out[h]);
      if (relook.passes) {
        Apply(relook, &out[h]);
        more = true;
      }
    }
    if (!more) break;
    SelectGreedily(hypotheses, options, overlap, &out, taken, done);
  }
}

// The selection's objective, the sum of its greedy gains (in any order): scene points
// explained, each once, less duplicate_weight per further explanation, violation_weight
// per violation and each hypothesis's prior.
double SelectionObjective(const std::vector<SceneHypothesis>& hypotheses,
                          const std::vector<HypothesisEvidence>& evidence,
                          const SceneVerificationOptions& options, size_t scene_points) {
  std::vector<uint8_t> seen(scene_points, 0);
  double objective = 0.0;
  for (size_t h = 0; h < hypotheses.size(); ++h) {
    const HypothesisEvidence& e = evidence[h];
    if (!e.accepted) continue;
    for (const int j : e.explained) {
      objective += seen[j] ? -options.duplicate_weight : 1.0;
      seen[j] = 1;
    }
    objective -= options.violation_weight * e.violations +
                 hypotheses[h].prior_penalty * static_cast<double>(e.explained.size());
  }
  return objective;
}

}  // namespace

void SceneVerificationOptions::Check() const {
  SOPE_CHECK(inlier_distance > 0, "scene verification: inlier distance must be > 0 m, got {}",
             inlier_distance);
  SOPE_CHECK(class_inlier_distance >= inlier_distance,
             "scene verification: class inlier distance must be ≥ the inlier distance ({} m), "
             "got {}",
             inlier_distance, class_inlier_distance);
  SOPE_CHECK(violation_distance > 0,
             "scene verification: violation distance must be > 0 m, got {}", violation_distance);
  SOPE_CHECK(ray_cell > 0, "scene verification: ray cell must be > 0, got {}", ray_cell);
  for (const double fraction :
       {min_model_fit, min_local_explained, max_violation_fraction, min_gain_fraction,
        min_class_probability, class_min_model_fit, class_min_local_explained,
        class_max_violation_fraction, scaled_min_model_fit, max_mutual_overlap,
        min_visible_fraction}) {
    SOPE_CHECK(fraction >= 0.0 && fraction <= 1.0,
               "scene verification: fractions must lie in [0, 1], got {}", fraction);
  }
  SOPE_CHECK(duplicate_weight >= 0 && violation_weight >= 0,
             "scene verification: weights must be ≥ 0, got {} and {}", duplicate_weight,
             violation_weight);
  SOPE_CHECK(box_margin >= 0, "scene verification: box margin must be ≥ 0 m, got {}",
             box_margin);
  SOPE_CHECK(relook_rounds >= 0, "scene verification: relook rounds must be ≥ 0, got {}",
             relook_rounds);
  SOPE_CHECK(exchange_rounds >= 0, "scene verification: exchange rounds must be ≥ 0, got {}",
             exchange_rounds);
  SOPE_CHECK(overlap_margin >= 0, "scene verification: overlap margin must be ≥ 0 m, got {}",
             overlap_margin);
}

struct VerificationCache::Impl {
  std::unique_ptr<DepthGrid> depth;
  std::vector<HypothesisEvidence> evidence;  // each hypothesis's own, before the selection
  std::vector<LevelExplanations> levels;
  OverlapShapes shapes;  // the overlap test's, by model cloud
  OverlapPairs overlap_pairs;
};
VerificationCache::VerificationCache() : impl(std::make_unique<Impl>()) {}
VerificationCache::~VerificationCache() = default;

std::vector<HypothesisEvidence> VerifyHypotheses(
    const PointCloud& scene, const PointCloud& observed,
    const std::vector<SceneHypothesis>& hypotheses, const SceneVerificationOptions& options,
    const std::function<bool(const Eigen::Vector3f&)>& ignore, VerificationCache* cache,
    int threads) {
  options.Check();
  VerificationCache local;
  VerificationCache::Impl& kept = cache ? *cache->impl : *local.impl;
  if (!kept.depth) kept.depth = std::make_unique<DepthGrid>(observed, options.ray_cell);
  SOPE_CHECK(kept.evidence.size() <= hypotheses.size(),
             "scene verification: the cache holds {} hypotheses, the call only {}",
             kept.evidence.size(), hypotheses.size());
  const size_t first_new = kept.evidence.size();
  for (size_t h = first_new; h < hypotheses.size(); ++h) {
    SOPE_CHECK(hypotheses[h].model_cloud != nullptr && hypotheses[h].model_cloud->HasNormals(),
               "scene verification: hypothesis {} has no model cloud with normals", h);
  }
  // Each new hypothesis's own evidence, independent of the others (on `threads` threads),
  // kept in order once all are done.
  const size_t count = hypotheses.size() - first_new;
  std::vector<HypothesisEvidence> evidence(count);
  std::vector<LevelExplanations> new_levels(count);
  const DepthGrid& depth = *kept.depth;
  RunJobs(threads, count, [&](size_t k) {
    evidence[k] = EvaluateHypothesis(scene, hypotheses[first_new + k], depth, options, ignore,
                                     &new_levels[k]);
  });
  kept.evidence.insert(kept.evidence.end(), std::make_move_iterator(evidence.begin()),
                       std::make_move_iterator(evidence.end()));
  kept.levels.insert(kept.levels.end(), std::make_move_iterator(new_levels.begin()),
                     std::make_move_iterator(new_levels.end()));
  const std::vector<LevelExplanations>& levels = kept.levels;
  std::vector<HypothesisEvidence> out = kept.evidence;
  std::vector<uint8_t> taken(scene.size(), 0), done(hypotheses.size(), 0);
  OverlapTest overlap(hypotheses, options, &kept.shapes, &kept.overlap_pairs);
  CompleteSelection(hypotheses, levels, options, &overlap, &out, &taken, &done);
  // Exchanges: each round, the first accepted hypothesis whose removal lets the completed
  // selection gain more is dropped (the objective rises strictly, so this ends).
  for (int round = 0; round < options.exchange_rounds; ++round) {
    const double current = SelectionObjective(hypotheses, out, options, scene.size());
    bool exchanged = false;
    for (size_t h = 0; h < hypotheses.size() && !exchanged; ++h) {
      if (!out[h].accepted) continue;
      // The selection without h: the others accepted stay (with the evidence they were
      // accepted on), every other hypothesis is judged afresh.
      std::vector<HypothesisEvidence> trial = kept.evidence;
      std::vector<uint8_t> trial_taken(scene.size(), 0), trial_done(hypotheses.size(), 0);
      for (size_t g = 0; g < hypotheses.size(); ++g) {
        if (g == h || !out[g].accepted) continue;
        trial[g] = out[g];
        trial_done[g] = 1;
        for (const int j : out[g].explained) trial_taken[j] = 1;
      }
      trial_done[h] = 1;
      CompleteSelection(hypotheses, levels, options, &overlap, &trial, &trial_taken,
                        &trial_done);
      if (SelectionObjective(hypotheses, trial, options, scene.size()) > current + 0.5) {
        trial[h] = kept.evidence[h];  // judged on its own again, not accepted
        trial[h].duplicates = 0;
        for (const int j : trial[h].explained) trial[h].duplicates += trial_taken[j];
        out = std::move(trial);
        exchanged = true;
      }
    }
    if (!exchanged) break;
  }
  return out;
}

}  // namespace sope
