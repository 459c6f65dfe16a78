// `sope build-db` and `sope recognise` as a user runs them: a database from a models
// directory (an unreadable mesh in it is reported and skipped), a rendered query recognised
// (human-readable and JSON), and on bad input exactly one error line and a non-zero exit.
#include <sys/wait.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/camera_model.h"
#include "core/file_util.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "recogniser/database.h"
#include "recogniser/viewpoints.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"
#include "tests/test_support.h"

namespace sope {
namespace {
namespace fs = std::filesystem;

using SopeRun = testing::CommandRun;
using testing::Quote;

SopeRun Sope(const std::string& arguments, const testing::ScratchDir& scratch) {
  return testing::RunCommand(SOPE_BINARY, arguments, scratch);
}

using testing::ExpectOneLineError;

std::string ReadBytes(const std::string& path) { return ReadFileToString(path, "file"); }
void WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

class RecogniseCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir();
    const std::string models = scratch_->File("models");
    WriteMesh(models + "/mug/mug_a.obj", MakeObject(ObjectClass::kMug, 1));
    WriteMesh(models + "/bottle/bottle_a.obj", MakeObject(ObjectClass::kBottle, 1));
    WriteFileAtomic(models + "/broken.obj", "v 0 0 0\nthis is not an OBJ line\n");
    build_ = new SopeRun(Sope("build-db --models " + models + " --out " +
                                  scratch_->File("db.sopedb") + " --views 40",
                              *scratch_));
    // A query: the mug 0.55 m away from an off-grid viewpoint, rolled.
    const TriangleMesh mug = MakeObject(ObjectClass::kMug, 1);
    Eigen::Vector3f lo, hi;
    mug.Bounds(&lo, &hi);
    DepthRenderer renderer(MakePinhole(640, 480, 1.0));
    renderer.SetMesh(mug);
    const Rigid3d look =
        CameraPoseForViewpoint(Viewpoint{1.1, 0.7}, 0.55, (0.5 * (lo + hi)).cast<double>());
    const Rigid3d cam_from_model(
        Eigen::AngleAxisd(0.6, Eigen::Vector3d::UnitZ()).toRotationMatrix() * look.rotation,
        Eigen::AngleAxisd(0.6, Eigen::Vector3d::UnitZ()).toRotationMatrix() * look.translation);
    PointCloud query = renderer.Render(cam_from_model);
    query.normals.clear();
    WritePointCloud(scratch_->File("query.ply"), query);
    WritePointCloud(scratch_->File("query.pcd"), query);
  }
  static void TearDownTestSuite() {
    delete build_;
    delete scratch_;
  }
  const std::string& db() const {
    static const std::string path = scratch_->File("db.sopedb");
    return path;
  }

  static testing::ScratchDir* scratch_;
  static SopeRun* build_;
  testing::ScratchDir local_;
};
testing::ScratchDir* RecogniseCli::scratch_ = nullptr;
SopeRun* RecogniseCli::build_ = nullptr;

TEST_F(RecogniseCli, BuildDbSkipsAndReportsTheUnreadableMesh) {
  ASSERT_EQ(build_->exit_code, 0) << build_->err;
  EXPECT_TRUE(fs::exists(db()));
  EXPECT_NE(build_->err.find("broken.obj"), std::string::npos) << build_->err;
  EXPECT_NE(build_->err.find("2 models, 80 views"), std::string::npos) << build_->err;
  EXPECT_EQ(build_->out, "");
  const SopeRun help = Sope("--help", local_);
  EXPECT_NE(help.out.find("build-db"), std::string::npos);
  EXPECT_NE(help.out.find("recognise"), std::string::npos);
  EXPECT_EQ(Sope("build-db --help", local_).exit_code, 0);
  EXPECT_EQ(Sope("recognise --help", local_).exit_code, 0);
}

