// `sope simulate --board` and `sope calibrate` as a user runs them: the sequence and the
// calibration files on good input; on bad input one clear line on stderr, a non-zero exit
// and no output file.
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "core/file_util.h"
#include "core/frame_set.h"
#include "core/rig_calibration.h"
#include "tests/test_support.h"

namespace sope {
namespace {
namespace fs = std::filesystem;

using SopeRun = testing::CommandRun;
using testing::Quote;

SopeRun Sope(const std::string& arguments, const testing::ScratchDir& scratch) {
  return testing::RunCommand(SOPE_BINARY, arguments, scratch);
}

int Lines(const std::string& text) {
  return static_cast<int>(std::count(text.begin(), text.end(), '\n'));
}

using testing::ExpectOneLineError;

// The tests' small rig (fast to render) with its principal points half a pixel off.
RigCalibration SmallRig() {
  RigCalibration rig = testing::SmallRig();
  rig.camera.matrix(0, 2) = 160.5;
  rig.camera.matrix(1, 2) = 119.5;
  rig.projector.matrix(0, 2) = 127.5;
  rig.projector.matrix(1, 2) = 95.5;
  return rig;
}

constexpr const char* kBoard = "5x4x0.04";  // 6×5 squares of 4 cm: ~20 px in this camera

class CalibrateCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir();
    const testing::ScratchDir& s = *scratch_;
    WriteRigCalibration(s.File("rig.yaml"), SmallRig());
    const std::string rig = " --rig " + s.File("rig.yaml") + " --supersample 2";
    SopeRun run = Sope(
        std::string("simulate --board ") + kBoard + " --views 6" + rig + " --out " + s.File("seq"),
        s);
    ASSERT_EQ(run.exit_code, 0) << run.err;
    run = Sope(
        "simulate --mesh builtin:sphere --backdrop 0.75" + rig + " --out " + s.File("sphere"), s);
    ASSERT_EQ(run.exit_code, 0) << run.err;
    run = Sope("simulate --mesh builtin:sphere --axes x" + rig + " --out " + s.File("x_only"), s);
    ASSERT_EQ(run.exit_code, 0) << run.err;
    // A frame set of another size (camera = projector = 256×192).
    run = Sope("patterns --projector 256x192 --out " + s.File("patterns"), s);
    ASSERT_EQ(run.exit_code, 0) << run.err;
  }
  static void TearDownTestSuite() { delete scratch_; }

  static std::string Seq(const std::string& view = "") {
    return view.empty() ? scratch_->File("seq") : scratch_->File("seq") + "/" + view;
  }
  void ExpectNoOutputs() {
    for (const char* file : {"cal.yaml", "cal.report.json", "cal.residuals.png"}) {
      EXPECT_FALSE(fs::exists(local_.File(file))) << file;
    }
  }

  static testing::ScratchDir* scratch_;
  testing::ScratchDir local_;
};

testing::ScratchDir* CalibrateCli::scratch_ = nullptr;

TEST_F(CalibrateCli, HelpNamesInnerCorners) {
  const SopeRun help = Sope("--help", local_);
  EXPECT_NE(help.out.find("calibrate"), std::string::npos);
  for (const char* command : {"calibrate --help", "simulate --help"}) {
    const SopeRun run = Sope(command, local_);
    EXPECT_EQ(run.exit_code, 0) << command;
    EXPECT_NE(run.out.find("INNER corners"), std::string::npos) << command;
  }
}

TEST_F(CalibrateCli, SimulateBoardWritesASequenceWithGroundTruth) {
  EXPECT_TRUE(fs::exists(Seq("calibration_true.yaml")));
  const RigCalibration truth = ReadRigCalibration(Seq("calibration_true.yaml"));
  EXPECT_EQ(truth.camera.width, 320);
  const nlohmann::json poses =
      nlohmann::json::parse(ReadFileToString(Seq("gt_board_poses.json"), "test"));
  EXPECT_EQ(poses["format"], "sope-gt-board-poses/1");
  EXPECT_EQ(poses["board"]["cols"], 5);
  EXPECT_EQ(poses["board"]["rows"], 4);
  ASSERT_EQ(poses["views"].size(), 6u);
  for (int v = 0; v < 6; ++v) {
    const std::string name = fmt::format("view_{:03d}", v);
    EXPECT_EQ(poses["views"][v]["name"], name);
    const double depth = poses["views"][v]["cam_from_board"]["translation"][2];
    EXPECT_GT(depth, 0.3);
    const FrameSetManifest manifest = ReadFrameSetManifest(Seq(name));
    EXPECT_EQ(manifest.calibration, "../calibration_true.yaml");
    EXPECT_EQ(manifest.frames.size(), 2u + 2u * (8 + 8));
  }
  // The manifest's calibration resolves: a view scans like any frame set.
  const SopeRun scan =
      Sope("scan --frames " + Seq("view_000") + " --out " + local_.File("board.ply"), local_);
  EXPECT_EQ(scan.exit_code, 0) << scan.err;
  EXPECT_TRUE(fs::exists(local_.File("board.ply")));
}

