// The stages of Recogniser::Recognise, each callable alone (a test or a bench can run one
// stage on the outputs of the previous ones):
//
//   ViewDescription query = DescribeQuery(db, cloud);            // preprocess + features
//   CoarseResult coarse = CoarseStage(db, query, options);        // codes, Hamming search
//   StageContext context(db, query, coarse);                      // shared by the rest
//   FineResult fine = FineStage(&context, options);               // ranking of the flagged
//   ScreeningPlan plan = PlanScreening(context, fine, options);   // candidate models
//   std::vector<PoseCandidate> screened = ScreenPoses(&context, fine, plan.request, options);
//   RefinementResult refined = RefinePoses(&context, std::move(screened),
//                                          options.refinement.candidates, options);
//   std::vector<PoseCandidate> wide = WidenSearch(&context, fine, refined.best_score,
//                                                 plan.request.views_per_model, options);
//   Assembly answer = AssembleSuggestions(&context, fine, posed, options);
//
// EstimatePoses runs screening → refinement → widening as Recognise does. Every function
// is deterministic: the same inputs give bit-identical outputs.
#pragma once

#include <atomic>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "core/point_cloud.h"
#include "core/rigid3d.h"
#include "recogniser/database.h"
#include "recogniser/hamming_search.h"
#include "recogniser/hashing.h"
#include "recogniser/pose.h"
#include "recogniser/recogniser.h"
#include "recogniser/view_description.h"

namespace sope {

// The view of `model_index` whose camera direction (from the model centre) is closest to
// that of the pose `canonical_from_model` (the canonical frame shares the camera centre;
// any frame centred on the camera will do).
int NearestModelView(const Database& db, int model_index, const Rigid3d& canonical_from_model);

// Preprocess + canonical frame + features of the query, exactly as the database views
// were described (the database's stored options). Throws sope::Error on an unusable cloud
// or features of other dimensions than the database's.
ViewDescription DescribeQuery(const Database& db, const PointCloud& cloud);
// The pose query (roll, ICP, verification; recogniser/pose.h MakePoseQuery) of a cloud
// pre-processed with the database's options, at the database's voxel leaf (4 mm when it
// does not thin).
PoseQuery PoseQueryOf(const Database& db, const PreprocessedCloud& preprocessed,
                      const PoseOptions& options);

// Coarse stage output.
struct CoarseResult {
  Eigen::VectorXf coarse;             // the query's standardised coarse vector
  BinaryCodes code;                   // its code (the database's hasher)
  std::vector<HammingMatch> flagged;  // flagged views (restrict_to_models: all their views)
};
// Standardise, encode, Hamming search (k-best or radius; every view of
// restrict_to_models when given — throws sope::Error naming a model out of range).
CoarseResult CoarseStage(const Database& db, const ViewDescription& query,
                         const RecognitionOptions& options);

// A database view with its fine-stage distances to the query.
struct RankedView {
  int view = 0;
  int hamming = 0;
  double fine = 0.0, coarse = 0.0, size = 0.0;
  double combined = 0.0;  // Σ weight · distance / DistanceScales (+ signature term)
  int fine_rank = -1;     // position in the fine ranking of the flagged views, −1 if not flagged
};
// The ranking order: by combined distance, ties by view index.
bool RankedBefore(const RankedView& a, const RankedView& b);

// What the stages after the coarse one share: the database, the query, its codes, the
// canonical pose query (built on first use) and the decoded view clouds (each once).
// Keeps references: db, query and coarse must outlive it. pose_query and ViewCloud may be
// called from several threads.
class StageContext {
 public:
  StageContext(const Database& db, const ViewDescription& query, const CoarseResult& coarse);

  const Database& db() const { return db_; }
  const ViewDescription& query() const { return query_; }
  const CoarseResult& coarse() const { return coarse_; }
  // Rotation of the canonical query frame into the camera frame.
  Rigid3d cam_from_canonical() const;
  // The canonical query for roll, ICP and verification (built with `options` on the
  // first call; later calls return the same).
  const PoseQuery& pose_query(const PoseOptions& options);
  // Decoded cloud of a database view (model frame, farthest-point order).
  const PointCloud& ViewCloud(int view);
  // Hamming distance of a database view's code to the query's.
  int HammingTo(int view) const;
  // Fine-stage distances of a database view (no signature term).
  RankedView Measure(int view, int hamming, const FineOptions& options) const;

