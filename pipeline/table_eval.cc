#include "pipeline/table_eval.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <optional>
#include <random>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "core/error.h"
#include "core/file_util.h"
#include "core/plots.h"
#include "core/statistics.h"
#include "core/stopwatch.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

double Ratio(int a, int b) { return b > 0 ? static_cast<double>(a) / b : 0.0; }

// The controller's options for one evaluation scene: a single tabletop scan, nothing found
// being a result; scans written under `out_dir`/scans unless the options name a directory.
ScanAndRecogniseOptions SceneControllerOptions(const TableEvalOptions& options,
                                               const std::string& out_dir) {
  ScanAndRecogniseOptions controller_options = options.controller;
  controller_options.tabletop = true;
  controller_options.max_scans = 1;
  controller_options.warm_up = false;  // one scan per controller
  controller_options.fail_on_nothing_found = false;
  if (controller_options.out_dir.empty() && !out_dir.empty()) {
    controller_options.out_dir = JoinPath(out_dir, "scans");
  }
  return controller_options;
}

// The virtual table of scene `k`: the options' source on the default rig (unless given),
// with the evaluation's clutter and the scene's seed.
VirtualTableSourceOptions SceneSourceOptions(const TableEvalOptions& options, int k) {
  VirtualTableSourceOptions source_options = options.source;
  if (source_options.calibration.camera.width == 0) {
    source_options.calibration = DefaultRigCalibration();
  }
  source_options.patterns.projector_width = source_options.calibration.projector.width;
  source_options.patterns.projector_height = source_options.calibration.projector.height;
  source_options.table.clutter = options.clutter;
  source_options.seed = options.seed + static_cast<uint64_t>(k);
  return source_options;
}

// Scans scene `k` showing min–max distinct meshes of the options' pool, drawn with `rng`.
ScanReport ScanMeshScene(const Database& database, const TableEvalOptions& options,
                         const ScanAndRecogniseOptions& controller_options,
                         VirtualTableSourceOptions source_options, int k, std::mt19937_64* rng) {
  // This scene's objects: min–max distinct meshes of the pool.
  std::vector<std::string> pool = options.meshes;
  std::shuffle(pool.begin(), pool.end(), *rng);
  const int count = std::min<int>(
      static_cast<int>(pool.size()),
      std::uniform_int_distribution<int>(options.min_objects, options.max_objects)(*rng));
  source_options.table.objects.clear();
  for (int i = 0; i < count; ++i) {
    TableObjectSpec spec;
    spec.spec = pool[i];
    // Scaled as build-db scaled it (its --units, or kept when plausible in metres): the
    // database's model.
    spec.size = kSizeAsDatabase;
    spec.mesh_unit = database.options().size.mesh_unit;
    NameAsInDatabase(database, &spec);  // the truth's class is the database's
    source_options.table.objects.push_back(spec);
  }
  VirtualTableSource source(source_options);
  ScanAndRecogniseController controller(controller_options, &source, database);
  ScanReport report = controller.Scan(0);
  if (!controller_options.out_dir.empty()) {
    report.index = k;
    WriteScanOutputs(controller_options.out_dir, database, &report);
  }
  return report;
}

// Scans scene `k` of the procedural source (made on the first call from `source_options`);
// empty when the scene's objects do not all fit on the visible table.
std::optional<ScanReport> ScanProceduralScene(const Database& database,
                                              const TableEvalOptions& options,
                                              const ScanAndRecogniseOptions& controller_options,
                                              VirtualTableSourceOptions source_options, int k,
                                              std::unique_ptr<VirtualTableSource>* procedural) {
  if (!*procedural) {
    source_options.seed = options.seed;
    source_options.objects = 0;  // 3–5
    if (source_options.classes.empty()) source_options.classes = ProceduralClassesIn(database);
    *procedural = std::make_unique<VirtualTableSource>(source_options);
  }
  ScanAndRecogniseController controller(controller_options, procedural->get(), database);
  ScanReport report;
  try {
    report = controller.Scan(k);
  } catch (const Error& e) {
    // A scene whose objects do not all fit on the visible table is drawn again with
    // the next seed by the source's next scan; counted, not evaluated.
    if (std::string(e.what()).find("cannot place") == std::string::npos) throw;
    spdlog::warn("scene {} skipped: {}", k, e.what());
    return std::nullopt;
  }
  if (!controller_options.out_dir.empty()) {
    WriteScanOutputs(controller_options.out_dir, database, &report);
  }
  return report;
}

// The confusion's labels for the unknown objects and for nothing (no detection, no object).
constexpr const char* kClutter = "clutter";
constexpr const char* kNone = "none";

