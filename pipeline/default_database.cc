#include "pipeline/default_database.h"

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <memory>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "core/error.h"
#include "core/file_util.h"
#include "recogniser/crc32c.h"
#include "recogniser/database.h"

#ifndef SOPE_VERSION
#error "SOPE_VERSION must be defined (pipeline/CMakeLists.txt)"
#endif

namespace sope {
namespace {

namespace fs = std::filesystem;

// A staged build older than this is left over by a killed process: removed.
constexpr auto kStaleStagingAge = std::chrono::hours(1);
// Every cache entry holds this file (written first): StagedDirectory replaces an existing
// entry only when it is there, i.e. sope wrote it.
constexpr char kEntryMarker[] = ".sope-default-database";

// Entries written before the marker existed hold only models/ and (when complete)
// db.sopedb; such an entry is sope's too and may be replaced. Anything else is not.
bool IsOwnEntry(const std::string& directory) {
  std::error_code error;
  if (fs::is_regular_file(JoinPath(directory, kEntryMarker), error)) return true;
  for (const fs::directory_entry& entry : fs::directory_iterator(directory, error)) {
    const std::string name = entry.path().filename().string();
    if (name != "models" && name != "db.sopedb") return false;
  }
  return !error;
}

DatabaseOptions DefaultBuildOptions(const DefaultDatabaseOptions& options) {
  DatabaseOptions db = DatabaseOptions::Preset("sope");
  db.layout = ViewpointLayout::kFibonacci;
  db.views_per_model = options.views;
  return db;
}

std::string EntryName(const DefaultDatabaseOptions& options) {
  // The key changes with the version, the file format and every build option (a checksum
  // of their JSON, and of the class list when it is not all of them).
  std::string text = DatabaseOptionsToJson(DefaultBuildOptions(options));
  for (ObjectClass cls : options.classes) text += "," + ToString(cls);
  const size_t classes =
      options.classes.empty() ? AllObjectClasses().size() : options.classes.size();
  return fmt::format("virtual-db-v{}-f{}-{}x{}-s{}-{}views-{:08x}", SOPE_VERSION,
                     kDatabaseFormatVersion, classes, options.instances, options.seed,
                     options.views, Crc32c(text.data(), text.size()));
}

// Removes staged builds of `name` in `root` that a killed process left behind.
void RemoveStaleStaging(const std::string& root, const std::string& name) {
  std::error_code error;
  const std::string prefix = "." + name + ".tmp-";
  for (const fs::directory_entry& entry : fs::directory_iterator(root, error)) {
    if (entry.path().filename().string().rfind(prefix, 0) != 0) continue;
    const auto age = fs::file_time_type::clock::now() - entry.last_write_time(error);
    if (error || age < kStaleStagingAge) continue;
    spdlog::info("removing an interrupted build of the default database: {}",
                 entry.path().string());
    fs::remove_all(entry.path(), error);
  }
}

// Writes models/ and db.sopedb into `staging`; the database names the meshes by their
// final place, `directory`/models/… (the overlay draws them).
void BuildEntry(const DefaultDatabaseOptions& options, const std::string& staging,
                const std::string& directory, const BuildProgress& progress) {
  WriteFileAtomic(JoinPath(staging, kEntryMarker),
                  "sope default-database cache entry (sope scan-and-recognise)\n");
  const std::string models = JoinPath(staging, "models");
  WriteProceduralModels(models, options.instances, options.seed);
  if (!options.classes.empty()) {
    for (ObjectClass cls : AllObjectClasses()) {
      if (std::find(options.classes.begin(), options.classes.end(), cls) ==
          options.classes.end()) {
        fs::remove_all(JoinPath(models, ToString(cls)));
      }
    }
  }
  BuildSummary summary;
  DatabaseData data = BuildDatabase(ListModels(models), DefaultBuildOptions(options), progress,
                                    &summary, options.threads);
  for (ModelRecord& model : data.models) {
    SOPE_CHECK(model.source_path.rfind(staging, 0) == 0, "model {} outside the build", model.name);
    model.source_path = directory + model.source_path.substr(staging.size());
  }
  WriteDatabase(JoinPath(staging, "db.sopedb"), data);
  spdlog::info("{} -> {}", summary.BriefReport(), JoinPath(directory, "db.sopedb"));
}

}  // namespace

void DefaultDatabaseOptions::Check() const {
  SOPE_CHECK(instances >= 1, "default database: instances per class must be ≥ 1, got {}",
             instances);
  SOPE_CHECK(views >= 1, "default database: views per model must be ≥ 1, got {}", views);
  SOPE_CHECK(threads >= 0, "default database: threads must be ≥ 0, got {}", threads);
}

std::string DefaultDatabaseCacheRoot() {
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg) {
    return JoinPath(xdg, "sope");
  }
  const char* home = std::getenv("HOME");
  SOPE_CHECK(home && *home, "no cache directory for the default database: neither "
             "XDG_CACHE_HOME nor HOME is set");
  return JoinPath(JoinPath(home, ".cache"), "sope");
}

std::string DefaultDatabaseDirectory(const DefaultDatabaseOptions& options) {
  options.Check();
  const std::string root =
      options.cache_root.empty() ? DefaultDatabaseCacheRoot() : options.cache_root;
  return JoinPath(root, EntryName(options));
}

std::string IncompleteDefaultDatabaseReason(const std::string& directory) {
  std::error_code error;
  const std::string db_path = JoinPath(directory, "db.sopedb");
  if (!fs::is_regular_file(db_path, error)) return "db.sopedb is missing";
  if (!fs::is_directory(JoinPath(directory, "models"), error)) return "models/ is missing";
  try {
    const std::unique_ptr<Database> db = Database::Open(db_path);
    for (const ModelRecord& model : db->models()) {
      if (!fs::is_regular_file(model.source_path, error)) {
        return fmt::format("the mesh of model {} ({}) is missing", model.name,
                           model.source_path);
      }
    }
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

std::string EnsureDefaultDatabase(const DefaultDatabaseOptions& options,
                                  const BuildProgress& progress) {
  const std::string directory = DefaultDatabaseDirectory(options);
  const std::string db_path = JoinPath(directory, "db.sopedb");
  std::error_code error;
  if (fs::exists(directory, error)) {
    const std::string reason = IncompleteDefaultDatabaseReason(directory);
    if (reason.empty()) {
      spdlog::info("database: {} (cached)", db_path);
      return db_path;
    }
    spdlog::warn("the cached default database {} is incomplete ({}); building it again",
                 directory, reason);
  }
  const size_t classes =
      options.classes.empty() ? AllObjectClasses().size() : options.classes.size();
  spdlog::info("building the default database (once; cached in {}): {} classes x {} "
               "procedural instances x {} views",
               directory, classes, options.instances, options.views);
  const std::string root = fs::path(directory).parent_path().string();
  RemoveStaleStaging(root, fs::path(directory).filename().string());
  // An incomplete entry may be replaced when sope wrote it (its marker, or the layout of
  // entries from before the marker); a directory of the user's under the same name is
  // refused with one error, never deleted.
  StagedDirectory staged(directory, IsOwnEntry);
  BuildEntry(options, staged.path(), directory, progress);
  staged.Commit();  // replaces an incomplete entry only now
  return db_path;
}

}  // namespace sope
