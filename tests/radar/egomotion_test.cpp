// Radar ego-motion: synthetic detections from known (v, ω) for the three default
// front mounts, with moving targets, aliasing, noise, sequential triggering.
#include "polmap/radar/egomotion.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <numbers>
#include <random>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

double wrap_velocity(double v, double v_ua) {
  return v - 2.0 * v_ua * std::floor((v + v_ua) / (2.0 * v_ua));
}

/// Radial velocity of a static target for motion (v, ω) seen by `m` at azimuth phi.
double static_vr(const SensorMount& m, double phi, double v, double w) {
  const double th = phi + m.T_vehicle_sensor.yaw_rad;
  const double vsx = v - w * m.T_vehicle_sensor.y_m, vsy = w * m.T_vehicle_sensor.x_m;
  return -(vsx * std::cos(th) + vsy * std::sin(th));
}

struct SynthSpec {
  int n_static = 70;
  int n_moving = 30;  // 30 % outliers
  double sigma_vr = 0.05;
  double sigma_az = 0.0;
};

/// One sensor frame: static targets (radial velocity from the motion model with
/// noise, then aliased) and moving targets (random extra velocity up to ±8 m/s).
SensorFrame make_frame(const SensorMount& m, double t, double v, double w, const SynthSpec& spec,
                       std::mt19937& rng) {
  std::uniform_real_distribution<double> az(-60.0 * kDeg, 60.0 * kDeg);
  std::uniform_real_distribution<double> rng_r(2.0, 70.0);
  std::uniform_real_distribution<double> extra(0.7, 8.0);
  std::bernoulli_distribution sign(0.5);
  std::normal_distribution<double> nv(0.0, spec.sigma_vr), na(0.0, spec.sigma_az);
  SensorFrame f;
  f.sensor_id = m.sensor_id;
  f.time_s = t;
  const double vua = m.spec.v_unambiguous_mps;
  for (int i = 0; i < spec.n_static + spec.n_moving; ++i) {
    const double phi = az(rng);
    double vr = static_vr(m, phi, v, w) + nv(rng);
    if (i >= spec.n_static) vr += sign(rng) ? extra(rng) : -extra(rng);
    Detection d;
    d.range_m = static_cast<float>(rng_r(rng));
    d.azimuth_rad = static_cast<float>(phi + (spec.sigma_az > 0 ? na(rng) : 0.0));
    d.radial_velocity_mps = static_cast<float>(wrap_velocity(vr, vua));
    d.snr_db = 20.0F;
    f.detections.push_back(d);
  }
  return f;
}

/// Feeds one full cycle (three sensors, offsets 0/33/66 ms) at constant motion
/// and returns the estimate of the last frame.
MotionEstimate run_cycle(EgoMotionEstimator& est, double t0, double v, double w,
                         const SynthSpec& spec, std::mt19937& rng) {
  MotionEstimate last;
  for (const SensorMount& m : est.mounts()) {
    last = est.process(make_frame(m, t0 + m.trigger_offset_s, v, w, spec, rng));
  }
  return last;
}

struct Motion {
  double v_mps;
  double yaw_rate_rps;
};

class EgoMotionAliasing : public ::testing::TestWithParam<Motion> {};

