#include "recogniser/database.h"

#include <fcntl.h>
#if defined(__AVX512F__)
#include <immintrin.h>
#endif
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <mutex>
#include <type_traits>

#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/options_json.h"
#include "recogniser/crc32c.h"

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__,
              "the .sopedb reader/writer assumes a little-endian host");

namespace sope {
namespace {

using json = nlohmann::json;

constexpr char kMagic[8] = {'S', 'O', 'P', 'E', 'D', 'B', '\r', '\n'};
constexpr size_t kHeaderBytes = 64;
constexpr size_t kSectionNameBytes = 16;
constexpr size_t kSectionEntryBytes = 40;
constexpr uint64_t kSectionAlignment = 4096;
constexpr float kNormalSteps = 32767.0f;

struct HeaderOnDisk {
  char magic[8];
  uint32_t version;
  uint32_t header_bytes;  // header + section table
  uint32_t section_count;
  uint32_t header_crc;
  uint64_t file_size;
  uint8_t reserved[32];
};
static_assert(sizeof(HeaderOnDisk) == kHeaderBytes, "header layout");

struct SectionEntryOnDisk {
  char name[kSectionNameBytes];
  uint64_t offset;
  uint64_t size;
  uint32_t crc;
  uint32_t reserved;
};
static_assert(sizeof(SectionEntryOnDisk) == kSectionEntryBytes, "section entry layout");

struct ViewRecordOnDisk {
  int32_t model;
  int32_t cloud_points;
  double theta, phi, distance;
  double rotation[9];  // row-major
  double translation[3];
  float centroid[3];
  float radius;
  float cloud_spacing;
  int32_t preprocessed_points;
};
static_assert(sizeof(ViewRecordOnDisk) == 152, "view record layout");
static_assert(std::is_trivially_copyable<ViewRecordOnDisk>::value, "view record is POD");

struct CloudPointOnDisk {
  int16_t position[3];
  int16_t normal[3];
};
static_assert(sizeof(CloudPointOnDisk) == 12, "cloud point layout");

// Sections in file order; the mapped ones are the last three.
constexpr const char* kSectionNames[] = {"metadata", "views",  "hasher", "standard",
                                         "codes",    "coarse", "fine",   "clouds"};
constexpr int kNumSections = 8;
constexpr int kFirstMappedSection = 5;
enum SectionId { kMetadata, kViews, kHasher, kStandard, kCodes, kCoarse, kFine, kClouds };

uint64_t AlignUp(uint64_t value, uint64_t alignment) {
  return (value + alignment - 1) / alignment * alignment;
}

// ---- options ↔ JSON ---------------------------------------------------------------------
// One field description per stored option (core/options.h); the JSON keys are those of
// format version 1 (plus preprocess.outlier_min_ratio and features.bezier_smoothing, which
// older files lack: they read as the defaults those files were built with).

const std::vector<OptionField<PreprocessOptions>>& PreprocessFields() {
  using O = PreprocessOptions;
  static const std::vector<OptionField<O>> fields = {
      Field(&O::min_range, "min_range", "Nearest range kept").Unit("m"),
      Field(&O::max_range, "max_range", "Farthest range kept").Unit("m"),
      Field(&O::outlier_neighbours, "outlier_neighbours", "Outlier filter neighbours"),
      Field(&O::outlier_stddev, "outlier_stddev", "Outlier filter threshold, σ"),
      Field(&O::outlier_min_ratio, "outlier_min_ratio", "Outlier filter minimum ratio"),
      Field(&O::voxel_leaf, "voxel_leaf", "Voxel grid leaf").Unit("m"),
      Field(&O::normal_neighbours, "normal_neighbours", "Normal estimation neighbours"),
      Field(&O::normalisation, "normalisation", "Scale normalisation"),
      Field(&O::median_fraction, "median_fraction", "Median normalisation quantile"),
      Field(&O::min_points, "min_points", "Fewest points after pre-processing")};
  return fields;
}

const std::vector<OptionField<FeatureOptions>>& FeatureFields() {
  using O = FeatureOptions;
  static const std::vector<OptionField<O>> fields = {
      Field(&O::kde_bandwidth, "kde_bandwidth", "Shape distribution KDE bandwidth"),
      Field(&O::kde_samples, "kde_samples", "Shape distribution samples"),
      Field(&O::direction_components_xyz, "direction_components_xyz", "Direction components"),
      Field(&O::bezier_order_u, "bezier_order_u", "Bézier patch order u"),
      Field(&O::bezier_order_v, "bezier_order_v", "Bézier patch order v"),
      Field(&O::bezier_iterations, "bezier_iterations", "Bézier fit iterations"),
      Field(&O::bezier_smoothing, "bezier_smoothing", "Bézier control-net smoothness weight"),
      Field(&O::metric_size, "metric_size", "Metric size block in the coarse vector"),
      Field(&O::fine, "fine", "Fine descriptor")};
  return fields;
}

const std::vector<OptionField<HashOptions>>& HashFields() {
  using O = HashOptions;
  static const std::vector<OptionField<O>> fields = [] {
    std::vector<OptionField<O>> f = {
        Field(&O::method, "method", "Binary codes (default: the preset's)").Flag("--hash"),
        Field(&O::bits, "bits", "Code length, bits (default: the preset's, 64)")
            .In(HashOptions::kMinBits, HashOptions::kMaxBits)
            .Flag("--bits"),
        Field(&O::seed, "seed", "Training seed"),
        Field(&O::max_training_samples, "max_training_samples", "Training samples at most")};
    AppendNested(&f, &O::lsh, "lsh",
                 std::vector<OptionField<LshOptions>>{Field(
                     &LshOptions::threshold_spread, "threshold_spread", "Threshold spread")});
    using M = MlhOptions;
    AppendNested(&f, &O::mlh, "mlh",
                 std::vector<OptionField<M>>{
                     Field(&M::margin_fraction, "margin_fraction", "Hinge margin"),
                     Field(&M::lambda, "lambda", "Loss ratio"),
                     Field(&M::learning_rate, "learning_rate", "Learning rate"),
                     Field(&M::momentum, "momentum", "Momentum"),
                     Field(&M::weight_decay, "weight_decay", "Weight decay"),
                     Field(&M::iterations, "iterations", "Iterations"),
                     Field(&M::pairs_per_batch, "pairs_per_batch", "Pairs per batch"),
                     Field(&M::training_points, "training_points", "Training points"),
                     Field(&M::neighbours, "neighbours", "Neighbours")});
    using B = BreOptions;
    AppendNested(&f, &O::bre, "bre",
                 std::vector<OptionField<B>>{
                     Field(&B::kernel, "kernel", "Kernel"),
                     Field(&B::bandwidth_scale, "bandwidth_scale", "Bandwidth scale"),
                     Field(&B::anchors, "anchors", "Anchors"),
                     Field(&B::training_points, "training_points", "Training points"),
                     Field(&B::neighbours, "neighbours", "Neighbours"),
                     Field(&B::updates_per_bit, "updates_per_bit", "Updates per bit")});
    AppendNested(&f, &O::itq, "itq",
                 std::vector<OptionField<ItqOptions>>{
                     Field(&ItqOptions::iterations, "iterations", "Iterations")});
    return f;
  }();
  return fields;
}

}  // namespace

const std::vector<OptionField<DatabaseOptions>>& DatabaseOptions::Fields() {
  using O = DatabaseOptions;
  static const std::vector<OptionField<O>> fields = [] {
    std::vector<OptionField<O>> f = {
        Field(&O::layout, "layout",
              "Viewpoints: thesis (18 on five declination rings) or fibonacci (any number, "
              "even sphere sampling); default: thesis for 18 views under --preset thesis, else "
              "fibonacci")
            .Flag("--layout"),
        Field(&O::views_per_model, "views_per_model",
              "Viewpoints per model (default: the preset's)")
            .AtLeast(1)
            .Flag("--views")};
    using R = ViewRenderOptions;
    AppendNested(&f, &O::render, "render",
                 std::vector<OptionField<R>>{
                     Field(&R::width, "width", "Image width, pixels"),
                     Field(&R::height, "height", "Image height, pixels"),
                     Field(&R::horizontal_fov, "horizontal_fov", "Field of view").Unit("rad"),
                     Field(&R::distance, "distance", "Camera distance").Unit("m"),
                     Field(&R::fit_margin, "fit_margin", "Fit margin")});
    using Z = SizeNormalisationOptions;
    AppendNested(&f, &O::size, "size",
                 std::vector<OptionField<Z>>{
                     Field(&Z::min_plausible_diagonal, "min_plausible_diagonal",
                           "Smallest plausible diagonal")
                         .Unit("m"),
                     Field(&Z::max_plausible_diagonal, "max_plausible_diagonal",
                           "Largest plausible diagonal")
                         .Unit("m"),
                     Field(&Z::target_diagonal, "target_diagonal", "Diagonal of scaled meshes")
                         .Unit("m"),
                     Field(&Z::mesh_unit, "mesh_unit", "Metres per mesh unit (0: guessed)")
                         .Unit("m")});
    AppendNested(&f, &O::preprocess, "preprocess", PreprocessFields());
    AppendNested(&f, &O::features, "features", FeatureFields());
    AppendNested(&f, &O::hash, "hash", HashFields());
    f.push_back(Field(&O::view_cloud_points, "view_cloud_points", "Points kept per view"));
    f.push_back(Field(&O::equal_block_weights, "equal_block_weights", "Equal coarse blocks"));
    f.push_back(Field(&O::hash_fine_weight, "hash_fine_weight", "Fine part of the hashed vector"));
    return f;
  }();
  return fields;
}

namespace {

json OptionsToJsonObject(const DatabaseOptions& o) {
  return FieldsToJson(o, DatabaseOptions::Fields());
}

DatabaseOptions OptionsFromJsonObject(const json& j) {
  DatabaseOptions o;
  FieldsFromJson(j, DatabaseOptions::Fields(), &o);
  return o;
}

json Vec3ToJson(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }
Eigen::Vector3d Vec3FromJson(const json& j) {
  return Eigen::Vector3d(j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>());
}

// ---- file mapping -------------------------------------------------------------------------

struct MappedFile {
  int fd = -1;
  const uint8_t* data = nullptr;
  uint64_t size = 0;
  ~MappedFile() {
    if (data != nullptr && size > 0) ::munmap(const_cast<uint8_t*>(data), size);
    if (fd >= 0) ::close(fd);
  }
};

}  // namespace

// ---- options -------------------------------------------------------------------------------

void ViewRenderOptions::Check() const {
  SOPE_CHECK(width >= 16 && height >= 16, "view rendering: image size {}x{} is too small (≥ 16)",
             width, height);
  SOPE_CHECK(horizontal_fov > 0.05 && horizontal_fov < 3.0,
             "view rendering: horizontal_fov must be in (0.05, 3) rad, got {}", horizontal_fov);
  SOPE_CHECK(distance > 0.0 && std::isfinite(distance),
             "view rendering: distance must be > 0 m, got {}", distance);
  SOPE_CHECK(fit_margin >= 1.0, "view rendering: fit_margin must be ≥ 1, got {}", fit_margin);
}

void SizeNormalisationOptions::Check() const {
  SOPE_CHECK(min_plausible_diagonal > 0.0 && max_plausible_diagonal > min_plausible_diagonal,
             "size normalisation: need 0 < min_plausible_diagonal < max_plausible_diagonal, "
             "got {} and {}",
             min_plausible_diagonal, max_plausible_diagonal);
  SOPE_CHECK(target_diagonal > 0.0, "size normalisation: target_diagonal must be > 0 m, got {}",
             target_diagonal);
  SOPE_CHECK(std::isfinite(mesh_unit) && mesh_unit >= 0.0 && mesh_unit <= 1000.0,
             "size normalisation: mesh_unit must be in [0, 1000] m per unit (0: guessed), got {}",
             mesh_unit);
}

DatabaseOptions DatabaseOptions::Preset(const std::string& name) {
  DatabaseOptions options;
  if (name == "sope") return options;
  if (name == "thesis") {
    options.layout = ViewpointLayout::kThesis18;
    options.views_per_model = 18;
    options.features = FeatureOptions::ThesisPreset();
    options.hash.method = HashMethod::kMinimalLoss;
    options.equal_block_weights = false;
    options.hash_fine_weight = 0.0;
    return options;
  }
  SOPE_THROW("unknown preset '{}' (expected sope or thesis)", name);
}

void DatabaseOptions::Check() const {
  if (layout == ViewpointLayout::kThesis18) {
    SOPE_CHECK(views_per_model == 18, "the thesis layout has 18 views per model, got {}",
               views_per_model);
  } else {
    SOPE_CHECK(views_per_model >= 1 && views_per_model <= 100000,
               "views per model must be in [1, 100000], got {}", views_per_model);
  }
  render.Check();
  size.Check();
  preprocess.Check();
  features.Check();
  hash.Check();
  SOPE_CHECK(view_cloud_points >= 16 && view_cloud_points <= 4096,
             "view_cloud_points must be in [16, 4096], got {}", view_cloud_points);
  SOPE_CHECK(hash_fine_weight >= 0.0 && std::isfinite(hash_fine_weight),
             "hash_fine_weight must be ≥ 0, got {}", hash_fine_weight);
}

Eigen::VectorXf HashInputVector(const Eigen::VectorXf& standardised_coarse,
                                const Eigen::VectorXf& fine, const Eigen::VectorXf& fine_mean,
                                float fine_hash_scale) {
  if (fine_hash_scale <= 0.0f) return standardised_coarse;
  Eigen::VectorXf input(standardised_coarse.size() + fine.size());
  input << standardised_coarse, fine_hash_scale * (fine - fine_mean);
  return input;
}

std::string DatabaseOptionsToJson(const DatabaseOptions& options) {
  return OptionsToJsonObject(options).dump();
}

DatabaseOptions DatabaseOptionsFromJson(const std::string& text) {
  try {
    return OptionsFromJsonObject(json::parse(text));
  } catch (const json::exception& e) {
    SOPE_THROW("database options: {}", e.what());
  }
}

void DatabaseData::Check() const {
  const size_t num_views = views.size();
  SOPE_CHECK(!models.empty() && num_views > 0, "database: no models or no views");
  SOPE_CHECK(coarse.rows() == static_cast<Eigen::Index>(num_views) &&
                 fine.rows() == static_cast<Eigen::Index>(num_views),
             "database: {} views but {} coarse and {} fine rows", num_views, coarse.rows(),
             fine.rows());
  SOPE_CHECK(coarse.cols() > 0 && fine.cols() > 0, "database: empty feature vectors");
  SOPE_CHECK(coarse_mean.size() == coarse.cols() && coarse_scale.size() == coarse.cols(),
             "database: standardisation has {} / {} values for {} coarse dimensions",
             coarse_mean.size(), coarse_scale.size(), coarse.cols());
  SOPE_CHECK(fine_mean.size() == fine.cols() && fine_hash_scale >= 0.0f,
             "database: fine mean has {} values for {} fine dimensions", fine_mean.size(),
             fine.cols());
  const Eigen::Index hash_dims = coarse.cols() + (fine_hash_scale > 0.0f ? fine.cols() : 0);
  SOPE_CHECK(hasher.trained() && hasher.input_dims() == hash_dims,
             "database: hasher untrained or for {} dimensions instead of {}",
             hasher.trained() ? hasher.input_dims() : 0, hash_dims);
  codes.Check();
  SOPE_CHECK(codes.size() == static_cast<int64_t>(num_views) && codes.bits == hasher.bits(),
             "database: {} codes of {} bits for {} views and a {}-bit hasher", codes.size(),
             codes.bits, num_views, hasher.bits());
  SOPE_CHECK(view_clouds.size() == num_views, "database: {} view clouds for {} views",
             view_clouds.size(), num_views);
  for (size_t k = 0; k < categories.size(); ++k) {
    SOPE_CHECK(std::count(classes.begin(), classes.end(), categories[k]) == 1 &&
                   std::count(categories.begin(), categories.end(), categories[k]) == 1,
               "database: category {} is not one class of the database (or named twice)",
               categories[k]);
  }
  int expected_first = 0;
  for (size_t m = 0; m < models.size(); ++m) {
    const ModelRecord& model = models[m];
    SOPE_CHECK(model.class_index >= 0 && model.class_index < static_cast<int>(classes.size()) &&
                   classes[model.class_index] == model.class_name,
               "database: model {} has an invalid class", model.name);
    SOPE_CHECK(model.first_view == expected_first && model.num_views >= 1,
               "database: model {} views [{}, +{}) are not contiguous", model.name,
               model.first_view, model.num_views);
    SOPE_CHECK(model.cloud_quantum > 0.0 && model.bounding_radius > 0.0,
               "database: model {} has no size", model.name);
    expected_first += model.num_views;
  }
  SOPE_CHECK(expected_first == static_cast<int>(num_views),
             "database: models cover {} views, {} stored", expected_first, num_views);
  for (size_t v = 0; v < num_views; ++v) {
    const ViewRecord& view = views[v];
    SOPE_CHECK(view.model >= 0 && view.model < static_cast<int>(models.size()) &&
                   static_cast<int>(v) >= models[view.model].first_view &&
                   static_cast<int>(v) < models[view.model].first_view + models[view.model].num_views,
               "database: view {} names model {}", v, view.model);
    const PointCloud& cloud = view_clouds[v];
    SOPE_CHECK(cloud.size() == static_cast<size_t>(view.cloud_points) &&
                   cloud.size() <= static_cast<size_t>(options.view_cloud_points) &&
                   cloud.normals.size() == cloud.size(),
               "database: view {} cloud has {} points ({} normals), record says {}, limit {}", v,
               cloud.size(), cloud.normals.size(), view.cloud_points, options.view_cloud_points);
  }
}

// ---- writing -------------------------------------------------------------------------------

namespace {

// The metadata section: format, options, classes, models, sizes, coarse layout, scales.
std::string MetadataSection(const DatabaseData& data) {
  const int num_views = static_cast<int>(data.views.size());
  json meta;
  meta["format"] = "sope-db";
  meta["version"] = kDatabaseFormatVersion;
  meta["options"] = OptionsToJsonObject(data.options);
  meta["classes"] = data.classes;
  meta["categories"] = data.categories;
  json models = json::array();
  for (const ModelRecord& m : data.models) {
    models.push_back({{"name", m.name},
                      {"class", m.class_name},
                      {"class_index", m.class_index},
                      {"source", m.source_path},
                      {"scale", m.scale},
                      {"center", Vec3ToJson(m.center)},
                      {"diameter", m.diameter},
                      {"bounding_radius", m.bounding_radius},
                      {"cloud_quantum", m.cloud_quantum},
                      {"first_view", m.first_view},
                      {"num_views", m.num_views}});
  }
  meta["models"] = models;
  meta["num_views"] = num_views;
  meta["coarse_dim"] = data.coarse.cols();
  meta["fine_dim"] = data.fine.cols();
  json layout = json::array();
  for (const auto& block : CoarseLayout(data.options.features)) {
    layout.push_back({block.first, block.second});
  }
  meta["coarse_layout"] = layout;
  meta["distance_scales"] = {{"fine", data.distance_scales.fine},
                             {"coarse", data.distance_scales.coarse},
                             {"size", data.distance_scales.size}};
  return meta.dump(1);
}

std::string ViewsSection(const DatabaseData& data) {
  const int num_views = static_cast<int>(data.views.size());
  std::string views;
  views.resize(sizeof(ViewRecordOnDisk) * num_views);
  for (int v = 0; v < num_views; ++v) {
    const ViewRecord& view = data.views[v];
    ViewRecordOnDisk record{};
    record.model = view.model;
    record.cloud_points = view.cloud_points;
    record.theta = view.viewpoint.theta;
    record.phi = view.viewpoint.phi;
    record.distance = view.distance;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) record.rotation[3 * r + c] = view.cam_from_model.rotation(r, c);
      record.translation[r] = view.cam_from_model.translation[r];
      record.centroid[r] = view.centroid_in_model[r];
    }
    record.radius = view.radius;
    record.cloud_spacing = view.cloud_spacing;
    record.preprocessed_points = view.preprocessed_points;
    std::memcpy(&views[sizeof(record) * v], &record, sizeof(record));
  }
  return views;
}

