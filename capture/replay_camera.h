// A recorded frame set played back as a camera: frames in order, as if live, so a rig
// session (and everything above it) runs unchanged on a recording.
#pragma once

#include <string>

#include "capture/camera.h"
#include "core/frame_set.h"

namespace sope {

class ReplayCamera : public Camera {
 public:
  // Loads the frame set (LoadFrameSet: throws sope::Error on a missing or bad set).
  explicit ReplayCamera(const std::string& directory);
  // Plays an in-memory set; `source` names it in messages.
  ReplayCamera(FrameSet frames, const std::string& source);

  // Frame i on the i-th call. Its exposure_start is max(not_before, previous + period) on a
  // simulated clock, so stale-frame logic upstream behaves as with a camera. Throws
  // sope::Error when all frames were delivered (exhausted) or when `request.showing`
  // differs from the role/axis/code/bit/inverse the frame was recorded with (mismatched).
  Frame Grab(const GrabRequest& request) override;
  int width() const override { return frames_.manifest.camera_width; }
  int height() const override { return frames_.manifest.camera_height; }
  double Now() const override { return now_; }
  double frame_period() const override { return kFramePeriod; }
  bool live() const override { return false; }
  std::string name() const override { return "replay:" + source_; }
  std::string description() const override;

  const FrameSet& frames() const { return frames_; }
  size_t delivered() const { return next_; }

  // Nominal frame period of the simulated clock, seconds.
  static constexpr double kFramePeriod = 1.0 / 30.0;

 private:
  FrameSet frames_;
  std::string source_;
  size_t next_ = 0;
  double now_ = 0.0;
};

// Whether a recorded frame matches what is shown: same role and, for codes, the same axis,
// code, bit count, bit and inverse. `why` (optional) gets a description of the difference.
bool SameFrameInfo(const FrameInfo& recorded, const FrameInfo& shown, std::string* why = nullptr);
// "white", "black", "code x gray bit 7/10 inverted".
std::string DescribeFrameInfo(const FrameInfo& info);

}  // namespace sope
