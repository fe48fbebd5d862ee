// RunRecorder (run_recorder.hpp).
#include "polmap/localization_client/run_recorder.hpp"

#include <cmath>
#include <numbers>

namespace polmap::loc {

RunStatus to_run_status(LocalizationOutput::Status s) {
  switch (s) {
    case LocalizationOutput::Status::Tracking:
      return RunStatus::Tracking;
    case LocalizationOutput::Status::Degraded:
      return RunStatus::Degraded;
    case LocalizationOutput::Status::Lost:
      return RunStatus::Lost;
    default:
      return RunStatus::Initializing;
  }
}

void RunRecorder::add(const LocalizationOutput& out) {
  if (!out.has_pose) return;
  map_version_ = std::max(map_version_, out.map_version);
  const RunStatus status = to_run_status(out.status);
  if (!samples_.empty()) {
    const auto& last = samples_.back();
    if (!(out.time_s > last.t_s)) return;  // frames of several sensors at one instant
    if (status == last.status && out.time_s - last.t_s < cfg_.min_interval_s) return;
  }
  if (samples_.size() >= cfg_.max_samples) {
    truncated_ = true;
    return;
  }
  LocalizationRunSample s;
  s.t_s = out.time_s;
  s.lat_deg = out.pose.position.lat_deg;
  s.lon_deg = out.pose.position.lon_deg;
  // (-180, 180], as the report format wants.
  double yaw_deg = std::remainder(out.pose.yaw_enu_rad * 180.0 / std::numbers::pi, 360.0);
  if (yaw_deg <= -180.0) yaw_deg += 360.0;
  s.yaw_enu_deg = yaw_deg;
  s.status = status;
  s.cov_xx_m2 = std::max(out.covariance(0, 0), 0.0);
  s.cov_yy_m2 = std::max(out.covariance(1, 1), 0.0);
  // Clamped into the PSD cone against rounding in the solver's covariance.
  const double bound = std::sqrt(s.cov_xx_m2 * s.cov_yy_m2);
  s.cov_xy_m2 = std::clamp(out.covariance(0, 1), -bound, bound);
  s.cov_yaw_rad2 = std::max(out.covariance(2, 2), 0.0);
  samples_.push_back(s);
}

LocalizationRun RunRecorder::run(std::string label, std::string pol,
                                 std::optional<double> realtime_factor) const {
  LocalizationRun r;
  r.label = std::move(label);
  r.pol = std::move(pol);
  r.map_version = static_cast<std::int64_t>(map_version_);
  r.realtime_factor = realtime_factor;
  r.samples = samples_;
  return r;
}

}  // namespace polmap::loc
