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
  std::printf("urban 300 m: %.1f s simulated in %.2f s wall (%.1fx), %d frames, %.0f cells/frame, "
              "%.0f detections/frame\n",
              dur, wall, dur / wall, frames, double(cells) / frames, double(dets) / frames);
  EXPECT_GT(dur, 20.0);
  EXPECT_NEAR(traj, dur * cfg.gnss.rate_hz, 2.0);
  EXPECT_NEAR(frames, dur * 30.0, 4.0);
}

}  // namespace
}  // namespace polmap::sim
