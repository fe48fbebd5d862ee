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
