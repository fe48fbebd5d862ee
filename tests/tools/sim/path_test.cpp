// Path from a polyline: corners become arcs everywhere, up to the ends, and the heading
// agrees with the curvature the drive simulator turns into the yaw rate (a heading kink
// the yaw rate does not show is a turn the vehicle's sensors cannot see).
#include "polmap/sim/path.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include "polmap/schema/pose2.hpp"

namespace polmap::sim {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

/// Largest heading change per metre between neighbouring samples, and the largest
/// disagreement of that change with the curvature of the samples (rad/m).
struct HeadingCheck {
  double max_turn_rad_per_m = 0.0;
  double max_kappa_mismatch_1pm = 0.0;
};

HeadingCheck check(const Path& p) {
  HeadingCheck c;
  const auto& q = p.points();
  for (std::size_t i = 1; i < q.size(); ++i) {
    const double ds = q[i].s_m - q[i - 1].s_m;
    const double turn = wrap_angle_rad(q[i].yaw_rad - q[i - 1].yaw_rad) / ds;
    const double kappa = 0.5 * (q[i].kappa_1pm + q[i - 1].kappa_1pm);
    c.max_turn_rad_per_m = std::max(c.max_turn_rad_per_m, std::abs(turn));
    c.max_kappa_mismatch_1pm = std::max(c.max_kappa_mismatch_1pm, std::abs(turn - kappa));
  }
  return c;
}

TEST(PathFromPolyline, CornerNearTheEndBecomesAnArcTheCurvatureShows) {
  // 50 m east, then a right angle 1 m before the end (a lanelet joint at the end of a
  // route): the old smoothing shrank its window to nothing at the ends and kept it.
  const std::vector<Eigen::Vector2d> pts{{0.0, 0.0}, {50.0, 0.0}, {50.0, 1.0}};
  const Path p = Path::from_polyline(pts, 0.1, 4.0);
  const HeadingCheck c = check(p);
  // A 4 m window turns 90 deg over a few metres (0.69 rad/m at most; 0.70 for the same
  // corner inside a route); the window that shrank at the ends kept a 4.0 rad/m step
  // whose heading disagreed with the curvature by 3.1 rad/m. The curvature (over +-1 m)
  // lags the reflected S bend at the end a little more than inside (0.36 against 0.16).
  EXPECT_LT(c.max_turn_rad_per_m, 1.0);
  EXPECT_LT(c.max_kappa_mismatch_1pm, 0.5);
  // The ends stay where they are.
  EXPECT_NEAR(p.points().front().x_m, 0.0, 1e-9);
  EXPECT_NEAR(p.points().front().y_m, 0.0, 1e-9);
  const auto& last = p.points().back();
  EXPECT_LT((Eigen::Vector2d(last.x_m, last.y_m) - Eigen::Vector2d(50.0, 1.0)).norm(), 0.1);
}

TEST(PathFromPolyline, CornerAtTheStartToo) {
  const std::vector<Eigen::Vector2d> pts{{0.0, 0.0}, {0.0, 1.0}, {40.0, 1.0}};
  const HeadingCheck c = check(Path::from_polyline(pts, 0.1, 4.0));
  EXPECT_LT(c.max_turn_rad_per_m, 1.0);
  EXPECT_LT(c.max_kappa_mismatch_1pm, 0.5);
}

TEST(PathFromPolyline, StraightAndArcAreUnchangedUpToTheEnds) {
  // A straight line stays straight to the last sample (point reflection continues it).
  const Path straight = Path::from_polyline({{0.0, 0.0}, {30.0, 0.0}}, 0.1, 4.0);
  for (const auto& q : straight.points()) {
    EXPECT_NEAR(q.y_m, 0.0, 1e-9);
    EXPECT_NEAR(q.yaw_rad, 0.0, 1e-9);
  }
  EXPECT_NEAR(straight.length_m(), 30.0, 0.1);
  // A finely sampled arc of radius 20 m keeps its curvature inside (ends excepted: the
  // path straightens over the last half window).
  std::vector<Eigen::Vector2d> arc;
  for (int i = 0; i <= 900; ++i) {
    const double a = i * 0.1 * kDeg;
    arc.emplace_back(20.0 * std::sin(a), 20.0 - 20.0 * std::cos(a));
  }
  const Path p = Path::from_polyline(arc, 0.1, 4.0);
  for (const auto& q : p.points()) {
    if (q.s_m < 4.0 || q.s_m > p.length_m() - 4.0) continue;
    EXPECT_NEAR(q.kappa_1pm, 1.0 / 20.0, 0.002) << "at s = " << q.s_m;
  }
  EXPECT_LT(check(p).max_kappa_mismatch_1pm, 0.02);
}

}  // namespace
}  // namespace polmap::sim
