// pCFAR's d_ex in closed form (pcfar::excess) against the Cholesky form
// (pcfar::excess_reference): same value to rounding and the same positive-definiteness
// verdict, for q = 1, 2, 3, over the dynamic range a radar map holds.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "pcfar_kernels.hpp"

namespace polmap::radar::pcfar {
namespace {

/// A random Hermitian positive definite matrix with eigenvalues spread over `range`
/// (a unitary from a complex Gaussian's QR).
template <int Q>
CMat<Q> random_pd(std::mt19937& rng, double range) {
  std::normal_distribution<double> n(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  CMat<Q> g;
  for (int i = 0; i < Q; ++i) {
    for (int j = 0; j < Q; ++j) g(i, j) = cdouble(n(rng), n(rng));
  }
  const CMat<Q> unitary = Eigen::HouseholderQR<CMat<Q>>(g).householderQ();
  Eigen::Matrix<double, Q, 1> ev;
  for (int i = 0; i < Q; ++i) ev(i) = std::pow(range, u(rng));
  CMat<Q> m = unitary * ev.template cast<cdouble>().asDiagonal() * unitary.adjoint();
  for (int i = 0; i < Q; ++i) m(i, i) = cdouble(m(i, i).real(), 0.0);
  return 0.5 * (m + m.adjoint()).eval();
}

template <int Q>
void expect_same_as_reference(std::uint32_t seed) {
  std::mt19937 rng(seed);
  for (int t = 0; t < 2000; ++t) {
    const double range = t % 2 == 0 ? 1e2 : 1e6;  // up to 60 dB above the loading
    const double scale = std::pow(10.0, std::uniform_real_distribution<double>(-3, 3)(rng));
    const CMat<Q> sigma = random_pd<Q>(rng, range) * scale;
    // C near Σ (cells like their neighbourhood) or unrelated (a bright point).
    const CMat<Q> c = t % 3 == 0 ? (sigma * 1.3).eval() : (random_pd<Q>(rng, range) * scale).eval();
    bool ok_fast = false, ok_ref = false;
    const double fast = excess<Q>(sigma, c, ok_fast);
    const double ref = excess_reference<Q>(sigma, c, ok_ref);
    ASSERT_TRUE(ok_ref) << t;
    ASSERT_EQ(ok_fast, ok_ref) << t;
    // The same factorization in another operation order: rounding, amplified by the
    // condition number (≤ 1e6 here) to ~1e-11.
    EXPECT_NEAR(fast, ref, 1e-9 * (1.0 + ref)) << "q " << Q << " trial " << t;
  }
  // Not positive definite: both say so.
  CMat<Q> bad = random_pd<Q>(rng, 10.0);
  bad(Q - 1, Q - 1) = cdouble(-1.0, 0.0);
  bool ok_fast = true, ok_ref = true;
  excess<Q>(bad, random_pd<Q>(rng, 10.0), ok_fast);
  excess_reference<Q>(bad, random_pd<Q>(rng, 10.0), ok_ref);
  EXPECT_FALSE(ok_ref);
  EXPECT_FALSE(ok_fast);
  excess<Q>(random_pd<Q>(rng, 10.0), bad, ok_fast);
  EXPECT_FALSE(ok_fast);
}

TEST(PcfarExcess, ClosedFormEqualsCholeskyFormAtEveryPolarimetricLevel) {
  expect_same_as_reference<1>(1);
  expect_same_as_reference<2>(2);
  expect_same_as_reference<3>(3);
}

TEST(PcfarExcess, IsZeroAtEqualityAndGrowsWithContrast) {
  std::mt19937 rng(9);
  const CMat<3> s = random_pd<3>(rng, 100.0);
  bool ok = false;
  EXPECT_NEAR(excess<3>(s, s, ok), 0.0, 1e-12);
  EXPECT_TRUE(ok);
  // λ·Σ: d_ex = λ − ln λ − 1 per dimension.
  for (double lambda : {2.0, 4.5, 10.0}) {
    EXPECT_NEAR(excess<3>(s, (lambda * s).eval(), ok), lambda - std::log(lambda) - 1.0, 1e-9);
  }
}

}  // namespace
}  // namespace polmap::radar::pcfar
