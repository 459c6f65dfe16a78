// The evaluation protocol on a small database of procedural objects: the instance protocol
// (queries of the database's models) and the class protocol (held-out instances), the
// scores checked against the ground truth they are computed from, and the report files.
#include "recogniser/tools/evaluation.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "core/error.h"
#include "recogniser/tools/database_builder.h"
#include "simulator/procedural_objects.h"
#include "tests/test_support.h"

namespace sope {
namespace {

class EvaluationTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir();
    // Four classes, two instances each for the database (seeds 100, 101) and one held-out
    // instance each (seed 500).
    for (const char* dir : {"train", "held_out"}) {
      const std::string models = scratch_->File(dir);
      WriteProceduralModels(models, std::string(dir) == "train" ? 2 : 1,
                            std::string(dir) == "train" ? 100 : 500);
      for (const char* unused : {"can", "glass", "plate", "vase", "wine_glass", "saucepan"}) {
        std::filesystem::remove_all(models + "/" + unused);
      }
    }
    DatabaseOptions options;
    options.views_per_model = 80;
    WriteDatabase(scratch_->File("test.sopedb"),
                  BuildDatabase(scratch_->File("train"), options));
    db_ = Database::Open(scratch_->File("test.sopedb")).release();
  }
  static void TearDownTestSuite() {
    delete db_;
    delete scratch_;
  }
  static testing::ScratchDir* scratch_;
  static Database* db_;
};
testing::ScratchDir* EvaluationTest::scratch_ = nullptr;
Database* EvaluationTest::db_ = nullptr;

