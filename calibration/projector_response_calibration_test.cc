#include "calibration/projector_response_calibration.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace {

// Camera images of a ramp: per pixel α·R(v) + β with varying albedo α and ambient β,
// noise, 8-bit; a dark corner (shadow) and a saturated one that must be left out.
std::vector<cv::Mat> SyntheticRamp(const ResponseCalibrationOptions& options, double gamma) {
  std::mt19937_64 engine(5);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::vector<cv::Mat> images;
  for (int k = 0; k < options.levels; ++k) {
    const double v = GreyRampValue(k, options.levels);
    cv::Mat image(60, 80, CV_8UC1);
    for (int y = 0; y < image.rows; ++y) {
      for (int x = 0; x < image.cols; ++x) {
        double alpha = 120.0 + 80.0 * x / image.cols, beta = 10.0 + 0.2 * y;
        if (x < 10 && y < 10) alpha = 5.0;    // shadow
        if (x > 70 && y > 50) alpha = 400.0;  // saturates
        image.at<uint8_t>(y, x) =
            cv::saturate_cast<uint8_t>(alpha * std::pow(v, gamma) + beta + noise(engine));
      }
    }
    images.push_back(image);
  }
  return images;
}

TEST(ProjectorResponseCalibration, RecoversAGammaCurveIndependentOfAlbedo) {
  ResponseCalibrationOptions options;
  const ResponseCalibrationSummary summary =
      MeasureProjectorResponse(SyntheticRamp(options, 2.2), options);
  EXPECT_NEAR(summary.fitted_gamma, 2.2, 0.05);
  EXPECT_LT(summary.pixels_used, 80u * 60u - 100u + 1u);  // shadow left out
  for (double v = 0.0; v <= 1.0; v += 0.05) {
    EXPECT_NEAR(summary.response.Apply(v), std::pow(v, 2.2), 0.01) << v;
  }
  EXPECT_NE(summary.BriefReport().find("gamma 2.2"), std::string::npos) << summary.BriefReport();
}

TEST(ProjectorResponseCalibration, RampDirectoryRoundTripAndBadInput) {
  testing::ScratchDir scratch;
  ResponseCalibrationOptions options;
  options.levels = 6;
  const std::vector<cv::Mat> ramp = SyntheticRamp(options, 1.8);
  WriteGreyRamp(scratch.File("ramp"), ramp);
  const std::vector<cv::Mat> read = ReadGreyRamp(scratch.File("ramp"));
  ASSERT_EQ(read.size(), ramp.size());
  EXPECT_EQ(cv::norm(read[3], ramp[3], cv::NORM_INF), 0.0);
  EXPECT_NEAR(MeasureProjectorResponse(read, options).fitted_gamma, 1.8, 0.1);
  options.levels = 7;
  EXPECT_THROW_WITH_MESSAGE(MeasureProjectorResponse(read, options), Error, "6 captures for 7 levels");
  options.levels = 6;
  std::vector<cv::Mat> flat(6, cv::Mat(10, 10, CV_8UC1, cv::Scalar(50)));
  EXPECT_THROW_WITH_MESSAGE(MeasureProjectorResponse(flat, options), Error, "no pixel has a contrast");
  EXPECT_THROW_WITH_MESSAGE(ReadGreyRamp(scratch.File("missing")), Error, "ramp.json");
}

}  // namespace
}  // namespace sope
