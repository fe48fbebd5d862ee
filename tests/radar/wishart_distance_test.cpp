// The Wishart distance of pCFAR: the paper form d(Σ, C) = q⁻¹(ln|Σ| + tr(Σ⁻¹C)) is
// minimal over Σ at Σ = C, and the excess form used for detection is ≥ 0, zero at
// C = Σ, scale invariant and invariant under the LR -> HV basis change.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "polmap/radar/point_extractor.hpp"
#include "polmap/radar/polarimetry.hpp"

namespace polmap::radar {
namespace {

Eigen::MatrixXcd random_pd(std::mt19937& rng, int q) {
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::MatrixXcd a(q, q + 2);
  for (int i = 0; i < a.rows(); ++i) {
    for (int j = 0; j < a.cols(); ++j) a(i, j) = cdouble(n(rng), n(rng));
  }
  return a * a.adjoint() / double(q + 2) + 0.05 * Eigen::MatrixXcd::Identity(q, q);
}

Eigen::MatrixXcd random_hermitian(std::mt19937& rng, int q, double scale) {
  std::normal_distribution<double> n(0.0, scale);
  Eigen::MatrixXcd h(q, q);
  for (int i = 0; i < q; ++i) {
    h(i, i) = n(rng);
    for (int j = i + 1; j < q; ++j) {
      h(i, j) = cdouble(n(rng), n(rng));
      h(j, i) = std::conj(h(i, j));
    }
  }
  return h;
}

bool is_pd(const Eigen::MatrixXcd& m) {
  return Eigen::LLT<Eigen::MatrixXcd>(m).info() == Eigen::Success;
}

TEST(WishartDistance, PaperFormIsMinimalAtSigmaEqualC) {
  std::mt19937 rng(1);
  for (int q = 1; q <= 3; ++q) {
    for (int trial = 0; trial < 20; ++trial) {
      const Eigen::MatrixXcd c = random_pd(rng, q);
      const double d0 = wishart_distance(c, c);
      EXPECT_NEAR(d0, (std::log(c.determinant().real()) + q) / q, 1e-9);
      for (int p = 0; p < 50; ++p) {
        const Eigen::MatrixXcd s = c + random_hermitian(rng, q, 0.05);
        if (!is_pd(s)) continue;
        EXPECT_GE(wishart_distance(s, c), d0 - 1e-12);
      }
    }
  }
}

TEST(WishartDistance, ExcessIsNonNegativeAndZeroOnlyAtEquality) {
  std::mt19937 rng(2);
  for (int q = 1; q <= 3; ++q) {
    const Eigen::MatrixXcd s = random_pd(rng, q);
    EXPECT_NEAR(wishart_excess(s, s), 0.0, 1e-12);
    for (int p = 0; p < 100; ++p) {
      const Eigen::MatrixXcd c = s + random_hermitian(rng, q, 0.1);
      if (!is_pd(c)) continue;
      const double e = wishart_excess(s, c);
      EXPECT_GT(e, 0.0);
      // Excess = paper form minus its minimum over Σ.
      EXPECT_NEAR(e, wishart_distance(s, c) - wishart_distance(c, c), 1e-9);
    }
  }
}

TEST(WishartDistance, ExcessIsScaleAndBasisInvariant) {
  std::mt19937 rng(3);
  const Eigen::MatrixXcd s = random_pd(rng, 3), c = random_pd(rng, 3);
  const double e = wishart_excess(s, c);
  EXPECT_NEAR(wishart_excess(7.5 * s, 7.5 * c), e, 1e-9);
  const Eigen::Matrix3cd u = pauli_hv_from_lr();
  EXPECT_NEAR(wishart_excess(transform_covariance(s, u), transform_covariance(c, u)), e, 1e-9);
}

TEST(WishartDistance, ScalarCaseIsLambdaMinusLogLambdaMinusOne) {
  Eigen::MatrixXcd s(1, 1), c(1, 1);
  s(0, 0) = 2.0;
  c(0, 0) = 9.0;
  const double l = 4.5;
  EXPECT_NEAR(wishart_excess(s, c), l - std::log(l) - 1.0, 1e-12);
}

}  // namespace
}  // namespace polmap::radar
