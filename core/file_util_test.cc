#include "core/file_util.h"

#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

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
    // An earlier output is recognised by its marker file (see the test below).
    StagedDirectory staged(target, "a.txt");
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

// Issue 13: a FIFO named as an input blocked open(2) forever.
TEST(FileUtil, FifosAndDirectoriesAreRefusedWithoutBlocking) {
  testing::ScratchDir scratch;
  const std::string fifo = scratch.File("fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  try {
    OpenRegularFileForReading(fifo, "database");
    ADD_FAILURE() << "no exception";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("not a regular file"), std::string::npos) << e.what();
  }
  EXPECT_THROW(OpenRegularFileForReading(scratch.path(), "x"), Error);
  EXPECT_THROW(ReadFileToString(fifo, "x"), Error);
  WriteFileAtomic(scratch.File("plain"), "abc");
  const int fd = OpenRegularFileForReading(scratch.File("plain"), "x");
  EXPECT_GE(fd, 0);
  ::close(fd);
}

// Issue 13: a corrupt PNG made libpng print "libpng error: ..." on stderr before our error.
TEST(FileUtil, CorruptPngPrintsNothingOfItsOwn) {
  testing::ScratchDir scratch;
  cv::Mat grey(40, 60, CV_8UC1);
  cv::randu(grey, 0, 255);
  WriteImageAtomic(scratch.File("good.png"), grey);
  const std::string bytes = ReadFileToString(scratch.File("good.png"), "test");
  // Truncated inside the image data; and one byte of the image data flipped (bad CRC).
  WriteFileAtomic(scratch.File("cut.png"), bytes.substr(0, bytes.size() / 2));
  std::string flipped = bytes;
  flipped[bytes.size() / 2] ^= 0x5a;
  WriteFileAtomic(scratch.File("flip.png"), flipped);
  WriteFileAtomic(scratch.File("sig.png"), "\x89PNG truncated");
  for (const char* name : {"cut.png", "flip.png", "sig.png"}) {
    SCOPED_TRACE(name);
    ::testing::internal::CaptureStderr();
    std::string error;
    try {
      ReadImage(scratch.File(name));
    } catch (const Error& e) {
      error = e.what();
    }
    const std::string printed = ::testing::internal::GetCapturedStderr();
    EXPECT_NE(error.find(name), std::string::npos) << error;
    EXPECT_NE(error.find("cannot decode"), std::string::npos) << error;
    EXPECT_EQ(printed, "");
  }
  EXPECT_EQ(cv::norm(ReadImage(scratch.File("good.png")), grey, cv::NORM_INF), 0.0);
}

// Issue 13: `simulate --out d` replaced a directory holding a user's file.
TEST(FileUtil, StagedDirectoryNeverReplacesWhatSopeDidNotWrite) {
  testing::ScratchDir scratch;
  const std::string target = scratch.File("out");
  fs::create_directories(target);
  WriteFileAtomic(JoinPath(target, "thesis.tex"), "precious");
  try {
    StagedDirectory staged(target, "frames.json");
    ADD_FAILURE() << "no exception";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("did not write"), std::string::npos) << e.what();
  }
  EXPECT_EQ(ReadFileToString(JoinPath(target, "thesis.tex"), "test"), "precious");
  EXPECT_EQ(CountEntries(scratch.path()), 1u);  // no staging directory left either
  // An earlier output (it holds the marker) is replaced; an empty directory too.
  WriteFileAtomic(JoinPath(target, "frames.json"), "{}");
  {
    StagedDirectory staged(target, "frames.json");
    WriteFileAtomic(JoinPath(staged.path(), "frames.json"), "new");
    staged.Commit();
  }
  EXPECT_FALSE(fs::exists(JoinPath(target, "thesis.tex")));
  EXPECT_EQ(ReadFileToString(JoinPath(target, "frames.json"), "test"), "new");
  fs::create_directories(scratch.File("empty"));
  {
    StagedDirectory staged(scratch.File("empty"));
    staged.Commit();
  }
  EXPECT_EQ(internal::RegisteredTemporaryCount(), 0u);
}

// Issue 13 item 4: SIGINT/SIGTERM during a staged write left `.name.tmp-XXXXXX` behind.
// The policy removes every registered temporary, prints one line and exits 128 + signal.
void InterruptWhileWriting(const std::string& directory, int signal_number) {
  InstallInterruptPolicy("sope test");
  StagedDirectory staged(JoinPath(directory, "out"));
  WriteFileAtomic(JoinPath(staged.path(), "done.txt"), "complete");
  // A file write in flight: its temporary exists and is registered.
  const std::string in_flight = JoinPath(directory, ".file.txt.tmp-abcdef");
  internal::RegisterTemporary(in_flight, [&] { std::ofstream(in_flight) << "half"; });
  ::kill(::getpid(), signal_number);
  for (;;) ::pause();  // the policy's thread ends the process
}

TEST(InterruptPolicyDeathTest, SigtermAndSigintRemoveStagedTemporaries) {
  // "fast" (fork) style: the child must write into this test's scratch directory.
  ::testing::FLAGS_gtest_death_test_style = "fast";
  for (int signal_number : {SIGTERM, SIGINT}) {
    SCOPED_TRACE(signal_number);
    testing::ScratchDir scratch;
    EXPECT_EXIT(InterruptWhileWriting(scratch.path(), signal_number),
                ::testing::ExitedWithCode(128 + signal_number),
                "^sope test: error: interrupted\n$");
    EXPECT_EQ(CountEntries(scratch.path()), 0u) << "a temporary survived";
  }
}

TEST(FileUtil, TemporariesAreForgottenAfterUse) {
  testing::ScratchDir scratch;
  WriteFileAtomic(scratch.File("a.txt"), "a");
  {
    StagedDirectory staged(scratch.File("d"));
    EXPECT_EQ(internal::RegisteredTemporaryCount(), 1u);
  }
  {
    StagedDirectory staged(scratch.File("d"));
    staged.Commit();
  }
  {
    StagedDirectory staged(scratch.File("d"));
    staged.Commit();  // replaces the (empty) earlier one
  }
  EXPECT_EQ(internal::RegisteredTemporaryCount(), 0u);
  EXPECT_EQ(CountEntries(scratch.path()), 2u);
}

}  // namespace
}  // namespace sope
