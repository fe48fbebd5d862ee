#pragma once
/// @file run_recorder.hpp
/// RunRecorder: turns the localizer's outputs into a localization run report
/// (schema/localization_run.hpp) for the mapping service (POST /v1/runs; sent by
/// loc::report_localization_run in tile_fetcher's module, or by `polmap localize --report`).
/// The report is decimated: one sample per `min_interval_s`, plus every status change,
/// so a report stays small while the places where the status changed stay exact.
#include <optional>
#include <string>
#include <vector>

#include "polmap/localization_client/localizer.hpp"
#include "polmap/schema/localization_run.hpp"

namespace polmap::loc {

struct RunRecorderConfig {
  /// Shortest time between two kept samples (s): 5 Hz, ≈ 3 m apart at 50 km/h.
  double min_interval_s = 0.2;
  /// Samples kept at most (later outputs are dropped; `truncated()` tells).
  std::size_t max_samples = 100'000;
};

/// The report status of a localizer status.
[[nodiscard]] RunStatus to_run_status(LocalizationOutput::Status s);

class RunRecorder {
 public:
  explicit RunRecorder(RunRecorderConfig cfg = {}) : cfg_(cfg) {}

  /// Adds one output of Localizer::process (outputs without a pose are skipped).
  void add(const LocalizationOutput& out);

  [[nodiscard]] const std::vector<LocalizationRunSample>& samples() const { return samples_; }
  [[nodiscard]] bool truncated() const { return truncated_; }

  /// The report so far: map_version is the newest seen.
  [[nodiscard]] LocalizationRun run(std::string label, std::string pol,
                                    std::optional<double> realtime_factor = std::nullopt) const;

 private:
  RunRecorderConfig cfg_;
  std::vector<LocalizationRunSample> samples_;
  std::uint64_t map_version_ = 0;
  bool truncated_ = false;
};

}  // namespace polmap::loc
