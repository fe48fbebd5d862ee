// Map geometry against truth: a shifted and rotated copy of the truth (plus noise and
// false landmarks) is matched, its offset and rotation recovered, and the window RMS
// ignores what a rigid fit per window explains but not a local distortion.
#include "polmap/eval/map_geometry.hpp"

#include <gtest/gtest.h>

#include <cmath>
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

TEST(MapGeometry, NothingToMatchIsReported) {
  const std::vector<Eigen::Vector2d> truth{{0, 0}, {10, 0}};
  const std::vector<Eigen::Vector2d> map{{500, 500}};
  EXPECT_EQ(map_geometry(map, truth).status, MapGeometry::Status::TooFewMatches);
}

}  // namespace
}  // namespace polmap::eval
