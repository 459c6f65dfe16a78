#include "capture/import_layouts.h"

#include <fnmatch.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <map>
#include <set>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/units.h"

namespace sope {
namespace {

// SLStudio's constants (src/codec/CodecGrayCode.cpp: Nhorz, Nvert; CodecPhaseShift2x3.cpp
// and CodecCalibration.cpp: nPhases).
constexpr int kSlStudioGrayBitsX = 10;
constexpr int kSlStudioGrayBitsY = 6;
constexpr int kSlStudioPhases = 16;
constexpr const char* kCalibrationFile = "calibration.yaml";

ImportedFrame Reference(ImportedFrame::Role role) {
  ImportedFrame frame;
  frame.role = role;
  return frame;
}

ImportedFrame Code(PatternAxis axis, PatternCode code, int bits, int bit, bool inverted) {
  ImportedFrame frame;
  frame.role = ImportedFrame::Role::kCode;
  frame.axis = axis;
  frame.code = code;
  frame.bits = bits;
  frame.bit = bit;
  frame.inverted = inverted;
  return frame;
}

ImportedFrame Phase(PatternAxis axis, double period_px, double shift_rad) {
  ImportedFrame frame;
  frame.role = ImportedFrame::Role::kPhase;
  frame.axis = axis;
  frame.period_px = period_px;
  frame.shift_rad = shift_rad;
  return frame;
}

bool HasX(PatternAxes axes) { return axes != PatternAxes::kY; }
bool HasY(PatternAxes axes) { return axes != PatternAxes::kX; }

// Three shifts 0, 2π/3, 4π/3 at each of the periods, as pstools::computePhaseVector draws
// them (amplitude ½(1 + cos(2π·i/pitch − phase)), i the pixel index).
void AppendThreeStep(PatternAxis axis, double period_px, std::vector<ImportedFrame>* frames) {
  for (int i = 0; i < 3; ++i) frames->push_back(Phase(axis, period_px, 2.0 * kPi / 3.0 * i));
}

void AppendTwoByThree(PatternAxes axes, int width, int height,
                      std::vector<ImportedFrame>* frames) {
  if (HasX(axes)) {
    AppendThreeStep(PatternAxis::kX, static_cast<double>(width) / kSlStudioPhases, frames);
    AppendThreeStep(PatternAxis::kX, width, frames);
  }
  if (HasY(axes)) {
    AppendThreeStep(PatternAxis::kY, static_cast<double>(height) / kSlStudioPhases, frames);
    AppendThreeStep(PatternAxis::kY, height, frames);
  }
}

int ParseInt(const std::string& text, const std::string& token) {
  SOPE_CHECK(!text.empty() && text.size() <= 3 &&
                 std::all_of(text.begin(), text.end(), [](char c) { return std::isdigit(c); }),
             "order token '{}': '{}' is not a bit number", token, text);
  return std::stoi(text);
}

double ParseReal(const std::string& text, const std::string& token, const char* what) {
  size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  SOPE_CHECK(used == text.size() && used > 0 && std::isfinite(value),
             "order token '{}': {} '{}' is not a number", token, what, text);
  return value;
}

std::vector<std::string> Split(const std::string& text, char separator) {
  std::vector<std::string> parts;
  std::string part;
  for (char c : text) {
    if (c == separator) {
      parts.push_back(part);
      part.clear();
    } else if (!std::isspace(static_cast<unsigned char>(c))) {
      part += c;
    }
  }
  parts.push_back(part);
  return parts;
}

std::string RoleName(ImportedFrame::Role role) {
  switch (role) {
    case ImportedFrame::Role::kWhite: return "white";
    case ImportedFrame::Role::kBlack: return "black";
    case ImportedFrame::Role::kCode: return "code";
    case ImportedFrame::Role::kPhase: return "phase";
    case ImportedFrame::Role::kSkip: return "skip";
  }
  return "?";
}

bool IsImageFile(const std::string& name) {
  static const std::set<std::string> kExtensions = {"png", "jpg", "jpeg", "bmp", "tif",
                                                    "tiff", "pgm", "ppm"};
  return kExtensions.count(FileExtension(name)) == 1;
}

}  // namespace

std::string ToString(ImportLayout layout) {
  switch (layout) {
    case ImportLayout::kOpenCvGrayCode: return "opencv-graycode";
    case ImportLayout::kSlStudioGrayCode: return "slstudio-graycode";
    case ImportLayout::kSlStudioPhaseShift2x3: return "slstudio-2x3";
    case ImportLayout::kSlStudioPhaseShift3: return "slstudio-3";
    case ImportLayout::kSlStudioCalibration: return "slstudio-calibration";
    case ImportLayout::kOrder: return "order";
  }
  return "?";
}

ImportLayout ImportLayoutFromString(const std::string& text) {
  for (ImportLayout layout :
       {ImportLayout::kOpenCvGrayCode, ImportLayout::kSlStudioGrayCode,
        ImportLayout::kSlStudioPhaseShift2x3, ImportLayout::kSlStudioPhaseShift3,
        ImportLayout::kSlStudioCalibration, ImportLayout::kOrder}) {
    if (ToString(layout) == text) return layout;
  }
  SOPE_THROW("unknown layout '{}' (expected opencv-graycode, slstudio-graycode, slstudio-2x3, "
             "slstudio-3, slstudio-calibration or order)",
             text);
}

void ImportOptions::Check() const {
  SOPE_CHECK(projector_width > 0 && projector_height > 0 && projector_width <= 65536 &&
                 projector_height <= 65536,
             "invalid projector size {}x{}", projector_width, projector_height);
  if (layout == ImportLayout::kOrder) {
    SOPE_CHECK(!order.empty(), "layout 'order' needs an order spec (--order)");
  } else {
    SOPE_CHECK(order.empty(), "an order spec is only for layout 'order' (got layout '{}')",
               ToString(layout));
  }
  if (layout == ImportLayout::kSlStudioGrayCode) {
    // SLStudio projects bit ⌈log2 size⌉ − 1 − p for p < 10 (columns) / 6 (rows): a smaller
    // projector has fewer bits than SLStudio projects, which its own codec cannot decode.
    SOPE_CHECK(!HasX(axes) || BitsForSize(projector_width) >= kSlStudioGrayBitsX,
               "SLStudio's Gray codec projects {} column bits; a {}-pixel-wide projector has "
               "only {}",
               kSlStudioGrayBitsX, projector_width, BitsForSize(projector_width));
    SOPE_CHECK(!HasY(axes) || BitsForSize(projector_height) >= kSlStudioGrayBitsY,
               "SLStudio's Gray codec projects {} row bits; a {}-pixel-high projector has only "
               "{}",
               kSlStudioGrayBitsY, projector_height, BitsForSize(projector_height));
  }
}

std::vector<ImportedFrame> LayoutFrames(const ImportOptions& options) {
  options.Check();
  const int width = options.projector_width;
  const int height = options.projector_height;
  std::vector<ImportedFrame> frames;
  switch (options.layout) {
    case ImportLayout::kOpenCvGrayCode:
      for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
        const int bits = BitsForSize(axis == PatternAxis::kX ? width : height);
        for (int bit = bits - 1; bit >= 0; --bit) {
          frames.push_back(Code(axis, PatternCode::kGray, bits, bit, false));
          frames.push_back(Code(axis, PatternCode::kGray, bits, bit, true));
        }
      }
      frames.push_back(Reference(ImportedFrame::Role::kWhite));
      frames.push_back(Reference(ImportedFrame::Role::kBlack));
      break;
    case ImportLayout::kSlStudioGrayCode: {
      frames.push_back(Reference(ImportedFrame::Role::kWhite));
      frames.push_back(Reference(ImportedFrame::Role::kBlack));
      const auto append = [&](PatternAxis axis, int size, int projected) {
        const int bits = BitsForSize(size);
        for (int p = 0; p < projected; ++p) {
          frames.push_back(Code(axis, PatternCode::kGray, bits, bits - 1 - p, false));
        }
      };
      if (HasX(options.axes)) append(PatternAxis::kX, width, kSlStudioGrayBitsX);
      if (HasY(options.axes)) append(PatternAxis::kY, height, kSlStudioGrayBitsY);
      break;
    }
    case ImportLayout::kSlStudioPhaseShift2x3:
      AppendTwoByThree(options.axes, width, height, &frames);
      break;
    case ImportLayout::kSlStudioPhaseShift3:
      AppendThreeStep(PatternAxis::kX, width, &frames);
      break;
    case ImportLayout::kSlStudioCalibration:
      AppendTwoByThree(PatternAxes::kXY, width, height, &frames);
      break;
    case ImportLayout::kOrder:
      frames = ParseOrderSpec(options.order, width, height, options.order_code);
      break;
  }
  return frames;
}

