#pragma once
// Internal: adds objects of the documented classes (tools/sim/README.md) to a
// world, either relative to the route (station s, lateral d, left positive)
// or in world coordinates (HD maps). RCS values are drawn uniformly in dB
// within the class range, once per object.
#include <Eigen/Core>
#include <string>
#include <vector>

#include "polmap/sim/random.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::sim {

/// Isotropic point scattering centre of `object` at xy (other fields default).
inline PointScatterer point_scatterer(const Eigen::Vector2d& xy, const ScatteringVector& omega,
                                      double rcs_dbsm, std::uint32_t object) {
  PointScatterer p;
  p.pos_m = xy;
  p.omega = omega;
  p.rcs_dbsm = static_cast<float>(rcs_dbsm);
  p.object = object;
  return p;
}

/// Sub-scatterer chain prototype of extended `object` (other fields default).
inline LineScatterer line_scatterer(ExtendedModel model, double rcs_per_m_dbsm,
                                    float grazing_exponent, std::uint32_t object) {
  LineScatterer l;
  l.model = model;
  l.rcs_per_m_dbsm = static_cast<float>(rcs_per_m_dbsm);
  l.grazing_exponent = grazing_exponent;
  l.object = object;
  return l;
}

/// Traffic lanes of a road with one oncoming lane (at oncoming_lane_m, oncoming_per_km
/// vehicles) and no same-direction lane; traffic up to the configured speed, the ego at
/// 15 m/s by default.
inline RoadLayout oncoming_lane_road(const SimConfig& cfg, double oncoming_lane_m,
                                     double oncoming_per_km) {
  return {.oncoming_lane_m = oncoming_lane_m,
          .has_same_dir_lane = false,
          .same_dir_lane_m = 0.0,
          .oncoming_per_km = oncoming_per_km,
          .same_dir_per_km = 0.0,
          .traffic_max_speed_mps = cfg.traffic.max_speed_mps,
          .default_max_speed_mps = 15.0};
}

class WorldBuilder {
 public:
  WorldBuilder(World& w, Rng& rng, std::uint64_t seed) : w_(w), rng_(rng), seed_(seed) {}

  // --- route-relative (procedural presets) ---
  void pole(ObjectClass cls, double s, double d);
  /// Sign pole + plate; the plate faces traffic approaching in +s direction.
  void sign(double s, double d, int facing);
  void traffic_light(double s, double d);
  void curb(double s0, double s1, double d);
  /// Curb with occasional driveway gaps.
  void curb_with_driveways(double s0, double s1, double d);
  /// side: -1 right of the route, +1 left (the facade faces the route).
  void facade(double s0, double s1, double d, int side);
  void wall(double s0, double s1, double d, int side);
  void fence(double s0, double s1, double d, int side);
  void guardrail(double s0, double s1, double d, int side, double post_spacing_m);
  void guide_post(double s, double d);
  void tree(double s, double d);
  void vegetation(double s0, double s1, double d, bool permanent, double presence);
  /// Temporary car / bin at station s, lateral d; present with probability presence,
  /// standing within +-shift_m along the route of that place in each drive.
  void parked_car(double s, double d, double presence, double shift_m);
  void bin(double s, double d, double presence, double shift_m);

  // --- world coordinates (HD maps) ---
  /// Point object of a pole-like class at xy (odd, isotropic).
  std::uint32_t pole_at(ObjectClass cls, const Eigen::Vector2d& xy, const std::string& source);
  /// Sign plate (specular lobe around normal_rad, two-sided) + its pole.
  void sign_at(const Eigen::Vector2d& xy, double normal_rad, const std::string& source);
  /// Extended object from a polyline. toward_road_rad(p) gives, for implied posts and lobes,
  /// the direction from the object to the road at p.
  std::uint32_t curb_line(ObjectClass cls, const std::vector<Eigen::Vector2d>& poly,
                          const std::string& source);
  std::uint32_t wall_line(const std::vector<Eigen::Vector2d>& poly, const std::string& source);
  std::uint32_t fence_line(const std::vector<Eigen::Vector2d>& poly, double post_spacing_m,
                           const std::string& source);
  std::uint32_t guardrail_line(const std::vector<Eigen::Vector2d>& poly, double post_spacing_m,
                               const std::string& source);
  /// Lamps every spacing metres along poly, offset outward (away from the route).
  void lamps_along(const std::vector<Eigen::Vector2d>& poly, double spacing_m, double offset_m);

 private:
  std::uint32_t object(ObjectClass cls, Mechanism m, std::vector<Eigen::Vector2d> geom,
                       double rcs_dbsm, bool permanent = true, double presence = 1.0,
                       std::string source = "procedural");
  void point(const PointScatterer& p) { w_.points.push_back(p); }
  [[nodiscard]] double yaw(double s) const { return w_.route.at(s).yaw_rad; }
  [[nodiscard]] Eigen::Vector2d at(double s, double d) const { return w_.route.offset_point(s, d); }
  /// Direction from p towards the nearest route point.
  [[nodiscard]] double toward_route(const Eigen::Vector2d& p) const;
  void posts_along(const std::vector<Eigen::Vector2d>& poly, double spacing, ObjectClass cls,
                   double behind_m, const std::string& source);
  void car_like(ObjectClass cls, const Eigen::Vector2d& c, double yaw, double length, double width,
                double rcs_min, double rcs_max, int centres, double presence, double shift_m);
  ScatteringVector mixed_omega();
  /// A uniformly drawn fixed phase offset of a scattering centre.
  float random_phase();
  /// Opaque diffuse surface (facades, walls) with a specular lobe around its normal.
  void surface_lines(const std::vector<Eigen::Vector2d>& poly, double rcs_per_m_dbsm,
                     std::uint32_t object);
  /// Odd-bounce corner objects at both ends of poly; with_phase: a random phase each.
  void end_corners(const std::vector<Eigen::Vector2d>& poly, const std::string& source,
                   bool with_phase);

  World& w_;
  Rng& rng_;
  std::uint64_t seed_;
};

}  // namespace polmap::sim
