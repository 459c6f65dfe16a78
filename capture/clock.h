// Time for the capture loop: seconds as doubles on one clock per camera. Real cameras use
// CLOCK_MONOTONIC (the V4L2 buffer time base); simulated ones advance a SimulatedClock as
// their frames "arrive", so virtual sessions run as fast as rendering allows and are
// deterministic.
#pragma once

#include <atomic>

namespace sope {

// CLOCK_MONOTONIC now, seconds (the time base of V4L2 buffer timestamps).
double MonotonicSeconds();
// Sleeps until CLOCK_MONOTONIC reaches `time` (seconds); returns at once if it has passed.
void SleepUntilMonotonic(double time);

// A clock that only moves when told to. Thread-safe.
class SimulatedClock {
 public:
  explicit SimulatedClock(double start = 0.0) : now_(start) {}
  double Now() const { return now_.load(); }
  // Moves the clock forward to `time` (never backward).
  void AdvanceTo(double time);
  void Advance(double seconds) { AdvanceTo(Now() + seconds); }

 private:
  std::atomic<double> now_;
};

}  // namespace sope
