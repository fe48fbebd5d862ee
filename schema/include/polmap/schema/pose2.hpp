#pragma once
/// @file pose2.hpp
/// Planar rigid transform SE(2). Name instances after the frames they map:
/// `T_map_vehicle` maps vehicle-frame points into the map frame.
#include <Eigen/Core>
#include <cmath>
#include <numbers>

namespace polmap {

/// Wraps an angle into [-pi, pi).
inline double wrap_angle_rad(double a) {
  a = std::fmod(a + std::numbers::pi, 2.0 * std::numbers::pi);
  if (a < 0) a += 2.0 * std::numbers::pi;
  return a - std::numbers::pi;
}

/// SE(2) element: rotation by yaw_rad, then translation (x_m, y_m).
struct Pose2 {
  double x_m = 0.0;
  double y_m = 0.0;
  double yaw_rad = 0.0;

  [[nodiscard]] Eigen::Vector2d translation() const { return {x_m, y_m}; }
  [[nodiscard]] Eigen::Matrix2d rotation() const {
    const double c = std::cos(yaw_rad), s = std::sin(yaw_rad);
    Eigen::Matrix2d r;
    r << c, -s, s, c;
    return r;
  }
  /// Maps a point given in this pose's child frame into its parent frame.
  [[nodiscard]] Eigen::Vector2d operator*(const Eigen::Vector2d& p) const {
    return rotation() * p + translation();
  }
  /// Composition: (T_a_b * T_b_c) = T_a_c.
  [[nodiscard]] Pose2 operator*(const Pose2& o) const {
    const Eigen::Vector2d t = (*this) * o.translation();
    return {t.x(), t.y(), wrap_angle_rad(yaw_rad + o.yaw_rad)};
  }
  [[nodiscard]] Pose2 inverse() const {
    const Eigen::Vector2d t = -(rotation().transpose() * translation());
    return {t.x(), t.y(), wrap_angle_rad(-yaw_rad)};
  }
};

/// Relative motion of constant forward velocity and yaw rate over dt_s
/// (exact arc integration, zero side slip): returns T_prev_next.
inline Pose2 integrate_motion(double v_mps, double yaw_rate_rps, double dt_s) {
  const double dyaw = yaw_rate_rps * dt_s;
  if (std::abs(dyaw) < 1e-9) return {v_mps * dt_s, 0.0, dyaw};
  const double r = v_mps / yaw_rate_rps;
  return {r * std::sin(dyaw), r * (1.0 - std::cos(dyaw)), wrap_angle_rad(dyaw)};
}

}  // namespace polmap
