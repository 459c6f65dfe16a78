#include "capture/replay_camera.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "core/error.h"

namespace sope {

std::string DescribeFrameInfo(const FrameInfo& info) {
  if (info.role == FrameRole::kPhase) {
    return fmt::format("phase {} period {} shift {}", ToString(info.axis), info.period,
                       info.shift);
  }
  if (info.role != FrameRole::kCode) return ToString(info.role);
  return fmt::format("code {} {} bit {}/{}{}", ToString(info.axis), ToString(info.code), info.bit,
                     info.bits, info.inverted ? " inverted" : "");
}

bool SameFrameInfo(const FrameInfo& recorded, const FrameInfo& shown, std::string* why) {
  bool same = recorded.role == shown.role;
  if (same && recorded.role == FrameRole::kCode) {
    same = recorded.axis == shown.axis && recorded.code == shown.code &&
           recorded.bits == shown.bits && recorded.bit == shown.bit &&
           recorded.inverted == shown.inverted;
  }
  if (same && recorded.role == FrameRole::kPhase) {
    same = recorded.axis == shown.axis && recorded.period == shown.period &&
           recorded.shift == shown.shift;
  }
  if (!same && why) {
    *why = fmt::format("recorded {} but the projector shows {}", DescribeFrameInfo(recorded),
                       DescribeFrameInfo(shown));
  }
  return same;
}

ReplayCamera::ReplayCamera(const std::string& directory)
    : ReplayCamera(LoadFrameSet(directory), directory) {}

ReplayCamera::ReplayCamera(FrameSet frames, const std::string& source)
    : frames_(std::move(frames)), source_(source) {
  frames_.Check();
}

Frame ReplayCamera::Grab(const GrabRequest& request) {
  SOPE_CHECK(next_ < frames_.images.size(),
             "replay {}: exhausted — all {} recorded frames were delivered and another was "
             "asked for (was it recorded with a different pattern sequence?)",
             source_, frames_.images.size());
  const FrameInfo& recorded = frames_.manifest.frames[next_];
  std::string why;
  SOPE_CHECK(!request.showing || SameFrameInfo(recorded, *request.showing, &why),
             "replay {}: frame {} ({}) does not match the pattern sequence: {}", source_, next_,
             recorded.file, why);
  Frame frame;
  frame.image = frames_.images[next_];
  if (request.want_color && recorded.role == FrameRole::kWhite) frame.color = frames_.white_color;
  const double earliest = now_;  // the previous frame's end
  frame.exposure_start =
      std::isfinite(request.not_before) ? std::max(earliest, request.not_before) : earliest;
  frame.sequence = next_;
  now_ = frame.exposure_start + kFramePeriod;  // "read out" one period later
  ++next_;
  return frame;
}

std::string ReplayCamera::description() const {
  return fmt::format("{} ({} frames, {}x{})", name(), frames_.images.size(), width(), height());
}

}  // namespace sope
