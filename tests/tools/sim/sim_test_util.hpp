#pragma once
// Helpers shared by the simulator tests: tiny hand-made worlds.
#include <cmath>
#include <memory>
#include <numbers>

#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/scattering.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::sim::test {

inline constexpr double kDeg = std::numbers::pi / 180.0;

/// Wraps a radial velocity into the unambiguous interval [-5, 5) m/s.
inline double wrap5(double v) {
  double w = std::fmod(v + 5.0, 10.0);
  if (w < 0) w += 10.0;
  return w - 5.0;
}

/// An empty world with a straight route along +x from (0, 0).
inline std::shared_ptr<World> empty_world(double length_m = 200.0) {
  auto w = std::make_shared<World>("test", GeoPoint{48.0, 11.0, 0.0});
  w->route = Path::from_curvature({0.0, 0.0}, 0.0, length_m, [](double) { return 0.0; });
  w->road.oncoming_per_km = 0.0;
  return w;
}

/// Adds a point object at xy with the given scattering vector and RCS.
inline std::uint32_t add_point(World& w, const Eigen::Vector2d& xy, const ScatteringVector& omega,
                               double rcs_dbsm, ObjectClass cls = ObjectClass::Pole) {
  WorldObject o;
  o.cls = cls;
  o.geometry_m = {xy};
  o.rcs_dbsm = rcs_dbsm;
  const std::uint32_t id = w.add_object(o);
  PointScatterer p;
  p.pos_m = xy;
  p.omega = normalized(omega);
  p.rcs_dbsm = static_cast<float>(rcs_dbsm);
  p.object = id;
  w.points.push_back(p);
  return id;
}

/// A config without ground clutter or false alarms (isolated-target tests).
inline SimConfig quiet_config() {
  SimConfig c;
  c.radar.ground_clutter = false;
  c.radar.false_alarms_per_frame = 0.0;
  return c;
}

/// Vehicle state at the origin heading +x.
inline ExactState state_at(double x, double y, double yaw, double v, double yaw_rate = 0.0,
                           double t = 0.0) {
  ExactState s;
  s.time_s = t;
  s.x_m = x;
  s.y_m = y;
  s.yaw_rad = yaw;
  s.v_mps = v;
  s.yaw_rate_rps = yaw_rate;
  return s;
}

/// The strongest spectrum cell by total power.
inline const SpectrumCell* peak_cell(const PolSpectrum& sp) {
  const SpectrumCell* best = nullptr;
  double bp = -1;
  for (const auto& c : sp.cells) {
    double p = 0;
    for (const auto& v : c.s) p += std::norm(v);
    if (p > bp) {
      bp = p;
      best = &c;
    }
  }
  return best;
}

}  // namespace polmap::sim::test