TEST_F(RecogniseCli, RecognisesTheQueryInTextAndJson) {
  ASSERT_EQ(build_->exit_code, 0) << build_->err;
  SopeRun run = Sope("recognise --db " + db() + " --cloud " + scratch_->File("query.ply"), local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_EQ(run.out.rfind("1. mug", 0), 0u) << run.out;
  EXPECT_NE(run.out.find("ICP-refined"), std::string::npos) << run.out;

  run = Sope("recognise --json --top 2 --db " + db() + " --cloud " + scratch_->File("query.pcd"),
             local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_EQ(std::count(run.out.begin(), run.out.end(), '\n'), 1) << run.out;
  const nlohmann::json j = nlohmann::json::parse(run.out);
  EXPECT_EQ(j.at("class"), "mug");
  EXPECT_EQ(j.at("model"), "mug_a");
  EXPECT_TRUE(j.at("refined").get<bool>());
  EXPECT_GT(j.at("score").get<double>(), 0.8);
  EXPECT_EQ(j.at("pose").at("rotation").size(), 3u);
  EXPECT_EQ(j.at("candidates").size(), 2u);
  EXPECT_TRUE(j.at("timing_ms").contains("total"));
}

// A cloud in millimetres (other tools' clouds often are): without --cloud-units one error
// line that says so; with --cloud-units mm the answer of the cloud in metres.
TEST_F(RecogniseCli, CloudsInMillimetresNeedTheirUnit) {
  ASSERT_EQ(build_->exit_code, 0) << build_->err;
  PointCloud millimetres = ReadPointCloud(scratch_->File("query.ply"));
  for (Eigen::Vector3f& p : millimetres.points) p *= 1000.0f;
  WritePointCloud(local_.File("query_mm.ply"), millimetres);
  const std::string base = "recognise --json --db " + db() + " --cloud ";
  ExpectOneLineError(Sope(base + local_.File("query_mm.ply"), local_), "recognise",
                     "give --cloud-units mm");
  const SopeRun metres = Sope(base + scratch_->File("query.ply"), local_);
  const SopeRun given = Sope(base + local_.File("query_mm.ply") + " --cloud-units mm", local_);
  ASSERT_EQ(metres.exit_code, 0) << metres.err;
  ASSERT_EQ(given.exit_code, 0) << given.err;
  const nlohmann::json a = nlohmann::json::parse(metres.out);
  const nlohmann::json b = nlohmann::json::parse(given.out);
  EXPECT_EQ(b.at("model"), "mug_a");
  EXPECT_EQ(b.at("model"), a.at("model"));
  for (int k = 0; k < 3; ++k) {
    // The same query within the float rounding of ×1000 then ×0.001 (and the ICP's answer
    // to it): well under a millimetre.
    EXPECT_NEAR(b.at("pose").at("translation").at(k).get<double>(),
                a.at("pose").at("translation").at(k).get<double>(), 2e-4);
  }
  // A table scene in millimetres is a result (nothing on a table), with the hint beside it.
  const SopeRun table = Sope(base + local_.File("query_mm.ply") + " --table", local_);
  ASSERT_EQ(table.exit_code, 0) << table.err;
  EXPECT_EQ(nlohmann::json::parse(table.out).at("objects").size(), 0u);
  EXPECT_NE(table.err.find("give --cloud-units mm"), std::string::npos) << table.err;
  ExpectOneLineError(Sope(base + local_.File("query_mm.ply") + " --cloud-units yards", local_),
                     "recognise", "--cloud-units 'yards'");
}

TEST_F(RecogniseCli, BadCloudsGiveOneErrorLine) {
  ASSERT_EQ(build_->exit_code, 0) << build_->err;
  const std::string base = "recognise --db " + db() + " --cloud ";
  ExpectOneLineError(Sope(base + local_.File("missing.ply"), local_), "recognise", "missing.ply");

  WritePointCloud(local_.File("empty.ply"), PointCloud());
  ExpectOneLineError(Sope(base + local_.File("empty.ply"), local_), "recognise", "empty");

  PointCloud nans;
  nans.points.assign(2000, Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  WritePointCloud(local_.File("nan.ply"), nans);
  ExpectOneLineError(Sope(base + local_.File("nan.ply"), local_), "recognise", "finite");

  PointCloud tiny;
  for (int i = 0; i < 12; ++i) tiny.points.emplace_back(0.002f * i, 0.0f, 0.6f);
  WritePointCloud(local_.File("tiny.ply"), tiny);
  ExpectOneLineError(Sope(base + local_.File("tiny.ply"), local_), "recognise", "points");

  WriteFileAtomic(local_.File("garbage.ply"), "ply\nformat ascii 1.0\nelement vertex 3\n");
  ExpectOneLineError(Sope(base + local_.File("garbage.ply"), local_), "recognise", "garbage.ply");
}

// Issue 13: clouds of no known object — uniform noise, a line of points — get "no known
// object" (text) and "class": null with the best guess only among the candidates (JSON).
TEST_F(RecogniseCli, NoiseIsNoKnownObject) {
  ASSERT_EQ(build_->exit_code, 0) << build_->err;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> unit(-0.5f, 0.5f);
  PointCloud noise, line;
  for (int i = 0; i < 5000; ++i) noise.points.emplace_back(unit(rng), unit(rng), 1.0f + unit(rng));
  for (int i = 0; i < 2000; ++i) line.points.emplace_back(-0.2f + 2e-4f * i, 0.0f, 0.6f);
  WritePointCloud(local_.File("noise.ply"), noise);
  WritePointCloud(local_.File("line.ply"), line);
  for (const char* name : {"noise.ply", "line.ply"}) {
    const std::string base = "recognise --db " + db() + " --cloud " + local_.File(name);
    SopeRun run = Sope(base, local_);
    ASSERT_EQ(run.exit_code, 0) << name << ": " << run.err;
    EXPECT_EQ(run.out.rfind("no known object", 0), 0u) << name << ": " << run.out;
    run = Sope(base + " --json", local_);
    ASSERT_EQ(run.exit_code, 0) << name << ": " << run.err;
    const nlohmann::json j = nlohmann::json::parse(run.out);
    EXPECT_TRUE(j.at("class").is_null()) << name << ": " << run.out;
    EXPECT_FALSE(j.at("recognised").get<bool>());
    EXPECT_FALSE(j.at("candidates").empty());
    // --min-score 0 restores the old answer (the best guess at the top level).
    run = Sope(base + " --json --min-score 0", local_);
    ASSERT_EQ(run.exit_code, 0) << run.err;
    EXPECT_TRUE(nlohmann::json::parse(run.out).at("class").is_string()) << run.out;
  }
}

TEST_F(RecogniseCli, BadDatabasesGiveOneErrorLine) {
  ASSERT_EQ(build_->exit_code, 0) << build_->err;
  const std::string cloud = " --cloud " + scratch_->File("query.ply");
  const std::string bytes = ReadBytes(db());

  ExpectOneLineError(Sope("recognise --db " + local_.File("none.sopedb") + cloud, local_),
                     "recognise", "cannot open database");

  WriteBytes(local_.File("truncated.sopedb"), bytes.substr(0, bytes.size() * 2 / 3));
  ExpectOneLineError(Sope("recognise --db " + local_.File("truncated.sopedb") + cloud, local_),
                     "recognise", "truncated");

  std::string flipped = bytes;
  flipped[flipped.size() - 5000] ^= 0x04;  // inside the last (clouds) section
  WriteBytes(local_.File("flipped.sopedb"), flipped);
  ExpectOneLineError(Sope("recognise --db " + local_.File("flipped.sopedb") + cloud, local_),
                     "recognise", "corrupted");

  std::string version = bytes;
  const uint32_t future = 99;
  std::memcpy(&version[8], &future, sizeof(future));
  WriteBytes(local_.File("v99.sopedb"), version);
  ExpectOneLineError(Sope("recognise --db " + local_.File("v99.sopedb") + cloud, local_),
                     "recognise", "version 99");

  ExpectOneLineError(Sope("recognise --db " + scratch_->File("query.ply") + cloud, local_),
                     "recognise", "not a sope database");
}

TEST_F(RecogniseCli, BadBuildInputsGiveOneErrorLine) {
  fs::create_directories(local_.File("nothing"));
  ExpectOneLineError(Sope("build-db --models " + local_.File("nothing") + " --out " +
                              local_.File("x.sopedb"),
                          local_),
                     "build-db", "holds no mesh");
  ExpectOneLineError(Sope("build-db --models " + local_.File("absent") + " --out " +
                              local_.File("x.sopedb"),
                          local_),
                     "build-db", "does not exist");
  const std::string models = " --models " + scratch_->File("models") + " --out " +
                             local_.File("x.sopedb");
  ExpectOneLineError(Sope("build-db --views 0" + models, local_), "build-db", "--views");
  ExpectOneLineError(Sope("build-db --hash md5" + models, local_), "build-db", "md5");
  ExpectOneLineError(Sope("build-db --preset fast" + models, local_), "build-db", "fast");
  ExpectOneLineError(Sope("build-db --layout thesis --views 20" + models, local_), "build-db",
                     "18");
  // Only unreadable meshes: each is reported (a warning line), then one error line.
  WriteFileAtomic(local_.File("bad/a.obj"), "not a mesh\n");
  WriteFileAtomic(local_.File("bad/b/c.off"), "OFF\n3 1 0\n0 0 0\n");
  const SopeRun run = Sope("build-db --models " + local_.File("bad") + " --out " +
                               local_.File("x.sopedb"),
                           local_);
  EXPECT_NE(run.exit_code, 0);
  std::istringstream lines(run.err);
  std::string line;
  int errors = 0, warnings = 0;
  while (std::getline(lines, line)) {
    errors += line.rfind("sope build-db: error: ", 0) == 0;
    warnings += line.find("skipping model") != std::string::npos;
  }
  EXPECT_EQ(errors, 1) << run.err;
  EXPECT_EQ(warnings, 2) << run.err;
  EXPECT_NE(run.err.find("no database view could be built"), std::string::npos) << run.err;
  EXPECT_FALSE(fs::exists(local_.File("x.sopedb")));
}

// Issue 13: an empty PCD, "hello world" or only "VERSION 0.7" crashed pcl::PCDReader.
TEST_F(RecogniseCli, MalformedPcdHeadersGiveOneErrorLine) {
  ASSERT_EQ(build_->exit_code, 0) << build_->err;
  const std::string base = "recognise --db " + db() + " --cloud ";
  for (const std::string& text : {std::string(""), std::string("hello world"),
                                  std::string("VERSION 0.7\n")}) {
    SCOPED_TRACE(text);
    WriteFileAtomic(local_.File("bad.pcd"), text);
    const SopeRun run = Sope(base + local_.File("bad.pcd"), local_);
    EXPECT_NE(run.exit_code, -1) << "killed by a signal";
    ExpectOneLineError(run, "recognise", "bad.pcd");
  }
  // The good PCD still recognises.
  EXPECT_EQ(Sope(base + scratch_->File("query.pcd"), local_).exit_code, 0);
}

// Issue 13: a mesh claiming more elements than its file holds failed the whole build with
// std::bad_alloc; now it is reported and skipped like any unreadable mesh.
TEST_F(RecogniseCli, BuildDbSkipsMeshesWithImpossibleCounts) {
  const std::string models = local_.File("models");
  WriteMesh(models + "/mug/mug_a.obj", MakeObject(ObjectClass::kMug, 1));
  WriteFileAtomic(models + "/bowl/huge.ply",
                  "ply\nformat ascii 1.0\nelement vertex 9223372036854775807\n"
                  "property float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n");
  WriteFileAtomic(models + "/bowl/huge.off", "OFF\n1000000000000 1 0\n0 0 0\n");
  const SopeRun run = Sope("build-db --views 12 --models " + models + " --out " +
                               local_.File("x.sopedb"),
                           local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.err.find("skipping model " + models + "/bowl/huge.ply"), std::string::npos)
      << run.err;
  EXPECT_NE(run.err.find("skipping model " + models + "/bowl/huge.off"), std::string::npos)
      << run.err;
  EXPECT_EQ(run.err.find("internal error"), std::string::npos) << run.err;
  EXPECT_EQ(Database::Open(local_.File("x.sopedb"))->models().size(), 1u);
}

// build-db --units: a mesh in millimetres keeps its real size (the database records the
// unit and scales every model by it), where the size rule guesses 0.25 m across.
TEST_F(RecogniseCli, BuildDbTakesTheMeshesUnit) {
  const std::string models = local_.File("mm_models");
  TriangleMesh mug = MakeObject(ObjectClass::kMug, 1);
  const double diagonal_m = mug.BoundingDiagonal();
  mug.Transform(1000.0, Eigen::Vector3d::Zero());
  WriteMesh(models + "/mug/mug_a.obj", mug);
  for (const std::string units : {"", " --units mm", " --units 0.001"}) {
    SCOPED_TRACE(units);
    const SopeRun run = Sope("build-db --views 12 --models " + models + " --out " +
                                 local_.File("mm.sopedb") + units,
                             local_);
    ASSERT_EQ(run.exit_code, 0) << run.err;
    const std::unique_ptr<Database> db = Database::Open(local_.File("mm.sopedb"));
    ASSERT_EQ(db->models().size(), 1u);
    const double scale = db->models()[0].scale;
    if (units.empty()) {
      // The guess: 0.25 m across (within the OBJ's float vertices).
      EXPECT_NEAR(scale * 1000.0 * diagonal_m, 0.25, 1e-6);
      EXPECT_EQ(db->options().size.mesh_unit, 0.0);
    } else {
      EXPECT_EQ(scale, 0.001);
      EXPECT_EQ(db->options().size.mesh_unit, 0.001);
    }
  }
}

// build-db --categories: by default a class folder holding a CATEGORY file is a category
// (alike objects: unseen instances recognised as the class) and any other is not; all and
// none override the files; the log names them; an unknown value is one error line.
TEST_F(RecogniseCli, BuildDbRecordsWhichClassesAreCategories) {
  const std::string models = local_.File("category_models");
  WriteMesh(models + "/mug/mug_a.obj", MakeObject(ObjectClass::kMug, 1));
  WriteMesh(models + "/mug/mug_b.obj", MakeObject(ObjectClass::kMug, 2));
  WriteFileAtomic(models + "/mug/" + kCategoryMarker, "");
  WriteMesh(models + "/dataset/bottle.obj", MakeObject(ObjectClass::kBottle, 1));
  WriteMesh(models + "/dataset/bowl.obj", MakeObject(ObjectClass::kBowl, 1));
  for (const std::string choice : {"", "auto", "all", "none"}) {
    SCOPED_TRACE(choice);
    const SopeRun run = Sope("build-db --views 6 --models " + models + " --out " +
                                 local_.File("categories.sopedb") +
                                 (choice.empty() ? "" : " --categories " + choice),
                             local_);
    ASSERT_EQ(run.exit_code, 0) << run.err;
    const std::unique_ptr<Database> db = Database::Open(local_.File("categories.sopedb"));
    ASSERT_EQ(db->classes(), (std::vector<std::string>{"dataset", "mug"}));
    const bool all = choice == "all", none = choice == "none";
    EXPECT_EQ(db->IsCategory(0), all);
    EXPECT_EQ(db->IsCategory(1), !none);
    EXPECT_EQ(run.err.find("mug (2, category)") != std::string::npos, !none) << run.err;
    // A folder of several models that is not a category is named as a set of instances.
    const std::string sets =
        none ? "dataset, mug: sets of instances" : "dataset: sets of instances";
    EXPECT_EQ(run.err.find(sets) != std::string::npos, !all) << run.err;
  }
  ExpectOneLineError(Sope("build-db --categories some --models " + models + " --out " +
                              local_.File("categories.sopedb"),
                          local_),
                     "build-db", "--categories");
}

}  // namespace
}  // namespace sope
