// sope build-db --models DIR --out DB.sopedb [--views N] [--layout thesis|fibonacci]
//               [--hash lsh|sh|mlh|bre|itq] [--bits B] [--preset sope|thesis]
//               [--units auto|m|cm|mm|in|METRES]
#include <map>
#include <set>
#include <string>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/option_flags.h"
#include "core/error.h"
#include "core/mesh.h"
#include "recogniser/database.h"
#include "recogniser/tools/database_builder.h"

namespace sope {
namespace {

// Beyond these the build is not useful, only long: 2000 Fibonacci viewpoints are ≈ 4.5°
// apart (the sope preset uses 300, the thesis 18), and no machine has more cores to feed.
constexpr int kMaxViewsPerModel = 2000;
constexpr int kMaxThreads = 256;

}  // namespace

int RunBuildDb(int argc, char** argv) {
  CLI::App app{"Build a recognition database (.sopedb) from a models directory "
               "DIR/<class>/<model>.{obj,ply,off,stl} (a mesh directly in DIR is its own "
               "class): every model is rendered from many viewpoints by an ideal depth "
               "camera, each view described like a query, the descriptors hashed. Meshes "
               "whose size is implausible in metres (bounding-box diagonal outside "
               "[0.02, 0.75]) are scaled to a 0.25 m diagonal, unless --units gives the files' "
               "unit (e.g. mm for BOP models: the real objects' size). Unreadable meshes are "
               "reported and skipped. A class folder holding a file named CATEGORY (as `sope "
               "objects` writes) is a category of alike objects, whose unseen instances the "
               "tabletop recogniser may take for the class; any other folder of several "
               "models is a set of instances (see --categories).",
               "sope build-db"};
  std::string models_dir, out, preset = "sope", units = "auto", categories = "auto";
  int threads = 0;
  cli::LoggingFlags logging;
  app.add_option("--models", models_dir, "Models directory")->required();
  app.add_option("--out", out, "Database file to write (.sopedb)")->required();
  app.add_option("--preset", preset,
                 "sope (300 Fibonacci viewpoints, ITQ codes of coarse + fine descriptors) or "
                 "thesis (the thesis's 18 viewpoints, features and MLH codes)")
      ->capture_default_str();
  // --views, --layout, --hash and --bits come from the field descriptions of
  // DatabaseOptions (recogniser/database.cc): bound to a scratch struct, and only those
  // given are applied over the preset (ResolveDatabaseOptions).
  DatabaseOptions given;
  const std::vector<cli::BoundFlag<DatabaseOptions>> bound =
      cli::AddOptionFlags(app, &given, DatabaseOptions::Fields());
  cli::AddMeshUnitFlag(app, &units);
  app.add_option("--categories", categories,
                 "Which classes are categories (alike objects: unseen instances recognised "
                 "as the class): auto (the class folders holding a CATEGORY file), all, or "
                 "none")
      ->check(CLI::IsMember({"auto", "all", "none"}))
      ->capture_default_str();
  app.add_option("--threads", threads, "Worker threads describing views (0 = all cores)")
      ->capture_default_str();
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  DatabasePresetChoices choices;
  choices.preset = preset;
  for (const cli::BoundFlag<DatabaseOptions>& flag : bound) {
    if (flag.option->count() == 0) continue;
    const OptionField<DatabaseOptions>& field = *flag.field;
    if (field.IsNumber()) {
      SOPE_CHECK(field.InRange(field.Number(given)), "{} must be {}, got {}", field.flag,
                 field.RangeText(), field.Number(given));
    }
    if (field.name == "views_per_model") {
      SOPE_CHECK(given.views_per_model <= kMaxViewsPerModel, "--views must be in [1, {}], got {}",
                 kMaxViewsPerModel, given.views_per_model);
      choices.views = given.views_per_model;
    } else if (field.name == "layout") {
      choices.layout = given.layout;
    } else if (field.name == "hash.method") {
      choices.hash = given.hash.method;
    } else if (field.name == "hash.bits") {
      choices.bits = given.hash.bits;
    } else {
      SOPE_THROW("build-db: the flag {} has no preset choice (internal)", field.flag);
    }
  }
  SOPE_CHECK(threads >= 0 && threads <= kMaxThreads, "--threads must be in [0, {}], got {}",
             kMaxThreads, threads);
  DatabaseOptions options = ResolveDatabaseOptions(choices);
  options.size.mesh_unit = cli::ParseMeshUnit(units, "--units");

  std::vector<ModelSource> models = ListModels(models_dir);
  if (categories != "auto") {
    for (ModelSource& model : models) model.category = categories == "all";
  }
  spdlog::info("{} meshes in {}; {} {} viewpoints each, {} {}-bit codes", models.size(),
               models_dir, options.views_per_model, ToString(options.layout),
               ToString(options.hash.method), options.hash.bits);
  // The classes (DIR/<class>/<model>; a flat file's class is its name), so that a folder
  // that groups unlike objects (a dataset's) is seen to make them one class.
  std::map<std::string, int> class_sizes;
  std::set<std::string> category_names;
  for (const ModelSource& model : models) {
    ++class_sizes[model.class_name];
    if (model.category) category_names.insert(model.class_name);
  }
  // Each class with its size and whether it is a category; the folders of several models
  // that are not (sets of instances) named once more below.
  std::string classes, instance_sets;
  for (const auto& [name, count] : class_sizes) {
    const bool category = category_names.count(name) != 0;
    classes += fmt::format("{}{} ({}{})", classes.empty() ? "" : ", ", name, count,
                           category ? ", category" : "");
    if (count >= 2 && !category) {
      instance_sets += fmt::format("{}{}", instance_sets.empty() ? "" : ", ", name);
    }
  }
  spdlog::info("{} classes: {}", class_sizes.size(), classes);
  if (!instance_sets.empty()) {
    spdlog::info("{}: sets of instances (only their models are recognised); a folder of alike "
                 "objects whose unseen instances should be recognised as the class needs a "
                 "file named {} (or --categories all)",
                 instance_sets, kCategoryMarker);
  }
  BuildSummary summary;
  DatabaseData data;
  {
    cli::Progress progress("rendering views", models.size() * options.views_per_model);
    data = BuildDatabase(models, options, [&](int done, int) { progress.Update(done); }, &summary,
                         threads);
  }
  WriteDatabase(out, data);
  spdlog::info("{} -> {}", summary.BriefReport(), out);
  if (!summary.skipped.empty()) {
    spdlog::warn("{} of {} meshes skipped (see the warnings above)", summary.skipped.size(),
                 models.size());
  }
  return 0;
}

}  // namespace sope
