#include "polmap/sim/doppler_residuals.hpp"

#include <algorithm>
#include <cmath>

namespace polmap::sim {

double static_doppler_residual_mps(const Detection& d, const SensorMount& mount, double v, double w,
                                   double v_ua) {
  const Pose2& m = mount.T_vehicle_sensor;
  const double vx = v - w * m.y_m, vy = w * m.x_m;
  const double c = std::cos(m.yaw_rad), s = std::sin(m.yaw_rad);
  const double sx = c * vx + s * vy, sy = -s * vx + c * vy;
  const double az = d.azimuth_rad;
  const double v_static = -(sx * std::cos(az) + sy * std::sin(az));
  double r = d.radial_velocity_mps - v_static;
  if (v_ua > 0) {
    r = std::fmod(r + v_ua, 2.0 * v_ua);
    if (r < 0) r += 2.0 * v_ua;
    r -= v_ua;
  }
  return r;
}

void DopplerResidualAccumulator::add(const SensorFrame& f, const SensorMount& mount, double v,
                                     double w) {
  if (std::abs(v) < min_speed_) return;
  auto& r = residuals_[f.sensor_id];
  ++frames_[f.sensor_id];
  for (const Detection& d : f.detections) {
    r.push_back(static_cast<float>(
        static_doppler_residual_mps(d, mount, v, w, mount.spec.v_unambiguous_mps)));
  }
}

DopplerResidualStats DopplerResidualAccumulator::stats(std::vector<float> r,
                                                       std::size_t frames) const {
  DopplerResidualStats s;
  s.detections = r.size();
  s.frames = frames;
  if (r.empty()) return s;
  s.detections_per_frame = frames ? static_cast<double>(r.size()) / frames : 0.0;
  std::size_t out = 0;
  for (float x : r) out += std::abs(x) > threshold_ ? 1 : 0;
  s.outlier_share = static_cast<double>(out) / r.size();
  const auto mid = r.begin() + r.size() / 2;
  std::nth_element(r.begin(), mid, r.end());
  s.median_mps = *mid;
  for (float& x : r) x = std::abs(x - static_cast<float>(s.median_mps));
  std::nth_element(r.begin(), mid, r.end());
  s.robust_sigma_mps = 1.4826 * *mid;
  return s;
}

DopplerResidualStats DopplerResidualAccumulator::total() const {
  std::vector<float> all;
  std::size_t frames = 0;
  for (const auto& [id, r] : residuals_) all.insert(all.end(), r.begin(), r.end());
  for (const auto& [id, n] : frames_) frames += n;
  return stats(std::move(all), frames);
}

std::map<std::uint8_t, DopplerResidualStats> DopplerResidualAccumulator::per_sensor() const {
  std::map<std::uint8_t, DopplerResidualStats> out;
  for (const auto& [id, r] : residuals_) out[id] = stats(r, frames_.at(id));
  return out;
}

}  // namespace polmap::sim