// View clouds: int16 offsets from the model centre in cloud_quantum steps, int16 normals.
std::string CloudsSection(const DatabaseData& data) {
  const int num_views = static_cast<int>(data.views.size());
  std::string clouds;
  const int stride = data.options.view_cloud_points;
  clouds.assign(sizeof(CloudPointOnDisk) * stride * static_cast<size_t>(num_views), '\0');
  for (int v = 0; v < num_views; ++v) {
    const ModelRecord& model = data.models[data.views[v].model];
    const PointCloud& cloud = data.view_clouds[v];
    CloudPointOnDisk* out =
        reinterpret_cast<CloudPointOnDisk*>(&clouds[sizeof(CloudPointOnDisk) * stride * v]);
    for (size_t i = 0; i < cloud.size(); ++i) {
      const Eigen::Vector3d offset =
          (cloud.points[i].cast<double>() - model.center) / model.cloud_quantum;
      const Eigen::Vector3f normal = cloud.normals[i].normalized();
      for (int k = 0; k < 3; ++k) {
        SOPE_CHECK(std::abs(offset[k]) <= 32767.0,
                   "database: view {} point {} lies outside model {}'s bounding radius", v, i,
                   model.name);
        out[i].position[k] = static_cast<int16_t>(std::lround(offset[k]));
        out[i].normal[k] = static_cast<int16_t>(std::lround(normal[k] * kNormalSteps));
      }
    }
  }
  return clouds;
}

