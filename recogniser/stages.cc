#include "recogniser/stages.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <mutex>
#include <numeric>
#include <utility>

#include "core/error.h"
#include "core/run_jobs.h"

namespace sope {

int NearestModelView(const Database& db, int model_index, const Rigid3d& canonical_from_model) {
  const ModelRecord& model = db.model(model_index);
  const Eigen::Vector3d camera_in_model = canonical_from_model.Inverse().translation;
  const Eigen::Vector3d direction = (camera_in_model - model.center).normalized();
  int best = model.first_view;
  double best_dot = -2.0;
  for (int v = model.first_view; v < model.first_view + model.num_views; ++v) {
    const double dot = db.view(v).viewpoint.Direction().dot(direction);
    if (dot > best_dot) {
      best_dot = dot;
      best = v;
    }
  }
  return best;
}

namespace {

// The views of one model that get hypotheses: ranked, up to `count` at least
// `min_separation_cos` apart (neighbouring views would converge to the same pose).
// `view_at(k)` gives the k-th view in ranking order, null past the last.
std::vector<RankedView> SeparatedViews(const Database& db,
                                       const std::function<const RankedView*(int)>& view_at,
                                       int count, double min_separation_cos) {
  std::vector<RankedView> chosen;
  std::vector<Eigen::Vector3d> directions;
  for (int k = 0;; ++k) {
    if (static_cast<int>(directions.size()) >= count) break;
    const RankedView* at = view_at(k);
    if (at == nullptr) break;
    const RankedView r = *at;
    const Eigen::Vector3d direction = db.view(r.view).viewpoint.Direction();
    bool near = false;
    for (const Eigen::Vector3d& d : directions) near |= d.dot(direction) > min_separation_cos;
    if (near) continue;
    directions.push_back(direction);
    chosen.push_back(r);
  }
  return chosen;
}

// Roll hypotheses of one view and a short ICP from each on a prefix of its cloud; the
// best-scoring hypothesis, or nothing when the view gave no hypothesis.
// With a memo, hypotheses it holds are looked up and those run are appended to `run`.
bool ScreenView(StageContext* context, const RankedView& r, int model_index,
                const PoseOptions& hypothesis_options, const PoseOptions& quick_options,
                const RecognitionOptions& options, const PoseMemo* memo, PoseCandidate* out,
                std::vector<PoseMemo::Screened>* run) {
  const ViewRecord& view = context->db().view(r.view);
  const PoseQuery& pose_query = context->pose_query(options.pose);
  const PointCloud& cloud = context->ViewCloud(r.view);
  const std::vector<PoseHypothesis> hypotheses =
      InitialPoses(view.cam_from_model, view.centroid_in_model, view.radius, cloud.points,
                   cloud.normals, pose_query, hypothesis_options);
  const ScreeningOptions& screening = options.screening;
  const size_t quick_n = std::min<size_t>(cloud.size(), screening.quick_points);
  const std::vector<Eigen::Vector3f> quick_points(cloud.points.begin(),
                                                  cloud.points.begin() + quick_n);
  const std::vector<Eigen::Vector3f> quick_normals(cloud.normals.begin(),
                                                   cloud.normals.begin() + quick_n);
  const float quick_spacing =
      view.cloud_spacing *
      std::sqrt(static_cast<float>(cloud.size()) / std::max<size_t>(1, quick_n));
  PoseCandidate candidate;
  candidate.ranked = r;
  candidate.view = r.view;
  candidate.model = model_index;
  bool first = true;
  for (const PoseHypothesis& hypothesis : hypotheses) {
    const PoseMemo::Screened* known =
        memo != nullptr ? memo->FindScreened(r.view, hypothesis.canonical_from_model) : nullptr;
    IcpResult icp;
    AlignmentScore alignment;
    if (known != nullptr) {
      icp = known->icp;
      alignment = known->alignment;
    } else {
      icp = RefinePose(quick_points, quick_normals, pose_query, hypothesis.canonical_from_model,
                       quick_options, screening.quick_iterations);
      alignment =
          ScoreAlignment(quick_points, quick_normals, quick_spacing, pose_query,
                         icp.canonical_from_model, options.pose, screening.quick_coverage_samples);
      if (memo != nullptr) {
        run->push_back({r.view, hypothesis.canonical_from_model, icp, alignment});
      }
    }
    if (first || alignment.score > candidate.alignment.score) {
      candidate.canonical_from_model = icp.canonical_from_model;
      candidate.roll = hypothesis.roll.roll;
      candidate.icp = icp;
      candidate.alignment = alignment;
      first = false;
    }
  }
  if (first) return false;
  *out = std::move(candidate);
  return true;
}

// Refinement of one candidate (see RefinePoses).
void RefineCandidate(StageContext* context, const PoseOptions& refine_options,
                     const RecognitionOptions& options, PoseCandidate* candidate) {
  const Database& db = context->db();
  const PoseQuery& pose_query = context->pose_query(options.pose);
  const RefinementOptions& refinement = options.refinement;
  const int quick = candidate->icp.iterations;
  int iterations = 0;
  for (int pass = 0; pass < refinement.passes; ++pass) {
    const int nearest = NearestModelView(db, candidate->model, candidate->canonical_from_model);
    if (pass > 0 && nearest == candidate->view) break;
    candidate->view = nearest;
    const PointCloud& cloud = context->ViewCloud(nearest);
    candidate->icp = RefinePose(cloud.points, cloud.normals, pose_query,
                                candidate->canonical_from_model, refine_options,
                                refinement.iterations, refinement.initial_gate);
    candidate->canonical_from_model = candidate->icp.canonical_from_model;
    iterations += candidate->icp.iterations;
  }
  candidate->icp.iterations = quick + iterations;
  candidate->view = NearestModelView(db, candidate->model, candidate->canonical_from_model);
  const PointCloud& cloud = context->ViewCloud(candidate->view);
  candidate->alignment =
      ScoreAlignment(cloud.points, cloud.normals, db.view(candidate->view).cloud_spacing,
                     pose_query, candidate->canonical_from_model, options.pose);
  candidate->refined = true;
}

// A suggestion from a ranked view: unposed, the database view's pose moved so that its
// centroid lies on the query's.
Suggestion UnposedSuggestion(const StageContext& context, const RankedView& r) {
  const Database& db = context.db();
  const ViewRecord& view = db.view(r.view);
  const ModelRecord& model = db.model(view.model);
  Suggestion s;
  s.view = r.view;
  s.model = view.model;
  s.class_index = model.class_index;
  s.model_name = model.name;
  s.class_name = model.class_name;
  s.viewpoint = view.viewpoint;
  s.hamming_distance = r.hamming;
  s.fine_distance = r.fine;
  s.coarse_distance = r.coarse;
  s.size_distance = r.size;
  s.ranking_distance = r.combined;
  s.fine_rank = r.fine_rank;
  const Eigen::Vector3d centroid_in_view_cam =
      view.cam_from_model * view.centroid_in_model.cast<double>();
  const Eigen::Matrix3d canonical_from_view_cam =
      CamFromCanonical(centroid_in_view_cam).transpose();
  Rigid3d canonical_from_model(canonical_from_view_cam * view.cam_from_model.rotation,
                               Eigen::Vector3d::Zero());
  canonical_from_model.translation =
      Eigen::Vector3d(0, 0, context.query().preprocessed.centroid.norm()) -
      canonical_from_model.rotation * view.centroid_in_model.cast<double>();
  s.cam_from_model = context.cam_from_canonical() * canonical_from_model;
  return s;
}

Suggestion PosedSuggestion(const StageContext& context, const PoseCandidate& candidate) {
  Suggestion s = UnposedSuggestion(context, candidate.ranked);
  s.view = candidate.view;
  s.viewpoint = context.db().view(candidate.view).viewpoint;
  s.cam_from_model = context.cam_from_canonical() * candidate.canonical_from_model;
  s.posed = true;
  s.refined = candidate.refined;
  s.converged = candidate.icp.converged;
  s.roll = candidate.roll;
  s.icp_iterations = candidate.icp.iterations;
  s.icp_rms = candidate.icp.rms;
  s.alignment = candidate.alignment;
  s.score = candidate.alignment.score;
  return s;
}

// All suggestions in their final order, before grouping.
std::vector<Suggestion> OrderSuggestions(const StageContext& context, const FineResult& fine,
                                         const std::vector<PoseCandidate>& posed,
                                         const AssemblyOptions& options) {
  std::vector<Suggestion> ordered;
  std::vector<uint8_t> used(fine.ranked.size(), 0);
  for (const PoseCandidate& candidate : posed) {
    if (candidate.ranked.fine_rank >= 0) used[candidate.ranked.fine_rank] = 1;
    ordered.push_back(PosedSuggestion(context, candidate));
  }
  for (size_t i = 0; i < fine.ranked.size(); ++i) {
    if (!used[i]) ordered.push_back(UnposedSuggestion(context, fine.ranked[i]));
  }
  if (!options.rerank_by_alignment) {
    // Fine-stage order; views found only by the per-model search go last.
    std::stable_sort(ordered.begin(), ordered.end(), [](const Suggestion& a, const Suggestion& b) {
      const int ra = a.fine_rank < 0 ? std::numeric_limits<int>::max() : a.fine_rank;
      const int rb = b.fine_rank < 0 ? std::numeric_limits<int>::max() : b.fine_rank;
      return ra < rb;
    });
  }
  return ordered;
}

}  // namespace

ViewDescription DescribeQuery(const Database& db, const PointCloud& cloud) {
  const DatabaseOptions& db_options = db.options();
  ViewDescription query = DescribeView(cloud, db_options.preprocess, db_options.features);
  SOPE_CHECK(query.features.coarse.size() == db.coarse_dim() &&
                 query.features.fine.size() == db.fine_dim(),
             "query features have {} coarse / {} fine values, the database {} / {} (database "
             "built by an incompatible sope?)",
             query.features.coarse.size(), query.features.fine.size(), db.coarse_dim(),
             db.fine_dim());
  return query;
}

CoarseResult CoarseStage(const Database& db, const ViewDescription& query,
                         const RecognitionOptions& options) {
  CoarseResult result;
  result.coarse = db.Standardise(query.features.coarse);
  const Eigen::MatrixXf hash_row = db.HashInput(result.coarse, query.features.fine).transpose();
  result.code = db.hasher().Encode(hash_row);
  const uint64_t* code = result.code.code(0);
  std::vector<HammingMatch>& matches = result.flagged;
  if (!options.restrict_to_models.empty()) {
    for (int m : options.restrict_to_models) {
      SOPE_CHECK(m >= 0 && m < db.num_models(), "recognition: restrict_to_models names model {} "
                 "of {}", m, db.num_models());
      const ModelRecord& model = db.model(m);
      for (int v = model.first_view; v < model.first_view + model.num_views; ++v) {
        HammingMatch match;
        match.index = v;
        match.hamming_distance =
            HammingDistance(code, db.index().code(v), db.index().words_per_code());
        matches.push_back(match);
      }
    }
  } else if (options.coarse.search == CoarseSearch::kKBest) {
    const int k = std::min<int>(
        db.num_views(),
        std::max<int>(options.coarse.min_flagged,
                      static_cast<int>(std::ceil(options.coarse.flag_fraction * db.num_views()))));
    matches = options.coarse.coarse_kbest ? options.coarse.coarse_kbest(code, k)
                                          : db.index().KBestSearch(code, k);
  } else {
    const int radius =
        static_cast<int>(std::lround(options.coarse.radius_fraction * result.code.bits));
    matches = db.index().RadiusSearch(code, radius);
  }
  return result;
}

namespace {

bool SamePose(const Rigid3d& a, const Rigid3d& b) {
  return a.rotation == b.rotation && a.translation == b.translation;
}

}  // namespace

const PoseMemo::Screened* PoseMemo::FindScreened(int view, const Rigid3d& initial) const {
  const auto it = screened_.find(view);
  if (it == screened_.end()) return nullptr;
  for (const Screened& entry : it->second) {
    if (SamePose(entry.initial, initial)) {
      ++screened_hits_;
      return &entry;
    }
  }
  return nullptr;
}

const PoseMemo::Refined* PoseMemo::FindRefined(int model, const Rigid3d& initial,
                                               int quick_iterations) const {
  for (const Refined& entry : refined_) {
    if (entry.model == model && entry.quick_iterations == quick_iterations &&
        SamePose(entry.initial, initial)) {
      ++refined_hits_;
      return &entry;
    }
  }
  return nullptr;
}

void PoseMemo::Add(Screened screened) {
  screened_[screened.view].push_back(std::move(screened));
}

void PoseMemo::Add(Refined refined) { refined_.push_back(std::move(refined)); }

bool RankedBefore(const RankedView& a, const RankedView& b) {
  return a.combined != b.combined ? a.combined < b.combined : a.view < b.view;
}

StageContext::StageContext(const Database& db, const ViewDescription& query,
                           const CoarseResult& coarse)
    : db_(db),
      query_(query),
      coarse_(coarse),
      log_query_radius_(std::log(std::max(1e-6f, query.preprocessed.radius))) {}

PoseQuery PoseQueryOf(const Database& db, const PreprocessedCloud& preprocessed,
                      const PoseOptions& options) {
  const PreprocessOptions& preprocess = db.options().preprocess;
  const float spacing =
      static_cast<float>(preprocess.voxel_leaf > 0.0 ? preprocess.voxel_leaf : 0.004);
  return MakePoseQuery(preprocessed.cloud, preprocessed.centroid, preprocessed.radius, spacing,
                       options);
}

Rigid3d StageContext::cam_from_canonical() const {
  return Rigid3d(query_.cam_from_canonical, Eigen::Vector3d::Zero());
}

const PoseQuery& StageContext::pose_query(const PoseOptions& options) {
  std::lock_guard<std::mutex> lock(pose_query_mutex_);  // built once, then only read
  if (!have_pose_query_) {
    // The described query is already canonical: its sensor frame is the canonical frame.
    pose_query_ = PoseQueryOf(db_, query_.preprocessed, options);
    have_pose_query_ = true;
  }
  return pose_query_;
}

const PointCloud& StageContext::ViewCloud(int view) {
  // Guarded: the pose stages' threads share the cache. An element's address stays valid
  // while others are inserted (std::unordered_map), so the reference outlives the lock.
  std::lock_guard<std::mutex> lock(clouds_mutex_);
  auto it = clouds_.find(view);
  if (it == clouds_.end()) {
    it = clouds_.emplace(view, PointCloud()).first;
    db_.ViewCloud(view, &it->second);
  }
  return it->second;
}

int StageContext::HammingTo(int view) const {
  return HammingDistance(coarse_.code.code(0), db_.index().code(view),
                         db_.index().words_per_code());
}

RankedView StageContext::Measure(int view_index, int hamming, const FineOptions& options) const {
  const DistanceScales& scales = db_.distance_scales();
  const int coarse_dim = db_.coarse_dim(), fine_dim = db_.fine_dim();
  const Eigen::Map<const Eigen::VectorXf> query_fine(query_.features.fine.data(), fine_dim);
  RankedView r;
  r.view = view_index;
  r.hamming = hamming;
  r.fine = (Eigen::Map<const Eigen::VectorXf>(db_.fine(view_index), fine_dim) - query_fine)
               .cwiseAbs()
               .sum();
  r.coarse = (Eigen::Map<const Eigen::VectorXf>(db_.coarse(view_index), coarse_dim) -
              coarse_.coarse)
                 .norm();
  r.size = std::abs(log_query_radius_ - std::log(std::max(1e-6f, db_.view(view_index).radius)));
  r.combined = options.fine_weight * r.fine / scales.fine +
               options.coarse_weight * r.coarse / scales.coarse +
               options.size_weight * r.size / scales.size;
  return r;
}

FineResult FineStage(StageContext* context, const RecognitionOptions& options) {
  const Database& db = context->db();
  const std::vector<HammingMatch>& matches = context->coarse().flagged;
  FineResult result;
  std::vector<RankedView>& ranked = result.ranked;
  ranked.resize(matches.size());
  for (size_t i = 0; i < matches.size(); ++i) {
    ranked[i] = context->Measure(matches[i].index, matches[i].hamming_distance, options.fine);
  }
  std::sort(ranked.begin(), ranked.end(), RankedBefore);
  const FineOptions& fine = options.fine;
  if (fine.signature_views > 0 && fine.signature_weight > 0.0 && !ranked.empty()) {
    const PoseQuery& q = context->pose_query(options.pose);
    const size_t count = std::min<size_t>(ranked.size(), fine.signature_views);
    for (size_t i = 0; i < count; ++i) {
      const ViewRecord& view = db.view(ranked[i].view);
      const PointCloud& cloud = context->ViewCloud(ranked[i].view);
      const std::vector<float> signature =
          ViewSignature(view.cam_from_model, view.centroid_in_model, view.radius, cloud.points,
                        cloud.normals, options.pose);
      const std::vector<RollHypothesis> rolls = EstimateRoll(q.signature, signature, options.pose);
      const double correlation = rolls.empty() ? 0.0 : rolls.front().correlation;
      ranked[i].combined += fine.signature_weight * (1.0 - correlation);
    }
    std::sort(ranked.begin(), ranked.begin() + count, RankedBefore);
  }
  for (size_t i = 0; i < ranked.size(); ++i) {
    ranked[i].fine_rank = static_cast<int>(i);
    result.index_of_view.emplace(ranked[i].view, static_cast<int>(i));
  }
  return result;
}

std::vector<RankedView> AllViewsOf(const StageContext& context, const FineResult& fine,
                                   int model_index, const FineOptions& options) {
  const ModelRecord& model = context.db().model(model_index);
  std::vector<RankedView> views;
  views.reserve(model.num_views);
  for (int v = model.first_view; v < model.first_view + model.num_views; ++v) {
    const auto it = fine.index_of_view.find(v);
    if (it != fine.index_of_view.end()) {
      views.push_back(fine.ranked[it->second]);
    } else {
      views.push_back(context.Measure(v, context.HammingTo(v), options));
    }
  }
  return views;
}

namespace {

// The heap order of LazyViewRanking's measured views: the first in ranking order on top.
bool RankedAfter(const RankedView& a, const RankedView& b) { return RankedBefore(b, a); }

}  // namespace

LazyViewRanking::LazyViewRanking(const StageContext& context, const FineResult& fine,
                                 const FineOptions& options)
    : context_(context),
      fine_(fine),
      options_(options),
      sketches_(context.db().view_sketches()),
      // Measure: combined = w_f · Σ|a − b| / s_f + w_c · ‖a − b‖ / s_c + w_s · size / s_s,
      // each term ≥ 0 with weights ≥ 0.
      bounded_(options.fine_weight >= 0.0 && options.coarse_weight >= 0.0 &&
               options.size_weight >= 0.0),
      flagged_(context.db().num_views(), -1),
      models_(context.db().num_models()) {
  for (size_t i = 0; i < fine.ranked.size(); ++i) {
    flagged_[fine.ranked[i].view] = static_cast<int>(i);
  }
}

double LazyViewRanking::LowerBound(int view) const {
  // The size term is left out (a log per view).
  if (!bounded_) return -std::numeric_limits<double>::infinity();
  const Database& db = context_.db();
  const ViewSketches& sketches = sketches_;
  const DistanceScales& scales = db.distance_scales();
  const int coarse_dim = db.coarse_dim(), fine_dim = db.fine_dim();
  const size_t v = static_cast<size_t>(view);
  const ViewSketches::Row& fine_row = sketches.fine_rows[v];
  const ViewSketches::Row& coarse_row = sketches.coarse_rows[v];
  // Each float sum less 1e-4 of it (its rounding stays below ~2e-5 of it over a few hundred
  // terms ≥ 0) is at most the exact distance to the quantised row; less the quantisation
  // error, at most the distance to the row (triangle inequality); the whole less 1e-4 of
  // it, at most what Measure computes in float.
  const double fine_bound =
      ViewSketches::L1To(sketches.fine_codes.data() + v * fine_dim, fine_row,
                         context_.query().features.fine.data(), fine_dim) *
          (1.0 - 1e-4) -
      fine_row.l1_error;
  const double coarse_bound =
      std::sqrt(ViewSketches::SquaredL2To(sketches.coarse_codes.data() + v * coarse_dim, coarse_row,
                                          context_.coarse().coarse.data(), coarse_dim) *
                (1.0 - 1e-4)) -
      coarse_row.l2_error;
  const double bound = options_.fine_weight * std::max(0.0, fine_bound) / scales.fine +
                       options_.coarse_weight * std::max(0.0, coarse_bound) / scales.coarse;
  // A row with NaN (not checked at open) gives no bound.
  if (std::isnan(bound)) return -std::numeric_limits<double>::infinity();
  return bound * (1.0 - 1e-4) - 1e-9;
}

void LazyViewRanking::Start(int model_index) {
  ModelViews& m = models_[model_index];
  m.started = true;
  const ModelRecord& model = context_.db().model(model_index);
  for (int v = model.first_view; v < model.first_view + model.num_views; ++v) {
    if (flagged_[v] >= 0) {
      m.pending.push_back(fine_.ranked[flagged_[v]]);
      std::push_heap(m.pending.begin(), m.pending.end(), RankedAfter);
    } else {
      m.bounds.emplace_back(LowerBound(v), v);
    }
  }
  // A heap, least bound on top: most models are asked only for their first views.
  std::make_heap(m.bounds.begin(), m.bounds.end(), std::greater<>());
}

const RankedView* LazyViewRanking::At(int model, int k) {
  ModelViews& m = models_[model];
  if (!m.started) Start(model);
  while (static_cast<int>(m.ranked.size()) <= k) {
    const bool bounds_left = !m.bounds.empty();
    // The first measured view is placed once no view left unmeasured can come before it:
    // each of those is at least its bound, the least of them on top of m.bounds.
    if (!m.pending.empty() &&
        (!bounds_left || m.pending.front().combined < m.bounds.front().first)) {
      std::pop_heap(m.pending.begin(), m.pending.end(), RankedAfter);
      m.ranked.push_back(m.pending.back());
      m.pending.pop_back();
      continue;
    }
    if (!bounds_left) return nullptr;
    std::pop_heap(m.bounds.begin(), m.bounds.end(), std::greater<>());
    const int v = m.bounds.back().second;
    m.bounds.pop_back();
    m.pending.push_back(context_.Measure(v, context_.HammingTo(v), options_));
    std::push_heap(m.pending.begin(), m.pending.end(), RankedAfter);
    ++measured_;
  }
  return &m.ranked[k];
}

ScreeningRequest PlanScreening(const StageContext& context, const FineResult& fine,
                               const RecognitionOptions& options) {
  const ScreeningOptions& screening = options.screening;
  ScreeningRequest request;
  for (const RankedView& r : fine.ranked) {
    if (static_cast<int>(request.models.size()) >= screening.models) break;
    const int model = context.db().view(r.view).model;
    if (std::find(request.models.begin(), request.models.end(), model) ==
        request.models.end()) {
      request.models.push_back(model);
    }
  }
  // The screening budget is models × views_per_model views: with fewer candidate models
  // (a small database, a pose-only query) each gets more views.
  request.views_per_model =
      std::max(screening.views_per_model,
               screening.models * screening.views_per_model /
                   std::max<int>(1, request.models.size()));
  request.rank_all_views = screening.rank_all_views;
  request.hypotheses = options.pose;
  return request;
}

std::vector<PoseCandidate> ScreenPoses(StageContext* context, const FineResult& fine,
                                       const ScreeningRequest& request,
                                       const RecognitionOptions& options, PoseMemo* memo) {
  const Database& db = context->db();
  const double min_separation_cos = std::cos(options.screening.view_separation);
  // The short ICP reaches the final gate two iterations before it ends, so its score is
  // taken at a settled pose.
  PoseOptions quick_options = options.pose;
  quick_options.gate_iterations = std::max(1, options.screening.quick_iterations - 2);
  // The views to screen, in order; then each screened (on options.threads threads), the
  // results kept in that order — the same answers for any thread count.
  std::vector<std::pair<int, RankedView>> jobs;  // model, view
  for (int model_index : request.models) {
    std::vector<RankedView> views;
    std::function<const RankedView*(int)> view_at;
    if (request.rank_all_views && request.ranking != nullptr) {
      view_at = [&](int k) { return request.ranking->At(model_index, k); };
    } else {
      if (request.rank_all_views) {
        views = AllViewsOf(*context, fine, model_index, options.fine);
      } else {
        for (const RankedView& r : fine.ranked) {
          if (db.view(r.view).model == model_index) views.push_back(r);
        }
      }
      std::sort(views.begin(), views.end(), RankedBefore);
      view_at = [&](int k) { return k < static_cast<int>(views.size()) ? &views[k] : nullptr; };
    }
    for (const RankedView& r :
         SeparatedViews(db, view_at, request.views_per_model, min_separation_cos)) {
      jobs.emplace_back(model_index, r);
    }
  }
  std::vector<PoseCandidate> screened(jobs.size());
  std::vector<uint8_t> found(jobs.size(), 0);
  std::vector<std::vector<PoseMemo::Screened>> run(jobs.size());
  // All views at once, or stop_chunk at a time until a hypothesis reaches stop_score (the
  // chunks fixed by the order, not by the threads: the same answers for any thread count).
  const bool stop = request.stop_score > 0.0;
  const size_t chunk = stop ? static_cast<size_t>(std::max(1, request.stop_chunk))
                            : std::max<size_t>(1, jobs.size());
  size_t done = 0;
  double best = 0.0;
  while (done < jobs.size() && !(stop && best >= request.stop_score)) {
    const size_t begin = done, count = std::min(chunk, jobs.size() - begin);
    RunJobs(options.threads, count, [&](size_t k) {
      const size_t j = begin + k;
      found[j] = ScreenView(context, jobs[j].second, jobs[j].first, request.hypotheses,
                            quick_options, options, memo, &screened[j], &run[j]);
    });
    for (size_t j = begin; j < begin + count; ++j) {
      if (found[j]) best = std::max(best, screened[j].alignment.score);
    }
    done = begin + count;
  }
  if (memo != nullptr) {
    for (size_t j = 0; j < done; ++j) {
      for (PoseMemo::Screened& entry : run[j]) memo->Add(std::move(entry));
    }
  }
  std::vector<PoseCandidate> out;
  for (size_t j = 0; j < done; ++j) {
    if (found[j]) out.push_back(std::move(screened[j]));
  }
  std::stable_sort(out.begin(), out.end(), [](const PoseCandidate& a, const PoseCandidate& b) {
    return a.alignment.score > b.alignment.score;
  });
  return out;
}

RefinementResult RefinePoses(StageContext* context, std::vector<PoseCandidate> candidates,
                             int count, const RecognitionOptions& options, PoseMemo* memo) {
  PoseOptions refine_options = options.pose;
  refine_options.gate_iterations = 2;
  RefinementResult result;
  result.candidates = std::move(candidates);
  // The best candidate of each of the first `count` distinct models (the choice does not
  // depend on the refinements), refined on options.threads threads.
  std::vector<int> refined_models;
  std::vector<PoseCandidate*> chosen;
  for (PoseCandidate& candidate : result.candidates) {
    if (static_cast<int>(refined_models.size()) >= count) break;
    if (std::find(refined_models.begin(), refined_models.end(), candidate.model) !=
        refined_models.end()) {
      continue;
    }
    refined_models.push_back(candidate.model);
    chosen.push_back(&candidate);
  }
  // Those the memo holds are copied; the others refined on options.threads threads.
  std::vector<PoseCandidate*> to_refine;
  std::vector<PoseMemo::Refined> keys;  // their starting state, for the memo
  for (PoseCandidate* candidate : chosen) {
    const PoseMemo::Refined* known =
        memo != nullptr ? memo->FindRefined(candidate->model, candidate->canonical_from_model,
                                            candidate->icp.iterations)
                        : nullptr;
    if (known != nullptr) {
      const PoseCandidate& r = known->result;
      candidate->view = r.view;
      candidate->canonical_from_model = r.canonical_from_model;
      candidate->icp = r.icp;
      candidate->alignment = r.alignment;
      candidate->refined = true;
      continue;
    }
    to_refine.push_back(candidate);
    keys.push_back({candidate->model, candidate->canonical_from_model, candidate->icp.iterations,
                    PoseCandidate()});
  }
  RunJobs(options.threads, to_refine.size(), [&](size_t j) {
    RefineCandidate(context, refine_options, options, to_refine[j]);
  });
  if (memo != nullptr) {
    for (size_t j = 0; j < to_refine.size(); ++j) {
      keys[j].result = *to_refine[j];
      memo->Add(std::move(keys[j]));
    }
  }
  for (const PoseCandidate* candidate : chosen) {
    result.best_score = std::max(result.best_score, candidate->alignment.score);
  }
  return result;
}

std::vector<PoseCandidate> WidenSearch(StageContext* context, const FineResult& fine,
                                       double best_score, int views_per_model,
                                       const RecognitionOptions& options, PoseMemo* memo) {
  // The best verification is too low to be the right model at the right pose, so the
  // descriptors (corrupted by occlusion) probably ranked the right model or its right
  // views too low, or the polar signature (about a centroid shifted by the occluder) gave
  // no right roll. The verification itself is reliable there — at the true pose the true
  // model scores ≈ 0.9 or more — so a broader hypothesis search fixes these queries.
  const WideningOptions& widening = options.widening;
  if (!(widening.below_score > 0.0 && best_score < widening.below_score &&
        widening.models > 0 && options.refinement.candidates > 0)) {
    return {};
  }
  const Database& db = context->db();
  std::vector<std::pair<double, int>> model_distance;  // best view's distance, model
  std::vector<int> pool = options.restrict_to_models;
  if (pool.empty()) {
    pool.resize(db.num_models());
    std::iota(pool.begin(), pool.end(), 0);
  }
  LazyViewRanking ranking(*context, fine, options.fine);
  for (int m : pool) {
    const RankedView* best = ranking.At(m, 0);
    model_distance.emplace_back(best ? best->combined : std::numeric_limits<double>::infinity(),
                                m);
  }
  std::sort(model_distance.begin(), model_distance.end());
  ScreeningRequest request;
  for (const auto& [distance, m] : model_distance) {
    if (static_cast<int>(request.models.size()) >= widening.models) break;
    request.models.push_back(m);
  }
  request.views_per_model = std::max(views_per_model, widening.views_per_model);
  request.rank_all_views = true;
  request.ranking = &ranking;
  request.hypotheses = options.pose;
  request.hypotheses.roll_hypotheses =
      std::min(std::max(options.pose.roll_hypotheses, widening.roll_hypotheses),
               options.pose.angle_bins / 2);
  request.stop_score = widening.screen_stop;  // stop_chunk: its default
  // In batches of batch_models models, in the order of their best views: each batch's
  // best hypotheses refined (its share of refine_candidates), and no further batch once
  // one of them verifies as the right model at the right pose would.
  const int num_models = static_cast<int>(request.models.size());
  const int batch = widening.batch_models > 0 ? std::min(widening.batch_models, num_models)
                                              : num_models;
  const int refine_per_batch =
      std::max(1, (widening.refine_candidates * batch + num_models - 1) / std::max(1, num_models));
  std::vector<PoseCandidate> wide;
  double best_so_far = best_score;
  ScreeningRequest part = request;
  for (int first = 0; first < num_models; first += batch) {
    part.models.assign(request.models.begin() + first,
                       request.models.begin() + std::min(num_models, first + batch));
    RefinementResult refined = RefinePoses(
        context, ScreenPoses(context, fine, part, options, memo),
        std::min(refine_per_batch, widening.refine_candidates), options, memo);
    for (PoseCandidate& candidate : refined.candidates) wide.push_back(std::move(candidate));
    if (refined.best_score >= widening.below_score) break;
    best_so_far = std::max(best_so_far, refined.best_score);
    if (best_so_far >= widening.continue_below) break;
  }
  return wide;
}

std::vector<PoseCandidate> EstimatePoses(StageContext* context, const FineResult& fine,
                                         const RecognitionOptions& options) {
  if (options.screening.models <= 0 || fine.ranked.empty()) return {};
  const ScreeningRequest request = PlanScreening(*context, fine, options);
  // The widened search and the class screening come back to what the first screening ran.
  PoseMemo memo;
  RefinementResult refined =
      RefinePoses(context, ScreenPoses(context, fine, request, options, &memo),
                  options.refinement.candidates, options, &memo);
  std::vector<PoseCandidate> posed = std::move(refined.candidates);
  for (PoseCandidate& candidate : WidenSearch(context, fine, refined.best_score,
                                              request.views_per_model, options, &memo)) {
    posed.push_back(std::move(candidate));
  }
  for (PoseCandidate& candidate : ScreenClasses(context, fine, posed, request.views_per_model,
                                                options, &memo)) {
    posed.push_back(std::move(candidate));
  }
  return posed;
}

std::vector<PoseCandidate> ScreenClasses(StageContext* context, const FineResult& fine,
                                         const std::vector<PoseCandidate>& posed,
                                         int views_per_model, const RecognitionOptions& options,
                                         PoseMemo* memo) {
  const AssemblyOptions& assembly = options.assembly;
  if (!assembly.class_ranking || assembly.class_screen_classes <= 0 ||
      options.screening.models <= 0 || options.refinement.candidates <= 0) {
    return {};
  }
  const Database& db = context->db();
  const int num_classes = static_cast<int>(db.classes().size());
  // Refined models per class so far.
  std::vector<int> refined_models;
  std::vector<int> missing(num_classes, assembly.class_screen_models);
  for (const PoseCandidate& candidate : posed) {
    if (!candidate.refined || std::find(refined_models.begin(), refined_models.end(),
                                        candidate.model) != refined_models.end()) {
      continue;
    }
    refined_models.push_back(candidate.model);
    --missing[db.model(candidate.model).class_index];
  }
  // The first class_screen_classes classes of the fine ranking (by their best view); each
  // one with fewer than class_screen_models refined models gets its next models (in the
  // order of their best views) screened.
  std::vector<int> classes_seen;
  ScreeningRequest request;
  for (const RankedView& r : fine.ranked) {
    const int model = db.view(r.view).model;
    const int c = db.model(model).class_index;
    if (std::find(classes_seen.begin(), classes_seen.end(), c) == classes_seen.end()) {
      if (static_cast<int>(classes_seen.size()) >= assembly.class_screen_classes) continue;
      classes_seen.push_back(c);
    }
    if (missing[c] <= 0 ||
        std::find(refined_models.begin(), refined_models.end(), model) != refined_models.end() ||
        std::find(request.models.begin(), request.models.end(), model) != request.models.end()) {
      continue;
    }
    --missing[c];
    request.models.push_back(model);
  }
  if (request.models.empty()) return {};
  request.views_per_model = views_per_model;
  request.rank_all_views = options.screening.rank_all_views;
  request.hypotheses = options.pose;
  std::vector<PoseCandidate> screened = ScreenPoses(context, fine, request, options, memo);
  // The best hypothesis of each screened model refined.
  return RefinePoses(context, std::move(screened), static_cast<int>(request.models.size()),
                     options, memo)
      .candidates;
}

std::vector<ClassScore> ScoreClasses(const StageContext& context, const FineResult& fine,
                                     const std::vector<PoseCandidate>& posed,
                                     const AssemblyOptions& options) {
  const Database& db = context.db();
  const int num_classes = static_cast<int>(db.classes().size());
  std::vector<ClassScore> scores(num_classes);
  std::vector<uint8_t> evidence(num_classes, 0);
  for (int c = 0; c < num_classes; ++c) {
    scores[c].class_index = c;
    scores[c].class_name = db.classes()[c];
  }
  // Verification: the best refined score of each model, then per class the mean of its
  // best class_models models (a class with fewer refined models counts the missing as 0).
  std::unordered_map<int, const AlignmentScore*> model_best;
  for (const PoseCandidate& candidate : posed) {
    if (!candidate.refined) continue;
    const AlignmentScore*& best = model_best.emplace(candidate.model, nullptr).first->second;
    if (best == nullptr || candidate.alignment.score > best->score) best = &candidate.alignment;
  }
  std::vector<std::vector<const AlignmentScore*>> class_models(num_classes);
  for (const auto& [model, alignment] : model_best) {
    class_models[db.model(model).class_index].push_back(alignment);
  }
  for (int c = 0; c < num_classes; ++c) {
    std::vector<const AlignmentScore*>& models = class_models[c];
    if (models.empty()) continue;
    std::sort(models.begin(), models.end(),
              [](const AlignmentScore* a, const AlignmentScore* b) { return a->score > b->score; });
    const int n = std::max(1, options.class_models);
    double sum = 0.0;
    for (int i = 0; i < n && i < static_cast<int>(models.size()); ++i) sum += models[i]->score;
    scores[c].verification = sum / n;
    scores[c].fit = models[0]->model_fit;
    scores[c].coverage = models[0]->query_coverage;
    scores[c].rms = models[0]->rms;
    evidence[c] = 1;
  }
  // Class-balanced vote of the first fine-ranked views.
  std::vector<int> class_views(num_classes, 0);
  for (int m = 0; m < db.num_models(); ++m) class_views[db.model(m).class_index] += db.model(m).num_views;
  const size_t voters = std::min<size_t>(fine.ranked.size(), std::max(0, options.class_vote_views));
  double total = 0.0;
  for (size_t i = 0; i < voters; ++i) {
    const int c = db.model(db.view(fine.ranked[i].view).model).class_index;
    const double share = static_cast<double>(class_views[c]) / std::max(1, db.num_views());
    const double vote = 1.0 / (static_cast<double>(i) + 1.0) / std::max(1e-9, share);
    scores[c].vote += vote;
    total += vote;
    evidence[c] = 1;
  }
  if (total > 0.0) {
    for (ClassScore& score : scores) score.vote /= total;
  }
  // Softmax over the classes with evidence.
  std::vector<ClassScore> out;
  for (int c = 0; c < num_classes; ++c) {
    if (evidence[c]) out.push_back(scores[c]);
  }
  ClassProbabilities(options, &out);
  return out;
}

void ClassProbabilities(const AssemblyOptions& options, std::vector<ClassScore>* classes) {
  std::vector<ClassScore>& out = *classes;
  if (out.empty()) return;
  const double temperature = std::max(1e-6, options.class_temperature);
  std::vector<double> z(out.size());
  for (size_t i = 0; i < out.size(); ++i) {
    z[i] = (out[i].verification + options.class_vote_weight * out[i].vote) / temperature;
  }
  const double z_max = *std::max_element(z.begin(), z.end());
  double sum = 0.0;
  for (size_t i = 0; i < out.size(); ++i) sum += (out[i].probability = std::exp(z[i] - z_max));
  for (ClassScore& score : out) score.probability /= sum;
  std::stable_sort(out.begin(), out.end(), [](const ClassScore& a, const ClassScore& b) {
    return a.probability > b.probability;
  });
}

Assembly AssembleSuggestions(StageContext* context, const FineResult& fine,
                             std::vector<PoseCandidate> posed, const RecognitionOptions& options) {
  const AssemblyOptions& assembly = options.assembly;
  Assembly result;
  if (assembly.class_ranking) {
    result.classes = ScoreClasses(*context, fine, posed, assembly);
    if (result.classes.size() >= 2 &&
        result.classes[0].probability - result.classes[1].probability <=
            assembly.ambiguity_margin) {
      result.ambiguous_with = result.classes[1].class_name;
    }
  }
  if (assembly.rerank_by_alignment) {
    const double penalty = assembly.ranking_penalty;
    std::stable_sort(posed.begin(), posed.end(),
                     [penalty](const PoseCandidate& a, const PoseCandidate& b) {
                       if (a.refined != b.refined) return a.refined;
                       return a.alignment.score - penalty * a.ranked.combined >
                              b.alignment.score - penalty * b.ranked.combined;
                     });
  }
  std::vector<Suggestion> ordered = OrderSuggestions(*context, fine, posed, assembly);
  if (!result.classes.empty()) {
    // The best suggestion of the most probable class first (with class grouping, the best
    // of each class in the order of the class probabilities); the rest keep their order.
    const size_t leading =
        options.grouping == SuggestionGrouping::kClass ? result.classes.size() : 1;
    auto next = ordered.begin();
    for (size_t k = 0; k < leading && next != ordered.end(); ++k) {
      const int c = result.classes[k].class_index;
      const auto first = std::find_if(next, ordered.end(),
                                      [c](const Suggestion& s) { return s.class_index == c; });
      if (first == ordered.end()) continue;
      std::rotate(next, first, first + 1);
      ++next;
    }
  }
  std::vector<int> seen;
  size_t cut = ordered.size();  // the suggestions after the cut to top_k start here
  for (size_t k = 0; k < ordered.size(); ++k) {
    Suggestion& s = ordered[k];
    if (static_cast<int>(result.suggestions.size()) >= options.top_k) {
      cut = k;
      break;
    }
    int key = -1;
    if (options.grouping == SuggestionGrouping::kModel) key = s.model;
    if (options.grouping == SuggestionGrouping::kClass) key = s.class_index;
    if (key >= 0) {
      if (std::find(seen.begin(), seen.end(), key) != seen.end()) continue;
      seen.push_back(key);
    }
    result.suggestions.push_back(std::move(s));
  }
  // The classes the cut left without a suggestion: their best posed ones (`ordered` keeps
  // each class's best first after the cut, as before it).
  for (const ClassScore& class_score : result.classes) {
    const int c = class_score.class_index;
    const auto has_class = [c](const Suggestion& s) { return s.class_index == c; };
    if (std::any_of(result.suggestions.begin(), result.suggestions.end(), has_class)) continue;
    const auto best = std::find_if(ordered.begin() + cut, ordered.end(),
                                   [c](const Suggestion& s) {
                                     return s.posed && s.class_index == c;
                                   });
    if (best != ordered.end()) result.other_class_poses.push_back(*best);
  }
  // Suggestions without a verified pose still get the roll about the line of sight (the
  // best signature correlation), so their pose is the unrefined estimate, not the bare
  // database view's.
  for (Suggestion& s : result.suggestions) {
    if (s.posed) continue;
    const ViewRecord& view = context->db().view(s.view);
    const PointCloud& cloud = context->ViewCloud(s.view);
    const std::vector<PoseHypothesis> hypotheses =
        InitialPoses(view.cam_from_model, view.centroid_in_model, view.radius, cloud.points,
                     cloud.normals, context->pose_query(options.pose), options.pose);
    if (hypotheses.empty()) continue;
    s.roll = hypotheses.front().roll.roll;
    s.cam_from_model = context->cam_from_canonical() * hypotheses.front().canonical_from_model;
  }
  // A verified best answer below the threshold is no known object.
  result.recognised = !result.suggestions.empty() &&
                      (!result.suggestions.front().posed ||
                       result.suggestions.front().score >= assembly.min_score);
  return result;
}

}  // namespace sope
