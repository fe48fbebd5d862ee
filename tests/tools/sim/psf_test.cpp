// Point spread, radar equation, floor and noise statistics of the spectrum.
#include <gtest/gtest.h>

#include <cmath>

#include "polmap/sim/spectrum.hpp"
#include "sim_test_util.hpp"

namespace polmap::sim {
namespace {

using test::kDeg;

/// Full -3 dB width (power) of a symmetric response f(x), by bisection from the peak.
template <typename F>
double minus3db_width(F f, double hi) {
  double lo = 0.0;
  for (int i = 0; i < 80; ++i) {
    const double m = 0.5 * (lo + hi);
    if (f(m) * f(m) > 0.5) {
      lo = m;
    } else {
      hi = m;
    }
  }
  return 2.0 * lo;
}

TEST(Psf, RangeResponseIsHannWith1_5BinWidth) {
  EXPECT_DOUBLE_EQ(SpectrumSynthesizer::range_response(0.0), 1.0);
  EXPECT_NEAR(SpectrumSynthesizer::range_response(1.0), 0.5, 1e-9);
  EXPECT_NEAR(SpectrumSynthesizer::range_response(2.0), 0.0, 1e-9);
  const double w =
      minus3db_width([](double x) { return SpectrumSynthesizer::range_response(x); }, 1.0);
  // Hann: 1.44 bins = 10.8 cm at 7.5 cm bins (tools/sim/README.md: ~1.5 dr).
  EXPECT_NEAR(w, 1.44, 0.02);
  // Brute force: the DTFT of a Hann-windowed tone over N = 256 samples agrees.
  const int n = 256;
  for (double x : {0.3, 0.7, 1.2, 1.6}) {
    std::complex<double> s = 0, s0 = 0;
    for (int k = 0; k < n; ++k) {
      const double wv = 0.5 - 0.5 * std::cos(2 * M_PI * (k + 0.5) / n);
      s += wv * std::polar(1.0, 2 * M_PI * x * (k - 0.5 * (n - 1)) / n);
      s0 += wv;
    }
    EXPECT_NEAR(std::abs(s / s0), std::abs(SpectrumSynthesizer::range_response(x)), 2e-3) << x;
  }
}

TEST(Psf, BeamIsAbout3DegAtBoresightAndWidensAsOneOverCos) {
  const SimConfig cfg;
  const SpectrumSynthesizer s(cfg.radar, RadarSpec{});
  const double wu = minus3db_width([&](double du) { return s.beam_response(du); }, 0.2);
  const double w0_deg = wu / kDeg;  // at boresight d(sin phi) = d phi
  EXPECT_GT(w0_deg, 2.9);
  EXPECT_LT(w0_deg, 3.6);
  // At phi = 45 deg the beam in angle is wider by 1/cos(45 deg).
  const double phi = 45 * kDeg;
  // Asymmetric in angle off boresight: add the two half widths.
  const double w45 =
      0.5 * minus3db_width(
                [&](double d) { return s.beam_response(std::sin(phi + d) - std::sin(phi)); }, 0.2) +
      0.5 * minus3db_width(
                [&](double d) { return s.beam_response(std::sin(phi - d) - std::sin(phi)); }, 0.2);
  EXPECT_NEAR(w45 / (w0_deg * kDeg), 1.0 / std::cos(phi), 0.02);
  // Brute force array factor of the taper: 31 elements at lambda/2.
  const int n = cfg.radar.array_elements;
  for (double du : {0.01, 0.03, 0.05}) {
    double num = 0, den = 0;
    for (int i = 0; i < n; ++i) {
      const double x = (i - 0.5 * (n - 1)) / (n - 1);
      const double w = 0.7 + 0.3 * std::cos(M_PI * x) * std::cos(M_PI * x);
      num += w * std::cos(M_PI * (i - 0.5 * (n - 1)) * du);
      den += w;
    }
    EXPECT_NEAR(s.beam_response(du), num / den, 1e-4);
  }
  EXPECT_EQ(s.num_beams(), 81);
  EXPECT_EQ(s.num_range_bins(), 1067);
}

TEST(Psf, RenderedPointTargetFollowsRadarEquationAndPsf) {
  // Noise-free so amplitudes are exact; target centred on a range bin and a beam.
  auto w = test::empty_world();
  const double r = 30.0;
  test::add_point(*w, {3.7 + r, 0.0}, odd_bounce(), 0.0);
  w->build_index();
  const SimConfig cfg = test::noise_free_config();
  FrameRenderer rend(w, cfg);
  const SensorFrame f = test::render_standing_at_origin(rend, cfg);
  const int rb = static_cast<int>(std::lround(r / 0.075));
  const int b0 = 40;  // boresight beam
  auto lr_power = [&](int rbin, int beam) {
    for (const auto& c : f.spectrum.cells) {
      if (c.range_bin == rbin && c.azimuth_bin == beam)
        return static_cast<double>(std::norm(c.s[1]));
    }
    return 0.0;
  };
  const double snr = std::pow(10.0, (20.0 + 0.0 - 40.0 * std::log10(r / 50.0)) / 10.0);
  EXPECT_NEAR(lr_power(rb, b0) / snr, 1.0, 1e-3);
  // Neighbouring range bin: W(1)^2 = 0.25; neighbouring beam: AF(sin 1.5deg)^2.
  EXPECT_NEAR(lr_power(rb + 1, b0) / snr, 0.25, 0.01);
  EXPECT_NEAR(lr_power(rb - 1, b0) / snr, 0.25, 0.01);
  const double af = rend.synthesizer().beam_response(std::sin(1.5 * kDeg));
  EXPECT_NEAR(lr_power(rb, b0 + 1) / snr, af * af, 0.01);
  EXPECT_NEAR(lr_power(rb, b0 - 1) / snr, af * af, 0.01);
}

TEST(Psf, NoiseOnlyCellsRespectTheFloorAndNoiseSigma) {
  // An empty world: the stored cells are floor exceedances of noise + clutter only.
  auto w = test::empty_world();
  w->build_index();
  SimConfig cfg = test::quiet_config();
  cfg.radar.ground_clutter = false;
  FrameRenderer rend(w, cfg);
  double n_cells = 0, frames = 200, above = 0;
  for (int k = 0; k < frames; ++k) {
    const SensorFrame f =
        rend.render(cfg.sensors[0], test::state_at(0, 0, 0, 5.0), nullptr, k, false, 100 + k);
    n_cells += f.spectrum.cells.size();
    for (const auto& c : f.spectrum.cells) {
      double m = 0;
      for (const auto& v : c.s) m = std::max(m, static_cast<double>(std::norm(v)));
      EXPECT_GT(m, 9.0);  // (3 sigma)^2
      above += m;
    }
  }
  // Expected exceedances: cells * 4 channels * exp(-9).
  const double expected = 1067.0 * 81 * 4 * std::exp(-9.0);
  EXPECT_NEAR(n_cells / frames, expected, 0.15 * expected);
  // Memoryless tail: mean of the exceeding channel's power is 9 + 1 (sigma = 1).
  EXPECT_NEAR(above / n_cells, 10.0, 0.3);
}

}  // namespace
}  // namespace polmap::sim
