// The projector window: GLFW + legacy OpenGL (2.1 compatibility: it is all a textured quad
// needs, and every driver has it). Exact pixel mapping: the pattern is a texture of the
// framebuffer's own size drawn with GL_NEAREST onto a quad covering the viewport, so the
// fragment centred at window pixel (i + ½, j + ½) samples texel (i, H − 1 − j) exactly —
// pattern row 0 at the top.
#include <cstdlib>
#include <deque>
#include <mutex>
#include <string>

#define GLFW_INCLUDE_NONE
#include <GL/gl.h>
#include <GLFW/glfw3.h>
#include <spdlog/spdlog.h>

#include <opencv2/core.hpp>

#include "core/error.h"
#include "projector/display.h"
#include "projector/x11_read_back.h"

#ifndef GL_BGR
#define GL_BGR 0x80E0
#endif
#ifndef GL_CLAMP_TO_EDGE
#define GL_CLAMP_TO_EDGE 0x812F
#endif

namespace sope {
namespace {

// GLFW is process-global: initialised while a window or a monitor query needs it, one
// window at a time. All calls come from the thread that opened the display.
std::mutex glfw_mutex;
int glfw_users = 0;
bool window_open = false;
std::string last_glfw_error;

void OnGlfwError(int code, const char* description) {
  last_glfw_error = description ? description : "unknown error";
  spdlog::debug("GLFW error {}: {}", code, last_glfw_error);
}

void AcquireGlfw() {
  std::lock_guard<std::mutex> lock(glfw_mutex);
  if (glfw_users == 0) {
    const char* x_display = std::getenv("DISPLAY");
    const char* wayland_display = std::getenv("WAYLAND_DISPLAY");
    SOPE_CHECK((x_display && *x_display) || (wayland_display && *wayland_display),
               "no display: $DISPLAY is not set (the projector window needs an X server; for "
               "tests run under xvfb-run, without hardware use --camera virtual)");
    glfwSetErrorCallback(OnGlfwError);
    last_glfw_error.clear();
    if (glfwInit() != GLFW_TRUE) {
      SOPE_THROW(
          "no display: GLFW cannot initialise ({}) — is the X server on $DISPLAY={} "
          "running?",
          last_glfw_error.empty() ? "no reason given" : last_glfw_error,
          x_display ? x_display : "");
    }
  }
  ++glfw_users;
}

void ReleaseGlfw() {
  std::lock_guard<std::mutex> lock(glfw_mutex);
  if (--glfw_users == 0) glfwTerminate();
}

std::vector<MonitorInfo> QueryMonitors() {
  int count = 0;
  GLFWmonitor** monitors = glfwGetMonitors(&count);
  std::vector<MonitorInfo> result;
  for (int i = 0; i < count; ++i) {
    MonitorInfo info;
    info.index = i;
    const char* name = glfwGetMonitorName(monitors[i]);
    info.name = name ? name : "unnamed";
    if (const GLFWvidmode* mode = glfwGetVideoMode(monitors[i])) {
      info.width = mode->width;
      info.height = mode->height;
      info.refresh_hz = mode->refreshRate;
    }
    result.push_back(info);
  }
  return result;
}

std::string DescribeMonitors(const std::vector<MonitorInfo>& monitors) {
  std::string text;
  for (const MonitorInfo& m : monitors) {
    text += fmt::format("{}{}: {} {}x{}@{}Hz", text.empty() ? "" : ", ", m.index, m.name, m.width,
                        m.height, m.refresh_hz);
  }
  return text.empty() ? "none" : text;
}

// The GL entry points, resolved through GLFW (glXGetProcAddress) for the current context.
// Never linked directly: libOSMesa (the simulator, in the same binary) exports the whole
// GL API too, and the dynamic linker would bind direct calls to whichever came first.
struct GlFunctions {
  void (*BindTexture)(GLenum, GLuint) = nullptr;
  void (*PixelStorei)(GLenum, GLint) = nullptr;
  void (*TexSubImage2D)(GLenum, GLint, GLint, GLint, GLsizei, GLsizei, GLenum, GLenum,
                        const void*) = nullptr;
  void (*Clear)(GLbitfield) = nullptr;
  void (*Begin)(GLenum) = nullptr;
  void (*End)() = nullptr;
  void (*TexCoord2f)(GLfloat, GLfloat) = nullptr;
  void (*Vertex2f)(GLfloat, GLfloat) = nullptr;
  void (*Finish)() = nullptr;
  GLenum (*GetError)() = nullptr;
  void (*ReadBuffer)(GLenum) = nullptr;
  void (*ReadPixels)(GLint, GLint, GLsizei, GLsizei, GLenum, GLenum, void*) = nullptr;
  void (*Viewport)(GLint, GLint, GLsizei, GLsizei) = nullptr;
  void (*MatrixMode)(GLenum) = nullptr;
  void (*LoadIdentity)() = nullptr;
  void (*Disable)(GLenum) = nullptr;
  void (*Enable)(GLenum) = nullptr;
  void (*ClearColor)(GLfloat, GLfloat, GLfloat, GLfloat) = nullptr;
  void (*GenTextures)(GLsizei, GLuint*) = nullptr;
  void (*DeleteTextures)(GLsizei, const GLuint*) = nullptr;
  void (*TexParameteri)(GLenum, GLenum, GLint) = nullptr;
  void (*TexEnvi)(GLenum, GLenum, GLint) = nullptr;
  void (*TexImage2D)(GLenum, GLint, GLint, GLsizei, GLsizei, GLint, GLenum, GLenum,
                     const void*) = nullptr;
  const GLubyte* (*GetString)(GLenum) = nullptr;

