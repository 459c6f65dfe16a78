// The default database of the virtual rig (`sope scan-and-recognise` without a database):
// every procedural class, `instances` instances (seeds seed …), `views` Fibonacci
// viewpoints each, the "sope" preset — built on first use and cached under
// CACHE/virtual-db-<key>/ (models/ and db.sopedb; the key names everything that decides
// the contents, so a stale entry is never used).
//
// An entry appears only complete: it is built in a staged sibling directory and renamed
// into place when db.sopedb is written (core/file_util.h StagedDirectory), so an
// interrupted build (Ctrl-C, a full disk) leaves no entry. An entry that is nevertheless
// incomplete or unreadable (written by an older version, damaged since) is detected on use
// and rebuilt.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "recogniser/tools/database_builder.h"
#include "simulator/procedural_objects.h"

namespace sope {

struct DefaultDatabaseOptions {
  // 16 instances per class: class top-1 on unseen instances grows with the instances (see
  // README "Scan and recognise": 2 → 8 → 16 instances); 16 × 10 classes × 100 views =
  // 16000 views, ~5 CPU-minutes (~2.6 min on 2 cores) to build once.
  int instances = 16;
  int views = 100;
  uint64_t seed = 0;
  // The classes; empty: every procedural class (AllObjectClasses).
  std::vector<ObjectClass> classes;
  // Where entries live; empty: DefaultDatabaseCacheRoot().
  std::string cache_root;
  int threads = 0;  // building: worker threads (0 = all cores)
  void Check() const;
};
// Unseen instances for the virtual scenes start here (the default database holds seeds
// seed … seed + instances − 1, far below).
constexpr uint64_t kUnseenInstanceSeedBase = 1000;

// $XDG_CACHE_HOME/sope, else $HOME/.cache/sope. Throws sope::Error when neither is set.
std::string DefaultDatabaseCacheRoot();
// The entry directory for `options` (whether or not it exists).
std::string DefaultDatabaseDirectory(const DefaultDatabaseOptions& options);
// Why the entry at `directory` cannot be used ("" when it is complete): db.sopedb missing
// or unreadable (Database::Open refuses it), models/ missing, or a model mesh the database
// names missing.
std::string IncompleteDefaultDatabaseReason(const std::string& directory);

// The path of the entry's db.sopedb, building the entry first when it is absent or
// incomplete. `progress` is called while views are built. Throws sope::Error.
std::string EnsureDefaultDatabase(const DefaultDatabaseOptions& options = {},
                                  const BuildProgress& progress = {});

}  // namespace sope
