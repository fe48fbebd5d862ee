// Visibility of places from drive passes: the index against a brute-force distance
// reference, and the view range estimated from a drive's own candidates.
#include "polmap/mapping_service/visibility.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

namespace polmap::mapping {
namespace {

double path_distance(const std::vector<Eigen::Vector2d>& path, const Eigen::Vector2d& p) {
  double best = 1e300;
  for (std::size_t i = 0; i + 1 < path.size(); ++i) {
    const Eigen::Vector2d ab = path[i + 1] - path[i];
    const double t = std::clamp((p - path[i]).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (p - (path[i] + t * ab)).norm());
  }
  return best;
}

DrivePass straight_pass(std::int64_t drive, Eigen::Vector2d a, Eigen::Vector2d b, double range) {
  DrivePass p;
  p.drive = drive;
  p.view_range_m = range;
  const int n = 200;
  for (int k = 0; k <= n; ++k) p.path_m.push_back(a + (b - a) * (double(k) / n));
  return p;
}

TEST(Visibility, StraightPassSeesWithinItsRangeOnly) {
  const VisibilityIndex view({straight_pass(7, {0, 0}, {100, 0}, 10.0)});
  EXPECT_EQ(view.drives_in_view({50, 9.9}), std::vector<std::int64_t>{7});
  EXPECT_TRUE(view.drives_in_view({50, 10.1}).empty());
  EXPECT_EQ(view.count_in_view({109.9, 0}), 1U);  // beyond the end, within range of it
  EXPECT_EQ(view.count_in_view({110.1, 0}), 0U);
  EXPECT_EQ(view.count_in_view({-5, -5}), 1U);
  EXPECT_EQ(view.count_in_view({5000, 5000}), 0U);  // no cell at all
}

TEST(Visibility, MatchesBruteForceOverRandomPassesAndRanges) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-300.0, 300.0), r(5.0, 60.0);
  std::vector<DrivePass> passes;
  for (int d = 0; d < 25; ++d) {
    DrivePass p;
    p.drive = 100 + (d % 20);  // drives 100..104 have two passes each
    p.view_range_m = r(rng);
    Eigen::Vector2d pos(u(rng), u(rng));
    double heading = u(rng);
    for (int k = 0; k < 400; ++k) {  // a wandering path with 1.5 m steps
      heading += 0.05 * std::sin(0.03 * k + d);
      pos += 1.5 * Eigen::Vector2d(std::cos(heading), std::sin(heading));
      p.path_m.push_back(pos);
    }
    passes.push_back(std::move(p));
  }
  VisibilityConfig cfg;
  cfg.simplify_tolerance_m = 0.0;  // exact paths: the reference has no tolerance
  const VisibilityIndex view(passes, cfg);
  int agree = 0, borderline = 0;
  for (int q = 0; q < 3000; ++q) {
    const Eigen::Vector2d p(u(rng), u(rng));
    std::vector<std::int64_t> expect;
    bool near_border = false;
    for (const auto& pass : passes) {
      const double d = path_distance(pass.path_m, p);
      near_border = near_border || std::abs(d - pass.view_range_m) < 1e-9;
      if (d <= pass.view_range_m) expect.push_back(pass.drive);
    }
    std::sort(expect.begin(), expect.end());
    expect.erase(std::unique(expect.begin(), expect.end()), expect.end());
    if (near_border) {
      ++borderline;
      continue;
    }
    ASSERT_EQ(view.drives_in_view(p), expect) << p.transpose();
    agree += expect.empty() ? 0 : 1;
  }
  EXPECT_GT(agree, 300);  // the queries do exercise non-empty answers
  EXPECT_LT(borderline, 5);
}

