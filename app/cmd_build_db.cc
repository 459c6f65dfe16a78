// sope build-db --models DIR --out DB.sopedb [--views N] [--layout thesis|fibonacci]
//               [--hash lsh|sh|mlh|bre|itq] [--bits B] [--preset sope|thesis]
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "core/error.h"
#include "recogniser/database.h"
#include "recogniser/tools/database_builder.h"

namespace sope {

int RunBuildDb(int argc, char** argv) {
  CLI::App app{"Build a recognition database (.sopedb) from a models directory "
               "DIR/<class>/<model>.{obj,ply,off,stl} (a mesh directly in DIR is its own "
               "class): every model is rendered from many viewpoints by an ideal depth "
               "camera, each view described like a query, the descriptors hashed. Meshes "
               "whose size is implausible in metres (bounding-box diagonal outside "
               "[0.02, 0.75]) are scaled to a 0.25 m diagonal. Unreadable meshes are reported "
               "and skipped.",
               "sope build-db"};
  std::string models_dir, out, preset = "sope", layout, hash;
  int views = 0, bits = 0, threads = 0;
  cli::LoggingFlags logging;
  app.add_option("--models", models_dir, "Models directory")->required();
  app.add_option("--out", out, "Database file to write (.sopedb)")->required();
  app.add_option("--preset", preset,
                 "sope (300 Fibonacci viewpoints, ITQ codes of coarse + fine descriptors) or "
                 "thesis (the thesis's 18 viewpoints, features and MLH codes)")
      ->capture_default_str();
  CLI::Option* views_option =
      app.add_option("--views", views, "Viewpoints per model (default: the preset's)");
  CLI::Option* layout_option = app.add_option(
      "--layout", layout,
      "Viewpoints: thesis (18 on five declination rings) or fibonacci (any number, even "
      "sphere sampling); default: thesis for 18 views under --preset thesis, else fibonacci");
  app.add_option("--hash", hash, "Binary codes: lsh, sh, mlh, bre or itq (default: the preset's)");
  app.add_option("--bits", bits, "Code length, bits (default: the preset's, 64)");
  app.add_option("--threads", threads, "Worker threads describing views (0 = all cores)")
      ->capture_default_str();
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  DatabasePresetChoices choices;
  choices.preset = preset;
  if (views_option->count() > 0) {
    SOPE_CHECK(views >= 1, "--views must be ≥ 1, got {}", views);
    choices.views = views;
  }
  if (layout_option->count() > 0) choices.layout = ViewpointLayoutFromString(layout);
  if (!hash.empty()) choices.hash = HashMethodFromString(hash);
  if (bits != 0) choices.bits = bits;
  SOPE_CHECK(threads >= 0, "--threads must be ≥ 0, got {}", threads);
  const DatabaseOptions options = ResolveDatabaseOptions(choices);

  const std::vector<ModelSource> models = ListModels(models_dir);
  spdlog::info("{} meshes in {}; {} {} viewpoints each, {} {}-bit codes", models.size(),
               models_dir, options.views_per_model, ToString(options.layout),
               ToString(options.hash.method), options.hash.bits);
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
