#pragma once
/// @file drive.hpp
/// One pass over a world's route: the exact trajectory (speed profile with
/// acceleration limits, curve speeds, stops at red lights, lane wander), the
/// drive's moving traffic and temporary objects, and the GNSS/IMU error model.
#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <vector>

#include "polmap/schema/recording.hpp"
#include "polmap/sim/config.hpp"
#include "polmap/sim/consumer_gnss.hpp"
#include "polmap/sim/path.hpp"
#include "polmap/sim/random.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::sim {

/// Exact vehicle state (rear-axle centre, world frame).
struct ExactState {
  double time_s = 0.0;
  double s_m = 0.0;  ///< station along the drive path
  double x_m = 0.0;
  double y_m = 0.0;
  double yaw_rad = 0.0;  ///< world-frame yaw
  double v_mps = 0.0;
  double yaw_rate_rps = 0.0;
  double accel_mps2 = 0.0;
  /// Rear-axle side slip beta = atan(v_y / v_x) (ISO 8855); the velocity in the vehicle frame
  /// is v_mps * (cos beta, sin beta). Zero unless RealismConfig::slip is enabled.
  double side_slip_rad = 0.0;
};

/// A vehicle of the moving traffic, driving along the world route.
struct Mover {
  double s0_m = 0.0;       ///< station at t = 0
  double speed_mps = 0.0;  ///< along its direction
  int direction = -1;      ///< +1 with the ego, -1 oncoming
  double lateral_m = 0.0;  ///< lane offset from the route (left positive)
  double length_m = 4.5;
  double width_m = 1.8;
  /// Scattering centres; pos_m in the car frame (x forward, y left).
  std::vector<PointScatterer> centres;
  [[nodiscard]] double station(double t) const { return s0_m + direction * speed_mps * t; }
};

class DrivePlan {
 public:
  DrivePlan(const World& world, const SimConfig& cfg, int drive_index);

  [[nodiscard]] int drive_index() const { return drive_; }
  [[nodiscard]] double duration_s() const { return duration_; }
  [[nodiscard]] double distance_m() const;
  [[nodiscard]] const Path& path() const { return path_; }
  [[nodiscard]] double cruise_speed_mps() const { return cruise_; }
  /// Exact state at time t in [0, duration].
  [[nodiscard]] ExactState state(double t) const;
  [[nodiscard]] const std::vector<Mover>& movers() const { return movers_; }
  /// Temporary-object presence in this drive (permanent ones: true).
  [[nodiscard]] bool present(std::uint32_t object_id) const { return present_[object_id] != 0; }
  /// Where a present temporary object stands in this drive relative to its world place
  /// (World::drive_shift_m; zero for permanent objects).
  [[nodiscard]] const Eigen::Vector2d& shift_m(std::uint32_t object_id) const {
    return shift_[object_id];
  }
  /// Red lights of this drive: (stop station, dwell seconds).
  [[nodiscard]] const std::vector<std::pair<double, double>>& stops() const { return stops_; }

 private:
  const World& world_;
  int drive_;
  Path path_;
  double cruise_ = 0.0;
  double ds_ = 0.5;
  std::vector<double> v_;  ///< speed at grid stations i * ds
  std::vector<double> t_arrive_, t_depart_;
  double duration_ = 0.0;
  std::vector<std::pair<double, double>> stops_;
  std::vector<Mover> movers_;
  std::vector<std::uint8_t> present_;
  std::vector<Eigen::Vector2d> shift_;
  SlipRealism slip_;
};

/// GNSS/IMU errors: first-order Gauss-Markov position (sigma by fix state) and heading
/// errors, planned stretches without carrier-phase fix, white speed / yaw-rate noise.
class GnssErrorModel {
 public:
  /// ins and slip (realism.hpp) add INS errors and wheel slip of the recorded speed; their
  /// draws come from separate generators (disabled: bit-identical to the ideal model).
  GnssErrorModel(const GnssSimConfig& cfg, double duration_s, std::uint64_t seed,
                 const InsRealism& ins = {}, const SlipRealism& slip = {});
  /// Next sample (call with strictly increasing times). truth.time_s is the sample's time
  /// stamp; with INS latency the caller passes the state of time_s - latency_s().
  TrajectorySample sample(const ExactState& truth, const tiles::LocalFrame& frame);
  /// Consumer grade (GnssSimConfig::grade): the place-dependent multipath error to add
  /// (none by default). Must outlive this model's samples.
  void set_multipath(std::shared_ptr<const CanyonMultipathField> field) {
    multipath_ = std::move(field);
  }
  /// Consumer grade: seconds of the drive spent in outages so far (dead reckoning).
  [[nodiscard]] double consumer_outage_s() const { return consumer_outage_total_s_; }
  /// Latency error of the INS time stamps (0 unless InsRealism is enabled).
  [[nodiscard]] double latency_s() const { return latency_s_; }
  [[nodiscard]] bool fixed_at(double t) const;
  [[nodiscard]] const std::vector<std::pair<double, double>>& no_fix_stretches() const {
    return stretches_;
  }

 private:
  GnssSimConfig cfg_;
  Rng rng_;
  std::vector<std::pair<double, double>> stretches_;
  double last_t_ = -1.0;
  double ex_ = 0.0, ey_ = 0.0, eh_ = 0.0;  ///< unit-variance GM states
  // Realism (realism.hpp): per-drive INS constants and the dead-reckoning drift state.
  InsRealism ins_;
  SlipRealism slip_;
  double lever_x_m_ = 0, lever_y_m_ = 0, heading_bias_rad_ = 0, yaw_rate_bias_rps_ = 0;
  double latency_s_ = 0, accel_bias_x_ = 0, accel_bias_y_ = 0, wheel_scale_ = 0;
  double drift_x_m_ = 0, drift_y_m_ = 0, drift_vx_ = 0, drift_vy_ = 0;
  // Consumer grade: own generator (the RTK stream stays as it is), unit-variance GM bias and
  // heading states, the outage in progress and its drift.
  TrajectorySample sample_consumer(const ExactState& truth, const tiles::LocalFrame& frame,
                                   double dt_s);
  Rng consumer_rng_;
  std::shared_ptr<const CanyonMultipathField> multipath_;
  double cbx_ = 0, cby_ = 0, ch_ = 0;
  double outage_left_s_ = 0, consumer_outage_total_s_ = 0;
  Eigen::Vector2d outage_dir_ = Eigen::Vector2d::UnitX();
  Eigen::Vector2d outage_drift_m_ = Eigen::Vector2d::Zero();
  /// Receiver error (bias + multipath) after the navigation filter's low-pass.
  Eigen::Vector2d fused_error_m_ = Eigen::Vector2d::Zero();
  bool fused_started_ = false;
};

/// Exact pose converted to geodetic (truth CSV, tests).
struct GeoTruth {
  double lat_deg, lon_deg, yaw_enu_rad;
};
GeoTruth to_geo_truth(const ExactState& s, const tiles::LocalFrame& frame);

}  // namespace polmap::sim
