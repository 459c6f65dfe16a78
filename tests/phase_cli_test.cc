// `sope` on phase-shift sets (issue 10): patterns, simulate, calibrate-gamma, decode and
// scan as a user runs them, and one clear error line for each kind of bad phase input.
#include <filesystem>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/file_util.h"
#include "core/frame_set.h"
#include "core/point_cloud.h"
#include "core/rig_calibration.h"
#include "tests/test_support.h"

namespace sope {
namespace {
namespace fs = std::filesystem;

testing::CommandRun Sope(const std::string& arguments, const testing::ScratchDir& scratch) {
  return testing::RunCommand(SOPE_BINARY, arguments, scratch);
}

TEST(PhaseCli, PatternsFollowTheContract) {
  testing::ScratchDir scratch;
  testing::CommandRun run = Sope("patterns --projector 1024x768 --code phase --periods "
                                 "1024,64,8 --steps 4 --out " + scratch.File("phase"), scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const FrameSetManifest phase = ReadFrameSetManifest(scratch.File("phase"));
  EXPECT_EQ(phase.frames.size(), 2u + 24u);  // white, black, 3 periods × 4 shifts × 2 axes
  EXPECT_EQ(phase.PhaseGroups(PatternAxis::kX).size(), 3u);
  EXPECT_EQ(phase.PhaseGroups(PatternAxis::kY).back().period, 8.0);
  run = Sope("patterns --projector 1000x700 --axes x --code gray+phase --period 16 --steps 4 "
             "--out " + scratch.File("hybrid"), scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const FrameSetManifest hybrid = ReadFrameSetManifest(scratch.File("hybrid"));
  EXPECT_EQ(hybrid.AxisLowestBit(PatternAxis::kX), 3);  // 16 px blocks + complementary bit
  EXPECT_EQ(hybrid.PhaseGroups(PatternAxis::kX).size(), 1u);
}

TEST(PhaseCli, BadPhaseInputGivesOneErrorLine) {
  testing::ScratchDir scratch;
  testing::ExpectOneLineError(
      Sope("patterns --projector 1024x768 --code phase --periods 512,64 --out " +
               scratch.File("a"), scratch),
      "patterns", "coarsest phase period 512");
  testing::ExpectOneLineError(
      Sope("patterns --projector 1024x768 --code phase --periods 1024,0 --out " +
               scratch.File("b"), scratch),
      "patterns", "phase period 0");
  testing::ExpectOneLineError(
      Sope("patterns --projector 1024x768 --code phase --steps 2 --out " + scratch.File("c"),
           scratch),
      "patterns", "phase steps 2");
  testing::ExpectOneLineError(
      Sope("patterns --projector 1024x768 --code gray+phase --period 12 --out " +
               scratch.File("d"), scratch),
      "patterns", "gray+phase period 12");
  EXPECT_FALSE(fs::exists(scratch.File("a")));
  // Frame sets that do not decode: written as patterns, then the manifest damaged.
  ASSERT_EQ(Sope("patterns --projector 64x48 --axes x --code phase --periods 64,8 --steps 3 "
                 "--out " + scratch.File("set"), scratch).exit_code, 0);
  const std::string manifest_path = scratch.File("set/frames.json");
  const nlohmann::json good = nlohmann::json::parse(ReadFileToString(manifest_path, "test"));
  const auto decode_with = [&](const nlohmann::json& manifest, const std::string& needle) {
    WriteFileAtomic(manifest_path, manifest.dump(2));
    testing::ExpectOneLineError(
        Sope("decode --frames " + scratch.File("set") + " --out " + scratch.File("maps"), scratch),
        "decode", needle);
    EXPECT_FALSE(fs::exists(scratch.File("maps")));
  };
  nlohmann::json bad = good;
  bad["frames"][4]["shift"] = bad["frames"][3]["shift"];  // period 64 (frames 2..4): 2 shifts
  decode_with(bad, "2 distinct shifts");
  bad = good;
  bad["frames"][6]["period"] = -8.0;
  decode_with(bad, "phase period -8");
  bad = good;
  for (int k = 0; k < 3; ++k) bad["frames"].erase(2);  // the absolute group
  decode_with(bad, "no coarser group or Gray code to unwrap it");
  bad = good;
  for (int bit : {5, 4}) {  // Gray blocks of 16 px under a coarsest period of 64
    const std::string file = "gray_" + std::to_string(bit) + ".png";
    fs::copy_file(scratch.File("set/frame_00.png"), scratch.File("set/" + file),
                  fs::copy_options::overwrite_existing);
    bad["frames"].push_back({{"file", file},
                             {"role", "code"}, {"axis", "x"}, {"code", "gray"}, {"bits", 6},
                             {"bit", bit}, {"inverted", false}});
  }
  decode_with(bad, "Gray code's finest stripe is 16 px but the coarsest phase period is 64");
}

TEST(PhaseCli, SimulateCalibrateGammaDecodeScan) {
  testing::ScratchDir scratch;
  WriteRigCalibration(scratch.File("rig.yaml"), testing::SmallRig());
  testing::CommandRun run = Sope(
      "simulate --mesh builtin:sphere --object-size 0.15 --backdrop 0.75 --rig " +
          scratch.File("rig.yaml") + " --code phase --periods 256,32,8 --steps 4 "
          "--no-white-black --projector-gamma 2.2 --camera-gamma 1 --supersample 2 --out " +
          scratch.File("scan"), scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  run = Sope("calibrate-gamma --virtual --projector-gamma 2.2 --camera-gamma 1 --calibration " +
                 scratch.File("rig.yaml") + " --out " + scratch.File("gamma.yaml"), scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const RigCalibration gamma = ReadRigCalibration(scratch.File("gamma.yaml"));
  ASSERT_FALSE(gamma.projector_response.IsIdentity());
  EXPECT_NEAR(gamma.projector_response.Apply(0.5), 0.218, 0.02);  // 0.5^2.2
  run = Sope("decode --frames " + scratch.File("scan") + " --calibration " +
                 scratch.File("gamma.yaml") + " --out " + scratch.File("maps"), scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  for (const char* file : {"proj_x.exr", "proj_y.png", "mask.png", "phase_x.png", "phase_y.exr",
                           "modulation.png", "texture.png", "correspondence.json"}) {
    EXPECT_TRUE(fs::exists(scratch.File("maps/") + file)) << file;
  }
  run = Sope("scan --frames " + scratch.File("scan") + " --calibration " +
                 scratch.File("gamma.yaml") + " --out " + scratch.File("cloud.ply"), scratch);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const PointCloud cloud = ReadPointCloud(scratch.File("cloud.ply"));
  EXPECT_GT(cloud.size(), 20000u);
  EXPECT_TRUE(cloud.HasColors());  // from the synthesised texture: no white frame
  testing::ExpectOneLineError(
      Sope("calibrate-gamma --virtual --levels 2 --out " + scratch.File("x.yaml"), scratch),
      "calibrate-gamma", "ramp levels 2");
}

}  // namespace
}  // namespace sope