// The whole file: header, section table, sections at aligned offsets.
std::string AssembleFile(const std::vector<std::string>& sections) {
  const uint64_t table_end = kHeaderBytes + kSectionEntryBytes * kNumSections;
  std::vector<SectionEntryOnDisk> entries(kNumSections);
  uint64_t offset = AlignUp(table_end, kSectionAlignment);
  for (int s = 0; s < kNumSections; ++s) {
    SectionEntryOnDisk& entry = entries[s];
    std::memset(&entry, 0, sizeof(entry));
    std::strncpy(entry.name, kSectionNames[s], kSectionNameBytes);
    entry.offset = offset;
    entry.size = sections[s].size();
    entry.crc = Crc32c(sections[s].data(), sections[s].size());
    offset = AlignUp(offset + entry.size, kSectionAlignment);
  }
  const uint64_t file_size = offset;
  HeaderOnDisk header{};
  std::memcpy(header.magic, kMagic, sizeof(kMagic));
  header.version = kDatabaseFormatVersion;
  header.header_bytes = static_cast<uint32_t>(table_end);
  header.section_count = kNumSections;
  header.header_crc = 0;
  header.file_size = file_size;

  std::string file(file_size, '\0');
  std::memcpy(&file[0], &header, sizeof(header));
  std::memcpy(&file[kHeaderBytes], entries.data(), kSectionEntryBytes * kNumSections);
  header.header_crc = Crc32c(file.data(), table_end);
  std::memcpy(&file[0], &header, sizeof(header));
  for (int s = 0; s < kNumSections; ++s) {
    if (!sections[s].empty()) {
      std::memcpy(&file[entries[s].offset], sections[s].data(), sections[s].size());
    }
  }
  return file;
}

}  // namespace

