#pragma once
// Helpers shared by the simulator tests: tiny hand-made worlds.
#include <cmath>
#include <memory>
#include <numbers>
#include <utility>
#include <vector>

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

/// Adds an object of class cls with the given geometry and RCS, without scattering centres.
inline std::uint32_t add_object(World& w, ObjectClass cls, std::vector<Eigen::Vector2d> geometry_m,
                                double rcs_dbsm = 0.0) {
  WorldObject o;
  o.cls = cls;
  o.geometry_m = std::move(geometry_m);
  o.rcs_dbsm = rcs_dbsm;
  return w.add_object(std::move(o));
}

/// Adds a point object at xy with the given scattering vector and RCS.
inline std::uint32_t add_point(World& w, const Eigen::Vector2d& xy, const ScatteringVector& omega,
                               double rcs_dbsm, ObjectClass cls = ObjectClass::Pole) {
  const std::uint32_t id = add_object(w, cls, {xy}, rcs_dbsm);
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

/// quiet_config() without thermal noise: exact amplitudes.
inline SimConfig noise_free_config() {
  SimConfig c = quiet_config();
  c.radar.thermal_noise = false;
  return c;
}

/// The frame of cfg's first sensor on a vehicle standing at the origin heading +x
/// (no plan, no cube, frame seed 1).
inline SensorFrame render_standing_at_origin(FrameRenderer& rend, const SimConfig& cfg) {
  return rend.render(cfg.sensors[0], state_at(0, 0, 0, 0.0), nullptr, 0, false, 1);
}

/// Indexes w and renders its noise-free render_standing_at_origin frame.
inline SensorFrame render_noise_free_at_origin(const std::shared_ptr<World>& w) {
  w->build_index();
  const SimConfig cfg = noise_free_config();
  FrameRenderer rend(w, cfg);
  return render_standing_at_origin(rend, cfg);
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
