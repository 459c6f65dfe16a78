#include "simulator/simulate_scan.h"

#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/json.h"

namespace sope {
namespace {

constexpr const char* kCalibrationFile = "calibration.yaml";

}  // namespace

SimulatedScan SimulateScan(VirtualRig& rig, const Scene& scene,
                           const PatternOptions& patterns) {
  const RigCalibration& calibration = rig.calibration();
  SOPE_CHECK(patterns.projector_width == calibration.projector.width &&
                 patterns.projector_height == calibration.projector.height,
             "patterns are for a {}x{} projector but the rig's projector is {}x{}",
             patterns.projector_width, patterns.projector_height, calibration.projector.width,
             calibration.projector.height);
  SimulatedScan scan;
  scan.calibration = calibration;
  scan.scene = scene;
  rig.SetScene(scene);
  scan.ground_truth = rig.ground_truth();
  scan.frames.manifest =
      MakePatternManifest(patterns, calibration.camera.width, calibration.camera.height);
  scan.frames.manifest.calibration = kCalibrationFile;
  for (const Pattern& pattern : GeneratePatterns(patterns)) {
    scan.frames.images.push_back(rig.Capture(pattern.image));
  }
  scan.frames.Check();
  return scan;
}

void WriteSimulatedScan(const std::string& directory, const SimulatedScan& scan) {
  WriteSimulatedScan(directory, scan, SimulatedScanExtras());
}

void WriteSimulatedScan(const std::string& directory, const SimulatedScan& scan,
                        const SimulatedScanExtras& extras) {
  StagedDirectory staged(directory, FrameSetManifest::kFileName);
  const std::string& out = staged.path();
  WriteFrameSetFiles(out, scan.frames);
  WriteRigCalibration(JoinPath(out, kCalibrationFile), scan.calibration);
  const GroundTruth& truth = scan.ground_truth;
  WriteImageAtomic(JoinPath(out, "gt_depth.exr"), truth.depth);
  WriteImageAtomic(JoinPath(out, "gt_proj_x.exr"), truth.proj_x);
  WriteImageAtomic(JoinPath(out, "gt_proj_y.exr"), truth.proj_y);
  WriteImageAtomic(JoinPath(out, "gt_lit.png"), truth.lit);
  cv::Mat object_id;
  truth.object_id.convertTo(object_id, CV_16UC1, 1.0, 1.0);
  WriteImageAtomic(JoinPath(out, "gt_object_id.png"), object_id);
  for (const auto& [name, image] : extras.images) WriteImageAtomic(JoinPath(out, name), image);
  if (!extras.gt_pose_json.empty()) {
    WriteFileAtomic(JoinPath(out, "gt_pose.json"), extras.gt_pose_json);
    staged.Commit();
    return;
  }
  nlohmann::json objects = nlohmann::json::array();
  for (const SceneObject& object : scan.scene.objects) {
    objects.push_back({{"cam_from_model", Rigid3dToJson(object.cam_from_model)},
                       {"albedo", object.albedo}});
  }
  WriteFileAtomic(JoinPath(out, "gt_pose.json"),
                  nlohmann::json({{"format", "sope-gt-pose/1"},
                                  {"units", "metres; rotation maps model to camera"},
                                  {"objects", objects}})
                          .dump(2) +
                      "\n");
  staged.Commit();
}

GroundTruth ReadGroundTruth(const std::string& directory) {
  GroundTruth truth;
  truth.depth = ReadImage(JoinPath(directory, "gt_depth.exr"));
  truth.proj_x = ReadImage(JoinPath(directory, "gt_proj_x.exr"));
  truth.proj_y = ReadImage(JoinPath(directory, "gt_proj_y.exr"));
  truth.lit = ReadImage(JoinPath(directory, "gt_lit.png"), 0);
  const cv::Mat object_id = ReadImage(JoinPath(directory, "gt_object_id.png"));
  object_id.convertTo(truth.object_id, CV_32SC1, 1.0, -1.0);
  SOPE_CHECK(truth.depth.type() == CV_32FC1 && truth.proj_x.type() == CV_32FC1 &&
                 truth.proj_y.type() == CV_32FC1 && truth.depth.size() == truth.lit.size() &&
                 truth.depth.size() == truth.object_id.size(),
             "ground truth in {} has inconsistent types or sizes", directory);
  return truth;
}

}  // namespace sope
