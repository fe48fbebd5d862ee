// Polarimetric conventions: LR <-> HV transforms (polarimetry.hpp), unitary Pauli-like
// reductions, covariance transforms C' = A C A^H, partial levels and the scattering
// class from a covariance.
#include "polmap/radar/polarimetry.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <random>

namespace polmap::radar {
namespace {

const cdouble kJ(0.0, 1.0);

ScatteringVector random_reciprocal(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  const cdouble lr(n(rng), n(rng));
  return {cdouble(n(rng), n(rng)), lr, lr, cdouble(n(rng), n(rng))};
}

TEST(Polarimetry, LrHvRoundTripIsIdentity) {
  std::mt19937 rng(1);
  for (int i = 0; i < 20; ++i) {
    const ScatteringVector o = random_reciprocal(rng);
    const ScatteringVector back = lr_from_hv(hv_from_lr(o));
    for (int c = 0; c < 4; ++c) EXPECT_LT(std::abs(back[c] - o[c]), 1e-12);
  }
  const Eigen::Matrix3cd u = pauli_lr_from_hv();
  EXPECT_LT((u * u.adjoint() - Eigen::Matrix3cd::Identity()).norm(), 1e-12);
  EXPECT_LT((pauli_hv_from_lr() * u - Eigen::Matrix3cd::Identity()).norm(), 1e-12);
}

TEST(Polarimetry, CanonicalMechanismsFollowTheConvention) {
  // Odd bounce (sphere, pole): HH = VV = 1 -> only LR/RL, = j.
  const ScatteringVector odd = lr_from_hv({1.0, 0.0, 1.0});
  EXPECT_LT(std::abs(odd[0]), 1e-12);
  EXPECT_LT(std::abs(odd[3]), 1e-12);
  EXPECT_LT(std::abs(odd[1] - kJ), 1e-12);
  // Dihedral at θ: LL = e^{j2θ}, RR = −e^{−j2θ}, no LR.
  const double th = 0.37;
  const ScatteringVector dih = lr_from_hv({std::cos(2 * th), std::sin(2 * th), -std::cos(2 * th)});
  EXPECT_LT(std::abs(dih[0] - std::polar(1.0, 2 * th)), 1e-12);
  EXPECT_LT(std::abs(dih[3] + std::polar(1.0, -2 * th)), 1e-12);
  EXPECT_LT(std::abs(dih[1]), 1e-12);
  // Level vectors agree with the Pauli matrix: k_LR = U k_HV.
  const Eigen::Vector3cd k_hv(std::cos(2 * th), std::sqrt(2.0) * std::sin(2 * th),
                              -std::cos(2 * th));
  EXPECT_LT((pauli_lr_from_hv() * k_hv - level_vector(dih, PolLevel::Full)).norm(), 1e-12);
}

TEST(Polarimetry, OddBounceCovarianceShowsHhEqualVvInLinearBasis) {
  const Eigen::VectorXcd k = level_vector(lr_from_hv({2.0, 0.0, 2.0}), PolLevel::Full);
  const Eigen::MatrixXcd c_lr = k * k.adjoint();
  const Eigen::MatrixXcd c_hv = transform_covariance(c_lr, pauli_hv_from_lr());
  EXPECT_NEAR(c_hv(0, 0).real(), 4.0, 1e-12);                    // |HH|²
  EXPECT_NEAR(c_hv(2, 2).real(), 4.0, 1e-12);                    // |VV|²
  EXPECT_LT(std::abs(c_hv(0, 2) - cdouble(4.0)), 1e-12);         // HH VV* real positive: in phase
  EXPECT_NEAR(c_hv(1, 1).real(), 0.0, 1e-12);                    // no cross-pol
  EXPECT_NEAR(c_lr.trace().real(), c_hv.trace().real(), 1e-12);  // span preserved
}

TEST(Polarimetry, PartialLevelsFollowFromTheFullCovariance) {
  std::mt19937 rng(2);
  Eigen::MatrixXcd c_full = Eigen::MatrixXcd::Zero(3, 3);
  std::vector<ScatteringVector> samples;
  for (int i = 0; i < 10; ++i) {
    samples.push_back(random_reciprocal(rng));
    const Eigen::VectorXcd k = level_vector(samples.back(), PolLevel::Full);
    c_full += k * k.adjoint();
  }
  for (PolLevel level : {PolLevel::DualLLLR, PolLevel::DualHHVV, PolLevel::SingleLR,
                         PolLevel::SingleRR, PolLevel::SingleHH}) {
    Eigen::MatrixXcd c = Eigen::MatrixXcd::Zero(pol_dimension(level), pol_dimension(level));
    for (const auto& s : samples) {
      const Eigen::VectorXcd k = level_vector(s, level);
      c += k * k.adjoint();
    }
    const Eigen::MatrixXcd p = level_projection(level);
    EXPECT_LT((transform_covariance(c_full, p) - c).norm(), 1e-9) << to_string(level);
    // The single-precision hot-path variant agrees.
    std::array<cfloat, 4> sf{};
    for (int ch = 0; ch < 4; ++ch) sf[ch] = cfloat(samples[0][ch]);
    std::array<cfloat, 3> out{};
    level_vector(sf, level, out.data());
    const Eigen::VectorXcd k = level_vector(samples[0], level);
    for (int i = 0; i < k.size(); ++i) EXPECT_LT(std::abs(cdouble(out[i]) - k(i)), 1e-5);
  }
}

TEST(Polarimetry, ScatteringClassOfCanonicalCovariances) {
  auto cov = [](const ScatteringVector& o, PolLevel l) {
    const Eigen::VectorXcd k = level_vector(o, l);
    return Eigen::MatrixXcd(k * k.adjoint());
  };
  const ScatteringVector odd = lr_from_hv({1.0, 0.0, 1.0});
  const ScatteringVector dih = lr_from_hv({std::cos(0.8), std::sin(0.8), -std::cos(0.8)});
  for (PolLevel l : {PolLevel::Full, PolLevel::DualLLLR}) {
    EXPECT_EQ(classify_scattering(cov(odd, l), l), ScatteringClass::Odd);
    EXPECT_EQ(classify_scattering(cov(dih, l), l), ScatteringClass::Even);
  }
  const ScatteringVector dih0 = lr_from_hv({1.0, 0.0, -1.0});  // seen by HH/VV
  EXPECT_EQ(classify_scattering(cov(odd, PolLevel::DualHHVV), PolLevel::DualHHVV),
            ScatteringClass::Odd);
  EXPECT_EQ(classify_scattering(cov(dih0, PolLevel::DualHHVV), PolLevel::DualHHVV),
            ScatteringClass::Even);
  EXPECT_EQ(classify_scattering(cov(odd, PolLevel::SingleLR), PolLevel::SingleLR),
            ScatteringClass::Unknown);
  // Random-dipole volume: odd = even in the LR basis -> Mixed.
  Eigen::Matrix3cd c_hv;
  c_hv << 1.0, 0.0, 1.0 / 3.0, 0.0, 2.0 / 3.0, 0.0, 1.0 / 3.0, 0.0, 1.0;
  const Eigen::MatrixXcd c_lr = transform_covariance(c_hv, pauli_lr_from_hv());
  EXPECT_EQ(classify_scattering(c_lr, PolLevel::Full), ScatteringClass::Mixed);
  const MechanismPowers mp = mechanism_powers(c_lr, PolLevel::Full);
  EXPECT_NEAR(mp.odd, mp.even, 1e-12);
  // Noise subtraction: a weak pole over noise is still odd once the noise is removed.
  Eigen::MatrixXcd noisy = cov(odd, PolLevel::Full) * 0.5 + Eigen::MatrixXcd::Identity(3, 3) * 0.6;
  EXPECT_EQ(classify_scattering(noisy, PolLevel::Full), ScatteringClass::Mixed);
  EXPECT_EQ(classify_scattering(noisy, PolLevel::Full, {}, 0.6), ScatteringClass::Odd);
}

}  // namespace
}  // namespace polmap::radar
