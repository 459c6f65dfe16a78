#include "recogniser/bop.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include <fmt/format.h>

#include "core/error.h"
#include "core/file_util.h"

namespace sope {
namespace {

constexpr const char* kHeader = "scene_id,im_id,obj_id,score,R,t,time";
constexpr double kMillimetresPerMetre = 1000.0;

std::vector<std::string> SplitOn(const std::string& text, char separator) {
  std::vector<std::string> parts;
  std::string part;
  std::istringstream stream(text);
  while (std::getline(stream, part, separator)) parts.push_back(part);
  if (!text.empty() && text.back() == separator) parts.push_back("");
  return parts;
}

double ParseNumber(const std::string& text, const std::string& where) {
  size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  while (used < text.size() && std::isspace(static_cast<unsigned char>(text[used]))) ++used;
  SOPE_CHECK(used == text.size() && !text.empty() && std::isfinite(value),
             "{}: '{}' is not a number", where, text);
  return value;
}

int ParseId(const std::string& text, const std::string& where) {
  const double value = ParseNumber(text, where);
  SOPE_CHECK(value == std::floor(value) && std::abs(value) < 2e9, "{}: '{}' is not an integer",
             where, text);
  return static_cast<int>(value);
}

std::vector<double> ParseNumbers(const std::string& text, size_t count, const std::string& where) {
  std::istringstream stream(text);
  std::vector<double> values;
  std::string token;
  while (stream >> token) values.push_back(ParseNumber(token, where));
  SOPE_CHECK(values.size() == count, "{}: expected {} space-separated numbers, got {}", where,
             count, values.size());
  return values;
}

Eigen::Vector2d Project(const Eigen::Matrix3d& camera_matrix, const Eigen::Vector3d& point) {
  const Eigen::Vector3d image = camera_matrix * point;
  return image.head<2>() / image.z();
}

template <typename Distance>
double MaxSymmetricDistance(const Rigid3d& est, const Rigid3d& gt,
                            const std::vector<Eigen::Vector3d>& points,
                            const std::vector<Rigid3d>& symmetries, const Distance& distance) {
  SOPE_CHECK(!points.empty(), "pose error: no model points");
  const std::vector<Rigid3d> identity = {Rigid3d()};
  const std::vector<Rigid3d>& syms = symmetries.empty() ? identity : symmetries;
  double best = std::numeric_limits<double>::infinity();
  for (const Rigid3d& symmetry : syms) {
    const Rigid3d gt_sym = gt * symmetry;
    double worst = 0.0;
    for (const Eigen::Vector3d& point : points) {
      worst = std::max(worst, distance(est * point, gt_sym * point));
    }
    best = std::min(best, worst);
  }
  return best;
}

}  // namespace

std::string FormatBopCsv(const std::vector<BopEstimate>& estimates) {
  std::string text = std::string(kHeader) + "\n";
  for (const BopEstimate& e : estimates) {
    const Eigen::Matrix3d& r = e.cam_from_model.rotation;
    const Eigen::Vector3d t = e.cam_from_model.translation * kMillimetresPerMetre;
    SOPE_CHECK(r.allFinite() && t.allFinite() && std::isfinite(e.score) &&
                   std::isfinite(e.time_s),
               "BOP CSV: estimate scene {} image {} object {} is not finite", e.scene_id,
               e.im_id, e.obj_id);
    text += fmt::format("{},{},{},{:.9g},{:.17g} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g} "
                        "{:.17g} {:.17g} {:.17g},{:.17g} {:.17g} {:.17g},{:.9g}\n",
                        e.scene_id, e.im_id, e.obj_id, e.score, r(0, 0), r(0, 1), r(0, 2),
                        r(1, 0), r(1, 1), r(1, 2), r(2, 0), r(2, 1), r(2, 2), t.x(), t.y(),
                        t.z(), e.time_s);
  }
  return text;
}

void WriteBopCsv(const std::string& path, const std::vector<BopEstimate>& estimates) {
  WriteFileAtomic(path, FormatBopCsv(estimates));
}

std::vector<BopEstimate> ParseBopCsv(const std::string& text, const std::string& source) {
  std::istringstream stream(text);
  std::string line;
  SOPE_CHECK(std::getline(stream, line), "{}: empty file", source);
  if (!line.empty() && line.back() == '\r') line.pop_back();
  SOPE_CHECK(line == kHeader, "{}: header must be '{}', got '{}'", source, kHeader, line);
  std::vector<BopEstimate> estimates;
  int number = 1;
  while (std::getline(stream, line)) {
    ++number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    const std::string where = fmt::format("{} line {}", source, number);
    const std::vector<std::string> columns = SplitOn(line, ',');
    SOPE_CHECK(columns.size() == 7, "{}: expected 7 columns, got {}", where, columns.size());
    BopEstimate e;
    e.scene_id = ParseId(columns[0], where + " scene_id");
    e.im_id = ParseId(columns[1], where + " im_id");
    e.obj_id = ParseId(columns[2], where + " obj_id");
    e.score = ParseNumber(columns[3], where + " score");
    const std::vector<double> r = ParseNumbers(columns[4], 9, where + " R");
    const std::vector<double> t = ParseNumbers(columns[5], 3, where + " t");
    e.time_s = ParseNumber(columns[6], where + " time");
    for (int i = 0; i < 9; ++i) e.cam_from_model.rotation(i / 3, i % 3) = r[i];
    e.cam_from_model.translation = Eigen::Vector3d(t[0], t[1], t[2]) / kMillimetresPerMetre;
    estimates.push_back(e);
  }
  return estimates;
}

double Mssd(const Rigid3d& est_cam_from_model, const Rigid3d& gt_cam_from_model,
            const std::vector<Eigen::Vector3d>& model_points,
            const std::vector<Rigid3d>& symmetries) {
  return MaxSymmetricDistance(
      est_cam_from_model, gt_cam_from_model, model_points, symmetries,
      [](const Eigen::Vector3d& a, const Eigen::Vector3d& b) { return (a - b).norm(); });
}

double Mspd(const Rigid3d& est_cam_from_model, const Rigid3d& gt_cam_from_model,
            const Eigen::Matrix3d& camera_matrix,
            const std::vector<Eigen::Vector3d>& model_points,
            const std::vector<Rigid3d>& symmetries) {
  return MaxSymmetricDistance(est_cam_from_model, gt_cam_from_model, model_points, symmetries,
                              [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
                                return (Project(camera_matrix, a) - Project(camera_matrix, b))
                                    .norm();
                              });
}

std::vector<double> MssdThresholds(double diameter) {
  SOPE_CHECK(diameter > 0.0 && std::isfinite(diameter), "MSSD: invalid diameter {}", diameter);
  std::vector<double> thresholds;
  for (int i = 1; i <= 10; ++i) thresholds.push_back(0.05 * i * diameter);
  return thresholds;
}

std::vector<double> MspdThresholds(int image_width) {
  SOPE_CHECK(image_width > 0, "MSPD: invalid image width {}", image_width);
  std::vector<double> thresholds;
  for (int i = 1; i <= 10; ++i) thresholds.push_back(5.0 * i * image_width / 640.0);
  return thresholds;
}

double RecallAt(const std::vector<double>& errors, double threshold) {
  if (errors.empty()) return 0.0;
  const auto below = std::count_if(errors.begin(), errors.end(),
                                   [&](double e) { return e < threshold; });
  return static_cast<double>(below) / errors.size();
}

double AverageRecall(const std::vector<double>& errors, const std::vector<double>& thresholds) {
  if (thresholds.empty()) return 0.0;
  double sum = 0.0;
  for (double threshold : thresholds) sum += RecallAt(errors, threshold);
  return sum / thresholds.size();
}

}  // namespace sope
