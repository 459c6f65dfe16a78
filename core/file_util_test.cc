#include "core/file_util.h"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace {
namespace fs = std::filesystem;

size_t CountEntries(const std::string& directory) {
  size_t count = 0;
  for ([[maybe_unused]] const auto& entry : fs::directory_iterator(directory)) ++count;
  return count;
}

TEST(FileUtil, WriteFileAtomicReplacesAndLeavesNoTemporary) {
  testing::ScratchDir scratch;
  const std::string path = scratch.File("sub/dir/file.txt");
  WriteFileAtomic(path, "first");
  WriteFileAtomic(path, "second");
  EXPECT_EQ(ReadFileToString(path, "test"), "second");
  EXPECT_EQ(CountEntries(scratch.File("sub/dir")), 1u);
}

TEST(FileUtil, ReadErrorsNameTheFile) {
  testing::ScratchDir scratch;
  try {
    ReadFileToString(scratch.File("missing.txt"), "widget");
    FAIL() << "no exception";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("widget"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("missing.txt"), std::string::npos);
  }
  EXPECT_THROW_WITH_MESSAGE(RequireReadableFile(scratch.path(), "dir"), Error, scratch.path(),
                            "not a regular file");
}

TEST(FileUtil, ImageRoundTripIncludingExr) {
  testing::ScratchDir scratch;
  cv::Mat grey(5, 7, CV_8UC1);
  cv::randu(grey, 0, 255);
  WriteImageAtomic(scratch.File("grey.png"), grey);
  EXPECT_EQ(cv::norm(ReadImage(scratch.File("grey.png")), grey, cv::NORM_INF), 0.0);
  cv::Mat depth(5, 7, CV_32FC1, cv::Scalar(0.6125f));
  depth.at<float>(2, 3) = std::numeric_limits<float>::quiet_NaN();
  WriteImageAtomic(scratch.File("depth.exr"), depth);
  const cv::Mat read = ReadImage(scratch.File("depth.exr"));
  ASSERT_EQ(read.type(), CV_32FC1);
  EXPECT_FLOAT_EQ(read.at<float>(0, 0), 0.6125f);
  EXPECT_TRUE(std::isnan(read.at<float>(2, 3)));
}

TEST(FileUtil, CorruptImageIsAClearError) {
  testing::ScratchDir scratch;
  std::ofstream(scratch.File("bad.png")) << "not a png";
  EXPECT_THROW_WITH_MESSAGE(ReadImage(scratch.File("bad.png")), Error, "bad.png", "cannot decode");
}

TEST(FileUtil, StagedDirectoryCommitsWholeOrNothing) {
  testing::ScratchDir scratch;
  const std::string target = scratch.File("out");
  {
    StagedDirectory staged(target);
    WriteFileAtomic(JoinPath(staged.path(), "a.txt"), "a");
    // No commit: nothing appears.
  }
  EXPECT_FALSE(fs::exists(target));
  EXPECT_EQ(CountEntries(scratch.path()), 0u);
  {
    StagedDirectory staged(target);
    WriteFileAtomic(JoinPath(staged.path(), "a.txt"), "a");
    staged.Commit();
  }
  EXPECT_EQ(ReadFileToString(JoinPath(target, "a.txt"), "test"), "a");
  {
    StagedDirectory staged(target);
    WriteFileAtomic(JoinPath(staged.path(), "b.txt"), "b");
    staged.Commit();
  }
  EXPECT_FALSE(fs::exists(JoinPath(target, "a.txt")));
  EXPECT_TRUE(fs::exists(JoinPath(target, "b.txt")));
  EXPECT_EQ(CountEntries(scratch.path()), 1u);
}

TEST(FileUtil, ExtensionIsLowerCase) {
  EXPECT_EQ(FileExtension("a/b/C.PLY"), "ply");
  EXPECT_EQ(FileExtension("noext"), "");
}

}  // namespace
}  // namespace sope
