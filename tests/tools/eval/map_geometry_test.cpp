// Map geometry against truth: a shifted and rotated copy of the truth (plus noise and
// false landmarks) is matched, its offset and rotation recovered, the window RMS ignores
// what a rigid fit per window explains but not a local distortion, and a section that broke
// apart lowers its window's matched share instead of dropping out of the figures.
#include "polmap/eval/map_geometry.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace polmap::eval {
namespace {

std::vector<Eigen::Vector2d> truth_points(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Eigen::Vector2d> t;
  for (double x = 0; x < 600.0; x += 3.0 + 6.0 * u(rng)) {
    t.emplace_back(x, (u(rng) < 0.5 ? -1 : 1) * (5.0 + 15.0 * u(rng)));
  }
  return t;
}

TEST(MapGeometry, RecoversOffsetAndRotationOfAShiftedMap) {
  std::mt19937_64 rng(3);
  const auto truth = truth_points(rng);
  std::normal_distribution<double> g(0.0, 0.03);
  const double th = 0.2 * M_PI / 180.0;
  Eigen::Matrix2d R;
  R << std::cos(th), -std::sin(th), std::sin(th), std::cos(th);
  const Eigen::Vector2d t(2.4, -1.1);
  std::vector<Eigen::Vector2d> map;
  for (const auto& p : truth)
    map.push_back(R.transpose() * (p - t) + Eigen::Vector2d(g(rng), g(rng)));
  std::uniform_real_distribution<double> u(0.0, 600.0);
  for (int i = 0; i < 30; ++i) map.emplace_back(u(rng), 40.0 + u(rng) / 20.0);  // false ones
  const MapGeometry m = map_geometry(map, truth);
  ASSERT_EQ(m.status, MapGeometry::Status::Ok);
  EXPECT_GE(m.matched, static_cast<int>(0.95 * truth.size()));
  EXPECT_NEAR(m.yaw_truth_map_rad, th, 2e-4);
  EXPECT_NEAR(m.raw_rms_m, 2.6, 0.6);  // the shift plus the rotation about the origin
  EXPECT_NEAR(m.global_rms_m, 0.03 * std::sqrt(2.0), 0.01);
  EXPECT_LT(m.window_rms_m, m.global_rms_m + 1e-9);
  EXPECT_GE(m.windows, 3);
}

TEST(MapGeometry, WindowFitAbsorbsASlowBendButNotNoise) {
  std::mt19937_64 rng(4);
  const auto truth = truth_points(rng);
  std::vector<Eigen::Vector2d> map;
  // A bend: the map drifts 1 m sideways over 600 m (sinusoid), no noise.
  for (const auto& p : truth)
    map.push_back(p + Eigen::Vector2d(0.0, 0.5 * std::sin(p.x() / 100.0)));
  const MapGeometry m = map_geometry(map, truth);
  ASSERT_EQ(m.status, MapGeometry::Status::Ok);
  EXPECT_GT(m.global_rms_m, 0.15);
  EXPECT_LT(m.window_rms_m, 0.5 * m.global_rms_m);
}

TEST(MapGeometry, AWindowOffFromTheRestIsFittedOnItsOwn) {
  std::mt19937_64 rng(5);
  const auto truth = truth_points(rng);
  std::vector<Eigen::Vector2d> map;
  // The middle 200 m sit 2 m to the side: beyond the global fit's last gate, but one rigid
  // shift of their own window.
  for (const auto& p : truth) {
    map.push_back(p + Eigen::Vector2d(0.0, p.x() >= 200.0 && p.x() < 400.0 ? 2.0 : 0.0));
  }
  const MapGeometry m = map_geometry(map, truth);
  ASSERT_EQ(m.status, MapGeometry::Status::Ok);
  EXPECT_LT(m.matched, static_cast<int>(0.8 * truth.size()));  // the global fit drops them
  EXPECT_GT(m.worst_window_share, 0.95);
  EXPECT_LT(m.window_rms_m, 1e-6);
  double max_shift_m = 0.0;
  for (const auto& w : m.window_fits) max_shift_m = std::max(max_shift_m, w.shift_m);
  EXPECT_NEAR(max_shift_m, 2.0, 0.05);
  EXPECT_DOUBLE_EQ(m.max_window_shift_m, max_shift_m);
}

TEST(MapGeometry, FitRigidMatchesABruteForceSearch) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g(0.0, 0.05);
  std::uniform_real_distribution<double> u(-50.0, 50.0);
  const double th = 0.03;
  Eigen::Matrix2d R;
  R << std::cos(th), -std::sin(th), std::sin(th), std::cos(th);
  std::vector<MapTruthPair> pairs;
  for (int i = 0; i < 40; ++i) {
    const Eigen::Vector2d m(u(rng), u(rng));
    pairs.push_back({m, R * m + Eigen::Vector2d(1.5, -0.7) + Eigen::Vector2d(g(rng), g(rng))});
  }
  auto sse = [&](const Eigen::Matrix2d& Rf, const Eigen::Vector2d& tf) {
    double s = 0.0;
    for (const auto& p : pairs) s += (Rf * p.map_m + tf - p.truth_m).squaredNorm();
    return s;
  };
  const RigidFit2 f = fit_rigid(pairs);
  EXPECT_EQ(f.pairs, 40);
  // Brute force over the angle (the best translation for an angle is the centroid's).
  Eigen::Vector2d cm = Eigen::Vector2d::Zero(), cg = Eigen::Vector2d::Zero();
  for (const auto& p : pairs) cm += p.map_m / 40.0, cg += p.truth_m / 40.0;
  double best = std::numeric_limits<double>::infinity();
  for (double a = -0.1; a <= 0.1; a += 1e-5) {
    Eigen::Matrix2d Ra;
    Ra << std::cos(a), -std::sin(a), std::sin(a), std::cos(a);
    best = std::min(best, sse(Ra, cg - Ra * cm));
  }
  EXPECT_LE(sse(f.R_truth_map, f.t_truth_map_m), best + 1e-9);
  EXPECT_NEAR(std::atan2(f.R_truth_map(1, 0), f.R_truth_map(0, 0)), th, 2e-3);
}

