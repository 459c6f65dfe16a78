#include "core/frame_set.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <tuple>
#include <type_traits>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/file_util.h"

namespace sope {
namespace {

using nlohmann::json;

constexpr int kMaxCodeBits = 16;
constexpr double kTwoPi = 6.283185307179586476925286766559;
// Phase shifts closer than this (modulo 2π) count as one, radians.
constexpr double kDistinctShiftRad = 1e-6;
constexpr int kMaxDeviceSize = 1 << kMaxCodeBits;

template <typename T>
T Get(const json& object, const char* key, const std::string& where) {
  SOPE_CHECK(object.is_object() && object.contains(key), "{}: missing '{}'", where, key);
  if constexpr (std::is_integral_v<T> && !std::is_same_v<T, bool>) {
    // nlohmann's get<int>() truncates 320.7, wraps 4294967616 and saturates 1e30: only
    // an exact integer in range is accepted.
    const json& value = object.at(key);
    SOPE_CHECK(value.is_number_integer(), "{}: '{}' has the wrong type: must be an integer, got {}", where, key,
               value.dump());
    const bool in_range =
        value.is_number_unsigned()
            ? value.get<uint64_t>() <= static_cast<uint64_t>(std::numeric_limits<T>::max())
            : value.get<int64_t>() >= static_cast<int64_t>(std::numeric_limits<T>::min()) &&
                  value.get<int64_t>() <= static_cast<int64_t>(std::numeric_limits<T>::max());
    SOPE_CHECK(in_range, "{}: '{}' = {} is out of range", where, key, value.dump());
  }
  try {
    return object.at(key).get<T>();
  } catch (const json::exception&) {
    SOPE_THROW("{}: '{}' has the wrong type", where, key);
  }
}

}  // namespace

int BitsForSize(int size) {
  int bits = 1;
  while ((1 << bits) < size) ++bits;
  return bits;
}

std::string ToString(FrameRole role) {
  switch (role) {
    case FrameRole::kWhite: return "white";
    case FrameRole::kBlack: return "black";
    case FrameRole::kCode: return "code";
    case FrameRole::kPhase: return "phase";
  }
  return "?";
}
std::string ToString(PatternAxis axis) { return axis == PatternAxis::kX ? "x" : "y"; }
std::string ToString(PatternCode code) { return code == PatternCode::kGray ? "gray" : "binary"; }

FrameRole FrameRoleFromString(const std::string& text) {
  if (text == "white") return FrameRole::kWhite;
  if (text == "black") return FrameRole::kBlack;
  if (text == "code") return FrameRole::kCode;
  if (text == "phase") return FrameRole::kPhase;
  SOPE_THROW("unknown frame role '{}' (expected white, black, code or phase)", text);
}
PatternAxis PatternAxisFromString(const std::string& text) {
  if (text == "x") return PatternAxis::kX;
  if (text == "y") return PatternAxis::kY;
  SOPE_THROW("unknown pattern axis '{}' (expected x or y)", text);
}
PatternCode PatternCodeFromString(const std::string& text) {
  if (text == "gray") return PatternCode::kGray;
  if (text == "binary") return PatternCode::kBinary;
  SOPE_THROW("unknown pattern code '{}' (expected gray or binary)", text);
}

void FrameSetManifest::Check() const {
  SOPE_CHECK(camera_width > 0 && camera_height > 0 && camera_width < kMaxDeviceSize &&
                 camera_height < kMaxDeviceSize,
             "invalid camera size {}x{}", camera_width, camera_height);
  SOPE_CHECK(projector_width > 0 && projector_height > 0 &&
                 projector_width <= kMaxDeviceSize && projector_height <= kMaxDeviceSize,
             "invalid projector size {}x{}", projector_width, projector_height);
  SOPE_CHECK(!frames.empty(), "no frames");
  std::set<std::string> files;
  std::set<std::tuple<int, int, bool>> codes;
  std::map<int, std::pair<int, PatternCode>> axis_format;
  int whites = 0, blacks = 0, phase_frames = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    const FrameInfo& frame = frames[i];
    SOPE_CHECK(!frame.file.empty(), "frame {}: empty file name", i);
    SOPE_CHECK(frame.file.find("..") == std::string::npos && frame.file[0] != '/',
               "frame {}: file '{}' must be a plain name inside the frame-set directory", i,
               frame.file);
    SOPE_CHECK(files.insert(frame.file).second, "frame {}: file '{}' listed twice", i,
               frame.file);
    if (frame.role == FrameRole::kWhite) {
      ++whites;
      continue;
    }
    if (frame.role == FrameRole::kBlack) {
      ++blacks;
      continue;
    }
    if (frame.role == FrameRole::kPhase) {
      SOPE_CHECK(std::isfinite(frame.period) && frame.period > 0.0,
                 "frame {} ({}): phase period {} must be a positive, finite number of "
                 "projector pixels", i, frame.file, frame.period);
      SOPE_CHECK(std::isfinite(frame.shift), "frame {} ({}): phase shift {} is not finite", i,
                 frame.file, frame.shift);
      ++phase_frames;
      continue;
    }
    const int size = frame.axis == PatternAxis::kX ? projector_width : projector_height;
    SOPE_CHECK(frame.bits >= 1 && frame.bits <= kMaxCodeBits, "frame {} ({}): bits {} out of "
               "range 1..{}", i, frame.file, frame.bits, kMaxCodeBits);
    SOPE_CHECK(frame.bits >= BitsForSize(size), "frame {} ({}): {} bits cannot code {} "
               "projector {} (needs {})", i, frame.file, frame.bits, size,
               frame.axis == PatternAxis::kX ? "columns" : "rows", BitsForSize(size));
    SOPE_CHECK(frame.bit >= 0 && frame.bit < frame.bits, "frame {} ({}): bit {} not in 0..{}",
               i, frame.file, frame.bit, frame.bits - 1);
    const int axis = static_cast<int>(frame.axis);
    const auto [it, inserted] = axis_format.emplace(axis, std::make_pair(frame.bits, frame.code));
    SOPE_CHECK(it->second.first == frame.bits && it->second.second == frame.code,
               "frame {} ({}): axis {} mixes code lengths or code types", i, frame.file,
               ToString(frame.axis));
    SOPE_CHECK(codes.emplace(axis, frame.bit, frame.inverted).second,
               "frame {} ({}): axis {} bit {}{} appears twice", i, frame.file,
               ToString(frame.axis), frame.bit, frame.inverted ? " (inverted)" : "");
  }
  SOPE_CHECK(whites <= 1 && blacks <= 1, "more than one white or black frame");
  SOPE_CHECK(!axis_format.empty() || phase_frames > 0, "no code or phase frames");
  CheckPhaseGroups();
  for (const auto& [axis, bit, inverted] : codes) {
    if (inverted) {
      SOPE_CHECK(codes.count({axis, bit, false}) == 1,
                 "axis {} bit {}: inverted frame without its pattern",
                 ToString(static_cast<PatternAxis>(axis)), bit);
    }
  }
  // The coded bits of an axis must be the top bits, contiguous: bits lowest..bits-1.
  for (const auto& [axis, format] : axis_format) {
    const PatternAxis pattern_axis = static_cast<PatternAxis>(axis);
    const int lowest = AxisLowestBit(pattern_axis);
    for (int bit = lowest; bit < format.first; ++bit) {
      SOPE_CHECK(codes.count({axis, bit, false}) == 1,
                 "axis {}: bit {} missing (bits {}..{} must all be present)",
                 ToString(pattern_axis), bit, lowest, format.first - 1);
    }
  }
  // Without inverse frames a per-pixel threshold needs both references.
  bool any_without_inverse = false;
  for (const auto& [axis, bit, inverted] : codes) {
    if (!inverted && codes.count({axis, bit, true}) == 0) any_without_inverse = true;
  }
  // Phase sets may threshold a Gray code of a phase axis at the sinusoids' offset instead.
  bool without_reference = false;
  for (const auto& [axis, bit, inverted] : codes) {
    if (!inverted && codes.count({axis, bit, true}) == 0 &&
        !HasPhaseAxis(static_cast<PatternAxis>(axis))) {
      without_reference = true;
    }
  }
  SOPE_CHECK(!without_reference || (whites == 1 && blacks == 1),
             "code frames without inverses need both a white and a black frame");
}

