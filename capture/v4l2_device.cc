// The ioctl shell of the V4L2 camera: each V4l2Device method is one or two ioctls, no
// decisions (those are in v4l2_logic.cc and v4l2_camera.cc, tested on a fake device).
// The only file that includes <linux/videodev2.h>. Not exercised by the tests (no camera
// on CI machines); keep it this small.
#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>

#include "capture/clock.h"
#include "capture/v4l2_internal.h"

namespace sope {
namespace internal {
namespace {

int Ioctl(int fd, unsigned long request, void* argument) {
  int result;
  do {
    result = ::ioctl(fd, request, argument);
  } while (result == -1 && errno == EINTR);
  return result;
}

uint32_t ControlId(Control control) {
  switch (control) {
    case Control::kExposureAuto:
      return V4L2_CID_EXPOSURE_AUTO;
    case Control::kExposureAutoPriority:
      return V4L2_CID_EXPOSURE_AUTO_PRIORITY;
    case Control::kExposureAbsolute:
      return V4L2_CID_EXPOSURE_ABSOLUTE;
    case Control::kAutoGain:
      return V4L2_CID_AUTOGAIN;
    case Control::kGain:
      return V4L2_CID_GAIN;
    case Control::kAutoWhiteBalance:
      return V4L2_CID_AUTO_WHITE_BALANCE;
  }
  return 0;
}

std::string FixedString(const uint8_t* text, size_t size) {
  return std::string(reinterpret_cast<const char*>(text),
                     strnlen(reinterpret_cast<const char*>(text), size));
}

class RealV4l2Device : public V4l2Device {
 public:
  explicit RealV4l2Device(const std::string& path) {
    fd_ = ::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd_ < 0) throw DeviceError("open", errno);
  }

  ~RealV4l2Device() override {
    for (const Mapping& mapping : buffers_) ::munmap(mapping.start, mapping.length);
    ::close(fd_);
  }

  DeviceCapabilities QueryCapabilities() override {
    v4l2_capability capability{};
    Check(Ioctl(fd_, VIDIOC_QUERYCAP, &capability), "VIDIOC_QUERYCAP");
    const uint32_t caps = (capability.capabilities & V4L2_CAP_DEVICE_CAPS)
                              ? capability.device_caps
                              : capability.capabilities;
    DeviceCapabilities result;
    result.driver = FixedString(capability.driver, sizeof(capability.driver));
    result.card = FixedString(capability.card, sizeof(capability.card));
    result.bus_info = FixedString(capability.bus_info, sizeof(capability.bus_info));
    result.video_capture = (caps & V4L2_CAP_VIDEO_CAPTURE) != 0;
    result.streaming = (caps & V4L2_CAP_STREAMING) != 0;
    return result;
  }

  std::vector<FormatOffer> EnumerateFormats() override {
    std::vector<FormatOffer> offers;
    for (uint32_t index = 0;; ++index) {
      v4l2_fmtdesc description{};
      description.index = index;
      description.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      if (Ioctl(fd_, VIDIOC_ENUM_FMT, &description) != 0) {
        if (errno == EINVAL) break;
        throw DeviceError("VIDIOC_ENUM_FMT", errno);
      }
      const size_t before = offers.size();
      for (uint32_t size_index = 0;; ++size_index) {
        v4l2_frmsizeenum size{};
        size.index = size_index;
        size.pixel_format = description.pixelformat;
        if (Ioctl(fd_, VIDIOC_ENUM_FRAMESIZES, &size) != 0) break;
        if (size.type == V4L2_FRMSIZE_TYPE_DISCRETE) {
          offers.push_back(FormatOffer::Discrete(description.pixelformat,
                                                 static_cast<int>(size.discrete.width),
                                                 static_cast<int>(size.discrete.height)));
        } else {
          const v4l2_frmsize_stepwise& range = size.stepwise;
          offers.push_back({description.pixelformat, static_cast<int>(range.min_width),
                            static_cast<int>(range.max_width),
                            static_cast<int>(std::max(range.step_width, 1u)),
                            static_cast<int>(range.min_height), static_cast<int>(range.max_height),
                            static_cast<int>(std::max(range.step_height, 1u))});
          break;
        }
      }
      if (offers.size() == before) {  // no ENUM_FRAMESIZES: the current size only
        v4l2_format format{};
        format.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        Check(Ioctl(fd_, VIDIOC_G_FMT, &format), "VIDIOC_G_FMT");
        offers.push_back(FormatOffer::Discrete(description.pixelformat,
                                               static_cast<int>(format.fmt.pix.width),
                                               static_cast<int>(format.fmt.pix.height)));
      }
    }
    return offers;
  }