 private:
  const Database& db_;
  const ViewDescription& query_;
  const CoarseResult& coarse_;
  double log_query_radius_ = 0.0;
  PoseQuery pose_query_;
  bool have_pose_query_ = false;
  // pose_query and ViewCloud are called from the pose stages' threads
  // (RecognitionOptions::threads): each cache has its own lock.
  std::mutex pose_query_mutex_;
  std::unordered_map<int, PointCloud> clouds_;
  std::mutex clouds_mutex_;
};

// Fine stage output.
struct FineResult {
  std::vector<RankedView> ranked;              // best first; fine_rank = position
  std::unordered_map<int, int> index_of_view;  // view → index into `ranked`
};
// Ranks the flagged views (FineOptions; the polar-signature term for the first
// signature_views when weighted).
FineResult FineStage(StageContext* context, const RecognitionOptions& options);
// Every view of `model` with its fine-stage distances (flagged ones as ranked).
std::vector<RankedView> AllViewsOf(const StageContext& context, const FineResult& fine,
                                   int model, const FineOptions& options);

// Every model's views in ranking order (RankedBefore) with the distances AllViewsOf gives
// them, produced as asked: each view not flagged is bounded from below by its quantised
// rows (Database::view_sketches) and measured only once that bound no longer puts it behind
// the views measured before — the same views in the same order as sorting AllViewsOf,
// without reading most views' rows (the widened search ranks every model of the database
// by its best view, then screens the best views of a few). One thread at a time.
class LazyViewRanking {
 public:
  LazyViewRanking(const StageContext& context, const FineResult& fine,
                  const FineOptions& options);
  // The k-th view of `model` in ranking order (k ≥ 0), or null past its last; valid until
  // the next call.
  const RankedView* At(int model, int k);
  // Views measured so far (the flagged ones are not measured again).
  int measured() const { return measured_; }

 private:
  struct ModelViews {
    bool started = false;
    // The views not yet measured with their lower bounds: a heap, least bound on top.
    std::vector<std::pair<double, int>> bounds;
    std::vector<RankedView> pending;  // measured, not yet placed: a heap, first on top
    std::vector<RankedView> ranked;   // placed, in ranking order
  };
  void Start(int model);
  // A lower bound on Measure(view)'s combined distance (−∞ when the weights give none).
  double LowerBound(int view) const;

  const StageContext& context_;
  const FineResult& fine_;
  const FineOptions options_;
  const ViewSketches& sketches_;  // the database's, made on first use
  const bool bounded_;            // the weights ≥ 0: LowerBound has a bound to give
  std::vector<int> flagged_;  // view → index into fine_.ranked, −1 when not flagged
  std::vector<ModelViews> models_;
  int measured_ = 0;
};

// A pose hypothesis during the pose stages.
struct PoseCandidate {
  RankedView ranked;  // the view it started from
  int view = 0;       // the view whose cloud the pose and score refer to
  int model = 0;
  Rigid3d canonical_from_model;
  double roll = 0.0;
  IcpResult icp;
  AlignmentScore alignment;
  bool refined = false;
};

// The short ICPs and refinements already run for one query with one set of options. The
// widened search and the class screening come back to views, roll hypotheses and
// candidates that the first screening ran (the models it screened, their first views, the
// first of their rolls — a longer roll list starts with the shorter one), whose results
// are the same: with a memo they are looked up, not run again, and the answers are
// bit-identical. Keyed by view (model) and the exact starting pose; EstimatePoses keeps
// one for its stages. Not for reuse across queries or options.
class PoseMemo {
 public:
  struct Screened {
    int view = 0;
    Rigid3d initial;  // the roll hypothesis' pose
    IcpResult icp;
    AlignmentScore alignment;
  };
  struct Refined {
    int model = 0;
    Rigid3d initial;      // the screened pose
    int quick_iterations = 0;
    PoseCandidate result;  // its refined view, pose, ICP and verification
  };
  // nullptr when not run yet.
  const Screened* FindScreened(int view, const Rigid3d& initial) const;
  const Refined* FindRefined(int model, const Rigid3d& initial, int quick_iterations) const;
  // Not thread-safe: the stages add after their parallel jobs, from the calling thread.
  void Add(Screened screened);
  void Add(Refined refined);
  size_t screened_hits() const { return screened_hits_; }
  size_t refined_hits() const { return refined_hits_; }

