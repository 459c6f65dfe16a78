// Reading a GLFW window back from the X server (glfw_display.cc's ReadBack): a separate
// translation unit because Xlib's macros and its `Display` type must not meet ours.
#pragma once

#include <opencv2/core/mat.hpp>
#include <string>

struct GLFWwindow;

namespace sope {
namespace internal {

// The window's pixels as the X server holds them (XGetImage), CV_8UC3 BGR, top row first.
// False when the window is not on X11 or the X server refuses (e.g. the window is partly
// off screen); `message` then says why.
bool ReadBackX11(GLFWwindow* window, int width, int height, cv::Mat* bgr, std::string* message);

}  // namespace internal
}  // namespace sope
