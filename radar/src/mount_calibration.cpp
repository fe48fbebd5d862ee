#include "polmap/radar/mount_calibration.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {

const char* to_string(MountCalibrationResult::Status s) {
  switch (s) {
    case MountCalibrationResult::Status::NotObservableYet:
      return "not_observable_yet";
    case MountCalibrationResult::Status::Converged:
      return "converged";
  }
  return "unknown";
}

MountDopplerJacobian mount_doppler_jacobian(const Pose2& T_vehicle_sensor, double azimuth_rad,
                                            double v_mps, double yaw_rate_rps, double v_lat_mps,
                                            double accel_mps2, double yaw_accel_rps2) {
  const double x = T_vehicle_sensor.x_m, y = T_vehicle_sensor.y_m;
  const double th = azimuth_rad + T_vehicle_sensor.yaw_rad;
  const double c = std::cos(th), s = std::sin(th);
  // Sensor velocity (v − ω·y, v_y + ω·x); v_r = −v_s·u(θ).
  const double h0 = -c, h1 = y * c - x * s, hy = -s;
  const double g0 = s, g1 = -y * s - x * c, gy = -c;  // ∂h/∂θ
  MountDopplerJacobian j;
  j.v_r_mps = h0 * v_mps + h1 * yaw_rate_rps + hy * v_lat_mps;
  j.d_yaw = g0 * v_mps + g1 * yaw_rate_rps + gy * v_lat_mps;
  j.d_time = h0 * accel_mps2 + h1 * yaw_accel_rps2;  // lateral velocity held constant
  j.d_v = h0;
  j.d_yaw_rate = h1;
  j.d_v_lat = hy;
  return j;
}

MountCalibrator::MountCalibrator(std::vector<SensorMount> mounts, MountCalibrationConfig cfg)
    : mounts_(std::move(mounts)), cfg_(cfg) {
  POLMAP_EXPECT(!mounts_.empty());
  POLMAP_EXPECT(cfg_.block_window_s > 0 && cfg_.motion_fit_half_window_s > 0);
  POLMAP_EXPECT(cfg_.vr_sigma_mps > 0 && cfg_.prior_yaw_sigma_rad > 0 &&
                cfg_.prior_time_offset_sigma_s > 0);
  const auto n = static_cast<Eigen::Index>(2 * mounts_.size());
  info_ = Eigen::MatrixXd::Zero(n, n);
  rhs_ = Eigen::VectorXd::Zero(n);
  theta_ = Eigen::VectorXd::Zero(n);
  detections_.assign(mounts_.size(), 0);
}

void MountCalibrator::add_frame(const SensorFrame& frame) {
  std::size_t idx = mounts_.size();
  for (std::size_t i = 0; i < mounts_.size(); ++i) {
    if (mounts_[i].sensor_id == frame.sensor_id) idx = i;
  }
  if (idx == mounts_.size()) return;
  frames_.push_back(Frame{idx, frame.time_s, frame.detections});
  // Without estimates (outage) frames would pile up: keep a few seconds.
  while (frames_.front().stamp_s < frame.time_s - 5.0) frames_.pop_front();
}

bool MountCalibrator::add_estimate(const MotionEstimate& e) {
  if (e.status != MotionEstimate::Status::Ok) return false;
  motions_.push_back({e.time_s, e.v_mps, e.yaw_rate_rps});
  bool changed = false;
  const double H = cfg_.motion_fit_half_window_s;
  while (!frames_.empty()) {
    const double t0 = frames_.front().stamp_s;
    const double t_end = t0 + cfg_.block_window_s;
    if (motions_.back().time_s < t_end + H) break;  // fit window not complete yet
    std::size_t n = 0;
    while (n < frames_.size() && frames_[n].stamp_s < t_end - 1e-6) ++n;
    const int before = blocks_;
    process_block(n);
    changed = changed || blocks_ != before;
    frames_.erase(frames_.begin(), frames_.begin() + static_cast<std::ptrdiff_t>(n));
    while (!motions_.empty() && motions_.front().time_s < t_end - H) motions_.pop_front();
  }
  return changed;
}

