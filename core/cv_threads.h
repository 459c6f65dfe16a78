// OpenCV's thread pool size for a scope.
#pragma once

#include <opencv2/core/utility.hpp>

namespace sope {

// Sets cv::setNumThreads(threads) for its lifetime and restores the previous value after,
// also when the scope is left by an exception.
//
//   {
//     const ScopedCvThreads one(1);  // cv::parallel_for_ runs on the calling thread
//     ...
//   }
class ScopedCvThreads {
 public:
  explicit ScopedCvThreads(int threads) : previous_(cv::getNumThreads()) {
    cv::setNumThreads(threads);
  }
  ~ScopedCvThreads() { cv::setNumThreads(previous_); }
  ScopedCvThreads(const ScopedCvThreads&) = delete;
  ScopedCvThreads& operator=(const ScopedCvThreads&) = delete;

 private:
  int previous_;
};

}  // namespace sope
