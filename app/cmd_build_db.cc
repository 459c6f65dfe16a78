// sope build-db --models DIR --out DB.sopedb [--views N] [--layout thesis|fibonacci]
//               [--hash lsh|sh|mlh|bre|itq] [--bits B] [--preset sope|thesis]
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/option_flags.h"
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
  std::string models_dir, out, preset = "sope";
  int threads = 0;
  cli::LoggingFlags logging;
  app.add_option("--models", models_dir, "Models directory")->required();
  app.add_option("--out", out, "Database file to write (.sopedb)")->required();
  app.add_option("--preset", preset,
                 "sope (300 Fibonacci viewpoints, ITQ codes of coarse + fine descriptors) or "
                 "thesis (the thesis's 18 viewpoints, features and MLH codes)")
      ->capture_default_str();
  // --layout, --views, --hash, --bits (DatabaseOptions::Fields()): bound to a scratch copy;
  // those given are applied over the preset's.
  DatabaseOptions given;
  const auto flags = cli::AddOptionFlags(app, &given, DatabaseOptions::Fields());
  auto count = [&](const char* flag) {
    for (const auto& b : flags) {
      if (b.field->flag == flag) return b.option->count();
    }
    return size_t{0};
  };
  app.add_option("--threads", threads, "Worker threads describing views (0 = all cores)")
      ->capture_default_str();
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  DatabaseOptions options = DatabaseOptions::Preset(preset);
  const bool layout_given = count("--layout") > 0, views_given = count("--views") > 0;
  cli::ApplyGivenFlags(flags, given, &options);
  if (views_given) {
    SOPE_CHECK(options.views_per_model >= 1, "--views must be ≥ 1, got {}",
               options.views_per_model);
    if (!layout_given) {
      options.layout = options.views_per_model == 18 &&
                               options.layout == ViewpointLayout::kThesis18
                           ? ViewpointLayout::kThesis18
                           : ViewpointLayout::kFibonacci;
    }
  }
  if (options.layout == ViewpointLayout::kThesis18 && !views_given) {
    options.views_per_model = 18;
  }
  SOPE_CHECK(options.layout != ViewpointLayout::kThesis18 || options.views_per_model == 18,
             "--layout thesis has 18 viewpoints, --views {} given", options.views_per_model);
  SOPE_CHECK(threads >= 0, "--threads must be ≥ 0, got {}", threads);
  options.Check();

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
