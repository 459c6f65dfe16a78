// Test helper (header only; for test binaries that link the recogniser and the simulator):
// a database of chosen procedural instances.
#pragma once

#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "recogniser/database.h"
#include "recogniser/tools/database_builder.h"
#include "simulator/procedural_objects.h"
#include "tests/test_support.h"

namespace sope::testing {

// A database of the given procedural instances (per class the instance seeds), 80 views
// each, written in `scratch` (models/ and procedural.sopedb). Its classes are categories
// (as the models directory marks them) unless `categories` is false (then each class is a
// set of instances, as a dataset's folder without a CATEGORY file).
inline std::unique_ptr<Database> ProceduralDatabase(
    const ScratchDir& scratch,
    const std::vector<std::pair<ObjectClass, std::vector<uint64_t>>>& instances,
    bool categories = true) {
  const std::string models = scratch.File("models");
  WriteProceduralModels(models, instances);
  DatabaseOptions db_options = DatabaseOptions::Preset("sope");
  db_options.views_per_model = 80;
  DatabaseData data = BuildDatabase(models, db_options);
  if (!categories) data.categories.clear();
  WriteDatabase(scratch.File("procedural.sopedb"), data);
  return Database::Open(scratch.File("procedural.sopedb"));
}

}  // namespace sope::testing