  void LoadAll() {
    Load(&BindTexture, "glBindTexture");
    Load(&PixelStorei, "glPixelStorei");
    Load(&TexSubImage2D, "glTexSubImage2D");
    Load(&Clear, "glClear");
    Load(&Begin, "glBegin");
    Load(&End, "glEnd");
    Load(&TexCoord2f, "glTexCoord2f");
    Load(&Vertex2f, "glVertex2f");
    Load(&Finish, "glFinish");
    Load(&GetError, "glGetError");
    Load(&ReadBuffer, "glReadBuffer");
    Load(&ReadPixels, "glReadPixels");
    Load(&Viewport, "glViewport");
    Load(&MatrixMode, "glMatrixMode");
    Load(&LoadIdentity, "glLoadIdentity");
    Load(&Disable, "glDisable");
    Load(&Enable, "glEnable");
    Load(&ClearColor, "glClearColor");
    Load(&GenTextures, "glGenTextures");
    Load(&DeleteTextures, "glDeleteTextures");
    Load(&TexParameteri, "glTexParameteri");
    Load(&TexEnvi, "glTexEnvi");
    Load(&TexImage2D, "glTexImage2D");
    Load(&GetString, "glGetString");
  }

 private:
  template <typename F>
  void Load(F* function, const char* symbol) {
    *function = reinterpret_cast<F>(glfwGetProcAddress(symbol));
    SOPE_CHECK(*function != nullptr, "OpenGL driver lacks {}", symbol);
  }
};

class GlfwDisplay : public Display {
 public:
  explicit GlfwDisplay(const DisplayOptions& options) : options_(options) {
    options_.Check();
    AcquireGlfw();
    try {
      Open();
    } catch (...) {
      Close();
      throw;
    }
  }

  ~GlfwDisplay() override { Close(); }

  void Show(const cv::Mat& pattern) override {
    internal::CheckPattern(pattern, options_.width, options_.height, name_);
    glfwMakeContextCurrent(window_);
    const cv::Mat image = pattern.isContinuous() ? pattern : pattern.clone();
    gl_.BindTexture(GL_TEXTURE_2D, texture_);
    gl_.PixelStorei(GL_UNPACK_ALIGNMENT, 1);
    gl_.TexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, image.cols, image.rows,
                      image.channels() == 1 ? GL_LUMINANCE : GL_BGR, GL_UNSIGNED_BYTE, image.data);
    gl_.Clear(GL_COLOR_BUFFER_BIT);
    gl_.Begin(GL_QUADS);
    gl_.TexCoord2f(0.f, 0.f);
    gl_.Vertex2f(-1.f, 1.f);
    gl_.TexCoord2f(1.f, 0.f);
    gl_.Vertex2f(1.f, 1.f);
    gl_.TexCoord2f(1.f, 1.f);
    gl_.Vertex2f(1.f, -1.f);
    gl_.TexCoord2f(0.f, 1.f);
    gl_.Vertex2f(-1.f, -1.f);
    gl_.End();
    glfwSwapBuffers(window_);
    // Block until the swap has really happened, so the caller's timestamp follows it.
    gl_.Finish();
    glfwPollEvents();
    CheckGlError("drawing the pattern");
  }

  int width() const override { return options_.width; }
  int height() const override { return options_.height; }