void WriteDatabase(const std::string& path, const DatabaseData& data) {
  data.Check();
  std::vector<std::string> sections(kNumSections);
  sections[kMetadata] = MetadataSection(data);
  sections[kViews] = ViewsSection(data);

  // hasher
  const std::vector<uint8_t> hasher = data.hasher.Serialize();
  sections[kHasher].assign(reinterpret_cast<const char*>(hasher.data()), hasher.size());

  // standardisation
  const int coarse_dim = static_cast<int>(data.coarse.cols());
  const int fine_dim = static_cast<int>(data.fine.cols());
  std::string& standard = sections[kStandard];
  standard.resize(sizeof(float) * (2 * coarse_dim + fine_dim + 1));
  std::memcpy(&standard[0], data.coarse_mean.data(), sizeof(float) * coarse_dim);
  std::memcpy(&standard[sizeof(float) * coarse_dim], data.coarse_scale.data(),
              sizeof(float) * coarse_dim);
  std::memcpy(&standard[sizeof(float) * 2 * coarse_dim], data.fine_mean.data(),
              sizeof(float) * fine_dim);
  std::memcpy(&standard[sizeof(float) * (2 * coarse_dim + fine_dim)], &data.fine_hash_scale,
              sizeof(float));

  // codes, coarse, fine
  sections[kCodes].assign(reinterpret_cast<const char*>(data.codes.words.data()),
                          data.codes.words.size() * sizeof(uint64_t));
  sections[kCoarse].assign(reinterpret_cast<const char*>(data.coarse.data()),
                           sizeof(float) * data.coarse.size());
  sections[kFine].assign(reinterpret_cast<const char*>(data.fine.data()),
                         sizeof(float) * data.fine.size());

  sections[kClouds] = CloudsSection(data);
  WriteFileAtomic(path, AssembleFile(sections));
}

// ---- reading -------------------------------------------------------------------------------

struct Database::Impl {
  std::string path;
  MappedFile file;
  DatabaseOptions options;
  std::vector<std::string> classes;
  std::vector<uint8_t> category;  // per class: a category (DatabaseData::categories)
  std::vector<ModelRecord> models;
  std::vector<ViewRecord> views;
  DistanceScales distance_scales;
  Hasher hasher;
  BinaryCodes codes;
  std::unique_ptr<HammingIndex> index;
  Eigen::VectorXf coarse_mean, coarse_scale, fine_mean;
  float fine_hash_scale = 0.0f;
  int coarse_dim = 0, fine_dim = 0;
  const float* coarse = nullptr;
  const float* fine = nullptr;
  const CloudPointOnDisk* clouds = nullptr;
  int cloud_stride = 0;
  // Made on first use (view_sketches()).
  mutable std::once_flag sketches_once;
  mutable ViewSketches sketches;
};

