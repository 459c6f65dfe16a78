#include "capture/clock.h"

#include <time.h>

#include <cerrno>
#include <cmath>

namespace sope {

double MonotonicSeconds() {
  timespec now{};
  clock_gettime(CLOCK_MONOTONIC, &now);
  return static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec);
}

void SleepUntilMonotonic(double time) {
  if (!(time > MonotonicSeconds())) return;
  timespec until{};
  until.tv_sec = static_cast<time_t>(std::floor(time));
  until.tv_nsec = static_cast<long>((time - std::floor(time)) * 1e9);
  if (until.tv_nsec >= 1000000000L) until.tv_nsec = 999999999L;
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &until, nullptr) == EINTR) {
  }
}

void SimulatedClock::AdvanceTo(double time) {
  double current = now_.load();
  while (time > current && !now_.compare_exchange_weak(current, time)) {
  }
}

}  // namespace sope
