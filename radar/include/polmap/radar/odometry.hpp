#pragma once
/// @file odometry.hpp
/// Dead reckoning from radar ego-motion estimates: the odometry frame in which
/// localization builds its sliding-window gridmap (paper §III-B1).
///
/// Integration. Between consecutive accepted estimates (t₀, v₀, ω₀) and
/// (t₁, v₁, ω₁) the vehicle is taken to move on an arc with the mean state
/// v̄ = (v₀+v₁)/2, ω̄ = (ω₀+ω₁)/2 (trapezoid rule; exact for constant v, ω
/// and second-order accurate under constant acceleration), integrated exactly
/// with polmap::integrate_motion. The odometry frame is the vehicle pose at the
/// first accepted estimate.
///
/// Queries. T_odom_vehicle(t) between two estimate times follows the same arc
/// (interpolation consistent with the integration); after the last estimate it
/// extrapolates with the last motion state held constant, for at most
/// `max_hold_s`. Estimates with a status other than Ok are ignored: the last
/// motion state is held. A gap between accepted estimates longer than
/// `max_hold_s` is still bridged (trapezoid), but counted in num_gaps() so
/// callers can tell that the odometry crossed an outage.
#include <deque>
#include <optional>

#include "polmap/radar/egomotion.hpp"
#include "polmap/schema/pose2.hpp"

namespace polmap::radar {

struct OdometryConfig {
  /// Longest time the last motion state is held (extrapolation after the last
  /// estimate; longer gaps between estimates are counted as gaps).
  double max_hold_s = 0.5;
  /// Poses older than this (relative to the newest estimate) are forgotten;
  /// 0 keeps the whole history. 120 s covers any localization window.
  double history_s = 120.0;
  /// Zero-velocity update: an estimate slower than this is integrated as
  /// standstill (v = 0 and, as a car cannot turn on the spot, ω = 0). At a
  /// stop the estimates scatter around 0 (σ ≈ 0.005 m/s, 0.0016 rad/s in the
  /// simulator) and any bias would creep 0.1-0.2 m per 10 s; accelerating
  /// through 0.05 m/s at 1 m/s² loses about 1 mm. 0 disables it.
  double standstill_speed_mps = 0.05;
};

class Odometry {
 public:
  explicit Odometry(OdometryConfig cfg = {}) : cfg_(cfg) {}

  /// Integrates (arc model) from the previous accepted estimate to m.time_s.
  /// Estimates must come in non-decreasing time; non-Ok estimates are ignored.
  void add(const MotionEstimate& m);

  /// Pose of the vehicle in the odometry frame at time_s, for any time in
  /// [oldest kept estimate, newest estimate + max_hold_s]. Throws
  /// ContractViolation outside that range (see try_T_odom_vehicle).
  [[nodiscard]] Pose2 T_odom_vehicle(double time_s) const;
  /// As T_odom_vehicle, std::nullopt outside the available range.
  [[nodiscard]] std::optional<Pose2> try_T_odom_vehicle(double time_s) const;

  /// Path length integrated so far (|v̄|·Δt summed), metres.
  [[nodiscard]] double distance_m() const { return distance_m_; }
  [[nodiscard]] bool empty() const { return nodes_.empty(); }
  /// Time of the newest accepted estimate (requires !empty()).
  [[nodiscard]] double latest_time_s() const;
  /// Number of gaps between accepted estimates longer than max_hold_s.
  [[nodiscard]] int num_gaps() const { return num_gaps_; }
  [[nodiscard]] const OdometryConfig& config() const { return cfg_; }

 private:
  struct Node {
    double time_s;
    Pose2 T_odom_vehicle;
    double v_mps;  // estimate at time_s
    double yaw_rate_rps;
    double seg_v_mps;  // mean state of the arc from this node to the next
    double seg_yaw_rate_rps;
  };
  OdometryConfig cfg_;
  std::deque<Node> nodes_;
  double distance_m_ = 0.0;
  int num_gaps_ = 0;
};

}  // namespace polmap::radar
