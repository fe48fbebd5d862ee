// Drive plans and the record stream of a whole drive.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>

#include "polmap/sim/drive_simulator.hpp"
#include "sim_test_util.hpp"

namespace polmap::sim {
namespace {

TEST(Drive, UrbanStreamIsTimeOrderedAndPlausible) {
  SimConfig cfg;
  auto world = load_world("urban", 300.0, 1, cfg);
  DriveSimulator sim(world, cfg, 0);
  double last_t = -1;
  int traj = 0, frames = 0;
  std::size_t cells = 0, dets = 0;
  const auto t0 = std::chrono::steady_clock::now();
  while (auto rec = sim.next()) {
    if (const auto* s = std::get_if<TrajectorySample>(&*rec)) {
      EXPECT_GE(s->time_s, last_t);
      last_t = s->time_s;
      ++traj;
    } else {
      const auto& f = std::get<SensorFrame>(*rec);
      EXPECT_GE(f.time_s, last_t);
      last_t = f.time_s;
      ++frames;
      cells += f.spectrum.cells.size();
      dets += f.detections.size();
      EXPECT_LE(f.detections.size(), 800U);
      for (std::size_t i = 1; i < f.spectrum.cells.size(); ++i) {
        const auto& a = f.spectrum.cells[i - 1];
        const auto& b = f.spectrum.cells[i];
        ASSERT_TRUE(a.azimuth_bin < b.azimuth_bin ||
                    (a.azimuth_bin == b.azimuth_bin && a.range_bin < b.range_bin));
      }
    }
  }
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double dur = sim.duration_s();
  std::printf(
      "urban 300 m: %.1f s simulated in %.2f s wall (%.1fx), %d frames, %.0f cells/frame, "
      "%.0f detections/frame\n",
      dur, wall, dur / wall, frames, double(cells) / frames, double(dets) / frames);
  EXPECT_GT(dur, 20.0);
  EXPECT_NEAR(traj, dur * cfg.gnss.rate_hz, 2.0);
  EXPECT_NEAR(frames, dur * 30.0, 4.0);
}

/// Distance from p to the nearest object geometry of the world (points and polylines).
double distance_to_objects(const World& w, const Eigen::Vector2d& p) {
  double best = 1e9;
  for (const auto& o : w.objects) {
    const auto& g = o.geometry_m;
    if (g.size() == 1) {
      best = std::min(best, (g[0] - p).norm());
      continue;
    }
    for (std::size_t i = 1; i < g.size(); ++i) {
      const Eigen::Vector2d e = g[i] - g[i - 1];
      const double t =
          std::clamp((p - g[i - 1]).dot(e) / std::max(e.squaredNorm(), 1e-12), 0.0, 1.0);
      best = std::min(best, (g[i - 1] + t * e - p).norm());
    }
  }
  return best;
}

TEST(Drive, StrongSpectrumCellsLieOnWorldObjects) {
  // Geometry chain check: sensor mounts, azimuth sign, range, world frame. Strong cells
  // mapped through the exact pose must sit on truth objects (cars are 4.5 x 1.8 boxes whose
  // centre is the truth point, hence the 2.6 m allowance for them).
  SimConfig cfg;
  cfg.duration_s = 8.0;
  cfg.traffic.oncoming_per_km_urban = 0.0;
  auto world = load_world("urban", 400.0, 2, cfg);
  DriveSimulator sim(world, cfg, 0);
  int strong = 0, on_object = 0;
  while (auto rec = sim.next()) {
    const auto* f = std::get_if<SensorFrame>(&*rec);
    if (f == nullptr || f->cycle_index % 10 != 0) continue;
    const ExactState st = sim.plan().state(f->time_s);
    const SensorMount& m = cfg.sensors[f->sensor_id];
    const Pose2 T_ws = Pose2{st.x_m, st.y_m, st.yaw_rad} * m.T_vehicle_sensor;
    for (const auto& c : f->spectrum.cells) {
      double p = 0;
      for (const auto& v : c.s) p += std::norm(v);
      if (p < 1000.0) continue;  // > ~27 dB: echoes, not noise or clutter
      const double r = c.range_bin * f->spectrum.range_bin_m;
      const double az = f->spectrum.azimuth_bins_rad[c.azimuth_bin];
      const Eigen::Vector2d pw = T_ws * Eigen::Vector2d(r * std::cos(az), r * std::sin(az));
      ++strong;
      // Beam spacing and width: allow r * 2 deg across plus the car box.
      on_object += distance_to_objects(*world, pw) < 0.3 + r * 0.035 + 2.6;
    }
  }
  ASSERT_GT(strong, 100);
  EXPECT_GT(static_cast<double>(on_object) / strong, 0.97) << on_object << " of " << strong;
}

}  // namespace
}  // namespace polmap::sim