TEST_P(EgoMotionAliasing, RecoversMotionWithOutliersBeyondUnambiguousRange) {
  const Motion truth = GetParam();
  std::mt19937 rng(42);
  EgoMotionEstimator est(default_front_mounts());
  const SynthSpec spec;  // 30 % moving targets, σ_vr = 0.05 m/s
  // First frame alone (no prior, one sensor) must already be right.
  const MotionEstimate first =
      est.process(make_frame(est.mounts()[0], 0.0, truth.v_mps, truth.yaw_rate_rps, spec, rng));
  ASSERT_EQ(first.status, MotionEstimate::Status::Ok);
  EXPECT_NEAR(first.v_mps, truth.v_mps, 0.05);
  EXPECT_NEAR(first.yaw_rate_rps, truth.yaw_rate_rps, 0.03);
  for (int cycle = 0; cycle < 3; ++cycle) {
    const MotionEstimate e =
        run_cycle(est, 0.1 * (cycle + 1), truth.v_mps, truth.yaw_rate_rps, spec, rng);
    ASSERT_EQ(e.status, MotionEstimate::Status::Ok) << "v = " << truth.v_mps;
    EXPECT_EQ(e.num_frames, 3);
    EXPECT_EQ(e.num_detections, 300);
    EXPECT_NEAR(e.v_mps, truth.v_mps, 0.03);
    EXPECT_NEAR(e.yaw_rate_rps, truth.yaw_rate_rps, 0.2 * kDeg * 5);
    // Error consistent with the reported covariance (5σ).
    EXPECT_LT(std::abs(e.v_mps - truth.v_mps), 5.0 * std::sqrt(e.covariance(0, 0)));
    EXPECT_LT(std::abs(e.yaw_rate_rps - truth.yaw_rate_rps), 5.0 * std::sqrt(e.covariance(1, 1)));
    // Most of the 210 static detections are inliers, few of the 90 moving ones.
    EXPECT_GT(e.num_inliers, 170);
    EXPECT_LT(e.num_inliers, 225);
  }
}

INSTANTIATE_TEST_SUITE_P(Speeds, EgoMotionAliasing,
                         ::testing::Values(Motion{3.0, 0.0}, Motion{8.0, 0.15}, Motion{14.0, -0.1},
                                           Motion{19.0, 0.05}, Motion{-2.0, 0.1}));

TEST(EgoMotion, AzimuthNoiseAtSpeedIsHandledByScaledThreshold) {
  std::mt19937 rng(7);
  EgoMotionEstimator est(default_front_mounts());
  SynthSpec spec;
  spec.sigma_az = 0.5 * kDeg;  // at 19 m/s lateral detections get ±0.15 m/s extra error
  for (int cycle = 0; cycle < 3; ++cycle) {
    const MotionEstimate e = run_cycle(est, 0.1 * cycle, 19.0, 0.1, spec, rng);
    ASSERT_EQ(e.status, MotionEstimate::Status::Ok);
    EXPECT_NEAR(e.v_mps, 19.0, 0.05);
    EXPECT_NEAR(e.yaw_rate_rps, 0.1, 0.01);
    EXPECT_GT(e.num_inliers, 150);
  }
}

TEST(EgoMotion, Standstill) {
  std::mt19937 rng(3);
  EgoMotionEstimator est(default_front_mounts());
  SynthSpec spec;
  spec.n_static = 40;
  spec.n_moving = 20;  // pedestrians/cars moving while we wait
  for (int cycle = 0; cycle < 5; ++cycle) {
    const MotionEstimate e = run_cycle(est, 0.1 * cycle, 0.0, 0.0, spec, rng);
    ASSERT_EQ(e.status, MotionEstimate::Status::Ok);
    EXPECT_NEAR(e.v_mps, 0.0, 0.02);
    EXPECT_NEAR(e.yaw_rate_rps, 0.0, 0.01);
  }
}

TEST(EgoMotion, TooFewDetectionsNeverInventsAValue) {
  std::mt19937 rng(5);
  EgoMotionEstimator est(default_front_mounts());
  SynthSpec spec;
  spec.n_static = 4;
  spec.n_moving = 2;
  const SensorFrame f = make_frame(est.mounts()[0], 0.0, 5.0, 0.0, spec, rng);
  const MotionEstimate e = est.process(f);
  EXPECT_EQ(e.status, MotionEstimate::Status::TooFewDetections);
  EXPECT_TRUE(std::isnan(e.v_mps));
  EXPECT_TRUE(std::isnan(e.yaw_rate_rps));
  EXPECT_EQ(e.num_detections, 6);
  ASSERT_EQ(est.last_static_mask().size(), f.detections.size());
  for (bool b : est.last_static_mask()) EXPECT_FALSE(b);

  // Enough detections but almost all moving in different ways: too few inliers.
  SensorFrame g;
  g.sensor_id = 0;
  g.time_s = 0.1;
  std::uniform_real_distribution<double> vr(-5.0, 5.0);
  for (int i = 0; i < 8; ++i) {
    g.detections.push_back(
        {10.0F, static_cast<float>((-50 + 12 * i) * kDeg), static_cast<float>(vr(rng)), 10.0F});
  }
  EXPECT_EQ(est.process(g).status, MotionEstimate::Status::TooFewDetections);
}

