// Simultaneous object recognition and pose estimation (thesis §4.6–4.7): a partial view
// of an object is compared with a database of models seen from many viewpoints, and the
// best matches name the object's class, model and viewpoint together; the pose follows
// from the matched view, the roll about the line of sight and ICP.
//
// Pipeline of Recogniser::Recognise (per-stage times in RecognitionTimings):
//  1. preprocess — Preprocess + canonical frame (DescribeView, exactly as the database
//     views were built, with the options stored in the database);
//  2. features — ComputeFeatures (coarse vector, fine descriptor);
//  3. coarse — standardise the coarse vector, encode it with the database's hasher, and
//     flag database views by Hamming distance: the k nearest codes (k =
//     max(min_flagged, flag_fraction · views)) or, as in the thesis, all codes within a
//     radius;
//  4. fine — rank the flagged views by a weighted sum of three distances, each in units
//     of its typical value between unrelated views (DistanceScales): L1 between the fine
//     descriptors (VFH), Euclidean between the standardised coarse vectors, and
//     |log(radius ratio)| (metric size agreement — a structured-light scan is metric);
//  5. pose — for the best-ranked views (a few per model): roll hypotheses from polar
//     signatures, a short ICP from each and a verification score; the best hypotheses get
//     a full ICP and are re-ranked by how well model and query explain each other
//     (recogniser/pose.h). This verification is what makes the first suggestion reliable
//     when several models share a look from some viewpoints. When even the best refined
//     hypothesis verifies poorly, the search is widened once (more models, views, rolls;
//     WideningOptions::below_score);
//  6. assembly — re-ranking, grouping, top-k, and "no known object" below
//     AssemblyOptions::min_score.
// Each stage is a function of recogniser/stages.h that can be called alone.
// The result lists the top-k suggestions (one per model by default), each with class,
// model, viewpoint, scores and the 6-DoF pose cam_from_model.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "core/enum_strings.h"
#include "core/options.h"
#include "core/point_cloud.h"
#include "core/rigid3d.h"
#include "recogniser/database.h"
#include "recogniser/pose.h"