TEST(Visibility, NearestPathDirectionIsThatOfTheNearestPassInView) {
  // An L: one pass east along y = 0, another north along x = 100; ranges 10 m.
  const VisibilityIndex view(
      {straight_pass(1, {0, 0}, {100, 0}, 10.0), straight_pass(2, {100, 0}, {100, 100}, 10.0)});
  const auto east = view.nearest_path_direction({40, 3});
  ASSERT_TRUE(east.has_value());
  EXPECT_NEAR(std::abs(east->x()), 1.0, 1e-9);
  EXPECT_NEAR(east->norm(), 1.0, 1e-12);
  const auto north = view.nearest_path_direction({97, 60});
  ASSERT_TRUE(north.has_value());
  EXPECT_NEAR(std::abs(north->y()), 1.0, 1e-9);
  // Near the corner the nearer leg wins: 2 m from the east leg, 4 m from the north one.
  const auto corner = view.nearest_path_direction({96, 2});
  ASSERT_TRUE(corner.has_value());
  EXPECT_NEAR(std::abs(corner->x()), 1.0, 1e-9);
  // Out of every pass's range: no direction.
  EXPECT_FALSE(view.nearest_path_direction({40, 30}).has_value());
  EXPECT_FALSE(view.nearest_path_direction({5000, 5000}).has_value());
  // The nearest path point: the foot on the nearer leg, clamped to its ends.
  EXPECT_TRUE(view.nearest_path_point({40, 3})->isApprox(Eigen::Vector2d(40, 0)));
  EXPECT_TRUE(view.nearest_path_point({97, 60})->isApprox(Eigen::Vector2d(100, 60)));
  EXPECT_TRUE(view.nearest_path_point({96, 2})->isApprox(Eigen::Vector2d(96, 0)));
  EXPECT_TRUE(view.nearest_path_point({-5, 1})->isApprox(Eigen::Vector2d(0, 0)));
  EXPECT_FALSE(view.nearest_path_point({40, 30}).has_value());
}

TEST(Visibility, NearestPathPointOfGivenDrivesIgnoresTheirRange) {
  // Ranges of 10 m; the point is 30 m from pass 1 and 50 m from pass 2: out of view of both.
  const VisibilityIndex view(
      {straight_pass(1, {0, 0}, {100, 0}, 10.0), straight_pass(2, {0, -20}, {100, -20}, 10.0)});
  EXPECT_FALSE(view.nearest_path_point({40, 30}).has_value());
  const std::vector<std::int64_t> both{1, 2}, second{2}, none{9};
  EXPECT_TRUE(view.nearest_path_point({40, 30}, both)->isApprox(Eigen::Vector2d(40, 0)));
  EXPECT_TRUE(view.nearest_path_point({40, 30}, second)->isApprox(Eigen::Vector2d(40, -20)));
  EXPECT_TRUE(view.nearest_path_point({140, 30}, second)->isApprox(Eigen::Vector2d(100, -20)));
  EXPECT_FALSE(view.nearest_path_point({40, 30}, none).has_value());
}

/// Reference: the segments cross or touch iff the parametric solution lies in [0, 1]² (or,
/// parallel, they are collinear and overlap).
bool crosses_reference(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c,
                       const Eigen::Vector2d& d) {
  const Eigen::Vector2d r = b - a, s = d - c;
  const double den = r.x() * s.y() - r.y() * s.x();
  const Eigen::Vector2d q = c - a;
  if (std::abs(den) < 1e-12) {
    if (std::abs(q.x() * r.y() - q.y() * r.x()) > 1e-9) return false;  // parallel apart
    const double t0 = q.dot(r) / r.squaredNorm(), t1 = (d - a).dot(r) / r.squaredNorm();
    return std::max(t0, t1) >= 0.0 && std::min(t0, t1) <= 1.0;
  }
  const double t = (q.x() * s.y() - q.y() * s.x()) / den;
  const double u = (q.x() * r.y() - q.y() * r.x()) / den;
  return t >= 0.0 && t <= 1.0 && u >= 0.0 && u <= 1.0;
}

TEST(Visibility, DrivesCrossingMatchesBruteForceOverRandomZigzags) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> pos(0.0, 200.0), off(-40.0, 40.0);
  std::vector<DrivePass> passes;
  for (int d = 1; d <= 12; ++d) {
    DrivePass p;
    p.drive = d;
    p.view_range_m = 5.0 + d;
    // Zigzags with vertices 20 m apart and tens of metres off the chord: the index's 0.5 m
    // simplification keeps every vertex.
    for (int k = 0; k <= 10; ++k) p.path_m.emplace_back(20.0 * k, 100.0 + off(rng));
    passes.push_back(p);
  }
  const VisibilityIndex view(passes);
  int crossings = 0;
  for (int q = 0; q < 400; ++q) {
    const Eigen::Vector2d a(pos(rng), pos(rng));
    const Eigen::Vector2d b = a + Eigen::Vector2d(off(rng), off(rng)) * (q % 2 == 0 ? 1.0 : 0.2);
    std::vector<std::int64_t> expected;
    for (const DrivePass& p : passes) {
      for (std::size_t k = 0; k + 1 < p.path_m.size(); ++k) {
        if (crosses_reference(a, b, p.path_m[k], p.path_m[k + 1])) {
          expected.push_back(p.drive);
          break;
        }
      }
    }
    crossings += static_cast<int>(expected.size());
    EXPECT_EQ(view.drives_crossing(a, b), expected) << q;
  }
  EXPECT_GT(crossings, 100);  // the sample exercises both answers
  // Touching counts: a segment ending on a path vertex.
  const auto touching =
      view.drives_crossing(passes[0].path_m[3] + Eigen::Vector2d(0, 7), passes[0].path_m[3]);
  EXPECT_NE(std::find(touching.begin(), touching.end(), 1), touching.end());
}

