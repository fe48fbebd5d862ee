#pragma once
/// @file cpu_time.hpp
/// CPU time of the calling thread: what a computation costs independent of other load
/// on the machine (benchmarks, the study's real-time factor, per-stage budgets).
#include <time.h>

namespace polmap::util {

/// CPU seconds the calling thread has used (CLOCK_THREAD_CPUTIME_ID).
[[nodiscard]] inline double thread_cpu_s() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

/// Lap timer on the thread CPU clock: lap() returns the CPU seconds since the last lap
/// (or construction).
class CpuLap {
 public:
  CpuLap() : last_s_(thread_cpu_s()) {}
  double lap() {
    const double now = thread_cpu_s();
    const double d = now - last_s_;
    last_s_ = now;
    return d;
  }

 private:
  double last_s_;
};

}  // namespace polmap::util
