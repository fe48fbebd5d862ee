// The ego-motion's side-slip model (EgoMotionConfig::side_slip_gradient_rad_per_mps2): on a
// simulated drive whose vehicle slips in curves (β = −k·a_y, the simulator's realism slip
// source), the kinematic model reads the rear axle's lateral velocity as yaw rate; with
// the vehicle's gradient the yaw-rate error in curves falls to that of a drive without
// slip, and on a drive without slip the gradient 0 changes nothing.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "polmap/radar/egomotion.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/realism.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::radar {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

struct Drive {
  std::vector<SensorMount> mounts;
  std::vector<SensorFrame> frames;
  std::vector<sim::ExactState> truth;
  double gradient_rad = 0.0;
};

Drive simulate(bool slip) {
  sim::SimConfig cfg;
  cfg.seed = 5;
  cfg.duration_s = 45.0;
  if (slip) {
    cfg.realism = sim::only_sources(sim::realism_preset("realistic"), "slip");
  }
  auto world = sim::load_world("urban", 800.0, cfg.seed, cfg);
  sim::DriveSimulator simulator(world, cfg, 0);
  Drive d;
  d.mounts = simulator.header().sensors;
  while (auto rec = simulator.next()) {
    if (auto* f = std::get_if<SensorFrame>(&*rec)) {
      f->spectrum.cells.clear();
      d.frames.push_back(std::move(*f));
    }
  }
  d.truth = simulator.exact_trajectory();
  d.gradient_rad = cfg.realism.slip.side_slip_gradient_deg_per_mps2 * kDeg;
  return d;
}

/// RMS of the yaw-rate error (°/s) over estimates with |true lateral acceleration| > 1 m/s².
double curve_yaw_rate_rms_dps(const Drive& d, double gradient_rad) {
  EgoMotionConfig cfg;
  cfg.side_slip_gradient_rad_per_mps2 = gradient_rad;
  EgoMotionEstimator est(d.mounts, cfg);
  double se = 0.0;
  int n = 0;
  std::size_t j = 0;
  for (const SensorFrame& f : d.frames) {
    const MotionEstimate m = est.process(f);
    if (m.status != MotionEstimate::Status::Ok) continue;
    while (j + 1 < d.truth.size() && d.truth[j + 1].time_s <= m.time_s) ++j;
    const sim::ExactState& s = d.truth[j];
    if (std::abs(s.v_mps * s.yaw_rate_rps) < 1.0) continue;
    const double e = (m.yaw_rate_rps - s.yaw_rate_rps) / kDeg;
    se += e * e;
    ++n;
  }
  EXPECT_GT(n, 30) << "curves in the drive";
  return n > 0 ? std::sqrt(se / n) : 0.0;
}

TEST(EgoMotionSideSlip, TheVehiclesGradientRemovesTheYawRateErrorSlipCausesInCurves) {
  static const Drive plain = simulate(false);
  static const Drive slipping = simulate(true);
  const double baseline = curve_yaw_rate_rms_dps(plain, 0.0);
  const double unmodelled = curve_yaw_rate_rms_dps(slipping, 0.0);
  const double modelled = curve_yaw_rate_rms_dps(slipping, slipping.gradient_rad);
  std::printf("curve yaw-rate RMS: no slip %.3f °/s, slip unmodelled %.3f, modelled %.3f\n",
              baseline, unmodelled, modelled);
  EXPECT_GT(unmodelled, 2.0 * baseline);       // slip reads as yaw rate
  EXPECT_LT(modelled, 1.5 * baseline + 0.05);  // the model takes it out
  EXPECT_LT(modelled, 0.6 * unmodelled);
}

}  // namespace
}  // namespace polmap::radar
