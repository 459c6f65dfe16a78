// The `sope` binary as a user runs it: outputs on good input, and on bad input exactly
// one clear line on stderr, a non-zero exit and no output file.
#include <sys/wait.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/file_util.h"
#include "core/frame_set.h"
#include "core/point_cloud.h"
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

using testing::ExpectOneLineError;

using testing::SmallRig;

class Cli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new testing::ScratchDir();
    WriteRigCalibration(scratch_->File("rig.yaml"), SmallRig());
    // A unit box scaled to 0.2 m, tilted, before a backdrop.
    WriteFileAtomic(scratch_->File("box.obj"),
                    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
                    "f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\n"
                    "f 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n");
    const SopeRun run = Sope("simulate --mesh " + scratch_->File("box.obj") + " --rig " +
                             scratch_->File("rig.yaml") +
                             " --object-size 0.2 --object-pose 30,40,0,0,0,0.6 --backdrop 0.75"
                             " --supersample 2 --out " + scratch_->File("scan"),
                         *scratch_);
    ASSERT_EQ(run.exit_code, 0) << run.err;
  }
  static void TearDownTestSuite() { delete scratch_; }

  // A fresh copy of the simulated frame set to damage.
  std::string CopyOfScan() {
    const std::string copy = local_.File("scan");
    fs::copy(scratch_->File("scan"), copy, fs::copy_options::recursive);
    return copy;
  }

  static testing::ScratchDir* scratch_;
  testing::ScratchDir local_;
};

testing::ScratchDir* Cli::scratch_ = nullptr;

TEST_F(Cli, UsageAndHelp) {
  EXPECT_EQ(Sope("", local_).exit_code, 2);
  const SopeRun help = Sope("--help", local_);
  EXPECT_EQ(help.exit_code, 0);
  for (const char* command : {"patterns", "simulate", "decode", "scan"}) {
    EXPECT_NE(help.out.find(command), std::string::npos) << command;
    EXPECT_EQ(Sope(std::string(command) + " --help", local_).exit_code, 0) << command;
  }
  EXPECT_EQ(Sope("frobnicate", local_).exit_code, 2);
  EXPECT_EQ(Sope("scan --no-such-flag", local_).exit_code, 2);
}

