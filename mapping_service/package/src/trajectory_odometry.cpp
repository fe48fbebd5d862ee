#include "polmap/mapping_service/trajectory_odometry.hpp"

#include <cmath>

#include "polmap/schema/errors.hpp"

namespace polmap::mapping {

TrajectoryOdometry::TrajectoryOdometry(std::span<const TrajectorySample> samples)
    : t_(samples), yaw_rad_(samples.size(), 0.0), distance_m_(samples.size(), 0.0) {
  for (std::size_t i = 1; i < samples.size(); ++i) {
    const auto& a = samples[i - 1];
    const auto& b = samples[i];
    const double dt = b.time_s - a.time_s;
    yaw_rad_[i] = yaw_rad_[i - 1] + 0.5 * (a.yaw_rate_rps + b.yaw_rate_rps) * dt;
    distance_m_[i] = distance_m_[i - 1] + 0.5 * (a.speed_mps + b.speed_mps) * dt;
  }
}

bool TrajectoryOdometry::kept_by(std::size_t a, std::size_t b, double max_yaw_rad,
                                 double max_distance_m) const {
  POLMAP_EXPECT(a < b && b < t_.size());
  const auto& x = t_[a];
  const auto& y = t_[b];
  const double span = y.time_s - x.time_s;
  return std::abs(0.5 * (x.yaw_rate_rps + y.yaw_rate_rps) * span - (yaw_rad_[b] - yaw_rad_[a])) <=
             max_yaw_rad &&
         std::abs(0.5 * (x.speed_mps + y.speed_mps) * span - (distance_m_[b] - distance_m_[a])) <=
             max_distance_m;
}

}  // namespace polmap::mapping