void FrameSetManifest::CheckPhaseGroups() const {
  for (PatternAxis axis : {PatternAxis::kX, PatternAxis::kY}) {
    const std::vector<PhaseGroup> groups = PhaseGroups(axis);
    if (groups.empty()) continue;
    const std::string name = ToString(axis);
    for (const PhaseGroup& group : groups) {
      // Distinct shifts modulo 2π: three distinct points on the unit circle make the
      // least-squares system [1, cos s, sin s] regular.
      std::vector<double> wrapped;
      for (double shift : group.shifts) {
        double w = std::fmod(shift, kTwoPi);
        if (w < 0.0) w += kTwoPi;
        bool seen = false;
        for (double other : wrapped) {
          const double d = std::abs(w - other);
          seen = seen || std::min(d, kTwoPi - d) < kDistinctShiftRad;
        }
        if (!seen) wrapped.push_back(w);
      }
      SOPE_CHECK(wrapped.size() >= 3,
                 "axis {} phase group of period {}: {} distinct shift{} (frame '{}'); a group "
                 "needs at least 3 distinct shifts", name, group.period, wrapped.size(),
                 wrapped.size() == 1 ? "" : "s", frames[group.frames.front()].file);
    }
    const PhaseGroup& coarsest = groups.front();
    const int size = axis == PatternAxis::kX ? projector_width : projector_height;
    if (AxisBits(axis) > 0) {
      // Gray + phase: the code gives the period index (blocks of 2^lowest pixels), one
      // period wide, or half a period with one complementary bit.
      SOPE_CHECK(AxisCode(axis) == PatternCode::kGray,
                 "axis {}: phase frames can be combined with a Gray code only, not {}", name,
                 ToString(AxisCode(axis)));
      const double block = std::ldexp(1.0, AxisLowestBit(axis));
      SOPE_CHECK(block == coarsest.period || 2.0 * block == coarsest.period,
                 "axis {}: the Gray code's finest stripe is {} px but the coarsest phase "
                 "period is {} px (they must be equal, or the stripe half the period with a "
                 "complementary bit)", name, block, coarsest.period);
    } else {
      SOPE_CHECK(coarsest.absolute,
                 "axis {}: the phase group of period {} px is finer than the projector ({} "
                 "px) and has no coarser group or Gray code to unwrap it", name,
                 coarsest.period, size);
    }
  }
}

