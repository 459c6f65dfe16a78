#include "core/rig_calibration.h"

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "tests/test_support.h"

namespace sope {
namespace {

RigCalibration TestRig() {
  RigCalibration rig;
  rig.camera.width = 1280;
  rig.camera.height = 720;
  rig.camera.matrix << 1400, 0, 640, 0, 1401, 360, 0, 0, 1;
  rig.camera.distortion = {-0.08, 0.06, 0.001, -0.002, 0.0};
  rig.projector.width = 1024;
  rig.projector.height = 768;
  rig.projector.matrix << 1500, 0, 512, 0, 1500, 384, 0, 0, 1;
  rig.projector.distortion = {-0.01, 0, 0, 0, 0};
  rig.proj_from_cam.rotation = RotationFromEulerXYZ(0.01, -0.3, 0.02);
  rig.proj_from_cam.translation = Eigen::Vector3d(-0.19, 0.001, 0.06);
  rig.rms_camera_px = 0.11;
  return rig;
}

TEST(RigCalibration, YamlRoundTrip) {
  testing::ScratchDir scratch;
  const RigCalibration rig = TestRig();
  WriteRigCalibration(scratch.File("cal.yaml"), rig);
  const RigCalibration read = ReadRigCalibration(scratch.File("cal.yaml"));
  EXPECT_EQ(read.camera.width, 1280);
  EXPECT_EQ(read.projector.height, 768);
  EXPECT_LT((read.camera.matrix - rig.camera.matrix).norm(), 1e-9);
  EXPECT_EQ(read.camera.distortion, rig.camera.distortion);
  EXPECT_LT((read.proj_from_cam.rotation - rig.proj_from_cam.rotation).norm(), 1e-12);
  EXPECT_LT((read.proj_from_cam.translation - rig.proj_from_cam.translation).norm(), 1e-12);
  EXPECT_DOUBLE_EQ(read.rms_camera_px, 0.11);
  EXPECT_NEAR(read.BaselineLength(), rig.proj_from_cam.translation.norm(), 1e-12);
}

TEST(RigCalibration, ReadableByOpenCvFileStorageWithDesignKeys) {
  testing::ScratchDir scratch;
  WriteRigCalibration(scratch.File("cal.yaml"), TestRig());
  cv::FileStorage fs(scratch.File("cal.yaml"), cv::FileStorage::READ);
  ASSERT_TRUE(fs.isOpened());
  for (const char* key : {"camera_width", "camera_height", "camera_matrix", "camera_distortion",
                          "projector_width", "projector_height", "projector_matrix",
                          "projector_distortion", "proj_from_cam_rotation",
                          "proj_from_cam_translation", "rms_camera_px", "rms_projector_px",
                          "rms_stereo_px"}) {
    EXPECT_FALSE(fs[key].empty()) << key;
  }
  cv::Mat translation;
  fs["proj_from_cam_translation"] >> translation;
  EXPECT_EQ(translation.rows, 3);
  EXPECT_EQ(translation.cols, 1);
}

TEST(RigCalibration, MalformedFilesNameTheProblem) {
  testing::ScratchDir scratch;
  WriteRigCalibration(scratch.File("good.yaml"), TestRig());
  const std::string good = ReadFileToString(scratch.File("good.yaml"), "test");
  auto error_for = [&](const std::string& text) -> std::string {
    WriteFileAtomic(scratch.File("bad.yaml"), text);
    try {
      ReadRigCalibration(scratch.File("bad.yaml"));
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_NE(error_for("%YAML:1.0\ncamera_width: 10\n").find("'camera_height'"),
            std::string::npos);
  EXPECT_NE(error_for("%YAML:1.0\ncamera_width: 10\ncamera_height: 10\n").find("missing key"),
            std::string::npos);
  std::string text = good;
  text.replace(text.find("camera_width: 1280"), 18, "camera_width: -3");
  EXPECT_NE(error_for(text).find("camera_width"), std::string::npos);
  EXPECT_NE(error_for("this: [is not: yaml").find("bad.yaml"), std::string::npos);
  EXPECT_NE(error_for("").find("bad.yaml"), std::string::npos);
  RigCalibration rig = TestRig();
  rig.proj_from_cam.rotation(0, 0) = 3.0;
  EXPECT_THROW_WITH_MESSAGE(WriteRigCalibration(scratch.File("x.yaml"), rig), Error,
                            "proj_from_cam_rotation", "det = 2.95");
  EXPECT_THROW_WITH_MESSAGE(ReadRigCalibration(scratch.File("missing.yaml")), Error, "missing.yaml",
                            "no such file");
}

}  // namespace
}  // namespace sope
