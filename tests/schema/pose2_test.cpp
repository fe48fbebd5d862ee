#include "polmap/schema/pose2.hpp"

#include <gtest/gtest.h>

#include <numbers>

namespace polmap {
namespace {

TEST(Pose2, ComposeWithInverseIsIdentity) {
  const Pose2 T_a_b{1.5, -2.0, 0.7};
  const Pose2 id = T_a_b * T_a_b.inverse();
  EXPECT_NEAR(id.x_m, 0.0, 1e-12);
  EXPECT_NEAR(id.y_m, 0.0, 1e-12);
  EXPECT_NEAR(id.yaw_rad, 0.0, 1e-12);
}

TEST(Pose2, TransformsPointsLikeRotationThenTranslation) {
  const Pose2 T_map_vehicle{10.0, 5.0, std::numbers::pi / 2};
  const Eigen::Vector2d p_map = T_map_vehicle * Eigen::Vector2d(1.0, 0.0);
  EXPECT_NEAR(p_map.x(), 10.0, 1e-12);
  EXPECT_NEAR(p_map.y(), 6.0, 1e-12);
}

TEST(Pose2, ArcIntegrationMatchesFineEulerSteps) {
  const double v = 12.0, w = 0.3, dt = 0.5;
  Pose2 fine;
  const int n = 100000;
  for (int i = 0; i < n; ++i) fine = fine * Pose2{v * dt / n, 0.0, w * dt / n};
  const Pose2 arc = integrate_motion(v, w, dt);
  EXPECT_NEAR(arc.x_m, fine.x_m, 1e-4);
  EXPECT_NEAR(arc.y_m, fine.y_m, 1e-4);
  EXPECT_NEAR(arc.yaw_rad, fine.yaw_rad, 1e-9);
}

TEST(Pose2, WrapAngleStaysInHalfOpenInterval) {
  EXPECT_NEAR(wrap_angle_rad(3 * std::numbers::pi), -std::numbers::pi, 1e-12);
  EXPECT_NEAR(wrap_angle_rad(-0.5), -0.5, 1e-12);
  EXPECT_NEAR(wrap_angle_rad(2 * std::numbers::pi + 0.25), 0.25, 1e-12);
}

}  // namespace
}  // namespace polmap
