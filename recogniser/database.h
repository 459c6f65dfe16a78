// The recognition database (thesis §4.4–4.5): every model seen from many viewpoints, each
// view described coarse to fine (recogniser/features.h), the coarse vectors compressed to
// binary codes (recogniser/hashing.h), and a small copy of each view's cloud kept for roll
// estimation, ICP and verification (recogniser/pose.h). BuildDatabase()
// (recogniser/tools/database_builder.h) makes one from meshes; this header holds what a database
// is, its file, and the read-only view of an opened file.
//
// File `.sopedb` (DESIGN.md "Database"), little-endian, format version kDatabaseFormatVersion:
//
//   header (64 bytes)  magic "SOPEDB\r\n" (8) · format version u32 · header bytes u32 ·
//                      section count u32 · header CRC-32C u32 (of the header and section
//                      table with this field zero) · file size u64 · reserved (32)
//   section table      per section: name (16, NUL-padded) · offset u64 · size u64 ·
//                      CRC-32C u32 · reserved u32
//   sections           each at a 4096-byte (page) aligned offset, zero padding between:
//     metadata  JSON: format, build options (viewpoints, rendering, size normalisation,
//               pre-processing, features, hashing), classes, categories (optional: absent
//               = every class), models, coarse layout, sizes
//     views     one 152-byte record per view (ViewRecord, see ViewRecordOnDisk in the .cc)
//     hasher    Hasher::Serialize()
//     standard  coarse-feature standardisation: mean, scale (float32 × coarse_dim each),
//               then the fine mean (float32 × fine_dim) and the fine hash scale (float32)
//     codes     the binary codes, ⌈bits/64⌉ uint64 per view, contiguous
//     coarse    standardised coarse vectors, float32, views × coarse_dim, row-major
//     fine      fine descriptors, float32, views × fine_dim, row-major
//     clouds    per view `view_cloud_points` points, model frame: int16 x, y, z in units of
//               the model's cloud quantum about its centre, int16 normal x, y, z × 32767
//               (12 bytes a point; unused slots zero; the view record holds the count)
//
// Open() reads metadata, views, hasher, standard and codes into memory and verifies their
// checksums eagerly; coarse, fine and clouds stay memory-mapped read-only (pages are read
// only when a query touches a flagged view) and their checksums are verified at open too
// unless DatabaseOpenOptions::verify_mapped_sections is false (then only their sizes are).
// A truncated, corrupted (checksum mismatch), wrong-version or non-database file is refused
// with one sope::Error naming the file and the problem.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/object_size.h"
#include "core/options.h"
#include "core/point_cloud.h"
#include "core/rigid3d.h"
#include "recogniser/features.h"
#include "recogniser/hamming_search.h"
#include "recogniser/hashing.h"
#include "recogniser/preprocess.h"
#include "recogniser/viewpoints.h"

namespace sope {

constexpr uint32_t kDatabaseFormatVersion = 1;

// How database views are rendered (simulator DepthRenderer: an ideal depth camera).
struct ViewRenderOptions {
  int width = 320;   // pixels
  int height = 240;  // pixels
  // Horizontal field of view, radians (pinhole, no distortion).
  double horizontal_fov = 0.9;
  // Camera distance from the model centre, metres: the middle of the working range
  // (queries come from 0.4–0.8 m). Increased for a model that would not fit the image:
  // distance ≥ fit_margin · bounding_radius / sin(half the smaller field of view).
  double distance = 0.6;
  double fit_margin = 1.15;
  void Check() const;
};

// Meshes of arbitrary units (the classic test models are ~1–13 units across) are scaled to
// a plausible real-world size: a mesh whose bounding-box diagonal, read as metres, lies
// outside [min_plausible_diagonal, max_plausible_diagonal] is scaled uniformly (about the
// file's origin) to `target_diagonal`; other meshes keep their file's units as metres.
// With `mesh_unit` given (build-db --units) every mesh is scaled by it instead: models in
// millimetres (BOP's) keep their real size, which a rig scanning the real objects needs.
struct SizeNormalisationOptions {
  // Defaults: the one plausibility rule (core/object_size.h).
  double min_plausible_diagonal = kMinPlausibleDiagonal;  // metres
  double max_plausible_diagonal = kMaxPlausibleDiagonal;  // metres
  double target_diagonal = kDefaultObjectDiagonal;        // metres
  // Metres per mesh file unit (0.001: millimetres); 0 guesses by the rule above.
  double mesh_unit = 0.0;
  void Check() const;
};

// Everything that determines a database's contents; stored in its metadata, so queries are
// pre-processed and featurised exactly like the views.
struct DatabaseOptions {
  ViewpointLayout layout = ViewpointLayout::kFibonacci;
  int views_per_model = 300;  // kThesis18: 18
  ViewRenderOptions render;
  SizeNormalisationOptions size;
  PreprocessOptions preprocess;
  FeatureOptions features;
  HashOptions hash;
  // Points kept per view for roll estimation, ICP and verification (farthest-point
  // sample of the pre-processed view, model frame).
  int view_cloud_points = 256;
  // Scale each coarse block (CoarseLayout) so that every block, whatever its length,
  // contributes equally to the coarse distance and the codes: the per-dimension
  // standard deviation times √(block length).
  bool equal_block_weights = true;
  // What the binary codes compress. The thesis hashed the coarse vector only; a query
  // whose coarse features suffer from occlusion then loses its model in the coarse search
  // although its fine descriptor still matches. With a weight w > 0 the hashed vector is
  // [standardised coarse; w · s · (fine − fine mean)], s chosen so that the fine part's
  // typical distance between views equals the coarse part's (w = 1: equal say).
  double hash_fine_weight = 1.0;

