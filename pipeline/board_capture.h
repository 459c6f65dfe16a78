// Live capture of calibration views (`sope calibrate --camera`): one pattern sequence
// (white, black, Gray code in x and y with inverses) per board pose, each recorded as a
// frame set `record/view_NNN` (atomically, RigSession::Record), ready for RigCalibrator.
// A real camera captures a pose whenever the caller says the board is ready; the virtual
// rig has no board to hold up, so the poses are scripted like `sope simulate --board`
// (its true calibration is written to record/calibration_true.yaml).
#pragma once

#include <atomic>
#include <functional>
#include <string>
#include <vector>

#include "calibration/board.h"
#include "core/rig_calibration.h"
#include "pipeline/live_rig.h"
#include "pipeline/scan_source.h"

namespace sope {

struct BoardCaptureOptions {
  std::string spec;            // "/dev/videoN" or "virtual"
  RigCalibration sizes;        // camera and projector sizes (the rest unused); "virtual":
                               // the virtual rig's true calibration
  BoardSpec board;
  std::string record_directory;
  int virtual_views = 12;      // "virtual": scripted board poses
  LiveRigOptions rig;
  RigSessionOptions session;   // its `cancel` stops the capture ("interrupted")
  void Check() const;
};

// Before pose `index` (`captured` so far) of a real camera: true when the board is held
// still in view, false to finish.
using BoardPoseReady = std::function<bool(int index, int captured)>;

// Captures the views; returns their directories in order. Throws sope::Error (a lost
// camera, cancellation: the view under way is not left behind).
std::vector<std::string> CaptureBoardViews(const BoardCaptureOptions& options,
                                           const BoardPoseReady& ready,
                                           const std::function<void(int index)>& on_pose = {},
                                           const CaptureProgress& progress = {});

}  // namespace sope
