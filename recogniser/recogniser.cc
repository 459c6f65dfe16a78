#include "recogniser/recogniser.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/stopwatch.h"
#include "core/units.h"
#include "recogniser/stages.h"
#include "recogniser/view_description.h"

namespace sope {
namespace {


nlohmann::json SuggestionToJson(const Suggestion& s) {
  nlohmann::json rotation = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) {
    rotation.push_back({s.cam_from_model.rotation(r, 0), s.cam_from_model.rotation(r, 1),
                        s.cam_from_model.rotation(r, 2)});
  }
  return {{"class", s.class_name},
          {"model", s.model_name},
          {"score", s.score},
          {"view",
           {{"index", s.view},
            {"theta_deg", s.viewpoint.theta * kRadToDeg},
            {"phi_deg", s.viewpoint.phi * kRadToDeg}}},
          {"pose",
           {{"rotation", rotation},
            {"translation",
             {s.cam_from_model.translation.x(), s.cam_from_model.translation.y(),
              s.cam_from_model.translation.z()}}}},
          {"refined", s.refined},
          {"roll_deg", s.roll * kRadToDeg},
          {"hamming_distance", s.hamming_distance},
          {"fine_distance", s.fine_distance},
          {"coarse_distance", s.coarse_distance},
          {"size_distance", s.size_distance},
          {"ranking_distance", s.ranking_distance},
          {"fine_rank", s.fine_rank},
          {"icp_rms_m", s.icp_rms},
          {"model_fit", s.alignment.model_fit},
          {"query_coverage", s.alignment.query_coverage}};
}

}  // namespace

std::string ToString(CoarseSearch search) { return EnumToString(search); }
CoarseSearch CoarseSearchFromString(const std::string& text) {
  return EnumFromString<CoarseSearch>(text);
}
std::string ToString(SuggestionGrouping grouping) { return EnumToString(grouping); }
SuggestionGrouping SuggestionGroupingFromString(const std::string& text) {
  return EnumFromString<SuggestionGrouping>(text);
}

const std::vector<OptionField<CoarseOptions>>& CoarseOptions::Fields() {
  using O = CoarseOptions;
  static const std::vector<OptionField<O>> fields = {
      Field(&O::search, "search", "Coarse search: the k nearest codes or all within a radius"),
      Field(&O::flag_fraction, "flag_fraction", "Fraction of the database flagged (kbest)")
          .Above(0.0)
          .AtMost(1.0)
          .Flag("--flag-fraction"),
      Field(&O::min_flagged, "min_flagged", "Views flagged at least (kbest)").AtLeast(1),
      Field(&O::radius_fraction, "radius_fraction",
            "Hamming radius as a fraction of the code length (radius)")
          .In(0.0, 1.0)};
  return fields;
}
void CoarseOptions::Check() const { CheckFields(*this, Fields(), "recognition: coarse."); }

const std::vector<OptionField<FineOptions>>& FineOptions::Fields() {
  using O = FineOptions;
  static const std::vector<OptionField<O>> fields = {
      Field(&O::fine_weight, "fine_weight", "Ranking weight of the fine descriptor distance")
          .AtLeast(0.0),
      Field(&O::coarse_weight, "coarse_weight", "Ranking weight of the coarse vector distance")
          .AtLeast(0.0),
      Field(&O::size_weight, "size_weight", "Ranking weight of |log radius ratio|").AtLeast(0.0),
      Field(&O::signature_views, "signature_views",
            "Best-ranked views re-ranked with the polar signature")
          .AtLeast(0),
      Field(&O::signature_weight, "signature_weight",
            "Weight of 1 − polar-signature correlation in that re-ranking")
          .AtLeast(0.0)};
  return fields;
}
void FineOptions::Check() const {
  CheckFields(*this, Fields(), "recognition: fine.");
  SOPE_CHECK(fine_weight + coarse_weight + size_weight > 0.0,
             "recognition: fine: ranking weights must not all be 0");
}