namespace sope {

enum class CoarseSearch {
  kKBest,   // "kbest": the k nearest codes
  kRadius,  // "radius": every code within radius_fraction · bits (thesis)
};
template <>
struct EnumTable<CoarseSearch> {
  static constexpr const char* kWhat = "coarse search";
  static constexpr EnumName<CoarseSearch> kNames[] = {{CoarseSearch::kKBest, "kbest"},
                                                     {CoarseSearch::kRadius, "radius"}};
};
std::string ToString(CoarseSearch search);
CoarseSearch CoarseSearchFromString(const std::string& text);

// What makes two suggestions different.
enum class SuggestionGrouping {
  kModel,  // "model": the best view of each model (default)
  kView,   // "view": any database entries, as the thesis listed them
  kClass,  // "class": the best model of each class
};
template <>
struct EnumTable<SuggestionGrouping> {
  static constexpr const char* kWhat = "suggestion grouping";
  static constexpr EnumName<SuggestionGrouping> kNames[] = {{SuggestionGrouping::kModel, "model"},
                                                           {SuggestionGrouping::kView, "view"},
                                                           {SuggestionGrouping::kClass, "class"}};
};
std::string ToString(SuggestionGrouping grouping);
SuggestionGrouping SuggestionGroupingFromString(const std::string& text);

// Options of each stage (recogniser/stages.h). Every field is described once in the
// struct's Fields() (name, doc, unit, valid range, CLI flag; core/options.h), which drives
// Check(), the CLI flags of `recognise` / `eval` and JSON.

// Coarse stage: which database views are flagged by the Hamming distance of their codes.
struct CoarseOptions {
  CoarseSearch search = CoarseSearch::kKBest;
  double flag_fraction = 0.03;  // kKBest: fraction of the database flagged …
  int min_flagged = 48;         // … but at least this many views (small databases)
  double radius_fraction = 0.25;  // kRadius: Hamming radius as a fraction of the code length
  // kKBest: an external coarse index to search instead of the database's Hamming index
  // (e.g. FaissCoarseIndex::KBestSearch over the same codes); (query code words, k) →
  // matches sorted by distance, ties by view index. Empty: the database's own index.
  std::function<std::vector<HammingMatch>(const uint64_t* code, int k)> coarse_kbest;
  static const std::vector<OptionField<CoarseOptions>>& Fields();
  void Check() const;
};

// Fine stage: ranking distance = Σ weight · distance / DistanceScales. The coarse vector
// already holds the metric size block (FeatureOptions::metric_size), so the separate
// size term is off by default: on held-out instance queries with occlusion it pushed
// the first view of the right model from rank ≤ 1 to rank ≤ 44 at the 95th percentile
// (the normalisation radius shrinks when part of the object is hidden).
struct FineOptions {
  double fine_weight = 1.0;
  double coarse_weight = 1.0;
  double size_weight = 0.0;
  // Then the best signature_views of them are re-ranked with the polar-signature
  // correlation added: + signature_weight · (1 − best correlation over rolls). The
  // signature (silhouette, depth and normal layout about the line of sight) is not
  // mirror-invariant, unlike the histogram descriptors.
  int signature_views = 0;
  double signature_weight = 0.0;
  static const std::vector<OptionField<FineOptions>>& Fields();
  void Check() const;  // also: the weights not all 0
};

// Pose screening. The first `models` distinct models of the fine ranking are candidates;
// each one's views are ranked with the same distance (all its views when rank_all_views,
// else its flagged ones) and up to views_per_model of them, at least view_separation
// (radians between viewing directions) apart, get roll hypotheses and a short ICP of
// quick_iterations (with fewer candidate models than `models`, each gets a
// proportionally larger share of the models · views_per_model views). 0 `models` skips
// ICP and verification: suggestions then carry the unrefined pose (database view, best
// roll, centroids aligned).
struct ScreeningOptions {
  int models = 8;
  int views_per_model = 4;
  double view_separation = 0.6;
  bool rank_all_views = false;
  int quick_iterations = 5;
  // The short ICP and its score use the first quick_points points of the view cloud
  // (stored in farthest-point order, so any prefix is an even subsample) and
  // quick_coverage_samples query points.
  int quick_points = 64;
  int quick_coverage_samples = 128;
  static const std::vector<OptionField<ScreeningOptions>>& Fields();
  void Check() const;
};

// Refinement: the best hypothesis of up to `candidates` models gets up to `passes` ICP
// runs of `iterations`, each with the stored view nearest to the current pose (a dense
// database has one within a few degrees), starting from a gate of initial_gate metres;
// then the full verification with the view nearest to the final pose.
struct RefinementOptions {
  int candidates = 6;
  int passes = 2;
  int iterations = 12;
  double initial_gate = 0.015;
  static const std::vector<OptionField<RefinementOptions>>& Fields();
  void Check() const;
};

// Widened search: when the best verification score after refinement is below
// below_score (the right model at the right pose scores ≈ 0.9 or more, even with a
// quarter of it hidden), the hypotheses probably missed it — occlusion corrupts the
// descriptors (the right model or its right views rank too low) and the polar signature
// (its centroid shifts), not the verification. The pose search then runs again with the
// first `models` models by their best view over the whole database (or over
// restrict_to_models), all views of each ranked, views_per_model views per model and
// roll_hypotheses rolls per view, and the best hypotheses of refine_candidates models are
// refined; all refined hypotheses compete in the final order. Costs time only on such
// queries (instance evaluation: median time unchanged, 95th percentile ≈ 13 → 23 ms).
// 0 below_score or models, or 0 RefinementOptions::candidates: off.
struct WideningOptions {
  double below_score = 0.85;
  int models = 12;
  int views_per_model = 8;
  int roll_hypotheses = 3;
  int refine_candidates = 6;
  // The widened models are screened batch_models at a time (in the order of their best
  // views), each batch's best hypotheses refined (its share of refine_candidates), and the
  // search stops after a batch whose refined hypotheses reach below_score. 0: all models at
  // once, refine_candidates of them refined. Instance protocol (190 queries, up to 25%
  // hidden): model top-1 99.5% and pose errors unchanged from 0; p95 CPU time per query
  // 27.6–31.5 → 19.5–22 ms for 2–6 (median unchanged).
  int batch_models = 4;
  // Batches after the first only while the best verification so far (the first pass's
  // included) is below continue_below: an answer that explains this much of the query and
  // that the first batch (the closest models by their best views) did not beat is the
  // right model seen through heavy occlusion, not a miss (instance protocol: of 15
  // widened queries, 6 ran all three batches without a better answer — 5 of them from
  // 0.71–0.82 — while the 2 answers found after the first batch started from 0.39 and
  // 0.50). ≥ below_score: every batch.
  double continue_below = 0.7;
  // A batch's views are screened a few at a time (model by model in the batch's order, each
  // model's best-ranked views first), and the rest of the batch is not screened once a
  // short-ICP hypothesis scores at least screen_stop: that model is refined with the others
  // screened so far (0: every view of the batch). Instance protocol (190 queries, up to 25%
  // hidden): the same answers as 0 (at 0.85 and 0.9), the widened screening's CPU time
  // 84.5 → 63.1 ms over the 15 widened queries.
  double screen_stop = 0.9;
  static const std::vector<OptionField<WideningOptions>>& Fields();
  void Check() const;
};

// Assembly of the answer.
struct AssemblyOptions {
  // Final order: by alignment score (verification), ties and unposed suggestions by the
  // ranking distance. false keeps the fine-stage order.
  bool rerank_by_alignment = true;
  // The re-ranking key is the alignment score minus ranking_penalty × the ranking distance
  // of the view the pose search started from (descriptor similarity as a tie-breaker
  // between models that fit about equally well).
  double ranking_penalty = 0.0;
  // "No known object" below this verification score: when the best suggestion was posed
  // and verified (ScreeningOptions::models > 0) but its alignment score is below
  // min_score, RecognitionResult::recognised is false (JSON "class": null, the best
  // guess only among the candidates; CLI "no known object"). Uniform noise and a line of
  // points score 0.000; the right model at the right pose ≈ 0.9 (see
  // WideningOptions); on the instance evaluation (190 queries, up to 25% hidden) the
  // lowest-scoring correct first answer scored 0.71. Unseen instances of known classes
  // score lower: on a small class-protocol run (1 training instance per class, 60 views,
  // 60 queries) 1 of 36 class-correct answers scored below 0.3 (0.26). 0: every answer
  // stands.
  double min_score = 0.3;
  // Class-aware ranking (RecognitionResult::classes): every class gets a score from two
  // kinds of evidence — the verification of its best refined hypothesis (the mean over its
  // best class_models models), and a class-balanced vote of the first class_vote_views
  // views of the fine ranking (weight 1/(rank+1), divided by the class's share of the
  // database's views) — combined as z = verification + class_vote_weight · vote and turned
  // into probabilities by a softmax of z / class_temperature. With class_ranking the first
  // suggestion is the best one of the most probable class. A second class whose
  // probability is within ambiguity_margin of the first's is named in
  // RecognitionResult::ambiguous_with. Tuned on the class protocol (default database of 8
  // instances per class, 60 depth-rendered queries of 20 unseen instances, seeds 2000–2001,
  // up to 25% hidden): class top-1 88.3% without, 93.3% with; the mean of the best 2 models
  // (83.3%) and vote weights 0.2–0.5 (88–92%) did worse — among 8 instances of a class
  // usually only one fits an unseen one closely. With class screening the vote weight was
  // retuned on 180 depth-rendered queries of 30 other unseen instances (seeds 2000–2002, 6
  // each, up to 25% hidden; the same stored class scores re-combined): weight 0 → 87.2%
  // top-1, 0.02–0.05 → 88.3%, 0.1 and 0.2 → 86.1%.
  bool class_ranking = true;
  int class_models = 1;
  int class_vote_views = 24;
  double class_vote_weight = 0.05;
  double class_temperature = 0.05;
  double ambiguity_margin = 0.25;
  // Class screening (stages.h ScreenClasses): each of the first class_screen_classes
  // classes of the fine ranking gets refined hypotheses of at least class_screen_models of
  // its models (its next models by their best flagged view) when the pose search gave it
  // fewer. 0 class_screen_classes: off (the class ranking of issue 16's first step).
  // Two models per screened class since the default database holds 16 instances per class
  // (class protocol scanned with the occluder, 16 training instances, 180 queries each:
  // tuning seeds 2000–2002 top-2 93.3% → 95.0%, held-out seeds 1000–1002 96.7% → 97.8%,
  // top-1 unchanged (87.8%, 91.1%); median CPU per query +8–12%, in the pose stage).
  int class_screen_classes = 4;
  int class_screen_models = 2;
  static const std::vector<OptionField<AssemblyOptions>>& Fields();
  void Check() const;
};

struct RecognitionOptions {
  // Suggestions returned.
  int top_k = 4;
  SuggestionGrouping grouping = SuggestionGrouping::kModel;
  // Threads of the pose stages: the views screened and the candidates refined in
  // parallel (the calling thread and threads − 1 more; each view's hypotheses and each
  // candidate's refinement are independent), the results kept in order — the answers are
  // the same for any count. 1 for figures in CPU time per query (evaluation); the live
  // loop's last frame → result can use the cores the capture no longer needs. A tabletop
  // scene (SceneRecogniser) with several clusters recognises them side by side instead,
  // each on one thread.
  int threads = 1;
  // Pose-only queries (thesis §5, the object known): when not empty, only these database
  // models are considered and all their views are ranked (no coarse search).
  std::vector<int> restrict_to_models;

