#include "polmap/localization_client/initialization.hpp"

#include <cmath>
#include <limits>

namespace polmap::loc {

double clear_margin(const MatchResult& m) {
  return m.runner_up_cost ? *m.runner_up_cost - m.cost : std::numeric_limits<double>::infinity();
}

bool counts_for_initialization(const MatchResult& m, const InitializationConfig& cfg) {
  return m.status == MatchResult::Status::Ok &&
         static_cast<int>(m.points.size()) >= cfg.min_point_matches &&
         clear_margin(m) >= cfg.min_margin;
}

bool poses_agree(const Pose2& T_map_odom_a, const Pose2& T_map_odom_b, const Pose2& T_odom_vehicle,
                 const InitializationConfig& cfg) {
  const Pose2 a = T_map_odom_a * T_odom_vehicle;
  const Pose2 b = T_map_odom_b * T_odom_vehicle;
  return (a.translation() - b.translation()).norm() < cfg.agreement_xy_m &&
         std::abs(wrap_angle_rad(a.yaw_rad - b.yaw_rad)) < cfg.agreement_yaw_rad;
}

InitializationStreak::Step InitializationStreak::add(const MatchResult& match,
                                                     const Pose2& T_odom_vehicle,
                                                     double odometry_distance_m) {
  // TooFewMatches still carries the best transform; NoCandidate / TooFewClusters do not.
  const bool has_pose = match.status == MatchResult::Status::Ok ||
                        match.status == MatchResult::Status::Ambiguous ||
                        match.status == MatchResult::Status::TooFewMatches;
  const bool counts = counts_for_initialization(match, cfg_);
  const bool agrees =
      count_ > 0 && has_pose && poses_agree(match.T_map_odom, T_map_odom_, T_odom_vehicle, cfg_);
  if (counts) {
    const Step step = agrees ? Step::Confirmed : Step::Started;
    if (!agrees) {
      count_ = 0;
      start_m_ = odometry_distance_m;
    }
    ++count_;
    T_map_odom_ = match.T_map_odom;
    return step;
  }
  if (agrees) return Step::Continued;
  count_ = 0;
  return Step::Ended;
}

std::optional<Pose2> InitializationStreak::ready(double odometry_distance_m) const {
  if (count_ < cfg_.confirmations || odometry_distance_m - start_m_ < cfg_.min_travel_m) {
    return std::nullopt;
  }
  return T_map_odom_;
}

std::optional<Pose2> RelocalizationConfirmation::add(const MatchResult& wide,
                                                     std::size_t tracking_point_matches,
                                                     bool distinct, const Pose2& T_odom_vehicle) {
  const bool better =
      counts_for_initialization(wide, init_) &&
      wide.points.size() >= tracking_point_matches + static_cast<std::size_t>(cfg_.extra_matches);
  if (!better || !distinct) {
    count_ = 0;
    return std::nullopt;
  }
  InitializationConfig agreement = init_;
  agreement.agreement_xy_m = cfg_.agreement_xy_m;
  agreement.agreement_yaw_rad = cfg_.agreement_yaw_rad;
  const bool agrees =
      count_ > 0 && poses_agree(wide.T_map_odom, T_map_odom_, T_odom_vehicle, agreement);
  count_ = agrees ? count_ + 1 : 1;
  T_map_odom_ = wide.T_map_odom;
  if (count_ < 2) return std::nullopt;
  count_ = 0;
  return T_map_odom_;
}

}  // namespace polmap::loc