std::vector<ImportedFrame> ParseOrderSpec(const std::string& spec, int projector_width,
                                          int projector_height, PatternCode code) {
  std::vector<ImportedFrame> frames;
  for (const std::string& token : Split(spec, ',')) {
    SOPE_CHECK(!token.empty(), "order spec '{}': empty token", spec);
    if (token == "white") {
      frames.push_back(Reference(ImportedFrame::Role::kWhite));
      continue;
    }
    if (token == "black") {
      frames.push_back(Reference(ImportedFrame::Role::kBlack));
      continue;
    }
    if (token == "skip") {
      frames.push_back(Reference(ImportedFrame::Role::kSkip));
      continue;
    }
    if (token.rfind("phase:", 0) == 0) {
      const std::vector<std::string> parts = Split(token, ':');
      SOPE_CHECK(parts.size() == 4 && (parts[1] == "x" || parts[1] == "y"),
                 "order token '{}': expected phase:<x|y>:<period_px>:<shift_deg>", token);
      const double period = ParseReal(parts[2], token, "period");
      SOPE_CHECK(period > 0.0, "order token '{}': period must be > 0", token);
      const double shift_deg = ParseReal(parts[3], token, "shift");
      frames.push_back(Phase(PatternAxisFromString(parts[1]), period, shift_deg * kPi / 180.0));
      continue;
    }
    SOPE_CHECK(token[0] == 'x' || token[0] == 'y',
               "order token '{}': expected white, black, skip, x<bit>[i], y<bit>[i], "
               "x<hi>-<lo>[i|+i] or phase:<axis>:<period_px>:<shift_deg>",
               token);
    const PatternAxis axis = token[0] == 'x' ? PatternAxis::kX : PatternAxis::kY;
    const int bits = BitsForSize(axis == PatternAxis::kX ? projector_width : projector_height);
    std::string body = token.substr(1);
    bool inverse_only = false, pairs = false;
    if (body.size() >= 2 && body.compare(body.size() - 2, 2, "+i") == 0) {
      pairs = true;
      body.resize(body.size() - 2);
    } else if (!body.empty() && body.back() == 'i') {
      inverse_only = true;
      body.pop_back();
    }
    const size_t dash = body.find('-');
    const int first = ParseInt(dash == std::string::npos ? body : body.substr(0, dash), token);
    const int last = dash == std::string::npos ? first : ParseInt(body.substr(dash + 1), token);
    for (int bit : {first, last}) {
      SOPE_CHECK(bit < bits, "order token '{}': bit {} out of range for a {}-pixel axis "
                 "({} bits, 0..{})",
                 token, bit, axis == PatternAxis::kX ? projector_width : projector_height, bits,
                 bits - 1);
    }
    const int step = last >= first ? 1 : -1;
    for (int bit = first;; bit += step) {
      frames.push_back(Code(axis, code, bits, bit, inverse_only));
      if (pairs) frames.push_back(Code(axis, code, bits, bit, true));
      if (bit == last) break;
    }
  }
  return frames;
}

