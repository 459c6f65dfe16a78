// Small pictures for reports, drawn with OpenCV (BGR, CV_8UC3): a confusion matrix and a
// histogram. Written as PNG by the tools (WriteImageAtomic).
#pragma once

#include <limits>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

namespace sope {

// Rows are the true labels, columns the predicted ones; cells are coloured by the row's
// share (so every class reads the same however often it was asked) and show the count.
// Throws sope::Error when counts is not labels.size() square.
cv::Mat DrawConfusionMatrix(const std::vector<std::vector<int>>& counts,
                            const std::vector<std::string>& labels, const std::string& title);

// Histogram of `values` over [lo, hi] in `bins` bins (values outside go to the end bins,
// so nothing is lost), with the median marked and an optional threshold line (NaN: none).
cv::Mat DrawHistogram(const std::vector<double>& values, double lo, double hi, int bins,
                      const std::string& title, const std::string& x_label,
                      double threshold = std::numeric_limits<double>::quiet_NaN());

// `text` for OpenCV's Hershey fonts, which draw ASCII only (other bytes come out as '?'):
// the symbols our messages use become ASCII ("–" → "-", "≥" → ">=", "°" → " deg", "×" → "x",
// "µ" → "u", …); any other non-ASCII character becomes one '?'.
std::string HersheyText(const std::string& text);

}  // namespace sope