const std::vector<OptionField<ScreeningOptions>>& ScreeningOptions::Fields() {
  using O = ScreeningOptions;
  static const std::vector<OptionField<O>> fields = {
      Field(&O::models, "models", "Candidate models that get pose hypotheses (0: no pose)")
          .AtLeast(0)
          .Flag("--pose-models"),
      Field(&O::views_per_model, "views_per_model",
            "Views per candidate model that get hypotheses")
          .AtLeast(1)
          .Flag("--pose-views"),
      Field(&O::view_separation, "view_separation",
            "Angle between the views of a candidate that get hypotheses")
          .Unit("rad")
          .AtLeast(0.0)
          .Flag("--view-separation"),
      Field(&O::rank_all_views, "rank_all_views",
            "Rank all views of candidate models, not only the flagged ones")
          .Flag("--rank-all-views"),
      Field(&O::quick_iterations, "quick_iterations", "Short ICP iterations per hypothesis")
          .AtLeast(1)
          .Flag("--quick-iterations"),
      Field(&O::quick_points, "quick_points", "View cloud points of the short ICP").AtLeast(6),
      Field(&O::quick_coverage_samples, "quick_coverage_samples",
            "Query points of the short ICP's score")
          .AtLeast(1)};
  return fields;
}
void ScreeningOptions::Check() const { CheckFields(*this, Fields(), "recognition: screening."); }

const std::vector<OptionField<RefinementOptions>>& RefinementOptions::Fields() {
  using O = RefinementOptions;
  static const std::vector<OptionField<O>> fields = {
      Field(&O::candidates, "candidates", "Models whose best pose is refined")
          .AtLeast(0)
          .Flag("--refine-candidates"),
      Field(&O::passes, "passes", "ICP runs per refined model, each with the nearest view")
          .AtLeast(1),
      Field(&O::iterations, "iterations", "ICP iterations per run").AtLeast(1),
      Field(&O::initial_gate, "initial_gate", "Correspondence gate of the first iteration")
          .Unit("m")
          .AtLeast(0.0)};
  return fields;
}
void RefinementOptions::Check() const { CheckFields(*this, Fields(), "recognition: refinement."); }

const std::vector<OptionField<WideningOptions>>& WideningOptions::Fields() {
  using O = WideningOptions;
  static const std::vector<OptionField<O>> fields = {
      Field(&O::below_score, "below_score",
            "Widen the pose search when the best verification score is below this (0: off)")
          .AtLeast(0.0)
          .Flag("--widen-below"),
      Field(&O::models, "models", "Models of the widened search").AtLeast(0),
      Field(&O::views_per_model, "views_per_model", "Views per model of the widened search")
          .AtLeast(1),
      Field(&O::roll_hypotheses, "roll_hypotheses", "Roll hypotheses per view when widened")
          .AtLeast(1),
      Field(&O::refine_candidates, "refine_candidates", "Models refined when widened")
          .AtLeast(0),
      Field(&O::batch_models, "batch_models",
            "Widened models screened per batch; stop after a batch that verifies (0: all)")
          .AtLeast(0)
          .Flag("--widen-batch"),
      Field(&O::continue_below, "continue_below",
            "Widened batches after the first only while the best score so far is below this")
          .AtLeast(0.0),
      Field(&O::screen_stop, "screen_stop",
            "A widened batch stops screening once a short-ICP hypothesis scores this much (0: "
            "screens all its views)")
          .AtLeast(0.0)
          .Flag("--widen-stop")};
  return fields;
}
void WideningOptions::Check() const { CheckFields(*this, Fields(), "recognition: widening."); }

const std::vector<OptionField<AssemblyOptions>>& AssemblyOptions::Fields() {
  using O = AssemblyOptions;
  static const std::vector<OptionField<O>> fields = {
      Field(&O::rerank_by_alignment, "rerank_by_alignment",
            "Keep the fine-stage order (no re-ranking by the alignment score)")
          .Flag("--no-rerank"),
      Field(&O::ranking_penalty, "ranking_penalty",
            "Re-ranking key: alignment score − this × ranking distance")
          .AtLeast(0.0)
          .Flag("--ranking-penalty"),
      Field(&O::min_score, "min_score",
            "Below this verification score of the best answer: no known object (0: off)")
          .In(0.0, 1.0)
          .Flag("--min-score"),
      Field(&O::class_ranking, "class_ranking",
            "No class-aware ranking (the first suggestion is the best-verified one, whatever "
            "the evidence for its class)")
          .Flag("--no-class-ranking"),
      Field(&O::class_models, "class_models",
            "Class verification: mean score of the class's best this many refined models")
          .AtLeast(1)
          .Flag("--class-models"),
      Field(&O::class_vote_views, "class_vote_views",
            "Fine-ranked views whose classes vote (0: no vote)")
          .AtLeast(0)
          .Flag("--class-vote-views"),
      Field(&O::class_vote_weight, "class_vote_weight",
            "Weight of the vote share beside the verification score")
          .AtLeast(0.0)
          .Flag("--class-vote-weight"),
      Field(&O::class_temperature, "class_temperature",
            "Softmax temperature of the class probabilities")
          .Above(0.0)
          .Flag("--class-temperature"),
      Field(&O::ambiguity_margin, "ambiguity_margin",
            "Name the second class (ambiguous_with) when its probability is within this of "
            "the first's")
          .In(0.0, 1.0)
          .Flag("--ambiguity-margin"),
      Field(&O::class_screen_classes, "class_screen_classes",
            "Class screening: the first this many classes of the fine ranking each get a "
            "refined hypothesis (0: off)")
          .AtLeast(0)
          .Flag("--class-screen-classes"),
      Field(&O::class_screen_models, "class_screen_models",
            "Class screening: refined models each of those classes gets at least")
          .AtLeast(1)
          .Flag("--class-screen-models")};
  return fields;
}
void AssemblyOptions::Check() const { CheckFields(*this, Fields(), "recognition: assembly."); }

