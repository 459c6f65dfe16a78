// The `sope` binary as a user runs it: outputs on good input, and on bad input exactly
// one clear line on stderr, a non-zero exit and no output file.
#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

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

// ---- Issue 13: hostile input and signals -------------------------------------------------

// Hidden staging leftovers (".name.tmp-XXXXXX") or any entry but the run's captured output.
std::vector<std::string> EntriesBesidesCapture(const std::string& directory) {
  std::vector<std::string> entries;
  for (const auto& entry : fs::directory_iterator(directory)) {
    const std::string name = entry.path().filename().string();
    if (name != ".stdout" && name != ".stderr") entries.push_back(name);
  }
  return entries;
}

TEST_F(Cli, UsageErrorsAreOneLine) {
  ExpectOneLineError(Sope("scan --frames x --out y --no-such-flag", local_), "scan",
                     "--no-such-flag");
  ExpectOneLineError(Sope("simulate --mesh", local_), "simulate", "--mesh");
  ExpectOneLineError(Sope("decode --frames " + scratch_->File("scan"), local_), "decode",
                     "--out is required");
  ExpectOneLineError(Sope("build-db --models m --out d.sopedb --threads four", local_),
                     "build-db", "four");
  ExpectOneLineError(Sope("scan -q --frames x --out y --bogus", local_), "scan", "--bogus");
  // eval's pattern flags: only for scanned queries, checked before the database is opened.
  ExpectOneLineError(Sope("eval --db none.sopedb --code phase --out r", local_), "eval",
                     "--scan-pipeline or --table");
  ExpectOneLineError(Sope("eval --db none.sopedb --scan-pipeline --code phase --periods 100,10 "
                          "--out r", local_),
                     "eval", "coarsest phase period 100 px");
}

TEST_F(Cli, ImpossibleValuesAndCountsAreRefused) {
  const std::string rig = " --rig " + scratch_->File("rig.yaml");
  const std::string out = " --out " + local_.File("o");
  const std::string sphere = "simulate --mesh builtin:sphere" + rig;
  struct Case {
    std::string command, arguments, needle;
  };
  const std::vector<Case> cases = {
      {"simulate", sphere + " --object-pose 0,0,0,0,0,0.6,", "stray comma"},
      {"simulate", sphere + " --object-pose ,0,0,0,0,0.6", "stray comma"},
      {"simulate", sphere + " --object-size 0", "--object-size"},
      {"simulate", sphere + " --object-size nan", "--object-size"},
      {"simulate", sphere + " --backdrop nan", "--backdrop"},
      {"simulate", sphere + " --backdrop -1", "--backdrop"},
      {"simulate", sphere + " --object-pose 0,0,0,0,0,1e300", "beyond 100 m"},
      {"simulate", sphere + " --defocus 1e5", "defocus_sigma_px must be in [0, 25]"},
      {"simulate", sphere + " --defocus 1e9", "defocus_sigma_px must be in [0, 25]"},
      {"simulate", "simulate --board 5x4x0.04 --views 1000000" + rig, "num_views must be in [1, 1000]"},
      {"objects", "objects --seed -1", "--seed: must be ≥ 0"},
      {"objects", "objects --instances 2000000000", "[1, 1000]"},
      {"build-db", "build-db --models m --views 100000", "[1, 2000]"},
      {"build-db", "build-db --models m --threads 100000", "[0, 256]"},
      {"build-db", "build-db --models m --units furlong", "--units 'furlong': expected auto"},
      {"build-db", "build-db --models m --units 0", "per unit must be in (0, 1000]"},
      {"simulate", sphere + " --units -1", "per unit must be in (0, 1000]"},
      {"simulate", sphere + " --units mm --object-size 0.2", "exclude each other"},
      {"patterns", "patterns --projector 32768x32768", "1..16384"},
      {"patterns", "patterns --projector 16384x16384", "limit"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.arguments);
    ExpectOneLineError(Sope(c.arguments + out, local_), c.command, c.needle);
    EXPECT_FALSE(fs::exists(local_.File("o")));
    EXPECT_EQ(EntriesBesidesCapture(local_.path()), std::vector<std::string>());
  }
}