  CoarseOptions coarse;
  FineOptions fine;
  ScreeningOptions screening;
  RefinementOptions refinement;
  WideningOptions widening;
  AssemblyOptions assembly;
  PoseOptions pose;  // roll hypotheses, ICP and verification (all pose stages)

  // The thesis's query: radius search (15% of the code length for MLH/BRE, 25% SH, 50%
  // LSH — pass the method), fine ranking by VFH and the radial distribution only, no pose
  // refinement, database entries listed as they rank.
  static RecognitionOptions ThesisPreset(HashMethod method);
  // Every field but restrict_to_models, named "coarse.flag_fraction", "pose.empty_weight"…
  static const std::vector<OptionField<RecognitionOptions>>& Fields();
  // Throws sope::Error naming the first invalid value.
  void Check() const;
};

struct Suggestion {
  // Database view: for a posed suggestion the model's view nearest to the estimated pose
  // (so `viewpoint` is the estimate's, to the database's spacing); the fine-stage distances
  // below are those of the view the pose search started from.
  int view = -1;
  int model = -1;        // database model index
  int class_index = -1;  // into Database::classes()
  std::string model_name;
  std::string class_name;
  Viewpoint viewpoint;  // of the database view (radians)
  int hamming_distance = 0;
  // Fine-stage distances (raw) and their weighted combination (lower is better), and the
  // rank of the view in the fine stage (0 = best).
  double fine_distance = 0.0;
  double coarse_distance = 0.0;
  double size_distance = 0.0;
  double ranking_distance = 0.0;
  int fine_rank = 0;  // −1: found by the per-model view search, not among the flagged views
  // Pose: X_cam = R·X_model + t, metres. `posed`: roll + (at least a short) ICP ran and
  // the pose was verified; `refined`: the full ICP ran. Otherwise the unrefined estimate
  // (database view turned by the best roll, centroids aligned).
  Rigid3d cam_from_model;
  bool posed = false;
  bool refined = false;
  bool converged = false;
  double roll = 0.0;  // radians, about the line of sight
  int icp_iterations = 0;
  double icp_rms = 0.0;  // metres
  AlignmentScore alignment;
  // Confidence in [0, 1]: the alignment score (model fit × query coverage) for posed
  // suggestions, 0 otherwise.
  double score = 0.0;
};

// Milliseconds per stage: wall-clock time, and the calling thread's CPU time (the same
// unless the machine is busy — compare CPU times on shared machines).
struct RecognitionTimings {
  double preprocess = 0.0;
  double features = 0.0;
  double coarse = 0.0;
  double fine = 0.0;
  double pose = 0.0;
  double total = 0.0;
  double preprocess_cpu = 0.0;
  double features_cpu = 0.0;
  double coarse_cpu = 0.0;
  double fine_cpu = 0.0;
  double pose_cpu = 0.0;
  double total_cpu = 0.0;
};

// The evidence for one class (AssemblyOptions, class-aware ranking).
struct ClassScore {
  int class_index = -1;  // into Database::classes()
  std::string class_name;
  double probability = 0.0;   // softmax of the combined evidence over the classes
  double verification = 0.0;  // mean verification score of its best refined models (0: none)
  double vote = 0.0;          // class-balanced vote share of the fine ranking, in [0, 1]
  // The best refined model's verification parts (AlignmentScore; 0 without one): model fit,
  // query coverage, and the RMS distance of its fitting points (metres).
  double fit = 0.0, coverage = 0.0, rms = 0.0;
};

struct RecognitionResult {
  std::vector<Suggestion> suggestions;  // best first, at most top_k
  // Every class with evidence, most probable first (empty when class ranking is off).
  std::vector<ClassScore> classes;
  // The second class when its probability is within AssemblyOptions::ambiguity_margin of
  // the first's, else empty.
  std::string ambiguous_with;
  // Per class of `classes` that none of `suggestions` is of, its best suggestion with a
  // verified pose, when it has one (the class screening posed it, but the cut to top_k
  // left it out): for callers that look at other classes' poses (a tabletop's other-class
  // looks). Not part of the answer.
  std::vector<Suggestion> other_class_poses;
  // False when the best suggestion's verification score is below
  // AssemblyOptions::min_score: "no known object", the suggestions are only guesses.
  bool recognised = false;
  int query_points = 0;                 // after pre-processing
  float query_radius = 0.0f;            // normalisation radius, metres
  int database_views = 0;
  int flagged = 0;  // views the coarse search flagged
  double flagged_fraction = 0.0;
  int posed = 0;  // views that got a pose hypothesis
  RecognitionTimings timing;