  // Our configuration (default) and the thesis's (18 viewpoints, thesis features, MLH
  // codes): "sope" | "thesis". Throws sope::Error naming an unknown preset.
  static DatabaseOptions Preset(const std::string& name);
  // Every field, named as in the database file's JSON ("hash.bits", …; core/options.h).
  static const std::vector<OptionField<DatabaseOptions>>& Fields();
  // Throws sope::Error naming the first invalid value (checks every nested options).
  void Check() const;
};

struct ModelRecord {
  std::string name;         // file stem, e.g. "mug_3"
  std::string class_name;   // directory name, or the stem for a flat file
  int class_index = 0;      // into DatabaseData::classes
  std::string source_path;  // the mesh file as given to the builder
  // Model frame = file coordinates × scale (metres); no offset.
  double scale = 1.0;
  // Bounding-box centre (model frame, metres): the point the viewpoints look at.
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  // Largest distance between two surface points (metres, from a surface sample), and the
  // largest distance of a vertex from `center`.
  double diameter = 0.0;
  double bounding_radius = 0.0;
  // Metres per int16 unit of the stored view clouds (bounding_radius / 32000).
  double cloud_quantum = 0.0;
  int first_view = 0;  // the model's views are [first_view, first_view + num_views)
  int num_views = 0;
};

struct ViewRecord {
  int32_t model = 0;
  Viewpoint viewpoint;    // radians
  double distance = 0.0;  // camera distance from the model centre, metres
  // Pose of the database camera: X_cam = R·X_model + t (metres).
  Rigid3d cam_from_model;
  // Centroid (model frame, metres) and normalisation radius (metres) of the pre-processed
  // view (PreprocessedCloud::centroid / radius).
  Eigen::Vector3f centroid_in_model = Eigen::Vector3f::Zero();
  float radius = 0.0f;
  int32_t cloud_points = 0;  // points of the stored view cloud
  // Median distance from a stored cloud point to its nearest neighbour, metres.
  float cloud_spacing = 0.0f;
  int32_t preprocessed_points = 0;  // points of the pre-processed view
};

// Typical distances between unrelated views (medians over random pairs of views), the
// units in which the recogniser's fine stage combines its distances: fine = L1 between
// fine descriptors, coarse = Euclidean between standardised coarse vectors, size =
// |log(radius ratio)|.
struct DistanceScales {
  double fine = 1.0;
  double coarse = 1.0;
  double size = 1.0;
};

// A database in memory: what the builder produces and WriteDatabase() stores.
struct DatabaseData {
  using RowMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  DatabaseOptions options;
  std::vector<std::string> classes;
  // The classes that are categories: folders of alike objects (DIR/<class>/CATEGORY, as
  // `sope objects` writes), whose unseen instances the tabletop recogniser may accept at
  // class level. A class of a dataset's unlike objects is not one. A subset of `classes`,
  // in their order.
  std::vector<std::string> categories;
  std::vector<ModelRecord> models;
  std::vector<ViewRecord> views;
  // Coarse standardisation: standardised = (coarse − mean) / scale, per dimension.
  Eigen::VectorXf coarse_mean, coarse_scale;
  RowMatrix coarse;  // views × coarse_dim, standardised
  RowMatrix fine;    // views × fine_dim
  // Fine part of the hashed vector: w · fine_hash_scale · (fine − fine_mean) (see
  // DatabaseOptions::hash_fine_weight; fine_hash_scale includes w, 0 when w = 0).
  Eigen::VectorXf fine_mean;
  float fine_hash_scale = 0.0f;
  Hasher hasher;
  BinaryCodes codes;  // one per view
  // Per view, ≤ options.view_cloud_points points with normals, model frame.
  std::vector<PointCloud> view_clouds;
  DistanceScales distance_scales;