TEST_F(Cli, SimulateNeverDeletesAUsersFiles) {
  const std::string dir = local_.File("d");
  fs::create_directories(dir);
  WriteFileAtomic(dir + "/notes.txt", "my notes");
  const std::string sphere =
      "simulate --mesh builtin:sphere --rig " + scratch_->File("rig.yaml") + " --supersample 1";
  ExpectOneLineError(Sope(sphere + " --out " + dir, local_), "simulate", "did not write");
  EXPECT_EQ(ReadFileToString(dir + "/notes.txt", "test"), "my notes");
  // An earlier frame set is sope's own: replaced.
  const SopeRun first = Sope(sphere + " --out " + local_.File("again"), local_);
  ASSERT_EQ(first.exit_code, 0) << first.err;
  const SopeRun second = Sope(sphere + " --out " + local_.File("again"), local_);
  EXPECT_EQ(second.exit_code, 0) << second.err;
  EXPECT_TRUE(fs::exists(local_.File("again/frames.json")));
  // decode and objects refuse the user's directory too.
  ExpectOneLineError(Sope("decode --frames " + scratch_->File("scan") + " --out " + dir, local_),
                     "decode", "did not write");
  ExpectOneLineError(Sope("objects --instances 1 --out " + dir, local_), "objects",
                     "did not write");
  EXPECT_EQ(ReadFileToString(dir + "/notes.txt", "test"), "my notes");
}

TEST_F(Cli, ScenesWithNothingLitAreErrors) {
  const std::string base = "simulate --rig " + scratch_->File("rig.yaml") + " --supersample 1";
  const std::string out = " --out " + local_.File("o");
  ExpectOneLineError(Sope(base + " --mesh builtin:sphere --object-pose 0,0,0,0,0,-0.6" + out,
                          local_),
                     "simulate", "no camera pixel");
  ExpectOneLineError(Sope(base + " --mesh builtin:sphere --object-pose 0,0,0,0,0,0" + out, local_),
                     "simulate", "no camera pixel");
  WriteFileAtomic(local_.File("huge.obj"),
                  "v -3e38 -3e38 -3e38\nv 3e38 -3e38 -3e38\nv 3e38 3e38 3e38\nf 1 2 3\n");
  ExpectOneLineError(Sope(base + " --mesh " + local_.File("huge.obj") + out, local_), "simulate",
                     "huge.obj");
  // One triangle seen edge-on.
  WriteFileAtomic(local_.File("tri.obj"), "v 0 0 0\nv 0.1 0 0\nv 0 0 0.1\nf 1 2 3\n");
  ExpectOneLineError(Sope(base + " --mesh " + local_.File("tri.obj") +
                              " --object-pose 0,0,0,0,0,0.6 --object-size 0.1" + out,
                          local_),
                     "simulate", "no camera pixel");
  RigCalibration tiny = SmallRig();
  tiny.camera.width = tiny.camera.height = 1;  // its one pixel looks ≈ 28° off-axis
  WriteRigCalibration(local_.File("tiny.yaml"), tiny);
  ExpectOneLineError(Sope("simulate --mesh builtin:sphere --rig " + local_.File("tiny.yaml") + out,
                          local_),
                     "simulate", "no camera pixel");
  EXPECT_FALSE(fs::exists(local_.File("o")));
  // Asked for, the empty frame set is written.
  const SopeRun allowed =
      Sope(base + " --mesh builtin:sphere --object-pose 0,0,0,0,0,-0.6 --allow-empty" + out,
           local_);
  EXPECT_EQ(allowed.exit_code, 0) << allowed.err;
  EXPECT_TRUE(fs::exists(local_.File("o/frames.json")));
}