  bool empty() const { return suggestions.empty(); }
  const Suggestion& best() const { return suggestions.front(); }
  // Several lines: the suggestions with class, model, viewpoint, score and pose, and the
  // stage times.
  std::string BriefReport() const;
};

// One JSON object (one line, DESIGN.md "Recognition result"): the best suggestion's
// class, model, score, view (degrees), pose (cam_from_model: rotation 3×3 row by row,
// translation metres), refined, timing_ms per stage, flagged and flagged_fraction, and
// "candidates": every suggestion with the same fields plus its distances; "recognised".
// Not recognised: "class" and "model" are null, "score" is the best guess's, no
// view/pose at the top level (the guesses are in "candidates"). With class ranking:
// "classes" (RecognitionResult::classes, most probable first: "class", "score" = its
// probability, "verification", "vote") and "ambiguous_with" (a class name, or null).
std::string RecognitionResultToJson(const RecognitionResult& result);

class Recogniser {
 public:
  // Keeps a reference: `database` must outlive the recogniser.
  explicit Recogniser(const Database& database);

  // Recognises the object in `cloud` (sensor frame, metres; normals and colours ignored).
  // Single-threaded; safe to call concurrently. Throws sope::Error on invalid options or
  // an unusable cloud (empty, no finite point, too few points after pre-processing — the
  // message says which).
  RecognitionResult Recognise(const PointCloud& cloud, const RecognitionOptions& options = {}) const;

  const Database& database() const { return database_; }

 private:
  const Database& database_;
};

}  // namespace sope