// Adds one scanned scene's detections and truth matches to the summary's counts and errors.
void CountScene(const ScanReport& report, TableEvalSummary* summary) {
  ++summary->scenes;
  SOPE_CHECK(report.truth.has_value(), "table evaluation: the source gave no ground truth");
  const int detections = report.scene ? static_cast<int>(report.scene->objects.size()) : 0;
  summary->detections += detections;
  const auto detected_class = [&](int d) {
    return d >= 0 ? report.scene->objects[d].best().class_name : std::string(kNone);
  };
  std::vector<uint8_t> matched(detections, 0);
  for (const TableObjectMatch& m : report.matches) {
    const ScanObjectTruth& truth = report.truth->objects[m.truth];
    if (m.detection >= 0) matched[m.detection] = 1;
    ++summary->confusion[{truth.known ? truth.class_name : std::string(kClutter),
                          detected_class(m.detection)}];
    if (!truth.known) {
      ++summary->clutter;
      summary->clutter_rejected += m.detection < 0;
      continue;
    }
    ++summary->known;
    summary->correct += m.correct;
    summary->class_correct += m.class_correct;
    TableEvalSummary::ClassCounts& counts = summary->per_class[truth.class_name];
    ++counts.known;
    counts.correct += m.correct;
    counts.class_correct += m.class_correct;
    if (truth.visible_fraction >= 0.5) {
      ++summary->visible_known;
      summary->visible_correct += m.correct;
      summary->visible_class_correct += m.class_correct;
    }
    if (m.pose_error) {
      summary->rotation_errors_deg.push_back(m.pose_error->rotation_error_deg);
      summary->center_errors_m.push_back(m.pose_error->center_error_m);
    }
  }
  for (int d = 0; d < detections; ++d) {
    if (!matched[d]) ++summary->confusion[{std::string(kNone), detected_class(d)}];
  }
}

// The confusion's labels: the classes in name order, then "clutter" and "none"; and its
// counts, rows the true labels.
std::vector<std::vector<int>> ConfusionCounts(const TableEvalSummary& summary,
                                              std::vector<std::string>* labels) {
  std::vector<std::string> names;
  for (const auto& [pair, count] : summary.confusion) {
    for (const std::string& name : {pair.first, pair.second}) {
      if (name != kClutter && name != kNone) names.push_back(name);
    }
  }
  std::sort(names.begin(), names.end());
  names.erase(std::unique(names.begin(), names.end()), names.end());
  names.push_back(kClutter);
  names.push_back(kNone);
  std::vector<std::vector<int>> counts(names.size(), std::vector<int>(names.size(), 0));
  const auto index = [&](const std::string& name) {
    return std::find(names.begin(), names.end(), name) - names.begin();
  };
  for (const auto& [pair, count] : summary.confusion) {
    counts[index(pair.first)][index(pair.second)] += count;
  }
  *labels = std::move(names);
  return counts;
}

// The summary's rates, median errors and per-stage median and p95 times (`stage_ms`: per
// stage, per scene).
void FinishSummary(const std::vector<std::vector<double>>& stage_ms, TableEvalSummary* summary) {
  summary->recall = Ratio(summary->correct, summary->known);
  summary->precision = Ratio(summary->correct, summary->detections);
  summary->class_recall = Ratio(summary->class_correct, summary->known);
  summary->rejection = Ratio(summary->clutter_rejected, summary->clutter);
  summary->visible_recall = Ratio(summary->visible_correct, summary->visible_known);
  summary->visible_class_recall = Ratio(summary->visible_class_correct, summary->visible_known);
  if (!summary->rotation_errors_deg.empty()) {
    summary->median_rotation_deg = Median(summary->rotation_errors_deg);
    summary->median_center_m = Median(summary->center_errors_m);
  }
  for (const std::vector<double>& ms : stage_ms) {
    summary->stage_median_ms.push_back(ms.empty() ? 0.0 : Median(ms));
    summary->stage_p95_ms.push_back(ms.empty() ? 0.0 : Quantile(ms, 0.95));
  }
}

