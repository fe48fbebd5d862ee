// The ego-motion RANSAC's inner loop (radar/src/doppler_inliers.hpp) against the
// straightforward loop that divides every row.
#include "doppler_inliers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace polmap::radar::detail {
namespace {

struct Rows {
  std::vector<double> vr, h0, h1, g0, g1, ext;
  [[nodiscard]] DopplerRows view() const {
    return {vr.data(), h0.data(), h1.data(), g0.data(), g1.data(), ext.data(), vr.size()};
  }
};

constexpr double kThr2 = 0.1 * 0.1;
constexpr double kAz2 = 0.17 * 0.17;

/// n rows of corner radars seeing static targets at random azimuths for (v, w): a fraction
/// `static_share` consistent with the motion (noise well inside the threshold), a few
/// placed exactly at the threshold (q = 1 up to rounding), the rest clutter.
Rows make_rows(std::size_t n, double v, double w, double static_share, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> az(-M_PI, M_PI), u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.03);
  Rows r;
  for (std::size_t i = 0; i < n; ++i) {
    const double th = az(rng), xm = 3.5, ym = u(rng) < 0.5 ? 0.8 : -0.8;
    const double c = std::cos(th), s = std::sin(th);
    const double h0 = -c, h1 = ym * c - xm * s, g0 = s, g1 = -ym * s - xm * c;
    const double ext = u(rng) < 0.3 ? u(rng) * 0.5 : 0.0;
    const double pred = h0 * v + h1 * w, d = g0 * v + g1 * w;
    const double t = std::sqrt(kThr2 * (1.0 + kAz2 * d * d + ext));
    double vr = pred + 8.0 * (u(rng) - 0.5);
    const double pick = u(rng);
    if (pick < static_share) vr = pred + noise(rng);
    if (pick > 0.97) vr = pred + (u(rng) < 0.5 ? t : -t) * (1.0 + (u(rng) - 0.5) * 1e-15);
    r.vr.push_back(vr);
    r.h0.push_back(h0);
    r.h1.push_back(h1);
    r.g0.push_back(g0);
    r.g1.push_back(g1);
    r.ext.push_back(ext);
  }
  return r;
}

TEST(DopplerSupport, EqualsDividingEveryRowBitForBit) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int inlier_total = 0, boundary_rows = 0;
  for (int trial = 0; trial < 40; ++trial) {
    const double v = 20.0 * u(rng), w = 0.6 * (u(rng) - 0.5);
    const std::size_t n = 1 + static_cast<std::size_t>(u(rng) * 700);  // partial last blocks
    const Rows rows = make_rows(n, v, w, 0.25, rng);
    for (std::size_t i = 0; i < n; ++i) {
      const double r = rows.vr[i] - (rows.h0[i] * v + rows.h1[i] * w);
      const double d = rows.g0[i] * v + rows.g1[i] * w;
      const double q = r * r / (kThr2 * (1.0 + kAz2 * d * d + rows.ext[i]));
      boundary_rows += std::abs(q - 1.0) < 1e-12 ? 1 : 0;
    }
    // The true motion, perturbed ones and random ones.
    for (int k = 0; k < 30; ++k) {
      const double hv = k == 0 ? v : v + (u(rng) - 0.5) * (k < 15 ? 0.05 : 10.0);
      const double hw = k == 0 ? w : w + (u(rng) - 0.5) * (k < 15 ? 0.01 : 0.5);
      const DopplerSupport fast = doppler_support(rows.view(), hv, hw, kThr2, kAz2);
      const DopplerSupport ref = doppler_support_reference(rows.view(), hv, hw, kThr2, kAz2);
      ASSERT_EQ(fast.inliers, ref.inliers);
      ASSERT_EQ(fast.cost, ref.cost);  // bit for bit: same q, same order
      inlier_total += ref.inliers;
      // The early exit gives up in the same cases.
      for (int to_beat : {ref.inliers, ref.inliers + 1, static_cast<int>(n) / 2}) {
        const DopplerSupport f = doppler_support(rows.view(), hv, hw, kThr2, kAz2, to_beat);
        const DopplerSupport g =
            doppler_support_reference(rows.view(), hv, hw, kThr2, kAz2, to_beat);
        ASSERT_EQ(f.inliers, g.inliers);
        ASSERT_EQ(f.cost, g.cost);
      }
    }
  }
  EXPECT_GT(inlier_total, 1000);  // the hypotheses found real support
  EXPECT_GT(boundary_rows, 50);   // and rows sat on the threshold
}

TEST(DopplerSupport, GivesUpOnlyWhenTheRestCannotReachTheBar) {
  std::mt19937_64 rng(3);
  const Rows rows = make_rows(640, 10.0, 0.1, 0.5, rng);  // ten full blocks
  const DopplerSupport all = doppler_support(rows.view(), 10.0, 0.1, kThr2, kAz2);
  ASSERT_GT(all.inliers, 250);
  // Reachable bar: full result. Unreachable: gives up.
  const DopplerSupport at = doppler_support(rows.view(), 10.0, 0.1, kThr2, kAz2, all.inliers);
  EXPECT_EQ(at.inliers, all.inliers);
  const DopplerSupport above =
      doppler_support(rows.view(), 10.0, 0.1, kThr2, kAz2, all.inliers + 1);
  EXPECT_EQ(above.inliers, -1);
  EXPECT_TRUE(std::isinf(above.cost));
}

}  // namespace
}  // namespace polmap::radar::detail