TEST_F(Cli, PatternsWritesAFrameSet) {
  const SopeRun run = Sope("patterns --projector 100x30 --axes xy --out " + local_.File("p"), local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const FrameSet set = LoadFrameSet(local_.File("p"));
  // white + black + 2·(7 column bits + 5 row bits).
  EXPECT_EQ(set.images.size(), 2u + 2u * (7 + 5));
  EXPECT_EQ(set.images[0].cols, 100);
  ExpectOneLineError(Sope("patterns --projector 100by30 --out " + local_.File("q"), local_),
                     "patterns", "WIDTHxHEIGHT");
  EXPECT_FALSE(fs::exists(local_.File("q")));
}

TEST_F(Cli, SimulateDecodeScanProduceOutputs) {
  const std::string scan = scratch_->File("scan");
  for (const char* file : {"frames.json", "calibration.yaml", "gt_depth.exr", "gt_proj_x.exr",
                           "gt_lit.png", "gt_pose.json"}) {
    EXPECT_TRUE(fs::exists(scan + "/" + file)) << file;
  }
  SopeRun run = Sope("decode --frames " + scan + " --out " + local_.File("maps"), local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  for (const char* file : {"proj_x.exr", "proj_y.exr", "mask.png", "proj_x.png"}) {
    EXPECT_TRUE(fs::exists(local_.File("maps/") + file)) << file;
  }
  run = Sope("scan --frames " + scan + " --out " + local_.File("cloud.ply"), local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const PointCloud cloud = ReadPointCloud(local_.File("cloud.ply"));
  EXPECT_GT(cloud.size(), 5000u);
  EXPECT_TRUE(cloud.HasColors());
  for (const Eigen::Vector3f& point : cloud.points) {
    ASSERT_GT(point.z(), 0.4f);
    ASSERT_LT(point.z(), 0.8f);
  }
  run = Sope("scan --frames " + scan + " --calibration " + scratch_->File("rig.yaml") +
                 " --ascii --out " + local_.File("cloud.pcd"),
             local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_EQ(ReadPointCloud(local_.File("cloud.pcd")).size(), cloud.size());
}

TEST_F(Cli, MissingFrame) {
  const std::string scan = CopyOfScan();
  fs::remove(scan + "/frame_05.png");
  ExpectOneLineError(Sope("scan --frames " + scan + " --out " + local_.File("c.ply"), local_),
                     "scan", "frame_05.png");
  EXPECT_FALSE(fs::exists(local_.File("c.ply")));
}

TEST_F(Cli, UnreadableFrame) {
  const std::string scan = CopyOfScan();
  WriteFileAtomic(scan + "/frame_07.png", "\x89PNG truncated");
  ExpectOneLineError(Sope("decode --frames " + scan + " --out " + local_.File("m"), local_),
                     "decode", "frame_07.png");
  EXPECT_FALSE(fs::exists(local_.File("m")));
}

TEST_F(Cli, MismatchedFrameSize) {
  const std::string scan = CopyOfScan();
  WriteImageAtomic(scan + "/frame_03.png", cv::Mat(120, 160, CV_8UC1, cv::Scalar(9)));
  ExpectOneLineError(Sope("scan --frames " + scan + " --out " + local_.File("c.ply"), local_),
                     "scan", "does not match");
  EXPECT_FALSE(fs::exists(local_.File("c.ply")));
}

TEST_F(Cli, MalformedAndInconsistentManifests) {
  std::string scan = CopyOfScan();
  WriteFileAtomic(scan + "/frames.json", "{\"format\": \"sope-frames/1\", \"camera\": ");
  ExpectOneLineError(Sope("scan --frames " + scan + " --out " + local_.File("c.ply"), local_),
                     "scan", "not valid JSON");
  fs::remove_all(scan);
  scan = CopyOfScan();
  nlohmann::json manifest =
      nlohmann::json::parse(ReadFileToString(scan + "/frames.json", "test"));
  manifest["frames"][4]["bit"] = 40;
  WriteFileAtomic(scan + "/frames.json", manifest.dump());
  ExpectOneLineError(Sope("scan --frames " + scan + " --out " + local_.File("c.ply"), local_),
                     "scan", "bit 40");
  ExpectOneLineError(Sope("scan --frames " + local_.File("nowhere") + " --out " +
                              local_.File("c.ply"),
                          local_),
                     "scan", "no such file");
  EXPECT_FALSE(fs::exists(local_.File("c.ply")));
}

TEST_F(Cli, CalibrationThatDoesNotFitTheFrames) {
  const std::string scan = CopyOfScan();
  RigCalibration other = SmallRig();
  other.camera.width = 640;
  WriteRigCalibration(local_.File("other.yaml"), other);
  ExpectOneLineError(Sope("scan --frames " + scan + " --calibration " + local_.File("other.yaml") +
                              " --out " + local_.File("c.ply"),
                          local_),
                     "scan", "camera is 640x240 but the frames are 320x240");
  WriteFileAtomic(local_.File("broken.yaml"), "%YAML:1.0\ncamera_width: [1, 2\n");
  ExpectOneLineError(Sope("scan --frames " + scan + " --calibration " +
                              local_.File("broken.yaml") + " --out " + local_.File("c.ply"),
                          local_),
                     "scan", "broken.yaml");
  EXPECT_FALSE(fs::exists(local_.File("c.ply")));
}

// `sope objects --contact-sheet DIR`: one PNG per class plus an overview, each a real
// picture (the shaded rows hold the rendered objects, the last row their profiles).
TEST_F(Cli, ObjectsContactSheets) {
  const std::string dir = local_.File("sheets");
  const SopeRun run = Sope("objects --instances 2 --seed 5 --contact-sheet " + dir, local_);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_FALSE(fs::exists(local_.File("models")));  // no --out: no models written
  for (const char* name : {"mug", "bottle", "bowl", "box", "can", "glass", "plate", "vase",
                           "wine_glass", "saucepan"}) {
    SCOPED_TRACE(name);
    const std::string path = dir + "/" + name + ".png";
    ASSERT_TRUE(fs::is_regular_file(path));
    EXPECT_GT(fs::file_size(path), 20000u);  // 640×1280 colour, mostly not flat
    const cv::Mat sheet = ReadImage(path, cv::IMREAD_COLOR);
    // Two instances in columns of 320 px; three shaded views and the profile in rows.
    ASSERT_EQ(sheet.cols, 2 * 320);
    ASSERT_EQ(sheet.rows, 4 * 320);
    // Not blank: in the shaded rows, a good share of pixels are neither the background
    // grey nor the label's white; in the profile row, the filled silhouette is there (lathe
    // classes).
    int object = 0, silhouette = 0;
    for (int y = 0; y < sheet.rows; ++y) {
      for (int x = 0; x < sheet.cols; ++x) {
        const cv::Vec3b bgr = sheet.at<cv::Vec3b>(y, x);
        if (y < 3 * 320) {
          object += bgr != cv::Vec3b(40, 40, 40) && bgr != cv::Vec3b(255, 255, 255);
        } else {
          silhouette += bgr == cv::Vec3b(200, 120, 60);
        }
      }
    }
    EXPECT_GT(object, 3 * 320 * 640 / 20);
    // The box is no lathe object: it has no profile to draw.
    if (std::string(name) != "box") EXPECT_GT(silhouette, 320 * 640 / 50);
  }
  const std::string overview = dir + "/overview.png";
  ASSERT_TRUE(fs::is_regular_file(overview));
  const cv::Mat image = ReadImage(overview, cv::IMREAD_COLOR);
  EXPECT_EQ(image.cols, 5 * 400);
  EXPECT_EQ(image.rows, 2 * 400);
  cv::Mat grey;
  cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  cv::Scalar mean, stddev;
  cv::meanStdDev(grey, mean, stddev);
  EXPECT_GT(stddev[0], 5.0);
  // Atomic writes leave no temporary files behind.
  int entries = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    ++entries;
    EXPECT_EQ(entry.path().extension(), ".png") << entry.path();
  }
  EXPECT_EQ(entries, 11);
}

TEST_F(Cli, ObjectsNeedsAnOutput) {
  ExpectOneLineError(Sope("objects --instances 2", local_), "objects", "--contact-sheet");
  ExpectOneLineError(Sope("objects --instances 0 --contact-sheet " + local_.File("s"), local_),
                     "objects", "got 0");
  EXPECT_FALSE(fs::exists(local_.File("s")));
}

}  // namespace
}  // namespace sope