const std::vector<OptionField<RecognitionOptions>>& RecognitionOptions::Fields() {
  using O = RecognitionOptions;
  static const std::vector<OptionField<O>> fields = [] {
    std::vector<OptionField<O>> f = {
        Field(&O::top_k, "top_k", "Suggestions returned").AtLeast(1).Flag("--top"),
        Field(&O::grouping, "grouping",
              "One suggestion per model, per class, or per database view (thesis)")
            .Flag("--grouping"),
        Field(&O::threads, "threads",
              "Threads of the pose screening and refinement, and of a table scene's clusters' "
              "first recognitions (the same answers for any count)")
            .AtLeast(1)
            .AtMost(64)
            .Flag("--pose-threads")};
    AppendNested(&f, &O::coarse, "coarse", CoarseOptions::Fields());
    AppendNested(&f, &O::fine, "fine", FineOptions::Fields());
    AppendNested(&f, &O::screening, "screening", ScreeningOptions::Fields());
    AppendNested(&f, &O::refinement, "refinement", RefinementOptions::Fields());
    AppendNested(&f, &O::widening, "widening", WideningOptions::Fields());
    AppendNested(&f, &O::assembly, "assembly", AssemblyOptions::Fields());
    AppendNested(&f, &O::pose, "pose", PoseOptions::Fields());
    return f;
  }();
  return fields;
}

RecognitionOptions RecognitionOptions::ThesisPreset(HashMethod method) {
  RecognitionOptions options;
  options.coarse.search = CoarseSearch::kRadius;
  switch (method) {
    case HashMethod::kMinimalLoss:
    case HashMethod::kBinaryReconstructive:
    case HashMethod::kItq:
      options.coarse.radius_fraction = 0.15;
      break;
    case HashMethod::kSpectral:
      options.coarse.radius_fraction = 0.25;
      break;
    case HashMethod::kLsh:
      options.coarse.radius_fraction = 0.5;
      break;
  }
  options.fine.coarse_weight = 0.0;
  options.fine.size_weight = 0.0;
  options.screening.models = 0;
  options.assembly.rerank_by_alignment = false;
  options.assembly.class_ranking = false;
  options.grouping = SuggestionGrouping::kView;
  return options;
}

void RecognitionOptions::Check() const {
  SOPE_CHECK(top_k >= 1, "recognition: top_k must be ≥ 1, got {}", top_k);
  coarse.Check();
  fine.Check();
  screening.Check();
  refinement.Check();
  widening.Check();
  assembly.Check();
  pose.Check();
}

std::string RecognitionResult::BriefReport() const {
  std::string report;
  if (!suggestions.empty() && !recognised) {
    report += fmt::format("no known object (best guess {} {}, score {:.3f}; candidates:)\n",
                          best().class_name, best().model_name, best().score);
  }
  for (size_t i = 0; i < suggestions.size(); ++i) {
    const Suggestion& s = suggestions[i];
    const Eigen::Vector3d euler = s.cam_from_model.rotation.eulerAngles(2, 1, 0) * kRadToDeg;
    report += fmt::format(
        "{}. {:<12} {:<20} score {:.3f}  view θ {:5.1f}° φ {:5.1f}°  pose t = ({:.3f}, {:.3f}, "
        "{:.3f}) m, R = Rz {:.1f}° · Ry {:.1f}° · Rx {:.1f}°{}\n",
        i + 1, s.class_name, s.model_name, s.score, s.viewpoint.theta * kRadToDeg,
        s.viewpoint.phi * kRadToDeg, s.cam_from_model.translation.x(),
        s.cam_from_model.translation.y(), s.cam_from_model.translation.z(), euler[0], euler[1],
        euler[2], s.refined ? " (ICP-refined)" : (s.posed ? "" : " (unverified)"));
  }
  report += fmt::format(
      "{} query points; flagged {} of {} views ({:.1f}%); times: preprocess {:.1f} ms, "
      "features {:.1f} ms, coarse {:.2f} ms, fine {:.2f} ms, pose {:.1f} ms, total {:.1f} ms",
      query_points, flagged, database_views, 100.0 * flagged_fraction, timing.preprocess,
      timing.features, timing.coarse, timing.fine, timing.pose, timing.total);
  return report;
}