TEST_F(EvaluationTest, InstanceProtocolScoresAgainstTheTruth) {
  const std::vector<EvalModel> models = InstanceModels(*db_);
  ASSERT_EQ(static_cast<int>(models.size()), db_->num_models());
  EvalOptions options;
  options.queries_per_model = 3;
  options.query.max_occlusion = 0.15;
  const EvalReport report = Evaluate(*db_, models, options);
  ASSERT_EQ(report.queries(), 3 * db_->num_models());
  std::printf("%s\n", report.BriefReport().c_str());
  for (const QueryOutcome& o : report.outcomes) {
    ASSERT_TRUE(o.error.empty()) << o.error;
    EXPECT_EQ(o.model_top1, o.predicted_model == o.truth_model);
    EXPECT_EQ(o.class_top1, o.predicted_class == o.truth_class);
    EXPECT_TRUE(!o.model_top1 || o.class_top1);
    EXPECT_TRUE(!o.model_top1 || o.model_topk);
    // Pose errors exist exactly for correctly recognised queries, and agree with each other.
    EXPECT_EQ(std::isfinite(o.rotation_error_deg), o.model_top1);
    EXPECT_EQ(std::isfinite(o.adds_over_diameter), o.model_top1);
    EXPECT_EQ(std::isfinite(o.mssd_over_diameter), o.model_top1);
    EXPECT_EQ(std::isfinite(o.mspd_px), o.model_top1);
    if (o.model_top1) {
      // MSSD minimises over the symmetries, the identity among them: at most the largest
      // displacement of a surface sample between the two poses (no symmetry), which the
      // test computes from the poses alone.
      const EvalModel& truth = models[o.query_model];
      double largest = 0.0;
      for (const Eigen::Vector3f& x : truth.truth.samples) {
        largest = std::max(largest, (o.estimated_cam_from_model * x.cast<double>() -
                                     o.truth_cam_from_model * x.cast<double>())
                                        .norm());
      }
      EXPECT_GE(o.mssd_over_diameter, 0.0);
      EXPECT_LE(o.mssd_over_diameter, largest / truth.truth.diameter + 1e-9);
      EXPECT_GE(o.mspd_px, 0.0);
      EXPECT_EQ(o.adds_ok, o.adds_over_diameter < options.adds_fraction);
      EXPECT_GE(o.rotation_error_deg, 0.0);
      // The viewing direction turns with the rotation; the centre error (~0.3 mm at
      // 0.6 m, ~0.03°) adds a little.
      EXPECT_LE(o.viewpoint_error_deg, o.rotation_error_deg + 0.5);
    }
    EXPECT_GE(o.flagged_fraction, 0.0);
    EXPECT_LE(o.flagged_fraction, 1.0);
  }
  // 8 models x 80 views, occlusion ≤ 15%: measured 22/24 correct (the two others in the
  // top 4), median rotation error ~0.3°.
  EXPECT_GE(report.ModelTop1(), 0.85);
  EXPECT_GE(report.AddsSuccess(), 0.8);
  EXPECT_LT(report.MedianRotationErrorDeg(), 3.0);
  EXPECT_LT(report.MedianTranslationErrorMm(), 3.0);
  EXPECT_LE(report.ModelTop1(), report.ModelTopK());
  EXPECT_LE(report.ClassTop1(), report.ClassTopK());
  // BOP average recalls: a wrong model misses at every threshold.
  EXPECT_EQ(report.query_image_width, options.camera_width);
  EXPECT_GT(report.MssdAverageRecall(), 0.0);
  EXPECT_LE(report.MssdAverageRecall(), report.ModelTop1());
  EXPECT_GT(report.MspdAverageRecall(), 0.0);
  EXPECT_LE(report.MspdAverageRecall(), report.ModelTop1());

  std::vector<std::string> labels;
  const auto counts = report.Confusion(&labels);
  int diagonal = 0, total = 0;
  for (size_t r = 0; r < counts.size(); ++r) {
    for (size_t c = 0; c < counts.size(); ++c) total += counts[r][c];
    diagonal += counts[r][r];
  }
  EXPECT_EQ(total, report.queries());
  EXPECT_EQ(diagonal, static_cast<int>(std::lround(report.ModelTop1() * report.queries())));

  const std::string out = scratch_->File("instance_report");
  WriteEvalReport(report, out);
  const nlohmann::json j = nlohmann::json::parse(std::ifstream(out + "/report.json"));
  EXPECT_EQ(j.at("queries").get<int>(), report.queries());
  EXPECT_DOUBLE_EQ(j.at("model_top1").get<double>(), report.ModelTop1());
  EXPECT_DOUBLE_EQ(j.at("bop_mssd_average_recall").get<double>(), report.MssdAverageRecall());
  EXPECT_DOUBLE_EQ(j.at("bop_mspd_average_recall").get<double>(), report.MspdAverageRecall());
  EXPECT_EQ(j.at("outcomes").size(), report.outcomes.size());
  for (const char* png : {"/confusion.png", "/pose_errors.png"}) {
    const cv::Mat image = cv::imread(out + png);
    EXPECT_FALSE(image.empty()) << png;
  }
  std::ifstream md(out + "/report.md");
  std::string first_line;
  std::getline(md, first_line);
  EXPECT_NE(first_line.find("instance protocol"), std::string::npos);
}

TEST_F(EvaluationTest, ClassProtocolOnHeldOutInstances) {
  std::vector<std::string> skipped;
  const std::vector<EvalModel> models = HeldOutModels(*db_, scratch_->File("held_out"), &skipped);
  ASSERT_EQ(models.size(), 4u);
  EXPECT_TRUE(skipped.empty());
  for (const EvalModel& m : models) EXPECT_EQ(m.db_model, -1);
  EvalOptions options;
  options.protocol = EvalProtocol::kClass;
  options.queries_per_model = 4;
  options.query.max_occlusion = 0.15;
  const EvalReport report = Evaluate(*db_, models, options);
  std::printf("%s\n", report.BriefReport().c_str());
  ASSERT_EQ(report.queries(), 16);
  for (const QueryOutcome& o : report.outcomes) {
    EXPECT_FALSE(o.model_top1);  // held out: never a database model
    EXPECT_FALSE(std::isfinite(o.rotation_error_deg));
    EXPECT_EQ(std::isfinite(o.viewpoint_error_deg), o.class_top1);
  }
  // Four classes (chance 25%); measured 16/16 top-1 with two training instances each.
  EXPECT_GE(report.ClassTop1(), 0.6);
  EXPECT_GE(report.ClassTopK(), 0.9);
}