TEST(EgoMotion, EmptyFrame) {
  EgoMotionEstimator est(default_front_mounts());
  SensorFrame f;
  f.sensor_id = 1;
  const MotionEstimate e = est.process(f);
  EXPECT_EQ(e.status, MotionEstimate::Status::TooFewDetections);
  EXPECT_TRUE(est.last_static_mask().empty());
}

/// Detections of one vehicle driving ahead with velocity (vx, 0) in the
/// vehicle frame: they fit the ego-motion model for v' = v − vx (same ω).
SensorFrame cluster_frame(const SensorMount& m, double t, double v, double w, double target_vx,
                          int n, std::mt19937& rng) {
  SynthSpec spec;
  spec.n_static = n;
  spec.n_moving = 0;
  return make_frame(m, t, v - target_vx, w, spec, rng);
}

TEST(EgoMotion, AccelerationLimitsRejectDominantMovingCluster) {
  std::mt19937 rng(11);
  const auto mounts = default_front_mounts();
  EgoMotionEstimator est(mounts);
  const double v = 10.0, w = 0.05;
  double t = 0.0;
  for (int cycle = 0; cycle < 10; ++cycle, t += 0.1) {
    ASSERT_EQ(run_cycle(est, t, v, w, SynthSpec{}, rng).status, MotionEstimate::Status::Ok);
  }
  // A truck ahead (moving at 6 m/s) fills most of the field of view: 120 of its
  // detections per frame against 25 static ones.
  for (int cycle = 0; cycle < 3; ++cycle, t += 0.1) {
    for (const SensorMount& m : mounts) {
      SensorFrame f = cluster_frame(m, t + m.trigger_offset_s, v, w, 6.0, 120, rng);
      SynthSpec s;
      s.n_static = 25;
      s.n_moving = 0;
      const SensorFrame st = make_frame(m, f.time_s, v, w, s, rng);
      f.detections.insert(f.detections.end(), st.detections.begin(), st.detections.end());
      const MotionEstimate e = est.process(f);
      ASSERT_EQ(e.status, MotionEstimate::Status::Ok);
      // The truck dominates once all combined frames show it; the search within the
      // acceleration limits cannot pick its motion.
      EXPECT_TRUE(e.searched_within_limits);
      EXPECT_NEAR(e.v_mps, v, 0.05);
      EXPECT_NEAR(e.yaw_rate_rps, w, 0.02);
      // The mask marks the static detections (appended last), not the truck,
      // except truck points seen near ±90° from the driving direction, where the
      // truck's own speed has no radial component (physically indistinguishable).
      const auto& mask = est.last_static_mask();
      int truck_marked = 0, static_marked = 0;
      for (std::size_t i = 0; i < mask.size(); ++i)
        (i < 120 ? truck_marked : static_marked) += mask[i];
      EXPECT_LE(truck_marked, 10);
      EXPECT_GE(static_marked, 20);
    }
  }
  // Only the truck is seen by all sensors: no consistent hypothesis -> Rejected
  // once no frame with static detections is combined any more.
  std::vector<MotionEstimate::Status> statuses;
  for (int cycle = 0; cycle < 2; ++cycle, t += 0.1) {
    for (const SensorMount& m : mounts) {
      const MotionEstimate e =
          est.process(cluster_frame(m, t + m.trigger_offset_s, v, w, 6.0, 120, rng));
      statuses.push_back(e.status);
      if (e.status == MotionEstimate::Status::Ok) {
        EXPECT_NEAR(e.v_mps, v, 0.05);
      }
    }
  }
  EXPECT_EQ(statuses.back(), MotionEstimate::Status::Rejected);

  // Without a prior the same truck-only frame wins: this is what the limits prevent.
  EgoMotionEstimator fresh(mounts);
  const MotionEstimate e = fresh.process(cluster_frame(mounts[0], 0.0, v, w, 6.0, 120, rng));
  ASSERT_EQ(e.status, MotionEstimate::Status::Ok);
  EXPECT_NEAR(e.v_mps, v - 6.0, 0.05);
}

