// Full data cube: the static reduction computed from the cube (beamforming +
// Doppler DTFT at the static velocity of each beam, README "Data cube") equals
// the directly synthesised spectrum.
#include <gtest/gtest.h>

#include <cmath>
#include <complex>

#include "polmap/radar/static_reduction.hpp"
#include "polmap/sim/spectrum.hpp"
#include "sim_test_util.hpp"

namespace polmap::sim {
namespace {

using test::kDeg;

/// The largest |LL| + |LR| of the spectrum's cells.
double peak_amplitude(const PolSpectrum& sp) {
  double peak = 0;
  for (const auto& c : sp.cells)
    peak = std::max(peak, static_cast<double>(std::abs(c.s[0]) + std::abs(c.s[1])));
  return peak;
}

/// Polarisation channel pol of range bin r of the cube, beamformed towards sin_phi (the
/// simulator's taper over the virtual channels) and Doppler-processed at v_mps (a Hann
/// window over the chirps; v_ua_mps: unambiguous velocity), normalised by the window sum.
std::complex<double> beamformed(const DataCube& cube, int pol, int r, double sin_phi, double v_mps,
                                double v_ua_mps) {
  const int nr = cube.num_range_bins, nv = cube.num_virtual_channels, nc = cube.num_chirps;
  std::complex<double> acc = 0;
  double sw = 0;
  for (int v = 0; v < nv; ++v) {
    const double x = (v - 0.5 * (nv - 1)) / (nv - 1);
    const double wv = 0.7 + 0.3 * std::cos(M_PI * x) * std::cos(M_PI * x);
    for (int c = 0; c < nc; ++c) {
      const double wc = std::pow(std::sin(M_PI * (c + 0.5) / nc), 2);
      const double ph = -2 * M_PI * 0.5 * (v - 0.5 * (nv - 1)) * sin_phi +
                        M_PI * v_mps * (c - 0.5 * (nc - 1)) / v_ua_mps;
      const std::complex<double> d(
          cube.data[((static_cast<std::size_t>(pol) * nv + v) * nc + c) * nr + r]);
      acc += wv * wc * std::polar(1.0, ph) * d;
      sw += wv * wc;
    }
  }
  return acc / sw;
}

TEST(Cube, StaticReductionOfCubeMatchesDirectSpectrum) {
  auto w = test::empty_world(200);
  test::add_point(*w, {3.7 + 6.0, 1.2}, odd_bounce(), 0.0);
  test::add_point(*w, {3.7 + 4.0, -2.5}, dihedral(0.4), 5.0);
  w->build_index();
  SimConfig cfg = test::noise_free_config();
  cfg.radar.cube_max_range_m = 8.0;
  FrameRenderer rend(w, cfg);
  const ExactState st = test::state_at(0, 0, 0, 7.0, 0.1);
  const SensorMount& m = cfg.sensors[0];
  const SensorFrame f = rend.render(m, st, nullptr, 0, true, 3);
  ASSERT_TRUE(f.cube.has_value());
  const DataCube& cube = *f.cube;
  const int nr = cube.num_range_bins, nv = cube.num_virtual_channels, nc = cube.num_chirps;
  EXPECT_EQ(nv, 31);
  EXPECT_EQ(nc, 64);
  EXPECT_EQ(nr, 108);
  EXPECT_NEAR(cube.chirp_interval_s, 299792458.0 / 78e9 / 20.0, 1e-9);
  ASSERT_EQ(cube.data.size(), static_cast<std::size_t>(4) * nv * nc * nr);

  // Static velocity of each beam from the sensor velocity v_s = (v - w y_m, w x_m).
  const Eigen::Vector2d vs(st.v_mps - st.yaw_rate_rps * m.T_vehicle_sensor.y_m,
                           st.yaw_rate_rps * m.T_vehicle_sensor.x_m);
  const double v_ua = 5.0;
  const double peak = peak_amplitude(f.spectrum);
  ASSERT_GT(peak, 100.0);
  int compared = 0;
  for (const auto& cell : f.spectrum.cells) {
    if (cell.range_bin >= nr) continue;
    const double strength =
        std::max({std::abs(cell.s[0]), std::abs(cell.s[1]), std::abs(cell.s[3])});
    if (strength < 0.2 * peak) continue;
    const double phi = (-60.0 + 1.5 * cell.azimuth_bin) * kDeg;
    const double v_static = -(vs.x() * std::cos(phi) + vs.y() * std::sin(phi));
    for (int p = 0; p < 4; ++p) {
      const std::complex<double> acc =
          beamformed(cube, p, cell.range_bin, std::sin(phi), v_static, v_ua);
      EXPECT_LT(std::abs(acc - std::complex<double>(cell.s[p])), 0.01 * peak)
          << "cell r=" << cell.range_bin << " b=" << cell.azimuth_bin << " pol " << p;
    }
    ++compared;
  }
  EXPECT_GT(compared, 6);
}

TEST(Cube, RadarStaticReductionReproducesDirectSpectrum) {
  // Cross-module check: radar::static_reduce (the processing) on the simulated cube gives
  // the simulator's direct spectrum (side sensor, moving and turning).
  auto w = test::empty_world(200);
  test::add_point(*w, {3.5 + 5.0, 5.5}, odd_bounce(), 0.0);
  test::add_point(*w, {3.5 + 7.0, 3.0}, dihedral(1.1), 3.0);
  w->build_index();
  SimConfig cfg = test::noise_free_config();
  cfg.radar.cube_max_range_m = 10.0;
  FrameRenderer rend(w, cfg);
  const ExactState st = test::state_at(0, 0, 0, 9.0, -0.2);
  const SensorMount& m = cfg.sensors[1];  // front_left, +40 deg
  const SensorFrame f = rend.render(m, st, nullptr, 0, true, 3);
  radar::StaticReductionConfig rc;
  rc.azimuth_bins_rad = f.spectrum.azimuth_bins_rad;
  rc.noise_sigma = 1.0;
  rc.floor_sigmas = 0.0;
  const PolSpectrum red = radar::static_reduce(*f.cube, m, st.v_mps, st.yaw_rate_rps, rc);
  const double peak = peak_amplitude(f.spectrum);
  ASSERT_GT(peak, 100.0);
  int compared = 0;
  for (const auto& cell : f.spectrum.cells) {
    if (cell.range_bin >= red.num_range_bins) continue;
    if (std::max({std::abs(cell.s[0]), std::abs(cell.s[1]), std::abs(cell.s[3])}) < 0.2 * peak)
      continue;
    const SpectrumCell& r =
        red.cells[static_cast<std::size_t>(cell.azimuth_bin) * red.num_range_bins + cell.range_bin];
    ASSERT_EQ(r.range_bin, cell.range_bin);
    ASSERT_EQ(r.azimuth_bin, cell.azimuth_bin);
    for (int p = 0; p < 4; ++p) EXPECT_LT(std::abs(r.s[p] - cell.s[p]), 0.01 * peak);
    ++compared;
  }
  EXPECT_GT(compared, 6);
}

TEST(Cube, NoiseIsScaledToTheSpectrumNoiseAfterProcessing) {
  auto w = test::empty_world(200);
  w->build_index();
  SimConfig cfg = test::quiet_config();
  cfg.radar.cube_max_range_m = 3.0;
  FrameRenderer rend(w, cfg);
  const SensorFrame f =
      rend.render(cfg.sensors[0], test::state_at(0, 0, 0, 0.0), nullptr, 0, true, 9);
  const DataCube& cube = *f.cube;
  // Beamform (boresight) + Doppler at 0 m/s over many range bins / pols: processed
  // variance ~ sigma^2 = 1.
  double acc2 = 0;
  int n = 0;
  for (int p = 0; p < 4; ++p) {
    for (int r = 0; r < cube.num_range_bins; ++r) {
      acc2 += std::norm(beamformed(cube, p, r, 0.0, 0.0, 5.0));
      ++n;
    }
  }
  EXPECT_NEAR(acc2 / n, 1.0, 0.35);
}

}  // namespace
}  // namespace polmap::sim