// Scanned instance queries without an occluder: each recognised from the segmented object
// (not the backdrop), the right model for ≥ 3 in 4, poses within 3° and 3 mm (medians).
void ExpectScannedQueriesRecognised(const EvalReport& report) {
  for (const QueryOutcome& o : report.outcomes) {
    ASSERT_TRUE(o.error.empty()) << o.error;
    EXPECT_GT(o.cloud_points, 1000);  // the segmented object, not the backdrop
    EXPECT_EQ(o.occluded_fraction, 0.0);
  }
  EXPECT_GE(report.ModelTop1(), 0.75);
  EXPECT_LT(report.MedianRotationErrorDeg(), 3.0);
  EXPECT_LT(report.MedianTranslationErrorMm(), 3.0);
}

TEST_F(EvaluationTest, ThroughTheScanPipeline) {
  // The queries scanned on the virtual rig (patterns, decoding, triangulation, range band)
  // instead of depth-rendered: the same scores, from real scan clouds.
  std::vector<EvalModel> models = InstanceModels(*db_);
  models.resize(2);
  EvalOptions options;
  options.queries_per_model = 2;
  options.through_scan = true;
  const EvalReport report = Evaluate(*db_, models, options);
  std::printf("%s\n", report.BriefReport().c_str());
  ASSERT_EQ(report.queries(), 4);
  // Measured: 4/4, median rotation error 0.02° (modulo symmetry), centre error 0.15 mm.
  ExpectScannedQueriesRecognised(report);
  EXPECT_NE(report.ToMarkdown().find("full pipeline"), std::string::npos);
}

// Issue 10: scanned queries captured with phase-shift sequences — three periods on both
// axes (ray–ray), and Gray + phase on x alone (ray–plane) — score as the Gray code does.
TEST_F(EvaluationTest, ThroughTheScanPipelineWithPhaseShift) {
  std::vector<EvalModel> models = InstanceModels(*db_);
  models.resize(2);
  EvalOptions options;
  options.queries_per_model = 2;
  options.through_scan = true;
  options.scan_patterns.family = PatternFamily::kPhase;  // automatic periods, 4 steps
  const EvalReport phase = Evaluate(*db_, models, options);
  std::printf("%s\n", phase.BriefReport().c_str());
  options.scan_patterns.family = PatternFamily::kGrayPhase;  // 16 px
  options.scan_patterns.axes = PatternAxes::kX;
  models.resize(1);
  const EvalReport gray_phase = Evaluate(*db_, models, options);
  std::printf("%s\n", gray_phase.BriefReport().c_str());
  ASSERT_EQ(phase.queries(), 4);
  ASSERT_EQ(gray_phase.queries(), 2);
  ExpectScannedQueriesRecognised(phase);
  ExpectScannedQueriesRecognised(gray_phase);
  EXPECT_NE(phase.ToMarkdown().find(
                "phase shift, axes xy, periods 1024/128/16 px (x), 768/96/12 px (y), 4 steps"),
            std::string::npos);
  EXPECT_NE(gray_phase.ToJson().find("Gray code + phase shift at 16 px, axes x"),
            std::string::npos);
}

// Issue 16: the scanned class protocol with occlusion — the query's occluder hides its
// share of the scanned object's points.
TEST_F(EvaluationTest, ScannedQueriesCanBeOccluded) {
  std::vector<EvalModel> models = InstanceModels(*db_);
  models.resize(1);
  EvalOptions options;
  options.queries_per_model = 2;
  options.through_scan = true;
  options.occlude_scans = true;
  options.query.max_occlusion = 0.3;
  const EvalReport report = Evaluate(*db_, models, options);
  ASSERT_EQ(report.queries(), 2);
  for (const QueryOutcome& o : report.outcomes) {
    ASSERT_TRUE(o.error.empty()) << o.error;
    // The depth-rendered draw of the occluded share (≤ 0.3), applied to the scanned cloud.
    EXPECT_GT(o.occluded_fraction, 0.0);
    EXPECT_LE(o.occluded_fraction, 0.3 + 1e-9);
    EXPECT_GT(o.cloud_points, 500);
  }
  EXPECT_NE(report.ToMarkdown().find("occluder hides"), std::string::npos);
}

