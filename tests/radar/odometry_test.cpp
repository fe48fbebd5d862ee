// Odometry: exact arc integration of ego-motion estimates.
#include "polmap/radar/odometry.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {

MotionEstimate ok(double t, double v, double w) {
  MotionEstimate m;
  m.status = MotionEstimate::Status::Ok;
  m.time_s = t;
  m.v_mps = v;
  m.yaw_rate_rps = w;
  return m;
}

/// Pose on a circle of constant v, ω after time t from the origin.
Pose2 circle(double v, double w, double t) {
  const double r = v / w;
  return {r * std::sin(w * t), r * (1.0 - std::cos(w * t)), wrap_angle_rad(w * t)};
}

TEST(Odometry, ConstantMotionGivesExactCircle) {
  Odometry odo;
  const double v = 10.0, w = 0.2;
  for (int k = 0; k <= 100; ++k) odo.add(ok(5.0 + 0.1 * k, v, w));  // 10 s: 2 rad of arc
  for (double t : {0.0, 1.0, 3.3, 7.77, 10.0}) {
    const Pose2 p = odo.T_odom_vehicle(5.0 + t);
    const Pose2 e = circle(v, w, t);
    EXPECT_NEAR(p.x_m, e.x_m, 1e-9) << t;
    EXPECT_NEAR(p.y_m, e.y_m, 1e-9) << t;
    EXPECT_NEAR(wrap_angle_rad(p.yaw_rad - e.yaw_rad), 0.0, 1e-12) << t;
  }
  EXPECT_NEAR(odo.distance_m(), 100.0, 1e-9);
  // Interpolated between estimate times: on the same circle.
  const Pose2 mid = odo.T_odom_vehicle(5.0 + 4.2345);
  const Pose2 e = circle(v, w, 4.2345);
  EXPECT_NEAR(mid.x_m, e.x_m, 1e-9);
  EXPECT_NEAR(mid.y_m, e.y_m, 1e-9);
  // A full turn comes back to the start.
  Odometry full;
  const double period = 2 * std::numbers::pi / w;
  for (int k = 0; k <= 1000; ++k) full.add(ok(period * k / 1000.0, v, w));
  const Pose2 end = full.T_odom_vehicle(period);
  EXPECT_NEAR(end.x_m, 0.0, 1e-9);
  EXPECT_NEAR(end.y_m, 0.0, 1e-9);
}

TEST(Odometry, StraightLineUnderConstantAccelerationIsExact) {
  // Trapezoid rule on linear v(t) integrates exactly: x = v0 t + a t²/2.
  Odometry odo;
  for (int k = 0; k <= 30; ++k) odo.add(ok(0.1 * k, 1.0 + 2.0 * 0.1 * k, 0.0));
  const Pose2 p = odo.T_odom_vehicle(3.0);
  EXPECT_NEAR(p.x_m, 1.0 * 3.0 + 0.5 * 2.0 * 9.0, 1e-9);
  EXPECT_NEAR(p.y_m, 0.0, 1e-12);
  EXPECT_NEAR(odo.distance_m(), 12.0, 1e-9);
}

TEST(Odometry, ExtrapolatesWithHeldStateForLimitedTime) {
  OdometryConfig cfg;
  cfg.max_hold_s = 0.5;
  Odometry odo(cfg);
  EXPECT_FALSE(odo.try_T_odom_vehicle(0.0).has_value());
  odo.add(ok(0.0, 5.0, 0.1));
  odo.add(ok(0.1, 5.0, 0.1));
  const Pose2 p = odo.T_odom_vehicle(0.4);
  const Pose2 e = circle(5.0, 0.1, 0.4);
  EXPECT_NEAR(p.x_m, e.x_m, 1e-9);
  EXPECT_NEAR(p.y_m, e.y_m, 1e-9);
  EXPECT_FALSE(odo.try_T_odom_vehicle(0.61).has_value());
  EXPECT_THROW((void)odo.T_odom_vehicle(0.61), ContractViolation);
  EXPECT_THROW((void)odo.T_odom_vehicle(-0.01), ContractViolation);
}

TEST(Odometry, IgnoresFailedEstimatesAndCountsGaps) {
  Odometry odo;
  odo.add(ok(0.0, 4.0, 0.0));
  MotionEstimate bad;
  bad.status = MotionEstimate::Status::Rejected;
  bad.time_s = 0.1;
  bad.v_mps = 100.0;
  odo.add(bad);
  EXPECT_DOUBLE_EQ(odo.latest_time_s(), 0.0);
  odo.add(ok(0.2, 4.0, 0.0));
  EXPECT_EQ(odo.num_gaps(), 0);
  odo.add(ok(1.2, 4.0, 0.0));  // 1 s without estimates
  EXPECT_EQ(odo.num_gaps(), 1);
  EXPECT_NEAR(odo.T_odom_vehicle(1.2).x_m, 4.8, 1e-12);
}

TEST(Odometry, ForgetsOldHistory) {
  OdometryConfig cfg;
  cfg.history_s = 1.0;
  Odometry odo(cfg);
  for (int k = 0; k <= 50; ++k) odo.add(ok(0.1 * k, 2.0, 0.0));
  EXPECT_FALSE(odo.try_T_odom_vehicle(3.5).has_value());
  EXPECT_NEAR(odo.T_odom_vehicle(4.5).x_m, 9.0, 1e-9);
}

}  // namespace
}  // namespace polmap::radar
