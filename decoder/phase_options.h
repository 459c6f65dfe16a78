// Options of the phase-shift decoder (decoder/phase_decoder.h), part of DecoderOptions.
#pragma once

#include "core/projector_response.h"

namespace sope {

struct PhaseDecoderOptions {
  // Minimum modulation B of every phase group (the amplitude of the fitted sinusoid
  // I = A + B·cos(φ − s)), grey levels on an 8-bit scale (16-bit images: ×257). Weaker
  // pixels are shadow, off the projector or too dark to decode. B = (white − black) / 2
  // for a full-contrast sinusoid, so 5 matches DecoderOptions::min_contrast = 10.
  double min_modulation = 5.0;
  // Temporal unwrapping check: a pixel whose coordinate from the coarser group (or the Gray
  // code) and its unwrapped finer coordinate differ by more than this fraction of the finer
  // period is invalid, not guessed. An unwrapping error is a whole period; at 16× period
  // ratios realistic noise moves the coarse coordinate by several percent of the fine
  // period (1024 → 64 at modulation / noise = 20: σ ≈ 0.09 periods, the check at 3.9 σ).
  double max_unwrap_error = 0.35;
  // Noise of one sample, grey levels (8-bit scale), when the fit has no redundancy
  // (3 shifts per group), and the floor of the per-pixel estimate otherwise; the
  // confidence is modulation / noise.
  double noise_floor = 1.0;
  // Edge-preserving local fit of the decoded coordinates (noise reduction): each valid
  // pixel's coordinate on every phase axis becomes the centre value of the least-squares
  // plane u = a + b·dx + c·dy through the valid pixels of its (2r + 1)² window that lie on
  // its surface — a neighbour more than the tolerance (local_fit_tolerance_px, or 4
  // standard deviations of the pixel's coordinate noise from its confidence when that is
  // more) from the pixel's value
  // extrapolated by its slopes (per axis the smaller one-sided difference, 0 when they
  // differ in sign: a step beside the pixel does not tilt it) is dropped, then any whose
  // residual from the fit exceeds the tolerance, and the plane is refitted
  // (coordinate steps above the tolerance, i.e. depth and code discontinuities, are not
  // averaged across; a period-jump pixel keeps its value and its neighbours theirs). Fewer than
  // 2r + 3 samples left: the pixel keeps its own value. The per-pixel phase noise is
  // independent between pixels while the surface's coordinate is smooth, so a 3×3 window
  // divides its standard deviation by up to 3 on plane patches; a plane through a curved
  // patch is biased by ≈ (u_xx + u_yy)·r(r + 1)/6. 0: off.
  int local_fit_radius = 1;
  double local_fit_tolerance_px = 0.5;
  // The rig's projector → camera response (calibrate-gamma); the phase of every group is
  // corrected for the harmonics it adds (gamma ripple). Identity: no correction (linear
  // rig, or patterns pre-distorted with PatternOptions::precompensate).
  ProjectorResponse response;
  // Scans (calibration/scan.h): take `response` from the rig calibration's
  // projector_response when `response` is the identity. Off for patterns that were
  // pre-distorted with the measured response (they would be corrected twice).
  bool use_calibration_response = true;

  // Throws sope::Error naming an invalid value.
  void Check() const;
};

}  // namespace sope
