#include "calibration/projector_response_calibration.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/statistics.h"

namespace sope {
namespace {

constexpr const char* kRampFormat = "sope-grey-ramp/1";
constexpr const char* kRampFile = "ramp.json";
constexpr int kMaxLevels = 256;
// Projector values whose response enters the reported gamma fit.
constexpr double kFitLow = 0.1, kFitHigh = 0.9;

}  // namespace

void ResponseCalibrationOptions::Check() const {
  SOPE_CHECK(levels >= 3 && levels <= kMaxLevels, "ramp levels {} must be in 3..{}", levels,
             kMaxLevels);
  SOPE_CHECK(table_size >= 2 && table_size <= 4096, "response table size {} must be in 2..4096",
             table_size);
  SOPE_CHECK(std::isfinite(min_contrast) && min_contrast > 0.0 && min_contrast < 255.0,
             "ramp min_contrast {} must be in (0, 255) grey levels", min_contrast);
  SOPE_CHECK(std::isfinite(max_level) && max_level > min_contrast && max_level <= 255.0,
             "ramp max_level {} must be in (min_contrast, 255]", max_level);
}

double GreyRampValue(int k, int levels) {
  return std::round(255.0 * k / (levels - 1)) / 255.0;
}

std::vector<cv::Mat> GreyRampPatterns(int projector_width, int projector_height, int levels) {
  SOPE_CHECK(projector_width > 0 && projector_height > 0, "invalid projector size {}x{}",
             projector_width, projector_height);
  SOPE_CHECK(levels >= 3 && levels <= kMaxLevels, "ramp levels {} must be in 3..{}", levels,
             kMaxLevels);
  std::vector<cv::Mat> patterns;
  for (int k = 0; k < levels; ++k) {
    patterns.emplace_back(projector_height, projector_width, CV_8UC1,
                          cv::Scalar(std::round(255.0 * GreyRampValue(k, levels))));
  }
  return patterns;
}

std::string ResponseCalibrationSummary::BriefReport() const {
  return fmt::format("projector response from {} pixels: {} levels, best-fit gamma {:.3f}",
                     pixels_used, response.table.size(), fitted_gamma);
}

ResponseCalibrationSummary MeasureProjectorResponse(const std::vector<cv::Mat>& captures,
                                                    const ResponseCalibrationOptions& options) {
  options.Check();
  const int levels = options.levels;
  SOPE_CHECK(static_cast<int>(captures.size()) == levels,
             "grey ramp: {} captures for {} levels", captures.size(), levels);
  for (size_t k = 0; k < captures.size(); ++k) {
    SOPE_CHECK(!captures[k].empty() && (captures[k].type() == CV_8UC1 || captures[k].type() == CV_16UC1),
               "grey ramp capture {}: must be 8- or 16-bit single-channel", k);
    SOPE_CHECK(captures[k].size() == captures[0].size() && captures[k].type() == captures[0].type(),
               "grey ramp capture {}: size or type differs from capture 0", k);
  }
  const double scale = captures[0].depth() == CV_16U ? 1.0 / 257.0 : 1.0;
  std::vector<cv::Mat> levels_f(levels);
  for (int k = 0; k < levels; ++k) captures[k].convertTo(levels_f[k], CV_32F, scale);
  std::vector<std::vector<double>> normalised(levels);
  size_t used = 0;
  const cv::Mat& dark = levels_f.front();
  const cv::Mat& bright = levels_f.back();
  for (int y = 0; y < dark.rows; ++y) {
    for (int x = 0; x < dark.cols; ++x) {
      const double low = dark.at<float>(y, x), high = bright.at<float>(y, x);
      if (high - low < options.min_contrast || high >= options.max_level) continue;
      ++used;
      for (int k = 0; k < levels; ++k) {
        normalised[k].push_back((levels_f[k].at<float>(y, x) - low) / (high - low));
      }
    }
  }
  SOPE_CHECK(used > 0, "grey ramp: no pixel has a contrast of {} grey levels between the "
             "darkest and brightest frame without saturating (is the projector lighting the "
             "surface?)", options.min_contrast);
  std::vector<double> measured(levels);
  for (int k = 0; k < levels; ++k) measured[k] = Median(normalised[k]);
  const ProjectorResponse at_levels = ProjectorResponse::FromMeasured(measured);
  // Resample the measured points (at the ramp's pixel values) to an even table.
  ResponseCalibrationSummary summary;
  summary.pixels_used = used;
  summary.response.table.resize(options.table_size);
  for (int t = 0; t < options.table_size; ++t) {
    const double v = static_cast<double>(t) / (options.table_size - 1);
    int k = 0;
    while (k + 2 < levels && GreyRampValue(k + 1, levels) < v) ++k;
    const double v0 = GreyRampValue(k, levels), v1 = GreyRampValue(k + 1, levels);
    const double w = std::clamp((v - v0) / (v1 - v0), 0.0, 1.0);
    summary.response.table[t] = (1 - w) * at_levels.table[k] + w * at_levels.table[k + 1];
  }
  summary.response.table.front() = 0.0;
  summary.response.table.back() = 1.0;
  for (size_t t = 1; t < summary.response.table.size(); ++t) {
    summary.response.table[t] = std::max(summary.response.table[t], summary.response.table[t - 1]);
  }
  summary.response.Check();
  // log R = γ log v, least squares through the origin.
  double num = 0.0, den = 0.0;
  for (int k = 0; k < levels; ++k) {
    const double v = GreyRampValue(k, levels), r = at_levels.table[k];
    if (v < kFitLow || v > kFitHigh || r <= 0.0) continue;
    num += std::log(v) * std::log(r);
    den += std::log(v) * std::log(v);
  }
  summary.fitted_gamma = den > 0.0 ? num / den : 1.0;
  return summary;
}

void WriteGreyRamp(const std::string& directory, const std::vector<cv::Mat>& images) {
  SOPE_CHECK(images.size() >= 3, "grey ramp: {} images (need ≥ 3)", images.size());
  StagedDirectory staged(directory);
  nlohmann::json files = nlohmann::json::array();
  for (size_t k = 0; k < images.size(); ++k) {
    const std::string name = fmt::format("ramp_{:03}.png", k);
    WriteImageAtomic(JoinPath(staged.path(), name), images[k]);
    files.push_back(name);
  }
  const nlohmann::json root = {{"format", kRampFormat},
                               {"levels", static_cast<int>(images.size())},
                               {"files", files}};
  WriteFileAtomic(JoinPath(staged.path(), kRampFile), root.dump(2) + "\n");
  staged.Commit();
}

std::vector<cv::Mat> ReadGreyRamp(const std::string& directory) {
  const std::string path = JoinPath(directory, kRampFile);
  nlohmann::json root;
  try {
    root = nlohmann::json::parse(ReadFileToString(path, "grey ramp"));
  } catch (const nlohmann::json::exception& e) {  // parse_error, or a number overflow
    SOPE_THROW("{}: not valid JSON ({})", path, e.what());
  }
  std::vector<cv::Mat> images;
  try {
    SOPE_CHECK(root.at("format").get<std::string>() == kRampFormat,
               "{}: unsupported format (expected '{}')", path, kRampFormat);
    const int levels = root.at("levels").get<int>();
    const nlohmann::json& files = root.at("files");
    SOPE_CHECK(files.is_array() && static_cast<int>(files.size()) == levels && levels >= 3 &&
                   levels <= kMaxLevels,
               "{}: 'files' must list 'levels' ({}) images, 3..{}", path, levels, kMaxLevels);
    for (const auto& file : files) {
      const std::string name = file.get<std::string>();
      SOPE_CHECK(name.find('/') == std::string::npos, "{}: file '{}' must be a plain name", path,
                 name);
      cv::Mat image = ReadImage(JoinPath(directory, name), -1);
      if (image.channels() == 3 || image.channels() == 4) {
        cv::Mat grey;
        cv::cvtColor(image, grey, image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
        image = grey;
      }
      images.push_back(image);
    }
  } catch (const nlohmann::json::exception& e) {
    SOPE_THROW("{}: missing or mistyped field ({})", path, e.what());
  }
  return images;
}

}  // namespace sope
