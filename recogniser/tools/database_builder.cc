#include "recogniser/tools/database_builder.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <mutex>
#include <optional>
#include <random>
#include <system_error>
#include <thread>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "core/camera_model.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/object_size.h"
#include "core/statistics.h"
#include "core/units.h"
#include "recogniser/view_description.h"
#include "simulator/virtual_rig.h"

namespace sope {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

constexpr double kQuantumSteps = 32000.0;  // int16 units per bounding radius
constexpr int kDiameterSamples = 2000;     // vertices compared pairwise for the diameter
constexpr int kScalePairs = 4000;          // random view pairs for the distance scales

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

bool IsMeshExtension(const std::string& path) {
  const std::string ext = FileExtension(path);
  return ext == "obj" || ext == "ply" || ext == "off" || ext == "stl";
}

// A model ready to render: the scaled mesh and its record (views filled in later).
struct LoadedModel {
  TriangleMesh mesh;
  ModelRecord record;
  bool category = false;  // ModelSource::category
};

std::optional<LoadedModel> LoadModel(const ModelSource& source,
                                     const SizeNormalisationOptions& size, std::string* reason) {
  LoadedModel model;
  try {
    model.mesh = ReadMesh(source.path);
    model.mesh.Check();
  } catch (const Error& e) {
    *reason = e.what();
    return std::nullopt;
  }
  const double diagonal = model.mesh.BoundingDiagonal();
  if (!(diagonal > 0.0) || !std::isfinite(diagonal)) {
    *reason = "degenerate mesh (zero size)";
    return std::nullopt;
  }
  ModelRecord& record = model.record;
  record.name = source.name;
  record.class_name = source.class_name;
  record.source_path = source.path;
  model.category = source.category;
  record.scale = SizeNormalisationScale(model.mesh, size);
  if (size.mesh_unit > 0.0 && !IsPlausibleDiagonal(diagonal * record.scale)) {
    spdlog::warn("{}: {:.4g} m across at {} m per mesh unit, not {}-{} m: is the unit right?",
                 source.path, diagonal * record.scale, size.mesh_unit, kMinPlausibleDiagonal,
                 kMaxPlausibleDiagonal);
  }
  if (record.scale != 1.0) model.mesh.Transform(record.scale, Eigen::Vector3d::Zero());
  Eigen::Vector3f lo, hi;
  model.mesh.Bounds(&lo, &hi);
  record.center = (0.5 * (lo + hi)).cast<double>();
  // Vertices used by faces (unused ones can lie anywhere).
  std::vector<uint8_t> used(model.mesh.vertices.size(), 0);
  for (const Eigen::Vector3i& face : model.mesh.faces) {
    for (int k = 0; k < 3; ++k) used[face[k]] = 1;
  }
  std::vector<Eigen::Vector3f> vertices;
  double radius = 0.0;
  for (size_t i = 0; i < used.size(); ++i) {
    if (!used[i]) continue;
    vertices.push_back(model.mesh.vertices[i]);
    radius = std::max(radius, (model.mesh.vertices[i].cast<double>() - record.center).norm());
  }
  record.bounding_radius = radius;
  record.cloud_quantum = radius / kQuantumSteps;
  const size_t stride = std::max<size_t>(1, vertices.size() / kDiameterSamples);
  double diameter2 = 0.0;
  for (size_t i = 0; i < vertices.size(); i += stride) {
    for (size_t j = i + stride; j < vertices.size(); j += stride) {
      diameter2 = std::max<double>(diameter2, (vertices[i] - vertices[j]).squaredNorm());
    }
  }
  record.diameter = std::sqrt(diameter2);
  return model;
}

// One rendered view waiting to be described.
struct ViewJob {
  int slot = 0;  // index into the per-view results
  int model = 0;
  Viewpoint viewpoint;
  double distance = 0.0;
  Rigid3d cam_from_model;
  PointCloud cloud;  // camera frame
};

struct ViewResult {
  bool ok = false;
  std::string error;
  ViewRecord record;
  Eigen::VectorXf coarse, fine;
  PointCloud view_cloud;  // model frame
  double seconds = 0.0;
};

ViewResult DescribeJob(const ViewJob& job, const DatabaseOptions& options) {
  ViewResult result;
  const auto start = Clock::now();
  ViewDescription description;
  try {
    description = DescribeView(job.cloud, options.preprocess, options.features);
  } catch (const Error& e) {
    result.error = e.what();
    result.seconds = SecondsSince(start);
    return result;
  }
  const PreprocessedCloud& pre = description.preprocessed;
  const Rigid3d model_from_canonical =
      job.cam_from_model.Inverse() * Rigid3d(description.cam_from_canonical, Eigen::Vector3d::Zero());
  const Eigen::Matrix3f rotation = model_from_canonical.rotation.cast<float>();
  const Eigen::Vector3f translation = model_from_canonical.translation.cast<float>();

  ViewRecord& record = result.record;
  record.viewpoint = job.viewpoint;
  record.distance = job.distance;
  record.cam_from_model = job.cam_from_model;
  record.centroid_in_model = rotation * pre.centroid + translation;
  record.radius = pre.radius;
  record.preprocessed_points = static_cast<int32_t>(pre.cloud.size());

  const std::vector<int> sample =
      internal::FarthestPointSample(pre.cloud.points, options.view_cloud_points);
  result.view_cloud.points.reserve(sample.size());
  result.view_cloud.normals.reserve(sample.size());
  for (int i : sample) {
    result.view_cloud.points.push_back(rotation * pre.cloud.points[i] + translation);
    result.view_cloud.normals.push_back((rotation * pre.cloud.normals[i]).normalized());
  }
  record.cloud_points = static_cast<int32_t>(sample.size());
  record.cloud_spacing = internal::MedianNearestNeighbourDistance(result.view_cloud.points);
  result.coarse = description.features.coarse;
  result.fine = description.features.fine;
  result.ok = result.coarse.allFinite() && result.fine.allFinite();
  if (!result.ok) result.error = "non-finite features";
  result.seconds = SecondsSince(start);
  return result;
}

// A bounded queue between the rendering thread and the describing workers.
class JobQueue {
 public:
  explicit JobQueue(size_t capacity) : capacity_(capacity) {}
  void Push(ViewJob job) {
    std::unique_lock<std::mutex> lock(mutex_);
    not_full_.wait(lock, [&] { return jobs_.size() < capacity_; });
    jobs_.push_back(std::move(job));
    not_empty_.notify_one();
  }
  std::optional<ViewJob> Pop() {
    std::unique_lock<std::mutex> lock(mutex_);
    not_empty_.wait(lock, [&] { return !jobs_.empty() || closed_; });
    if (jobs_.empty()) return std::nullopt;
    ViewJob job = std::move(jobs_.front());
    jobs_.pop_front();
    not_full_.notify_one();
    return job;
  }
  void Close() {
    std::lock_guard<std::mutex> lock(mutex_);
    closed_ = true;
    not_empty_.notify_all();
  }

