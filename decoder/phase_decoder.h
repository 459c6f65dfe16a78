// Phase-shift decoding (frame role `phase`, DESIGN.md "Frame set"): per-pixel least-squares
// phase, hierarchical temporal unwrapping, Gray code + phase, sub-pixel correspondences.
//
// Each group (axis, period) of N ≥ 3 frames with shifts s_k is fitted per pixel by linear
// least squares, I_k = A + B·cos(φ − s_k) = A + C·cos s_k + S·sin s_k, φ = atan2(S, C),
// B = √(C² + S²): the normal matrix of [1, cos s_k, sin s_k] is inverted once per group,
// any shifts (not a fixed 3- or 4-step formula; Servin, Quiroga & Padilla, "Fringe
// Pattern Analysis for Optical Metrology", ch. 2). φ = 2π·u/period at projector coordinate
// u (pixel centres at integers).
//
// Unwrapping (temporal, hierarchical; Huntley & Saldner 1993, Zuo et al. 2016 "Temporal
// phase unwrapping algorithms for fringe projection profilometry"): the coarsest group is
// absolute (period ≥ the projector size), or is unwrapped by a Gray code one period wide;
// every finer group takes the period index k = round((u_coarse − f·P)/P) from the group
// before it, f = φ/2π. A pixel whose coarse and unwrapped fine coordinates differ by more
// than PhaseDecoderOptions::max_unwrap_error periods is invalid, not guessed.
//
// Gray + phase: the Gray code's period index is wrong by one near its stripe edges, which
// coincide with the phase wrap (the classic spikes). With the complementary bit half a
// period wide (Zhang et al. 2019, "High-speed high dynamic range 3D shape measurement based
// on deep learning", and SLMaster's SinusCompleGrayCode): near the wrap (f < ¼, f > ¾) the
// index comes from the half-period code, whose edges lie mid-period. Without it, the phase
// says the pixel is near an edge (f < ¼: just after one, f > ¾: just before one) and the
// Gray bit that changes at the neighbouring edge says whether the Gray code put the pixel
// on its wrong side: that bit's pattern/inverse margin is then small against the pixel's
// contrast, and the period index moves by one.
//
// Gamma: a non-linear projector response R bends the sinusoids; the N-step phase then has
// a periodic error at N× the phase. With the rig's measured response the decoder inverts
// the error through a table per group (the phase of samples α·R(I(φ − s_k)) + β does not
// depend on the pixel's α, β).
#pragma once

#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "core/frame_set.h"
#include "decoder/decoder.h"

namespace sope {

// Per-pixel images of a phase decode beside the correspondence map.
struct PhaseDecodeImages {
  // Wrapped phase of each axis's finest group, radians in [0, 2π), CV_32FC1; NaN where the
  // pixel is too dark; empty when the axis has no phase frames.
  cv::Mat wrapped_phase_x;
  cv::Mat wrapped_phase_y;
  // Weakest modulation B over all groups, grey levels (8-bit scale), CV_32FC1.
  cv::Mat modulation;
  // A + B of the finest group (what a white frame would show), CV_8UC1 or CV_16UC1 like
  // the frames: the texture of sets without a white frame.
  cv::Mat texture;
};

// Decodes a set with phase frames (FrameSetManifest::HasPhase) into `map`; Decode()
// dispatches here. Axes with code frames but no phase frames decode to their block
// centres. Throws sope::Error on invalid options or a set that cannot be decoded.
void DecodePhase(const FrameSet& frame_set, const DecoderOptions& options,
                 CorrespondenceMap* map, PhaseDecodeImages* images = nullptr);

// The texture (A + B of the finest phase group) of a set with phase frames.
cv::Mat SynthesizePhaseTexture(const FrameSet& frame_set);

// Writes phase_x.png / phase_y.png (wrapped phase, grey 0…2π), phase_x.exr / phase_y.exr,
// modulation.png (grey levels ×2, clipped) and modulation.exr, texture.png into
// `directory` (existing), atomically per file.
void WritePhaseDecodeImages(const std::string& directory, const PhaseDecodeImages& images);

namespace internal {

// The least-squares fit of one group: with M = [1, cos s_k, sin s_k] (N × 3) and
// q = Mᵀ·I, (A, C, S) = (MᵀM)⁻¹·q and the residual sum of squares Σ I_k² − (A, C, S)·q.
struct PhaseFit {
  std::vector<float> cos_shift, sin_shift;
  float inverse_normal[3][3];  // (MᵀM)⁻¹
  // Throws sope::Error when the shifts do not make M of rank 3.
  explicit PhaseFit(const std::vector<double>& shifts);
};

// The phase error a response R adds to a group's fit, as a table over the measured phase:
// φ_true = φ_measured − correction(φ_measured). Empty for the identity.
std::vector<float> MakePhaseCorrectionTable(const PhaseFit& fit, const ProjectorResponse& response,
                                            int bins);

// PhaseDecoderOptions::local_fit_radius applied to one axis's coordinates (CV_32FC1) at
// the pixels where `mask` (CV_8UC1) is non-zero. The tolerance is at least 4 standard
// deviations of the pixel's coordinate noise, noise_scale / confidence (CV_32FC1; empty:
// the option's tolerance alone). Rows in parallel when num_threads > 1.
void FitCoordinatesLocally(const PhaseDecoderOptions& options, const cv::Mat& mask,
                           const cv::Mat& confidence, double noise_scale, cv::Mat* coordinate,
                           int num_threads = 1);

// atan2(y, x) in [0, 2π), |error| < 2e-6 rad, branch-free (vectorises); 0 for (0, 0).
float WrappedAtan2(float y, float x);

}  // namespace internal
}  // namespace sope