// HideBeyondEdge hides exactly the requested share, the points farthest along the edge.
TEST(HideBeyondEdge, HidesTheShareFarthestAlongTheEdge) {
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 100; ++i) points.emplace_back(0.001f * i, 0.0f, 1.0f);  // x/z = i / 1000
  const std::vector<Eigen::Vector3f> kept = HideBeyondEdge(points, 0.25, 0.0);  // edge along +x
  ASSERT_EQ(kept.size(), 75u);
  for (const Eigen::Vector3f& p : kept) EXPECT_LT(p.x(), 0.0745f);
  const std::vector<Eigen::Vector3f> other = HideBeyondEdge(points, 0.25, M_PI);  // along −x
  ASSERT_EQ(other.size(), 75u);
  for (const Eigen::Vector3f& p : other) EXPECT_GT(p.x(), 0.0245f);
  EXPECT_EQ(HideBeyondEdge(points, 0.0, 0.0).size(), 100u);
}

// Class top-2 and the confusable pairs, from constructed outcomes.
TEST(EvalReportClasses, TopTwoAndConfusablePairs) {
  EvalReport report;
  const auto add = [&](const char* truth, const char* predicted, bool top2) {
    QueryOutcome o;
    o.truth_class = truth;
    o.predicted_class = predicted;
    o.class_top1 = o.truth_class == o.predicted_class;
    o.class_top2 = top2;
    report.outcomes.push_back(o);
  };
  add("can", "glass", true);
  add("can", "glass", false);
  add("glass", "mug", true);
  add("mug", "mug", true);
  EXPECT_DOUBLE_EQ(report.ClassTop1(), 0.25);
  EXPECT_DOUBLE_EQ(report.ClassTop2(), 0.75);
  const std::vector<std::pair<std::string, int>> pairs = report.ConfusablePairs();
  ASSERT_EQ(pairs.size(), 2u);
  EXPECT_EQ(pairs[0].first, "can → glass");
  EXPECT_EQ(pairs[0].second, 2);
  EXPECT_EQ(pairs[1].first, "glass → mug");
  EXPECT_EQ(pairs[1].second, 1);
}

TEST_F(EvaluationTest, UnknownClassesAndBadOptions) {
  const std::string other = scratch_->File("other");
  WriteProceduralModels(other, 1, 7);
  std::vector<std::string> skipped;
  // The database knows bottle, bowl, box and mug; the other six classes are skipped.
  const std::vector<EvalModel> models = HeldOutModels(*db_, other, &skipped);
  EXPECT_EQ(models.size(), 4u);
  EXPECT_EQ(skipped.size(), 6u);
  for (const char* unused : {"bottle", "bowl", "box", "mug"}) {
    std::filesystem::remove_all(other + "/" + unused);
  }
  EXPECT_THROW_WITH_MESSAGE(HeldOutModels(*db_, other, &skipped), Error, other,
                            "no usable held-out model");
  EvalOptions options;
  options.queries_per_model = 0;
  EXPECT_THROW_WITH_MESSAGE(Evaluate(*db_, models, options), Error, "queries per model", "got 0");
  options = EvalOptions();  // instance protocol with held-out models
  EXPECT_THROW_WITH_MESSAGE(Evaluate(*db_, models, options), Error, "instance protocol",
                            "is not in the database");
  EXPECT_THROW_WITH_MESSAGE(EvalProtocolFromString("objects"), Error, "'objects'");
}

}  // namespace
}  // namespace sope
