#include "core/projector_response.h"

#include <algorithm>
#include <cmath>

#include "core/error.h"

namespace sope {
namespace {

// A tabulated curve must start at 0 and end at 1 within this.
constexpr double kEndpointTolerance = 1e-6;
constexpr int kMaxTableSize = 4096;

}  // namespace

double ProjectorResponse::Apply(double value) const {
  const double v = std::clamp(value, 0.0, 1.0);
  if (table.empty()) return v;
  const double position = v * static_cast<double>(table.size() - 1);
  const size_t k = std::min(static_cast<size_t>(position), table.size() - 2);
  const double t = position - static_cast<double>(k);
  return table[k] + t * (table[k + 1] - table[k]);
}

double ProjectorResponse::Invert(double response) const {
  const double r = std::clamp(response, 0.0, 1.0);
  if (table.empty()) return r;
  // First entry ≥ r; the segment before it holds the answer (flat runs: their start).
  const auto it = std::lower_bound(table.begin(), table.end(), r);
  if (it == table.begin()) return 0.0;
  if (it == table.end()) return 1.0;
  const size_t k = static_cast<size_t>(it - table.begin()) - 1;
  const double rise = table[k + 1] - table[k];
  const double t = rise > 0.0 ? (r - table[k]) / rise : 0.0;
  return (static_cast<double>(k) + t) / static_cast<double>(table.size() - 1);
}

void ProjectorResponse::Check() const {
  if (table.empty()) return;
  SOPE_CHECK(table.size() >= 2 && table.size() <= static_cast<size_t>(kMaxTableSize),
             "projector response: {} table entries (need 2..{})", table.size(), kMaxTableSize);
  for (size_t k = 0; k < table.size(); ++k) {
    SOPE_CHECK(std::isfinite(table[k]), "projector response: entry {} is not finite", k);
    SOPE_CHECK(k == 0 || table[k] >= table[k - 1],
               "projector response: entry {} ({}) is below entry {} ({}); the curve must not "
               "decrease", k, table[k], k - 1, table[k - 1]);
  }
  SOPE_CHECK(std::abs(table.front()) <= kEndpointTolerance &&
                 std::abs(table.back() - 1.0) <= kEndpointTolerance,
             "projector response: must run from 0 to 1, runs from {} to {}", table.front(),
             table.back());
}

ProjectorResponse ProjectorResponse::Gamma(double gamma, int samples) {
  SOPE_CHECK(std::isfinite(gamma) && gamma > 0.0, "projector gamma {} must be > 0", gamma);
  SOPE_CHECK(samples >= 2 && samples <= kMaxTableSize, "projector response: {} samples (need "
             "2..{})", samples, kMaxTableSize);
  ProjectorResponse response;
  response.table.resize(samples);
  for (int k = 0; k < samples; ++k) {
    response.table[k] = std::pow(static_cast<double>(k) / (samples - 1), gamma);
  }
  return response;
}

ProjectorResponse ProjectorResponse::FromMeasured(const std::vector<double>& camera_levels) {
  SOPE_CHECK(camera_levels.size() >= 2 && camera_levels.size() <= kMaxTableSize,
             "projector response: {} measured levels (need 2..{})", camera_levels.size(),
             kMaxTableSize);
  const double low = camera_levels.front(), high = camera_levels.back();
  SOPE_CHECK(std::isfinite(low) && std::isfinite(high) && high > low,
             "projector response: no contrast between the darkest ({}) and brightest ({}) "
             "level", low, high);
  ProjectorResponse response;
  response.table.resize(camera_levels.size());
  double running = 0.0;
  for (size_t k = 0; k < camera_levels.size(); ++k) {
    SOPE_CHECK(std::isfinite(camera_levels[k]), "projector response: level {} is not finite", k);
    running = std::max(running, std::clamp((camera_levels[k] - low) / (high - low), 0.0, 1.0));
    response.table[k] = running;
  }
  response.table.front() = 0.0;
  response.table.back() = 1.0;
  return response;
}

}  // namespace sope
