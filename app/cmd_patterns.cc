// sope patterns --projector WxH --axes x|y|xy --code gray|binary --out DIR
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/pipeline_flags.h"
#include "core/file_util.h"
#include "projector/patterns.h"

namespace sope {

int RunPatterns(int argc, char** argv) {
  CLI::App app{"Write the stripe pattern sequence as PNG images plus frames.json (the "
               "manifest's camera size is the projector size: these are projector images).",
               "sope patterns"};
  std::string projector_size = "1024x768";
  std::string out;
  cli::PatternFlags pattern_flags;
  cli::LoggingFlags logging;
  app.add_option("--projector", projector_size, "Projector resolution WxH")->capture_default_str();
  pattern_flags.Add(app);
  app.add_option("--out", out, "Output directory")->required();
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  int width = 0, height = 0;
  cli::ParseSize(projector_size, "--projector", &width, &height);
  const PatternOptions options = pattern_flags.ToOptions(width, height);
  FrameSet frames;
  frames.manifest = MakePatternManifest(options, width, height);
  for (const Pattern& pattern : GeneratePatterns(options)) frames.images.push_back(pattern.image);
  WriteFrameSet(out, frames);
  spdlog::info("wrote {} patterns for a {}x{} projector to {}", frames.images.size(), width,
               height, out);
  return 0;
}

}  // namespace sope