void MountCalibrator::process_block(std::size_t n_frames) {
  const auto S = static_cast<Eigen::Index>(mounts_.size());
  const double H = cfg_.motion_fit_half_window_s;
  if (n_frames == 0) return;
  const double t0 = frames_.front().stamp_s;
  double tc = 0.0;
  for (std::size_t k = 0; k < n_frames; ++k) tc += frames_[k].stamp_s;
  tc /= static_cast<double>(n_frames);

  // Line fit of the estimates around the block: motion at tc and its rate.
  int n = 0;
  double st = 0, sv = 0, sw = 0, t_lo = 1e300, t_hi = -1e300;
  for (const Motion& m : motions_) {
    if (m.time_s < t0 - H || m.time_s > t0 + cfg_.block_window_s + H) continue;
    ++n, st += m.time_s - tc, sv += m.v_mps, sw += m.yaw_rate_rps;
    t_lo = std::min(t_lo, m.time_s), t_hi = std::max(t_hi, m.time_s);
  }
  if (n < cfg_.motion_fit_min_estimates || t_hi - t_lo < H) return;
  const double tm = st / n, vm = sv / n, wm = sw / n;
  double stt = 0, stv = 0, stw = 0;
  for (const Motion& m : motions_) {
    if (m.time_s < t0 - H || m.time_s > t0 + cfg_.block_window_s + H) continue;
    const double dt = m.time_s - tc - tm;
    stt += dt * dt, stv += dt * (m.v_mps - vm), stw += dt * (m.yaw_rate_rps - wm);
  }
  const double a = stv / stt, alpha = stw / stt;
  const double v_c = vm - a * tm, w_c = wm - alpha * tm;
  if (v_c < cfg_.min_speed_mps) return;

  // Rows of the block: residual r = v_r − h·m̂(t), nuisance columns A, parameter columns B.
  const int p =
      cfg_.side_slip_nuisance && std::abs(v_c * w_c) >= cfg_.side_slip_min_lateral_accel_mps2 ? 3
                                                                                              : 2;
  std::vector<double> r, w, az;
  std::vector<std::array<double, 3>> A;
  std::vector<std::pair<double, double>> B;  // (∂/∂δψ_s, ∂/∂δt_s)
  std::vector<Eigen::Index> sensor;
  const double s_vr2 = cfg_.vr_sigma_mps * cfg_.vr_sigma_mps;
  const double s_az2 = cfg_.azimuth_sigma_rad * cfg_.azimuth_sigma_rad;
  for (std::size_t k = 0; k < n_frames; ++k) {
    const Frame& f = frames_[k];
    const SensorMount& mount = mounts_[f.sensor];
    const double dt = f.stamp_s - tc;
    const double v = v_c + a * dt, om = w_c + alpha * dt;
    const double vua = mount.spec.v_unambiguous_mps;
    // Side slip the vehicle model predicts (zero with a zero gradient); the block nuisance
    // takes what it does not explain in curves.
    const double v_lat = -cfg_.side_slip_gradient_rad_per_mps2 * v * v * om;
    for (const Detection& d : f.detections) {
      const MountDopplerJacobian j = mount_doppler_jacobian(
          mount.T_vehicle_sensor, static_cast<double>(d.azimuth_rad), v, om, v_lat, a, alpha);
      double vr = d.radial_velocity_mps;
      if (vua > 0) vr += 2.0 * vua * std::round((j.v_r_mps - vr) / (2.0 * vua));
      r.push_back(vr - j.v_r_mps);
      w.push_back(1.0 / (s_vr2 + s_az2 * j.d_yaw * j.d_yaw));
      A.push_back({j.d_v, j.d_yaw_rate, j.d_v_lat});
      B.emplace_back(j.d_yaw, j.d_time);
      sensor.push_back(static_cast<Eigen::Index>(f.sensor));
    }
  }
  const std::size_t N = r.size();
  if (N < 2 * static_cast<std::size_t>(cfg_.min_detections_per_sensor)) return;

  // Residuals under the current calibration; gate iteratively around the block nuisance.
  std::vector<double> rc(N);
  for (std::size_t i = 0; i < N; ++i) {
    rc[i] = r[i] - B[i].first * theta_(sensor[i]) - B[i].second * theta_(S + sensor[i]);
  }
  std::vector<char> use(N);
  for (std::size_t i = 0; i < N; ++i) use[i] = std::abs(rc[i]) < 1.0;
  Eigen::Vector3d delta = Eigen::Vector3d::Zero();
  for (int round = 0; round < 3; ++round) {
    Eigen::Matrix3d Naa = Eigen::Matrix3d::Zero();
    Eigen::Vector3d ba = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < N; ++i) {
      if (!use[i]) continue;
      const Eigen::Vector3d ai(A[i][0], A[i][1], A[i][2]);
      Naa += w[i] * ai * ai.transpose();
      ba += w[i] * ai * rc[i];
    }
    Eigen::Matrix3d Nr = Naa;
    if (p == 2) Nr(2, 2) = 1.0, Nr(0, 2) = Nr(2, 0) = Nr(1, 2) = Nr(2, 1) = ba(2) = 0.0;
    delta = Nr.ldlt().solve(ba);
    for (std::size_t i = 0; i < N; ++i) {
      const double e = rc[i] - (A[i][0] * delta(0) + A[i][1] * delta(1) + A[i][2] * delta(2));
      const double gate = std::max(cfg_.gate_sigmas / std::sqrt(w[i]), cfg_.gate_min_mps);
      use[i] = std::abs(e) < gate;
    }
  }
  std::vector<int> per_sensor(mounts_.size(), 0);
  for (std::size_t i = 0; i < N; ++i) per_sensor[static_cast<std::size_t>(sensor[i])] += use[i];
  int sensors_used = 0;
  for (std::size_t s = 0; s < mounts_.size(); ++s) {
    if (per_sensor[s] >= cfg_.min_detections_per_sensor) ++sensors_used;
  }
  if (sensors_used < 2) return;  // one sensor alone: its yaw is absorbed by the nuisance

  // Normal equations of the block, nuisance eliminated (Schur complement).
  const Eigen::Index P = 2 * S;
  Eigen::MatrixXd Naa = Eigen::MatrixXd::Zero(p, p), Nab = Eigen::MatrixXd::Zero(p, P);
  Eigen::MatrixXd Nbb = Eigen::MatrixXd::Zero(P, P);
  Eigen::VectorXd ba = Eigen::VectorXd::Zero(p), bb = Eigen::VectorXd::Zero(P);
  double rwr = 0.0;
  long long used = 0;
  for (std::size_t i = 0; i < N; ++i) {
    const auto s = static_cast<std::size_t>(sensor[i]);
    if (!use[i] || per_sensor[s] < cfg_.min_detections_per_sensor) continue;
    const Eigen::Index ys = sensor[i], ts = S + sensor[i];
    const double wi = w[i];
    const double b1 = B[i].first, b2 = B[i].second;
    for (int q = 0; q < p; ++q) {
      for (int u = 0; u < p; ++u) Naa(q, u) += wi * A[i][q] * A[i][u];
      Nab(q, ys) += wi * A[i][q] * b1;
      Nab(q, ts) += wi * A[i][q] * b2;
      ba(q) += wi * A[i][q] * r[i];
    }
    Nbb(ys, ys) += wi * b1 * b1;
    Nbb(ys, ts) += wi * b1 * b2;
    Nbb(ts, ys) += wi * b1 * b2;
    Nbb(ts, ts) += wi * b2 * b2;
    bb(ys) += wi * b1 * r[i];
    bb(ts) += wi * b2 * r[i];
    rwr += wi * r[i] * r[i];
    ++used;
    ++detections_[s];
  }
  const Eigen::LDLT<Eigen::MatrixXd> naa(Naa);
  info_ += Nbb - Nab.transpose() * naa.solve(Nab);
  rhs_ += bb - Nab.transpose() * naa.solve(ba);
  chi2_const_ += rwr - ba.dot(naa.solve(ba));
  observations_ += used;
  nuisance_ += p;
  observed_s_ += cfg_.block_window_s;
  ++blocks_;
  theta_ = solve(nullptr);
}