bool NaturalLess(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    const bool digit_a = std::isdigit(static_cast<unsigned char>(a[i]));
    const bool digit_b = std::isdigit(static_cast<unsigned char>(b[j]));
    if (digit_a && digit_b) {
      size_t end_a = i, end_b = j;
      while (end_a < a.size() && std::isdigit(static_cast<unsigned char>(a[end_a]))) ++end_a;
      while (end_b < b.size() && std::isdigit(static_cast<unsigned char>(b[end_b]))) ++end_b;
      // Compare the numbers without leading zeros: longer is larger, then digit by digit.
      size_t start_a = i, start_b = j;
      while (start_a + 1 < end_a && a[start_a] == '0') ++start_a;
      while (start_b + 1 < end_b && b[start_b] == '0') ++start_b;
      const std::string number_a = a.substr(start_a, end_a - start_a);
      const std::string number_b = b.substr(start_b, end_b - start_b);
      if (number_a.size() != number_b.size()) return number_a.size() < number_b.size();
      if (number_a != number_b) return number_a < number_b;
      i = end_a;
      j = end_b;
      continue;
    }
    if (a[i] != b[j]) return static_cast<unsigned char>(a[i]) < static_cast<unsigned char>(b[j]);
    ++i;
    ++j;
  }
  if (i < a.size() || j < b.size()) return j < b.size() && i >= a.size();
  return a < b;  // equal up to zero padding
}