 private:
  size_t capacity_;
  std::mutex mutex_;
  std::condition_variable not_full_, not_empty_;
  std::deque<ViewJob> jobs_;
  bool closed_ = false;
};

DistanceScales ComputeDistanceScales(const DatabaseData& data) {
  DistanceScales scales;
  const int n = static_cast<int>(data.views.size());
  if (n < 2) return scales;
  std::mt19937_64 rng(12345);
  std::uniform_int_distribution<int> pick(0, n - 1);
  std::vector<double> fine, coarse, size;
  for (int k = 0; k < kScalePairs; ++k) {
    const int a = pick(rng), b = pick(rng);
    if (a == b) continue;
    fine.push_back((data.fine.row(a) - data.fine.row(b)).cwiseAbs().sum());
    coarse.push_back((data.coarse.row(a) - data.coarse.row(b)).norm());
    size.push_back(std::abs(std::log(data.views[a].radius / data.views[b].radius)));
  }
  // NaN (no pairs) and 0 both fall back to 1.
  auto positive = [](double value) { return value > 1e-9 ? value : 1.0; };
  scales.fine = positive(Median(fine));
  scales.coarse = positive(Median(coarse));
  scales.size = positive(Median(size));
  return scales;
}

// Median Euclidean distance between random pairs of rows.
double MedianPairDistanceL2(const DatabaseData::RowMatrix& rows) {
  const int n = static_cast<int>(rows.rows());
  if (n < 2) return 0.0;
  std::mt19937_64 rng(54321);
  std::uniform_int_distribution<int> pick(0, n - 1);
  std::vector<double> distances;
  for (int k = 0; k < kScalePairs; ++k) {
    const int a = pick(rng), b = pick(rng);
    if (a != b) distances.push_back((rows.row(a) - rows.row(b)).norm());
  }
  return Median(distances);
}

}  // namespace

