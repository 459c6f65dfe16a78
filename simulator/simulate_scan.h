// Whole simulated scans: a pattern sequence captured by the virtual rig, as a frame set
// plus ground truth, and its files (`sope simulate`).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "core/frame_set.h"
#include "core/rig_calibration.h"
#include "projector/patterns.h"
#include "simulator/virtual_rig.h"

namespace sope {

struct SimulatedScan {
  FrameSet frames;           // the captures, manifest included
  GroundTruth ground_truth;  // per camera pixel
  RigCalibration calibration;
  Scene scene;
};

// Renders every pattern of `patterns` (projector size taken from the rig) on `scene`.
// Throws sope::Error when the pattern projector size differs from the rig's projector.
SimulatedScan SimulateScan(VirtualRig& rig, const Scene& scene,
                           const PatternOptions& patterns);

// Writes a simulated scan atomically as a directory: the frame set (PNG + frames.json
// naming calibration.yaml), calibration.yaml (the true rig), gt_depth.exr, gt_proj_x.exr,
// gt_proj_y.exr, gt_lit.png, gt_object_id.png (16-bit, 0 = none, i+1 = object i) and
// gt_pose.json (cam_from_model of every object: rotation 3×3, translation in metres).
void WriteSimulatedScan(const std::string& directory, const SimulatedScan& scan);

// What a scene adds to the files above (table scenes: simulator/table_scene.h).
struct SimulatedScanExtras {
  std::string gt_pose_json;  // replaces gt_pose.json's contents when not empty
  std::vector<std::pair<std::string, cv::Mat>> images;  // file name → image, written too
};
void WriteSimulatedScan(const std::string& directory, const SimulatedScan& scan,
                        const SimulatedScanExtras& extras);

// Ground truth read back from a directory WriteSimulatedScan wrote (depth, projector
// coordinates, lit mask, object ids). Throws sope::Error naming a missing file.
GroundTruth ReadGroundTruth(const std::string& directory);

}  // namespace sope