bool FrameSetManifest::HasPhase() const {
  for (const FrameInfo& f : frames) {
    if (f.role == FrameRole::kPhase) return true;
  }
  return false;
}

bool FrameSetManifest::HasPhaseAxis(PatternAxis axis) const {
  for (const FrameInfo& f : frames) {
    if (f.role == FrameRole::kPhase && f.axis == axis) return true;
  }
  return false;
}

std::vector<PhaseGroup> FrameSetManifest::PhaseGroups(PatternAxis axis) const {
  std::vector<PhaseGroup> groups;
  const int size = axis == PatternAxis::kX ? projector_width : projector_height;
  for (size_t i = 0; i < frames.size(); ++i) {
    const FrameInfo& f = frames[i];
    if (f.role != FrameRole::kPhase || f.axis != axis) continue;
    auto it = std::find_if(groups.begin(), groups.end(),
                           [&](const PhaseGroup& g) { return g.period == f.period; });
    if (it == groups.end()) {
      PhaseGroup group;
      group.axis = axis;
      group.period = f.period;
      group.absolute = f.period >= size;
      groups.push_back(group);
      it = groups.end() - 1;
    }
    it->frames.push_back(i);
    it->shifts.push_back(f.shift);
  }
  std::stable_sort(groups.begin(), groups.end(),
                   [](const PhaseGroup& a, const PhaseGroup& b) { return a.period > b.period; });
  return groups;
}

std::optional<size_t> FrameSetManifest::Find(FrameRole role) const {
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].role == role) return i;
  }
  return std::nullopt;
}

std::optional<size_t> FrameSetManifest::FindCode(PatternAxis axis, int bit,
                                                 bool inverted) const {
  for (size_t i = 0; i < frames.size(); ++i) {
    const FrameInfo& f = frames[i];
    if (f.role == FrameRole::kCode && f.axis == axis && f.bit == bit &&
        f.inverted == inverted) {
      return i;
    }
  }
  return std::nullopt;
}

