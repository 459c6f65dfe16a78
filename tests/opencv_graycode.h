// OpenCV's GrayCodePattern (opencv_contrib structured_light) as a peer for tests: the
// pattern object for a projector size and its sequence in the order OpenCV's capture
// sample projects it (the patterns from generate(), then white, then black). Header-only:
// for tests that link opencv_structured_light.
#pragma once

#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/structured_light.hpp>

namespace sope {
namespace testing {

inline cv::Ptr<cv::structured_light::GrayCodePattern> MakeOpenCvGrayCode(cv::Size projector) {
  cv::structured_light::GrayCodePattern::Params params;
  params.width = projector.width;
  params.height = projector.height;
  return cv::structured_light::GrayCodePattern::create(params);
}

struct OpenCvGrayCodeSequence {
  std::vector<cv::Mat> patterns;  // generate(): pattern/inverse pairs, columns then rows
  cv::Mat white, black;           // getImagesForShadowMasks(black, white)
  // The capture order of OpenCV's sample: patterns, white, black.
  std::vector<cv::Mat> CaptureOrder() const {
    std::vector<cv::Mat> sequence = patterns;
    sequence.push_back(white);
    sequence.push_back(black);
    return sequence;
  }
};

// The images OpenCV generates for `projector` (a test failure, and no patterns, when
// generate() fails).
inline OpenCvGrayCodeSequence GenerateOpenCvGrayCode(cv::Size projector) {
  const cv::Ptr<cv::structured_light::GrayCodePattern> opencv = MakeOpenCvGrayCode(projector);
  OpenCvGrayCodeSequence sequence;
  if (!opencv->generate(sequence.patterns)) {
    ADD_FAILURE() << "GrayCodePattern::generate failed for " << projector;
    sequence.patterns.clear();
  }
  opencv->getImagesForShadowMasks(sequence.black, sequence.white);
  return sequence;
}

}  // namespace testing
}  // namespace sope