namespace internal {

std::vector<int> FarthestPointSample(const std::vector<Eigen::Vector3f>& points, int count) {
  const int n = static_cast<int>(points.size());
  std::vector<int> sample;
  if (count >= n) {
    sample.resize(n);
    for (int i = 0; i < n; ++i) sample[i] = i;
    return sample;
  }
  if (count <= 0) return sample;
  Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
  for (const Eigen::Vector3f& p : points) centroid += p;
  centroid /= static_cast<float>(n);
  int first = 0;
  float best = std::numeric_limits<float>::max();
  for (int i = 0; i < n; ++i) {
    const float d2 = (points[i] - centroid).squaredNorm();
    if (d2 < best) {
      best = d2;
      first = i;
    }
  }
  std::vector<float> distance2(n, std::numeric_limits<float>::max());
  sample.reserve(count);
  int current = first;
  for (int k = 0; k < count; ++k) {
    sample.push_back(current);
    const Eigen::Vector3f c = points[current];
    int next = 0;
    float farthest = -1.0f;
    for (int i = 0; i < n; ++i) {
      const float d2 = std::min(distance2[i], (points[i] - c).squaredNorm());
      distance2[i] = d2;
      if (d2 > farthest) {
        farthest = d2;
        next = i;
      }
    }
    current = next;
  }
  return sample;
}

float MedianNearestNeighbourDistance(const std::vector<Eigen::Vector3f>& points) {
  const size_t n = points.size();
  if (n < 2) return 0.0f;
  std::vector<double> nearest(n);
  for (size_t i = 0; i < n; ++i) {
    float best = std::numeric_limits<float>::max();
    for (size_t j = 0; j < n; ++j) {
      if (j != i) best = std::min(best, (points[i] - points[j]).squaredNorm());
    }
    nearest[i] = std::sqrt(best);
  }
  return static_cast<float>(Median(nearest));
}

}  // namespace internal

std::vector<ModelSource> ListModels(const std::string& models_dir) {
  std::error_code error;
  SOPE_CHECK(fs::is_directory(models_dir, error), "models directory {} does not exist or is not "
             "a directory", models_dir);
  std::vector<ModelSource> models;
  auto add = [&](const fs::path& path, const std::string& class_name, bool category) {
    ModelSource source;
    source.path = path.string();
    source.name = path.stem().string();
    source.class_name = class_name.empty() ? source.name : class_name;
    source.category = category;
    models.push_back(std::move(source));
  };
  try {
    for (const fs::directory_entry& entry : fs::directory_iterator(models_dir)) {
      if (entry.is_directory()) {
        const bool category = fs::is_regular_file(entry.path() / kCategoryMarker);
        for (const fs::directory_entry& inner : fs::directory_iterator(entry.path())) {
          if (inner.is_regular_file() && IsMeshExtension(inner.path().string())) {
            add(inner.path(), entry.path().filename().string(), category);
          }
        }
      } else if (entry.is_regular_file() && IsMeshExtension(entry.path().string())) {
        add(entry.path(), "", false);
      }
    }
  } catch (const fs::filesystem_error& e) {
    SOPE_THROW("cannot list models directory {}: {}", models_dir, e.code().message());
  }
  SOPE_CHECK(!models.empty(), "models directory {} holds no mesh (.obj .ply .off .stl), "
             "neither DIR/<class>/<model>.obj nor DIR/<model>.obj", models_dir);
  std::sort(models.begin(), models.end(), [](const ModelSource& a, const ModelSource& b) {
    return std::tie(a.class_name, a.name, a.path) < std::tie(b.class_name, b.name, b.path);
  });
  return models;
}

