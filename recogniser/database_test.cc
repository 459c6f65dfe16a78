#include "recogniser/database.h"

#include <sys/stat.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <limits>
#include <random>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "recogniser/crc32c.h"
#include "tests/test_support.h"

namespace sope {
namespace {

TEST(Crc32c, KnownValuesAndHardwareAgreesWithTable) {
  const char* check = "123456789";
  EXPECT_EQ(Crc32c(check, 9), 0xE3069283u);
  EXPECT_EQ(internal::Crc32cPortable(check, 9, 0), 0xE3069283u);
  EXPECT_EQ(Crc32c("", 0), 0u);
  // 32 zero bytes (RFC 3720 B.4).
  const std::vector<uint8_t> zeros(32, 0);
  EXPECT_EQ(Crc32c(zeros.data(), zeros.size()), 0x8A9136AAu);
  std::mt19937 rng(7);
  std::vector<uint8_t> buffer(5000);
  for (uint8_t& b : buffer) b = static_cast<uint8_t>(rng());
  for (size_t offset : {0, 1, 3, 7}) {
    for (size_t size : {0, 1, 7, 8, 31, 32, 33, 1000, 4990}) {
      EXPECT_EQ(Crc32c(buffer.data() + offset, size),
                internal::Crc32cPortable(buffer.data() + offset, size, 0))
          << offset << " " << size;
    }
  }
  // Incremental = whole.
  const uint32_t whole = Crc32c(buffer.data(), buffer.size());
  EXPECT_EQ(Crc32c(buffer.data() + 1234, buffer.size() - 1234, Crc32c(buffer.data(), 1234)), whole);
}

// A small database with random contents (no rendering): checks the file, not the features.
DatabaseData MakeSyntheticData(uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  DatabaseData data;
  data.options.view_cloud_points = 40;
  data.options.views_per_model = 7;
  data.classes = {"bowl", "mug"};
  const int num_models = 3, coarse_dim = 12, fine_dim = 20;
  for (int m = 0; m < num_models; ++m) {
    ModelRecord model;
    model.name = "model_" + std::to_string(m);
    model.class_index = m == 0 ? 0 : 1;
    model.class_name = data.classes[model.class_index];
    model.source_path = "/models/" + model.class_name + "/" + model.name + ".obj";
    model.scale = m == 2 ? 0.031 : 1.0;
    model.center = Eigen::Vector3d(0.01 * m, -0.02, 0.05);
    model.bounding_radius = 0.08 + 0.02 * m;
    model.diameter = 1.9 * model.bounding_radius;
    model.cloud_quantum = model.bounding_radius / 32000.0;
    model.first_view = static_cast<int>(data.views.size());
    model.num_views = 7;
    for (int v = 0; v < model.num_views; ++v) {
      ViewRecord view;
      view.model = m;
      view.viewpoint = Viewpoint{uniform(rng) * 3.14, uniform(rng) * 6.28};
      view.distance = 0.6;
      view.cam_from_model = CameraPoseForViewpoint(view.viewpoint, 0.6, model.center);
      view.centroid_in_model = model.center.cast<float>() + Eigen::Vector3f(0.01f, 0.0f, -0.01f);
      view.radius = 0.05f + 0.01f * v;
      PointCloud cloud;
      const int points = 10 + v * 4;
      for (int i = 0; i < points; ++i) {
        Eigen::Vector3f direction(normal(rng), normal(rng), normal(rng));
        direction.normalize();
        cloud.points.push_back(model.center.cast<float>() +
                               static_cast<float>(model.bounding_radius * uniform(rng)) * direction);
        Eigen::Vector3f n(normal(rng), normal(rng), normal(rng));
        cloud.normals.push_back(n.normalized());
      }
      view.cloud_points = points;
      view.cloud_spacing = 0.01f * (v + 1);
      view.preprocessed_points = 1000 + v;
      data.views.push_back(view);
      data.view_clouds.push_back(cloud);
    }
    data.models.push_back(model);
  }
  const int n = static_cast<int>(data.views.size());
  data.coarse.resize(n, coarse_dim);
  data.fine.resize(n, fine_dim);
  for (int v = 0; v < n; ++v) {
    for (int d = 0; d < coarse_dim; ++d) data.coarse(v, d) = normal(rng);
    for (int d = 0; d < fine_dim; ++d) data.fine(v, d) = static_cast<float>(uniform(rng));
  }
  data.coarse_mean = Eigen::VectorXf::Random(coarse_dim);
  data.coarse_scale = Eigen::VectorXf::Constant(coarse_dim, 1.5f);
  data.fine_mean = Eigen::VectorXf::Constant(fine_dim, 0.5f);
  data.fine_hash_scale = 2.0f;
  Eigen::MatrixXf hashed(n, coarse_dim + fine_dim);
  for (int v = 0; v < n; ++v) {
    hashed.row(v) = HashInputVector(data.coarse.row(v).transpose(), data.fine.row(v).transpose(),
                                    data.fine_mean, data.fine_hash_scale)
                        .transpose();
  }
  HashOptions hash;
  hash.bits = 64;
  data.hasher = Hasher::Train(hashed, hash);
  data.codes = data.hasher.Encode(hashed);
  data.distance_scales = DistanceScales{0.4, 3.0, 0.25};
  return data;
}

std::string ReadBytes(const std::string& path) { return ReadFileToString(path, "file"); }

void WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// The error Open throws for `path`, or "" when it opens.
std::string OpenError(const std::string& path, const DatabaseOpenOptions& options = {}) {
  try {
    Database::Open(path, options);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// Offset of a named section's data, from the table in the header.
uint64_t SectionOffset(const std::string& bytes, const std::string& name) {
  for (int s = 0; s < 8; ++s) {
    const char* entry = bytes.data() + 64 + 40 * s;
    if (std::strncmp(entry, name.c_str(), 16) == 0) {
      uint64_t offset;
      std::memcpy(&offset, entry + 16, 8);
      return offset;
    }
  }
  ADD_FAILURE() << "no section " << name;
  return 0;
}

TEST(Database, RoundTripEqualsWhatWasWritten) {
  testing::ScratchDir scratch;
  const DatabaseData data = MakeSyntheticData(1);
  const std::string path = scratch.File("small.sopedb");
  WriteDatabase(path, data);
  const std::unique_ptr<Database> db = Database::Open(path);

  EXPECT_EQ(DatabaseOptionsToJson(db->options()), DatabaseOptionsToJson(data.options));
  EXPECT_EQ(db->classes(), data.classes);
  ASSERT_EQ(db->num_models(), 3);
  for (int m = 0; m < 3; ++m) {
    const ModelRecord& a = data.models[m];
    const ModelRecord& b = db->model(m);
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.class_name, b.class_name);
    EXPECT_EQ(a.class_index, b.class_index);
    EXPECT_EQ(a.source_path, b.source_path);
    EXPECT_EQ(a.scale, b.scale);
    EXPECT_EQ(a.center, b.center);
    EXPECT_EQ(a.diameter, b.diameter);
    EXPECT_EQ(a.bounding_radius, b.bounding_radius);
    EXPECT_EQ(a.cloud_quantum, b.cloud_quantum);
    EXPECT_EQ(a.first_view, b.first_view);
    EXPECT_EQ(a.num_views, b.num_views);
  }
  ASSERT_EQ(db->num_views(), 21);
  for (int v = 0; v < db->num_views(); ++v) {
    const ViewRecord& a = data.views[v];
    const ViewRecord& b = db->view(v);
    EXPECT_EQ(a.model, b.model);
    EXPECT_EQ(a.viewpoint.theta, b.viewpoint.theta);
    EXPECT_EQ(a.viewpoint.phi, b.viewpoint.phi);
    EXPECT_EQ(a.distance, b.distance);
    EXPECT_EQ(a.cam_from_model.rotation, b.cam_from_model.rotation);
    EXPECT_EQ(a.cam_from_model.translation, b.cam_from_model.translation);
    EXPECT_EQ(a.centroid_in_model, b.centroid_in_model);
    EXPECT_EQ(a.radius, b.radius);
    EXPECT_EQ(a.cloud_points, b.cloud_points);
    EXPECT_EQ(a.cloud_spacing, b.cloud_spacing);
    EXPECT_EQ(a.preprocessed_points, b.preprocessed_points);
    // Memory-mapped features equal bit for bit.
    EXPECT_EQ(std::memcmp(db->coarse(v), data.coarse.row(v).data(), sizeof(float) * 12), 0);
    EXPECT_EQ(std::memcmp(db->fine(v), data.fine.row(v).data(), sizeof(float) * 20), 0);
    // Clouds within the quantisation: half a quantum per coordinate, 1/32767 per normal
    // component (plus float rounding).
    const PointCloud cloud = db->ViewCloud(v);
    const double quantum = data.models[a.model].cloud_quantum;
    ASSERT_EQ(cloud.size(), data.view_clouds[v].size());
    for (size_t i = 0; i < cloud.size(); ++i) {
      EXPECT_LE((cloud.points[i] - data.view_clouds[v].points[i]).cwiseAbs().maxCoeff(),
                0.5 * quantum + 1e-7);
      EXPECT_LE((cloud.normals[i] - data.view_clouds[v].normals[i]).norm(), 1e-4);
    }
  }
  EXPECT_EQ(db->coarse_dim(), 12);
  EXPECT_EQ(db->fine_dim(), 20);
  EXPECT_EQ(db->coarse_mean(), data.coarse_mean);
  EXPECT_EQ(db->coarse_scale(), data.coarse_scale);
  EXPECT_EQ(db->codes().words, data.codes.words);
  EXPECT_EQ(db->index().size(), 21);
  EXPECT_EQ(db->hasher().Serialize(), data.hasher.Serialize());
  EXPECT_EQ(db->distance_scales().fine, 0.4);
  EXPECT_EQ(db->distance_scales().coarse, 3.0);
  EXPECT_EQ(db->distance_scales().size, 0.25);
  // Standardise inverts the stored mean/scale.
  const Eigen::VectorXf raw = Eigen::VectorXf::Constant(12, 2.0f);
  EXPECT_TRUE(db->Standardise(raw).isApprox(
      ((raw - data.coarse_mean).array() / data.coarse_scale.array()).matrix()));
  // The hashed vector (fine mean and scale) survives, and so do the codes of the stored rows.
  const Eigen::VectorXf fine = Eigen::VectorXf::LinSpaced(20, 0.0f, 1.0f);
  EXPECT_EQ(db->HashInput(raw, fine),
            HashInputVector(raw, fine, data.fine_mean, data.fine_hash_scale));
  const BinaryCodes recoded = db->hasher().Encode(
      db->HashInput(data.coarse.row(4).transpose(), data.fine.row(4).transpose()).transpose());
  EXPECT_EQ(HammingDistance(recoded.code(0), db->codes().code(4), recoded.words_per_code), 0);
  // The same file when written again (deterministic writer).
  WriteDatabase(scratch.File("again.sopedb"), data);
  EXPECT_EQ(ReadBytes(path), ReadBytes(scratch.File("again.sopedb")));
}

// The quantised rows (ViewSketches) bound the distances from below: for any row b,
// L1To − l1_error ≤ Σ|a − b| and √SquaredL2To − l2_error ≤ ‖a − b‖, with the errors those
// of the codes (rows of every sign and scale, a constant row, lengths not a multiple of
// the vector width); and an opened database's sketches are those of its rows.
TEST(ViewSketches, QuantisedRowsBoundTheDistancesFromBelow) {
  std::mt19937 rng(7);
  for (const int dims : {1, 15, 16, 37, 308}) {
    for (int trial = 0; trial < 40; ++trial) {
      const float scale = std::pow(10.0f, std::uniform_real_distribution<float>(-4, 2)(rng));
      std::normal_distribution<float> value(trial % 3 == 0 ? 1.0f : 0.0f, scale);
      std::vector<float> a(dims), b(dims);
      for (int d = 0; d < dims; ++d) {
        a[d] = trial == 5 ? 0.25f : value(rng);  // trial 5: a constant row (step 0)
        b[d] = value(rng);
      }
      std::vector<uint8_t> codes(dims);
      const ViewSketches::Row row = ViewSketches::Quantise(a.data(), dims, codes.data());
      double l1 = 0.0, l2 = 0.0, error1 = 0.0, error2 = 0.0;
      for (int d = 0; d < dims; ++d) {
        l1 += std::abs(static_cast<double>(a[d]) - b[d]);
        l2 += std::pow(static_cast<double>(a[d]) - b[d], 2);
        const double rebuilt = std::fma(static_cast<float>(codes[d]), row.step, row.offset);
        error1 += std::abs(a[d] - rebuilt);
        error2 += std::pow(a[d] - rebuilt, 2);
      }
      EXPECT_NEAR(row.l1_error, error1, 1e-6 * error1 + 1e-12);
      EXPECT_NEAR(row.l2_error, std::sqrt(error2), 1e-6 * std::sqrt(error2) + 1e-12);
      EXPECT_LE(row.l1_error, dims * 0.5001 * row.step + 1e-12);  // the nearest code
      const double quantised1 = ViewSketches::L1To(codes.data(), row, b.data(), dims);
      const double quantised2 = ViewSketches::SquaredL2To(codes.data(), row, b.data(), dims);
      EXPECT_LE(quantised1 * (1 - 1e-4) - row.l1_error, l1) << dims << " " << trial;
      EXPECT_LE(std::sqrt(quantised2 * (1 - 1e-4)) - row.l2_error, std::sqrt(l2))
          << dims << " " << trial;
      // Tight: within the quantisation error of the exact distance.
      EXPECT_GE(quantised1 - row.l1_error, l1 - 2 * row.l1_error - 1e-4 * l1 - 1e-9);
    }
  }
  testing::ScratchDir scratch;
  const DatabaseData data = MakeSyntheticData(1);
  const std::string path = scratch.File("small.sopedb");
  WriteDatabase(path, data);
  const std::unique_ptr<Database> db = Database::Open(path);
  const ViewSketches& sketches = db->view_sketches();
  ASSERT_EQ(sketches.fine_rows.size(), static_cast<size_t>(db->num_views()));
  ASSERT_EQ(sketches.coarse_codes.size(), static_cast<size_t>(db->num_views() * 12));
  for (int v = 0; v < db->num_views(); ++v) {
    std::vector<uint8_t> codes(20);
    const ViewSketches::Row row = ViewSketches::Quantise(db->fine(v), 20, codes.data());
    EXPECT_EQ(std::memcmp(codes.data(), &sketches.fine_codes[v * 20], 20), 0);
    EXPECT_EQ(row.offset, sketches.fine_rows[v].offset);
    EXPECT_EQ(row.step, sketches.fine_rows[v].step);
  }
  EXPECT_EQ(&db->view_sketches(), &sketches);  // made once
}

TEST(Database, SectionsArePageAligned) {
  testing::ScratchDir scratch;
  WriteDatabase(scratch.File("db.sopedb"), MakeSyntheticData(2));
  const std::string bytes = ReadBytes(scratch.File("db.sopedb"));
  for (const char* name : {"metadata", "views", "hasher", "standard", "codes", "coarse", "fine",
                           "clouds"}) {
    EXPECT_EQ(SectionOffset(bytes, name) % 4096, 0u) << name;
  }
  EXPECT_EQ(bytes.size() % 4096, 0u);
}

TEST(Database, RefusesTruncatedFiles) {
  testing::ScratchDir scratch;
  const std::string path = scratch.File("db.sopedb");
  WriteDatabase(path, MakeSyntheticData(3));
  const std::string bytes = ReadBytes(path);
  for (size_t keep : {bytes.size() - 1, bytes.size() / 2, size_t{100}, size_t{40}}) {
    const std::string cut = scratch.File("cut.sopedb");
    WriteBytes(cut, bytes.substr(0, keep));
    const std::string error = OpenError(cut);
    EXPECT_NE(error.find("truncated"), std::string::npos) << keep << ": " << error;
    EXPECT_NE(error.find(cut), std::string::npos) << error;
  }
}

TEST(Database, RefusesBitFlipsInEverySection) {
  testing::ScratchDir scratch;
  const std::string path = scratch.File("db.sopedb");
  WriteDatabase(path, MakeSyntheticData(4));
  const std::string bytes = ReadBytes(path);
  for (const char* name : {"metadata", "views", "hasher", "standard", "codes", "coarse", "fine",
                           "clouds"}) {
    std::string flipped = bytes;
    flipped[SectionOffset(bytes, name) + 5] ^= 0x10;
    const std::string bad = scratch.File("flipped.sopedb");
    WriteBytes(bad, flipped);
    const std::string error = OpenError(bad);
    EXPECT_NE(error.find("corrupted: checksum mismatch in section '" + std::string(name) + "'"),
              std::string::npos)
        << name << ": " << error;
    const bool mapped = std::string(name) == "coarse" || std::string(name) == "fine" ||
                        std::string(name) == "clouds";
    DatabaseOpenOptions lazy;
    lazy.verify_mapped_sections = false;
    // Without eager verification of the mapped sections only those flips go unnoticed.
    EXPECT_EQ(OpenError(bad, lazy).empty(), mapped) << name;
  }
  // A flip in the section table (an offset) is caught by the header checksum.
  std::string flipped = bytes;
  flipped[64 + 40 * 2 + 17] ^= 0x01;
  WriteBytes(scratch.File("table.sopedb"), flipped);
  EXPECT_NE(OpenError(scratch.File("table.sopedb")).find("header checksum"), std::string::npos);
}

TEST(Database, RefusesOtherVersionsAndNonDatabaseFiles) {
  testing::ScratchDir scratch;
  const std::string path = scratch.File("db.sopedb");
  WriteDatabase(path, MakeSyntheticData(5));
  std::string bytes = ReadBytes(path);
  const uint32_t version = 2;
  std::memcpy(&bytes[8], &version, 4);
  WriteBytes(scratch.File("v2.sopedb"), bytes);
  std::string error = OpenError(scratch.File("v2.sopedb"));
  EXPECT_NE(error.find("format version 2, this sope reads version 1"), std::string::npos) << error;

  WriteFileAtomic(scratch.File("cloud.ply"), "ply\nformat ascii 1.0\nelement vertex 0\nend_header\n");
  error = OpenError(scratch.File("cloud.ply"));
  EXPECT_NE(error.find("is not a sope database"), std::string::npos) << error;
  WriteFileAtomic(scratch.File("empty.sopedb"), "");
  error = OpenError(scratch.File("empty.sopedb"));
  EXPECT_NE(error.find("is not a sope database"), std::string::npos) << error;
  error = OpenError(scratch.File("missing.sopedb"));
  EXPECT_NE(error.find("cannot open database"), std::string::npos) << error;
  error = OpenError(scratch.path());
  EXPECT_NE(error.find("not a regular file"), std::string::npos) << error;
}

TEST(Database, WriteRefusesInconsistentData) {
  testing::ScratchDir scratch;
  DatabaseData data = MakeSyntheticData(6);
  data.view_clouds.pop_back();
  EXPECT_THROW_WITH_MESSAGE(WriteDatabase(scratch.File("bad.sopedb"), data), Error,
                            "20 view clouds for 21 views");
  data = MakeSyntheticData(6);
  data.views[3].model = 2;  // not within model 2's view range
  EXPECT_THROW_WITH_MESSAGE(WriteDatabase(scratch.File("bad.sopedb"), data), Error, "view 3",
                            "model 2");
  EXPECT_FALSE(std::ifstream(scratch.File("bad.sopedb")).good());
}

TEST(Database, OptionsPresetsAndJson) {
  const DatabaseOptions sope = DatabaseOptions::Preset("sope");
  sope.Check();
  const DatabaseOptions thesis = DatabaseOptions::Preset("thesis");
  thesis.Check();
  EXPECT_EQ(thesis.layout, ViewpointLayout::kThesis18);
  EXPECT_EQ(thesis.views_per_model, 18);
  EXPECT_EQ(thesis.hash.method, HashMethod::kMinimalLoss);
  EXPECT_THROW_WITH_MESSAGE(DatabaseOptions::Preset("fast"), Error, "'fast'");
  DatabaseOptions custom = sope;
  custom.hash.method = HashMethod::kSpectral;
  custom.hash.bits = 128;
  custom.render.distance = 0.5;
  custom.preprocess.voxel_leaf = 0.003;
  custom.features.kde_samples = 12;
  EXPECT_EQ(DatabaseOptionsToJson(DatabaseOptionsFromJson(DatabaseOptionsToJson(custom))),
            DatabaseOptionsToJson(custom));
  DatabaseOptions bad = sope;
  bad.views_per_model = 0;
  EXPECT_THROW_WITH_MESSAGE(bad.Check(), Error, "views per model", "got 0");
  bad = sope;
  bad.view_cloud_points = 4;
  EXPECT_THROW_WITH_MESSAGE(bad.Check(), Error, "view_cloud_points", "got 4");
}

// Issue 13: crafted databases whose checksums are right but whose contents are not opened
// and answered. These helpers re-checksum what they change, as a crafter would.
void Rechecksum(std::string* bytes, int section) {
  char* entry = &(*bytes)[64 + 40 * section];
  uint64_t offset, size;
  std::memcpy(&offset, entry + 16, 8);
  std::memcpy(&size, entry + 24, 8);
  const uint32_t crc = Crc32c(bytes->data() + offset, size);
  std::memcpy(entry + 32, &crc, 4);
  uint32_t header_bytes;
  std::memcpy(&header_bytes, bytes->data() + 12, 4);
  std::string head = bytes->substr(0, header_bytes);
  std::memset(&head[20], 0, 4);
  const uint32_t header_crc = Crc32c(head.data(), head.size());
  std::memcpy(&(*bytes)[20], &header_crc, 4);
}

// The metadata JSON edited by `edit`, written back in the same number of bytes (padded
// with spaces), re-checksummed.
std::string WithMetadata(const std::string& bytes,
                         const std::function<void(nlohmann::json*)>& edit) {
  std::string out = bytes;
  const uint64_t offset = SectionOffset(bytes, "metadata");
  uint64_t size;
  std::memcpy(&size, bytes.data() + 64 + 24, 8);
  nlohmann::json meta = nlohmann::json::parse(bytes.substr(offset, size));
  edit(&meta);
  std::string text = meta.dump();
  EXPECT_LE(text.size(), size);
  text.resize(size, ' ');
  out.replace(offset, size, text);
  Rechecksum(&out, 0);
  return out;
}

// Categories (DatabaseData::categories) survive the file; a file without the key (written
// before categories were recorded) has every class a category, as it was recognised; a
// category that is no class is refused.
TEST(Database, CategoriesRoundTripAndOlderFilesHaveEveryClassOne) {
  testing::ScratchDir scratch;
  DatabaseData data = MakeSyntheticData(2);
  ASSERT_EQ(data.classes.size(), 2u);
  data.categories = {data.classes[1]};
  const std::string path = scratch.File("db.sopedb");
  WriteDatabase(path, data);
  const std::unique_ptr<Database> db = Database::Open(path);
  EXPECT_FALSE(db->IsCategory(0));
  EXPECT_TRUE(db->IsCategory(1));
  EXPECT_FALSE(db->IsCategory(2));  // no such class
  EXPECT_FALSE(db->IsCategory(-1));

  const std::string bytes = ReadBytes(path);
  WriteBytes(scratch.File("older.sopedb"),
             WithMetadata(bytes, [](nlohmann::json* m) { m->erase("categories"); }));
  const std::unique_ptr<Database> older = Database::Open(scratch.File("older.sopedb"));
  EXPECT_TRUE(older->IsCategory(0));
  EXPECT_TRUE(older->IsCategory(1));

  WriteBytes(scratch.File("crafted.sopedb"), WithMetadata(bytes, [](nlohmann::json* m) {
               (*m)["categories"] = {"no such class"};
             }));
  const std::string error = OpenError(scratch.File("crafted.sopedb"));
  EXPECT_NE(error.find("corrupted"), std::string::npos) << error;
  EXPECT_NE(error.find("category no such class"), std::string::npos) << error;

  data.categories = {"no such class"};
  EXPECT_THROW_WITH_MESSAGE(WriteDatabase(scratch.File("bad.sopedb"), data), Error,
                            "category no such class");
}

TEST(Database, RefusesCraftedContentsWithValidChecksums) {
  testing::ScratchDir scratch;
  const std::string path = scratch.File("db.sopedb");
  WriteDatabase(path, MakeSyntheticData(8));
  const std::string bytes = ReadBytes(path);
  ASSERT_EQ(OpenError(path), "");
  // The crafter's own checksums are right: an unchanged rewrite opens.
  WriteBytes(scratch.File("same.sopedb"), WithMetadata(bytes, [](nlohmann::json*) {}));
  ASSERT_EQ(OpenError(scratch.File("same.sopedb")), "");

  struct Case {
    std::string name, needle;
    std::function<void(nlohmann::json*)> edit;
  };
  const std::vector<Case> cases = {
      {"zero scale", "invalid size (scale 0",
       [](nlohmann::json* m) { (*m)["models"][1]["scale"] = 0.0; }},
      {"negative scale", "invalid size (scale -2",
       [](nlohmann::json* m) { (*m)["models"][1]["scale"] = -2.0; }},
      {"zero diameter", "diameter 0",
       [](nlohmann::json* m) { (*m)["models"][0]["diameter"] = 0.0; }},
      {"overlapping first_view", "do not follow",
       [](nlohmann::json* m) { (*m)["models"][1]["first_view"] = 3; }},  // inside model 0's
      {"num_views 0", "do not follow",
       [](nlohmann::json* m) {
         (*m)["models"][1]["num_views"] = 0;
         (*m)["models"][2]["first_view"] = 7;
         (*m)["models"][2]["num_views"] = 14;
       }},
      {"unknown option key", "unknown option 'preprocess.turbo'",
       [](nlohmann::json* m) {
         (*m)["options"]["preprocess"]["turbo"] = true;
         for (auto& model : (*m)["models"]) model["source"] = "";
       }},
      {"zero distance scale", "distance scale 0",
       [](nlohmann::json* m) { (*m)["distance_scales"]["fine"] = 0.0; }},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    WriteBytes(scratch.File("crafted.sopedb"), WithMetadata(bytes, c.edit));
    const std::string error = OpenError(scratch.File("crafted.sopedb"));
    EXPECT_NE(error.find("corrupted"), std::string::npos) << error;
    EXPECT_NE(error.find(c.needle), std::string::npos) << error;
  }

  // NaN in a feature vector (coarse and fine) and a zero standardisation scale.
  for (const char* section : {"coarse", "fine", "standard"}) {
    SCOPED_TRACE(section);
    std::string crafted = bytes;
    const uint64_t offset = SectionOffset(bytes, section);
    // "standard" is coarse_mean then coarse_scale (12 values each): value 13 is a scale.
    const float bad = std::string(section) == "standard" ? 0.0f
                                                         : std::numeric_limits<float>::quiet_NaN();
    std::memcpy(&crafted[offset + (std::string(section) == "standard" ? 13 : 5) * 4], &bad, 4);
    const int index = std::string(section) == "coarse" ? 5 : std::string(section) == "fine" ? 6 : 3;
    Rechecksum(&crafted, index);
    WriteBytes(scratch.File("crafted.sopedb"), crafted);
    const std::string error = OpenError(scratch.File("crafted.sopedb"));
    EXPECT_NE(error.find("corrupted"), std::string::npos) << error;
    EXPECT_TRUE(error.find("NaN") != std::string::npos ||
                error.find("not positive") != std::string::npos)
        << error;
  }
}

// Issue 13: a FIFO named as the database blocked in open(2).
TEST(Database, RefusesAFifoWithoutBlocking) {
  testing::ScratchDir scratch;
  const std::string fifo = scratch.File("db.sopedb");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const std::string error = OpenError(fifo);
  EXPECT_NE(error.find("not a regular file"), std::string::npos) << error;
}

}  // namespace
}  // namespace sope
