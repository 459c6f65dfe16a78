// The projector → camera intensity response of a rig: what fraction of the way from black
// to white the camera sees when the projector shows a grey level. Projectors are far from
// linear (gamma ≈ 2.2), which bends sinusoids and leaves a periodic phase error ("gamma
// ripple", at N× the phase for N-step shifting); the phase decoder corrects it with this
// curve, and patterns can be pre-distorted by its inverse.
#pragma once

#include <vector>

namespace sope {

// R(v) for a projector value v ∈ [0, 1] (pixel value / 255), normalised so that R(0) = 0
// and R(1) = 1, tabulated at evenly spaced values v_k = k / (K − 1) and interpolated
// linearly in between. An empty table is the identity (a linear rig).
struct ProjectorResponse {
  std::vector<double> table;

  bool IsIdentity() const { return table.empty(); }
  // R(v), v clamped to [0, 1].
  double Apply(double value) const;
  // The v with R(v) = response (response clamped to [0, 1]); the table's inverse.
  double Invert(double response) const;
  // Throws sope::Error unless empty or ≥ 2 finite, non-decreasing entries from 0 to 1.
  void Check() const;
  // The power law R(v) = v^gamma, tabulated at `samples` values.
  static ProjectorResponse Gamma(double gamma, int samples = 65);
  // Normalises a measured curve (camera levels per projector level, any affine scale):
  // (c_k − c_0) / (c_{K−1} − c_0), made non-decreasing (noise). Throws sope::Error when
  // there are fewer than 2 levels or no contrast (c_{K−1} ≤ c_0).
  static ProjectorResponse FromMeasured(const std::vector<double>& camera_levels);
};

}  // namespace sope