double SizeNormalisationScale(const TriangleMesh& mesh, const SizeNormalisationOptions& options) {
  return MeshScale(mesh.BoundingDiagonal(), options.mesh_unit, options.min_plausible_diagonal,
                   options.max_plausible_diagonal, options.target_diagonal);
}

std::string BuildSummary::BriefReport() const {
  std::string report = fmt::format(
      "{} models, {} views ({} dropped), {} skipped; render {:.1f} s, describe {:.1f} s "
      "(thread time), hash {:.2f} s, total {:.1f} s",
      models, views, dropped_views, skipped.size(), render_seconds, describe_seconds,
      hash_seconds, total_seconds);
  return report;
}

DatabaseData BuildDatabase(const std::string& models_dir, const DatabaseOptions& options,
                           const BuildProgress& progress, BuildSummary* summary, int threads) {
  return BuildDatabase(ListModels(models_dir), options, progress, summary, threads);
}

namespace {

// Every view of every loadable model, rendered on this thread and described on `threads`
// workers; results[slot] belongs to loaded[result_model[slot]].
struct DescribedViews {
  std::vector<LoadedModel> loaded;
  std::vector<ViewResult> results;
  std::vector<int> result_model;
  int slots = 0;
};

DescribedViews RenderAndDescribe(const std::vector<ModelSource>& sources,
                                 const DatabaseOptions& options, const BuildProgress& progress,
                                 int threads, BuildSummary* report) {
  const std::vector<Viewpoint> viewpoints = MakeViewpoints(options.layout, options.views_per_model);
  const CameraModel camera =
      MakePinhole(options.render.width, options.render.height, options.render.horizontal_fov);
  const double half_fov = std::min(
      0.5 * options.render.horizontal_fov,
      std::atan(std::tan(0.5 * options.render.horizontal_fov) * options.render.height /
                options.render.width));
  DepthRenderer renderer(camera);

  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const int total_views = static_cast<int>(sources.size() * viewpoints.size());
  DescribedViews out;
  JobQueue queue(static_cast<size_t>(2 * threads));
  std::atomic<int> done{0};
  std::atomic<int64_t> describe_microseconds{0};
  // Workers write into `results` slots; the vector is fully sized before they start.
  out.results.resize(total_views);
  std::vector<std::thread> workers;
  auto worker = [&]() {
    while (std::optional<ViewJob> job = queue.Pop()) {
      ViewResult result = DescribeJob(*job, options);
      describe_microseconds += static_cast<int64_t>(result.seconds * 1e6);
      out.results[job->slot] = std::move(result);
      ++done;
    }
  };
  for (int t = 0; t < threads; ++t) {
    try {
      workers.emplace_back(worker);
    } catch (const std::system_error& e) {
      // Out of threads (a process limit): stop the ones started, one clear error.
      queue.Close();
      for (std::thread& started : workers) started.join();
      SOPE_THROW("BuildDatabase: cannot start worker thread {} of {} ({}); use fewer threads",
                 t + 1, threads, e.what());
    }
  }

  double render_seconds = 0.0;
  try {
    for (const ModelSource& source : sources) {
      std::string reason;
      std::optional<LoadedModel> model = LoadModel(source, options.size, &reason);
      if (model) {
        try {
          renderer.SetMesh(model->mesh);
        } catch (const Error& e) {
          reason = e.what();
          model.reset();
        }
      }
      if (!model) {
        spdlog::warn("skipping model {}: {}", source.path, reason);
        report->skipped.push_back(source.path + ": " + reason);
        continue;
      }
      const int model_index = static_cast<int>(out.loaded.size());
      const double distance =
          std::max(options.render.distance,
                   options.render.fit_margin * model->record.bounding_radius / std::sin(half_fov));
      for (const Viewpoint& viewpoint : viewpoints) {
        ViewJob job;
        job.slot = out.slots++;
        job.model = model_index;
        job.viewpoint = viewpoint;
        job.distance = distance;
        job.cam_from_model = CameraPoseForViewpoint(viewpoint, distance, model->record.center);
        const auto render_start = Clock::now();
        job.cloud = renderer.Render(job.cam_from_model);
        render_seconds += SecondsSince(render_start);
        out.result_model.push_back(model_index);
        queue.Push(std::move(job));
        if (progress) progress(done.load(), total_views);
      }
      out.loaded.push_back(std::move(*model));
    }
  } catch (...) {
    queue.Close();
    for (std::thread& t : workers) t.join();
    throw;
  }
  queue.Close();
  for (std::thread& t : workers) t.join();
  if (progress) progress(total_views, total_views);
  report->render_seconds = render_seconds;
  report->describe_seconds = describe_microseconds.load() * 1e-6;
  return out;
}

// The views that were described, model by model, into data.models/views/classes; returns
// the result slot of each stored view. Models without a kept view are skipped.
std::vector<int> AssembleViews(const DescribedViews& described, DatabaseData* data,
                               BuildSummary* report) {
  std::vector<int> kept;
  for (size_t m = 0; m < described.loaded.size(); ++m) {
    ModelRecord record = described.loaded[m].record;
    const int first = static_cast<int>(data->views.size());
    int views = 0;
    for (int s = 0; s < described.slots; ++s) {
      if (described.result_model[s] != static_cast<int>(m)) continue;
      const ViewResult& result = described.results[s];
      if (!result.ok) {
        spdlog::debug("model {}: view (θ {:.1f}°, φ {:.1f}°) dropped: {}", record.name,
                      RadToDeg(result.record.viewpoint.theta),
                      RadToDeg(result.record.viewpoint.phi), result.error);
        ++report->dropped_views;
        continue;
      }
      ViewRecord view = result.record;
      view.model = static_cast<int32_t>(data->models.size());
      data->views.push_back(view);
      kept.push_back(s);
      ++views;
    }
    if (views == 0) {
      const std::string reason = "no view kept enough points after pre-processing";
      spdlog::warn("skipping model {}: {}", record.source_path, reason);
      report->skipped.push_back(record.source_path + ": " + reason);
      continue;
    }
    auto it = std::find(data->classes.begin(), data->classes.end(), record.class_name);
    if (it == data->classes.end()) {
      data->classes.push_back(record.class_name);
      it = data->classes.end() - 1;
    }
    record.class_index = static_cast<int>(it - data->classes.begin());
    if (described.loaded[m].category &&
        std::find(data->categories.begin(), data->categories.end(), record.class_name) ==
            data->categories.end()) {
      data->categories.push_back(record.class_name);
    }
    record.first_view = first;
    record.num_views = views;
    data->models.push_back(record);
  }
  return kept;
}

// Standardises the coarse vectors (per-dimension mean and standard deviation, a constant
// dimension keeps scale 1, optionally × √(block length) so every block weighs the same),
// sets the distance scales, and trains the hasher and encodes every view.
void StandardiseAndHash(const DatabaseData::RowMatrix& coarse, const DatabaseOptions& options,
                        DatabaseData* data, BuildSummary* report) {
  const int n = static_cast<int>(coarse.rows());
  const int coarse_dim = static_cast<int>(coarse.cols());
  const int fine_dim = static_cast<int>(data->fine.cols());
  data->coarse_mean = coarse.colwise().mean().transpose();
  data->coarse_scale.resize(coarse_dim);
  for (int d = 0; d < coarse_dim; ++d) {
    const double variance =
        (coarse.col(d).array() - data->coarse_mean[d]).square().sum() / std::max(1, n);
    const double sigma = std::sqrt(variance);
    data->coarse_scale[d] = sigma > 1e-9 ? static_cast<float>(sigma) : 1.0f;
  }
  if (options.equal_block_weights) {
    int offset = 0;
    for (const auto& block : CoarseLayout(options.features)) {
      for (int k = 0; k < block.second && offset + k < coarse_dim; ++k) {
        data->coarse_scale[offset + k] *= std::sqrt(static_cast<float>(block.second));
      }
      offset += block.second;
    }
  }
  data->coarse = ((coarse.rowwise() - data->coarse_mean.transpose()).array().rowwise() /
                  data->coarse_scale.transpose().array())
                     .matrix();
  data->fine_mean = data->fine.colwise().mean().transpose();
  data->distance_scales = ComputeDistanceScales(*data);
  data->fine_hash_scale = 0.0f;
  if (options.hash_fine_weight > 0.0) {
    const double fine_l2 = MedianPairDistanceL2(data->fine);
    data->fine_hash_scale =
        fine_l2 > 1e-12 ? static_cast<float>(options.hash_fine_weight *
                                             data->distance_scales.coarse / fine_l2)
                        : 0.0f;
  }
  Eigen::MatrixXf training(n, coarse_dim + (data->fine_hash_scale > 0.0f ? fine_dim : 0));
  for (int v = 0; v < n; ++v) {
    training.row(v) = HashInputVector(data->coarse.row(v).transpose(),
                                      data->fine.row(v).transpose(), data->fine_mean,
                                      data->fine_hash_scale)
                          .transpose();
  }
  data->hasher = Hasher::Train(training, options.hash, &report->hash);
  data->codes = data->hasher.Encode(training);
}

}  // namespace

