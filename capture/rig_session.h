// A rig session: show pattern i on the projector, wait until it is on the camera's sensor,
// grab frame i — for a whole pattern sequence, into a frame set. It does not decode; it
// only produces FrameSets (in memory, or recorded atomically to a directory so any live
// scan can be replayed with `--frames`).
//
// Synchronisation. Frames carry the start time of their exposure on the camera's clock.
// After Show() returns at time t_show, a frame shows the new pattern only if its exposure
// started at or after t_show + L, where L, the projector→camera latency, adds up the
// display pipeline (swap, scan-out, the projector's processing) and the offset of the
// camera's timestamps. The session asks the camera for the first frame exposed after
// t_show + L + settle, dropping older (stale) frames. L is measured by flashing: the
// projector alternates black and white and, for every transition, the first frame whose
// mean brightness has moved most of the way to the new level gives an upper bound of L;
// the median of these bounds is robust to a misread frame and still ≥ L when the bounds
// are (every bound is ≥ L by construction, so a frame deemed fresh really is).
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "capture/camera.h"
#include "core/frame_set.h"
#include "core/rig_calibration.h"
#include "projector/display.h"
#include "projector/patterns.h"

namespace sope {

struct RigSessionOptions {
  // Projector→camera latency, seconds (see above); < 0: measure it by flashing before the
  // first capture.
  double latency = -1.0;
  // Extra wait on top of the latency before a frame counts, seconds: a margin for slow
  // projector response or rolling shutters whose last rows start later.
  double settle = 0.0;
  // Black↔white transitions timed by the latency measurement.
  int latency_flashes = 6;
  // Longest latency accepted, seconds: a transition not seen by then is an error (the
  // camera does not see the projector, or the exposure is far too long).
  double max_latency = 1.0;
  // Minimum white−black difference for a camera pixel to count as lit by the projector,
  // grey levels; fewer than min_lit_fraction of such pixels is an error.
  double min_flash_contrast = 10.0;
  double min_lit_fraction = 0.001;
  // A frame shows a transition when the mean of the lit pixels has moved this fraction of
  // the way from the old level to the new one.
  double transition_fraction = 0.75;
  // How long a frame may take beyond latency + settle, seconds, before it is an error.
  double grab_timeout = 2.0;
  // Checked before every frame; when it becomes true the capture stops with sope::Error
  // ("interrupted") — and a recording leaves nothing behind. May be null.
  const std::atomic<bool>* cancel = nullptr;

  // Throws sope::Error naming the invalid value.
  void Check() const;
};

struct LatencyMeasurement {
  // Median of `samples`, seconds; 0 for a camera that is not live.
  double latency = 0.0;
  // Per transition: exposure start of the first frame showing it − Show() return, seconds.
  std::vector<double> samples;
  // Mean grey level of the lit pixels with the projector black and white.
  double black_level = 0.0;
  double white_level = 0.0;
  // Fraction of camera pixels the projector lights (white − black ≥ min_flash_contrast).
  double lit_fraction = 0.0;
  // The camera's nominal frame period, seconds (0 unknown).
  double frame_period = 0.0;

  // Latency in frame periods (0 when the period is unknown).
  double frames() const { return frame_period > 0.0 ? latency / frame_period : 0.0; }
  // "latency 68.2 ms (2.05 frames; 6 transitions 66.7–70.1 ms), black 21 / white 187".
  std::string Summary() const;
};

// When each frame of the last capture was shown and exposed (camera clock, seconds).
struct FrameTiming {
  double shown = 0.0;           // Display::Show() returned
  double exposure_start = 0.0;  // of the frame kept
  uint64_t sequence = 0;        // camera frame counter
};

class RigSession {
 public:
  // (done, total) after each frame.
  using Progress = std::function<void(size_t done, size_t total)>;

  // The display and camera must outlive the session. Throws sope::Error on invalid
  // options.
  RigSession(Display& display, Camera& camera, const RigSessionOptions& options = {});

  // Measures the latency by flashing (for a camera that is not live, sets 0 without
  // flashing) and keeps it for the captures that follow. Throws sope::Error when the
  // camera does not see the projector, a transition is not seen within max_latency, or a
  // grab fails.
  const LatencyMeasurement& MeasureLatency();
  // The latency in use, seconds: options.latency if given, else measured (now, if not yet).
  double latency();
  const LatencyMeasurement& latency_measurement() const { return measurement_; }

  // Shows every pattern and grabs its frame. The manifest lists the patterns' frame infos
  // and file names, with the camera's size and the display's size as projector size.
  // Throws sope::Error on a pattern of the wrong size, a timeout, a lost camera, a replay
  // that does not match, or cancellation.
  FrameSet Capture(const std::vector<Pattern>& patterns, const Progress& progress = {});
  // The same, writing each frame as it arrives into a staged directory that appears at
  // `directory` only when the whole set is there (StagedDirectory): an error or
  // interruption leaves nothing at `directory`. With `calibration`, it is saved as
  // calibration.yaml and named in frames.json, so `sope scan --frames DIR` needs nothing
  // else. capture.json records the camera, the latency and every frame's timing.
  FrameSet Record(const std::vector<Pattern>& patterns, const std::string& directory,
                  const RigCalibration* calibration = nullptr, const Progress& progress = {});

  // Timing of the frames of the last Capture/Record.
  const std::vector<FrameTiming>& timings() const { return timings_; }

  // Called with every frame as soon as it is grabbed (Capture and Record), with the
  // manifest of the set being captured and the image the frame set keeps (not to be
  // written into): the live loop decodes while the rest is still being captured
  // (IncrementalDecoder). An exception from it ends the capture. Empty: none.
  using FrameSink =
      std::function<void(const FrameSetManifest& manifest, size_t index, const cv::Mat& image)>;
  void SetFrameSink(FrameSink sink) { frame_sink_ = std::move(sink); }

 private:
  // Shows `image` and returns the first frame exposed after it reached the sensor.
  Frame ShowAndGrab(const cv::Mat& image, const FrameInfo* info, double wait, double* shown);
  FrameSet CaptureInto(const std::vector<Pattern>& patterns, const std::string& staging,
                       const Progress& progress);
  void CheckCancelled() const;

  Display& display_;
  Camera& camera_;
  RigSessionOptions options_;
  LatencyMeasurement measurement_;
  bool have_latency_ = false;
  std::vector<FrameTiming> timings_;
  FrameSink frame_sink_;
};

// The manifest of `patterns` captured by a camera of the given size, projector size from
// the patterns. Throws sope::Error when the patterns are empty or of mixed sizes.
FrameSetManifest ManifestForPatterns(const std::vector<Pattern>& patterns, int camera_width,
                                     int camera_height);

}  // namespace sope