TEST_F(Cli, HugeCountsInFilesAreClearErrors) {
  const std::string base = "simulate --rig " + scratch_->File("rig.yaml") + " --out " +
                           local_.File("o") + " --mesh ";
  WriteFileAtomic(local_.File("huge.ply"),
                  "ply\nformat ascii 1.0\nelement vertex 9223372036854775807\n"
                  "property float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n");
  ExpectOneLineError(Sope(base + local_.File("huge.ply"), local_), "simulate",
                     "9223372036854775807 rows");
  WriteFileAtomic(local_.File("huge.off"), "OFF\n1000000000000 1 0\n");
  ExpectOneLineError(Sope(base + local_.File("huge.off"), local_), "simulate",
                     "1000000000000 vertices");
  RigCalibration big = SmallRig();
  WriteRigCalibration(local_.File("big.yaml"), big);
  std::string text = ReadFileToString(local_.File("big.yaml"), "test");
  text.replace(text.find("camera_width: 320"), 17, "camera_width: 999999");
  text.replace(text.find("camera_height: 240"), 18, "camera_height: 999999");
  WriteFileAtomic(local_.File("big.yaml"), text);
  ExpectOneLineError(Sope("simulate --mesh builtin:sphere --rig " + local_.File("big.yaml") +
                              " --out " + local_.File("o"),
                          local_),
                     "simulate", "beyond the limit");
  EXPECT_FALSE(fs::exists(local_.File("o")));
}

TEST_F(Cli, SilentlyWrongFilesAreRefused) {
  std::string scan = CopyOfScan();
  nlohmann::json manifest = nlohmann::json::parse(ReadFileToString(scan + "/frames.json", "t"));
  for (const nlohmann::json& width : {nlohmann::json(4294967616ull), nlohmann::json(320.7),
                                      nlohmann::json(1e30)}) {
    manifest["camera"]["width"] = width;
    WriteFileAtomic(scan + "/frames.json", manifest.dump());
    ExpectOneLineError(Sope("scan --frames " + scan + " --out " + local_.File("c.ply"), local_),
                       "scan", "'width'");
  }
  std::string yaml = ReadFileToString(scratch_->File("rig.yaml"), "test");
  // The camera matrix's bottom row 0 0 1 → 5 7 0.
  const size_t matrix = yaml.find("camera_matrix");
  const size_t data = yaml.find("data", matrix);
  const size_t close = yaml.find(']', data);
  const size_t third_comma = [&] {
    size_t at = close;
    for (int k = 0; k < 3; ++k) at = yaml.rfind(',', at - 1);
    return at;
  }();
  yaml.replace(third_comma + 1, close - third_comma - 1, " 5., 7., 0.");
  WriteFileAtomic(local_.File("row.yaml"), yaml);
  ExpectOneLineError(Sope("scan --frames " + scratch_->File("scan") + " --calibration " +
                              local_.File("row.yaml") + " --out " + local_.File("c.ply"),
                          local_),
                     "scan", "bottom row must be 0 0 1");
  EXPECT_FALSE(fs::exists(local_.File("c.ply")));
}

TEST_F(Cli, CorruptPngGivesOnlySopesLine) {
  const std::string scan = CopyOfScan();
  const std::string png = ReadFileToString(scan + "/frame_07.png", "test");
  WriteFileAtomic(scan + "/frame_07.png", png.substr(0, png.size() / 2));
  for (const char* quiet : {"", " -q"}) {
    SCOPED_TRACE(quiet);
    const SopeRun run =
        Sope("decode" + std::string(quiet) + " --frames " + scan + " --out " + local_.File("m"),
             local_);
    ExpectOneLineError(run, "decode", "frame_07.png");
    EXPECT_EQ(run.err.find("libpng"), std::string::npos) << run.err;
  }
  EXPECT_FALSE(fs::exists(local_.File("m")));
}

