// Database construction (thesis §4.4–4.5, functional units 4 and 5): every model mesh is
// rendered as a partial cloud from each viewpoint (simulator DepthRenderer: an ideal depth
// camera, occlusion by the depth buffer — the thesis's ray–triangle test, eq. 4.7–4.10),
// each view pre-processed and described exactly like a query (DescribeView), the coarse
// vectors standardised, the hasher trained on them and the codes computed.
//
// Models directory (DESIGN.md): DIR/<class>/<model>.{obj,ply,off,stl} (extension
// case-insensitive); a mesh directly in DIR is its own class, named after the file. Other
// files and deeper directories are ignored. Sizes: see SizeNormalisationOptions.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "core/mesh.h"
#include "recogniser/database.h"

namespace sope {

struct ModelSource {
  std::string path;        // mesh file
  std::string name;        // file stem
  std::string class_name;  // its directory, or `name` for a file directly in DIR
  // Its class is a category (DatabaseData::categories): the class directory holds a file
  // named kCategoryMarker.
  bool category = false;
};

// The meshes of a models directory, sorted by class then name, with their class's
// category flag. Throws sope::Error when `models_dir` is not a readable directory or holds
// no mesh file.
std::vector<ModelSource> ListModels(const std::string& models_dir);

// The scale SizeNormalisationOptions gives a mesh: mesh_unit when given, else 1 when its
// bounding-box diagonal is plausible in metres, else target_diagonal / diagonal.
double SizeNormalisationScale(const TriangleMesh& mesh, const SizeNormalisationOptions& options);

struct BuildSummary {
  int models = 0;                    // built
  std::vector<std::string> skipped;  // "path: reason" for each mesh left out
  int views = 0;                     // stored
  int dropped_views = 0;             // rendered but left out (too few points, e.g. a plate
                                     // seen edge-on)
  double render_seconds = 0.0;       // rendering (main thread)
  double describe_seconds = 0.0;     // pre-processing + features, summed over threads
  double hash_seconds = 0.0;
  double total_seconds = 0.0;
  HashTrainingSummary hash;
  std::string BriefReport() const;
};

// What may be chosen on top of a preset (`sope build-db`); unset fields keep the preset's.
struct DatabasePresetChoices {
  std::string preset = "sope";  // DatabaseOptions::Preset
  std::optional<int> views;
  std::optional<ViewpointLayout> layout;
  std::optional<HashMethod> hash;
  std::optional<int> bits;
};
// The preset with the choices applied. Unless chosen, the layout follows the views: the
// thesis's 18-view rings for 18 views under a preset with that layout, else Fibonacci; the
// thesis layout without a view count gets its 18. Throws sope::Error naming the value: an
// unknown preset, fewer than one view, the thesis layout with other than 18 views, or
// options DatabaseOptions::Check refuses.
DatabaseOptions ResolveDatabaseOptions(const DatabasePresetChoices& choices);

// Called from the building thread after each view: (views done, views in total).
using BuildProgress = std::function<void(int done, int total)>;

// Builds a database from `models`. A mesh that cannot be read or rendered is reported
// (spdlog warning naming the file and the reason), recorded in summary->skipped and left
// out; the rest is built. Throws sope::Error on invalid options or when no view of any
// model could be built. Views are described on `threads` worker threads (0 = one per
// hardware thread); the result does not depend on the thread count.
DatabaseData BuildDatabase(const std::vector<ModelSource>& models, const DatabaseOptions& options,
                           const BuildProgress& progress = {}, BuildSummary* summary = nullptr,
                           int threads = 0);
// ListModels(models_dir), then the above.
DatabaseData BuildDatabase(const std::string& models_dir, const DatabaseOptions& options,
                           const BuildProgress& progress = {}, BuildSummary* summary = nullptr,
                           int threads = 0);

namespace internal {
// Indices of `count` points chosen by farthest-point sampling (the first is the point
// nearest the centroid), all indices when count ≥ points.size().
std::vector<int> FarthestPointSample(const std::vector<Eigen::Vector3f>& points, int count);
// Median over points of the distance to the nearest other point, metres (0 for < 2).
float MedianNearestNeighbourDistance(const std::vector<Eigen::Vector3f>& points);
}  // namespace internal

}  // namespace sope
