// The V4L2 backend's pure logic (v4l2_internal.h): no device, no kernel header.
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "capture/v4l2_internal.h"
#include "core/error.h"

namespace sope {
namespace internal {

std::string FourCcToString(uint32_t fourcc) {
  std::string text(4, '?');
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((fourcc >> (8 * i)) & 0xff);
    if (c >= 0x20 && c < 0x7f) text[i] = c;
  }
  while (!text.empty() && text.back() == ' ') text.pop_back();
  return text;
}

bool FormatOffer::Contains(int width, int height) const {
  auto on_grid = [](int value, int minimum, int maximum, int step) {
    if (value < minimum || value > maximum) return false;
    return step <= 1 || (value - minimum) % step == 0;
  };
  return on_grid(width, min_width, max_width, step_width) &&
         on_grid(height, min_height, max_height, step_height);
}

namespace {

// Lower is better; -1 = unusable.
int FormatRank(uint32_t fourcc, PixelFormat preference) {
  const uint32_t wanted = preference == PixelFormat::kGrey    ? kFourCcGrey
                          : preference == PixelFormat::kYuyv  ? kFourCcYuyv
                          : preference == PixelFormat::kMjpeg ? kFourCcMjpeg
                                                              : 0;
  if (wanted != 0) return fourcc == wanted ? 0 : -1;
  if (fourcc == kFourCcGrey) return 0;
  if (fourcc == kFourCcYuyv) return 1;
  if (fourcc == kFourCcMjpeg) return 2;
  return -1;
}

std::string DescribeOffers(const std::vector<FormatOffer>& offers) {
  std::map<std::string, std::vector<std::string>> sizes;
  for (const FormatOffer& offer : offers) {
    std::string size = offer.min_width == offer.max_width && offer.min_height == offer.max_height
                           ? fmt::format("{}x{}", offer.max_width, offer.max_height)
                           : fmt::format("{}x{}..{}x{}", offer.min_width, offer.min_height,
                                         offer.max_width, offer.max_height);
    sizes[FourCcToString(offer.fourcc)].push_back(size);
  }
  std::string text;
  for (const auto& [format, list] : sizes) {
    text += fmt::format("{}{} {}", text.empty() ? "" : "; ", format, fmt::join(list, ", "));
  }
  return text.empty() ? "no formats at all" : text;
}

}  // namespace

FormatChoice ChooseFormat(const std::vector<FormatOffer>& offers, int width, int height,
                          PixelFormat preference, const std::string& device) {
  const bool sized = width > 0 && height > 0;
  std::optional<FormatChoice> best;
  int best_rank = 0;
  int64_t best_area = -1;
  for (const FormatOffer& offer : offers) {
    const int rank = FormatRank(offer.fourcc, preference);
    if (rank < 0) continue;
    FormatChoice candidate{offer.fourcc, width, height};
    if (sized) {
      if (!offer.Contains(width, height)) continue;
    } else {
      candidate.width = offer.max_width;
      candidate.height = offer.max_height;
    }
    const int64_t area = static_cast<int64_t>(candidate.width) * candidate.height;
    if (!best || area > best_area || (area == best_area && rank < best_rank)) {
      best = candidate;
      best_rank = rank;
      best_area = area;
    }
  }
  if (best) return *best;
  const std::string wanted_format =
      preference == PixelFormat::kAuto ? "GREY, YUYV or MJPEG" : ToString(preference);
  if (sized) {
    SOPE_THROW("camera {} cannot deliver {}x{} in {}; it offers: {}", device, width, height,
               wanted_format, DescribeOffers(offers));
  }
  SOPE_THROW("camera {} offers no {} format (usable: GREY, YUYV, MJPEG); it offers: {}", device,
             wanted_format, DescribeOffers(offers));
}

cv::Mat ConvertToGrey(const BufferLayout& layout, const uint8_t* data, size_t bytes_used,
                      cv::Mat* color) {
  SOPE_CHECK(layout.width > 0 && layout.height > 0, "invalid frame size {}x{}", layout.width,
             layout.height);
  if (color) color->release();
  if (layout.fourcc == kFourCcMjpeg) {
    SOPE_CHECK(bytes_used > 0, "empty MJPEG frame");
    const cv::Mat encoded(1, static_cast<int>(bytes_used), CV_8UC1, const_cast<uint8_t*>(data));
    cv::Mat decoded = cv::imdecode(encoded, color ? cv::IMREAD_COLOR : cv::IMREAD_GRAYSCALE);
    SOPE_CHECK(!decoded.empty(), "undecodable MJPEG frame ({} bytes)", bytes_used);
    SOPE_CHECK(decoded.cols == layout.width && decoded.rows == layout.height,
               "MJPEG frame is {}x{}, expected {}x{}", decoded.cols, decoded.rows, layout.width,
               layout.height);
    if (!color) return decoded;
    *color = decoded;
    cv::Mat grey;
    cv::cvtColor(decoded, grey, cv::COLOR_BGR2GRAY);
    return grey;
  }
  const int bytes_per_pixel = layout.fourcc == kFourCcYuyv ? 2 : 1;
  SOPE_CHECK(layout.fourcc == kFourCcYuyv || layout.fourcc == kFourCcGrey,
             "unsupported pixel format {}", FourCcToString(layout.fourcc));
  SOPE_CHECK(layout.fourcc != kFourCcYuyv || layout.width % 2 == 0,
             "YUYV frames need an even width, got {}", layout.width);
  const size_t stride = layout.bytes_per_line > 0
                            ? static_cast<size_t>(layout.bytes_per_line)
                            : static_cast<size_t>(layout.width) * bytes_per_pixel;
  SOPE_CHECK(stride >= static_cast<size_t>(layout.width) * bytes_per_pixel,
             "bytes per line {} is less than a row of {} pixels", stride, layout.width);
  const size_t needed =
      stride * (layout.height - 1) + static_cast<size_t>(layout.width) * bytes_per_pixel;
  SOPE_CHECK(bytes_used >= needed, "short frame: {} bytes, a {}x{} {} frame needs {}", bytes_used,
             layout.width, layout.height, FourCcToString(layout.fourcc), needed);
  const cv::Mat raw(layout.height, layout.width, bytes_per_pixel == 2 ? CV_8UC2 : CV_8UC1,
                    const_cast<uint8_t*>(data), stride);
  if (layout.fourcc == kFourCcGrey) return raw.clone();
  cv::Mat grey(layout.height, layout.width, CV_8UC1);
  for (int y = 0; y < layout.height; ++y) {
    const uint8_t* in = raw.ptr<uint8_t>(y);
    uint8_t* out = grey.ptr<uint8_t>(y);
    for (int x = 0; x < layout.width; ++x) out[x] = in[2 * x];  // Y0 U Y1 V
  }
  if (color) cv::cvtColor(raw, *color, cv::COLOR_YUV2BGR_YUYV);
  return grey;
}

std::string ToString(Control control) {
  switch (control) {
    case Control::kExposureAuto:
      return "auto exposure";
    case Control::kExposureAutoPriority:
      return "exposure priority";
    case Control::kExposureAbsolute:
      return "exposure time";
    case Control::kAutoGain:
      return "auto gain";
    case Control::kGain:
      return "gain";
    case Control::kAutoWhiteBalance:
      return "auto white balance";
  }
  return "unknown control";
}

ControlPlan PlanControls(const CameraOptions& options,
                         const std::function<std::optional<ControlInfo>(Control)>& query) {
  ControlPlan plan;
  // Adds `value` for `control` when the device has it writable and in range.
  auto want = [&](Control control, int64_t value, const std::string& meaning,
                  const std::string& range_unit = "", double unit_scale = 1.0) {
    const std::optional<ControlInfo> info = query(control);
    if (!info) {
      plan.cannot_set.push_back(fmt::format("{} (not supported)", meaning));
      return;
    }
    if (!info->writable) {
      plan.cannot_set.push_back(fmt::format("{} (read-only or inactive)", meaning));
      return;
    }
    if (info->is_menu) {
      if (std::find(info->menu_values.begin(), info->menu_values.end(), value) ==
          info->menu_values.end()) {
        plan.cannot_set.push_back(
            fmt::format("{} (not in the menu: {})", meaning, fmt::join(info->menu_values, ", ")));
        return;
      }
    } else if (value < info->minimum || value > info->maximum) {
      plan.cannot_set.push_back(fmt::format("{} (out of range {:.4g}..{:.4g}{})", meaning,
                                            info->minimum * unit_scale, info->maximum * unit_scale,
                                            range_unit));
      return;
    }
    plan.settings.push_back({control, value, meaning});
  };
  if (options.manual) {
    // Manual mode; shutter priority (fixed exposure, auto iris) is as good on webcams.
    const std::optional<ControlInfo> mode = query(Control::kExposureAuto);
    const bool has_manual =
        mode && mode->is_menu &&
        std::count(mode->menu_values.begin(), mode->menu_values.end(), kExposureModeManual);
    const bool has_shutter = mode && mode->is_menu &&
                             std::count(mode->menu_values.begin(), mode->menu_values.end(),
                                        kExposureModeShutterPriority);
    want(Control::kExposureAuto,
         has_manual || !has_shutter ? kExposureModeManual : kExposureModeShutterPriority,
         has_manual || !has_shutter ? "manual exposure" : "manual exposure (shutter priority)");
    want(Control::kExposureAutoPriority, 0, "exposure priority off (constant frame rate)");
    want(Control::kAutoGain, 0, "auto gain off");
    want(Control::kAutoWhiteBalance, 0, "auto white balance off");
  }
  if (options.exposure > 0.0) {
    const std::optional<ControlInfo> info = query(Control::kExposureAbsolute);
    int64_t units = std::llround(options.exposure / kExposureUnitSeconds);
    if (info && info->step > 1) {
      units = info->minimum + (units - info->minimum + info->step / 2) / info->step * info->step;
    }
    want(Control::kExposureAbsolute, units,
         fmt::format("exposure {:.1f} ms", 1e3 * units * kExposureUnitSeconds), " ms",
         1e3 * kExposureUnitSeconds);
  }
  if (options.gain >= 0.0) {
    want(Control::kGain, std::llround(options.gain), fmt::format("gain {}", options.gain));
  }
  return plan;
}

double ExposureStart(const DequeuedBuffer& buffer, double dequeue_time, double frame_period,
                     double exposure) {
  const double period = frame_period > 0.0 ? frame_period : 1.0 / 30.0;
  const double exposure_time = exposure > 0.0 ? exposure : period;
  if (buffer.timestamp_monotonic && buffer.source == TimestampSource::kStartOfExposure) {
    return buffer.timestamp;
  }
  const double end_of_frame = buffer.timestamp_monotonic ? buffer.timestamp : dequeue_time;
  return end_of_frame - period - exposure_time;
}

DeviceError::DeviceError(std::string operation, int error_number)
    : operation_(std::move(operation)), error_number_(error_number) {
  what_ = fmt::format("{}: {}", operation_, std::strerror(error_number_));
}

bool IsDeviceLost(int error_number) {
  return error_number == ENODEV || error_number == ENXIO || error_number == EIO ||
         error_number == EPIPE || error_number == ESHUTDOWN;
}

std::string OpenErrorMessage(const std::string& device, int error_number,
                             const std::vector<std::string>& present_devices) {
  switch (error_number) {
    case ENOENT:
      return fmt::format(
          "camera {}: no such device ({})", device,
          present_devices.empty()
              ? std::string("no /dev/video* devices present: is a camera plugged in?")
              : fmt::format("present: {}", fmt::join(present_devices, ", ")));
    case ENODEV:
    case ENXIO:
      return fmt::format("camera {}: device not present (unplugged?)", device);
    case EACCES:
    case EPERM:
      return fmt::format("camera {}: permission denied (add your user to the 'video' group)",
                         device);
    case EBUSY:
      return fmt::format("camera {}: busy — another program is using it", device);
    default:
      return fmt::format("camera {}: cannot open: {}", device, std::strerror(error_number));
  }
}

std::string DeviceErrorMessage(const std::string& device, const DeviceError& error) {
  const int number = error.error_number();
  if (error.operation() == "open") return OpenErrorMessage(device, number);
  if (error.operation() == "VIDIOC_QUERYCAP" && (number == ENOTTY || number == EINVAL)) {
    return fmt::format("camera {}: not a V4L2 video device", device);
  }
  if (IsDeviceLost(number)) {
    return fmt::format("camera {} disappeared or failed ({}: {}): unplugged?", device,
                       error.operation(), std::strerror(number));
  }
  if (number == EBUSY) {
    return fmt::format("camera {}: busy — another program is streaming from it ({})", device,
                       error.operation());
  }
  return fmt::format("camera {}: {} failed: {}", device, error.operation(), std::strerror(number));
}

}  // namespace internal

std::string ToString(PixelFormat format) {
  switch (format) {
    case PixelFormat::kAuto:
      return "auto";
    case PixelFormat::kGrey:
      return "grey";
    case PixelFormat::kYuyv:
      return "yuyv";
    case PixelFormat::kMjpeg:
      return "mjpeg";
  }
  return "unknown";
}

PixelFormat PixelFormatFromString(const std::string& text) {
  std::string lower = text;
  std::transform(lower.begin(), lower.end(), lower.begin(), ::tolower);
  if (lower == "auto") return PixelFormat::kAuto;
  if (lower == "grey" || lower == "gray") return PixelFormat::kGrey;
  if (lower == "yuyv") return PixelFormat::kYuyv;
  if (lower == "mjpeg" || lower == "mjpg") return PixelFormat::kMjpeg;
  SOPE_THROW("unknown pixel format '{}' (auto, grey, yuyv, mjpeg)", text);
}

}  // namespace sope
