#include "core/plots.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <opencv2/imgproc.hpp>

#include "core/error.h"

namespace sope {

std::string HersheyText(const std::string& text) {
  static const std::pair<const char*, const char*> kSymbols[] = {
      {"\u2013", "-"},  {"\u2014", "-"},   {"\u2212", "-"},  {"\u2265", ">="},
      {"\u2264", "<="}, {"\u00b0", " deg"}, {"\u00d7", "x"},  {"\u00b1", "+-"},
      {"\u00b5", "u"},  {"\u03bc", "u"},    {"\u2192", "->"}, {"\u2026", "..."},
      {"\u2018", "'"},  {"\u2019", "'"},    {"\u201c", "\""}, {"\u201d", "\""},
      {"\u2248", "~"},  {"\u2260", "!="},   {"\u00b7", "."}};
  std::string out;
  out.reserve(text.size());
  for (size_t i = 0; i < text.size();) {
    const auto byte = static_cast<unsigned char>(text[i]);
    if (byte < 0x80) {
      out += text[i++];
      continue;
    }
    bool replaced = false;
    for (const auto& [symbol, ascii] : kSymbols) {
      const size_t n = std::char_traits<char>::length(symbol);
      if (text.compare(i, n, symbol) == 0) {
        out += ascii;
        i += n;
        replaced = true;
        break;
      }
    }
    if (replaced) continue;
    // One '?' per character: skip the lead byte and its continuation bytes.
    out += '?';
    ++i;
    while (i < text.size() && (static_cast<unsigned char>(text[i]) & 0xC0) == 0x80) ++i;
  }
  return out;
}

namespace {

const cv::Scalar kBlack(0, 0, 0);
const cv::Scalar kGrey(120, 120, 120);
const cv::Scalar kWhite(255, 255, 255);
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;

void Text(cv::Mat& image, const std::string& text, cv::Point origin, double scale,
          const cv::Scalar& colour = kBlack, int thickness = 1) {
  cv::putText(image, HersheyText(text), origin, kFont, scale, colour, thickness, cv::LINE_AA);
}

int TextWidth(const std::string& text, double scale) {
  int baseline = 0;
  return cv::getTextSize(HersheyText(text), kFont, scale, 1, &baseline).width;
}

// White (0) to dark blue (1).
cv::Scalar Shade(double share) {
  const double s = std::clamp(share, 0.0, 1.0);
  return cv::Scalar(255 - 105 * s, 255 - 200 * s, 255 - 230 * s);
}

}  // namespace

cv::Mat DrawConfusionMatrix(const std::vector<std::vector<int>>& counts,
                            const std::vector<std::string>& labels, const std::string& title) {
  const int n = static_cast<int>(labels.size());
  SOPE_CHECK(n > 0 && static_cast<int>(counts.size()) == n,
             "confusion matrix: {} rows for {} labels", counts.size(), labels.size());
  for (const auto& row : counts) {
    SOPE_CHECK(static_cast<int>(row.size()) == n, "confusion matrix must be square");
  }
  constexpr double kLabelScale = 0.45;
  int label_width = 0;
  for (const std::string& label : labels) label_width = std::max(label_width, TextWidth(label, kLabelScale));
  const int cell = std::max(34, std::min(60, 900 / std::max(n, 1)));
  const int left = label_width + 20, top = 60 + label_width;
  cv::Mat image(top + n * cell + 40, left + n * cell + 30, CV_8UC3, kWhite);
  Text(image, title, cv::Point(10, 25), 0.6, kBlack, 1);
  Text(image, "rows: true, columns: predicted", cv::Point(10, 45), 0.4, kGrey);
  for (int r = 0; r < n; ++r) {
    int row_total = 0;
    for (int value : counts[r]) row_total += value;
    Text(image, labels[r], cv::Point(10, top + r * cell + cell / 2 + 5), kLabelScale);
    for (int c = 0; c < n; ++c) {
      const double share = row_total > 0 ? static_cast<double>(counts[r][c]) / row_total : 0.0;
      const cv::Rect box(left + c * cell, top + r * cell, cell, cell);
      cv::rectangle(image, box, Shade(share), cv::FILLED);
      cv::rectangle(image, box, cv::Scalar(200, 200, 200), 1);
      if (counts[r][c] > 0) {
        const std::string text = std::to_string(counts[r][c]);
        Text(image, text, cv::Point(box.x + (cell - TextWidth(text, 0.4)) / 2, box.y + cell / 2 + 5),
             0.4, share > 0.5 ? kWhite : kBlack);
      }
    }
  }
  // Column labels, rotated: draw on a sideways canvas and turn it.
  cv::Mat header(left + n * cell, top - 55, CV_8UC3, kWhite);
  for (int c = 0; c < n; ++c) {
    Text(header, labels[c], cv::Point(5, left + c * cell + cell / 2 + 5), kLabelScale);
  }
  cv::Mat turned;
  cv::rotate(header, turned, cv::ROTATE_90_COUNTERCLOCKWISE);
  turned(cv::Rect(left, 0, n * cell, turned.rows))
      .copyTo(image(cv::Rect(left, 55, n * cell, turned.rows)));
  return image;
}

cv::Mat DrawHistogram(const std::vector<double>& values, double lo, double hi, int bins,
                      const std::string& title, const std::string& x_label, double threshold) {
  SOPE_CHECK(hi > lo && bins > 0, "histogram: invalid range [{}, {}] or {} bins", lo, hi, bins);
  std::vector<int> counts(bins, 0);
  for (double v : values) {
    if (!std::isfinite(v)) continue;
    const int bin = std::clamp(static_cast<int>((v - lo) / (hi - lo) * bins), 0, bins - 1);
    ++counts[bin];
  }
  const int max_count = std::max(1, *std::max_element(counts.begin(), counts.end()));
  constexpr int kWidth = 640, kHeight = 360, kLeft = 50, kRight = 20, kTop = 50, kBottom = 50;
  cv::Mat image(kHeight, kWidth, CV_8UC3, kWhite);
  const int plot_w = kWidth - kLeft - kRight, plot_h = kHeight - kTop - kBottom;
  auto x_of = [&](double v) {
    return kLeft + static_cast<int>(std::round((v - lo) / (hi - lo) * plot_w));
  };
  for (int b = 0; b < bins; ++b) {
    const int x0 = kLeft + b * plot_w / bins, x1 = kLeft + (b + 1) * plot_w / bins;
    const int height = counts[b] * plot_h / max_count;
    cv::rectangle(image, cv::Rect(x0, kTop + plot_h - height, std::max(1, x1 - x0 - 1), height),
                  cv::Scalar(180, 120, 40), cv::FILLED);
  }
  cv::line(image, cv::Point(kLeft, kTop + plot_h), cv::Point(kLeft + plot_w, kTop + plot_h), kBlack);
  cv::line(image, cv::Point(kLeft, kTop), cv::Point(kLeft, kTop + plot_h), kBlack);
  for (int t = 0; t <= 4; ++t) {
    const double v = lo + (hi - lo) * t / 4.0;
    const std::string text = fmt::format("{:.3g}", v);
    Text(image, text, cv::Point(x_of(v) - TextWidth(text, 0.4) / 2, kTop + plot_h + 18), 0.4);
  }
  Text(image, fmt::format("{}", max_count), cv::Point(5, kTop + 5), 0.4);
  Text(image, x_label, cv::Point(kLeft + plot_w / 2 - TextWidth(x_label, 0.45) / 2, kHeight - 10), 0.45);
  std::vector<double> finite;
  for (double v : values) {
    if (std::isfinite(v)) finite.push_back(v);
  }
  std::string subtitle = fmt::format("n = {}", finite.size());
  if (!finite.empty()) {
    std::nth_element(finite.begin(), finite.begin() + finite.size() / 2, finite.end());
    const double median = finite[finite.size() / 2];
    subtitle += fmt::format(", median {:.3g}", median);
    if (median >= lo && median <= hi) {
      cv::line(image, cv::Point(x_of(median), kTop), cv::Point(x_of(median), kTop + plot_h),
               cv::Scalar(40, 160, 40), 2);
    }
  }
  if (std::isfinite(threshold) && threshold >= lo && threshold <= hi) {
    cv::line(image, cv::Point(x_of(threshold), kTop), cv::Point(x_of(threshold), kTop + plot_h),
             cv::Scalar(40, 40, 220), 1, cv::LINE_AA);
    subtitle += fmt::format(", threshold {:.3g} (red)", threshold);
  }
  Text(image, title, cv::Point(10, 22), 0.55);
  Text(image, subtitle + "; median green", cv::Point(10, 40), 0.4, kGrey);
  return image;
}

}  // namespace sope
