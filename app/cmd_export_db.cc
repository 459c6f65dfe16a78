// sope export-db --db DB.sopedb --faiss-binary FILE
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "recogniser/database.h"
#include "recogniser/faiss_coarse_index.h"

namespace sope {

int RunExportDb(int argc, char** argv) {
  CLI::App app{"Write the database's coarse binary codes as a FAISS binary index "
               "(faiss::write_index_binary: an IndexBinaryIDMap over an IndexBinaryFlat, one "
               "entry per view in database order, id = view index), readable by "
               "faiss.read_index_binary, plus FILE.json naming the views (models, classes, "
               "view ranges). `sope recognise --coarse-index FILE` searches it.",
               "sope export-db"};
  std::string db_path, faiss_path;
  cli::LoggingFlags logging;
  app.add_option("--db", db_path, "Database file (.sopedb)")->required();
  app.add_option("--faiss-binary", faiss_path, "FAISS binary index to write")->required();
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  const std::unique_ptr<Database> db = Database::Open(db_path);
  WriteFaissBinaryIndex(*db, faiss_path);
  spdlog::info("wrote {} {}-bit codes -> {} (+ {}.json)", db->num_views(), db->codes().bits,
               faiss_path, faiss_path);
  return 0;
}

}  // namespace sope