  // Throws sope::Error naming the first inconsistency (counts, dimensions, indices).
  void Check() const;
};

// The vector the hasher encodes (DatabaseOptions::hash_fine_weight), shared by the builder
// and Database::HashInput.
Eigen::VectorXf HashInputVector(const Eigen::VectorXf& standardised_coarse,
                                const Eigen::VectorXf& fine, const Eigen::VectorXf& fine_mean,
                                float fine_hash_scale);

// Writes `data` as one .sopedb file, atomically (WriteFileAtomic). View clouds are
// quantised (see the file comment: ≤ cloud_quantum/2 per coordinate, ≤ 1/32767 per normal
// component). Throws sope::Error on inconsistent data or a write failure.
void WriteDatabase(const std::string& path, const DatabaseData& data);

struct DatabaseOpenOptions {
  // Verify the checksums of the memory-mapped sections (coarse, fine, clouds) at open.
  // Reads them once (≈ 5 ms per 10k views from the page cache); false keeps open O(small
  // sections) for very large files, checking only their sizes.
  bool verify_mapped_sections = true;
};

// Each view's coarse and fine rows quantised to a byte per dimension (value ≈ offset +
// code · step, 256 steps between the row's least and greatest value) with the exact
// error that leaves: by the triangle inequality Σ|a − b| ≥ Σ|â − b| − Σ|a − â| and
// ‖a − b‖ ≥ ‖â − b‖ − ‖a − â‖, lower bounds on the fine stage's distances from a quarter
// of the bytes (the widened search ranks every view of the database: recogniser/stages.h
// LazyViewRanking).
struct ViewSketches {
  struct Row {
    float offset = 0.0f, step = 0.0f;
    double l1_error = 0.0, l2_error = 0.0;  // Σ|a − â|, ‖a − â‖
  };
  std::vector<uint8_t> coarse_codes, fine_codes;  // view-major, coarse_dim / fine_dim each
  std::vector<Row> coarse_rows, fine_rows;        // per view

  // Quantises `dims` values into `codes`.
  static Row Quantise(const float* row, int dims, uint8_t* codes);
  // Σ|â − b| and ‖â − b‖² of a quantised row against `b`, in float.
  static float L1To(const uint8_t* codes, const Row& row, const float* b, int dims);
  static float SquaredL2To(const uint8_t* codes, const Row& row, const float* b, int dims);
};

// An opened database file: small sections in memory, large ones memory-mapped. Immutable;
// all accessors are const and safe to call from several threads.
class Database {
 public:
  // Throws sope::Error with one clear message (see the file comment).
  static std::unique_ptr<Database> Open(const std::string& path,
                                        const DatabaseOpenOptions& options = {});
  ~Database();
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;

  const std::string& path() const;
  uint64_t file_size() const;
  const DatabaseOptions& options() const;
  const std::vector<std::string>& classes() const;
  // Whether class `class_index` is a category (DatabaseData::categories). A file written
  // before categories were recorded has every class a category (as it was recognised).
  bool IsCategory(int class_index) const;
  const std::vector<ModelRecord>& models() const;
  const std::vector<ViewRecord>& views() const;
  int num_models() const { return static_cast<int>(models().size()); }
  int num_views() const { return static_cast<int>(views().size()); }
  const ModelRecord& model(int index) const { return models()[index]; }
  const ViewRecord& view(int index) const { return views()[index]; }

  const DistanceScales& distance_scales() const;
  const Hasher& hasher() const;
  const HammingIndex& index() const;  // over the codes, in view order
  const BinaryCodes& codes() const;
  const Eigen::VectorXf& coarse_mean() const;
  const Eigen::VectorXf& coarse_scale() const;
  int coarse_dim() const;
  int fine_dim() const;
  // Memory-mapped rows (coarse_dim / fine_dim floats), valid while the database lives.
  const float* coarse(int view) const;
  const float* fine(int view) const;
  // Decodes the view's stored cloud (model frame, metres, unit normals) into `cloud`.
  void ViewCloud(int view, PointCloud* cloud) const;
  PointCloud ViewCloud(int view) const;
  // Every view's coarse and fine rows quantised (ViewSketches), made on the first call
  // (one pass over the mapped rows) and kept; safe from several threads.
  const ViewSketches& view_sketches() const;

  // Standardised coarse vector of raw coarse features (same layout as coarse()).
  Eigen::VectorXf Standardise(const Eigen::VectorXf& coarse) const;
  // The vector the hasher encodes for a standardised coarse vector and a fine descriptor.
  Eigen::VectorXf HashInput(const Eigen::VectorXf& standardised_coarse,
                            const Eigen::VectorXf& fine) const;

 private:
  struct Impl;
  explicit Database(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// JSON form of the options (as stored in the metadata section), for reports.
std::string DatabaseOptionsToJson(const DatabaseOptions& options);
DatabaseOptions DatabaseOptionsFromJson(const std::string& json);

}  // namespace sope
