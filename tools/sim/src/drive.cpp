#include "polmap/sim/drive.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "polmap/schema/errors.hpp"
#include "polmap/sim/scattering.hpp"

namespace polmap::sim {

namespace {
constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;

ScatteringVector car_omega(Rng& rng) {
  const double u = rng.uniform();
  if (u < 0.4) return odd_bounce();
  if (u < 0.7) return dihedral(rng.uniform(0.0, kPi));
  const ScatteringVector a = odd_bounce(), b = dihedral(rng.uniform(0.0, kPi));
  const cdouble ca = rng.cnormal(), cb = rng.cnormal();
  ScatteringVector o{};
  for (int c = 0; c < 4; ++c) o[c] = ca * a[c] + cb * b[c];
  return normalized(o);
}
}  // namespace

DrivePlan::DrivePlan(const World& world, const SimConfig& cfg, int drive_index)
    : world_(world), drive_(drive_index), slip_(cfg.realism.slip) {
  POLMAP_EXPECT(!world.route.empty());
  Rng rng(seed_of(cfg.seed, 0x6472697665ULL, static_cast<std::uint64_t>(drive_index)));
  const DriveSimConfig& dc = cfg.drive;
  // Lane wander: smooth lateral offset, zero at the start.
  const double amp = rng.uniform(0.3, 1.0) * dc.lane_wander_amplitude_m;
  const double wl = rng.uniform(dc.lane_wander_wavelength_min_m, dc.lane_wander_wavelength_max_m);
  const double ph = rng.uniform(0.0, 2 * kPi);
  path_ = world.route.displaced([&](double s) {
    const double ramp = std::min(1.0, s / 30.0);
    return ramp * amp * (std::sin(2 * kPi * s / wl + ph) - std::sin(ph));
  });
  const double vmax = dc.max_speed_mps > 0 ? dc.max_speed_mps : world.road.default_max_speed_mps;
  cruise_ = vmax * rng.uniform(dc.min_speed_factor, 1.0);

  // Speed profile over stations (forward/backward passes with the acceleration limits).
  const double len = path_.length_m();
  const auto n = static_cast<std::size_t>(std::floor(len / ds_)) + 1;
  std::vector<double> vlim(n);
  for (std::size_t i = 0; i < n; ++i) {
    // Curvature ahead/behind within 5 m, so the car is already slow in the curve.
    double k = 0;
    for (double d = -5.0; d <= 5.0; d += 1.0) {
      k = std::max(k, std::abs(path_.at(i * ds_ + d).kappa_1pm));
    }
    vlim[i] = std::min(cruise_, k > 1e-6 ? std::sqrt(dc.lateral_accel_mps2 / k) : cruise_);
  }
  std::vector<double> dwell(n, 0.0);
  for (double ls : world.light_stations_m) {
    const double s_stop = ls - dc.stop_before_light_m;
    if (s_stop <= 10.0 || s_stop >= len - 10.0) continue;
    if (!rng.bernoulli(dc.red_light_probability)) continue;
    const auto i = static_cast<std::size_t>(std::lround(s_stop / ds_));
    dwell[i] = rng.uniform(dc.red_min_s, dc.red_max_s);
    vlim[i] = 0.0;
    stops_.emplace_back(i * ds_, dwell[i]);
  }
  vlim.front() = 0.0;
  vlim.back() = 0.0;
  v_ = vlim;
  for (std::size_t i = 1; i < n; ++i) {
    v_[i] = std::min(v_[i], std::sqrt(v_[i - 1] * v_[i - 1] + 2.0 * dc.accel_mps2 * ds_));
  }
  for (std::size_t i = n - 1; i-- > 0;) {
    v_[i] = std::min(v_[i], std::sqrt(v_[i + 1] * v_[i + 1] + 2.0 * dc.decel_mps2 * ds_));
  }
  t_arrive_.assign(n, 0.0);
  t_depart_.assign(n, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    if (i > 0) {
      const double vs = v_[i - 1] + v_[i];
      t_arrive_[i] = t_depart_[i - 1] + (vs > 1e-9 ? 2.0 * ds_ / vs : 0.0);
    }
    t_depart_[i] = t_arrive_[i] + dwell[i];
  }
  duration_ = t_arrive_.back();
  if (cfg.duration_s > 0) duration_ = std::min(duration_, cfg.duration_s);

  // Temporary objects of this drive.
  present_.resize(world.objects.size());
  shift_.assign(world.objects.size(), Eigen::Vector2d::Zero());
  for (std::uint32_t id = 0; id < world.objects.size(); ++id) {
    present_[id] = world.present(id, drive_index, cfg.seed) ? 1 : 0;
    shift_[id] = world.drive_shift_m(id, drive_index, cfg.seed);
  }

  // Moving traffic along the world route.
  const double wl_len = world.route.length_m();
  const double tmax = world.road.traffic_max_speed_mps;
  const double tmin = std::min(cfg.traffic.min_speed_mps, tmax);
  auto make_mover = [&](int dir, double lateral, double s0, double speed) {
    Mover m;
    m.direction = dir;
    m.lateral_m = lateral;
    m.s0_m = s0;
    m.speed_mps = speed;
    m.length_m = rng.uniform(4.0, 5.0);
    m.width_m = rng.uniform(1.7, 1.9);
    const double total = rng.uniform(10.0, 20.0);
    const double hl = 0.5 * m.length_m, hw = 0.5 * m.width_m;
    const std::vector<Eigen::Vector2d> local = {{hl, hw},
                                                {hl, -hw},
                                                {-hl, hw},
                                                {-hl, -hw},
                                                {0.3 * m.length_m, hw},
                                                {0.3 * m.length_m, -hw},
                                                {-0.3 * m.length_m, hw},
                                                {-0.3 * m.length_m, -hw}};
    for (const auto& l : local) {
      PointScatterer c;
      c.pos_m = l;
      c.omega = car_omega(rng);
      c.rcs_dbsm = static_cast<float>(total - 9.0 + rng.uniform(-3.0, 3.0));
      c.phase_rad = static_cast<float>(rng.uniform(0, 2 * kPi));
      m.centres.push_back(c);
    }
    movers_.push_back(std::move(m));
  };
  const double span = wl_len + tmax * duration_;
  const int n_on = rng.poisson(world.road.oncoming_per_km * span / 1000.0);
  for (int k = 0; k < n_on; ++k) {
    make_mover(-1, world.road.oncoming_lane_m, rng.uniform(0.0, span), rng.uniform(tmin, tmax));
  }
  if (world.road.has_same_dir_lane) {
    const int n_same = rng.poisson(world.road.same_dir_per_km * span / 1000.0);
    for (int k = 0; k < n_same; ++k) {
      make_mover(+1, world.road.same_dir_lane_m, rng.uniform(wl_len - span, wl_len),
                 rng.uniform(tmin, tmax));
    }
  }
}

double DrivePlan::distance_m() const { return state(duration_).s_m; }

ExactState DrivePlan::state(double t) const {
  t = std::clamp(t, 0.0, t_arrive_.back());
  // First grid point whose departure is after t.
  const auto it = std::upper_bound(t_depart_.begin(), t_depart_.end(), t);
  std::size_t i = static_cast<std::size_t>(it - t_depart_.begin());
  double s = 0, v = 0, a = 0;
  if (i < t_arrive_.size() && t >= t_arrive_[i]) {  // standing (dwell) at grid point i
    s = i * ds_;
  } else if (i == 0) {
    s = 0;
  } else if (i >= t_arrive_.size()) {
    s = (t_arrive_.size() - 1) * ds_;
  } else {
    // Moving between grid points i-1 and i with constant acceleration.
    const double v0 = v_[i - 1], v1 = v_[i];
    a = (v1 * v1 - v0 * v0) / (2.0 * ds_);
    const double tau = t - t_depart_[i - 1];
    s = (i - 1) * ds_ + v0 * tau + 0.5 * a * tau * tau;
    v = v0 + a * tau;
    s = std::min(s, i * ds_);
    v = std::max(0.0, v);
  }
  const PathPoint p = path_.at(s);
  ExactState out{t, s, p.x_m, p.y_m, p.yaw_rad, v, p.kappa_1pm * v, a};
  if (slip_.enabled) {
    // The rear axle follows the path (course = path tangent); the body yaws by -beta against
    // it. beta = -k a_y with a_y = kappa v^2, so d(beta)/dt = -k (kappa' v^3 + 2 kappa v a).
    constexpr double kHalfStep = 0.25;
    const double k = -side_slip_rad(slip_, 1.0);
    const double dkds =
        (path_.at(s + kHalfStep).kappa_1pm - path_.at(s - kHalfStep).kappa_1pm) / (2.0 * kHalfStep);
    const double beta = side_slip_rad(slip_, p.kappa_1pm * v * v);
    const double dbeta = -k * (dkds * v * v * v + 2.0 * p.kappa_1pm * v * a);
    out.side_slip_rad = beta;
    out.yaw_rad = wrap_angle_rad(p.yaw_rad - beta);
    out.yaw_rate_rps = p.kappa_1pm * v - dbeta;
  }
  return out;
}

// ---------------------------------------------------------------------------

GnssErrorModel::GnssErrorModel(const GnssSimConfig& cfg, double duration, std::uint64_t seed,
                               const InsRealism& ins, const SlipRealism& slip)
    : cfg_(cfg),
      rng_(seed),
      ins_(ins),
      slip_(slip),
      consumer_rng_(seed_of(seed, 0x636f6e73756dULL)) {
  if (ins.enabled) {
    Rng r(seed_of(seed, 0x696e73ULL));
    lever_x_m_ = r.normal(0.0, ins.lever_arm_sigma_m);
    lever_y_m_ = r.normal(0.0, ins.lever_arm_sigma_m);
    heading_bias_rad_ = r.normal(0.0, ins.heading_bias_sigma_deg * kDeg);
    yaw_rate_bias_rps_ = r.normal(0.0, ins.yaw_rate_bias_sigma_dps * kDeg);
    latency_s_ = r.normal(0.0, ins.latency_sigma_s);
    accel_bias_x_ = r.normal(0.0, ins.outage_accel_bias_mps2);
    accel_bias_y_ = r.normal(0.0, ins.outage_accel_bias_mps2);
  }
  if (slip.enabled) {
    Rng r(seed_of(seed, 0x776865656cULL));
    wheel_scale_ = r.normal(0.0, slip.wheel_scale_sigma);
  }
  // Stretches without fix: total share f of the drive, lengths ~U(min, max), random gaps.
  const double f = rng_.uniform(cfg.no_fix_fraction_min, cfg.no_fix_fraction_max);
  const double total = f * duration;
  std::vector<double> lens;
  double acc = 0;
  while (acc < total - 1e-9) {
    double l = rng_.uniform(cfg.no_fix_stretch_min_s, cfg.no_fix_stretch_max_s);
    l = std::min(l, total - acc);
    lens.push_back(l);
    acc += l;
  }
  const double free_time = duration - total;
  std::vector<double> gaps(lens.size() + 1);
  double gs = 0;
  for (double& g : gaps) gs += (g = rng_.exponential());
  double t = 0;
  for (std::size_t k = 0; k < lens.size(); ++k) {
    t += free_time * gaps[k] / gs;
    stretches_.emplace_back(t, t + lens[k]);
    t += lens[k];
  }
  ex_ = rng_.normal();
  ey_ = rng_.normal();
  eh_ = rng_.normal();
  cbx_ = consumer_rng_.normal();
  cby_ = consumer_rng_.normal();
  ch_ = consumer_rng_.normal();
}

bool GnssErrorModel::fixed_at(double t) const {
  for (const auto& [a, b] : stretches_) {
    if (t >= a && t < b) return false;
  }
  return true;
}

TrajectorySample GnssErrorModel::sample(const ExactState& s, const tiles::LocalFrame& frame) {
  if (last_t_ >= 0) {
    const double dt = std::max(0.0, s.time_s - last_t_);
    auto step = [&](double& e, double tau) {
      const double phi = std::exp(-dt / tau);
      e = phi * e + std::sqrt(1.0 - phi * phi) * rng_.normal();
    };
    step(ex_, cfg_.position_tau_s);
    step(ey_, cfg_.position_tau_s);
    step(eh_, cfg_.heading_tau_s);
  }
  const double dt_ins = last_t_ >= 0 ? std::max(0.0, s.time_s - last_t_) : 0.0;
  last_t_ = s.time_s;
  if (cfg_.grade == GnssGrade::Consumer) return sample_consumer(s, frame, dt_ins);
  const bool fixed = fixed_at(s.time_s);
  const double sigma = fixed ? cfg_.sigma_fixed_m : cfg_.sigma_float_m;
  const double sh = cfg_.heading_sigma_deg * kDeg;
  Eigen::Vector2d xy(s.x_m + sigma * ex_, s.y_m + sigma * ey_);
  double yaw_err_rad = sh * eh_;
  if (ins_.enabled) {
    if (fixed) {  // the filter pulls the dead-reckoning drift back after an outage
      const double k = std::exp(-dt_ins / ins_.recovery_tau_s);
      drift_x_m_ *= k;
      drift_y_m_ *= k;
      drift_vx_ *= k;
      drift_vy_ *= k;
    } else {  // accelerometer bias integrated twice
      drift_vx_ += accel_bias_x_ * dt_ins;
      drift_vy_ += accel_bias_y_ * dt_ins;
      drift_x_m_ += drift_vx_ * dt_ins;
      drift_y_m_ += drift_vy_ * dt_ins;
    }
    const double c = std::cos(s.yaw_rad), sn = std::sin(s.yaw_rad);
    xy += Eigen::Vector2d(c * lever_x_m_ - sn * lever_y_m_ + drift_x_m_,
                          sn * lever_x_m_ + c * lever_y_m_ + drift_y_m_);
    yaw_err_rad += heading_bias_rad_;
  }
  const GeoPoint g = frame.to_geo(xy);
  TrajectorySample out;
  out.time_s = s.time_s;
  out.lat_deg = g.lat_deg;
  out.lon_deg = g.lon_deg;
  out.yaw_enu_rad = wrap_angle_rad(s.yaw_rad - frame.convergence_rad({s.x_m, s.y_m}) + yaw_err_rad);
  // Recorded speed: the wheel-speed reading (slip, scale error) when slip is enabled.
  const double v_read = wheel_speed_mps(slip_, s.v_mps, s.accel_mps2, wheel_scale_);
  out.speed_mps = std::max(0.0, v_read + cfg_.speed_sigma_mps * rng_.normal());
  out.yaw_rate_rps = s.yaw_rate_rps + cfg_.yaw_rate_sigma_rps * rng_.normal();
  if (ins_.enabled) out.yaw_rate_rps += yaw_rate_bias_rps_;
  out.std_east_m = static_cast<float>(sigma);
  out.std_north_m = static_cast<float>(sigma);
  out.std_yaw_rad = static_cast<float>(sh);
  out.solution = fixed ? GnssSolution::CarrierPhaseFixed : GnssSolution::CarrierPhaseFloat;
  return out;
}

TrajectorySample GnssErrorModel::sample_consumer(const ExactState& s,
                                                 const tiles::LocalFrame& frame, double dt_s) {
  const ConsumerGnssConfig& c = cfg_.consumer;
  auto step = [&](double& e, double tau) {
    const double phi = std::exp(-dt_s / std::max(tau, 1e-6));
    e = phi * e + std::sqrt(1.0 - phi * phi) * consumer_rng_.normal();
  };
  step(cbx_, c.bias_tau_s);
  step(cby_, c.bias_tau_s);
  step(ch_, c.heading_tau_s);
  // Outages start as a Poisson process in distance; during one the solution dead-reckons
  // and drifts along a direction of its own, afterwards the filter pulls the drift back.
  const double ds_m = std::abs(s.v_mps) * dt_s;
  if (outage_left_s_ <= 0.0 && consumer_rng_.uniform() < c.outages_per_km * ds_m / 1000.0) {
    outage_left_s_ = consumer_rng_.uniform(c.outage_min_s, c.outage_max_s);
    const double a = consumer_rng_.uniform(0.0, 2.0 * std::numbers::pi);
    outage_dir_ = {std::cos(a), std::sin(a)};
  }
  if (outage_left_s_ > 0.0) {
    outage_drift_m_ += c.outage_drift_fraction * ds_m * outage_dir_;
    outage_left_s_ -= dt_s;
    consumer_outage_total_s_ += dt_s;
  } else {
    outage_drift_m_ *= std::exp(-dt_s / std::max(c.recovery_tau_s, 1e-6));
  }
  const Eigen::Vector2d p_true(s.x_m, s.y_m);
  // The receiver's error (bias and canyon multipath) reaches the trajectory through the
  // car's navigation filter, which weighs it against wheel odometry and IMU: a first-order
  // low-pass. Without it the Gauss-Markov bias would be rough at the sample rate (its
  // increments grow with the square root of time: 0.12 m within 1 s for sigma 1.5 m,
  // tau 300 s), i.e. a velocity error of ~0.1 m/s, which a fused solution does not have
  // (the low-passed bias changes at sigma / sqrt(tau * fusion_tau) = 0.03 m/s).
  Eigen::Vector2d raw = c.bias_sigma_m * Eigen::Vector2d(cbx_, cby_);
  if (multipath_) raw += multipath_->error_m(p_true, s.yaw_rad);
  if (!fused_started_) {
    fused_error_m_ = raw;  // no history before the first sample
    fused_started_ = true;
  } else {
    fused_error_m_ +=
        (1.0 - std::exp(-dt_s / std::max(c.fusion_tau_s, 1e-6))) * (raw - fused_error_m_);
  }
  Eigen::Vector2d xy = p_true + fused_error_m_ + outage_drift_m_;
  double yaw_err_rad = c.heading_sigma_deg * kDeg * ch_;
  if (ins_.enabled) yaw_err_rad += heading_bias_rad_;
  const GeoPoint g = frame.to_geo(xy);
  TrajectorySample out;
  out.time_s = s.time_s;
  out.lat_deg = g.lat_deg;
  out.lon_deg = g.lon_deg;
  out.yaw_enu_rad = wrap_angle_rad(s.yaw_rad - frame.convergence_rad(p_true) + yaw_err_rad);
  const double v_read = wheel_speed_mps(slip_, s.v_mps, s.accel_mps2, wheel_scale_);
  out.speed_mps = std::max(0.0, v_read + cfg_.speed_sigma_mps * rng_.normal());
  out.yaw_rate_rps = s.yaw_rate_rps + cfg_.yaw_rate_sigma_rps * rng_.normal();
  if (ins_.enabled) out.yaw_rate_rps += yaw_rate_bias_rps_;
  out.std_east_m = static_cast<float>(c.reported_sigma_m);
  out.std_north_m = static_cast<float>(c.reported_sigma_m);
  out.std_yaw_rad = static_cast<float>(c.heading_sigma_deg * kDeg);
  out.solution = GnssSolution::Standalone;
  return out;
}

GeoTruth to_geo_truth(const ExactState& s, const tiles::LocalFrame& frame) {
  const GeoPoint g = frame.to_geo({s.x_m, s.y_m});
  return {g.lat_deg, g.lon_deg, wrap_angle_rad(s.yaw_rad - frame.convergence_rad({s.x_m, s.y_m}))};
}

}  // namespace polmap::sim
