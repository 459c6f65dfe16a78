#include "recogniser/tools/database_builder.h"

#include <filesystem>
#include <limits>

#include <gtest/gtest.h>

#include "core/camera_model.h"
#include "core/error.h"
#include "core/file_util.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"
#include "tests/test_support.h"

namespace sope {
namespace {

namespace fs = std::filesystem;

// A small, fast configuration: few views, coarse rendering.
DatabaseOptions SmallOptions(int views) {
  DatabaseOptions options;
  options.views_per_model = views;
  options.view_cloud_points = 128;
  return options;
}

TEST(ListModels, ClassDirectoriesAndFlatFiles) {
  testing::ScratchDir scratch;
  const std::string dir = scratch.File("models");
  const std::string box = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
  WriteFileAtomic(dir + "/mug/b.obj", box);
  WriteFileAtomic(dir + "/mug/a.PLY", box);  // extension case-insensitive
  WriteFileAtomic(dir + "/mug/notes.txt", "not a mesh");
  WriteFileAtomic(dir + "/mug/CATEGORY", "");  // kCategoryMarker: mug is a category
  WriteFileAtomic(dir + "/bowl/deep/c.obj", box);  // deeper levels are ignored
  WriteFileAtomic(dir + "/teapot.off", box);
  const std::vector<ModelSource> models = ListModels(dir);
  ASSERT_EQ(models.size(), 3u);
  EXPECT_EQ(models[0].class_name, "mug");
  EXPECT_EQ(models[0].name, "a");
  EXPECT_EQ(models[1].class_name, "mug");
  EXPECT_EQ(models[1].name, "b");
  EXPECT_TRUE(models[0].category && models[1].category);
  EXPECT_EQ(models[2].class_name, "teapot");  // a flat file is its own class
  EXPECT_EQ(models[2].name, "teapot");
  EXPECT_FALSE(models[2].category);
  EXPECT_EQ(fs::path(models[2].path).filename(), "teapot.off");

  fs::create_directories(scratch.File("empty"));
  EXPECT_THROW_WITH_MESSAGE(ListModels(scratch.File("empty")), Error, scratch.File("empty"),
                            "holds no mesh");
  EXPECT_THROW_WITH_MESSAGE(ListModels(scratch.File("missing")), Error, scratch.File("missing"),
                            "does not exist");
}

TEST(SizeNormalisation, ImplausibleSizesAreScaled) {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {3, 0, 0}, {0, 4, 0}};  // diagonal 5 "metres"
  mesh.faces = {{0, 1, 2}};
  const SizeNormalisationOptions options;
  EXPECT_DOUBLE_EQ(SizeNormalisationScale(mesh, options), 0.25 / 5.0);
  mesh.Transform(0.06, Eigen::Vector3d::Zero());  // 0.3 m: plausible
  EXPECT_DOUBLE_EQ(SizeNormalisationScale(mesh, options), 1.0);
}

// A mesh unit given (build-db --units) replaces the guess, plausible diagonal or not: a
// BOP model in millimetres keeps its real size, where the guess makes every such model
// 0.25 m across.
TEST(SizeNormalisation, AGivenMeshUnitReplacesTheGuess) {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {90, 0, 0}, {0, 120, 0}};  // diagonal 150 mm
  mesh.faces = {{0, 1, 2}};
  SizeNormalisationOptions options;
  EXPECT_DOUBLE_EQ(SizeNormalisationScale(mesh, options), 0.25 / 150.0);
  options.mesh_unit = 0.001;
  EXPECT_DOUBLE_EQ(SizeNormalisationScale(mesh, options), 0.001);
  mesh.Transform(0.001, Eigen::Vector3d::Zero());  // 0.15 "units": plausible as metres
  options.mesh_unit = 0.01;                          // but given in centimetres
  EXPECT_DOUBLE_EQ(SizeNormalisationScale(mesh, options), 0.01);
  options.mesh_unit = -0.001;
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "mesh_unit");
  options.mesh_unit = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW_WITH_MESSAGE(options.Check(), Error, "mesh_unit");
}