// report.md, report.json and the error histograms in `out_dir`.
void WriteTableEvalReport(const TableEvalSummary& summary, const std::string& out_dir) {
  std::filesystem::create_directories(out_dir);
  WriteFileAtomic(JoinPath(out_dir, "report.md"), summary.Markdown());
  WriteFileAtomic(JoinPath(out_dir, "report.json"), summary.Json() + "\n");
  if (!summary.confusion.empty()) {
    std::vector<std::string> labels;
    const std::vector<std::vector<int>> counts = ConfusionCounts(summary, &labels);
    WriteImageAtomic(JoinPath(out_dir, "confusion.png"),
                     DrawConfusionMatrix(counts, labels,
                                         fmt::format("Tabletop: class recall {:.1f}% ({}/{})",
                                                     100 * summary.class_recall,
                                                     summary.class_correct, summary.known)));
  }
  if (summary.rotation_errors_deg.empty()) return;
  WriteImageAtomic(JoinPath(out_dir, "rotation_errors.png"),
                   DrawHistogram(summary.rotation_errors_deg, 0.0, 10.0, 40,
                                 "Tabletop: rotation error (mod symmetry)", "degrees", 2.0));
  std::vector<double> mm;
  for (const double m : summary.center_errors_m) mm.push_back(1e3 * m);
  WriteImageAtomic(JoinPath(out_dir, "center_errors.png"),
                   DrawHistogram(mm, 0.0, 10.0, 40, "Tabletop: centre error", "mm", 3.0));
}

}  // namespace

void TableEvalOptions::Check() const {
  SOPE_CHECK(scenes >= 1, "table evaluation: scenes must be ≥ 1, got {}", scenes);
  SOPE_CHECK(min_objects >= 1 && max_objects >= min_objects,
             "table evaluation: objects per scene must satisfy 1 ≤ min ≤ max, got {}–{}",
             min_objects, max_objects);
  SOPE_CHECK(clutter >= 0, "table evaluation: clutter must be ≥ 0, got {}", clutter);
  SOPE_CHECK(adds_fraction > 0, "table evaluation: ADD-S fraction must be > 0, got {}",
             adds_fraction);
}

TableEvalSummary RunTableEvaluation(const Database& database, const TableEvalOptions& options,
                                    const std::string& out_dir,
                                    const std::function<void(int, int)>& progress) {
  options.Check();
  ScanAndRecogniseOptions controller_options = SceneControllerOptions(options, out_dir);
  // One scene recogniser for every scene's controller, its per-model caches built before
  // the first scene (as the live loop builds them during its first capture): the scenes'
  // times are then those of a warmed-up loop, not of building the caches of the models
  // each scene meets (the answers are the same either way).
  const SceneRecogniser scene_recogniser(database);
  {
    const Stopwatch warm_up;
    scene_recogniser.WarmUp(controller_options.scene);
    spdlog::info("scene recogniser warmed up: {} models, {:.0f} ms", database.num_models(),
                 warm_up.WallMs());
  }
  controller_options.shared_scene_recogniser = &scene_recogniser;
  // The scans' JSON lines are appended (the controller's contract); the report is rewritten.
  // So that they describe the same run, an earlier run's lines are kept aside, not mixed in.
  if (!controller_options.out_dir.empty()) {
    const std::filesystem::path lines = JoinPath(controller_options.out_dir, "results.jsonl");
    std::error_code error;
    if (std::filesystem::exists(lines, error)) {
      const std::filesystem::path kept = JoinPath(controller_options.out_dir, "results.previous.jsonl");
      std::filesystem::rename(lines, kept, error);
      SOPE_CHECK(!error, "table evaluation: cannot move the earlier run's {} aside: {}",
                 lines.string(), error.message());
      spdlog::info("the earlier run's scan lines are now {}", kept.string());
    }
  }
  TableEvalSummary summary;
  summary.stage_names = {"decode", "triangulate", "segment", "recognise", "frame_to_result"};
  summary.patterns = DescribePatterns(SceneSourceOptions(options, 0).patterns);
  std::vector<std::vector<double>> stage_ms(summary.stage_names.size());
  std::mt19937_64 rng(options.seed);
  std::unique_ptr<VirtualTableSource> procedural;
  for (int k = 0; k < options.scenes; ++k) {
    VirtualTableSourceOptions source_options = SceneSourceOptions(options, k);
    ScanReport report;
    if (!options.meshes.empty()) {
      report = ScanMeshScene(database, options, controller_options, std::move(source_options), k,
                             &rng);
    } else {
      std::optional<ScanReport> scanned = ScanProceduralScene(
          database, options, controller_options, std::move(source_options), k, &procedural);
      if (!scanned) {
        ++summary.skipped_scenes;
        if (progress) progress(k + 1, options.scenes);
        continue;
      }
      report = std::move(*scanned);
    }
    CountScene(report, &summary);
    const ScanRecognitionTimings& t = report.result.timing;
    const double values[] = {t.decode, t.triangulate, t.segment, t.recognise, t.total};
    for (size_t s = 0; s < stage_ms.size(); ++s) stage_ms[s].push_back(values[s]);
    summary.scan_lines.push_back(report.json.empty() ? ScanReportToJson(report) : report.json);
    spdlog::info("{}", ScanReportToText(report));
    if (progress) progress(k + 1, options.scenes);
  }
  FinishSummary(stage_ms, &summary);
  if (!out_dir.empty()) WriteTableEvalReport(summary, out_dir);
  return summary;
}