std::string RecognitionResultToJson(const RecognitionResult& result) {
  nlohmann::json j;
  if (!result.suggestions.empty()) {
    if (result.recognised) {
      j = SuggestionToJson(result.best());
    } else {
      // No known object: the best guess only among the candidates.
      j["class"] = nullptr;
      j["model"] = nullptr;
      j["score"] = result.best().score;
    }
  }
  j["recognised"] = result.recognised;
  const RecognitionTimings& t = result.timing;
  j["timing_ms"] = {{"preprocess", t.preprocess}, {"features", t.features}, {"coarse", t.coarse},
                    {"fine", t.fine},             {"pose", t.pose},         {"total", t.total}};
  j["cpu_ms"] = {{"preprocess", t.preprocess_cpu}, {"features", t.features_cpu},
                 {"coarse", t.coarse_cpu},         {"fine", t.fine_cpu},
                 {"pose", t.pose_cpu},             {"total", t.total_cpu}};
  j["query_points"] = result.query_points;
  j["flagged"] = result.flagged;
  j["flagged_fraction"] = result.flagged_fraction;
  j["database_views"] = result.database_views;
  nlohmann::json candidates = nlohmann::json::array();
  for (const Suggestion& s : result.suggestions) candidates.push_back(SuggestionToJson(s));
  j["candidates"] = candidates;
  if (!result.classes.empty()) {
    nlohmann::json classes = nlohmann::json::array();
    for (const ClassScore& c : result.classes) {
      classes.push_back({{"class", c.class_name},
                         {"score", c.probability},
                         {"verification", c.verification},
                         {"vote", c.vote}});
    }
    j["classes"] = classes;
    j["ambiguous_with"] = result.ambiguous_with.empty()
                              ? nlohmann::json(nullptr)
                              : nlohmann::json(result.ambiguous_with);
  }
  return j.dump();
}

Recogniser::Recogniser(const Database& database) : database_(database) {
  database.view_sketches();  // the widened search's quantised rows, made once per database
}

RecognitionResult Recogniser::Recognise(const PointCloud& cloud,
                                        const RecognitionOptions& options) const {
  options.Check();
  const Database& db = database_;
  const Stopwatch total_watch;
  RecognitionResult result;
  result.database_views = db.num_views();

  // 1–2. Pre-processing and features, as for the database views.
  const ViewDescription query = DescribeQuery(db, cloud);
  result.timing.preprocess = query.preprocess_ms;
  result.timing.features = query.features_ms;
  result.timing.preprocess_cpu = query.preprocess_cpu_ms;
  result.timing.features_cpu = query.features_cpu_ms;
  result.query_points = static_cast<int>(query.preprocessed.cloud.size());
  result.query_radius = query.preprocessed.radius;

  // 3. Coarse: standardise, encode, Hamming search.
  Stopwatch watch;
  const CoarseResult coarse = CoarseStage(db, query, options);
  result.flagged = static_cast<int>(coarse.flagged.size());
  result.flagged_fraction = static_cast<double>(coarse.flagged.size()) / db.num_views();
  result.timing.coarse = watch.WallMs();
  result.timing.coarse_cpu = watch.CpuMs();

  // 4. Fine ranking of the flagged views.
  watch.Restart();
  StageContext context(db, query, coarse);
  const FineResult fine = FineStage(&context, options);
  result.timing.fine = watch.WallMs();
  result.timing.fine_cpu = watch.CpuMs();

  // 5–6. Pose screening, refinement, widening; the answer.
  watch.Restart();
  std::vector<PoseCandidate> posed = EstimatePoses(&context, fine, options);
  result.posed = static_cast<int>(posed.size());
  Assembly assembly = AssembleSuggestions(&context, fine, std::move(posed), options);
  result.suggestions = std::move(assembly.suggestions);
  result.recognised = assembly.recognised;
  result.classes = std::move(assembly.classes);
  result.ambiguous_with = std::move(assembly.ambiguous_with);
  result.other_class_poses = std::move(assembly.other_class_poses);
  result.timing.pose = watch.WallMs();
  result.timing.pose_cpu = watch.CpuMs();
  result.timing.total = total_watch.WallMs();
  result.timing.total_cpu = total_watch.CpuMs();
  return result;
}

}  // namespace sope
