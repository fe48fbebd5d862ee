// Static reduction of a synthetic data cube (recording.hpp DataCube convention,
// tools/sim/README.md): a static scatterer comes back with its complex amplitude
// in the right beam and range bin for every polarization; a moving one is
// suppressed by the Doppler mismatch.
#include "polmap/radar/static_reduction.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

struct Echo {
  int range_bin;
  double azimuth_rad;
  double radial_velocity_mps;
  std::array<cdouble, 4> a;
};

DataCube make_cube(const RadarSpec& spec, const std::vector<Echo>& echoes) {
  DataCube cube;
  cube.num_range_bins = 40;
  cube.num_chirps = 64;
  cube.num_virtual_channels = 31;
  cube.range_bin_m = 0.075;
  cube.element_spacing_wavelengths = 0.5;
  const double v_ua = spec.v_unambiguous_mps;
  cube.chirp_interval_s = spec.wavelength_m() / (4.0 * v_ua);
  const int R = cube.num_range_bins, C = cube.num_chirps, V = cube.num_virtual_channels;
  cube.data.assign(static_cast<std::size_t>(4) * V * C * R, cfloat(0.0F, 0.0F));
  for (const Echo& e : echoes) {
    for (int p = 0; p < 4; ++p) {
      for (int v = 0; v < V; ++v) {
        for (int c = 0; c < C; ++c) {
          const double ph =
              2.0 * std::numbers::pi * 0.5 * (v - 0.5 * (V - 1)) * std::sin(e.azimuth_rad) -
              std::numbers::pi * e.radial_velocity_mps * (c - 0.5 * (C - 1)) / v_ua;
          const cdouble x = e.a[p] * std::polar(1.0, ph);
          cube.data[((static_cast<std::size_t>(p) * V + v) * C + c) * R + e.range_bin] +=
              cfloat(static_cast<float>(x.real()), static_cast<float>(x.imag()));
        }
      }
    }
  }
  return cube;
}

TEST(StaticReduction, RecoversStaticScattererAndSuppressesMovingOne) {
  SensorMount mount{1, "front_left", {3.5, 0.75, 40.0 * kDeg}, 0.033, {}};
  const double v = 12.0, w = 0.2;
  StaticReductionConfig cfg;
  cfg.noise_sigma = 0.01;
  cfg.floor_sigmas = 0.0;  // keep every cell
  // Beams: default 81 at 1.5°; put the echoes on beam centres 30 and 60.
  const double az_static = (-60.0 + 1.5 * 30) * kDeg, az_moving = (-60.0 + 1.5 * 60) * kDeg;
  const double vr_static = static_radial_velocity(mount, v, w, az_static);
  const double vr_moving = static_radial_velocity(mount, v, w, az_moving) + 2.0;
  const std::array<cdouble, 4> a_static{cdouble(0.3, 0.1), cdouble(0.0, 2.0), cdouble(0.1, 1.9),
                                        cdouble(-0.2, 0.4)};
  const std::array<cdouble, 4> a_moving{cdouble(5.0, 0.0), cdouble(5.0, 0.0), cdouble(5.0, 0.0),
                                        cdouble(5.0, 0.0)};
  // Static: aliased radial velocity (the cube only sees it modulo 2 v_ua).
  ASSERT_GT(std::abs(vr_static), 5.0);
  const DataCube cube = make_cube(
      mount.spec, {{12, az_static, vr_static, a_static}, {25, az_moving, vr_moving, a_moving}});
  const PolSpectrum s = static_reduce(cube, mount, v, w, cfg);
  ASSERT_EQ(s.azimuth_bins_rad.size(), 81U);
  EXPECT_NEAR(s.azimuth_bins_rad[30], az_static, 1e-6);
  ASSERT_EQ(s.cells.size(), 81U * 40U);
  auto cell = [&](int beam, int bin) -> const SpectrumCell& {
    return s.cells[static_cast<std::size_t>(beam) * 40 + bin];
  };
  for (int p = 0; p < 4; ++p) {
    const cdouble got(cell(30, 12).s[p].real(), cell(30, 12).s[p].imag());
    EXPECT_LT(std::abs(got - a_static[p]), 1e-3 * std::abs(a_static[1])) << "pol " << p;
    // Moving echo: at least 30 dB down (Hann sidelobes beyond 2 Doppler bins).
    EXPECT_LT(std::norm(cell(60, 25).s[p]), 1e-3 * std::norm(a_moving[p])) << "pol " << p;
  }
  // Neighbouring beams see less of the static echo (beam pattern), other ranges nothing.
  EXPECT_LT(std::norm(cell(32, 12).s[1]), 0.5 * std::norm(a_static[1]));
  EXPECT_LT(std::norm(cell(30, 14).s[1]), 1e-6);
}

TEST(StaticReduction, FloorDropsNoiseCellsAndEstimatesSigma) {
  SensorMount mount{0, "front_center", {3.7, 0.0, 0.0}, 0.0, {}};
  std::vector<Echo> echoes{{20,
                            0.0,
                            static_radial_velocity(mount, 5.0, 0.0, 0.0),
                            {cdouble(0, 0), cdouble(0, 10), cdouble(0, 10), cdouble(0, 0)}}};
  DataCube cube = make_cube(mount.spec, echoes);
  // Add white noise of σ_cube so the reduced noise is about σ_cube·sqrt(ρ_v ρ_c) small.
  std::mt19937 rng(1);
  std::normal_distribution<float> n(0.0F, 0.5F);
  for (auto& x : cube.data) x += cfloat(n(rng), n(rng));
  StaticReductionConfig cfg;  // estimate σ, floor 3σ
  const PolSpectrum s = static_reduce(cube, mount, 5.0, 0.0, cfg);
  EXPECT_GT(s.noise_sigma, 0.0F);
  EXPECT_LT(s.cells.size(), 81U * 40U / 10U);
  bool found = false;
  for (const auto& c : s.cells) {
    if (c.azimuth_bin == 40 && c.range_bin == 20) {
      found = true;
      EXPECT_NEAR(std::abs(c.s[1]), 10.0, 0.5);
    }
  }
  EXPECT_TRUE(found);
}

TEST(StaticReduction, InconsistentCubeIsRejected) {
  DataCube cube;
  cube.num_range_bins = 4;
  cube.num_chirps = 4;
  cube.num_virtual_channels = 4;
  cube.chirp_interval_s = 1e-4;
  cube.data.resize(10);
  EXPECT_THROW(static_reduce(cube, SensorMount{}, 1.0, 0.0), ValidationError);
}

}  // namespace
}  // namespace polmap::radar
