#include "app/cli_util.h"

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <sstream>
#include <utility>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "core/camera_model.h"
#include "core/error.h"
#include "core/units.h"

namespace sope {
namespace cli {

void ParseSize(const std::string& text, const std::string& option, int* width, int* height) {
  const size_t x = text.find_first_of("xX");
  SOPE_CHECK(x != std::string::npos, "{} '{}': expected WIDTHxHEIGHT, e.g. 1024x768", option,
             text);
  try {
    size_t used_w = 0, used_h = 0;
    *width = std::stoi(text.substr(0, x), &used_w);
    *height = std::stoi(text.substr(x + 1), &used_h);
    SOPE_CHECK(used_w == x && used_h == text.size() - x - 1, "trailing characters");
  } catch (const std::exception&) {
    SOPE_THROW("{} '{}': expected WIDTHxHEIGHT, e.g. 1024x768", option, text);
  }
  SOPE_CHECK(*width > 0 && *height > 0 && *width <= kMaxImageSide && *height <= kMaxImageSide,
             "{} '{}': sizes must be in 1..{}", option, text, kMaxImageSide);
  SOPE_CHECK(static_cast<int64_t>(*width) * *height <= kMaxImagePixels,
             "{} '{}': {} pixels is more than the limit of {} ({} Mpx)", option, text,
             static_cast<int64_t>(*width) * *height, kMaxImagePixels, kMaxImagePixels >> 20);
}

std::vector<double> ParseNumbers(const std::string& text, const std::string& option) {
  std::vector<double> numbers;
  SOPE_CHECK(!text.empty(), "{}: expected comma-separated numbers, got an empty value", option);
  // getline() drops one trailing empty item ("1,2," reads as "1", "2"): split by hand so an
  // empty item anywhere is an error.
  std::vector<std::string> items;
  size_t start = 0;
  while (true) {
    const size_t comma = text.find(',', start);
    items.push_back(text.substr(start, comma == std::string::npos ? std::string::npos
                                                                  : comma - start));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  for (const std::string& item : items) {
    SOPE_CHECK(!item.empty(), "{} '{}': empty item (stray comma?)", option, text);
    try {
      size_t used = 0;
      numbers.push_back(std::stod(item, &used));
      SOPE_CHECK(used == item.size(), "trailing characters");
    } catch (const std::exception&) {
      SOPE_THROW("{} '{}': '{}' is not a number", option, text, item);
    }
    SOPE_CHECK(std::isfinite(numbers.back()), "{} '{}': numbers must be finite", option, text);
  }
  return numbers;
}

namespace {

// Metres per unit of `text` (m, cm, mm, in, or a positive number); with `allow_auto`,
// "auto" gives 0.
double ParseUnit(const std::string& text, const std::string& option, bool allow_auto) {
  static constexpr std::pair<const char*, double> kUnits[] = {
      {"m", 1.0}, {"cm", 0.01}, {"mm", 0.001}, {"in", 0.0254}};
  if (allow_auto && text == "auto") return 0.0;
  for (const auto& [name, metres] : kUnits) {
    if (text == name) return metres;
  }
  double metres = 0.0;
  try {
    size_t used = 0;
    metres = std::stod(text, &used);
    SOPE_CHECK(used == text.size(), "trailing characters");
  } catch (const std::exception&) {
    SOPE_THROW("{} '{}': expected {}m, cm, mm, in or metres per unit (e.g. 0.001)", option, text,
               allow_auto ? "auto, " : "");
  }
  SOPE_CHECK(std::isfinite(metres) && metres > 0.0 && metres <= 1000.0,
             "{} '{}': metres per unit must be in (0, 1000]", option, text);
  return metres;
}

}  // namespace

double ParseMeshUnit(const std::string& text, const std::string& option) {
  return ParseUnit(text, option, true);
}

double ParseLengthUnit(const std::string& text, const std::string& option) {
  return ParseUnit(text, option, false);
}

void AddMeshUnitFlag(CLI::App& app, std::string* text) {
  app.add_option("--units", *text,
                 "Unit of the mesh files: m, cm, mm, in, or metres per unit (e.g. 0.001); "
                 "auto (default) keeps a mesh whose bounding-box diagonal is 0.02-0.75 "
                 "units as metres and scales any other to a 0.25 m diagonal")
      ->capture_default_str();
}

Rigid3d ParsePose(const std::string& text, const std::string& option) {
  const std::vector<double> v = ParseNumbers(text, option);
  SOPE_CHECK(v.size() == 6, "{} '{}': expected rx,ry,rz,tx,ty,tz (degrees, metres)", option,
             text);
  constexpr double kDegree = kDegToRad;
  return Rigid3d(RotationFromEulerXYZ(v[0] * kDegree, v[1] * kDegree, v[2] * kDegree),
                 Eigen::Vector3d(v[3], v[4], v[5]));
}

int Parse(CLI::App& app, int argc, char** argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) {
      app.exit(e);  // --help, --help-all: the help text on stdout
      return 0;
    }
    // A usage error: one line like every other error (CLI11's own failure message is two).
    std::string message = e.what();
    for (char& c : message) {
      if (c == '\n' || c == '\r') c = ' ';
    }
    while (!message.empty() && message.back() == ' ') message.pop_back();
    std::fputs(fmt::format("{}: error: {} (see --help)\n", app.get_name(), message).c_str(),
               stderr);
    return 2;
  }
  return -1;
}

void LoggingFlags::Add(CLI::App& app) {
  app.add_flag("-v,--verbose", verbose, "More detail on stderr");
  app.add_flag("-q,--quiet", quiet, "Only errors on stderr");
}

void LoggingFlags::Apply() const {
  spdlog::set_level(quiet ? spdlog::level::err
                          : (verbose ? spdlog::level::debug : spdlog::level::info));
}

Progress::Progress(std::string label, size_t total)
    : label_(std::move(label)), total_(total), enabled_(::isatty(STDERR_FILENO) == 1) {}

Progress::~Progress() {
  if (enabled_) std::fputs("\n", stderr);
}

void Progress::Update(size_t done) {
  if (!enabled_ || total_ == 0) return;
  constexpr int kWidth = 30;
  const int filled = static_cast<int>(kWidth * done / total_);
  std::fputs(fmt::format("\r{} [{:<{}}] {}/{}", label_, std::string(filled, '#'), kWidth,
                         done, total_)
                 .c_str(),
             stderr);
  std::fflush(stderr);
}

}  // namespace cli
}  // namespace sope
