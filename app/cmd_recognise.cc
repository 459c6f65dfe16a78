// sope recognise --db DB.sopedb --cloud CLOUD.{ply,pcd} [--cloud-units mm] [--top 4] [--json]
//                [--table [--object-clouds DIR] [--min-range M] [--max-range M]]
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "app/cli_util.h"
#include "app/commands.h"
#include "app/option_flags.h"
#include "core/error.h"
#include "core/point_cloud.h"
#include "recogniser/database.h"
#include "recogniser/faiss_coarse_index.h"
#include "recogniser/recogniser.h"
#include "recogniser/scene_recognition.h"

namespace sope {
namespace {

// A cloud whose points lie a median of more than this many units from the camera is not in
// metres (no structured-light rig works at 20 m): most likely millimetres.
constexpr double kImplausibleMedianRange = 20.0;

// "" or the hint that `cloud` looks like millimetres, not metres.
std::string UnitHint(const PointCloud& cloud) {
  std::vector<float> ranges;
  const size_t step = std::max<size_t>(1, cloud.size() / 4096);
  for (size_t i = 0; i < cloud.size(); i += step) {
    if (cloud.points[i].allFinite()) ranges.push_back(cloud.points[i].norm());
  }
  if (ranges.empty()) return "";
  std::nth_element(ranges.begin(), ranges.begin() + ranges.size() / 2, ranges.end());
  const double median = ranges[ranges.size() / 2];
  if (!(median > kImplausibleMedianRange)) return "";
  return fmt::format("the cloud's points lie a median {:.4g} units from the camera: recognise "
                     "reads metres; in millimetres? give --cloud-units mm",
                     median);
}

}  // namespace

int RunRecognise(int argc, char** argv) {
  CLI::App app{"Recognise the object in a point cloud (metres, camera frame) and estimate its "
               "pose: class, model, database viewpoint and cam_from_model (X_cam = R·X_model + "
               "t), ICP-refined and verified. --json prints one JSON object per line.",
               "sope recognise"};
  std::string db_path, cloud_path, cloud_units = "m";
  RecognitionOptions options;
  bool json = false, no_pose = false, table = false;
  std::string object_clouds_dir;
  std::string coarse_index_path;
  std::optional<double> min_range, max_range;
  cli::LoggingFlags logging;
  app.add_option("--db", db_path, "Database file (.sopedb, from sope build-db)")->required();
  app.add_option("--cloud", cloud_path, "Query cloud (.ply or .pcd)")->required();
  CLI::Option* cloud_units_option =
      app.add_option("--cloud-units", cloud_units,
                     "Unit of the cloud's coordinates: m, cm, mm, in, or metres per unit (the "
                     "results and --object-clouds segments are in metres)")
          ->capture_default_str();
  cli::AddOptionFlags(app, &options, RecognitionOptions::Fields());
  app.add_flag("--no-pose", no_pose, "Skip pose estimation and verification (ranking only)");
  app.add_flag("--json", json, "Print the result as one JSON object");
  app.add_flag("--table", table,
               "Tabletop scene: find the table plane (RANSAC), cluster what stands on it, "
               "recognise every cluster and verify the scene as a whole; the JSON line gains "
               "\"objects\" (every recognised object) and \"unknown\" (clusters no model "
               "explains). Nothing recognised is a result (\"objects\": [])");
  app.add_option("--object-clouds", object_clouds_dir,
                 "--table: write each recognised object's segment to DIR/object_K.ply (K as in "
                 "\"objects\") and each unknown one's to DIR/unknown_K.ply");
  app.add_option("--min-range", min_range,
                 "--table: segment only points at least this far from the camera, metres "
                 "(default 0.05)");
  app.add_option("--max-range", max_range,
                 "--table: segment only points at most this far from the camera, metres "
                 "(default 2; a scan-and-recognise result gives its band as "
                 "scan.range_band_m: the same band recognises its scan_NNNN.ply as the scan "
                 "did)");
  app.add_option("--coarse-index", coarse_index_path,
                 "Coarse stage from a FAISS binary index of the database's codes (sope export-db "
                 "--faiss-binary) instead of the built-in Hamming scan");
  logging.Add(app);
  if (const int code = cli::Parse(app, argc, argv); code >= 0) return code;
  logging.Apply();

  const double cloud_unit = cli::ParseLengthUnit(cloud_units, "--cloud-units");
  if (no_pose) options.screening.models = 0;
  options.Check();
  SOPE_CHECK(table || object_clouds_dir.empty(), "--object-clouds needs --table");
  SOPE_CHECK(table || (!min_range && !max_range), "--min-range and --max-range need --table");
  SceneRecognitionOptions scene_options;  // its recognition options set below
  if (min_range) scene_options.segmentation.min_range = *min_range;
  if (max_range) scene_options.segmentation.max_range = *max_range;
  if (table) scene_options.Check();

  const std::unique_ptr<Database> db = Database::Open(db_path);
  PointCloud cloud = ReadPointCloud(cloud_path);
  if (cloud_unit != 1.0) {
    for (Eigen::Vector3f& p : cloud.points) p *= static_cast<float>(cloud_unit);
  }
  // Only when no unit was given: a user who gave one meant it.
  const std::string hint = cloud_units_option->count() > 0 ? "" : UnitHint(cloud);
  std::unique_ptr<FaissCoarseIndex> coarse_index;
  if (!coarse_index_path.empty()) {
    coarse_index = FaissCoarseIndex::Read(coarse_index_path, db->codes().bits, db->num_views());
    options.coarse.coarse_kbest = [&](const uint64_t* code, int k) {
      return coarse_index->KBestSearch(code, k);
    };
  }
  if (table) {
    scene_options.recognition = options;
    const SceneRecognitionResult scene = SceneRecogniser(*db).Recognise(cloud, scene_options);
    if (!object_clouds_dir.empty()) {
      std::error_code error;
      std::filesystem::create_directories(object_clouds_dir, error);
      SOPE_CHECK(!error, "cannot create {}: {}", object_clouds_dir, error.message());
      auto write = [&](const std::string& name, const std::vector<int>& indices) {
        PointCloud part;
        for (const int i : indices) {
          part.points.push_back(cloud.points[i]);
          if (cloud.HasColors()) part.colors.push_back(cloud.colors[i]);
        }
        WritePointCloud(object_clouds_dir + "/" + name, part);
      };
      for (size_t k = 0; k < scene.objects.size(); ++k) {
        write("object_" + std::to_string(k) + ".ply", scene.objects[k].indices);
      }
      for (size_t k = 0; k < scene.unknown.size(); ++k) {
        write("unknown_" + std::to_string(k) + ".ply", scene.unknown[k].indices);
      }
    }
    // Nothing on a table is a result; a cloud in the wrong unit gets a hint beside it.
    if (scene.objects.empty() && !hint.empty()) spdlog::warn("{}", hint);
    std::printf("%s\n", json ? SceneRecognitionResultToJson(scene).c_str()
                             : SceneBriefReport(scene).c_str());
    return 0;
  }
  RecognitionResult result;
  try {
    result = Recogniser(*db).Recognise(cloud, options);
  } catch (const Error& e) {
    if (hint.empty()) throw;
    SOPE_THROW("{} ({})", e.what(), hint);
  }
  SOPE_CHECK(!result.empty(), "no suggestion (the database has no comparable view)");
  if (json) {
    // Not recognised: "class": null, the best guess among the candidates.
    std::printf("%s\n", RecognitionResultToJson(result).c_str());
  } else {
    std::printf("%s\n", result.BriefReport().c_str());
  }
  return 0;
}

}  // namespace sope
