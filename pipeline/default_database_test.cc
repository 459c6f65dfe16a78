// The default database's cache: built once, reused, and never used half-built — an entry
// left incomplete (by an interrupted build of an older version, or damaged since) is
// detected and rebuilt, and Ctrl-C during a build leaves no entry at all.
#include "pipeline/default_database.h"

#include <sys/wait.h>
#include <unistd.h>

#include <csignal>
#include <filesystem>

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/file_util.h"
#include "recogniser/database.h"
#include "tests/test_support.h"

namespace sope {
namespace {

namespace fs = std::filesystem;

// One mug, eight views: a second or so to build.
DefaultDatabaseOptions Tiny(const testing::ScratchDir& scratch) {
  DefaultDatabaseOptions options;
  options.classes = {ObjectClass::kMug};
  options.instances = 1;
  options.views = 8;
  options.cache_root = scratch.File("cache");
  return options;
}

// Hidden staged builds in the cache root.
int StagedBuilds(const std::string& root) {
  int count = 0;
  std::error_code error;
  for (const auto& entry : fs::directory_iterator(root, error)) {
    count += entry.path().filename().string().rfind(".virtual-db-", 0) == 0;
  }
  return count;
}

// First in the binary: it forks, best done before other tests have started threads.
TEST(DefaultDatabase, CtrlCDuringTheBuildLeavesNoEntryAndTheNextRunBuildsIt) {
  testing::ScratchDir scratch;
  const DefaultDatabaseOptions options = Tiny(scratch);
  const std::string directory = DefaultDatabaseDirectory(options);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    // SIGINT with its default action (as from a terminal) in the middle of the build.
    std::signal(SIGINT, SIG_DFL);
    try {
      EnsureDefaultDatabase(options, [](int done, int) {
        if (done >= 3) std::raise(SIGINT);  // progress may skip a count when views finish together
      });
    } catch (...) {
    }
    _exit(0);  // not reached when the signal killed the build
  }
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the build was not interrupted";
  EXPECT_EQ(WTERMSIG(status), SIGINT);
  // Nothing at the entry's place: only the hidden staged build, with models/ and no
  // database — what used to be left at the entry itself.
  EXPECT_FALSE(fs::exists(directory));
  EXPECT_EQ(StagedBuilds(options.cache_root), 1);
  // The next run builds the entry.
  const std::string db_path = EnsureDefaultDatabase(options);
  EXPECT_EQ(IncompleteDefaultDatabaseReason(directory), "");
  EXPECT_EQ(Database::Open(db_path)->num_models(), 1);
  // A staged build older than an hour is a leftover: the next build removes it.
  for (const auto& entry : fs::directory_iterator(options.cache_root)) {
    if (entry.path().filename().string().rfind(".virtual-db-", 0) == 0) {
      fs::last_write_time(entry.path(),
                          fs::file_time_type::clock::now() - std::chrono::hours(2));
    }
  }
  fs::remove_all(directory);
  EnsureDefaultDatabase(options);
  EXPECT_EQ(StagedBuilds(options.cache_root), 0);
}

TEST(DefaultDatabase, IsBuiltOnceWithItsMeshesInTheFinalPlace) {
  testing::ScratchDir scratch;
  const DefaultDatabaseOptions options = Tiny(scratch);
  const std::string directory = DefaultDatabaseDirectory(options);
  EXPECT_FALSE(fs::exists(directory));
  const std::string db_path = EnsureDefaultDatabase(options);
  EXPECT_EQ(db_path, directory + "/db.sopedb");
  EXPECT_EQ(IncompleteDefaultDatabaseReason(directory), "");
  const std::unique_ptr<Database> db = Database::Open(db_path);
  ASSERT_EQ(db->num_models(), 1);
  EXPECT_EQ(db->model(0).class_name, "mug");
  // Procedural classes are categories: unseen instances are recognised as the class.
  EXPECT_TRUE(db->IsCategory(0));
  // The database names its meshes where they stay (the overlay draws them), not in the
  // staging directory it was built in.
  EXPECT_EQ(db->model(0).source_path.rfind(directory + "/models/", 0), 0u)
      << db->model(0).source_path;
  EXPECT_TRUE(fs::is_regular_file(db->model(0).source_path));
  EXPECT_EQ(StagedBuilds(options.cache_root), 0);
  // The second use finds it (same file, not rebuilt).
  const auto written = fs::last_write_time(db_path);
  EXPECT_EQ(EnsureDefaultDatabase(options), db_path);
  EXPECT_EQ(fs::last_write_time(db_path), written);
  // Other contents, another entry.
  DefaultDatabaseOptions more = options;
  more.views = 9;
  EXPECT_NE(DefaultDatabaseDirectory(more), directory);
}

TEST(DefaultDatabase, AnIncompleteEntryIsDetectedAndRebuilt) {
  testing::ScratchDir scratch;
  const DefaultDatabaseOptions options = Tiny(scratch);
  const std::string directory = DefaultDatabaseDirectory(options);
  // What an interrupted build of the old code left: models/ and no db.sopedb.
  WriteProceduralModels(directory + "/models", 1, 0);
  EXPECT_NE(IncompleteDefaultDatabaseReason(directory).find("db.sopedb"), std::string::npos);
  const std::string db_path = EnsureDefaultDatabase(options);
  EXPECT_EQ(IncompleteDefaultDatabaseReason(directory), "");
  EXPECT_EQ(Database::Open(db_path)->num_models(), 1);
  // The old entry's extra classes are gone with it: the entry is the new build only.
  EXPECT_FALSE(fs::exists(directory + "/models/bottle"));

  // A damaged database file (truncated): refused by Database::Open, so rebuilt.
  const std::string bytes = ReadFileToString(db_path, "db");
  WriteFileAtomic(db_path, bytes.substr(0, bytes.size() / 2));
  EXPECT_NE(IncompleteDefaultDatabaseReason(directory), "");
  EnsureDefaultDatabase(options);
  EXPECT_EQ(IncompleteDefaultDatabaseReason(directory), "");
  // A mesh the database names has gone.
  fs::remove_all(directory + "/models");
  EXPECT_NE(IncompleteDefaultDatabaseReason(directory).find("models"), std::string::npos);
  EnsureDefaultDatabase(options);
  EXPECT_EQ(IncompleteDefaultDatabaseReason(directory), "");
}

// Every entry carries sope's marker file; a directory of the user's that happens to stand
// where an entry goes (no marker, files sope does not write) is refused, never deleted.
TEST(DefaultDatabase, EntriesAreMarkedAndAUsersDirectoryIsNeverReplaced) {
  testing::ScratchDir scratch;
  const DefaultDatabaseOptions options = Tiny(scratch);
  const std::string directory = DefaultDatabaseDirectory(options);
  WriteFileAtomic(directory + "/thesis.tex", "mine\n");
  try {
    EnsureDefaultDatabase(options);
    ADD_FAILURE() << "a user's directory was replaced";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(directory), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("did not write"), std::string::npos) << e.what();
  }
  EXPECT_EQ(ReadFileToString(directory + "/thesis.tex", "user file"), "mine\n");
  EXPECT_EQ(StagedBuilds(options.cache_root), 0);

  fs::remove_all(directory);
  EnsureDefaultDatabase(options);
  EXPECT_TRUE(fs::is_regular_file(directory + "/.sope-default-database"));
  // A marked entry whose database went missing is sope's: rebuilt.
  fs::remove(directory + "/db.sopedb");
  EnsureDefaultDatabase(options);
  EXPECT_EQ(IncompleteDefaultDatabaseReason(directory), "");
}

TEST(DefaultDatabase, BadOptionsAndNoCacheDirectoryAreNamed) {
  DefaultDatabaseOptions options;
  options.views = 0;
  try {
    DefaultDatabaseDirectory(options);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("views per model"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace sope