TEST_F(CalibrateCli, CalibrateWritesTheCalibrationItsReportAndResidualPlot) {
  // Six views of 20 corners are too few for the full distortion models; the small rig has
  // only k1, k2 in the camera and none in the projector.
  const SopeRun run = Sope("calibrate --frames " + Seq() + " --board " + kBoard +
                               " --camera-distortion k1,k2 --projector-distortion none --out " +
                               local_.File("cal.yaml"),
                           local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.out.find("6 given: 6 used, 0 dropped"), std::string::npos) << run.out;
  EXPECT_NE(run.out.find("baseline"), std::string::npos);
  const RigCalibration truth = SmallRig();
  const RigCalibration recovered = ReadRigCalibration(local_.File("cal.yaml"));
  EXPECT_EQ(recovered.camera.width, 320);
  EXPECT_EQ(recovered.projector.height, 192);
  EXPECT_NEAR(recovered.camera.fx() / truth.camera.fx(), 1.0, 0.01);
  EXPECT_NEAR(recovered.projector.fx() / truth.projector.fx(), 1.0, 0.01);
  EXPECT_NEAR(recovered.BaselineLength() / truth.BaselineLength(), 1.0, 0.02);
  EXPECT_GT(recovered.rms_camera_px, 0.0);
  EXPECT_LT(recovered.rms_camera_px, 0.3);
  EXPECT_LT(recovered.rms_projector_px, 0.4);
  EXPECT_GE(recovered.rms_stereo_px, std::min(recovered.rms_camera_px, recovered.rms_projector_px));
  const nlohmann::json report =
      nlohmann::json::parse(ReadFileToString(local_.File("cal.report.json"), "test"));
  EXPECT_EQ(report["views"].size(), 6u);
  EXPECT_EQ(report["views_used"], 6);
  EXPECT_NEAR(report["rms_camera_px"].get<double>(), recovered.rms_camera_px, 1e-6);
  const cv::Mat plot = cv::imread(local_.File("cal.residuals.png"));
  ASSERT_FALSE(plot.empty());
  EXPECT_GT(plot.cols, 800);
}