TEST(Visibility, PassesAsCloseAsTheFarthestOfGivenDrivesMatchBruteForce) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> off(-30.0, 30.0);
  std::vector<DrivePass> passes;
  for (int d = 1; d <= 20; ++d) {
    const double y = off(rng);
    passes.push_back(straight_pass(d, {0, y}, {100, y + off(rng) / 10.0}, 10.0));
  }
  const VisibilityIndex view(passes);
  for (int q = 0; q < 50; ++q) {
    const std::vector<Eigen::Vector2d> places{{50 + off(rng), off(rng)}, {50 + off(rng), off(rng)}};
    std::vector<std::int64_t> drives{1 + q % 20, 1 + (q * 7) % 20};
    auto dist = [&](const DrivePass& p) {
      return std::min(path_distance(p.path_m, places[0]), path_distance(p.path_m, places[1]));
    };
    double bar = 0.0;
    for (std::int64_t d : drives)
      bar = std::max(bar, dist(passes[static_cast<std::size_t>(d - 1)]));
    std::size_t expected = 0;
    for (const DrivePass& p : passes) expected += dist(p) <= bar + 1e-9 ? 1U : 0U;
    EXPECT_EQ(view.count_passes_as_close(places, drives), expected) << q;
    EXPECT_GE(expected, 1U);
  }
  const std::vector<Eigen::Vector2d> one{{50, 0}};
  const std::vector<std::int64_t> unknown{3, 99};
  EXPECT_FALSE(view.count_passes_as_close(one, unknown).has_value());
}

TEST(Visibility, LongDiagonalSegmentsAreIndexedAlongTheirLength) {
  DrivePass p;
  p.drive = 1;
  p.view_range_m = 3.0;
  p.path_m = {{0, 0}, {5000, 5000}};  // two samples, 7 km apart
  const VisibilityIndex view({p});
  EXPECT_EQ(view.count_in_view({2500, 2502}), 1U);
  EXPECT_EQ(view.count_in_view({2500, 2505}), 0U);
}

TEST(Visibility, DefaultRangeForPassesWithoutOne) {
  VisibilityConfig cfg;
  cfg.default_view_range_m = 12.0;
  const VisibilityIndex view({straight_pass(1, {0, 0}, {10, 0}, 0.0)}, cfg);
  EXPECT_EQ(view.count_in_view({5, 11.9}), 1U);
  EXPECT_EQ(view.count_in_view({5, 12.1}), 0U);
}

TEST(Visibility, ViewRangeIsAQuantileOfTheDrivesOwnCandidateDistances) {
  std::vector<Eigen::Vector2d> path;
  for (int k = 0; k <= 500; ++k) path.emplace_back(k, 0.0);
  std::vector<Eigen::Vector2d> cands;
  for (int i = 0; i < 1000; ++i) {  // lateral distances 0.02 .. 20 m, both sides
    const double d = 0.02 * (i + 1);
    cands.emplace_back(10.0 + 0.4 * i, i % 2 ? d : -d);
  }
  VisibilityConfig cfg;
  cfg.range_margin = 1.0;
  EXPECT_NEAR(estimate_view_range_m(path, cands, cfg), 18.0, 0.05);
  cfg.range_quantile = 0.5;
  EXPECT_NEAR(estimate_view_range_m(path, cands, cfg), 10.0, 0.05);
  cfg.range_margin = 1.25;
  EXPECT_NEAR(estimate_view_range_m(path, cands, cfg), 12.5, 0.07);
  cfg.max_view_range_m = 8.0;
  EXPECT_DOUBLE_EQ(estimate_view_range_m(path, cands, cfg), 8.0);
  cfg = {};
  cfg.min_view_range_m = 25.0;
  EXPECT_DOUBLE_EQ(estimate_view_range_m(path, cands, cfg), 25.0);
  EXPECT_DOUBLE_EQ(estimate_view_range_m(path, {}, cfg), cfg.default_view_range_m);
  // Candidates beyond the maximum range count as the maximum (a far outlier cannot
  // stretch the range beyond it).
  const std::vector<Eigen::Vector2d> far(50, Eigen::Vector2d(250.0, 900.0));
  EXPECT_DOUBLE_EQ(estimate_view_range_m(path, far, cfg), cfg.max_view_range_m);
}

}  // namespace
}  // namespace polmap::mapping
