// Internal to the decoder: the running sums of the normal equations of a least-squares
// plane u = c + g_x·dx + g_y·dy through samples (dx, dy, u) around a pixel (the phase
// decoder's local coordinate fit, the code consistency's prediction from the neighbours).
#pragma once

namespace sope::internal {

struct PlaneFitSums {
  double n = 0, x = 0, y = 0, xx = 0, xy = 0, yy = 0, u = 0, xu = 0, yu = 0;

  void Add(double dx, double dy, double value) {
    AddBasis(dx, dy);
    AddValue(dx, dy, value);
  }
  // Σ basis·basisᵀ, basis = (1, dx, dy): depends only on where the samples are (the code
  // consistency sums it once for both axes).
  void AddBasis(double dx, double dy) {
    n += 1.0;
    x += dx;
    y += dy;
    xx += dx * dx;
    xy += dx * dy;
    yy += dy * dy;
  }
  // Σ basis·u.
  void AddValue(double dx, double dy, double value) {
    u += value;
    xu += dx * value;
    yu += dy * value;
  }
};

}  // namespace sope::internal