Eigen::VectorXd MountCalibrator::solve(Eigen::MatrixXd* covariance) const {
  const auto S = static_cast<Eigen::Index>(mounts_.size());
  const Eigen::Index P = 2 * S;
  Eigen::MatrixXd L = info_;
  for (Eigen::Index s = 0; s < S; ++s) {
    L(s, s) += 1.0 / (cfg_.prior_yaw_sigma_rad * cfg_.prior_yaw_sigma_rad);
    L(S + s, S + s) += 1.0 / (cfg_.prior_time_offset_sigma_s * cfg_.prior_time_offset_sigma_s);
  }
  // Gauge: mean time offset = 0. The common yaw is always a parameter here (observed by the
  // zero-slip blocks; without it, a common yaw or a constant slip angle in those blocks would
  // be forced into the yaw-rate nuisance and from there into the left/right time offsets);
  // result() reports and applies only the relative part unless estimate_common_yaw (and the
  // common part stands out of its noise by common_yaw_min_sigmas). Without
  // any zero-slip block it is held by its prior alone. Solve in the null space Q of the
  // constraints: θ = Q z.
  const Eigen::Index k = 1;
  Eigen::MatrixXd C = Eigen::MatrixXd::Zero(k, P);
  for (Eigen::Index s = 0; s < S; ++s) {
    C(0, S + s) = 1.0;
  }
  // Null space of C: the last P − k columns of the full Q of Cᵀ's QR decomposition. (A
  // JacobiSVD of the wide 1 × P matrix with ComputeFullV wrote past its buffer under ASan
  // with one or two sensors, Eigen 3.4.0.)
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(C.transpose());
  const Eigen::MatrixXd Q_full = qr.householderQ() * Eigen::MatrixXd::Identity(P, P);
  const Eigen::MatrixXd Q = Q_full.rightCols(P - k);
  const Eigen::MatrixXd Lz = Q.transpose() * L * Q;
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(Lz);
  const Eigen::VectorXd theta = Q * ldlt.solve(Q.transpose() * rhs_);
  if (covariance) {
    const Eigen::MatrixXd Lz_inv = ldlt.solve(Eigen::MatrixXd::Identity(P - k, P - k));
    *covariance = Q * Lz_inv * Q.transpose();
  }
  return theta;
}

