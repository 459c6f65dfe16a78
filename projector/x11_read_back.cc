#include "projector/x11_read_back.h"

#include <cstdint>
#include <string>

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <X11/Xlib.h>
#include <X11/Xutil.h>

// GLFW's X11 native access, declared here rather than through <GLFW/glfw3native.h>, which
// also wants the XRandR development headers.
extern "C" {
::Display* glfwGetX11Display(void);
Window glfwGetX11Window(GLFWwindow* window);
}

namespace sope {
namespace internal {
namespace {

int x_error_code = 0;

int OnXError(::Display*, XErrorEvent* event) {
  x_error_code = event->error_code;
  return 0;
}

// Shift and width of a channel mask (0x00ff0000 → 16, 8).
void MaskShape(unsigned long mask, int* shift, int* bits) {
  *shift = 0;
  *bits = 0;
  if (mask == 0) return;
  while (!((mask >> *shift) & 1ul)) ++*shift;
  while ((mask >> (*shift + *bits)) & 1ul) ++*bits;
}

uint8_t Channel(unsigned long pixel, int shift, int bits) {
  const unsigned long value = (pixel >> shift) & ((1ul << bits) - 1ul);
  return bits >= 8 ? static_cast<uint8_t>(value >> (bits - 8))
                   : static_cast<uint8_t>(value * 255ul / ((1ul << bits) - 1ul));
}

}  // namespace

bool ReadBackX11(GLFWwindow* window, int width, int height, cv::Mat* bgr, std::string* message) {
  ::Display* display = glfwGetX11Display();
  const Window x_window = glfwGetX11Window(window);
  if (!display || !x_window) {
    *message = "not an X11 window";
    return false;
  }
  XSync(display, False);
  x_error_code = 0;
  XErrorHandler previous = XSetErrorHandler(OnXError);
  XImage* image = XGetImage(display, x_window, 0, 0, static_cast<unsigned>(width),
                            static_cast<unsigned>(height), AllPlanes, ZPixmap);
  XSync(display, False);
  XSetErrorHandler(previous);
  if (!image || x_error_code != 0) {
    if (image) XDestroyImage(image);
    *message = "XGetImage failed (X error " + std::to_string(x_error_code) +
               "; is the window entirely on screen?)";
    return false;
  }
  int red_shift, red_bits, green_shift, green_bits, blue_shift, blue_bits;
  MaskShape(image->red_mask, &red_shift, &red_bits);
  MaskShape(image->green_mask, &green_shift, &green_bits);
  MaskShape(image->blue_mask, &blue_shift, &blue_bits);
  bgr->create(height, width, CV_8UC3);
  for (int y = 0; y < height; ++y) {
    cv::Vec3b* row = bgr->ptr<cv::Vec3b>(y);
    for (int x = 0; x < width; ++x) {
      const unsigned long pixel = XGetPixel(image, x, y);
      row[x] =
          cv::Vec3b(Channel(pixel, blue_shift, blue_bits), Channel(pixel, green_shift, green_bits),
                    Channel(pixel, red_shift, red_bits));
    }
  }
  XDestroyImage(image);
  return true;
}

}  // namespace internal
}  // namespace sope