namespace {

// Keys of `stored` (recursively) that `known` does not have: options this sope does not
// know would otherwise be ignored silently.
void FindUnknownKeys(const json& stored, const json& known, const std::string& prefix,
                     std::vector<std::string>* unknown) {
  if (!stored.is_object() || !known.is_object()) return;
  for (auto it = stored.begin(); it != stored.end(); ++it) {
    const std::string name = prefix.empty() ? it.key() : prefix + "." + it.key();
    if (!known.contains(it.key())) {
      unknown->push_back(name);
    } else {
      FindUnknownKeys(it.value(), known.at(it.key()), name, unknown);
    }
  }
}

bool FiniteArray(const float* values, size_t count) {
  for (size_t i = 0; i < count; ++i) {
    if (!std::isfinite(values[i])) return false;
  }
  return true;
}

// The decoded contents, beyond the checksums (which a crafted file can get right): every
// number the recogniser divides by or compares with is finite and in range, the models'
// view ranges tile the views in order, and no option is unknown.
template <typename DatabaseImpl>  // Database::Impl (private, named by Database::Open)
void ValidateDecodedContents(const DatabaseImpl& impl, const json& stored_options,
                             bool check_mapped, const std::string& path) {
  try {
    impl.options.Check();
  } catch (const Error& e) {
    SOPE_THROW("database {} is corrupted: invalid options ({})", path, e.what());
  }
  std::vector<std::string> unknown;
  FindUnknownKeys(stored_options, OptionsToJsonObject(impl.options), "", &unknown);
  SOPE_CHECK(unknown.empty(), "database {} is corrupted: unknown option '{}' ({} unknown)",
             path, unknown.empty() ? "" : unknown.front(), unknown.size());
  const int num_views = static_cast<int>(impl.views.size());
  int expected_first = 0;
  for (size_t m = 0; m < impl.models.size(); ++m) {
    const ModelRecord& model = impl.models[m];
    SOPE_CHECK(model.first_view == expected_first && model.num_views >= 1,
               "database {} is corrupted: model {} views [{}, +{}) do not follow the previous "
               "model's (expected first view {}, at least one view)",
               path, model.name, model.first_view, model.num_views, expected_first);
    SOPE_CHECK(impl.classes[model.class_index] == model.class_name,
               "database {} is corrupted: model {} names class '{}', index {} is '{}'", path,
               model.name, model.class_name, model.class_index, impl.classes[model.class_index]);
    auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
    SOPE_CHECK(positive(model.scale) && positive(model.diameter) &&
                   positive(model.bounding_radius) && positive(model.cloud_quantum) &&
                   model.center.allFinite(),
               "database {} is corrupted: model {} has an invalid size (scale {}, diameter {} "
               "m, bounding radius {} m, cloud quantum {} m)",
               path, model.name, model.scale, model.diameter, model.bounding_radius,
               model.cloud_quantum);
    expected_first += model.num_views;
  }
  SOPE_CHECK(expected_first == num_views, "database {} is corrupted: models cover {} views, {} "
             "stored", path, expected_first, num_views);
  for (int v = 0; v < num_views; ++v) {
    const ViewRecord& view = impl.views[v];
    const ModelRecord& model = impl.models[view.model];
    SOPE_CHECK(v >= model.first_view && v < model.first_view + model.num_views,
               "database {} is corrupted: view {} names model {}, whose views are [{}, +{})",
               path, v, model.name, model.first_view, model.num_views);
    SOPE_CHECK(std::isfinite(view.distance) && view.distance > 0.0 &&
                   std::isfinite(view.radius) && view.radius > 0.0f &&
                   std::isfinite(view.cloud_spacing) && view.cloud_spacing >= 0.0f &&
                   view.centroid_in_model.allFinite() &&
                   view.cam_from_model.rotation.allFinite() &&
                   view.cam_from_model.translation.allFinite() &&
                   std::isfinite(view.viewpoint.theta) && std::isfinite(view.viewpoint.phi) &&
                   view.preprocessed_points >= 0,
               "database {} is corrupted: view {} has a non-finite or non-positive pose, "
               "distance or radius", path, v);
  }
  const DistanceScales& scales = impl.distance_scales;
  for (double scale : {scales.fine, scales.coarse, scales.size}) {
    SOPE_CHECK(std::isfinite(scale) && scale > 0.0,
               "database {} is corrupted: distance scale {} is not a positive number", path,
               scale);
  }
  SOPE_CHECK(FiniteArray(impl.coarse_mean.data(), impl.coarse_mean.size()) &&
                 FiniteArray(impl.fine_mean.data(), impl.fine_mean.size()) &&
                 std::isfinite(impl.fine_hash_scale) && impl.fine_hash_scale >= 0.0f,
             "database {} is corrupted: non-finite standardisation", path);
  for (Eigen::Index d = 0; d < impl.coarse_scale.size(); ++d) {
    SOPE_CHECK(std::isfinite(impl.coarse_scale[d]) && impl.coarse_scale[d] > 0.0f,
               "database {} is corrupted: coarse scale {} of dimension {} is not positive",
               path, impl.coarse_scale[d], d);
  }
  if (check_mapped) {
    // The mapped feature sections are read once for their checksums anyway.
    SOPE_CHECK(FiniteArray(impl.coarse, static_cast<size_t>(impl.coarse_dim) * num_views),
               "database {} is corrupted: a coarse feature vector holds NaN or infinity", path);
    SOPE_CHECK(FiniteArray(impl.fine, static_cast<size_t>(impl.fine_dim) * num_views),
               "database {} is corrupted: a fine feature vector holds NaN or infinity", path);
  }
}

// ---- Database::Open, step by step --------------------------------------------------------

// The file mapped read-only; refuses what is not a regular file or too short for the magic.
void MapDatabaseFile(const std::string& path, MappedFile* file) {
  // Non-blocking open: a FIFO named as the database would block open(2) forever.
  file->fd = OpenRegularFileForReading(path, "database");
  struct stat st {};
  SOPE_CHECK(::fstat(file->fd, &st) == 0, "cannot stat database {}: {}", path,
             std::strerror(errno));
  const uint64_t actual_size = static_cast<uint64_t>(st.st_size);
  SOPE_CHECK(actual_size >= sizeof(kMagic), "{} is not a sope database (only {} bytes)", path,
             actual_size);
  file->data = static_cast<const uint8_t*>(
      ::mmap(nullptr, actual_size, PROT_READ, MAP_PRIVATE, file->fd, 0));
  if (file->data == MAP_FAILED) {
    file->data = nullptr;
    SOPE_THROW("cannot map database {}: {}", path, std::strerror(errno));
  }
  file->size = actual_size;
}

// The section table of a mapped file, with the bounds of each section checked.
struct Sections {
  const uint8_t* base = nullptr;
  std::vector<SectionEntryOnDisk> entries;
  const uint8_t* data(int s) const { return base + entries[s].offset; }
  uint64_t size(int s) const { return entries[s].size; }
};

// Signature, format version, header checksum, file size and the section table (names,
// bounds, and the checksums of the sections read now; the mapped ones only when asked).
Sections ReadHeaderAndSections(const MappedFile& file, const std::string& path,
                               bool verify_mapped_sections) {
  const uint8_t* base = file.data;
  const uint64_t actual_size = file.size;
  SOPE_CHECK(std::memcmp(base, kMagic, sizeof(kMagic)) == 0,
             "{} is not a sope database (no SOPEDB signature)", path);
  SOPE_CHECK(actual_size >= kHeaderBytes,
             "database {} is truncated: {} bytes, shorter than its header", path, actual_size);
  HeaderOnDisk header;
  std::memcpy(&header, base, sizeof(header));
  SOPE_CHECK(header.version == kDatabaseFormatVersion,
             "database {} has format version {}, this sope reads version {} (rebuild it with "
             "sope build-db)",
             path, header.version, kDatabaseFormatVersion);
  SOPE_CHECK(header.section_count == kNumSections &&
                 header.header_bytes == kHeaderBytes + kSectionEntryBytes * kNumSections,
             "database {} is corrupted: invalid header ({} sections, {} header bytes)", path,
             header.section_count, header.header_bytes);
  SOPE_CHECK(actual_size >= header.header_bytes,
             "database {} is truncated: {} bytes, shorter than its header", path, actual_size);
  {
    std::string head(reinterpret_cast<const char*>(base), header.header_bytes);
    HeaderOnDisk zeroed = header;
    zeroed.header_crc = 0;
    std::memcpy(&head[0], &zeroed, sizeof(zeroed));
    SOPE_CHECK(Crc32c(head.data(), head.size()) == header.header_crc,
               "database {} is corrupted: header checksum mismatch", path);
  }
  SOPE_CHECK(actual_size >= header.file_size,
             "database {} is truncated: {} of {} bytes (interrupted copy or write?)", path,
             actual_size, header.file_size);
  SOPE_CHECK(actual_size == header.file_size,
             "database {} is corrupted: {} bytes, its header says {}", path, actual_size,
             header.file_size);

  Sections sections;
  sections.base = base;
  sections.entries.resize(kNumSections);
  std::memcpy(sections.entries.data(), base + kHeaderBytes, kSectionEntryBytes * kNumSections);
  for (int s = 0; s < kNumSections; ++s) {
    const SectionEntryOnDisk& entry = sections.entries[s];
    SOPE_CHECK(std::strncmp(entry.name, kSectionNames[s], kSectionNameBytes) == 0,
               "database {} is corrupted: section {} is not '{}'", path, s, kSectionNames[s]);
    SOPE_CHECK(entry.offset % kSectionAlignment == 0 && entry.offset <= header.file_size &&
                   entry.size <= header.file_size - entry.offset,
               "database {} is corrupted: section '{}' lies outside the file", path,
               kSectionNames[s]);
    if (s < kFirstMappedSection || verify_mapped_sections) {
      SOPE_CHECK(Crc32c(base + entry.offset, entry.size) == entry.crc,
                 "database {} is corrupted: checksum mismatch in section '{}'", path,
                 kSectionNames[s]);
    }
  }
  return sections;
}

// The metadata section (JSON): options, classes, models, dimensions and distance scales.
// Returns the number of views; `stored_options` receives the options as stored.
template <typename DatabaseImpl>  // Database::Impl (private, named by Database::Open)
int ReadMetadata(const Sections& sections, const std::string& path, DatabaseImpl* impl,
                 json* stored_options) {
  int num_views = 0;
  try {
    const char* text = reinterpret_cast<const char*>(sections.data(kMetadata));
    const json meta = json::parse(text, text + sections.size(kMetadata));
    SOPE_CHECK(meta.value("format", "") == "sope-db",
               "database {} is corrupted: metadata format is not sope-db", path);
    *stored_options = meta.at("options");
    impl->options = OptionsFromJsonObject(*stored_options);
    impl->classes = meta.at("classes").get<std::vector<std::string>>();
    impl->category.assign(impl->classes.size(), 1);  // older files: every class
    if (meta.contains("categories")) {
      std::fill(impl->category.begin(), impl->category.end(), 0);
      for (const std::string& name : meta.at("categories").get<std::vector<std::string>>()) {
        const auto it = std::find(impl->classes.begin(), impl->classes.end(), name);
        SOPE_CHECK(it != impl->classes.end(),
                   "database {} is corrupted: category {} is not one of its classes", path,
                   name);
        impl->category[it - impl->classes.begin()] = 1;
      }
    }
    for (const json& m : meta.at("models")) {
      ModelRecord model;
      model.name = m.at("name").get<std::string>();
      model.class_name = m.at("class").get<std::string>();
      model.class_index = m.at("class_index").get<int>();
      model.source_path = m.at("source").get<std::string>();
      model.scale = m.at("scale").get<double>();
      model.center = Vec3FromJson(m.at("center"));
      model.diameter = m.at("diameter").get<double>();
      model.bounding_radius = m.at("bounding_radius").get<double>();
      model.cloud_quantum = m.at("cloud_quantum").get<double>();
      model.first_view = m.at("first_view").get<int>();
      model.num_views = m.at("num_views").get<int>();
      impl->models.push_back(std::move(model));
    }
    num_views = meta.at("num_views").get<int>();
    impl->coarse_dim = meta.at("coarse_dim").get<int>();
    impl->fine_dim = meta.at("fine_dim").get<int>();
    const json& scales = meta.at("distance_scales");
    impl->distance_scales.fine = scales.at("fine").get<double>();
    impl->distance_scales.coarse = scales.at("coarse").get<double>();
    impl->distance_scales.size = scales.at("size").get<double>();
  } catch (const json::exception& e) {
    SOPE_THROW("database {} is corrupted: invalid metadata ({})", path, e.what());
  }
  SOPE_CHECK(num_views > 0 && !impl->models.empty() && impl->coarse_dim > 0 &&
                 impl->fine_dim > 0,
             "database {} is corrupted: empty ({} models, {} views)", path, impl->models.size(),
             num_views);
  return num_views;
}

void ExpectSectionSize(const Sections& sections, int s, uint64_t expected,
                       const std::string& path) {
  SOPE_CHECK(sections.size(s) == expected,
             "database {} is corrupted: section '{}' has {} bytes, expected {}", path,
             kSectionNames[s], sections.size(s), expected);
}

// The view records, and each model's view range and class index within bounds.
template <typename DatabaseImpl>
void ReadViews(const Sections& sections, int num_views, const std::string& path,
               DatabaseImpl* impl) {
  const int stride = impl->options.view_cloud_points;
  impl->views.resize(num_views);
  for (int v = 0; v < num_views; ++v) {
    ViewRecordOnDisk record;
    std::memcpy(&record, sections.data(kViews) + sizeof(record) * v, sizeof(record));
    ViewRecord& view = impl->views[v];
    view.model = record.model;
    view.cloud_points = record.cloud_points;
    view.viewpoint.theta = record.theta;
    view.viewpoint.phi = record.phi;
    view.distance = record.distance;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) view.cam_from_model.rotation(r, c) = record.rotation[3 * r + c];
      view.cam_from_model.translation[r] = record.translation[r];
      view.centroid_in_model[r] = record.centroid[r];
    }
    view.radius = record.radius;
    view.cloud_spacing = record.cloud_spacing;
    view.preprocessed_points = record.preprocessed_points;
    SOPE_CHECK(view.model >= 0 && view.model < static_cast<int>(impl->models.size()) &&
                   view.cloud_points >= 0 && view.cloud_points <= stride,
               "database {} is corrupted: view {} is invalid", path, v);
  }
  for (const ModelRecord& model : impl->models) {
    SOPE_CHECK(model.first_view >= 0 && model.num_views >= 0 &&
                   int64_t{model.first_view} + model.num_views <= num_views &&
                   model.class_index >= 0 &&
                   model.class_index < static_cast<int>(impl->classes.size()) &&
                   model.cloud_quantum > 0.0,
               "database {} is corrupted: model {} is invalid", path, model.name);
  }
}