TEST(FarthestPointSample, SpreadsAndEveryPrefixSpreads) {
  std::vector<Eigen::Vector3f> points;
  for (int x = 0; x < 20; ++x) {
    for (int y = 0; y < 20; ++y) points.emplace_back(0.01f * x, 0.01f * y, 0.0f);
  }
  const std::vector<int> sample = internal::FarthestPointSample(points, 16);
  ASSERT_EQ(sample.size(), 16u);
  // The 4 first samples include the corners' neighbourhood: the spread of the first
  // points covers the square.
  float min_pair = 1.0f;
  for (size_t i = 0; i < sample.size(); ++i) {
    for (size_t j = i + 1; j < sample.size(); ++j) {
      min_pair = std::min(min_pair, (points[sample[i]] - points[sample[j]]).norm());
    }
  }
  EXPECT_GT(min_pair, 0.04f);  // 16 points on a 0.19 m square: spacing ≈ 0.05 m
  EXPECT_EQ(internal::FarthestPointSample(points, 1000).size(), points.size());
  EXPECT_NEAR(internal::MedianNearestNeighbourDistance(points), 0.01f, 1e-6f);
}

class BuildDatabaseTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir();
    WriteProceduralModels(scratch_->File("models"), 1, 7);
    // Two classes only (keeps the test fast), plus an unreadable mesh.
    for (const auto& entry : fs::directory_iterator(scratch_->File("models"))) {
      const std::string name = entry.path().filename().string();
      if (name != "mug" && name != "box") fs::remove_all(entry.path());
    }
    WriteFileAtomic(scratch_->File("models/broken.obj"), "v 0 0 0\nf 1 2 3\n");
  }
  static void TearDownTestSuite() { delete scratch_; }
  static testing::ScratchDir* scratch_;
};
testing::ScratchDir* BuildDatabaseTest::scratch_ = nullptr;

TEST_F(BuildDatabaseTest, SkipsBadMeshesAndStoresConsistentViews) {
  BuildSummary summary;
  int last_done = -1, calls = 0;
  const DatabaseData data = BuildDatabase(
      scratch_->File("models"), SmallOptions(12),
      [&](int done, int total) {
        EXPECT_GE(done, last_done);
        EXPECT_EQ(total, 36);
        last_done = done;
        ++calls;
      },
      &summary, 2);
  EXPECT_EQ(last_done, 36);
  EXPECT_GT(calls, 1);
  ASSERT_EQ(summary.skipped.size(), 1u);
  EXPECT_NE(summary.skipped[0].find("broken.obj"), std::string::npos);
  ASSERT_EQ(data.models.size(), 2u);
  EXPECT_EQ(data.classes, (std::vector<std::string>{"box", "mug"}));
  // WriteProceduralModels marks its classes as categories.
  EXPECT_EQ(data.categories, (std::vector<std::string>{"box", "mug"}));
  EXPECT_EQ(data.views.size(), 24u);
  EXPECT_EQ(summary.views, 24);
  data.Check();

  // Each stored view cloud lies on the surface its camera saw: moved into that camera, its
  // points are within a voxel of the rendered depth cloud, and its normals face it.
  DepthRenderer renderer(MakePinhole(data.options.render.width, data.options.render.height,
                                     data.options.render.horizontal_fov));
  for (size_t m = 0; m < data.models.size(); ++m) {
    const ModelRecord& model = data.models[m];
    TriangleMesh mesh = ReadMesh(model.source_path);
    EXPECT_EQ(model.scale, 1.0);  // procedural objects are in metres
    renderer.SetMesh(mesh);
    for (int v = model.first_view; v < model.first_view + model.num_views; v += 3) {
      const ViewRecord& view = data.views[v];
      EXPECT_NEAR((view.cam_from_model * model.center - Eigen::Vector3d(0, 0, view.distance)).norm(),
                  0.0, 1e-9);
      const PointCloud rendered = renderer.Render(view.cam_from_model);
      const PointCloud& cloud = data.view_clouds[v];
      ASSERT_GT(cloud.size(), 50u);
      int near = 0, facing = 0;
      for (size_t i = 0; i < cloud.size(); ++i) {
        const Eigen::Vector3f p = (view.cam_from_model * cloud.points[i].cast<double>()).cast<float>();
        const Eigen::Vector3f n = (view.cam_from_model.rotation * cloud.normals[i].cast<double>()).cast<float>();
        float best = 1e9f;
        for (const Eigen::Vector3f& r : rendered.points) best = std::min(best, (r - p).squaredNorm());
        near += std::sqrt(best) < data.options.preprocess.voxel_leaf;
        facing += n.dot(-p.normalized()) > 0.0f;
      }
      EXPECT_GE(near, static_cast<int>(0.98 * cloud.size())) << model.name << " view " << v;
      EXPECT_GE(facing, static_cast<int>(0.95 * cloud.size())) << model.name << " view " << v;
      // The centroid is that of the pre-processed view: inside the model's bounding sphere.
      EXPECT_LT((view.centroid_in_model.cast<double>() - model.center).norm(), model.bounding_radius);
      EXPECT_GT(view.radius, 0.0f);
      EXPECT_GT(view.cloud_spacing, 0.0f);
    }
  }
  // Codes are the hasher's codes of the stored vectors.
  for (size_t v = 0; v < data.views.size(); v += 5) {
    const Eigen::VectorXf input = HashInputVector(data.coarse.row(v).transpose(),
                                                  data.fine.row(v).transpose(), data.fine_mean,
                                                  data.fine_hash_scale);
    const BinaryCodes code = data.hasher.Encode(input.transpose());
    EXPECT_EQ(HammingDistance(code.code(0), data.codes.code(v), code.words_per_code), 0);
  }
}