std::vector<std::string> ListImagesInNameOrder(const std::string& directory,
                                               const std::string& select) {
  namespace fs = std::filesystem;
  std::error_code error;
  SOPE_CHECK(fs::is_directory(directory, error), "image folder {}: not a directory", directory);
  std::vector<std::string> files;
  for (const fs::directory_entry& entry : fs::directory_iterator(directory, error)) {
    if (!entry.is_regular_file(error)) continue;
    const std::string name = entry.path().filename().string();
    if (!IsImageFile(name)) continue;
    if (!select.empty() && fnmatch(select.c_str(), name.c_str(), 0) != 0) continue;
    files.push_back(name);
  }
  SOPE_CHECK(!error, "image folder {}: {}", directory, error.message());
  std::sort(files.begin(), files.end(), NaturalLess);
  return files;
}

bool ImportedFrameSet::HasPhase() const {
  return std::any_of(frames.begin(), frames.end(), [](const ImportedFrame& frame) {
    return frame.role == ImportedFrame::Role::kPhase;
  });
}

FrameSetManifest ImportedFrameSet::ToManifest() const {
  SOPE_CHECK(!HasPhase(), "a frame set with phase frames has no Gray-code manifest");
  FrameSetManifest manifest;
  manifest.camera_width = camera_width;
  manifest.camera_height = camera_height;
  manifest.projector_width = projector_width;
  manifest.projector_height = projector_height;
  manifest.calibration = calibration;
  for (const ImportedFrame& frame : frames) {
    FrameInfo info;
    info.file = frame.file;
    info.role = frame.role == ImportedFrame::Role::kWhite   ? FrameRole::kWhite
                : frame.role == ImportedFrame::Role::kBlack ? FrameRole::kBlack
                                                            : FrameRole::kCode;
    info.axis = frame.axis;
    info.code = frame.code;
    info.bits = frame.bits;
    info.bit = frame.bit;
    info.inverted = frame.inverted;
    manifest.frames.push_back(info);
  }
  return manifest;
}