  DisplayKey WaitKey(double timeout_s) override {
    if (keys_.empty()) {
      if (timeout_s > 0) {
        glfwWaitEventsTimeout(timeout_s);
      } else {
        glfwPollEvents();
      }
    }
    if (glfwWindowShouldClose(window_)) return DisplayKey::kQuit;
    if (keys_.empty()) return DisplayKey::kNone;
    const DisplayKey key = keys_.front();
    keys_.pop_front();
    return key;
  }

  // What the window system holds for the window (XGetImage): the pixels that reached the
  // screen, not a GL buffer (Mesa's software rasterisers keep no readable front buffer after
  // a swap). Elsewhere than on X11: the GL front buffer.
  cv::Mat ReadBack() override {
    glfwMakeContextCurrent(window_);
    gl_.Finish();
    cv::Mat read_back;
    std::string why;
    if (internal::ReadBackX11(window_, options_.width, options_.height, &read_back, &why)) {
      return read_back;
    }
    SOPE_CHECK(why == "not an X11 window", "{}: cannot read the window back: {}", name_, why);
    cv::Mat bottom_up(options_.height, options_.width, CV_8UC3);
    gl_.ReadBuffer(GL_FRONT);
    gl_.PixelStorei(GL_PACK_ALIGNMENT, 1);
    gl_.ReadPixels(0, 0, options_.width, options_.height, GL_BGR, GL_UNSIGNED_BYTE, bottom_up.data);
    CheckGlError("reading the window back");
    cv::flip(bottom_up, read_back, 0);  // GL rows run bottom-up
    return read_back;
  }

  std::string name() const override { return name_; }

 private:
  static void OnKey(GLFWwindow* window, int key, int scancode, int action, int mods) {
    if (action != GLFW_PRESS && action != GLFW_REPEAT) return;
    auto* self = static_cast<GlfwDisplay*>(glfwGetWindowUserPointer(window));
    switch (key) {
      case GLFW_KEY_SPACE:
      case GLFW_KEY_RIGHT:
      case GLFW_KEY_ENTER:
      case GLFW_KEY_PAGE_DOWN:
        self->keys_.push_back(DisplayKey::kNext);
        break;
      case GLFW_KEY_LEFT:
      case GLFW_KEY_BACKSPACE:
      case GLFW_KEY_PAGE_UP:
        self->keys_.push_back(DisplayKey::kPrevious);
        break;
      case GLFW_KEY_Q:
      case GLFW_KEY_ESCAPE:
        self->keys_.push_back(DisplayKey::kQuit);
        break;
      default:
        break;
    }
  }

