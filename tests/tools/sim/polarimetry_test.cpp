// Polarimetric conventions of the simulator (sim/scattering.hpp) and what isolated
// odd / even scatterers look like in the rendered spectrum.
#include <gtest/gtest.h>

#include <cmath>
#include <complex>

#include "polmap/sim/scattering.hpp"
#include "sim_test_util.hpp"

namespace polmap::sim {
namespace {

using test::kDeg;
constexpr cdouble kJ{0.0, 1.0};

TEST(Polarimetry, OddBounceIsLrOnly) {
  const ScatteringVector o = odd_bounce();
  EXPECT_NEAR(std::abs(o[0]), 0.0, 1e-12);
  EXPECT_NEAR(std::abs(o[3]), 0.0, 1e-12);
  EXPECT_NEAR(std::abs(o[1] - kJ), 0.0, 1e-12);
  EXPECT_NEAR(std::abs(o[2] - kJ), 0.0, 1e-12);
  EXPECT_NEAR(half_span(o), 1.0, 1e-12);
}

TEST(Polarimetry, DihedralPhasesArePlusMinusTwoTheta) {
  for (double theta : {0.0, 10.0, 30.0, 45.0, 77.0, 90.0, 135.0}) {
    const ScatteringVector o = dihedral(theta * kDeg);
    const cdouble ll = std::polar(1.0, 2.0 * theta * kDeg);
    const cdouble rr = -std::polar(1.0, -2.0 * theta * kDeg);
    EXPECT_NEAR(std::abs(o[0] - ll), 0.0, 1e-12) << theta;
    EXPECT_NEAR(std::abs(o[3] - rr), 0.0, 1e-12) << theta;
    EXPECT_NEAR(std::abs(o[1]), 0.0, 1e-12);
    EXPECT_NEAR(std::abs(o[2]), 0.0, 1e-12);
  }
}

TEST(Polarimetry, LinearRoundTrip) {
  Rng rng(3);
  for (int k = 0; k < 50; ++k) {
    const cdouble hh = rng.cnormal(), hv = rng.cnormal(), vv = rng.cnormal();
    const auto lin = linear_from_lr(lr_from_linear(hh, hv, vv));
    EXPECT_NEAR(std::abs(lin[0] - hh), 0.0, 1e-12);
    EXPECT_NEAR(std::abs(lin[1] - hv), 0.0, 1e-12);
    EXPECT_NEAR(std::abs(lin[2] - vv), 0.0, 1e-12);
  }
}

TEST(Polarimetry, VolumeModelIsDiagonalReflectionSymmetric) {
  const DistributedModel m = DistributedModel::volume();
  Rng rng(11);
  Eigen::Matrix4cd c = Eigen::Matrix4cd::Zero();
  const int n = 200000;
  double span = 0;
  for (int k = 0; k < n; ++k) {
    const ScatteringVector s = m.sample(rng);
    Eigen::Vector4cd v(s[0], s[1], s[2], s[3]);
    c += v * v.adjoint();
    span += half_span(s);
  }
  c /= n;
  EXPECT_NEAR(span / n, 1.0, 0.02);
  // Equal channel powers (2/3 each for random dipoles), LL-RR and LL-LR uncorrelated.
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(c(i, i).real(), 0.5, 0.02);
  EXPECT_NEAR(std::abs(c(0, 3)), 0.0, 0.02);
  EXPECT_NEAR(std::abs(c(0, 1)), 0.0, 0.02);
  EXPECT_NEAR(std::abs(c(1, 2) - c(1, 1)), 0.0, 0.02);  // LR == RL (reciprocity)
  const auto expected = m.channel_power();
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(c(i, i).real(), expected[i], 0.03);
}

/// Renders one frame of a world with a single point scatterer 20 m ahead.
SensorFrame render_single(const ScatteringVector& omega, double rcs, std::uint64_t seed = 5) {
  auto w = test::empty_world();
  test::add_point(*w, {3.7 + 20.0, 0.0}, omega, rcs);
  w->build_index();
  SimConfig cfg = test::quiet_config();
  FrameRenderer r(w, cfg);
  return r.render(cfg.sensors[0], test::state_at(0, 0, 0, 0.0), nullptr, 0, false, seed);
}

TEST(Polarimetry, IsolatedPoleShowsInLrRlNotLlRr) {
  const SensorFrame f = render_single(odd_bounce(), 5.0);
  const SpectrumCell* c = test::peak_cell(f.spectrum);
  ASSERT_NE(c, nullptr);
  EXPECT_NEAR(c->range_bin * 0.075, 20.0, 0.08);
  const double lr = std::norm(c->s[1]), rl = std::norm(c->s[2]);
  const double ll = std::norm(c->s[0]), rr = std::norm(c->s[3]);
  // SNR = 20 + 5 - 40 log10(20/50) = 40.9 dB; LL/RR only noise (sigma = 1).
  EXPECT_GT(10 * std::log10(lr), 38.0);
  EXPECT_GT(10 * std::log10(rl), 38.0);
  EXPECT_LT(ll, 30.0);
  EXPECT_LT(rr, 30.0);
  // LR and RL carry the same complex value (reciprocity) up to noise.
  EXPECT_LT(std::abs(c->s[1] - c->s[2]) / std::abs(c->s[1]), 0.05);
}

TEST(Polarimetry, DihedralShowsInLlRrWithPlusMinusTwoTheta) {
  for (double theta_deg : {0.0, 20.0, 60.0, 100.0}) {
    const double th = theta_deg * kDeg;
    const SensorFrame f = render_single(dihedral(th), 10.0, 7);
    const SpectrumCell* c = test::peak_cell(f.spectrum);
    ASSERT_NE(c, nullptr);
    const double ll = std::norm(c->s[0]), rr = std::norm(c->s[3]);
    EXPECT_GT(10 * std::log10(ll), 40.0);
    EXPECT_GT(10 * std::log10(rr), 40.0);
    EXPECT_LT(std::norm(c->s[1]), 30.0);
    EXPECT_LT(std::norm(c->s[2]), 30.0);
    // The common (carrier, PSF) factor cancels in LL * conj(RR) = -e^{j4θ} |a|^2, and
    // LL / e^{j2θ} and RR / (-e^{-j2θ}) carry the same phase.
    const std::complex<double> lld(c->s[0]), rrd(c->s[3]);
    const double want = std::arg(-std::polar(1.0, 4.0 * th));
    EXPECT_NEAR(std::abs(wrap_angle_rad(std::arg(lld * std::conj(rrd)) - want)), 0.0, 0.02);
    const double common_ll = std::arg(lld / std::polar(1.0, 2.0 * th));
    const double common_rr = std::arg(rrd / -std::polar(1.0, -2.0 * th));
    EXPECT_NEAR(std::abs(wrap_angle_rad(common_ll - common_rr)), 0.0, 0.02) << theta_deg;
  }
}

}  // namespace
}  // namespace polmap::sim
