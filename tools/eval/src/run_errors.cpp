// attach_run_errors (run_errors.hpp).
#include "polmap/eval/run_errors.hpp"

#include <algorithm>
#include <numbers>

namespace polmap::eval {

TrajectoryMetrics attach_run_errors(LocalizationRun& run,
                                    const std::vector<ReferenceSample>& reference,
                                    RunReference kind, const TrajectoryEvalOptions& options) {
  std::vector<TrajectoryRow> rows;
  rows.reserve(run.samples.size());
  for (const LocalizationRunSample& s : run.samples) {
    TrajectoryRow r;
    r.time_s = s.t_s;
    r.status = std::string(to_string(s.status));
    r.lat_deg = s.lat_deg;
    r.lon_deg = s.lon_deg;
    r.yaw_enu_rad = s.yaw_enu_deg * std::numbers::pi / 180.0;
    r.cov_xx_m2 = s.cov_xx_m2;
    r.cov_xy_m2 = s.cov_xy_m2;
    r.cov_yy_m2 = s.cov_yy_m2;
    r.cov_yaw_rad2 = s.cov_yaw_rad2;
    rows.push_back(std::move(r));
  }
  TrajectoryMetrics m = evaluate_trajectory(rows, reference, options);
  for (LocalizationRunSample& s : run.samples) s.error.reset();
  // The evaluated samples come back in time order with the rows' own times.
  auto it = run.samples.begin();
  for (const TrajectoryError& e : m.errors) {
    it = std::lower_bound(it, run.samples.end(), e.time_s,
                          [](const LocalizationRunSample& s, double t) { return s.t_s < t; });
    if (it == run.samples.end() || it->t_s != e.time_s) continue;
    it->error = RunSampleError{e.long_m, e.lat_m, e.rot_rad * 180.0 / std::numbers::pi};
  }
  run.reference = kind;
  return m;
}

}  // namespace polmap::eval