TEST(EgoMotion, StalePriorIsDropped) {
  // Sensors without aliasing here: with aliasing, an impossible jump can still
  // leave a limit-consistent wrong-zone hypothesis (the fallback then reports a
  // value inside the limits; that case is covered by the truck test).
  auto mounts = default_front_mounts();
  for (auto& m : mounts) m.spec.v_unambiguous_mps = 50.0;
  std::mt19937 rng(13);
  EgoMotionEstimator est(mounts);
  run_cycle(est, 0.0, 10.0, 0.0, SynthSpec{}, rng);
  // 0.43 s after the last estimate a jump from 10 to 2 m/s (19 m/s²) is rejected...
  const MotionEstimate a = est.process(make_frame(mounts[0], 0.5, 2.0, 0.0, SynthSpec{}, rng));
  EXPECT_EQ(a.status, MotionEstimate::Status::Rejected);
  EXPECT_TRUE(std::isnan(a.v_mps));
  // ... and once the prior is older than max_prior_age_s (1 s) it is dropped.
  const MotionEstimate b = est.process(make_frame(mounts[0], 1.1, 2.0, 0.0, SynthSpec{}, rng));
  ASSERT_EQ(b.status, MotionEstimate::Status::Ok);
  EXPECT_NEAR(b.v_mps, 2.0, 0.05);
}

/// Static detections of one azimuth sector only (a building front): they
/// constrain one combination of v and ω well, the other poorly.
SensorFrame sector_frame(const SensorMount& m, double t, double v, double w, int n,
                         std::mt19937& rng) {
  std::uniform_real_distribution<double> az(-55.0 * kDeg, -40.0 * kDeg);
  std::normal_distribution<double> nv(0.0, 0.05);
  SensorFrame f;
  f.sensor_id = m.sensor_id;
  f.time_s = t;
  for (int i = 0; i < n; ++i) {
    const double phi = az(rng);
    f.detections.push_back({40.0F, static_cast<float>(phi),
                            static_cast<float>(wrap_velocity(static_vr(m, phi, v, w) + nv(rng),
                                                             m.spec.v_unambiguous_mps)),
                            20.0F});
  }
  return f;
}

TEST(EgoMotion, MotionPriorBridgesDegenerateGeometry) {
  const auto mounts = default_front_mounts();
  const double v = 8.0, w = 0.05;
  std::mt19937 rng(41);
  EgoMotionEstimator est(mounts);
  double t = 0.0;
  for (int cycle = 0; cycle < 5; ++cycle, t += 0.1) run_cycle(est, t, v, w, SynthSpec{}, rng);
  // Now only the centre sensor sees anything, one sector.
  int ok = 0;
  Eigen::Matrix2d first_cov = Eigen::Matrix2d::Zero();
  for (int cycle = 0; cycle < 5; ++cycle, t += 0.1) {
    for (const auto& m : mounts) {
      const int n = m.sensor_id == 0 ? 12 : 0;
      const MotionEstimate e = est.process(sector_frame(m, t + m.trigger_offset_s, v, w, n, rng));
      if (m.sensor_id != 0) continue;
      ASSERT_EQ(e.status, MotionEstimate::Status::Ok);
      EXPECT_TRUE(e.used_motion_prior);
      // The sector fixes one combination of v and ω; along the other the
      // estimate follows the prior's random walk, and says so in its covariance.
      EXPECT_NEAR(e.v_mps, v, 4.0 * std::sqrt(e.covariance(0, 0)) + 0.01);
      EXPECT_NEAR(e.yaw_rate_rps, w, 4.0 * std::sqrt(e.covariance(1, 1)) + 0.002);
      EXPECT_NEAR(e.v_mps, v, 0.3);
      EXPECT_NEAR(e.yaw_rate_rps, w, 0.06);
      if (ok == 0) first_cov = e.covariance;
      ++ok;
    }
  }
  EXPECT_EQ(ok, 5);
  // Without history the same kind of frame gives a less certain estimate than
  // the first one right after the dense stretch.
  EgoMotionEstimator fresh(mounts);
  const MotionEstimate e = fresh.process(sector_frame(mounts[0], 10.0, v, w, 12, rng));
  EXPECT_FALSE(e.used_motion_prior);
  if (e.status == MotionEstimate::Status::Ok) {
    EXPECT_GT(e.covariance(0, 0), first_cov(0, 0));
    EXPECT_GT(e.covariance(1, 1), first_cov(1, 1));
  }
}