 private:
  std::unordered_map<int, std::vector<Screened>> screened_;  // by view
  std::vector<Refined> refined_;
  mutable std::atomic<size_t> screened_hits_{0}, refined_hits_{0};
};

// Which models get pose hypotheses, how many views each, ranked how, with which roll
// hypotheses.
struct ScreeningRequest {
  std::vector<int> models;
  int views_per_model = 0;
  bool rank_all_views = false;
  // With rank_all_views: the caller's ranking of every model's views (its views taken from
  // it as far as needed); null: each model's are all measured (AllViewsOf).
  LazyViewRanking* ranking = nullptr;
  PoseOptions hypotheses;
  // > 0: the views are screened stop_chunk at a time in the request's order (model by
  // model, each model's views best-ranked first), and no further chunk once a hypothesis
  // has scored at least stop_score; 0: all of them. 4: two views per thread on two cores
  // between the checks (the widened search's batches).
  double stop_score = 0.0;
  int stop_chunk = 4;
};
// The first ScreeningOptions::models distinct models of the fine ranking; the budget of
// models × views_per_model views shared among them (fewer models: more views each).
ScreeningRequest PlanScreening(const StageContext& context, const FineResult& fine,
                               const RecognitionOptions& options);
// Per model of the request: its views ranked, up to views_per_model of them at least
// view_separation apart; roll hypotheses and a short ICP on a prefix of each view's
// cloud; the best hypothesis per view. Sorted by score, best first (stable). With
// request.stop_score, only the views up to the chunk that reached it.
// With a memo: short ICPs it holds are looked up, and those run are added to it.
std::vector<PoseCandidate> ScreenPoses(StageContext* context, const FineResult& fine,
                                       const ScreeningRequest& request,
                                       const RecognitionOptions& options,
                                       PoseMemo* memo = nullptr);

struct RefinementResult {
  std::vector<PoseCandidate> candidates;  // as given; the refined ones marked `refined`
  double best_score = 0.0;                // best verification score of the refined ones
};
// Refines the best hypothesis of the first `count` distinct models of `candidates`
// (sorted by their short-ICP score): ICP with the stored view nearest to the current
// pose, repeated once the pose has settled, and the full verification with that view.
// With a memo, as ScreenPoses.
RefinementResult RefinePoses(StageContext* context, std::vector<PoseCandidate> candidates,
                             int count, const RecognitionOptions& options,
                             PoseMemo* memo = nullptr);

// The widened search (WideningOptions) when `best_score` is below its threshold: more
// models (by their best view over the whole database), all views ranked, more views and
// rolls each, refined. Empty when not triggered.
std::vector<PoseCandidate> WidenSearch(StageContext* context, const FineResult& fine,
                                       double best_score, int views_per_model,
                                       const RecognitionOptions& options,
                                       PoseMemo* memo = nullptr);

// With class ranking (AssemblyOptions::class_screen_*): each of the first
// class_screen_classes classes of the fine ranking with fewer than class_screen_models
// refined models among `posed` gets its next models (by their best flagged view) screened
// (views_per_model views each) and the best hypothesis of each refined, so that every class
// the descriptors rank high is judged by the verification of as many of its models, not
// only the classes of the first models. Empty when off.
std::vector<PoseCandidate> ScreenClasses(StageContext* context, const FineResult& fine,
                                         const std::vector<PoseCandidate>& posed,
                                         int views_per_model, const RecognitionOptions& options,
                                         PoseMemo* memo = nullptr);

// Screening → refinement → widening → class screening: every pose candidate (empty when
// ScreeningOptions::models is 0 or nothing was flagged).
std::vector<PoseCandidate> EstimatePoses(StageContext* context, const FineResult& fine,
                                         const RecognitionOptions& options);

// Class scores (AssemblyOptions::class_*) from the refined candidates among `posed` and
// the first class_vote_views views of the fine ranking: every class with evidence, most
// probable first (ties by class index).
std::vector<ClassScore> ScoreClasses(const StageContext& context, const FineResult& fine,
                                     const std::vector<PoseCandidate>& posed,
                                     const AssemblyOptions& options);

// The classes' probabilities: the softmax over `classes` of (verification +
// class_vote_weight × vote) / class_temperature; then sorted most probable first (ties in
// their order).
void ClassProbabilities(const AssemblyOptions& options, std::vector<ClassScore>* classes);

struct Assembly {
  std::vector<Suggestion> suggestions;  // best first, at most top_k
  bool recognised = false;              // see RecognitionResult::recognised
  std::vector<ClassScore> classes;      // see RecognitionResult::classes
  std::string ambiguous_with;           // see RecognitionResult::ambiguous_with
  std::vector<Suggestion> other_class_poses;  // see RecognitionResult::other_class_poses
};
// Posed candidates first (re-ranked by AssemblyOptions), then the rest of the fine
// ranking; with class ranking the best suggestion of the most probable class moved to the
// front; grouped, cut to top_k; unposed suggestions get their best roll; the verification
// threshold decides `recognised`.
Assembly AssembleSuggestions(StageContext* context, const FineResult& fine,
                             std::vector<PoseCandidate> posed, const RecognitionOptions& options);

}  // namespace sope
