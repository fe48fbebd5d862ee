// Online mount calibration (mount_calibration.hpp): analytic Doppler derivatives against
// numeric ones, recovery of deliberately wrong relative mount yaws and time offsets on a
// simulated drive, and odometry drift with calibration on / off / exact mounts.
#include "polmap/radar/mount_calibration.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>

#include "polmap/radar/egomotion.hpp"
#include "polmap/radar/odometry.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/realism.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::radar {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

// ---------------------------------------------------------------- Jacobian

/// The exact (nonlinear) radial velocity of a static target: mount yaw perturbed by δψ,
/// motion taken at t + δt under constant acceleration.
double exact_vr(const Pose2& T, double az, double v, double w, double vy, double a, double alpha,
                double dpsi, double dt) {
  const double th = az + T.yaw_rad + dpsi;
  const double vv = v + a * dt, ww = w + alpha * dt;
  const double sx = vv - ww * T.y_m, sy = vy + ww * T.x_m;
  return -(sx * std::cos(th) + sy * std::sin(th));
}

TEST(MountCalibration, JacobianMatchesNumericDifferentiation) {
  const Pose2 T{3.5, -0.75, -40.0 * kDeg};
  for (double az : {-1.0, -0.3, 0.0, 0.4, 1.0}) {
    for (auto [v, w, vy, a, alpha] : {std::array<double, 5>{10.0, 0.0, 0.0, 0.0, 0.0},
                                      std::array<double, 5>{8.0, 0.3, 0.05, -2.0, 0.4},
                                      std::array<double, 5>{-2.0, -0.5, -0.1, 1.5, -0.7}}) {
      const MountDopplerJacobian j = mount_doppler_jacobian(T, az, v, w, vy, a, alpha);
      const double h = 1e-6;
      auto f = [&](double dpsi, double dt, double dv, double dw, double dvy) {
        return exact_vr(T, az, v + dv, w + dw, vy + dvy, a, alpha, dpsi, dt);
      };
      EXPECT_NEAR(j.v_r_mps, f(0, 0, 0, 0, 0), 1e-12);
      EXPECT_NEAR(j.d_yaw, (f(h, 0, 0, 0, 0) - f(-h, 0, 0, 0, 0)) / (2 * h), 1e-6);
      EXPECT_NEAR(j.d_time, (f(0, h, 0, 0, 0) - f(0, -h, 0, 0, 0)) / (2 * h), 1e-6);
      EXPECT_NEAR(j.d_v, (f(0, 0, h, 0, 0) - f(0, 0, -h, 0, 0)) / (2 * h), 1e-6);
      EXPECT_NEAR(j.d_yaw_rate, (f(0, 0, 0, h, 0) - f(0, 0, 0, -h, 0)) / (2 * h), 1e-6);
      EXPECT_NEAR(j.d_v_lat, (f(0, 0, 0, 0, h) - f(0, 0, 0, 0, -h)) / (2 * h), 1e-6);
    }
  }
}

// ---------------------------------------------------------------- simulated drives

struct Drive {
  std::vector<SensorMount> mounts;  // exact
  std::vector<SensorFrame> frames;  // detections only
  std::vector<sim::ExactState> truth;
};

Drive simulate_drive(const char* world_name) {
  sim::SimConfig cfg;
  cfg.seed = 11;
  cfg.duration_s = 65.0;
  auto world = sim::load_world(world_name, 1500.0, cfg.seed, cfg);
  sim::DriveSimulator simulator(world, cfg, 0);
  Drive out;
  out.mounts = simulator.header().sensors;
  while (auto rec = simulator.next()) {
    if (auto* f = std::get_if<SensorFrame>(&*rec)) {
      f->spectrum.cells.clear();
      out.frames.push_back(std::move(*f));
    }
  }
  out.truth = simulator.exact_trajectory();
  return out;
}

/// A 65 s urban drive of the ideal simulator (exact mounts and stamps), cached.
const Drive& urban_drive() {
  static const Drive d = simulate_drive("urban");
  return d;
}

