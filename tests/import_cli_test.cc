// `sope import` (issue 15) through the command line: on the real OpenCV-order capture in
// ../shared/data/sl/kibekibe-target, `sope import` + `sope decode` give exactly the
// correspondences of the hand-written manifest the tests used before; and bad input (an image
// count that does not fit the layout, a foreign calibration missing a key) is one clear line.
#include <filesystem>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "core/file_util.h"
#include "core/frame_set.h"
#include "decoder/decoder.h"
#include "projector/patterns.h"
#include "tests/test_support.h"

namespace sope {
namespace {

testing::CommandRun Sope(const std::string& arguments, const testing::ScratchDir& scratch) {
  return testing::RunCommand(SOPE_BINARY, arguments, scratch);
}

TEST(ImportCli, RealOpenCvCaptureReplacesTheHandWrittenManifest) {
  SOPE_REQUIRE_SHARED_DATA(data);
  const std::string images = JoinPath(data, "sl/kibekibe-target");
  testing::ScratchDir scratch;
  const testing::CommandRun imported =
      Sope(fmt::format("import --layout opencv-graycode --projector 512x384 --images {} --out {}",
                       testing::Quote(images), testing::Quote(scratch.File("frames"))),
           scratch);
  ASSERT_EQ(imported.exit_code, 0) << imported.err;
  const testing::CommandRun decoded =
      Sope(fmt::format("decode --frames {} --out {}", testing::Quote(scratch.File("frames")),
                       testing::Quote(scratch.File("maps"))),
           scratch);
  ASSERT_EQ(decoded.exit_code, 0) << decoded.err;
  const CorrespondenceMap from_cli = ReadCorrespondenceMap(scratch.File("maps"));

  // The hand-written manifest: DSC04052 … DSC04089 in OpenCV's order.
  std::vector<std::string> files;
  for (int i = 4052; i <= 4089; ++i) files.push_back(fmt::format("DSC0{}.JPG", i));
  std::filesystem::create_directories(scratch.File("hand"));
  for (const std::string& file : files) {
    std::filesystem::create_symlink(JoinPath(images, file), scratch.File("hand/" + file));
  }
  const cv::Mat first = ReadImage(JoinPath(images, files[0]), cv::IMREAD_GRAYSCALE);
  const FrameSetManifest manifest =
      MakeOpenCvGrayCodeManifest(512, 384, first.cols, first.rows, files);
  WriteFileAtomic(scratch.File("hand/frames.json"), SerializeFrameSetManifest(manifest));
  // Decoded as `sope decode` decodes by default (Gray codes refined from the stripe edges,
  // undecided pixels decoded from their neighbours).
  DecoderOptions as_cli;
  as_cli.gray_subpixel = GraySubpixel::kEdges;
  as_cli.consistency.enabled = true;
  const CorrespondenceMap from_hand = Decode(LoadFrameSet(scratch.File("hand")), as_cli);

  ASSERT_GT(from_hand.CountValid(), from_hand.mask.total() / 10);
  EXPECT_EQ(from_cli.CountValid(), from_hand.CountValid());
  EXPECT_EQ(cv::norm(from_cli.mask, from_hand.mask, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(from_cli.proj_x, from_hand.proj_x, cv::NORM_INF, from_hand.mask), 0.0);
  EXPECT_EQ(cv::norm(from_cli.proj_y, from_hand.proj_y, cv::NORM_INF, from_hand.mask), 0.0);
}

TEST(ImportCli, ImageCountThatDoesNotFitTheLayoutIsOneLine) {
  testing::ScratchDir scratch;
  std::filesystem::create_directories(scratch.File("capture"));
  const cv::Mat image(48, 64, CV_8UC1, cv::Scalar(100));
  for (int i = 0; i < 41; ++i) {  // a 1024x768 OpenCV capture has 42
    WriteImageAtomic(scratch.File(fmt::format("capture/graycode_{:02}.png", i)), image);
  }
  const testing::CommandRun run =
      Sope(fmt::format("import --layout opencv-graycode --projector 1024x768 --images {} --out {}",
                       testing::Quote(scratch.File("capture")),
                       testing::Quote(scratch.File("frames"))),
           scratch);
  testing::ExpectOneLineError(run, "import", "the layout expects 42 images");
  EXPECT_FALSE(std::filesystem::exists(scratch.File("frames")));
}

TEST(ImportCli, ForeignCalibrationMissingAKeyIsOneLine) {
  testing::ScratchDir scratch;
  std::filesystem::create_directories(scratch.File("capture"));
  PatternOptions options;
  options.projector_width = 64;
  options.projector_height = 48;
  options.inverted = false;
  size_t index = 0;
  for (const Pattern& pattern : GeneratePatterns(options)) {
    WriteImageAtomic(scratch.File(fmt::format("capture/{}.png", index++)), pattern.image);
  }
  // SLStudio's calibration.xml without its projector matrix Kp.
  WriteFileAtomic(scratch.File("calibration.xml"),
                  "<?xml version=\"1.0\"?>\n<opencv_storage>\n"
                  "<Kc type_id=\"opencv-matrix\"><rows>3</rows><cols>3</cols><dt>f</dt>"
                  "<data>500. 0. 32. 0. 500. 24. 0. 0. 1.</data></Kc>\n"
                  "<kc type_id=\"opencv-matrix\"><rows>5</rows><cols>1</cols><dt>f</dt>"
                  "<data>0. 0. 0. 0. 0.</data></kc>\n"
                  "<frameWidth>64</frameWidth><frameHeight>48</frameHeight>"
                  "<screenResX>64</screenResX><screenResY>48</screenResY>\n"
                  "</opencv_storage>\n");
  const testing::CommandRun run = Sope(
      fmt::format("import --layout order --order 'white,black,x5-0,y5-0' --projector 64x48 "
                  "--images {} --out {} --calibration {} --calibration-format slstudio --units mm",
                  testing::Quote(scratch.File("capture")), testing::Quote(scratch.File("frames")),
                  testing::Quote(scratch.File("calibration.xml"))),
      scratch);
  testing::ExpectOneLineError(run, "import", "missing key 'Kp'");
  // The unit must be stated.
  const testing::CommandRun no_units = Sope(
      fmt::format("import --layout order --order 'white,black,x5-0,y5-0' --projector 64x48 "
                  "--images {} --out {} --calibration {} --calibration-format slstudio",
                  testing::Quote(scratch.File("capture")), testing::Quote(scratch.File("frames")),
                  testing::Quote(scratch.File("calibration.xml"))),
      scratch);
  testing::ExpectOneLineError(no_units, "import", "--units");
}

}  // namespace
}  // namespace sope
