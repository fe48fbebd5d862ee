#pragma once
/// @file consumer_gnss.hpp
/// The place-dependent part of consumer-grade GNSS errors: multipath in street canyons.
/// A receiver between facades sees reflected signals, and its position error depends on
/// where it is, not when: every drive through the same canyon gets a similar error there.
/// The time-dependent parts (bias, heading, outages) are in GnssErrorModel (drive.hpp).
#include <Eigen/Core>
#include <cstdint>

#include "polmap/sim/config.hpp"

namespace polmap::sim {

class World;

/// Multipath error field of a world: a smooth unit-variance random field (value noise on a
/// lattice of multipath_correlation_m, fixed by the seed) scaled by the canyon factor and
/// canyon_multipath_m. Deterministic in (seed, position, heading).
class CanyonMultipathField {
 public:
  /// `world` must outlive the field.
  CanyonMultipathField(const World& world, const ConsumerGnssConfig& cfg, std::uint64_t seed);

  /// Position error (world frame, metres) of a receiver at p_m on a vehicle heading yaw_rad.
  [[nodiscard]] Eigen::Vector2d error_m(const Eigen::Vector2d& p_m, double yaw_rad) const;
  /// Sky blockage in [0, 1]: 1 with facades or walls of at least 15 m (weighted by
  /// 1 - (d / canyon_radius_m)^2) on both sides, 0.25 with one side only, 0 in the open.
  [[nodiscard]] double canyon_factor(const Eigen::Vector2d& p_m, double yaw_rad) const;
  /// The unit-variance random field alone (tests check its statistics).
  [[nodiscard]] Eigen::Vector2d unit_field(const Eigen::Vector2d& p_m) const;

 private:
  const World& world_;
  ConsumerGnssConfig cfg_;
  std::uint64_t seed_;
};

}  // namespace polmap::sim