TEST_F(BuildDatabaseTest, ResultDoesNotDependOnTheThreadCount) {
  const std::vector<ModelSource> models = ListModels(scratch_->File("models"));
  const DatabaseData one = BuildDatabase(models, SmallOptions(6), {}, nullptr, 1);
  const DatabaseData three = BuildDatabase(models, SmallOptions(6), {}, nullptr, 3);
  EXPECT_EQ(one.coarse, three.coarse);
  EXPECT_EQ(one.fine, three.fine);
  EXPECT_EQ(one.codes.words, three.codes.words);
  ASSERT_EQ(one.view_clouds.size(), three.view_clouds.size());
  for (size_t v = 0; v < one.view_clouds.size(); ++v) {
    EXPECT_EQ(one.view_clouds[v].points, three.view_clouds[v].points);
  }
}

TEST_F(BuildDatabaseTest, NoReadableMeshIsAnError) {
  testing::ScratchDir scratch;
  WriteFileAtomic(scratch.File("bad/a.obj"), "garbage\n");
  WriteFileAtomic(scratch.File("bad/b.stl"), "solid x\nendsolid x\n");
  try {
    BuildDatabase(scratch.File("bad"), SmallOptions(4));
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no database view could be built"), std::string::npos)
        << e.what();
  }
  DatabaseOptions invalid = SmallOptions(4);
  invalid.views_per_model = 0;
  EXPECT_THROW_WITH_MESSAGE(BuildDatabase(scratch_->File("models"), invalid), Error,
                            "views per model", "got 0");
}

TEST(ResolveDatabaseOptions, ChoicesOnTopOfAPreset) {
  DatabasePresetChoices choices;
  DatabaseOptions options = ResolveDatabaseOptions(choices);  // the sope preset as is
  EXPECT_EQ(options.views_per_model, DatabaseOptions::Preset("sope").views_per_model);
  EXPECT_EQ(options.layout, DatabaseOptions::Preset("sope").layout);
  // The thesis preset: its 18 views on the thesis rings; other view counts are Fibonacci.
  choices.preset = "thesis";
  options = ResolveDatabaseOptions(choices);
  EXPECT_EQ(options.layout, ViewpointLayout::kThesis18);
  EXPECT_EQ(options.views_per_model, 18);
  choices.views = 18;
  EXPECT_EQ(ResolveDatabaseOptions(choices).layout, ViewpointLayout::kThesis18);
  choices.views = 40;
  options = ResolveDatabaseOptions(choices);
  EXPECT_EQ(options.layout, ViewpointLayout::kFibonacci);
  EXPECT_EQ(options.views_per_model, 40);
  // The thesis layout chosen under the sope preset gets 18 views; with 20 it is refused.
  choices = DatabasePresetChoices();
  choices.layout = ViewpointLayout::kThesis18;
  EXPECT_EQ(ResolveDatabaseOptions(choices).views_per_model, 18);
  choices.views = 20;
  try {
    ResolveDatabaseOptions(choices);
    ADD_FAILURE() << "thesis layout with 20 views accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("18"), std::string::npos) << e.what();
  }
  // Codes.
  choices = DatabasePresetChoices();
  choices.hash = HashMethod::kLsh;
  choices.bits = 128;
  options = ResolveDatabaseOptions(choices);
  EXPECT_EQ(options.hash.method, HashMethod::kLsh);
  EXPECT_EQ(options.hash.bits, 128);
  choices.preset = "fast";
  EXPECT_THROW(ResolveDatabaseOptions(choices), Error);
  choices = DatabasePresetChoices();
  choices.views = 0;
  EXPECT_THROW(ResolveDatabaseOptions(choices), Error);
}

}  // namespace
}  // namespace sope