TEST(EgoMotion, CovarianceShrinksWithMoreInliers) {
  auto cov_for = [](int n_static) {
    std::mt19937 rng(17);
    EgoMotionConfig cfg;
    cfg.combine_window_s = 0.0;
    cfg.prior_accel_sigma_mps2 = 0.0;
    EgoMotionEstimator est(default_front_mounts(), cfg);
    SynthSpec spec;
    spec.n_static = n_static;
    spec.n_moving = 0;
    // Average over frames: the residual variance factor itself is noisy.
    Eigen::Matrix2d sum = Eigen::Matrix2d::Zero();
    for (int k = 0; k < 10; ++k) {
      const MotionEstimate e =
          est.process(make_frame(est.mounts()[0], 0.1 * k, 6.0, 0.1, spec, rng));
      EXPECT_EQ(e.status, MotionEstimate::Status::Ok);
      sum += e.covariance;
    }
    return Eigen::Matrix2d(sum / 10.0);
  };
  const Eigen::Matrix2d c30 = cov_for(30), c300 = cov_for(300);
  // ~1/N scaling: ten times the inliers, about a tenth of the variance.
  EXPECT_GT(c30(0, 0) / c300(0, 0), 5.0);
  EXPECT_GT(c30(1, 1) / c300(1, 1), 5.0);
  EXPECT_LT(c30(0, 0) / c300(0, 0), 20.0);
  // Covariance is symmetric positive definite.
  EXPECT_NEAR(c300(0, 1), c300(1, 0), 1e-15);
  EXPECT_GT(c300.determinant(), 0.0);
}

TEST(EgoMotion, CovarianceMatchesEmpiricalScatter) {
  EgoMotionConfig cfg;
  cfg.combine_window_s = 0.0;
  cfg.azimuth_sigma_rad = 0.0;
  cfg.inlier_threshold_mps = 0.25;   // 5σ: no truncation of the residuals
  cfg.prior_accel_sigma_mps2 = 0.0;  // independent estimates
  std::mt19937 rng(19);
  SynthSpec spec;
  spec.n_moving = 0;
  double sum_v2 = 0, sum_cv = 0;
  const int n = 200;
  EgoMotionEstimator est(default_front_mounts(), cfg);
  for (int k = 0; k < n; ++k) {
    const MotionEstimate e = est.process(make_frame(est.mounts()[1], 0.1 * k, 7.0, 0.2, spec, rng));
    ASSERT_EQ(e.status, MotionEstimate::Status::Ok);
    sum_v2 += (e.v_mps - 7.0) * (e.v_mps - 7.0);
    sum_cv += e.covariance(0, 0);
  }
  // Reported variance agrees with the actual error variance within 30 %.
  EXPECT_NEAR(sum_v2 / sum_cv, 1.0, 0.3);
}