void ImportedFrameSet::Check() const {
  if (!HasPhase()) {
    ToManifest().Check();
    return;
  }
  SOPE_CHECK(camera_width > 0 && camera_height > 0, "invalid camera size {}x{}", camera_width,
             camera_height);
  SOPE_CHECK(projector_width > 0 && projector_height > 0, "invalid projector size {}x{}",
             projector_width, projector_height);
  std::set<std::string> files;
  int whites = 0, blacks = 0;
  // (axis, period) → shifts; axis → has Gray frames.
  std::map<std::pair<int, double>, std::vector<double>> groups;
  std::set<int> coded_axes;
  for (size_t i = 0; i < frames.size(); ++i) {
    const ImportedFrame& frame = frames[i];
    SOPE_CHECK(!frame.file.empty() && frame.file.find('/') == std::string::npos &&
                   frame.file.find("..") == std::string::npos,
               "frame {}: file '{}' must be a plain name inside the frame-set directory", i,
               frame.file);
    SOPE_CHECK(files.insert(frame.file).second, "frame {}: file '{}' listed twice", i,
               frame.file);
    whites += frame.role == ImportedFrame::Role::kWhite;
    blacks += frame.role == ImportedFrame::Role::kBlack;
    if (frame.role == ImportedFrame::Role::kCode) coded_axes.insert(static_cast<int>(frame.axis));
    if (frame.role != ImportedFrame::Role::kPhase) continue;
    SOPE_CHECK(frame.period_px > 0.0 && std::isfinite(frame.period_px) &&
                   std::isfinite(frame.shift_rad),
               "frame {} ({}): invalid period {} or shift {}", i, frame.file, frame.period_px,
               frame.shift_rad);
    groups[{static_cast<int>(frame.axis), frame.period_px}].push_back(frame.shift_rad);
  }
  SOPE_CHECK(whites <= 1 && blacks <= 1, "more than one white or black frame");
  std::map<int, double> coarsest;
  for (const auto& [key, shifts] : groups) {
    std::set<long> distinct;
    for (double shift : shifts) {
      const double wrapped = std::remainder(shift, 2.0 * kPi);
      distinct.insert(std::lround(wrapped * 1e6));
    }
    SOPE_CHECK(distinct.size() >= 3, "phase group axis {} period {} px has {} distinct shifts "
               "(needs at least 3)",
               ToString(static_cast<PatternAxis>(key.first)), key.second, distinct.size());
    double& best = coarsest[key.first];
    best = std::max(best, key.second);
  }
  for (const auto& [axis, period] : coarsest) {
    const int size = axis == static_cast<int>(PatternAxis::kX) ? projector_width
                                                               : projector_height;
    SOPE_CHECK(period >= size || coded_axes.count(axis) == 1,
               "axis {}: the coarsest phase period {} px is shorter than the projector ({} px) "
               "and no Gray code unwraps it",
               ToString(static_cast<PatternAxis>(axis)), period, size);
  }
  // The Gray frames, if any, must themselves be a consistent code.
  if (!coded_axes.empty()) {
    ImportedFrameSet codes = *this;
    codes.frames.erase(std::remove_if(codes.frames.begin(), codes.frames.end(),
                                      [](const ImportedFrame& frame) {
                                        return frame.role == ImportedFrame::Role::kPhase;
                                      }),
                       codes.frames.end());
    FrameSetManifest manifest = codes.ToManifest();
    // Phase sets need no white/black references for their Gray frames' threshold when the
    // code has inverses; otherwise the manifest rule applies as for Gray-only sets.
    manifest.Check();
  }
}

std::string SerializeImportedFrameSet(const ImportedFrameSet& frame_set) {
  if (!frame_set.HasPhase()) return SerializeFrameSetManifest(frame_set.ToManifest());
  using nlohmann::json;
  json root;
  root["format"] = FrameSetManifest::kFormat;
  root["camera"] = {{"width", frame_set.camera_width}, {"height", frame_set.camera_height}};
  root["projector"] = {{"width", frame_set.projector_width},
                       {"height", frame_set.projector_height}};
  json frames = json::array();
  for (const ImportedFrame& frame : frame_set.frames) {
    json entry = {{"file", frame.file}, {"role", RoleName(frame.role)}};
    if (frame.role == ImportedFrame::Role::kCode) {
      entry["axis"] = ToString(frame.axis);
      entry["code"] = ToString(frame.code);
      entry["bits"] = frame.bits;
      entry["bit"] = frame.bit;
      entry["inverted"] = frame.inverted;
    } else if (frame.role == ImportedFrame::Role::kPhase) {
      entry["axis"] = ToString(frame.axis);
      entry["period"] = frame.period_px;
      entry["shift"] = frame.shift_rad;
    }
    frames.push_back(entry);
  }
  root["frames"] = frames;
  if (!frame_set.calibration.empty()) root["calibration"] = frame_set.calibration;
  return root.dump(2) + "\n";
}