// The hasher, the standardisation and the binary codes (with their Hamming index).
template <typename DatabaseImpl>
void ReadHasherAndCodes(const Sections& sections, int num_views, const std::string& path,
                        DatabaseImpl* impl) {
  const int coarse_dim = impl->coarse_dim, fine_dim = impl->fine_dim;
  try {
    impl->hasher = Hasher::Deserialize(sections.data(kHasher), sections.size(kHasher));
  } catch (const Error& e) {
    SOPE_THROW("database {} is corrupted: {}", path, e.what());
  }
  impl->coarse_mean.resize(coarse_dim);
  impl->coarse_scale.resize(coarse_dim);
  impl->fine_mean.resize(fine_dim);
  const uint8_t* standard = sections.data(kStandard);
  std::memcpy(impl->coarse_mean.data(), standard, sizeof(float) * coarse_dim);
  std::memcpy(impl->coarse_scale.data(), standard + sizeof(float) * coarse_dim,
              sizeof(float) * coarse_dim);
  std::memcpy(impl->fine_mean.data(), standard + sizeof(float) * 2 * coarse_dim,
              sizeof(float) * fine_dim);
  std::memcpy(&impl->fine_hash_scale, standard + sizeof(float) * (2 * coarse_dim + fine_dim),
              sizeof(float));
  const int hash_dims = coarse_dim + (impl->fine_hash_scale > 0.0f ? fine_dim : 0);
  SOPE_CHECK(impl->hasher.input_dims() == hash_dims,
             "database {} is corrupted: hasher for {} dimensions, hashed vectors have {}", path,
             impl->hasher.input_dims(), hash_dims);
  const int bits = impl->hasher.bits();
  ExpectSectionSize(sections, kCodes,
                    sizeof(uint64_t) * BinaryCodes::WordsPerCode(bits) *
                        static_cast<uint64_t>(num_views),
                    path);
  impl->codes = BinaryCodes(bits, num_views);
  std::memcpy(impl->codes.words.data(), sections.data(kCodes), sections.size(kCodes));
  try {
    impl->codes.Check();
  } catch (const Error& e) {
    SOPE_THROW("database {} is corrupted: {}", path, e.what());
  }
  impl->index = std::make_unique<HammingIndex>(impl->codes);
}

}  // namespace

