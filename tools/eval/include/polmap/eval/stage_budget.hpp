#pragma once
/// @file stage_budget.hpp
/// The per-stage CPU budget of a localization run: milliseconds of CPU per second of
/// driving, from the summed loc::StageCpuTimes of every Localizer::process call (and
/// the CPU of helper threads such as the tile fetcher's worker). 1000 ms/s is real time;
/// 100 ms/s is 10× real time.
#include <nlohmann/json.hpp>
#include <string>

#include "polmap/localization_client/localizer.hpp"

namespace polmap::eval {

/// {"egomotion": ms/s, "gridmap", "points", "lines", "clustering", "tiles", "matching",
///  "smoothing", "graph", "other" (total − stages), "helper_threads", "total",
///  "realtime_factor"}. drive_s > 0.
[[nodiscard]] nlohmann::json stage_budget_json(const loc::StageCpuTimes& sum, double drive_s,
                                               double helper_threads_cpu_s = 0.0);

/// The same as an aligned text table (one stage per line), for terminals.
[[nodiscard]] std::string format_stage_budget(const loc::StageCpuTimes& sum, double drive_s,
                                              double helper_threads_cpu_s = 0.0);

}  // namespace polmap::eval
