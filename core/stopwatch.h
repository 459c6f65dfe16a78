// The one timer: wall-clock (CLOCK_MONOTONIC) and calling-thread CPU time
// (CLOCK_THREAD_CPUTIME_ID) since construction or Restart(). Compare CPU times on shared
// machines; never assert either in a test (STYLE.md §6).
#pragma once

#include <time.h>

namespace sope {

class Stopwatch {
 public:
  Stopwatch() { Restart(); }
  void Restart() {
    wall_start_ = NowMs(CLOCK_MONOTONIC);
    cpu_start_ = NowMs(CLOCK_THREAD_CPUTIME_ID);
  }
  double WallMs() const { return NowMs(CLOCK_MONOTONIC) - wall_start_; }
  double CpuMs() const { return NowMs(CLOCK_THREAD_CPUTIME_ID) - cpu_start_; }
  double WallSeconds() const { return 1e-3 * WallMs(); }

  // Milliseconds on `clock` since its epoch.
  static double NowMs(clockid_t clock) {
    timespec ts{};
    clock_gettime(clock, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
  }

 private:
  double wall_start_ = 0.0, cpu_start_ = 0.0;
};

}  // namespace sope