TEST(EgoMotion, LeastSquaresMatchesGridSearch) {
  // Small case, no outliers, no aliasing, threshold so wide that all are
  // inliers: the refined estimate must be the least-squares minimum.
  EgoMotionConfig cfg;
  cfg.azimuth_sigma_rad = 0.0;
  cfg.inlier_threshold_mps = 2.0;
  cfg.prior_accel_sigma_mps2 = 0.0;  // pure least squares, no motion prior
  cfg.max_speed_mps = 4.0;
  cfg.min_speed_mps = 0.0;
  std::mt19937 rng(23);
  const auto mounts = default_front_mounts();
  EgoMotionEstimator est(mounts, cfg);
  SynthSpec spec;
  spec.n_static = 12;
  spec.n_moving = 0;
  spec.sigma_vr = 0.2;
  std::vector<SensorFrame> frames;
  MotionEstimate e;
  for (const auto& m : mounts) {
    frames.push_back(make_frame(m, 0.0, 2.0, 0.3, spec, rng));  // same time: no correction
    e = est.process(frames.back());
  }
  ASSERT_EQ(e.status, MotionEstimate::Status::Ok);
  ASSERT_EQ(e.num_inliers, 36);
  auto sse = [&](double v, double w) {
    double s = 0;
    for (std::size_t k = 0; k < frames.size(); ++k) {
      for (const auto& d : frames[k].detections) {
        const double r = d.radial_velocity_mps - static_vr(mounts[k], d.azimuth_rad, v, w);
        s += r * r;
      }
    }
    return s;
  };
  // Brute-force grid search, coarse then fine around the coarse minimum.
  double best_v = 0, best_w = 0, best = 1e300;
  for (double v = 1.0; v <= 3.0; v += 0.01) {
    for (double w = -0.2; w <= 0.8; w += 0.005) {
      if (const double s = sse(v, w); s < best) best = s, best_v = v, best_w = w;
    }
  }
  const double cv = best_v, cw = best_w;
  for (double v = cv - 0.01; v <= cv + 0.01; v += 0.0001) {
    for (double w = cw - 0.005; w <= cw + 0.005; w += 0.00005) {
      if (const double s = sse(v, w); s < best) best = s, best_v = v, best_w = w;
    }
  }
  EXPECT_NEAR(e.v_mps, best_v, 1.5e-4);
  EXPECT_NEAR(e.yaw_rate_rps, best_w, 1e-4);
  EXPECT_LE(sse(e.v_mps, e.yaw_rate_rps), best + 1e-9);

  // Covariance = s²·(HᵀH)⁻¹·σ² with HᵀH from the numeric Hessian of SSE/2.
  const double hv = 1e-3, hw = 1e-3, v0 = e.v_mps, w0 = e.yaw_rate_rps;
  Eigen::Matrix2d H;
  H(0, 0) = (sse(v0 + hv, w0) - 2 * sse(v0, w0) + sse(v0 - hv, w0)) / (hv * hv) / 2;
  H(1, 1) = (sse(v0, w0 + hw) - 2 * sse(v0, w0) + sse(v0, w0 - hw)) / (hw * hw) / 2;
  H(0, 1) = H(1, 0) = (sse(v0 + hv, w0 + hw) - sse(v0 + hv, w0 - hw) - sse(v0 - hv, w0 + hw) +
                       sse(v0 - hv, w0 - hw)) /
                      (4 * hv * hw) / 2;
  const Eigen::Matrix2d expected = (sse(v0, w0) / (36 - 2)) * H.inverse();
  EXPECT_NEAR(e.covariance(0, 0), expected(0, 0), 1e-6 * expected(0, 0) + 1e-12);
  EXPECT_NEAR(e.covariance(1, 1), expected(1, 1), 1e-6 * expected(1, 1) + 1e-12);
  EXPECT_NEAR(e.covariance(0, 1), expected(0, 1), 1e-6 * std::abs(expected(0, 1)) + 1e-12);
}

