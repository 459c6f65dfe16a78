#include "recogniser/recogniser.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "recogniser/view_description.h"

namespace sope {
namespace {

constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;

// A flagged view during ranking.
struct Ranked {
  int view = 0;
  int hamming = 0;
  double fine = 0.0, coarse = 0.0, size = 0.0, combined = 0.0;
  int fine_rank = -1;  // position in the fine ranking of the flagged views, −1 if not flagged
};

// A pose candidate during the pose stage.
struct Posed {
  Ranked ranked;   // the view it started from
  int view = 0;    // the view whose cloud the pose and score refer to
  int model = 0;
  Rigid3d canonical_from_model;
  double roll = 0.0;
  IcpResult icp;
  AlignmentScore alignment;
  bool refined = false;
};

// Decoded view clouds of one query (each view decoded once).
class ViewCloudCache {
 public:
  explicit ViewCloudCache(const Database& db) : db_(db) {}
  const PointCloud& Get(int view) {
    auto it = clouds_.find(view);
    if (it == clouds_.end()) {
      it = clouds_.emplace(view, PointCloud()).first;
      db_.ViewCloud(view, &it->second);
    }
    return it->second;
  }

 private:
  const Database& db_;
  std::unordered_map<int, PointCloud> clouds_;
};

// The view of `model` whose camera direction (from the model centre) is closest to that
// of the pose `canonical_from_model` (the canonical frame shares the camera centre).
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

std::string ToString(CoarseSearch search) {
  return search == CoarseSearch::kKBest ? "kbest" : "radius";
}

CoarseSearch CoarseSearchFromString(const std::string& text) {
  if (text == "kbest") return CoarseSearch::kKBest;
  if (text == "radius") return CoarseSearch::kRadius;
  SOPE_THROW("unknown coarse search '{}' (expected kbest or radius)", text);
}

std::string ToString(SuggestionGrouping grouping) {
  switch (grouping) {
    case SuggestionGrouping::kModel:
      return "model";
    case SuggestionGrouping::kView:
      return "view";
    case SuggestionGrouping::kClass:
      return "class";
  }
  return "unknown";
}

SuggestionGrouping SuggestionGroupingFromString(const std::string& text) {
  if (text == "model") return SuggestionGrouping::kModel;
  if (text == "view") return SuggestionGrouping::kView;
  if (text == "class") return SuggestionGrouping::kClass;
  SOPE_THROW("unknown suggestion grouping '{}' (expected model, view or class)", text);
}

RecognitionOptions RecognitionOptions::ThesisPreset(HashMethod method) {
  RecognitionOptions options;
  options.coarse_search = CoarseSearch::kRadius;
  switch (method) {
    case HashMethod::kMinimalLoss:
    case HashMethod::kBinaryReconstructive:
    case HashMethod::kItq:
      options.radius_fraction = 0.15;
      break;
    case HashMethod::kSpectral:
      options.radius_fraction = 0.25;
      break;
    case HashMethod::kLsh:
      options.radius_fraction = 0.5;
      break;
  }
  options.coarse_weight = 0.0;
  options.size_weight = 0.0;
  options.pose_models = 0;
  options.rerank_by_alignment = false;
  options.grouping = SuggestionGrouping::kView;
  return options;
}

void RecognitionOptions::Check() const {
  SOPE_CHECK(top_k >= 1, "recognition: top_k must be ≥ 1, got {}", top_k);
  SOPE_CHECK(flag_fraction > 0.0 && flag_fraction <= 1.0,
             "recognition: flag_fraction must be in (0, 1], got {}", flag_fraction);
  SOPE_CHECK(min_flagged >= 1, "recognition: min_flagged must be ≥ 1, got {}", min_flagged);
  SOPE_CHECK(radius_fraction >= 0.0 && radius_fraction <= 1.0,
             "recognition: radius_fraction must be in [0, 1], got {}", radius_fraction);
  SOPE_CHECK(fine_weight >= 0.0 && coarse_weight >= 0.0 && size_weight >= 0.0 &&
                 fine_weight + coarse_weight + size_weight > 0.0,
             "recognition: ranking weights must be ≥ 0 and not all 0");
  SOPE_CHECK(pose_models >= 0 && pose_views_per_model >= 1 && quick_iterations >= 1 &&
                 quick_points >= 6 && quick_coverage_samples >= 1 && refine_candidates >= 0 &&
                 refine_passes >= 1 && refine_iterations >= 1 && refine_initial_gate >= 0.0,
             "recognition: invalid pose stage sizes");
  SOPE_CHECK(pose_view_separation >= 0.0 && signature_views >= 0 && signature_weight >= 0.0,
             "recognition: pose_view_separation, signature_views and signature_weight must be "
             "≥ 0");
  SOPE_CHECK(widen_below_score >= 0.0 && widen_models >= 0 && widen_views_per_model >= 1 &&
                 widen_roll_hypotheses >= 1 && widen_refine_candidates >= 0,
             "recognition: invalid widened search settings");
  pose.Check();
}

std::string RecognitionResult::BriefReport() const {
  std::string report;
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
    j = SuggestionToJson(result.best());
  }
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
  return j.dump();
}

Recogniser::Recogniser(const Database& database) : database_(database) {}

RecognitionResult Recogniser::Recognise(const PointCloud& cloud,
                                        const RecognitionOptions& options) const {
  options.Check();
  const Database& db = database_;
  const DatabaseOptions& db_options = db.options();
  const internal::Stopwatch total_watch;
  RecognitionResult result;
  result.database_views = db.num_views();

  // 1–2. Pre-processing and features, as for the database views.
  ViewDescription query = DescribeView(cloud, db_options.preprocess, db_options.features);
  result.timing.preprocess = query.preprocess_ms;
  result.timing.features = query.features_ms;
  result.timing.preprocess_cpu = query.preprocess_cpu_ms;
  result.timing.features_cpu = query.features_cpu_ms;
  result.query_points = static_cast<int>(query.preprocessed.cloud.size());
  result.query_radius = query.preprocessed.radius;
  SOPE_CHECK(query.features.coarse.size() == db.coarse_dim() &&
                 query.features.fine.size() == db.fine_dim(),
             "query features have {} coarse / {} fine values, the database {} / {} (database "
             "built by an incompatible sope?)",
             query.features.coarse.size(), query.features.fine.size(), db.coarse_dim(),
             db.fine_dim());

  // 3. Coarse: standardise, encode, Hamming search.
  internal::Stopwatch watch;
  const Eigen::VectorXf coarse = db.Standardise(query.features.coarse);
  const Eigen::MatrixXf hash_row = db.HashInput(coarse, query.features.fine).transpose();
  const BinaryCodes code = db.hasher().Encode(hash_row);
  std::vector<HammingMatch> matches;
  if (!options.restrict_to_models.empty()) {
    for (int m : options.restrict_to_models) {
      SOPE_CHECK(m >= 0 && m < db.num_models(), "recognition: restrict_to_models names model {} "
                 "of {}", m, db.num_models());
      const ModelRecord& model = db.model(m);
      for (int v = model.first_view; v < model.first_view + model.num_views; ++v) {
        HammingMatch match;
        match.index = v;
        match.hamming_distance = HammingDistance(code.code(0), db.index().code(v),
                                                 db.index().words_per_code());
        matches.push_back(match);
      }
    }
  } else if (options.coarse_search == CoarseSearch::kKBest) {
    const int k = std::min<int>(
        db.num_views(),
        std::max<int>(options.min_flagged,
                      static_cast<int>(std::ceil(options.flag_fraction * db.num_views()))));
    matches = options.coarse_kbest ? options.coarse_kbest(code.code(0), k)
                                   : db.index().KBestSearch(code.code(0), k);
  } else {
    const int radius = static_cast<int>(std::lround(options.radius_fraction * code.bits));
    matches = db.index().RadiusSearch(code.code(0), radius);
  }
  result.flagged = static_cast<int>(matches.size());
  result.flagged_fraction = static_cast<double>(matches.size()) / db.num_views();
  result.timing.coarse = watch.WallMs();
  result.timing.coarse_cpu = watch.CpuMs();

  // 4. Fine ranking of the flagged views.
  watch.Restart();
  const DistanceScales& scales = db.distance_scales();
  const int coarse_dim = db.coarse_dim(), fine_dim = db.fine_dim();
  const Eigen::Map<const Eigen::VectorXf> query_fine(query.features.fine.data(), fine_dim);
  const double log_query_radius = std::log(std::max(1e-6f, query.preprocessed.radius));
  // Fine-stage distances of any database view to the query.
  auto measure = [&](int view_index, int hamming) {
    Ranked r;
    r.view = view_index;
    r.hamming = hamming;
    r.fine = (Eigen::Map<const Eigen::VectorXf>(db.fine(view_index), fine_dim) - query_fine)
                 .cwiseAbs()
                 .sum();
    r.coarse =
        (Eigen::Map<const Eigen::VectorXf>(db.coarse(view_index), coarse_dim) - coarse).norm();
    r.size = std::abs(log_query_radius - std::log(std::max(1e-6f, db.view(view_index).radius)));
    r.combined = options.fine_weight * r.fine / scales.fine +
                 options.coarse_weight * r.coarse / scales.coarse +
                 options.size_weight * r.size / scales.size;
    return r;
  };
  std::vector<Ranked> ranked(matches.size());
  for (size_t i = 0; i < matches.size(); ++i) {
    ranked[i] = measure(matches[i].index, matches[i].hamming_distance);
  }
  auto by_combined = [](const Ranked& a, const Ranked& b) {
    return a.combined != b.combined ? a.combined < b.combined : a.view < b.view;
  };
  std::sort(ranked.begin(), ranked.end(), by_combined);
  // The same canonical query the pose stage uses (built here when the signature is needed).
  const float spacing = static_cast<float>(
      db_options.preprocess.voxel_leaf > 0.0 ? db_options.preprocess.voxel_leaf : 0.004);
  PoseQuery pose_query;
  bool have_pose_query = false;
  auto get_pose_query = [&]() -> const PoseQuery& {
    if (!have_pose_query) {
      // The described query is already canonical: its sensor frame is the canonical frame.
      pose_query = MakePoseQuery(query.preprocessed.cloud, query.preprocessed.centroid,
                                 query.preprocessed.radius, spacing, options.pose);
      have_pose_query = true;
    }
    return pose_query;
  };
  ViewCloudCache clouds(db);
  if (options.signature_views > 0 && options.signature_weight > 0.0 && !ranked.empty()) {
    const PoseQuery& q = get_pose_query();
    const size_t count = std::min<size_t>(ranked.size(), options.signature_views);
    for (size_t i = 0; i < count; ++i) {
      const ViewRecord& view = db.view(ranked[i].view);
      const PointCloud& cloud = clouds.Get(ranked[i].view);
      const std::vector<float> signature =
          ViewSignature(view.cam_from_model, view.centroid_in_model, view.radius, cloud.points,
                        cloud.normals, options.pose);
      const std::vector<RollHypothesis> rolls = EstimateRoll(q.signature, signature, options.pose);
      const double correlation = rolls.empty() ? 0.0 : rolls.front().correlation;
      ranked[i].combined += options.signature_weight * (1.0 - correlation);
    }
    std::sort(ranked.begin(), ranked.begin() + count, by_combined);
  }
  for (size_t i = 0; i < ranked.size(); ++i) ranked[i].fine_rank = static_cast<int>(i);
  result.timing.fine = watch.WallMs();
  result.timing.fine_cpu = watch.CpuMs();

  // 5. Pose hypotheses, ICP, verification.
  watch.Restart();
  std::vector<Posed> posed;
  if (options.pose_models > 0 && !ranked.empty()) {
    const PoseQuery& pose_query = get_pose_query();
    std::unordered_map<int, int> flagged_rank;  // view → index into `ranked`
    for (size_t i = 0; i < ranked.size(); ++i) {
      flagged_rank.emplace(ranked[i].view, static_cast<int>(i));
    }
    // The fine-stage distances of every view of `model_index` (flagged ones as ranked).
    auto all_views_of = [&](int model_index) {
      const ModelRecord& model = db.model(model_index);
      std::vector<Ranked> views;
      views.reserve(model.num_views);
      for (int v = model.first_view; v < model.first_view + model.num_views; ++v) {
        const auto it = flagged_rank.find(v);
        if (it != flagged_rank.end()) {
          views.push_back(ranked[it->second]);
        } else {
          views.push_back(measure(v, HammingDistance(code.code(0), db.index().code(v),
                                                     db.index().words_per_code())));
        }
      }
      return views;
    };

    // Screening: per candidate model, its views ranked (all of them, or the flagged ones),
    // up to views_per_model of them at least pose_view_separation apart (neighbouring
    // views would converge to the same pose); roll hypotheses and a short ICP on a prefix
    // of each view's cloud; the best hypothesis per view is kept.
    const double min_separation_cos = std::cos(options.pose_view_separation);
    auto screen = [&](const std::vector<int>& models, int views_per_model, bool rank_all,
                      const PoseOptions& hypothesis_options, std::vector<Posed>* out) {
      // The short ICP reaches the final gate two iterations before it ends, so its score
      // is taken at a settled pose.
      PoseOptions quick_options = options.pose;
      quick_options.gate_iterations = std::max(1, options.quick_iterations - 2);
      for (int model_index : models) {
        std::vector<Ranked> views;
        if (rank_all) {
          views = all_views_of(model_index);
        } else {
          for (const Ranked& r : ranked) {
            if (db.view(r.view).model == model_index) views.push_back(r);
          }
        }
        std::sort(views.begin(), views.end(), by_combined);
        std::vector<Eigen::Vector3d> directions;
        for (const Ranked& r : views) {
          if (static_cast<int>(directions.size()) >= views_per_model) break;
          const ViewRecord& view = db.view(r.view);
          const Eigen::Vector3d direction = view.viewpoint.Direction();
          bool near = false;
          for (const Eigen::Vector3d& d : directions) {
            near |= d.dot(direction) > min_separation_cos;
          }
          if (near) continue;
          directions.push_back(direction);
          const PointCloud& cloud = clouds.Get(r.view);
          const std::vector<PoseHypothesis> hypotheses =
              InitialPoses(view.cam_from_model, view.centroid_in_model, view.radius,
                           cloud.points, cloud.normals, pose_query, hypothesis_options);
          const size_t quick_n = std::min<size_t>(cloud.size(), options.quick_points);
          const std::vector<Eigen::Vector3f> quick_points(cloud.points.begin(),
                                                          cloud.points.begin() + quick_n);
          const std::vector<Eigen::Vector3f> quick_normals(cloud.normals.begin(),
                                                           cloud.normals.begin() + quick_n);
          const float quick_spacing =
              view.cloud_spacing *
              std::sqrt(static_cast<float>(cloud.size()) / std::max<size_t>(1, quick_n));
          Posed candidate;
          candidate.ranked = r;
          candidate.view = r.view;
          candidate.model = model_index;
          bool first = true;
          for (const PoseHypothesis& hypothesis : hypotheses) {
            const IcpResult icp = RefinePose(quick_points, quick_normals, pose_query,
                                             hypothesis.canonical_from_model, quick_options,
                                             options.quick_iterations);
            const AlignmentScore alignment = ScoreAlignment(
                quick_points, quick_normals, quick_spacing, pose_query, icp.canonical_from_model,
                options.pose, options.quick_coverage_samples);
            if (first || alignment.score > candidate.alignment.score) {
              candidate.canonical_from_model = icp.canonical_from_model;
              candidate.roll = hypothesis.roll.roll;
              candidate.icp = icp;
              candidate.alignment = alignment;
              first = false;
            }
          }
          if (!first) out->push_back(std::move(candidate));
        }
      }
      std::stable_sort(out->begin(), out->end(), [](const Posed& a, const Posed& b) {
        return a.alignment.score > b.alignment.score;
      });
    };

    // Refinement of the best hypothesis of the best `count` models of `candidates` (sorted
    // by their short-ICP score): ICP with the stored view nearest to the current pose (so
    // model and query show the same side), repeated once the pose has settled, and the
    // full verification with that view's cloud. Returns the best verification score.
    PoseOptions refine_options = options.pose;
    refine_options.gate_iterations = 2;
    auto refine = [&](std::vector<Posed>* candidates, int count) {
      std::vector<int> refined_models;
      double best_score = 0.0;
      for (Posed& candidate : *candidates) {
        if (static_cast<int>(refined_models.size()) >= count) break;
        if (std::find(refined_models.begin(), refined_models.end(), candidate.model) !=
            refined_models.end()) {
          continue;
        }
        refined_models.push_back(candidate.model);
        const int quick = candidate.icp.iterations;
        int iterations = 0;
        for (int pass = 0; pass < options.refine_passes; ++pass) {
          const int nearest =
              NearestModelView(db, candidate.model, candidate.canonical_from_model);
          if (pass > 0 && nearest == candidate.view) break;
          candidate.view = nearest;
          const PointCloud& cloud = clouds.Get(nearest);
          candidate.icp = RefinePose(cloud.points, cloud.normals, pose_query,
                                     candidate.canonical_from_model, refine_options,
                                     options.refine_iterations, options.refine_initial_gate);
          candidate.canonical_from_model = candidate.icp.canonical_from_model;
          iterations += candidate.icp.iterations;
        }
        candidate.icp.iterations = quick + iterations;
        candidate.view = NearestModelView(db, candidate.model, candidate.canonical_from_model);
        const PointCloud& cloud = clouds.Get(candidate.view);
        candidate.alignment =
            ScoreAlignment(cloud.points, cloud.normals, db.view(candidate.view).cloud_spacing,
                           pose_query, candidate.canonical_from_model, options.pose);
        candidate.refined = true;
        best_score = std::max(best_score, candidate.alignment.score);
      }
      return best_score;
    };

    // Candidate models: the first pose_models distinct models of the fine ranking.
    std::vector<int> models;
    for (const Ranked& r : ranked) {
      if (static_cast<int>(models.size()) >= options.pose_models) break;
      const int model = db.view(r.view).model;
      if (std::find(models.begin(), models.end(), model) == models.end()) {
        models.push_back(model);
      }
    }
    // The screening budget is pose_models × pose_views_per_model views: with fewer
    // candidate models (a small database, a pose-only query) each gets more views.
    const int views_per_model = std::max(
        options.pose_views_per_model,
        options.pose_models * options.pose_views_per_model / std::max<int>(1, models.size()));
    screen(models, views_per_model, options.rank_all_views_of_candidates, options.pose, &posed);
    const double best_score = refine(&posed, options.refine_candidates);

    // Widened search (see RecognitionOptions::widen_below_score): the best verification
    // is too low to be the right model at the right pose, so the descriptors (corrupted
    // by occlusion) probably ranked the right model or its right views too low, or the
    // polar signature (about a centroid shifted by the occluder) gave no right roll. The
    // verification itself is reliable there — at the true pose the true model scores
    // ≈ 0.9 or more — so a broader hypothesis search fixes these queries: more candidate
    // models (by their best view over the whole database), more of each one's views (all
    // ranked), more roll hypotheses per view.
    if (options.widen_below_score > 0.0 && best_score < options.widen_below_score &&
        options.widen_models > 0 && options.refine_candidates > 0) {
      std::vector<std::pair<double, int>> model_distance;  // best view's distance, model
      std::vector<int> pool = options.restrict_to_models;
      if (pool.empty()) {
        pool.resize(db.num_models());
        std::iota(pool.begin(), pool.end(), 0);
      }
      for (int m : pool) {
        double best = std::numeric_limits<double>::infinity();
        for (const Ranked& r : all_views_of(m)) best = std::min(best, r.combined);
        model_distance.emplace_back(best, m);
      }
      std::sort(model_distance.begin(), model_distance.end());
      std::vector<int> wide_models;
      for (const auto& [distance, m] : model_distance) {
        if (static_cast<int>(wide_models.size()) >= options.widen_models) break;
        wide_models.push_back(m);
      }
      PoseOptions wide_hypotheses = options.pose;
      wide_hypotheses.roll_hypotheses =
          std::min(std::max(options.pose.roll_hypotheses, options.widen_roll_hypotheses),
                   options.pose.angle_bins / 2);
      std::vector<Posed> wide;
      screen(wide_models, std::max(views_per_model, options.widen_views_per_model), true,
             wide_hypotheses, &wide);
      refine(&wide, options.widen_refine_candidates);
      for (Posed& candidate : wide) posed.push_back(std::move(candidate));
    }

    if (options.rerank_by_alignment) {
      const double penalty = options.ranking_penalty;
      std::stable_sort(posed.begin(), posed.end(), [penalty](const Posed& a, const Posed& b) {
        if (a.refined != b.refined) return a.refined;
        return a.alignment.score - penalty * a.ranked.combined >
               b.alignment.score - penalty * b.ranked.combined;
      });
    }
  }
  result.posed = static_cast<int>(posed.size());

  // Suggestions: posed candidates (in their order) first when re-ranking, then the rest of
  // the fine ranking; grouped and cut to top_k.
  const Rigid3d cam_from_canonical(query.cam_from_canonical, Eigen::Vector3d::Zero());
  auto make_suggestion = [&](const Ranked& r) {
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
    // Unposed: the database view's pose moved so that its centroid lies on the query's.
    const Eigen::Vector3d centroid_in_view_cam =
        view.cam_from_model * view.centroid_in_model.cast<double>();
    const Eigen::Matrix3d canonical_from_view_cam =
        CamFromCanonical(centroid_in_view_cam).transpose();
    Rigid3d canonical_from_model(canonical_from_view_cam * view.cam_from_model.rotation,
                                 Eigen::Vector3d::Zero());
    canonical_from_model.translation =
        Eigen::Vector3d(0, 0, query.preprocessed.centroid.norm()) -
        canonical_from_model.rotation * view.centroid_in_model.cast<double>();
    s.cam_from_model = cam_from_canonical * canonical_from_model;
    return s;
  };
  std::vector<Suggestion> ordered;
  std::vector<uint8_t> used(ranked.size(), 0);
  for (const Posed& candidate : posed) {
    Suggestion s = make_suggestion(candidate.ranked);
    s.view = candidate.view;
    s.viewpoint = db.view(candidate.view).viewpoint;
    s.cam_from_model = cam_from_canonical * candidate.canonical_from_model;
    s.posed = true;
    s.refined = candidate.refined;
    s.converged = candidate.icp.converged;
    s.roll = candidate.roll;
    s.icp_iterations = candidate.icp.iterations;
    s.icp_rms = candidate.icp.rms;
    s.alignment = candidate.alignment;
    s.score = candidate.alignment.score;
    if (candidate.ranked.fine_rank >= 0) used[candidate.ranked.fine_rank] = 1;
    ordered.push_back(std::move(s));
  }
  for (size_t i = 0; i < ranked.size(); ++i) {
    if (!used[i]) ordered.push_back(make_suggestion(ranked[i]));
  }
  if (!options.rerank_by_alignment) {
    // Fine-stage order; views found only by the per-model search go last.
    std::stable_sort(ordered.begin(), ordered.end(), [](const Suggestion& a, const Suggestion& b) {
      const int ra = a.fine_rank < 0 ? std::numeric_limits<int>::max() : a.fine_rank;
      const int rb = b.fine_rank < 0 ? std::numeric_limits<int>::max() : b.fine_rank;
      return ra < rb;
    });
  }
  std::vector<int> seen;
  for (Suggestion& s : ordered) {
    if (static_cast<int>(result.suggestions.size()) >= options.top_k) break;
    int key = -1;
    if (options.grouping == SuggestionGrouping::kModel) key = s.model;
    if (options.grouping == SuggestionGrouping::kClass) key = s.class_index;
    if (key >= 0) {
      if (std::find(seen.begin(), seen.end(), key) != seen.end()) continue;
      seen.push_back(key);
    }
    result.suggestions.push_back(std::move(s));
  }
  // Suggestions without a verified pose still get the roll about the line of sight (the
  // best signature correlation), so their pose is the unrefined estimate, not the bare
  // database view's.
  for (Suggestion& s : result.suggestions) {
    if (s.posed) continue;
    const ViewRecord& view = db.view(s.view);
    const PointCloud& cloud = clouds.Get(s.view);
    const std::vector<PoseHypothesis> hypotheses =
        InitialPoses(view.cam_from_model, view.centroid_in_model, view.radius, cloud.points,
                     cloud.normals, get_pose_query(), options.pose);
    if (hypotheses.empty()) continue;
    s.roll = hypotheses.front().roll.roll;
    s.cam_from_model = cam_from_canonical * hypotheses.front().canonical_from_model;
  }
  result.timing.pose = watch.WallMs();
  result.timing.pose_cpu = watch.CpuMs();
  result.timing.total = total_watch.WallMs();
  result.timing.total_cpu = total_watch.CpuMs();
  return result;
}

}  // namespace sope
