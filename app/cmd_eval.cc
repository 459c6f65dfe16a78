// sope eval --db DB.sopedb [--models HELD_OUT_DIR] [--method sope|thesis] --out DIR
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/option_flags.h"
#include "app/pipeline_flags.h"
#include "core/error.h"
#include "recogniser/bop.h"
#include "recogniser/database.h"
#include "recogniser/tools/evaluation.h"
#include "simulator/virtual_rig.h"
#include "pipeline/table_eval.h"

namespace sope {

namespace {

// The tabletop protocol's flags (issue 12).
struct TableFlags {
  bool table = false, procedural = false;
  TableEvalOptions options;
  std::vector<std::string> meshes;

  void Add(CLI::App& app) {
    app.add_flag("--table", table,
                 "Tabletop protocol: table scenes of --min-objects..--max-objects objects (the "
                 "database's model files, or --procedural unseen instances of its procedural "
                 "classes) and --clutter unknown objects, scanned through the full virtual-rig "
                 "pipeline and recognised in tabletop mode: detection recall/precision (model "
                 "right, ADD-S < 10% diameter), class recall, pose errors, unknown rejection, "
                 "per-stage ms, per-class figures. Writes DIR/report.md, report.json, "
                 "confusion.png, rotation_errors.png, center_errors.png, scans/");
    app.add_option("--scenes", options.scenes, "--table: scenes")->capture_default_str();
    app.add_option("--min-objects", options.min_objects, "--table: objects per scene, least")
        ->capture_default_str();
    app.add_option("--max-objects", options.max_objects, "--table: objects per scene, most")
        ->capture_default_str();
    app.add_option("--clutter", options.clutter, "--table: unknown clutter objects per scene")
        ->capture_default_str();
    app.add_option("--table-mesh", meshes,
                   "--table: mesh specs to draw scenes from (default: every model file of the "
                   "database)");
    app.add_flag("--procedural", procedural,
                 "--table: procedural objects (unseen instances of the database's procedural "
                 "classes) instead of mesh files");
  }
};

// `sope eval --table`: the tabletop protocol (pipeline/table_eval.h).
int RunTableEval(const std::string& db_path,
                 const std::vector<cli::BoundFlag<RecognitionOptions>>& recognition_flags,
                 const RecognitionOptions& given, const EvalOptions& options,
                 const TableFlags& flags, const std::string& out) {
  TableEvalOptions table_options = flags.options;
  const std::unique_ptr<Database> db = Database::Open(db_path);
  cli::ApplyGivenFlags(recognition_flags, given, &table_options.controller.recognition);
  table_options.seed = options.seed;
  table_options.adds_fraction = options.adds_fraction;
  if (!flags.procedural) {
    table_options.meshes = flags.meshes;
    if (table_options.meshes.empty()) {
      for (const ModelRecord& model : db->models()) {
        table_options.meshes.push_back(model.source_path);
      }
    }
  }
  TableEvalSummary summary;
  {
    cli::Progress progress("scanning table scenes", table_options.scenes);
    summary = RunTableEvaluation(*db, table_options, out,
                                 [&](int done, int) { progress.Update(done); });
  }
  std::printf("%s", summary.Markdown().c_str());
  spdlog::info("report: {}/report.md, report.json, confusion.png, rotation_errors.png, "
               "center_errors.png", out);
  return 0;
}

// --bop-csv: the estimates as a BOP challenge results CSV.
void WriteBopEstimates(const EvalReport& report, const std::string& bop_csv) {
  std::vector<BopEstimate> estimates;
  for (size_t q = 0; q < report.outcomes.size(); ++q) {
    const QueryOutcome& outcome = report.outcomes[q];
    if (outcome.predicted_model_index < 0) continue;
    estimates.push_back({1, static_cast<int>(q), outcome.predicted_model_index + 1,
                         outcome.score, outcome.estimated_cam_from_model,
                         outcome.timing.total / 1000.0});
  }
  WriteBopCsv(bop_csv, estimates);
  spdlog::info("BOP results: {} estimates -> {}", estimates.size(), bop_csv);
}

// The instance or class protocol (recogniser/tools/evaluation.h).
int RunProtocolEval(const std::string& db_path, const std::string& models_dir,
                    const std::string& protocol_text, const std::string& method,
                    const std::vector<cli::BoundFlag<RecognitionOptions>>& recognition_flags,
                    const RecognitionOptions& given, EvalOptions options, const std::string& out,
                    const std::string& bop_csv) {
  options.protocol = protocol_text.empty()
                         ? (models_dir.empty() ? EvalProtocol::kInstance : EvalProtocol::kClass)
                         : EvalProtocolFromString(protocol_text);
  SOPE_CHECK(options.protocol == EvalProtocol::kInstance || !models_dir.empty(),
             "the class protocol needs --models DIR (held-out meshes of the database's classes)");
  SOPE_CHECK(options.protocol == EvalProtocol::kClass || models_dir.empty(),
             "--models is for the class protocol; the instance protocol queries the database's "
             "own models");
  const std::unique_ptr<Database> db = Database::Open(db_path);
  if (method == "thesis") {
    options.recognition = RecognitionOptions::ThesisPreset(db->hasher().method());
  } else {
    SOPE_CHECK(method == "sope", "unknown --method '{}' (sope or thesis)", method);
  }
  options.method_name = method;
  cli::ApplyGivenFlags(recognition_flags, given, &options.recognition);
  options.Check();

  std::vector<std::string> skipped;
  const std::vector<EvalModel> models = options.protocol == EvalProtocol::kInstance
                                            ? InstanceModels(*db)
                                            : HeldOutModels(*db, models_dir, &skipped);
  for (const std::string& s : skipped) spdlog::warn("skipped {}", s);
  EvalReport report;
  {
    cli::Progress progress("recognising queries", models.size() * options.queries_per_model);
    report = Evaluate(*db, models, options, [&](int done, int) { progress.Update(done); });
  }
  report.skipped_models = skipped;
  WriteEvalReport(report, out);
  if (!bop_csv.empty()) WriteBopEstimates(report, bop_csv);
  std::printf("%s\n", report.BriefReport().c_str());
  spdlog::info("report: {}/report.md, report.json, confusion.png, pose_errors.png", out);
  return 0;
}

}  // namespace

int RunEval(int argc, char** argv) {
  CLI::App app{"Evaluate the recogniser on synthetic queries with ground truth, rendered off "
               "the database's viewpoint grid (random viewpoint, roll, distance and off-axis "
               "angle, depth noise, partial occlusion). Instance protocol (default): queries "
               "of the database's own models — model/class accuracy, viewpoint, rotation "
               "(modulo symmetry), centre and ADD-S errors. Class protocol (--models DIR): "
               "held-out meshes of the database's classes — class accuracy and viewpoint "
               "error. Writes DIR/report.md, report.json, confusion.png, pose_errors.png.",
               "sope eval"};
  std::string db_path, models_dir, out, method = "sope", protocol_text;
  EvalOptions options;
  cli::LoggingFlags logging;
  app.add_option("--db", db_path, "Database file (.sopedb, from sope build-db)")->required();
  app.add_option("--models", models_dir,
                 "Held-out models directory (class protocol), DIR/<class>/<model>.obj")
      ->check(CLI::ExistingDirectory);
  app.add_option("--protocol", protocol_text,
                 "instance or class (default: class with --models, else instance)");
  app.add_option("--out", out, "Report directory")->required();
  std::string bop_csv;
  app.add_option("--bop-csv", bop_csv,
                 "Also write the estimates as a BOP challenge results CSV (scene_id 1, im_id = "
                 "query number, obj_id = database model index + 1, t in mm, time in s)");
  app.add_option("--method", method,
                 "Recognition options: sope (ours) or thesis (radius search, VFH + radial "
                 "ranking, no pose refinement)")
      ->capture_default_str();
  app.add_option("--queries-per-model", options.queries_per_model, "Queries of each model")
      ->capture_default_str();
  app.add_option("--seed", options.seed, "Seed of the query poses")->capture_default_str();
  app.add_option("--min-distance", options.query.min_distance, "Query distance, metres")
      ->capture_default_str();
  app.add_option("--max-distance", options.query.max_distance, "Query distance, metres")
      ->capture_default_str();
  app.add_option("--noise", options.query.depth_noise, "Depth noise σ at 0.6 m, metres")
      ->capture_default_str();
  app.add_option("--occlusion", options.query.max_occlusion,
                 "Largest fraction of the object hidden")
      ->capture_default_str();
  app.add_flag("--scan-pipeline", options.through_scan,
               "Scan every query on the virtual rig (patterns rendered, decoded, triangulated, "
               "range band) instead of rendering its depth; no occluder; ~1 s per query");
  app.add_flag("--scan-occlusion", options.occlude_scans,
               "With --scan-pipeline: the query's occluder (--occlusion) hides its share of "
               "the scanned object's points");
  // The scanned queries' pattern sequence: the flags of `sope patterns` / `scan`.
  cli::PatternFlags pattern_flags;
  CLI::App* patterns_group =
      app.add_option_group("scan patterns (--scan-pipeline)",
                           "The pattern sequence scanned queries are captured with (default "
                           "Gray code x and y with inverses): --code phase --periods "
                           "1024,128,16, --code gray+phase --period 16, ...");
  pattern_flags.Add(*patterns_group);
  app.add_option("--adds", options.adds_fraction, "ADD-S threshold, fraction of the diameter")
      ->capture_default_str();
  TableFlags table;
  table.Add(app);
  // Recognition options (--top, --pose-models, --flag-fraction, …; RecognitionOptions::
  // Fields()): bound to a scratch copy, and those given are applied over the method's.
  RecognitionOptions given;
  const auto recognition_flags = cli::AddOptionFlags(app, &given, RecognitionOptions::Fields());
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  if (patterns_group->count_all() > 0) {
    SOPE_CHECK(options.through_scan || table.table,
               "pattern flags (--code, --periods, ...) are for scanned queries (--scan-pipeline "
               "or --table)");
    // Checked on the scanned protocols' projector, the virtual rig's.
    const CameraModel projector = DefaultRigCalibration().projector;
    (table.table ? table.options.source.patterns : options.scan_patterns) =
        pattern_flags.ToOptions(projector.width, projector.height);
  }
  if (table.table) return RunTableEval(db_path, recognition_flags, given, options, table, out);
  return RunProtocolEval(db_path, models_dir, protocol_text, method, recognition_flags, given,
                         options, out, bop_csv);
}

}  // namespace sope