TEST(EgoMotion, SequentialTriggersAreCorrectedForAcceleration) {
  // Accelerating at 3 m/s² while turning in: each frame's detections are taken
  // at its own trigger time; the estimate refers to the newest frame's time.
  // Two mechanisms correct the older frames: the acceleration extrapolated from
  // previous estimates (accel_window_s) and the acceleration correction the
  // refinement estimates from the frames' time spread (prior σ_a).
  auto mean_error = [](double accel_window_s, double accel_sigma) {
    EgoMotionConfig cfg;
    cfg.accel_window_s = accel_window_s;
    cfg.accel_uncertainty_mps2 = accel_sigma;
    cfg.yaw_accel_uncertainty_rps2 = accel_sigma / 10.0;
    EgoMotionEstimator est(default_front_mounts(), cfg);
    std::mt19937 rng(29);
    SynthSpec spec;
    spec.n_static = 100;
    spec.n_moving = 20;
    double sum = 0;
    int n = 0, corrected = 0;
    for (int cycle = 0; cycle < 30; ++cycle) {
      for (const auto& m : est.mounts()) {
        const double t = 0.1 * cycle + m.trigger_offset_s;
        const double v = 4.0 + 3.0 * t, w = 0.1 + 0.2 * t;
        const MotionEstimate e = est.process(make_frame(m, t, v, w, spec, rng));
        EXPECT_EQ(e.status, MotionEstimate::Status::Ok);
        if (cycle >= 5) {
          sum += std::abs(e.v_mps - v);
          corrected += e.time_corrected;
          ++n;
        }
      }
    }
    return std::pair{sum / n, corrected};
  };
  const auto [both, n_both] = mean_error(0.3, 1.0);         // defaults
  const auto [history, n_history] = mean_error(0.3, 1e-6);  // extrapolation only
  const auto [data, n_data] = mean_error(0.0, 1.0);         // estimated from the frames only
  const auto [none, n_none] = mean_error(0.0, 1e-6);        // no correction at all
  EXPECT_EQ(n_both, 75);
  EXPECT_EQ(n_history, 75);
  EXPECT_EQ(n_none, 0);
  EXPECT_LT(both, 0.012);
  EXPECT_LT(history, 0.012);
  EXPECT_LT(data, 0.015);
  EXPECT_GT(none, 0.06);  // ≈ a·(33 + 67)/3 ms = 0.1 m/s bias without correction
}

TEST(EgoMotion, StaticMaskMarksStaticDetections) {
  std::mt19937 rng(31);
  EgoMotionEstimator est(default_front_mounts());
  const SynthSpec spec;
  const SensorFrame f = make_frame(est.mounts()[2], 0.0, 12.0, -0.05, spec, rng);
  const MotionEstimate e = est.process(f);
  ASSERT_EQ(e.status, MotionEstimate::Status::Ok);
  const auto& mask = est.last_static_mask();
  ASSERT_EQ(mask.size(), f.detections.size());
  int static_marked = 0, moving_marked = 0;
  for (int i = 0; i < 100; ++i) (i < 70 ? static_marked : moving_marked) += mask[i];
  EXPECT_GE(static_marked, 62);  // 2σ threshold: ~95 % of static ones
  EXPECT_LE(moving_marked, 2);
}

TEST(EgoMotion, Deterministic) {
  auto run = [] {
    std::mt19937 rng(37);
    EgoMotionEstimator est(default_front_mounts());
    std::vector<double> out;
    for (int c = 0; c < 3; ++c) {
      const MotionEstimate e = run_cycle(est, 0.1 * c, 13.0, 0.1, SynthSpec{}, rng);
      out.push_back(e.v_mps);
      out.push_back(e.yaw_rate_rps);
    }
    return out;
  };
  const std::vector<double> a = run();
  EXPECT_EQ(a, run());  // bit-identical on a second run
  ASSERT_EQ(a.size(), 6U);
  for (std::size_t i = 0; i < a.size(); i += 2) {  // and a real estimate, not a constant
    EXPECT_NEAR(a[i], 13.0, 0.1);
    EXPECT_NEAR(a[i + 1], 0.1, 0.01);
  }
}

TEST(EgoMotion, ContractViolations) {
  EgoMotionEstimator est(default_front_mounts());
  SensorFrame f;
  f.sensor_id = 7;
  EXPECT_THROW(est.process(f), ContractViolation);
  f.sensor_id = 0;
  f.time_s = 1.0;
  est.process(f);
  f.time_s = 0.5;
  EXPECT_THROW(est.process(f), ContractViolation);
}

}  // namespace
}  // namespace polmap::radar