DatabaseData BuildDatabase(const std::vector<ModelSource>& sources, const DatabaseOptions& options,
                           const BuildProgress& progress, BuildSummary* summary, int threads) {
  options.Check();
  SOPE_CHECK(!sources.empty(), "BuildDatabase: no models");
  const auto start = Clock::now();
  BuildSummary local_summary;
  BuildSummary& report = summary != nullptr ? *summary : local_summary;
  report = BuildSummary();

  DescribedViews described = RenderAndDescribe(sources, options, progress, threads, &report);
  DatabaseData data;
  data.options = options;
  const std::vector<int> kept = AssembleViews(described, &data, &report);
  SOPE_CHECK(!data.views.empty(), "no database view could be built ({} of {} models skipped)",
             report.skipped.size(), sources.size());

  const int n = static_cast<int>(data.views.size());
  std::vector<ViewResult>& results = described.results;
  const int coarse_dim = static_cast<int>(results[kept[0]].coarse.size());
  const int fine_dim = static_cast<int>(results[kept[0]].fine.size());
  DatabaseData::RowMatrix coarse(n, coarse_dim);
  data.fine.resize(n, fine_dim);
  data.view_clouds.resize(n);
  for (int v = 0; v < n; ++v) {
    ViewResult& result = results[kept[v]];
    SOPE_CHECK(result.coarse.size() == coarse_dim && result.fine.size() == fine_dim,
               "BuildDatabase: feature dimensions vary between views");
    coarse.row(v) = result.coarse.transpose();
    data.fine.row(v) = result.fine.transpose();
    data.view_clouds[v] = std::move(result.view_cloud);
  }
  results.clear();

  const auto hash_start = Clock::now();
  StandardiseAndHash(coarse, options, &data, &report);
  report.hash_seconds = SecondsSince(hash_start);
  report.models = static_cast<int>(data.models.size());
  report.views = n;
  report.total_seconds = SecondsSince(start);
  data.Check();
  return data;
}

DatabaseOptions ResolveDatabaseOptions(const DatabasePresetChoices& choices) {
  DatabaseOptions options = DatabaseOptions::Preset(choices.preset);
  if (choices.layout) options.layout = *choices.layout;
  if (choices.views) {
    SOPE_CHECK(*choices.views >= 1, "views per model must be ≥ 1, got {}", *choices.views);
    options.views_per_model = *choices.views;
    if (!choices.layout) {
      options.layout = *choices.views == 18 && options.layout == ViewpointLayout::kThesis18
                           ? ViewpointLayout::kThesis18
                           : ViewpointLayout::kFibonacci;
    }
  } else if (options.layout == ViewpointLayout::kThesis18) {
    options.views_per_model = 18;
  }
  SOPE_CHECK(options.layout != ViewpointLayout::kThesis18 || options.views_per_model == 18,
             "the thesis layout has 18 viewpoints, {} views per model given",
             options.views_per_model);
  if (choices.hash) options.hash.method = *choices.hash;
  if (choices.bits) options.hash.bits = *choices.bits;
  options.Check();
  return options;
}

}  // namespace sope