MountCalibrationResult MountCalibrator::result() const {
  MountCalibrationResult res;
  const auto S = static_cast<Eigen::Index>(mounts_.size());
  Eigen::MatrixXd cov;
  const Eigen::VectorXd theta = solve(&cov);
  // Residual variance factor of the accumulated fit (1 if the noise model holds).
  const long long dof = observations_ - nuisance_ - 2 * S;
  double s2 = 1.0;
  if (dof > 0) s2 = std::max((chi2_const_ - rhs_.dot(theta)) / static_cast<double>(dof), 1e-6);
  cov *= s2;
  // The common yaw (mean over the sensors) and, unless it is to be estimated, its removal.
  Eigen::VectorXd theta_out = theta;
  Eigen::RowVectorXd mean_row = Eigen::RowVectorXd::Zero(2 * S);
  mean_row.head(S).setConstant(1.0 / static_cast<double>(S));
  res.common_yaw_rad = mean_row.dot(theta);
  res.common_yaw_sigma_rad = std::sqrt(std::max((mean_row * cov * mean_row.transpose())(0), 0.0));
  const bool significant =
      std::abs(res.common_yaw_rad) >= cfg_.common_yaw_min_sigmas * res.common_yaw_sigma_rad;
  const bool relative = cfg_.side_slip_nuisance && (!cfg_.estimate_common_yaw || !significant);
  res.common_yaw_applied = !relative;
  res.common_yaw_applies_early = res.common_yaw_applied &&
                                 std::abs(res.common_yaw_rad) >= cfg_.common_yaw_early_min_rad &&
                                 res.common_yaw_sigma_rad <= cfg_.common_yaw_early_sigma_rad &&
                                 observed_s_ >= cfg_.common_yaw_early_min_observed_s;
  if (relative) {
    Eigen::MatrixXd J = Eigen::MatrixXd::Identity(2 * S, 2 * S);
    J.topLeftCorner(S, S).array() -= 1.0 / static_cast<double>(S);
    theta_out = J * theta;
    cov = J * cov * J.transpose();
  }
  res.covariance = cov;
  res.residual_sigma_factor = std::sqrt(s2);
  res.observed_s = observed_s_;
  res.blocks = blocks_;
  const bool long_enough = observed_s_ >= cfg_.min_observed_s;
  bool all = true;
  for (Eigen::Index s = 0; s < S; ++s) {
    MountCalibrationResult::Sensor e;
    e.sensor_id = mounts_[static_cast<std::size_t>(s)].sensor_id;
    e.yaw_offset_rad = theta_out(s);
    e.yaw_sigma_rad = std::sqrt(std::max(cov(s, s), 0.0));
    e.time_offset_s = theta(S + s);
    e.time_sigma_s = std::sqrt(std::max(cov(S + s, S + s), 0.0));
    e.detections = detections_[static_cast<std::size_t>(s)];
    e.yaw_status = long_enough && e.yaw_sigma_rad <= cfg_.converged_yaw_sigma_rad
                       ? MountCalibrationResult::Status::Converged
                       : MountCalibrationResult::Status::NotObservableYet;
    e.time_status = long_enough && e.time_sigma_s <= cfg_.converged_time_offset_sigma_s
                        ? MountCalibrationResult::Status::Converged
                        : MountCalibrationResult::Status::NotObservableYet;
    all = all && e.yaw_status == MountCalibrationResult::Status::Converged &&
          e.time_status == MountCalibrationResult::Status::Converged;
    res.sensors.push_back(e);
  }
  res.status = all ? MountCalibrationResult::Status::Converged
                   : MountCalibrationResult::Status::NotObservableYet;
  return res;
}

void apply_mount_calibration(EgoMotionEstimator& estimator, const MountCalibrationResult& result) {
  const auto& mounts = estimator.mounts();
  std::vector<double> yaw(mounts.size(), 0.0), dt(mounts.size(), 0.0);
  for (std::size_t i = 0; i < mounts.size(); ++i) {
    for (const auto& s : result.sensors) {
      if (s.sensor_id != mounts[i].sensor_id) continue;
      if (s.yaw_status == MountCalibrationResult::Status::Converged) {
        yaw[i] = s.yaw_offset_rad;
      } else if (result.common_yaw_applies_early) {
        yaw[i] = result.common_yaw_rad;
      }
      if (s.time_status == MountCalibrationResult::Status::Converged) dt[i] = s.time_offset_s;
    }
  }
  estimator.set_mount_corrections(std::move(yaw), std::move(dt));
}

}  // namespace polmap::radar