bool FrameSetManifest::HasAxis(PatternAxis axis) const { return AxisBits(axis) > 0; }

int FrameSetManifest::AxisBits(PatternAxis axis) const {
  for (const FrameInfo& f : frames) {
    if (f.role == FrameRole::kCode && f.axis == axis) return f.bits;
  }
  return 0;
}

int FrameSetManifest::AxisLowestBit(PatternAxis axis) const {
  int lowest = kMaxCodeBits;
  for (const FrameInfo& f : frames) {
    if (f.role == FrameRole::kCode && f.axis == axis) lowest = std::min(lowest, f.bit);
  }
  return lowest;
}

PatternCode FrameSetManifest::AxisCode(PatternAxis axis) const {
  for (const FrameInfo& f : frames) {
    if (f.role == FrameRole::kCode && f.axis == axis) return f.code;
  }
  return PatternCode::kGray;
}

FrameSetManifest ParseFrameSetManifest(const std::string& json_text, const std::string& source) {
  json root;
  try {
    root = json::parse(json_text);
  } catch (const json::exception& e) {  // parse_error, or out_of_range: a number overflow
    SOPE_THROW("{}: not valid JSON ({})", source, e.what());
  }
  SOPE_CHECK(root.is_object(), "{}: top level must be an object", source);
  const std::string format = Get<std::string>(root, "format", source);
  SOPE_CHECK(format == FrameSetManifest::kFormat, "{}: unsupported format '{}' (expected '{}')",
             source, format, FrameSetManifest::kFormat);
  FrameSetManifest manifest;
  const json camera = Get<json>(root, "camera", source);
  manifest.camera_width = Get<int>(camera, "width", source + " camera");
  manifest.camera_height = Get<int>(camera, "height", source + " camera");
  const json projector = Get<json>(root, "projector", source);
  manifest.projector_width = Get<int>(projector, "width", source + " projector");
  manifest.projector_height = Get<int>(projector, "height", source + " projector");
  const json frames = Get<json>(root, "frames", source);
  SOPE_CHECK(frames.is_array(), "{}: 'frames' must be an array", source);
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string where = fmt::format("{} frame {}", source, i);
    const json& entry = frames[i];
    FrameInfo frame;
    frame.file = Get<std::string>(entry, "file", where);
    try {
      frame.role = FrameRoleFromString(Get<std::string>(entry, "role", where));
      if (frame.role == FrameRole::kCode) {
        frame.axis = PatternAxisFromString(Get<std::string>(entry, "axis", where));
        frame.code = PatternCodeFromString(Get<std::string>(entry, "code", where));
        frame.bits = Get<int>(entry, "bits", where);
        frame.bit = Get<int>(entry, "bit", where);
        frame.inverted = entry.contains("inverted") ? Get<bool>(entry, "inverted", where) : false;
      } else if (frame.role == FrameRole::kPhase) {
        frame.axis = PatternAxisFromString(Get<std::string>(entry, "axis", where));
        frame.period = Get<double>(entry, "period", where);
        frame.shift = Get<double>(entry, "shift", where);
      }
    } catch (const Error& e) {
      const std::string message = e.what();
      if (message.rfind(source, 0) == 0) throw;
      SOPE_THROW("{}: {}", where, message);
    }
    manifest.frames.push_back(frame);
  }
  if (root.contains("calibration") && !root["calibration"].is_null()) {
    manifest.calibration = Get<std::string>(root, "calibration", source);
  }
  try {
    manifest.Check();
  } catch (const Error& e) {
    SOPE_THROW("{}: {}", source, e.what());
  }
  return manifest;
}