// Deliberately wrong calibration: the vehicle believes mount yaw = true − kYawError and stamps
// frames at true time − kTimeError. Zero mean over the sensors: radar alone observes only
// relative yaws and offsets (file comment of mount_calibration.hpp).
constexpr std::array<double, 3> kYawErrorDeg{0.5, -0.7, 0.2};
constexpr std::array<double, 3> kTimeErrorS{0.004, -0.003, -0.001};

/// Odometry drift is measured after this much driving (the calibration converges first).
constexpr double kSettleS = 25.0;

struct RunResult {
  MountCalibrationResult calibration;
  double converged_after_s = -1.0;
  double heading_error_deg = 0.0;  // |odometry − truth| heading at the end
  double position_error_m = 0.0;   // end point, odometry aligned with truth at its start
  double distance_m = 0.0;
};

sim::ExactState truth_at(const std::vector<sim::ExactState>& tr, double t) {
  auto it = std::lower_bound(tr.begin(), tr.end(), t,
                             [](const sim::ExactState& s, double x) { return s.time_s < x; });
  if (it == tr.begin()) return *it;
  if (it == tr.end()) return tr.back();
  const auto& a = *(it - 1);
  const auto& b = *it;
  const double u = (t - a.time_s) / (b.time_s - a.time_s);
  sim::ExactState s = a;
  s.x_m += u * (b.x_m - a.x_m);
  s.y_m += u * (b.y_m - a.y_m);
  s.yaw_rad += u * wrap_angle_rad(b.yaw_rad - a.yaw_rad);
  return s;
}

RunResult run(const Drive& d, bool wrong, bool calibrate, double common_yaw_error_deg = 0.0,
              bool estimate_common_yaw = false, double slip_gradient_rad_per_mps2 = 0.0,
              bool calibrator_models_slip = true) {
  std::vector<SensorMount> mounts = d.mounts;
  for (std::size_t i = 0; i < mounts.size(); ++i) {
    mounts[i].T_vehicle_sensor.yaw_rad -=
        ((wrong ? kYawErrorDeg[i] : 0.0) + common_yaw_error_deg) * kDeg;
  }
  EgoMotionConfig ecfg;
  ecfg.side_slip_gradient_rad_per_mps2 = slip_gradient_rad_per_mps2;
  EgoMotionEstimator estimator(mounts, ecfg);
  MountCalibrationConfig ccfg;
  ccfg.side_slip_gradient_rad_per_mps2 = calibrator_models_slip ? slip_gradient_rad_per_mps2 : 0.0;
  ccfg.calibrate_mounts = calibrate;
  ccfg.estimate_common_yaw = estimate_common_yaw;
  ccfg.vr_sigma_mps = ecfg.vr_sigma_mps;
  ccfg.azimuth_sigma_rad = ecfg.azimuth_sigma_rad;
  MountCalibrator calibrator(mounts, ccfg);
  Odometry odometry;
  RunResult r;
  double t_first = -1.0, t_first_ok = -1.0, t_last_ok = 0.0;
  for (SensorFrame f : d.frames) {
    std::size_t idx = 0;
    for (std::size_t i = 0; i < mounts.size(); ++i)
      idx = mounts[i].sensor_id == f.sensor_id ? i : idx;
    if (wrong) f.time_s -= kTimeErrorS[idx];
    if (t_first < 0) t_first = f.time_s;
    const MotionEstimate e = estimator.process(f);
    calibrator.add_frame(f);
    if (calibrator.add_estimate(e)) {
      const MountCalibrationResult c = calibrator.result();
      if (r.converged_after_s < 0 && c.status == MountCalibrationResult::Status::Converged) {
        r.converged_after_s = e.time_s - t_first;
      }
      if (calibrate) apply_mount_calibration(estimator, c);
    }
    odometry.add(e);
    if (e.status == MotionEstimate::Status::Ok) {
      if (t_first_ok < 0) t_first_ok = e.time_s;
      t_last_ok = e.time_s;
    }
  }
  r.calibration = calibrator.result();
  // End-point error of the odometry over the part of the drive after the first
  // kSettleS (the calibration has converged by then), aligned with the truth at its start.
  const double ta = t_first_ok + kSettleS, tb = t_last_ok;
  const sim::ExactState s0 = truth_at(d.truth, ta), s1 = truth_at(d.truth, tb);
  const Pose2 T_w0{s0.x_m, s0.y_m, s0.yaw_rad}, T_w1{s1.x_m, s1.y_m, s1.yaw_rad};
  const Pose2 rel_true = T_w0.inverse() * T_w1;
  const Pose2 rel_odo = odometry.T_odom_vehicle(ta).inverse() * odometry.T_odom_vehicle(tb);
  r.position_error_m = std::hypot(rel_true.x_m - rel_odo.x_m, rel_true.y_m - rel_odo.y_m);
  r.heading_error_deg = std::abs(wrap_angle_rad(rel_true.yaw_rad - rel_odo.yaw_rad)) / kDeg;
  for (std::size_t k = 1; k < d.truth.size(); ++k) {
    if (d.truth[k].time_s < ta || d.truth[k].time_s > tb) continue;
    r.distance_m +=
        std::hypot(d.truth[k].x_m - d.truth[k - 1].x_m, d.truth[k].y_m - d.truth[k - 1].y_m);
  }
  return r;
}