  void Open() {
    {
      std::lock_guard<std::mutex> lock(glfw_mutex);
      SOPE_CHECK(!window_open, "a projector window is already open in this process");
    }
    glfwDefaultWindowHints();
    glfwWindowHint(GLFW_CLIENT_API, GLFW_OPENGL_API);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 2);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 1);
    glfwWindowHint(GLFW_RESIZABLE, GLFW_FALSE);
    glfwWindowHint(GLFW_SCALE_TO_MONITOR, GLFW_FALSE);
    glfwWindowHint(GLFW_DOUBLEBUFFER, GLFW_TRUE);
    glfwWindowHint(GLFW_SRGB_CAPABLE, GLFW_FALSE);
    glfwWindowHint(GLFW_SAMPLES, 0);
    glfwWindowHint(GLFW_RED_BITS, 8);
    glfwWindowHint(GLFW_GREEN_BITS, 8);
    glfwWindowHint(GLFW_BLUE_BITS, 8);
    GLFWmonitor* monitor = nullptr;
    if (options_.windowed) {
      name_ = fmt::format("projector window ({}x{}, windowed)", options_.width, options_.height);
    } else {
      const std::vector<MonitorInfo> monitors = QueryMonitors();
      int count = 0;
      GLFWmonitor** handles = glfwGetMonitors(&count);
      SOPE_CHECK(options_.monitor < count, "no monitor {}: connected monitors: {}",
                 options_.monitor, DescribeMonitors(monitors));
      monitor = handles[options_.monitor];
      const MonitorInfo& info = monitors[options_.monitor];
      name_ = fmt::format("projector on monitor {} ({})", info.index, info.name);
      SOPE_CHECK(info.width == options_.width && info.height == options_.height,
                 "monitor {} ({}) runs at {}x{} but the patterns are {}x{}: set the "
                 "projector's mode to {}x{}, give the projector size as {}x{}, or use "
                 "--windowed",
                 info.index, info.name, info.width, info.height, options_.width, options_.height,
                 options_.width, options_.height, info.width, info.height);
      const GLFWvidmode* mode = glfwGetVideoMode(monitor);
      glfwWindowHint(GLFW_REFRESH_RATE, mode->refreshRate);
      // Stay on the projector when the user clicks into a terminal on another screen.
      glfwWindowHint(GLFW_AUTO_ICONIFY, GLFW_FALSE);
    }
    last_glfw_error.clear();
    window_ =
        glfwCreateWindow(options_.width, options_.height, options_.title.c_str(), monitor, nullptr);
    SOPE_CHECK(window_ != nullptr, "{}: cannot create an OpenGL window ({})", name_,
               last_glfw_error.empty() ? "no reason given" : last_glfw_error);
    {
      std::lock_guard<std::mutex> lock(glfw_mutex);
      window_open = true;
    }
    glfwSetWindowUserPointer(window_, this);
    glfwSetKeyCallback(window_, OnKey);
    if (monitor) glfwSetInputMode(window_, GLFW_CURSOR, GLFW_CURSOR_HIDDEN);
    glfwMakeContextCurrent(window_);
    gl_.LoadAll();
    gl_loaded_ = true;
    glfwSwapInterval(options_.vsync ? 1 : 0);
    // The window manager may have had its say: wait for the mapping, then insist on the size.
    glfwPollEvents();
    int framebuffer_width = 0, framebuffer_height = 0;
    glfwGetFramebufferSize(window_, &framebuffer_width, &framebuffer_height);
    SOPE_CHECK(framebuffer_width == options_.width && framebuffer_height == options_.height,
               "{}: the window's framebuffer is {}x{}, not the projector's {}x{} (desktop "
               "scaling or a window manager resized it); pixels would not map one to one",
               name_, framebuffer_width, framebuffer_height, options_.width, options_.height);
    gl_.Viewport(0, 0, options_.width, options_.height);
    gl_.MatrixMode(GL_PROJECTION);
    gl_.LoadIdentity();
    gl_.MatrixMode(GL_MODELVIEW);
    gl_.LoadIdentity();
    for (GLenum capability : {GL_DITHER, GL_BLEND, GL_DEPTH_TEST, GL_LIGHTING, GL_CULL_FACE,
                              GL_MULTISAMPLE, GL_FOG, GL_ALPHA_TEST}) {
      gl_.Disable(capability);
    }
    gl_.ClearColor(0.f, 0.f, 0.f, 1.f);
    gl_.Enable(GL_TEXTURE_2D);
    gl_.GenTextures(1, &texture_);
    gl_.BindTexture(GL_TEXTURE_2D, texture_);
    gl_.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    gl_.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    gl_.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    gl_.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    gl_.TexEnvi(GL_TEXTURE_ENV, GL_TEXTURE_ENV_MODE, GL_REPLACE);
    gl_.TexImage2D(GL_TEXTURE_2D, 0, GL_RGB8, options_.width, options_.height, 0, GL_RGB,
                   GL_UNSIGNED_BYTE, nullptr);
    CheckGlError("creating the pattern texture");
    spdlog::debug("{}: GL {} on {}", name_,
                  reinterpret_cast<const char*>(gl_.GetString(GL_VERSION)),
                  reinterpret_cast<const char*>(gl_.GetString(GL_RENDERER)));
    Show(cv::Mat::zeros(options_.height, options_.width, CV_8UC1));
  }

  void Close() {
    if (window_) {
      glfwMakeContextCurrent(window_);
      if (texture_ && gl_loaded_) gl_.DeleteTextures(1, &texture_);
      glfwDestroyWindow(window_);
      window_ = nullptr;
      std::lock_guard<std::mutex> lock(glfw_mutex);
      window_open = false;
    }
    if (acquired_) {
      acquired_ = false;
      ReleaseGlfw();
    }
  }

  void CheckGlError(const char* what) const {
    const GLenum error = gl_.GetError();
    SOPE_CHECK(error == GL_NO_ERROR, "{}: OpenGL error 0x{:x} {}", name_, error, what);
  }

  DisplayOptions options_;
  std::string name_ = "projector window";
  GLFWwindow* window_ = nullptr;
  GLuint texture_ = 0;
  GlFunctions gl_;
  bool gl_loaded_ = false;
  bool acquired_ = true;  // AcquireGlfw() succeeded before the members are used
  std::deque<DisplayKey> keys_;
};

}  // namespace

bool HaveGlfwDisplay() { return true; }

std::vector<MonitorInfo> ListMonitors() {
  AcquireGlfw();
  std::vector<MonitorInfo> monitors = QueryMonitors();
  ReleaseGlfw();
  return monitors;
}

std::unique_ptr<Display> OpenGlfwDisplay(const DisplayOptions& options) {
  return std::make_unique<GlfwDisplay>(options);
}

}  // namespace sope