  BufferLayout SetFormat(const FormatChoice& choice) override {
    v4l2_format format{};
    format.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    format.fmt.pix.width = static_cast<uint32_t>(choice.width);
    format.fmt.pix.height = static_cast<uint32_t>(choice.height);
    format.fmt.pix.pixelformat = choice.fourcc;
    format.fmt.pix.field = V4L2_FIELD_NONE;
    Check(Ioctl(fd_, VIDIOC_S_FMT, &format), "VIDIOC_S_FMT");
    BufferLayout layout;
    layout.fourcc = format.fmt.pix.pixelformat;
    layout.width = static_cast<int>(format.fmt.pix.width);
    layout.height = static_cast<int>(format.fmt.pix.height);
    layout.bytes_per_line = static_cast<int>(format.fmt.pix.bytesperline);
    layout.size_image = format.fmt.pix.sizeimage;
    return layout;
  }

  double SetFrameRate(double fps) override {
    v4l2_streamparm parameters{};
    parameters.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (Ioctl(fd_, VIDIOC_G_PARM, &parameters) != 0) return 0.0;
    if (fps > 0.0 && (parameters.parm.capture.capability & V4L2_CAP_TIMEPERFRAME)) {
      parameters.parm.capture.timeperframe.numerator = 1000;
      parameters.parm.capture.timeperframe.denominator =
          static_cast<uint32_t>(std::lround(fps * 1000.0));
      Ioctl(fd_, VIDIOC_S_PARM, &parameters);  // best effort: the result is read back
      Ioctl(fd_, VIDIOC_G_PARM, &parameters);
    }
    const v4l2_fract& period = parameters.parm.capture.timeperframe;
    return period.denominator > 0 ? static_cast<double>(period.numerator) / period.denominator
                                  : 0.0;
  }

  std::optional<ControlInfo> QueryControl(Control control) override {
    v4l2_queryctrl query{};
    query.id = ControlId(control);
    if (Ioctl(fd_, VIDIOC_QUERYCTRL, &query) != 0) {
      if (errno == EINVAL) return std::nullopt;
      throw DeviceError("VIDIOC_QUERYCTRL", errno);
    }
    if (query.flags & V4L2_CTRL_FLAG_DISABLED) return std::nullopt;
    ControlInfo info;
    info.minimum = query.minimum;
    info.maximum = query.maximum;
    info.step = std::max(query.step, 1);
    info.default_value = query.default_value;
    // INACTIVE controls (exposure time while auto exposure is on) can still be set; the
    // plan switches the automatics off first.
    info.writable = !(query.flags & (V4L2_CTRL_FLAG_READ_ONLY | V4L2_CTRL_FLAG_GRABBED));
    info.is_menu = query.type == V4L2_CTRL_TYPE_MENU || query.type == V4L2_CTRL_TYPE_INTEGER_MENU;
    if (info.is_menu) {
      for (int64_t value = query.minimum; value <= query.maximum; ++value) {
        v4l2_querymenu item{};
        item.id = query.id;
        item.index = static_cast<uint32_t>(value);
        if (Ioctl(fd_, VIDIOC_QUERYMENU, &item) == 0) info.menu_values.push_back(value);
      }
    }
    return info;
  }

  void SetControl(Control control, int64_t value) override {
    v4l2_control setting{};
    setting.id = ControlId(control);
    setting.value = static_cast<int32_t>(value);
    Check(Ioctl(fd_, VIDIOC_S_CTRL, &setting), "VIDIOC_S_CTRL " + ToString(control));
  }