void print(const char* name, const RunResult& r) {
  std::printf(
      "%-22s end-point %.3f m over %.0f m (%.2f %%), heading %.3f deg, converged %s\n", name,
      r.position_error_m, r.distance_m, 100.0 * r.position_error_m / r.distance_m,
      r.heading_error_deg,
      r.converged_after_s >= 0 ? (std::to_string(r.converged_after_s) + " s").c_str() : "never");
  for (const auto& s : r.calibration.sensors) {
    std::printf("  sensor %d: yaw %+.4f +- %.4f deg, time %+.3f +- %.3f ms\n", s.sensor_id,
                s.yaw_offset_rad / kDeg, s.yaw_sigma_rad / kDeg, s.time_offset_s * 1e3,
                s.time_sigma_s * 1e3);
  }
}

TEST(MountCalibration, RecoversWrongRelativeMountYawsAndTimeOffsets) {
  const Drive& d = urban_drive();
  ASSERT_EQ(d.mounts.size(), 3u);
  const RunResult r = run(d, /*wrong=*/true, /*calibrate=*/true);
  print("wrong, calibration on", r);
  EXPECT_GE(r.calibration.observed_s, 30.0);
  EXPECT_EQ(r.calibration.status, MountCalibrationResult::Status::Converged);
  for (std::size_t i = 0; i < 3; ++i) {
    const auto& s = r.calibration.sensors[i];
    // Targets of issue 15: relative mount yaw within 0.1°, time offsets within 1 ms.
    EXPECT_NEAR(s.yaw_offset_rad / kDeg, kYawErrorDeg[i], 0.1) << "sensor " << i;
    EXPECT_NEAR(s.time_offset_s, kTimeErrorS[i], 0.001) << "sensor " << i;
    // The reported σ is honest: the error is within 4σ (+ a floor for the linearization).
    EXPECT_LT(std::abs(s.yaw_offset_rad / kDeg - kYawErrorDeg[i]),
              4.0 * s.yaw_sigma_rad / kDeg + 0.01);
    EXPECT_GT(s.yaw_sigma_rad, 0.0);
  }
}