std::string TableEvalSummary::Markdown() const {
  std::string md = "# Tabletop evaluation (sope eval --table)\n\n";
  md += fmt::format("{} scenes scanned through the full virtual-rig pipeline ({} skipped: their "
                    "objects did not fit on the visible table); {} known objects, {} detections, "
                    "{} clutter objects. Patterns: {}.\n\n",
                    scenes, skipped_scenes, known, detections, clutter, patterns);
  md += "| figure | value |\n|---|---|\n";
  md += fmt::format("| detection recall (model right, ADD-S < 10% diameter) | {:.1f}% ({}/{}) |\n",
                    100 * recall, correct, known);
  md += fmt::format("| detection precision | {:.1f}% ({}/{}) |\n", 100 * precision, correct,
                    detections);
  md += fmt::format("| class recall | {:.1f}% ({}/{}) |\n", 100 * class_recall, class_correct,
                    known);
  md += fmt::format("| recall, objects ≥ 50% visible | {:.1f}% ({}/{}) |\n", 100 * visible_recall,
                    visible_correct, visible_known);
  md += fmt::format("| class recall, objects ≥ 50% visible | {:.1f}% ({}/{}) |\n",
                    100 * visible_class_recall, visible_class_correct, visible_known);
  md += fmt::format("| unknown clutter rejected | {:.1f}% ({}/{}) |\n", 100 * rejection,
                    clutter_rejected, clutter);
  md += fmt::format("| median rotation error (mod symmetry), class-correct | {:.2f}° (n = {}) |\n",
                    median_rotation_deg, rotation_errors_deg.size());
  md += fmt::format("| median centre error, class-correct | {:.2f} mm |\n", 1e3 * median_center_m);
  if (!per_class.empty()) {
    md += "\n| class | objects | detected right | class right | most often taken for |\n"
          "|---|---|---|---|---|\n";
    for (const auto& [name, counts] : per_class) {
      std::string taken_for = "–";
      int most = 0;
      for (const auto& [pair, count] : confusion) {
        if (pair.first == name && pair.second != name && count > most) {
          most = count;
          taken_for = fmt::format("{} ({})", pair.second, count);
        }
      }
      md += fmt::format("| {} | {} | {} | {} | {} |\n", name, counts.known, counts.correct,
                        counts.class_correct, taken_for);
    }
    md += "\n`confusion.png`: rows the true classes (\"clutter\" the unknown objects, "
          "\"none\" a detection of no object), columns the detected ones (\"none\": not "
          "detected).\n";
  }
  md += "\n| stage | median ms | p95 ms |\n|---|---|---|\n";
  for (size_t s = 0; s < stage_names.size(); ++s) {
    md += fmt::format("| {} | {:.1f} | {:.1f} |\n", stage_names[s], stage_median_ms[s],
                      stage_p95_ms[s]);
  }
  return md;
}

std::string TableEvalSummary::Json() const {
  nlohmann::json j = {{"scenes", scenes},
                      {"patterns", patterns},
                      {"skipped_scenes", skipped_scenes},
                      {"known", known},
                      {"detections", detections},
                      {"correct", correct},
                      {"class_correct", class_correct},
                      {"clutter", clutter},
                      {"clutter_rejected", clutter_rejected},
                      {"recall", recall},
                      {"precision", precision},
                      {"class_recall", class_recall},
                      {"visible_recall", visible_recall},
                      {"visible_class_recall", visible_class_recall},
                      {"rejection", rejection},
                      {"median_rotation_error_deg", median_rotation_deg},
                      {"median_center_error_m", median_center_m}};
  nlohmann::json stages;
  for (size_t s = 0; s < stage_names.size(); ++s) {
    stages[stage_names[s]] = {{"median_ms", stage_median_ms[s]}, {"p95_ms", stage_p95_ms[s]}};
  }
  j["stages"] = stages;
  nlohmann::json classes = nlohmann::json::object();
  for (const auto& [name, counts] : per_class) {
    classes[name] = {{"known", counts.known},
                     {"correct", counts.correct},
                     {"class_correct", counts.class_correct}};
  }
  j["per_class"] = classes;
  nlohmann::json pairs = nlohmann::json::array();
  for (const auto& [pair, count] : confusion) {
    pairs.push_back({{"truth", pair.first}, {"detected", pair.second}, {"count", count}});
  }
  j["confusion"] = pairs;
  return j.dump();
}

}  // namespace sope
