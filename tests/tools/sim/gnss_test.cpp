// GNSS/IMU error model: configured sigmas, no-fix share, correlation; exact
// trajectory kinematics (acceleration, speed limits, stops).
#include <gtest/gtest.h>

#include <cmath>

#include "polmap/sim/drive.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "sim_test_util.hpp"

namespace polmap::sim {
namespace {

TEST(Gnss, ErrorStatisticsMatchConfiguredSigmas) {
  GnssSimConfig cfg;
  const double duration = 4 * 3600.0;
  GnssErrorModel m(cfg, duration, 99);
  const tiles::LocalFrame frame(GeoPoint{48.0, 11.0, 0.0});
  double se_fix = 0, sn_fix = 0, nfix = 0, se_flo = 0, nflo = 0, sh = 0, n = 0;
  double lag_num = 0, lag_den = 0, prev = 0;
  bool have_prev = false;
  const double dt = 0.1;  // 10 Hz is enough for statistics
  for (double t = 0; t < duration; t += dt) {
    ExactState s = test::state_at(100.0, -50.0, 0.3, 10.0, 0.0, t);
    const TrajectorySample g = m.sample(s, frame);
    const Eigen::Vector2d xy = frame.to_local(g.lat_deg, g.lon_deg);
    const double ex = xy.x() - 100.0, ey = xy.y() + 50.0;
    const double yaw_frame = g.yaw_enu_rad + frame.convergence_rad(xy);
    sh += std::pow(wrap_angle_rad(yaw_frame - 0.3), 2);
    ++n;
    if (g.solution == GnssSolution::CarrierPhaseFixed) {
      se_fix += ex * ex;
      sn_fix += ey * ey;
      ++nfix;
      EXPECT_FLOAT_EQ(g.std_east_m, 0.014F);
    } else {
      se_flo += ex * ex + ey * ey;
      nflo += 2;
      EXPECT_FLOAT_EQ(g.std_east_m, 0.086F);
    }
    if (have_prev) {
      lag_num += prev * ex;
      lag_den += ex * ex;
    }
    prev = ex;
    have_prev = true;
  }
  EXPECT_NEAR(std::sqrt(se_fix / nfix), 0.014, 0.0025);
  EXPECT_NEAR(std::sqrt(sn_fix / nfix), 0.014, 0.0025);
  EXPECT_NEAR(std::sqrt(se_flo / nflo), 0.086, 0.02);
  const double no_fix = nflo / 2 / n;
  EXPECT_GE(no_fix, 0.099);
  EXPECT_LE(no_fix, 0.201);
  EXPECT_NEAR(std::sqrt(sh / n) * 180 / M_PI, 0.05, 0.012);
  // Correlated (Gauss-Markov), not white: lag-0.1 s correlation ~ exp(-0.1/10).
  EXPECT_GT(lag_num / lag_den, 0.95);
}

TEST(Gnss, NoFixStretchesCoverTenToTwentyPercent) {
  GnssSimConfig cfg;
  for (std::uint64_t seed = 1; seed < 20; ++seed) {
    GnssErrorModel m(cfg, 600.0, seed);
    double total = 0;
    for (const auto& [a, b] : m.no_fix_stretches()) {
      EXPECT_GE(a, 0.0);
      EXPECT_LE(b, 600.0 + 1e-6);
      total += b - a;
    }
    EXPECT_GE(total / 600.0, 0.0999);
    EXPECT_LE(total / 600.0, 0.2001);
  }
}

TEST(Trajectory, KinematicsWithinLimitsAndStopsAtLights) {
  SimConfig cfg;
  auto w = load_world("urban", 2000.0, 4, cfg);
  bool any_stop = false;
  for (int d = 0; d < 3; ++d) {
    DrivePlan plan(*w, cfg, d);
    any_stop = any_stop || !plan.stops().empty();
    double prev_v = 0, standstill = 0;
    ExactState prev = plan.state(0);
    for (double t = 0.01; t <= plan.duration_s(); t += 0.01) {
      const ExactState s = plan.state(t);
      EXPECT_LE(s.v_mps, 15.0 + 1e-9);
      EXPECT_GE(s.v_mps, 0.0);
      EXPECT_LE(std::abs(s.v_mps - prev_v) / 0.01, 3.0 + 1e-6) << "t=" << t;
      // Position increments agree with the speed (exact pose = integrated motion).
      const double ds = std::hypot(s.x_m - prev.x_m, s.y_m - prev.y_m);
      EXPECT_NEAR(ds, 0.5 * (s.v_mps + prev.v_mps) * 0.01, 2e-3);
      // Lateral acceleration v^2 kappa bounded (curve speeds).
      EXPECT_LE(s.v_mps * s.v_mps * std::abs(s.yaw_rate_rps / std::max(s.v_mps, 1e-6)), 2.3);
      if (s.v_mps == 0.0 && t > 1 && t < plan.duration_s() - 1) standstill += 0.01;
      prev_v = s.v_mps;
      prev = s;
    }
    double want = 0;
    for (const auto& [st, dwell] : plan.stops()) want += dwell;
    EXPECT_NEAR(standstill, want, 0.05 * plan.stops().size() + 0.02);
  }
  EXPECT_TRUE(any_stop);
}

TEST(Trajectory, RuralDrivesReach20mps) {
  SimConfig cfg;
  auto w = load_world("rural", 3000.0, 2, cfg);
  DrivePlan plan(*w, cfg, 0);
  double vmax = 0;
  for (double t = 0; t < plan.duration_s(); t += 0.1) vmax = std::max(vmax, plan.state(t).v_mps);
  EXPECT_GT(vmax, 16.5);
  EXPECT_LE(vmax, 20.0 + 1e-9);
}

}  // namespace
}  // namespace polmap::sim
