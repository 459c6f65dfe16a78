#include "core/plots.h"

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace {

int Brightness(const cv::Vec3b& pixel) { return pixel[0] + pixel[1] + pixel[2]; }

TEST(Plots, ConfusionMatrixShadesByRowShare) {
  const std::vector<std::string> labels = {"mug", "bottle", "plate"};
  const std::vector<std::vector<int>> counts = {{9, 1, 0}, {0, 10, 0}, {5, 0, 5}};
  const cv::Mat image = DrawConfusionMatrix(counts, labels, "classes");
  ASSERT_EQ(image.type(), CV_8UC3);
  // Locate the cells through their shading: the darkest pixels belong to the 100% cell
  // (bottle, bottle), and there is pure white (empty cells) as well.
  double darkest = 255 * 3, lightest = 0;
  for (int y = 0; y < image.rows; ++y) {
    for (int x = 0; x < image.cols; ++x) {
      const int b = Brightness(image.at<cv::Vec3b>(y, x));
      darkest = std::min<double>(darkest, b);
      lightest = std::max<double>(lightest, b);
    }
  }
  EXPECT_LT(darkest, 300);
  EXPECT_EQ(lightest, 765);
  EXPECT_THROW_WITH_MESSAGE(DrawConfusionMatrix({{1, 2}}, labels, "bad"), Error,
                            "1 rows for 3 labels");
}

TEST(Plots, HistogramBarsFollowTheCounts) {
  std::vector<double> values(100, 0.5);  // all in the first of 10 bins over [0, 10]
  values.push_back(95.0);                // clamps into the last bin: not lost
  const cv::Mat image = DrawHistogram(values, 0.0, 10.0, 10, "errors", "degrees", 3.0);
  ASSERT_EQ(image.type(), CV_8UC3);
  const cv::Vec3b bar(180, 120, 40);
  // The first bin's bar reaches the top of the plot area (y = 50), the last one is short.
  const int first_bin_x = 50 + 45, last_bin_x = 50 + 570 * 95 / 100;
  EXPECT_EQ(image.at<cv::Vec3b>(52, first_bin_x), bar);
  EXPECT_NE(image.at<cv::Vec3b>(52, last_bin_x), bar);
  EXPECT_EQ(image.at<cv::Vec3b>(360 - 51, last_bin_x), bar);  // 1 of 100: a 2-pixel bar
  EXPECT_THROW_WITH_MESSAGE(DrawHistogram(values, 1.0, 0.0, 10, "bad", "x"), Error, "[1, 0]");
}

TEST(Plots, HersheyTextIsAsciiWithTheSymbolsSpelledOut) {
  EXPECT_EQ(HersheyText("0.006\u20130.4 m above the plane"), "0.006-0.4 m above the plane");
  EXPECT_EQ(HersheyText("\u2265 15\u00b0, 2\u00d73 \u00b5m"), ">= 15 deg, 2x3 um");
  // Any other character is one '?', whatever its length in bytes.
  EXPECT_EQ(HersheyText("caf\u00e9 \u6771 \U0001F600!"), "caf? ? ?!");
  EXPECT_EQ(HersheyText("plain ASCII"), "plain ASCII");
}

}  // namespace
}  // namespace sope
