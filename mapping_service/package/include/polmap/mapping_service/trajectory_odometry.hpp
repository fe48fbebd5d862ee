#pragma once
/// @file trajectory_odometry.hpp
/// The vehicle's odometry in a trajectory (trapezoid integrals of yaw rate and speed) and
/// whether a thinned trajectory keeps it: shared by the package writer's simplification and
/// the store's decimation, because map builds align consumer-grade drives with that
/// odometry (drive_alignment.hpp).
#include <cstddef>
#include <span>
#include <vector>

#include "polmap/schema/recording.hpp"

namespace polmap::mapping {

/// Full-rate odometry from the first sample: yaw_rad[i] and distance_m[i] are the
/// trapezoid integrals of yaw rate and speed up to sample i.
class TrajectoryOdometry {
 public:
  explicit TrajectoryOdometry(std::span<const TrajectorySample> samples);
  /// Whether the trapezoid over samples a and b alone (a < b) reproduces the integrals
  /// between them within max_yaw_rad and max_distance_m.
  [[nodiscard]] bool kept_by(std::size_t a, std::size_t b, double max_yaw_rad,
                             double max_distance_m) const;

 private:
  std::span<const TrajectorySample> t_;
  std::vector<double> yaw_rad_, distance_m_;
};

}  // namespace polmap::mapping
