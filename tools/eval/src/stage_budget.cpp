#include "polmap/eval/stage_budget.hpp"

#include <cstdio>
#include <utility>
#include <vector>

#include "polmap/schema/errors.hpp"

namespace polmap::eval {
namespace {

std::vector<std::pair<const char*, double>> stages(const loc::StageCpuTimes& s) {
  const double listed = s.egomotion_s + s.gridmap_s + s.points_s + s.lines_s + s.clustering_s +
                        s.tiles_s + s.matching_s + s.smoothing_s + s.graph_s;
  return {{"egomotion", s.egomotion_s},   {"gridmap", s.gridmap_s},
          {"points", s.points_s},         {"lines", s.lines_s},
          {"clustering", s.clustering_s}, {"tiles", s.tiles_s},
          {"matching", s.matching_s},     {"smoothing", s.smoothing_s},
          {"graph", s.graph_s},           {"other", std::max(0.0, s.total_s - listed)}};
}

}  // namespace

nlohmann::json stage_budget_json(const loc::StageCpuTimes& sum, double drive_s,
                                 double helper_threads_cpu_s) {
  POLMAP_EXPECT(drive_s > 0.0);
  nlohmann::json j = nlohmann::json::object();
  for (const auto& [name, s] : stages(sum)) j[name] = 1e3 * s / drive_s;
  j["helper_threads"] = 1e3 * helper_threads_cpu_s / drive_s;
  const double total_s = sum.total_s + helper_threads_cpu_s;
  j["total"] = 1e3 * total_s / drive_s;
  j["realtime_factor"] = total_s > 0.0 ? drive_s / total_s : 0.0;
  return j;
}

std::string format_stage_budget(const loc::StageCpuTimes& sum, double drive_s,
                                double helper_threads_cpu_s) {
  POLMAP_EXPECT(drive_s > 0.0);
  std::string out = "stage            CPU ms per s of driving\n";
  char buf[96];
  auto row = [&](const char* name, double s) {
    std::snprintf(buf, sizeof buf, "  %-14s %8.1f\n", name, 1e3 * s / drive_s);
    out += buf;
  };
  for (const auto& [name, s] : stages(sum)) row(name, s);
  row("helper threads", helper_threads_cpu_s);
  const double total_s = sum.total_s + helper_threads_cpu_s;
  row("total", total_s);
  std::snprintf(buf, sizeof buf, "  %-14s %8.1fx\n", "real time",
                total_s > 0 ? drive_s / total_s : 0.0);
  out += buf;
  return out;
}

}  // namespace polmap::eval
