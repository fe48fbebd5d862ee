#pragma once
/// @file progress.hpp
/// A one-line progress indicator on stderr, shown only when stderr is a terminal.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <string>

namespace polmap::cli {

class Progress {
 public:
  /// total <= 0 means unknown total (shows a count only).
  Progress(std::string label, double total)
      : label_(std::move(label)), total_(total), enabled_(isatty(fileno(stderr)) != 0) {}
  ~Progress() { finish(); }
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;

  void update(double done, const std::string& note = {}) {
    if (!enabled_) return;
    const auto now = std::chrono::steady_clock::now();
    if (now - last_ < std::chrono::milliseconds(200)) return;
    last_ = now;
    if (total_ > 0) {
      std::fprintf(stderr, "\r%s: %5.1f%% %s   ", label_.c_str(), 100.0 * done / total_,
                   note.c_str());
    } else {
      std::fprintf(stderr, "\r%s: %.0f %s   ", label_.c_str(), done, note.c_str());
    }
    std::fflush(stderr);
    shown_ = true;
  }
  void finish() {
    if (enabled_ && shown_) {
      std::fprintf(stderr, "\r\033[K");
      std::fflush(stderr);
      shown_ = false;
    }
  }

 private:
  std::string label_;
  double total_;
  bool enabled_;
  bool shown_ = false;
  std::chrono::steady_clock::time_point last_{};
};

}  // namespace polmap::cli