ImportedFrameSet MatchImagesToLayout(const std::vector<std::string>& files,
                                     const std::vector<ImportedFrame>& layout,
                                     const std::string& directory) {
  SOPE_CHECK(files.size() == layout.size(),
             "the layout expects {} images, {} has {} (images are taken in name order; "
             "select some with --select)",
             layout.size(), directory, files.size());
  ImportedFrameSet frame_set;
  for (size_t i = 0; i < files.size(); ++i) {
    if (layout[i].role == ImportedFrame::Role::kSkip) continue;
    ImportedFrame frame = layout[i];
    frame.file = files[i];
    frame_set.frames.push_back(frame);
  }
  return frame_set;
}

ImportSummary ImportCapture(const std::string& images_dir, const ImportOptions& options,
                            const std::string& out_dir,
                            const std::optional<RigCalibration>& calibration) {
  const std::vector<ImportedFrame> layout = LayoutFrames(options);
  const std::vector<std::string> files = ListImagesInNameOrder(images_dir, options.select);
  SOPE_CHECK(!files.empty(), "image folder {}: no images{}", images_dir,
             options.select.empty() ? "" : fmt::format(" matching '{}'", options.select));
  ImportedFrameSet frame_set = MatchImagesToLayout(files, layout, images_dir);
  frame_set.projector_width = options.projector_width;
  frame_set.projector_height = options.projector_height;
  // Every image must decode and share one size (the decoder reads them as grey).
  for (const ImportedFrame& frame : frame_set.frames) {
    const cv::Mat image = ReadImage(JoinPath(images_dir, frame.file), cv::IMREAD_GRAYSCALE);
    if (frame_set.camera_width == 0) {
      frame_set.camera_width = image.cols;
      frame_set.camera_height = image.rows;
    }
    SOPE_CHECK(image.cols == frame_set.camera_width && image.rows == frame_set.camera_height,
               "image {}: {}x{}, but {} is {}x{} (all images of a capture share one size)",
               frame.file, image.cols, image.rows, frame_set.frames.front().file,
               frame_set.camera_width, frame_set.camera_height);
  }
  if (calibration) {
    calibration->Check();
    SOPE_CHECK(calibration->camera.width == frame_set.camera_width &&
                   calibration->camera.height == frame_set.camera_height,
               "calibration camera size {}x{} differs from the images' {}x{}",
               calibration->camera.width, calibration->camera.height, frame_set.camera_width,
               frame_set.camera_height);
    SOPE_CHECK(calibration->projector.width == options.projector_width &&
                   calibration->projector.height == options.projector_height,
               "calibration projector size {}x{} differs from --projector {}x{}",
               calibration->projector.width, calibration->projector.height,
               options.projector_width, options.projector_height);
    frame_set.calibration = kCalibrationFile;
  }
  frame_set.Check();

  StagedDirectory staged(out_dir);
  for (const ImportedFrame& frame : frame_set.frames) {
    std::error_code error;
    std::filesystem::copy_file(JoinPath(images_dir, frame.file),
                               JoinPath(staged.path(), frame.file), error);
    SOPE_CHECK(!error, "copying {} into {}: {}", frame.file, out_dir, error.message());
  }
  if (calibration) WriteRigCalibration(JoinPath(staged.path(), kCalibrationFile), *calibration);
  WriteFileAtomic(JoinPath(staged.path(), FrameSetManifest::kFileName),
                  SerializeImportedFrameSet(frame_set));
  staged.Commit();

  ImportSummary summary;
  summary.images = frame_set.frames.size();
  summary.skipped = files.size() - frame_set.frames.size();
  summary.camera_width = frame_set.camera_width;
  summary.camera_height = frame_set.camera_height;
  summary.has_phase = frame_set.HasPhase();
  summary.has_calibration = calibration.has_value();
  return summary;
}

}  // namespace sope