// Issue 11: boards partly out of the camera image in every second view (`simulate
// --partial-views`) are used and reported; --whole-boards drops them as before.
TEST_F(CalibrateCli, BoardsPartlyOutOfViewAreUsed) {
  const std::string rig = " --rig " + scratch_->File("rig.yaml") + " --supersample 2";
  // The noise seed: this small camera finds a board partly out of view only marginally
  // (~20 px squares, a few columns in view): all three partial views were found for 7 of 12
  // noise seeds with the earlier noise generator and for 4 of 8 with the current one; seed
  // 2 finds them. Partial boards at full size are calibrate_e2e_test's.
  SopeRun run = Sope(std::string("simulate --board ") + kBoard + " --views 6 --partial-views 0.5" +
                         rig + " --seed 2 --out " + local_.File("seq"),
                     local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const std::string calibrate = "calibrate --frames " + local_.File("seq") + " --board " + kBoard +
                                " --camera-distortion k1,k2 --projector-distortion none";
  run = Sope(calibrate + " --out " + local_.File("cal.yaml"), local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.out.find("6 given: 6 used, 0 dropped, 0 without the board; 3 used with the "
                         "board partly in view"),
            std::string::npos)
      << run.out;
  const nlohmann::json report =
      nlohmann::json::parse(ReadFileToString(local_.File("cal.report.json"), "test"));
  EXPECT_EQ(report["views_partial_used"], 3);
  for (int v = 0; v < 6; ++v) EXPECT_EQ(report["views"][v]["partial"], v % 2 == 1) << v;
  // A sanity bound only: six views of 20 corners (~20 px squares), three of them partial,
  // on the small rig; the accuracy figures are calibrate_e2e_test's.
  const RigCalibration truth = SmallRig();
  const RigCalibration recovered = ReadRigCalibration(local_.File("cal.yaml"));
  EXPECT_NEAR(recovered.camera.fx() / truth.camera.fx(), 1.0, 0.03);
  EXPECT_NEAR(recovered.projector.fx() / truth.projector.fx(), 1.0, 0.03);
  EXPECT_NEAR(recovered.BaselineLength() / truth.BaselineLength(), 1.0, 0.03);
  run = Sope(calibrate + " --whole-boards --out " + local_.File("whole.yaml"), local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.out.find("6 given: 3 used, 0 dropped, 3 without the board\n"), std::string::npos)
      << run.out;
  const RigCalibration whole = ReadRigCalibration(local_.File("whole.yaml"));
  std::printf("[small rig] camera fx error %+.2f%% with the partial views, %+.2f%% without; "
              "projector %+.2f%% / %+.2f%%; baseline %+.2f%% / %+.2f%%\n",
              100 * (recovered.camera.fx() / truth.camera.fx() - 1),
              100 * (whole.camera.fx() / truth.camera.fx() - 1),
              100 * (recovered.projector.fx() / truth.projector.fx() - 1),
              100 * (whole.projector.fx() / truth.projector.fx() - 1),
              100 * (recovered.BaselineLength() / truth.BaselineLength() - 1),
              100 * (whole.BaselineLength() / truth.BaselineLength() - 1));
}

TEST_F(CalibrateCli, ViewWithoutTheBoardIsSkippedWithAWarning) {
  const SopeRun run = Sope("calibrate --frames " + Seq() + " " + scratch_->File("sphere") +
                               " --board " + kBoard + " --out " + local_.File("cal.yaml"),
                           local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.err.find("warning: view " + scratch_->File("sphere") + ": board 5x4 not found"),
            std::string::npos)
      << run.err;
  EXPECT_NE(run.out.find("7 given: 6 used, 0 dropped, 1 without the board"), std::string::npos)
      << run.out;
  const nlohmann::json report =
      nlohmann::json::parse(ReadFileToString(local_.File("cal.report.json"), "test"));
  ASSERT_EQ(report["views"].size(), 7u);
  EXPECT_EQ(report["views"][6]["status"], "board not found");
  EXPECT_TRUE(fs::exists(local_.File("cal.yaml")));
}

TEST_F(CalibrateCli, FewerThanThreeUsableViews) {
  ExpectOneLineError(Sope("calibrate --frames " + Seq("view_000") + " " + Seq("view_001") +
                              " --board " + kBoard + " --out " + local_.File("cal.yaml"),
                          local_),
                     "calibrate",
                     "only 2 usable views (board found in 2 of 2); calibration "
                     "needs at least 3");
  ExpectNoOutputs();
}

TEST_F(CalibrateCli, WrongBoardSize) {
  const std::string arguments =
      "calibrate --frames " + Seq() + " --board 6x4x0.04 --out " + local_.File("cal.yaml");
  ExpectOneLineError(Sope(arguments + " --quiet", local_), "calibrate",
                     "board 6x4 not found in any view — check --board");
  // Without --quiet each view's warning comes first, the error last.
  const SopeRun run = Sope(arguments, local_);
  EXPECT_NE(run.exit_code, 0);
  EXPECT_EQ(Lines(run.err), 7) << run.err;
  EXPECT_NE(run.err.find("sope calibrate: error: board 6x4 not found in any view"),
            std::string::npos);
  ExpectNoOutputs();
}

TEST_F(CalibrateCli, MismatchedFrameSizes) {
  ExpectOneLineError(Sope("calibrate --frames " + Seq() + " " + scratch_->File("patterns") +
                              " --board " + kBoard + " --out " + local_.File("cal.yaml"),
                          local_),
                     "calibrate", "has a 256x192 camera and a 256x192 projector but view");
  ExpectNoOutputs();
}

TEST_F(CalibrateCli, FrameSetWithoutYCodes) {
  ExpectOneLineError(Sope("calibrate --frames " + scratch_->File("x_only") + " --board " + kBoard +
                              " --out " + local_.File("cal.yaml"),
                          local_),
                     "calibrate", "calibration needs both x and y codes");
  ExpectNoOutputs();
}

TEST_F(CalibrateCli, BadArguments) {
  ExpectOneLineError(
      Sope("calibrate --frames " + Seq() + " --board 5x4 --out " + local_.File("cal.yaml"), local_),
      "calibrate", "expected COLSxROWSxSQUARE_M");
  fs::create_directories(local_.File("empty"));
  ExpectOneLineError(Sope("calibrate --frames " + local_.File("empty") + " --board " + kBoard +
                              " --out " + local_.File("cal.yaml"),
                          local_),
                     "calibrate", "neither a frame set");
  ExpectOneLineError(Sope("calibrate --frames " + local_.File("nowhere") + " --board " + kBoard +
                              " --out " + local_.File("cal.yaml"),
                          local_),
                     "calibrate", "no such directory");
  ExpectOneLineError(Sope("calibrate --frames " + Seq() + " --board " + kBoard +
                              " --camera-distortion k1,k9 --out " + local_.File("cal.yaml"),
                          local_),
                     "calibrate", "unknown term 'k9'");
  EXPECT_EQ(Sope("calibrate --board " + std::string(kBoard) + " --out x.yaml", local_).exit_code,
            2);
  ExpectNoOutputs();
  ExpectOneLineError(Sope("simulate --out " + local_.File("s"), local_), "simulate",
                     "one of --mesh or --board is required");
  ExpectOneLineError(Sope("simulate --board 40x30x0.05 --rig " + scratch_->File("rig.yaml") +
                              " --views 2 --out " + local_.File("s"),
                          local_),
                     "simulate", "fits both the camera and the projector");
  EXPECT_EQ(
      Sope("simulate --board 5x4x0.04 --mesh builtin:sphere --out " + local_.File("s"), local_)
          .exit_code,
      2);
  EXPECT_FALSE(fs::exists(local_.File("s")));
}

}  // namespace
}  // namespace sope
