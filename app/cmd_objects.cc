// sope objects --instances N --seed S --out DIR
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "core/error.h"
#include "simulator/procedural_objects.h"

namespace sope {

int RunObjects(int argc, char** argv) {
  CLI::App app{"Write procedural household objects (mug, bottle, bowl, box, can, glass, plate, "
               "vase, wine glass, saucepan) as a models directory for sope build-db / sope "
               "eval: DIR/<class>/<class>_<k>.obj, instance k drawn from seed S + k. Seeds S "
               "and S' >= S + N give disjoint instances (training vs held-out).",
               "sope objects"};
  std::string out;
  int instances = 3;
  uint64_t seed = 1;
  cli::LoggingFlags logging;
  app.add_option("--out", out, "Models directory to write")->required();
  app.add_option("--instances", instances, "Instances per class")->capture_default_str();
  // CLI11 would wrap "-1" into 2^64 − 1 for the unsigned seed: refuse a sign.
  app.add_option("--seed", seed, "Seed of the first instance")
      ->check(CLI::Validator(
          [](std::string& text) {
            return text.find('-') != std::string::npos ? "must be ≥ 0, got " + text
                                                       : std::string();
          },
          "UINT", "non-negative"))
      ->capture_default_str();
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();
  SOPE_CHECK(instances >= 1 && instances <= kMaxInstancesPerClass,
             "--instances must be in [1, {}], got {}", kMaxInstancesPerClass, instances);
  const std::vector<std::string> written = WriteProceduralModels(out, instances, seed);
  spdlog::info("wrote {} meshes ({} per class, seeds {}–{}) to {}", written.size(), instances,
               seed, seed + instances - 1, out);
  return 0;
}

}  // namespace sope
