#pragma once
/// @file deadline.hpp
/// A wall-clock budget for work on hostile input: the work checks `expired()` at its loop
/// boundaries and gives up, so no input can hold a thread longer than its budget.
#include <chrono>
#include <cmath>

namespace polmap::util {

class Deadline {
 public:
  using Clock = std::chrono::steady_clock;

  /// No budget: never expires.
  [[nodiscard]] static Deadline never() { return Deadline(Clock::time_point::max(), 0.0); }
  /// Expires `budget_s` seconds from now; a budget <= 0 or not finite means never.
  [[nodiscard]] static Deadline after_s(double budget_s) {
    if (!(budget_s > 0.0) || !std::isfinite(budget_s)) return never();
    const auto d =
        std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(budget_s));
    return Deadline(Clock::now() + d, budget_s);
  }

  [[nodiscard]] bool expired() const {
    return at_ != Clock::time_point::max() && Clock::now() >= at_;
  }
  /// The budget this deadline was made with (0 for never).
  [[nodiscard]] double budget_s() const { return budget_s_; }

 private:
  Deadline(Clock::time_point at, double budget_s) : at_(at), budget_s_(budget_s) {}
  Clock::time_point at_;
  double budget_s_;
};

}  // namespace polmap::util
