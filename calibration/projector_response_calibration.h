// Measuring the projector → camera intensity response from a grey ramp: the projector shows
// uniform frames of increasing grey level, the camera films a surface; per pixel the levels
// are normalised between the darkest and the brightest frame and the median over the lit
// pixels is the response (core/projector_response.h). The phase decoder corrects the gamma
// ripple with it (sope calibrate-gamma writes it into the calibration YAML).
#pragma once

#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "core/projector_response.h"

namespace sope {

struct ResponseCalibrationOptions {
  // Uniform frames of the ramp, at pixel values round(255·k / (levels − 1)).
  int levels = 18;
  // Entries of the response table (evenly spaced projector values, interpolated).
  int table_size = 65;
  // A pixel takes part when its brightest − darkest frame is at least this, grey levels
  // (8-bit scale); darker pixels are shadow or off the projector.
  double min_contrast = 40.0;
  // A pixel whose brightest frame reaches this is saturated in the camera and left out.
  double max_level = 250.0;

  // Throws sope::Error naming an invalid value.
  void Check() const;
};

// The projector value (pixel value / 255) of ramp frame k.
double GreyRampValue(int k, int levels);
// The ramp's projector images (CV_8UC1, uniform).
std::vector<cv::Mat> GreyRampPatterns(int projector_width, int projector_height, int levels);

struct ResponseCalibrationSummary {
  ProjectorResponse response;
  size_t pixels_used = 0;
  // Least-squares fit of R(v) = v^γ over 0.1 ≤ v ≤ 0.9 (for the report).
  double fitted_gamma = 1.0;
  std::string BriefReport() const;
};

// `captures[k]` is the camera image of ramp frame k (CV_8UC1 or CV_16UC1, one size).
// Throws sope::Error when the sizes/types differ, the count is not options.levels, or no
// pixel has enough contrast.
ResponseCalibrationSummary MeasureProjectorResponse(const std::vector<cv::Mat>& captures,
                                                    const ResponseCalibrationOptions& options);

// A captured ramp directory: `ramp.json` {"format": "sope-grey-ramp/1", "levels": K,
// "files": [K names]} and the images.
void WriteGreyRamp(const std::string& directory, const std::vector<cv::Mat>& images);
std::vector<cv::Mat> ReadGreyRamp(const std::string& directory);

}  // namespace sope