TEST_F(Cli, FifoAsAnInputIsRefusedWithoutBlocking) {
  const std::string fifo = local_.File("fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  // `timeout` only guards the suite against the old hang; the run itself is immediate.
  const std::string guard = "timeout -s KILL 120";
  ExpectOneLineError(testing::RunCommand(SOPE_BINARY, "recognise --db " + fifo + " --cloud " +
                                                          fifo, local_, guard),
                     "recognise", "not a regular file");
  ExpectOneLineError(testing::RunCommand(SOPE_BINARY, "simulate --mesh builtin:sphere --rig " +
                                                          fifo + " --out " + local_.File("o"),
                                         local_, guard),
                     "simulate", "not a regular file");
}

// A full disk, imitated by RLIMIT_FSIZE (ulimit -f, SIGXFSZ ignored so that write(2) fails
// with EFBIG): the map directory, the models directory and every temporary are gone.
TEST_F(Cli, FullDiskLeavesNothingPartial) {
  const std::string full = "trap '' XFSZ; ulimit -f 16;";
  SopeRun run = testing::RunCommand(
      SOPE_BINARY, "decode --frames " + scratch_->File("scan") + " --out " + local_.File("maps"),
      local_, full);
  ExpectOneLineError(run, "decode", "maps");
  run = testing::RunCommand(SOPE_BINARY, "objects --instances 2 --out " + local_.File("models"),
                            local_, full);
  ExpectOneLineError(run, "objects", "File too large");
  run = testing::RunCommand(SOPE_BINARY,
                            "simulate --mesh builtin:sphere --rig " + scratch_->File("rig.yaml") +
                                " --supersample 1 --out " + local_.File("sim"),
                            local_, full);
  ExpectOneLineError(run, "simulate", "File too large");
  EXPECT_EQ(EntriesBesidesCapture(local_.path()), std::vector<std::string>());
}

// SIGTERM / SIGINT while a staged directory is being filled: one line, exit 128 + signal,
// nothing left (issue 13 item 4). The signal is sent once the staging directory exists.
struct Interrupted {
  int exit_code = -1;
  std::string err;
  bool saw_staging = false;
};

Interrupted InterruptWhileStaging(const std::vector<std::string>& arguments,
                                  const std::string& directory, const std::string& staged_name,
                                  int signal_number) {
  Interrupted result;
  const std::string err_file = JoinPath(directory, ".stderr");
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int fd = ::open(err_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ::dup2(fd, STDERR_FILENO);
    std::vector<char*> argv = {const_cast<char*>(SOPE_BINARY)};
    for (const std::string& a : arguments) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    ::execv(SOPE_BINARY, argv.data());
    ::_exit(127);
  }
  const std::string prefix = "." + staged_name + ".tmp-";
  int status = 0;
  for (int i = 0; i < 600000 && !result.saw_staging; ++i) {
    for (const auto& entry : fs::directory_iterator(directory)) {
      if (entry.path().filename().string().rfind(prefix, 0) == 0) result.saw_staging = true;
    }
    if (::waitpid(pid, &status, WNOHANG) == pid) return result;  // ended before staging
    if (!result.saw_staging) ::usleep(1000);
  }
  ::kill(pid, signal_number);
  ::waitpid(pid, &status, 0);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  result.err = ReadFileToString(err_file, "stderr");
  return result;
}

TEST_F(Cli, SignalsRemoveStagedOutputs) {
  struct Case {
    std::vector<std::string> arguments;
    std::string command, staged;
    int signal_number;
  };
  const std::string rig = scratch_->File("rig.yaml");
  const std::vector<Case> cases = {
      {{"objects", "--instances", "40", "--out", local_.File("models")}, "objects", "models",
       SIGTERM},
      {{"objects", "--instances", "40", "--out", local_.File("models")}, "objects", "models",
       SIGINT},
      {{"simulate", "--board", "5x4x0.04", "--views", "20", "--rig", rig, "--out",
        local_.File("seq")},
       "simulate", "seq", SIGTERM},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.command + " " + std::to_string(c.signal_number));
    const Interrupted run = InterruptWhileStaging(c.arguments, local_.path(), c.staged,
                                                  c.signal_number);
    ASSERT_TRUE(run.saw_staging) << "the run ended before it staged anything";
    EXPECT_EQ(run.exit_code, 128 + c.signal_number) << run.err;
    EXPECT_EQ(run.err, "sope " + c.command + ": error: interrupted\n");
    EXPECT_EQ(EntriesBesidesCapture(local_.path()), std::vector<std::string>());
  }
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
    if (std::string(name) != "box") {
      EXPECT_GT(silhouette, 320 * 640 / 50);
    }
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