  int RequestBuffers(int count) override {
    v4l2_requestbuffers request{};
    request.count = static_cast<uint32_t>(count);
    request.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    request.memory = V4L2_MEMORY_MMAP;
    Check(Ioctl(fd_, VIDIOC_REQBUFS, &request), "VIDIOC_REQBUFS");
    for (uint32_t index = 0; index < request.count; ++index) {
      v4l2_buffer buffer{};
      buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      buffer.memory = V4L2_MEMORY_MMAP;
      buffer.index = index;
      Check(Ioctl(fd_, VIDIOC_QUERYBUF, &buffer), "VIDIOC_QUERYBUF");
      void* start =
          ::mmap(nullptr, buffer.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, buffer.m.offset);
      if (start == MAP_FAILED) throw DeviceError("mmap", errno);
      buffers_.push_back({start, buffer.length});
    }
    return static_cast<int>(request.count);
  }

  void QueueBuffer(int index) override {
    v4l2_buffer buffer{};
    buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buffer.memory = V4L2_MEMORY_MMAP;
    buffer.index = static_cast<uint32_t>(index);
    Check(Ioctl(fd_, VIDIOC_QBUF, &buffer), "VIDIOC_QBUF");
  }

  void StreamOn() override {
    v4l2_buf_type type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    Check(Ioctl(fd_, VIDIOC_STREAMON, &type), "VIDIOC_STREAMON");
  }

  void StreamOff() override {
    v4l2_buf_type type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    Check(Ioctl(fd_, VIDIOC_STREAMOFF, &type), "VIDIOC_STREAMOFF");
  }

  bool WaitForFrame(double timeout) override {
    pollfd descriptor{fd_, POLLIN, 0};
    const int milliseconds = static_cast<int>(std::ceil(std::max(timeout, 0.0) * 1e3));
    int result;
    do {
      result = ::poll(&descriptor, 1, milliseconds);
    } while (result == -1 && errno == EINTR);
    if (result < 0) throw DeviceError("poll", errno);
    if (result == 0) return false;
    poll_error_ = (descriptor.revents & (POLLERR | POLLHUP | POLLNVAL)) != 0;
    return true;
  }

  std::optional<DequeuedBuffer> DequeueBuffer() override {
    v4l2_buffer buffer{};
    buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buffer.memory = V4L2_MEMORY_MMAP;
    if (Ioctl(fd_, VIDIOC_DQBUF, &buffer) != 0) {
      // POLLERR without an error from DQBUF: the device is gone or stopped streaming.
      if (errno == EAGAIN && !poll_error_) return std::nullopt;
      throw DeviceError("VIDIOC_DQBUF", errno == EAGAIN ? EIO : errno);
    }
    DequeuedBuffer result;
    result.index = static_cast<int>(buffer.index);
    result.bytes_used = buffer.bytesused;
    result.timestamp = static_cast<double>(buffer.timestamp.tv_sec) +
                       1e-6 * static_cast<double>(buffer.timestamp.tv_usec);
    result.timestamp_monotonic =
        (buffer.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
    result.source = (buffer.flags & V4L2_BUF_FLAG_TSTAMP_SRC_MASK) == V4L2_BUF_FLAG_TSTAMP_SRC_SOE
                        ? TimestampSource::kStartOfExposure
                        : TimestampSource::kEndOfFrame;
    result.sequence = buffer.sequence;
    result.error = (buffer.flags & V4L2_BUF_FLAG_ERROR) != 0;
    return result;
  }

  const uint8_t* BufferData(int index) const override {
    return static_cast<const uint8_t*>(buffers_.at(static_cast<size_t>(index)).start);
  }

  double Now() const override { return MonotonicSeconds(); }

 private:
  struct Mapping {
    void* start;
    size_t length;
  };

  static void Check(int result, const std::string& operation) {
    if (result != 0) throw DeviceError(operation, errno);
  }

  int fd_ = -1;
  std::vector<Mapping> buffers_;
  bool poll_error_ = false;
};

}  // namespace

std::unique_ptr<V4l2Device> OpenV4l2Device(const std::string& path) {
  return std::make_unique<RealV4l2Device>(path);
}

}  // namespace internal
}  // namespace sope