Database::Database(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Database::~Database() = default;

std::unique_ptr<Database> Database::Open(const std::string& path,
                                         const DatabaseOpenOptions& options) {
  auto impl = std::make_unique<Impl>();
  impl->path = path;
  MapDatabaseFile(path, &impl->file);
  const Sections sections =
      ReadHeaderAndSections(impl->file, path, options.verify_mapped_sections);
  json stored_options;
  const int num_views = ReadMetadata(sections, path, impl.get(), &stored_options);
  const uint64_t views = static_cast<uint64_t>(num_views);
  const uint64_t coarse_dim = impl->coarse_dim, fine_dim = impl->fine_dim;
  const int stride = impl->options.view_cloud_points;
  ExpectSectionSize(sections, kViews, sizeof(ViewRecordOnDisk) * views, path);
  ExpectSectionSize(sections, kStandard, sizeof(float) * (2 * coarse_dim + fine_dim + 1), path);
  ExpectSectionSize(sections, kCoarse, sizeof(float) * coarse_dim * views, path);
  ExpectSectionSize(sections, kFine, sizeof(float) * fine_dim * views, path);
  ExpectSectionSize(sections, kClouds, sizeof(CloudPointOnDisk) * static_cast<uint64_t>(stride) *
                                           views, path);
  ReadViews(sections, num_views, path, impl.get());
  ReadHasherAndCodes(sections, num_views, path, impl.get());
  impl->coarse = reinterpret_cast<const float*>(sections.data(kCoarse));
  impl->fine = reinterpret_cast<const float*>(sections.data(kFine));
  impl->clouds = reinterpret_cast<const CloudPointOnDisk*>(sections.data(kClouds));
  impl->cloud_stride = stride;
  ValidateDecodedContents(*impl, stored_options, options.verify_mapped_sections, path);
  return std::unique_ptr<Database>(new Database(std::move(impl)));
}

const std::string& Database::path() const { return impl_->path; }
uint64_t Database::file_size() const { return impl_->file.size; }
const DatabaseOptions& Database::options() const { return impl_->options; }
const std::vector<std::string>& Database::classes() const { return impl_->classes; }
bool Database::IsCategory(int class_index) const {
  return class_index >= 0 && class_index < static_cast<int>(impl_->category.size()) &&
         impl_->category[class_index] != 0;
}
const std::vector<ModelRecord>& Database::models() const { return impl_->models; }
const std::vector<ViewRecord>& Database::views() const { return impl_->views; }
const DistanceScales& Database::distance_scales() const { return impl_->distance_scales; }
const Hasher& Database::hasher() const { return impl_->hasher; }
const HammingIndex& Database::index() const { return *impl_->index; }
const BinaryCodes& Database::codes() const { return impl_->codes; }
const Eigen::VectorXf& Database::coarse_mean() const { return impl_->coarse_mean; }
const Eigen::VectorXf& Database::coarse_scale() const { return impl_->coarse_scale; }
int Database::coarse_dim() const { return impl_->coarse_dim; }
int Database::fine_dim() const { return impl_->fine_dim; }

const float* Database::coarse(int view) const {
  return impl_->coarse + static_cast<size_t>(view) * impl_->coarse_dim;
}

const float* Database::fine(int view) const {
  return impl_->fine + static_cast<size_t>(view) * impl_->fine_dim;
}

void Database::ViewCloud(int view, PointCloud* cloud) const {
  const ViewRecord& record = impl_->views[view];
  const ModelRecord& model = impl_->models[record.model];
  const CloudPointOnDisk* in = impl_->clouds + static_cast<size_t>(view) * impl_->cloud_stride;
  const Eigen::Vector3f center = model.center.cast<float>();
  const float quantum = static_cast<float>(model.cloud_quantum);
  cloud->points.resize(record.cloud_points);
  cloud->normals.resize(record.cloud_points);
  cloud->colors.clear();
  for (int i = 0; i < record.cloud_points; ++i) {
    cloud->points[i] = center + quantum * Eigen::Vector3f(in[i].position[0], in[i].position[1],
                                                          in[i].position[2]);
    cloud->normals[i] =
        Eigen::Vector3f(in[i].normal[0], in[i].normal[1], in[i].normal[2]).normalized();
  }
}

namespace {

// The quantised value of `code`: offset + code · step as one fused multiply-add (the same
// value in Quantise's errors and in the distances, scalar or vector).
inline float Dequantised(uint8_t code, const ViewSketches::Row& row) {
  return std::fma(static_cast<float>(code), row.step, row.offset);
}

#if defined(__AVX512F__)
inline __m256 UpperHalf(__m512 v) {
  return _mm256_castsi256_ps(_mm512_extracti64x4_epi64(_mm512_castps_si512(v), 1));
}
#endif

}  // namespace

ViewSketches::Row ViewSketches::Quantise(const float* values, int dims, uint8_t* codes) {
  Row row;
  if (dims <= 0) return row;
  const auto [least, greatest] = std::minmax_element(values, values + dims);
  row.offset = *least;
  row.step = (*greatest - *least) / 255.0f;
  const float inverse_step = row.step > 0.0f ? 1.0f / row.step : 0.0f;
  double l1 = 0.0, l2 = 0.0;
  int d = 0;
#if defined(__AVX512F__)
  // 16 dimensions a step; the errors in double (a float minus its quantised value is
  // exact there), summed per lane.
  const __m512 offset = _mm512_set1_ps(row.offset), step = _mm512_set1_ps(row.step);
  const __m512 inverse = _mm512_set1_ps(inverse_step);
  __m512d sum1[2] = {_mm512_setzero_pd(), _mm512_setzero_pd()};
  __m512d sum2[2] = {_mm512_setzero_pd(), _mm512_setzero_pd()};
  for (; d + 16 <= dims; d += 16) {
    const __m512 value = _mm512_loadu_ps(values + d);
    const __m512 nearest =
        _mm512_fmadd_ps(_mm512_sub_ps(value, offset), inverse, _mm512_set1_ps(0.5f));
    const __m512 scaled = _mm512_min_ps(_mm512_max_ps(nearest, _mm512_setzero_ps()),
                                        _mm512_set1_ps(255.0f));
    const __m512i code = _mm512_cvttps_epi32(scaled);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(codes + d), _mm512_cvtepi32_epi8(code));
    const __m512 rebuilt = _mm512_fmadd_ps(_mm512_cvtepi32_ps(code), step, offset);
    for (int half = 0; half < 2; ++half) {
      const __m256 v = half ? UpperHalf(value) : _mm512_castps512_ps256(value);
      const __m256 r = half ? UpperHalf(rebuilt) : _mm512_castps512_ps256(rebuilt);
      const __m512d error = _mm512_sub_pd(_mm512_cvtps_pd(v), _mm512_cvtps_pd(r));
      sum1[half] = _mm512_add_pd(sum1[half], _mm512_abs_pd(error));
      sum2[half] = _mm512_fmadd_pd(error, error, sum2[half]);
    }
  }
  l1 = _mm512_reduce_add_pd(_mm512_add_pd(sum1[0], sum1[1]));
  l2 = _mm512_reduce_add_pd(_mm512_add_pd(sum2[0], sum2[1]));
#endif
  for (; d < dims; ++d) {
    // Any code will do (the error below is that of the code chosen): the nearest one.
    codes[d] = static_cast<uint8_t>(
        std::clamp((values[d] - row.offset) * inverse_step + 0.5f, 0.0f, 255.0f));
    const double error = static_cast<double>(values[d]) - Dequantised(codes[d], row);
    l1 += std::abs(error);
    l2 += error * error;
  }
  // Rounded up a little: the sums' own rounding (double) must not make them too small.
  row.l1_error = l1 * (1.0 + 1e-9);
  row.l2_error = std::sqrt(l2) * (1.0 + 1e-9);
  return row;
}