std::string SerializeFrameSetManifest(const FrameSetManifest& manifest) {
  json root;
  root["format"] = FrameSetManifest::kFormat;
  root["camera"] = {{"width", manifest.camera_width}, {"height", manifest.camera_height}};
  root["projector"] = {{"width", manifest.projector_width},
                       {"height", manifest.projector_height}};
  json frames = json::array();
  for (const FrameInfo& frame : manifest.frames) {
    json entry = {{"file", frame.file}, {"role", ToString(frame.role)}};
    if (frame.role == FrameRole::kCode) {
      entry["axis"] = ToString(frame.axis);
      entry["code"] = ToString(frame.code);
      entry["bits"] = frame.bits;
      entry["bit"] = frame.bit;
      entry["inverted"] = frame.inverted;
    } else if (frame.role == FrameRole::kPhase) {
      entry["axis"] = ToString(frame.axis);
      entry["period"] = frame.period;
      entry["shift"] = frame.shift;
    }
    frames.push_back(entry);
  }
  root["frames"] = frames;
  if (!manifest.calibration.empty()) root["calibration"] = manifest.calibration;
  return root.dump(2) + "\n";
}

FrameSetManifest ReadFrameSetManifest(const std::string& directory) {
  const std::string path = JoinPath(directory, FrameSetManifest::kFileName);
  return ParseFrameSetManifest(ReadFileToString(path, "frame-set manifest"), path);
}

void FrameSet::Check() const {
  manifest.Check();
  SOPE_CHECK(images.size() == manifest.frames.size(), "frame set has {} images for {} frames",
             images.size(), manifest.frames.size());
  for (size_t i = 0; i < images.size(); ++i) {
    const cv::Mat& image = images[i];
    const std::string& name = manifest.frames[i].file;
    SOPE_CHECK(!image.empty(), "frame {} ({}): no image", i, name);
    SOPE_CHECK(image.type() == CV_8UC1 || image.type() == CV_16UC1,
               "frame {} ({}): must be 8- or 16-bit single-channel", i, name);
    SOPE_CHECK(image.cols == manifest.camera_width && image.rows == manifest.camera_height,
               "frame {} ({}): size {}x{} does not match the camera size {}x{} of the manifest",
               i, name, image.cols, image.rows, manifest.camera_width, manifest.camera_height);
    SOPE_CHECK(image.type() == images[0].type(), "frame {} ({}): bit depth differs from "
               "frame 0", i, name);
  }
}

FrameSet LoadFrameSet(const std::string& directory) {
  FrameSet frame_set;
  frame_set.directory = directory;
  frame_set.manifest = ReadFrameSetManifest(directory);
  const FrameSetManifest& manifest = frame_set.manifest;
  for (size_t i = 0; i < manifest.frames.size(); ++i) {
    const FrameInfo& frame = manifest.frames[i];
    const std::string path = JoinPath(directory, frame.file);
    cv::Mat image = ReadImage(path, cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
    if (image.depth() != CV_8U && image.depth() != CV_16U) {
      SOPE_THROW("frame {}: unsupported bit depth (8- or 16-bit images only)", path);
    }
    if (image.channels() == 3 || image.channels() == 4) {
      if (frame.role == FrameRole::kWhite && image.depth() == CV_8U) {
        if (image.channels() == 4) {
          cv::cvtColor(image, frame_set.white_color, cv::COLOR_BGRA2BGR);
        } else {
          frame_set.white_color = image.clone();
        }
      }
      cv::Mat grey;
      cv::cvtColor(image, grey, image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
      image = grey;
    }
    SOPE_CHECK(image.cols == manifest.camera_width && image.rows == manifest.camera_height,
               "frame {}: size {}x{} does not match the camera size {}x{} in frames.json", path,
               image.cols, image.rows, manifest.camera_width, manifest.camera_height);
    frame_set.images.push_back(image);
  }
  frame_set.Check();
  return frame_set;
}

void WriteFrameSetFiles(const std::string& directory, const FrameSet& frame_set) {
  frame_set.Check();
  for (size_t i = 0; i < frame_set.images.size(); ++i) {
    WriteImageAtomic(JoinPath(directory, frame_set.manifest.frames[i].file),
                     frame_set.images[i]);
  }
  WriteFileAtomic(JoinPath(directory, FrameSetManifest::kFileName),
                  SerializeFrameSetManifest(frame_set.manifest));
}

void WriteFrameSet(const std::string& directory, const FrameSet& frame_set) {
  frame_set.Check();
  StagedDirectory staged(directory, FrameSetManifest::kFileName);
  WriteFrameSetFiles(staged.path(), frame_set);
  staged.Commit();
}

}  // namespace sope