TEST(MountCalibration, ExactMountsStayAtZeroAndOdometryRecovers) {
  const Drive& d = urban_drive();
  const RunResult exact_off = run(d, false, false);
  const RunResult exact_on = run(d, false, true);
  const RunResult wrong_off = run(d, true, false);
  const RunResult wrong_on = run(d, true, true);
  print("exact, calibration off", exact_off);
  print("exact, calibration on", exact_on);
  print("wrong, calibration off", wrong_off);
  print("wrong, calibration on", wrong_on);
  // With exact mounts the estimates are zero within their noise, and applying them does
  // not degrade the odometry measurably.
  for (const auto& s : exact_on.calibration.sensors) {
    EXPECT_LT(std::abs(s.yaw_offset_rad / kDeg), 0.03);
    EXPECT_LT(std::abs(s.time_offset_s), 3.0 * s.time_sigma_s + 0.0002);
  }
  EXPECT_LT(exact_on.position_error_m, exact_off.position_error_m + 0.002 * exact_off.distance_m);
  // Wrong mounts without calibration drift clearly more; with calibration (converged before
  // kSettleS) the drift is that of exact mounts.
  EXPECT_GT(wrong_off.position_error_m, 3.0 * wrong_on.position_error_m);
  EXPECT_LT(wrong_on.position_error_m, exact_off.position_error_m + 0.002 * exact_off.distance_m);
  EXPECT_LT(wrong_on.heading_error_deg, exact_off.heading_error_deg + 0.1);
}

// A common yaw of all mounts is not in the relative calibration (it looks like side slip);
// with estimate_common_yaw it is recovered from the straight-driving blocks under their
// zero-side-slip assumption (exact in the ideal simulator).
TEST(MountCalibration, CommonYawOnlyUnderZeroSlipAssumption) {
  const Drive& d = urban_drive();
  const double common_deg = 0.3;
  const RunResult exact = run(d, false, false);
  const RunResult relative = run(d, true, true, common_deg, false);
  const RunResult absolute = run(d, true, true, common_deg, true);
  print("common 0.3, relative", relative);
  print("common 0.3, absolute", absolute);
  double mean_rel = 0.0;
  for (std::size_t i = 0; i < 3; ++i) {
    const auto& rs = relative.calibration.sensors[i];
    const auto& as = absolute.calibration.sensors[i];
    mean_rel += rs.yaw_offset_rad / kDeg / 3.0;
    EXPECT_NEAR(rs.yaw_offset_rad / kDeg, kYawErrorDeg[i], 0.1);  // relative part only
    EXPECT_NEAR(as.yaw_offset_rad / kDeg, kYawErrorDeg[i] + common_deg, 0.1);
  }
  EXPECT_NEAR(mean_rel, 0.0, 1e-6);  // gauge
  // Relative calibration leaves the common yaw's heading drift; the absolute one removes it.
  EXPECT_GT(relative.position_error_m, 3.0 * absolute.position_error_m);
  // The common yaw acts through the 3.5 m lever of the sensors: 0.01° of common error is a
  // yaw-rate bias of 0.03 °/s at 10 m/s, so the absolute drift stays above the exact one.
  EXPECT_LT(absolute.position_error_m, 0.01 * exact.distance_m);
  // The common yaw does not disturb the relative time offsets (it is a parameter, not
  // forced into the yaw-rate nuisance of the straight blocks).
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_NEAR(relative.calibration.sensors[i].time_offset_s, kTimeErrorS[i], 0.001);
  }
  EXPECT_NEAR(relative.calibration.common_yaw_rad / kDeg, common_deg, 0.1);
}

// Exact mounts: the common yaw estimate is noise around zero and is not applied (only the
// relative part, whose mean is zero by its gauge); a real common error of 0.3° is applied.
TEST(MountCalibration, CommonYawIsAppliedOnlyWhenItStandsOutOfItsNoise) {
  const Drive& d = urban_drive();
  const RunResult exact = run(d, false, true, 0.0, true);
  const auto& c = exact.calibration;
  ASSERT_GT(c.common_yaw_sigma_rad, 0.0);
  EXPECT_LT(std::abs(c.common_yaw_rad), 3.0 * c.common_yaw_sigma_rad);
  double mean = 0.0;
  for (const auto& s : c.sensors) mean += s.yaw_offset_rad / static_cast<double>(c.sensors.size());
  EXPECT_NEAR(mean, 0.0, 1e-9);
  const RunResult wrong = run(d, false, true, 0.3, true);
  double mean_wrong = 0.0;
  for (const auto& s : wrong.calibration.sensors) {
    mean_wrong += s.yaw_offset_rad / static_cast<double>(wrong.calibration.sensors.size());
  }
  EXPECT_NEAR(mean_wrong / kDeg, 0.3, 0.1);
}

