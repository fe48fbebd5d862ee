#include "polmap/radar/reference_mount_calibration.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {

const char* to_string(ReferenceMountCalibration::Status s) {
  return s == ReferenceMountCalibration::Status::Converged ? "converged" : "not observable yet";
}

ReferenceMountCalibrator::ReferenceMountCalibrator(std::vector<SensorMount> mounts,
                                                   ReferenceMountCalibrationConfig cfg)
    : mounts_(std::move(mounts)), cfg_(cfg), acc_(mounts_.size()) {
  POLMAP_EXPECT(cfg_.vr_sigma_mps > 0.0 && cfg_.azimuth_sigma_rad >= 0.0 &&
                cfg_.prior_yaw_sigma_rad > 0.0 && cfg_.prior_time_offset_sigma_s > 0.0 &&
                cfg_.gate_sigmas > 0.0 && cfg_.sigma_inflation >= 1.0);
}

Eigen::Matrix2d ReferenceMountCalibrator::information(std::size_t s) const {
  Eigen::Matrix2d L = acc_[s].info;
  L(0, 0) += 1.0 / (cfg_.prior_yaw_sigma_rad * cfg_.prior_yaw_sigma_rad);
  L(1, 1) += 1.0 / (cfg_.prior_time_offset_sigma_s * cfg_.prior_time_offset_sigma_s);
  return L;
}

Eigen::Vector2d ReferenceMountCalibrator::solve(std::size_t s) const {
  return information(s).ldlt().solve(acc_[s].rhs);
}

void ReferenceMountCalibrator::add_frame(const SensorFrame& frame, const ReferenceMotion& m) {
  std::size_t s = mounts_.size();
  for (std::size_t i = 0; i < mounts_.size(); ++i) {
    if (mounts_[i].sensor_id == frame.sensor_id) s = i;
  }
  if (s == mounts_.size() || std::hypot(m.v_x_mps, m.v_y_mps) < cfg_.min_speed_mps) return;
  const SensorMount& mount = mounts_[s];
  const double xs = mount.T_vehicle_sensor.x_m, ys = mount.T_vehicle_sensor.y_m;
  // Sensor velocity and its rate of change, vehicle-frame components.
  const Eigen::Vector2d vs(m.v_x_mps - m.yaw_rate_rps * ys, m.v_y_mps + m.yaw_rate_rps * xs);
  const Eigen::Vector2d as(m.a_x_mps2 - m.yaw_accel_rps2 * ys, m.a_y_mps2 + m.yaw_accel_rps2 * xs);
  const Eigen::Vector2d est = solve(s);
  const double vua = mount.spec.v_unambiguous_mps;
  const double s_vr2 = cfg_.vr_sigma_mps * cfg_.vr_sigma_mps;
  const double s_az2 = cfg_.azimuth_sigma_rad * cfg_.azimuth_sigma_rad;
  struct Row {
    double r, w, g_yaw, g_time;
  };
  std::vector<Row> rows;
  rows.reserve(frame.detections.size());
  for (const Detection& d : frame.detections) {
    const double th = mount.T_vehicle_sensor.yaw_rad + static_cast<double>(d.azimuth_rad);
    const Eigen::Vector2d u(std::cos(th), std::sin(th)), du(-std::sin(th), std::cos(th));
    const double pred = -vs.dot(u);
    const double g_yaw = -vs.dot(du), g_time = -as.dot(u);
    const double pred_now = pred + est(0) * g_yaw + est(1) * g_time;
    double vr = d.radial_velocity_mps;
    if (vua > 0) vr += 2.0 * vua * std::round((pred_now - vr) / (2.0 * vua));
    const double w = 1.0 / (s_vr2 + s_az2 * g_yaw * g_yaw);
    const double gate = acc_[s].frames == 0
                            ? cfg_.first_gate_mps
                            : std::max(cfg_.gate_sigmas / std::sqrt(w), cfg_.gate_min_mps);
    if (std::abs(vr - pred_now) > gate) continue;
    rows.push_back({vr - pred, w, g_yaw, g_time});
  }
  if (static_cast<int>(rows.size()) < cfg_.min_detections_per_frame) return;
  Accumulator& a = acc_[s];
  for (const Row& row : rows) {
    const Eigen::Vector2d g(row.g_yaw, row.g_time);
    a.info += row.w * g * g.transpose();
    a.rhs += row.w * g * row.r;
    a.rwr += row.w * row.r * row.r;
    ++a.n;
  }
  ++a.frames;
  if (!any_) first_time_s_ = frame.time_s;
  any_ = true;
  first_time_s_ = std::min(first_time_s_, frame.time_s);
  last_time_s_ = std::max(last_time_s_, frame.time_s);
}

ReferenceMountCalibration ReferenceMountCalibrator::result() const {
  ReferenceMountCalibration res;
  res.observed_s = any_ ? last_time_s_ - first_time_s_ : 0.0;
  bool all = !mounts_.empty();
  for (std::size_t s = 0; s < mounts_.size(); ++s) {
    const Accumulator& a = acc_[s];
    const Eigen::Matrix2d L = information(s);
    const Eigen::Vector2d x = L.ldlt().solve(a.rhs);
    double s2 = 1.0;
    if (a.n > 2) s2 = std::max((a.rwr - a.rhs.dot(x)) / static_cast<double>(a.n - 2), 1e-6);
    const Eigen::Matrix2d cov = L.inverse() * std::max(s2, 1.0);
    ReferenceMountCalibration::Sensor e;
    e.sensor_id = mounts_[s].sensor_id;
    e.yaw_offset_rad = x(0);
    e.time_offset_s = x(1);
    e.yaw_sigma_rad = cfg_.sigma_inflation * std::sqrt(std::max(cov(0, 0), 0.0));
    e.time_sigma_s = cfg_.sigma_inflation * std::sqrt(std::max(cov(1, 1), 0.0));
    e.detections = a.n;
    e.frames = a.frames;
    all = all && e.yaw_sigma_rad <= cfg_.converged_yaw_sigma_rad;
    res.sensors.push_back(e);
  }
  res.status = all && res.observed_s >= cfg_.min_observed_s
                   ? ReferenceMountCalibration::Status::Converged
                   : ReferenceMountCalibration::Status::NotObservableYet;
  return res;
}

std::vector<SensorMount> ReferenceMountCalibrator::calibrated_mounts() const {
  std::vector<SensorMount> out = mounts_;
  for (std::size_t s = 0; s < out.size(); ++s) out[s].T_vehicle_sensor.yaw_rad += solve(s)(0);
  return out;
}

}  // namespace polmap::radar
