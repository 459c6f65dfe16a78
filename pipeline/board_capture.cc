#include "pipeline/board_capture.h"

#include <spdlog/spdlog.h>

#include "capture/rig_session.h"
#include "core/error.h"
#include "core/file_util.h"
#include "simulator/board_sequence.h"

namespace sope {

void BoardCaptureOptions::Check() const {
  SOPE_CHECK(!spec.empty(), "board capture: no camera given");
  SOPE_CHECK(!record_directory.empty(), "board capture: no directory to record the views in");
  SOPE_CHECK(virtual_views >= 3, "board capture: at least 3 scripted views, got {}",
             virtual_views);
  rig.Check();
  session.Check();
}

std::vector<std::string> CaptureBoardViews(const BoardCaptureOptions& options,
                                           const BoardPoseReady& ready,
                                           const std::function<void(int index)>& on_pose,
                                           const CaptureProgress& progress) {
  options.Check();
  const bool is_virtual = options.spec == "virtual";
  SOPE_CHECK(is_virtual || ready, "board capture: a live camera needs a pose-ready callback");
  LiveRig rig = OpenLiveRig(options.spec, options.sizes, options.rig);
  RigSession session(rig.GetDisplay(), rig.GetCamera(), options.session);
  PatternOptions patterns;  // white, black, Gray code in x and y with inverses
  patterns.projector_width = options.sizes.projector.width;
  patterns.projector_height = options.sizes.projector.height;
  const std::vector<Pattern> sequence = GeneratePatterns(patterns);
  std::vector<Rigid3d> poses;
  BoardSequenceOptions board_options;
  if (is_virtual) {
    board_options.num_views = options.virtual_views;
    poses = SampleBoardPoses(options.sizes, options.board, board_options);
    WriteRigCalibration(JoinPath(options.record_directory, "calibration_true.yaml"),
                        options.sizes);
    spdlog::info("virtual rig: no board to hold up; {} scripted board poses", poses.size());
  }
  std::vector<std::string> directories;
  for (int index = 0;; ++index) {
    if (is_virtual) {
      if (index >= static_cast<int>(poses.size())) break;
      Scene scene;
      scene.objects.push_back(MakeCheckerboardObject(options.board, poses[index], board_options));
      rig.virtual_rig.rig->SetScene(scene);
    } else if (!ready(index, static_cast<int>(directories.size()))) {
      break;
    }
    SOPE_CHECK(!(options.session.cancel && options.session.cancel->load()), "interrupted");
    if (on_pose) on_pose(index);
    const std::string directory = JoinPath(options.record_directory, BoardViewName(index));
    session.Record(sequence, directory, nullptr,
                   progress ? RigSession::Progress(progress) : RigSession::Progress());
    directories.push_back(directory);
    spdlog::info("pose {} -> {}", index, directory);
  }
  return directories;
}

}  // namespace sope