// With side slip, the blocks below side_slip_min_lateral_accel_mps2 still carry slip of one
// sign through a long gentle curve; under a zero-slip assumption the common yaw absorbs it,
// and at rural speeds a few hundredths of a degree of common yaw are a yaw-rate bias of a
// tenth of a degree per second. Linearized at the slip the vehicle model predicts, they do
// not bias it. Synthetic drive against a reference: 60 s at 18 m/s with a_y = 0.4 m/s²
// (slip 0.09° with the simulator's gradient), exact motion estimates, a common yaw of 0.3°.
TEST(MountCalibration, CommonYawIsNotBiasedByTheSlipOfGentleCurves) {
  const std::vector<SensorMount> mounts = default_front_mounts();
  const double k = sim::SlipRealism{}.side_slip_gradient_deg_per_mps2 * kDeg;  // rad per m/s²
  const double v = 18.0, w = 0.4 / v, common = 0.3 * kDeg;
  const double v_lat = -k * v * v * w;
  auto estimate = [&](double gradient) {
    MountCalibrationConfig cfg;
    cfg.estimate_common_yaw = true;
    cfg.side_slip_gradient_rad_per_mps2 = gradient;
    MountCalibrator calibrator(mounts, cfg);
    std::mt19937_64 rng(5);
    std::normal_distribution<double> noise(0.0, 0.05);
    std::uniform_real_distribution<double> azimuth(-1.0, 1.0);
    for (int cycle = 0; cycle < 600; ++cycle) {
      for (const SensorMount& m : mounts) {
        SensorFrame f;
        f.sensor_id = m.sensor_id;
        f.time_s = 0.1 * cycle + m.trigger_offset_s;
        const double x = m.T_vehicle_sensor.x_m, y = m.T_vehicle_sensor.y_m;
        for (int i = 0; i < 40; ++i) {
          const double phi = azimuth(rng);  // measured, relative to the TRUE mount
          const double th = m.T_vehicle_sensor.yaw_rad + common + phi;
          Detection d;
          d.azimuth_rad = static_cast<float>(phi);
          d.radial_velocity_mps = static_cast<float>(
              -((v - w * y) * std::cos(th) + (v_lat + w * x) * std::sin(th)) + noise(rng));
          f.detections.push_back(d);
        }
        calibrator.add_frame(f);
        MotionEstimate e;
        e.status = MotionEstimate::Status::Ok;
        e.time_s = f.time_s;
        e.v_mps = v;
        e.yaw_rate_rps = w;
        calibrator.add_estimate(e);
      }
    }
    return calibrator.result();
  };
  const MountCalibrationResult modelled = estimate(k);
  const MountCalibrationResult zero_slip = estimate(0.0);
  const double err_modelled = std::abs(modelled.common_yaw_rad - common) / kDeg;
  const double err_zero = std::abs(zero_slip.common_yaw_rad - common) / kDeg;
  std::printf("common yaw error: modelled %.4f deg (sigma %.4f), zero-slip %.4f deg\n",
              err_modelled, modelled.common_yaw_sigma_rad / kDeg, err_zero);
  // The zero-slip estimate carries the slip angle (β = atan(v_lat / v) = 0.09°), the
  // modelled one is within its noise.
  EXPECT_NEAR(err_zero, std::abs(std::atan(v_lat / v)) / kDeg, 0.02);
  EXPECT_LT(err_modelled, 3.0 * modelled.common_yaw_sigma_rad / kDeg + 0.003);
  EXPECT_LT(err_modelled, 0.25 * err_zero);
}

}  // namespace
}  // namespace polmap::radar