TEST(MapGeometry, TheLocalFrameFollowsABentMap) {
  std::mt19937_64 rng(5);
  const auto truth = truth_points(rng);
  std::vector<Eigen::Vector2d> map;
  // As above: the middle 200 m sit 2 m to the side.
  auto off = [](const Eigen::Vector2d& p) { return p.x() >= 200.0 && p.x() < 400.0 ? 2.0 : 0.0; };
  for (const auto& p : truth) map.push_back(p + Eigen::Vector2d(0.0, off(p)));
  const MapGeometry m = map_geometry(map, truth);
  ASSERT_EQ(m.status, MapGeometry::Status::Ok);
  // Every window match is the true correspondence, bent section included.
  ASSERT_GE(m.window_pairs.size(), static_cast<std::size_t>(0.95 * truth.size()));
  for (const auto& p : m.window_pairs) {
    EXPECT_NEAR((p.map_m - p.truth_m).y(), off(p.truth_m), 1e-9);
    EXPECT_NEAR((p.map_m - p.truth_m).x(), 0.0, 1e-9);
  }
  // Around a car in the shifted section the map's frame is 2 m to the side; outside it, not.
  const auto mid = local_rigid_fit(m.window_pairs, {300.0, 0.0}, 200.0, 5);
  ASSERT_TRUE(mid.has_value());
  EXPECT_NEAR(mid->t_truth_map_m.y(), -2.0, 1e-6);
  EXPECT_NEAR(mid->t_truth_map_m.x(), 0.0, 1e-6);
  const auto start = local_rigid_fit(m.window_pairs, {80.0, 0.0}, 200.0, 5);
  ASSERT_TRUE(start.has_value());
  EXPECT_NEAR(start->t_truth_map_m.norm(), 0.0, 1e-6);
  // Straddling the step: a blend of both, with the pairs of the square only.
  const auto border = local_rigid_fit(m.window_pairs, {200.0, 0.0}, 200.0, 5);
  ASSERT_TRUE(border.has_value());
  const Eigen::Vector2d c(200.0, 0.0);
  const double moved_m = (border->R_truth_map * c + border->t_truth_map_m - c).norm();
  EXPECT_GT(moved_m, 0.3);
  EXPECT_LT(moved_m, 1.7);
  // Nowhere near the map: too few pairs.
  EXPECT_FALSE(local_rigid_fit(m.window_pairs, {2000.0, 0.0}, 200.0, 5).has_value());
}

TEST(MapGeometry, ASectionThatBrokeApartLowersItsShare) {
  std::mt19937_64 rng(6);
  const auto truth = truth_points(rng);
  std::vector<Eigen::Vector2d> map;
  // Beyond x = 400 m every other landmark sits 0.8 m ahead (near its object, but not on
  // it): no rigid fit of that window matches more than about half of them. The rest of the
  // map is exact.
  int beyond[2] = {0, 0};  // per side of the road, so each window is split evenly
  for (const auto& p : truth) {
    const bool broken = p.x() >= 400.0 && beyond[p.y() > 0.0 ? 1 : 0]++ % 2 == 0;
    map.push_back(p + Eigen::Vector2d(broken ? 0.8 : 0.0, 0.0));
  }
  const MapGeometry m = map_geometry(map, truth);
  ASSERT_EQ(m.status, MapGeometry::Status::Ok);
  EXPECT_LT(m.worst_window_share, 0.65);
  EXPECT_GT(m.worst_window_share, 0.35);
  EXPECT_LT(m.window_matched_share, 0.9);
  int whole = 0;
  for (const auto& w : m.window_fits) whole += w.ix < 2 && w.share() == 1.0 ? 1 : 0;
  EXPECT_GE(whole, 2);  // the windows before the break are whole
}

TEST(MapGeometry, NothingToMatchIsReported) {
  const std::vector<Eigen::Vector2d> truth{{0, 0}, {10, 0}};
  const std::vector<Eigen::Vector2d> map{{500, 500}};
  EXPECT_EQ(map_geometry(map, truth).status, MapGeometry::Status::TooFewMatches);
}

}  // namespace
}  // namespace polmap::eval