namespace {

// Σ|â − b| (kSquared false) or Σ(â − b)² of a quantised row against `b`, in float.
template <bool kSquared>
float QuantisedDistance(const uint8_t* codes, const ViewSketches::Row& row, const float* b,
                        int dims) {
  int d = 0;
  float sum = 0.0f;
#if defined(__AVX512F__)
  const __m512 step = _mm512_set1_ps(row.step), offset = _mm512_set1_ps(row.offset);
  // Two chains of additions, 16 dimensions each.
  __m512 acc[2] = {_mm512_setzero_ps(), _mm512_setzero_ps()};
  for (; d + 16 <= dims; d += 16) {
    const __m512 code = _mm512_cvtepi32_ps(
        _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(codes + d))));
    const __m512 diff =
        _mm512_sub_ps(_mm512_fmadd_ps(code, step, offset), _mm512_loadu_ps(b + d));
    __m512& chain = acc[(d >> 4) & 1];
    chain = kSquared ? _mm512_fmadd_ps(diff, diff, chain)
                     : _mm512_add_ps(chain, _mm512_abs_ps(diff));
  }
  sum = _mm512_reduce_add_ps(_mm512_add_ps(acc[0], acc[1]));
#endif
  for (; d < dims; ++d) {
    const float e = Dequantised(codes[d], row) - b[d];
    sum += kSquared ? e * e : std::abs(e);
  }
  return sum;
}

}  // namespace

float ViewSketches::L1To(const uint8_t* codes, const Row& row, const float* b, int dims) {
  return QuantisedDistance<false>(codes, row, b, dims);
}

float ViewSketches::SquaredL2To(const uint8_t* codes, const Row& row, const float* b, int dims) {
  return QuantisedDistance<true>(codes, row, b, dims);
}

const ViewSketches& Database::view_sketches() const {
  std::call_once(impl_->sketches_once, [this] {
    ViewSketches& s = impl_->sketches;
    const size_t views = static_cast<size_t>(num_views());
    const int cd = impl_->coarse_dim, fd = impl_->fine_dim;
    s.coarse_codes.resize(views * cd);
    s.fine_codes.resize(views * fd);
    s.coarse_rows.resize(views);
    s.fine_rows.resize(views);
    for (size_t v = 0; v < views; ++v) {
      const int view = static_cast<int>(v);
      s.coarse_rows[v] = ViewSketches::Quantise(coarse(view), cd, s.coarse_codes.data() + v * cd);
      s.fine_rows[v] = ViewSketches::Quantise(fine(view), fd, s.fine_codes.data() + v * fd);
    }
  });
  return impl_->sketches;
}

PointCloud Database::ViewCloud(int view) const {
  PointCloud cloud;
  ViewCloud(view, &cloud);
  return cloud;
}

Eigen::VectorXf Database::HashInput(const Eigen::VectorXf& standardised_coarse,
                                   const Eigen::VectorXf& fine) const {
  SOPE_CHECK(standardised_coarse.size() == impl_->coarse_dim && fine.size() == impl_->fine_dim,
             "Database::HashInput: {} coarse and {} fine values, the database has {} and {}",
             standardised_coarse.size(), fine.size(), impl_->coarse_dim, impl_->fine_dim);
  return HashInputVector(standardised_coarse, fine, impl_->fine_mean, impl_->fine_hash_scale);
}

Eigen::VectorXf Database::Standardise(const Eigen::VectorXf& coarse) const {
  SOPE_CHECK(coarse.size() == impl_->coarse_dim,
             "Database::Standardise: {} values, the database's coarse vectors have {}",
             coarse.size(), impl_->coarse_dim);
  return ((coarse - impl_->coarse_mean).array() / impl_->coarse_scale.array()).matrix();
}

}  // namespace sope
