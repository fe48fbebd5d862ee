#include "polmap/radar/odometry.hpp"

#include <algorithm>
#include <cmath>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {

void Odometry::add(const MotionEstimate& estimate) {
  if (estimate.status != MotionEstimate::Status::Ok) return;
  MotionEstimate m = estimate;
  if (std::abs(m.v_mps) < cfg_.standstill_speed_mps) {
    m.v_mps = 0.0;  // zero-velocity update (OdometryConfig::standstill_speed_mps)
    m.yaw_rate_rps = 0.0;
  }
  if (nodes_.empty()) {
    nodes_.push_back({m.time_s, Pose2{}, m.v_mps, m.yaw_rate_rps, m.v_mps, m.yaw_rate_rps});
    return;
  }
  Node& last = nodes_.back();
  POLMAP_EXPECT(m.time_s >= last.time_s);
  const double dt = m.time_s - last.time_s;
  if (dt <= 0.0) {
    // Same time: keep the pose, take the newer state.
    last.v_mps = last.seg_v_mps = m.v_mps;
    last.yaw_rate_rps = last.seg_yaw_rate_rps = m.yaw_rate_rps;
    return;
  }
  if (dt > cfg_.max_hold_s) ++num_gaps_;
  last.seg_v_mps = 0.5 * (last.v_mps + m.v_mps);
  last.seg_yaw_rate_rps = 0.5 * (last.yaw_rate_rps + m.yaw_rate_rps);
  const Pose2 T = last.T_odom_vehicle * integrate_motion(last.seg_v_mps, last.seg_yaw_rate_rps, dt);
  distance_m_ += std::abs(last.seg_v_mps) * dt;
  nodes_.push_back({m.time_s, T, m.v_mps, m.yaw_rate_rps, m.v_mps, m.yaw_rate_rps});
  if (cfg_.history_s > 0) {
    while (nodes_.size() > 2 && m.time_s - nodes_[1].time_s > cfg_.history_s) nodes_.pop_front();
  }
}

double Odometry::latest_time_s() const {
  POLMAP_EXPECT(!nodes_.empty());
  return nodes_.back().time_s;
}

std::optional<Pose2> Odometry::try_T_odom_vehicle(double time_s) const {
  if (nodes_.empty()) return std::nullopt;
  if (time_s < nodes_.front().time_s || time_s > nodes_.back().time_s + cfg_.max_hold_s) {
    return std::nullopt;
  }
  // Last node with node.time_s <= time_s; its segment state (the last node's
  // is its own estimate) carries the pose forward along the arc.
  auto it = std::upper_bound(nodes_.begin(), nodes_.end(), time_s,
                             [](double t, const Node& n) { return t < n.time_s; });
  const Node& n = *std::prev(it);
  const double dt = time_s - n.time_s;
  if (dt <= 0.0) return n.T_odom_vehicle;
  return n.T_odom_vehicle * integrate_motion(n.seg_v_mps, n.seg_yaw_rate_rps, dt);
}

Pose2 Odometry::T_odom_vehicle(double time_s) const {
  const std::optional<Pose2> T = try_T_odom_vehicle(time_s);
  if (!T) {
    throw ContractViolation("Odometry::T_odom_vehicle: time " + std::to_string(time_s) +
                            " s outside the available range");
  }
  return *T;
}

}  // namespace polmap::radar
