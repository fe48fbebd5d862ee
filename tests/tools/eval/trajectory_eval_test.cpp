// evaluate_trajectory's uncertainty figures: NEES of (long, lat, yaw) under the row's
// covariance (checked against a straightforward computation and against χ²(3) statistics
// of errors drawn from the covariance itself), the protection level's bounded share, and
// the pl_lat_m column's round trip through the trajectory CSV.
#include "polmap/eval/trajectory_eval.hpp"

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>
#include <numbers>
#include <random>

#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::eval {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

/// A reference driving at 10 m/s with heading `yaw_enu_rad`, 100 Hz, for `seconds`.
std::vector<ReferenceSample> reference(const tiles::LocalFrame& f, double yaw_enu_rad,
                                       double seconds) {
  std::vector<ReferenceSample> ref;
  const Eigen::Vector2d dir(std::cos(yaw_enu_rad), std::sin(yaw_enu_rad));
  for (int i = 0; i <= static_cast<int>(seconds * 100); ++i) {
    ReferenceSample r;
    r.time_s = 0.01 * i;
    const GeoPoint p = f.to_geo(dir * 10.0 * r.time_s);
    r.lat_deg = p.lat_deg;
    r.lon_deg = p.lon_deg;
    r.yaw_enu_rad = yaw_enu_rad;
    r.speed_mps = 10.0;
    ref.push_back(r);
  }
  return ref;
}

TEST(TrajectoryEval, NeesIsTheErrorWeightedByTheCovarianceInTheReferenceFrame) {
  const tiles::LocalFrame f(GeoPoint{48.4, 9.99, 0.0});
  const double yaw = 30.0 * kDeg;
  const auto ref = reference(f, yaw, 2.0);
  // One row 0.2 m ahead and 0.1 m left, 0.5° off, with a correlated covariance.
  TrajectoryRow r;
  r.time_s = 1.0;
  r.status = "tracking";
  const Eigen::Vector2d along(std::cos(yaw), std::sin(yaw)), left(-std::sin(yaw), std::cos(yaw));
  const GeoPoint p = f.to_geo(along * 10.0 + along * 0.2 + left * 0.1);
  r.lat_deg = p.lat_deg;
  r.lon_deg = p.lon_deg;
  r.yaw_enu_rad = yaw + 0.5 * kDeg;
  r.cov_xx_m2 = 0.04;
  r.cov_xy_m2 = 0.01;
  r.cov_yy_m2 = 0.02;
  r.cov_yaw_rad2 = std::pow(0.3 * kDeg, 2);
  r.pl_lat_m = 0.12;
  const auto m = evaluate_trajectory({r}, ref);
  ASSERT_EQ(m.evaluated, 1);
  const TrajectoryError& e = m.errors[0];
  // Reference: the error in east/north weighted by the east/north covariance (NEES does not
  // depend on the frame), plus the yaw term.
  const Eigen::Vector2d e_en = along * e.long_m + left * e.lat_m;
  Eigen::Matrix2d c;
  c << r.cov_xx_m2, r.cov_xy_m2, r.cov_xy_m2, r.cov_yy_m2;
  const double want = e_en.dot(c.inverse() * e_en) + std::pow(0.5 * kDeg, 2) / r.cov_yaw_rad2;
  EXPECT_NEAR(e.nees, want, 1e-3 * want);
  EXPECT_NEAR(e.long_m, 0.2, 1e-3);
  EXPECT_NEAR(e.lat_m, 0.1, 1e-3);
  EXPECT_NEAR(e.sigma_lat_m, std::sqrt(left.dot(c * left)), 1e-6);  // meridian convergence
  EXPECT_EQ(m.nees_samples, 1);
  EXPECT_EQ(m.pl_samples, 1);
  EXPECT_DOUBLE_EQ(m.pl_bounded_share, 1.0);  // 0.1 m across, bounded by 0.12 m
}

TEST(TrajectoryEval, ErrorsDrawnFromTheCovarianceGiveChiSquareStatistics) {
  const tiles::LocalFrame f(GeoPoint{48.4, 9.99, 0.0});
  const double yaw = -70.0 * kDeg;
  const auto ref = reference(f, yaw, 60.0);
  const Eigen::Vector2d along(std::cos(yaw), std::sin(yaw)), left(-std::sin(yaw), std::cos(yaw));
  std::mt19937 rng(7);
  std::normal_distribution<double> n01;
  // σ 8 cm east, 3 cm north, correlation 0.5; yaw σ 0.2°.
  Eigen::Matrix2d c;
  c << 0.0064, 0.5 * 0.08 * 0.03, 0.5 * 0.08 * 0.03, 0.0009;
  const Eigen::Matrix2d L = c.llt().matrixL();
  const double sigma_yaw = 0.2 * kDeg;
  std::vector<TrajectoryRow> rows;
  for (int i = 1; i < 20000; ++i) {
    TrajectoryRow r;
    r.time_s = 0.003 * i;
    r.status = "tracking";
    const Eigen::Vector2d e_en = L * Eigen::Vector2d(n01(rng), n01(rng));
    const GeoPoint p = f.to_geo(along * 10.0 * r.time_s + e_en);
    r.lat_deg = p.lat_deg;
    r.lon_deg = p.lon_deg;
    r.yaw_enu_rad = yaw + sigma_yaw * n01(rng);
    r.cov_xx_m2 = c(0, 0);
    r.cov_xy_m2 = c(0, 1);
    r.cov_yy_m2 = c(1, 1);
    r.cov_yaw_rad2 = sigma_yaw * sigma_yaw;
    r.pl_lat_m = 3.29 * std::sqrt(left.dot(c * left));
    rows.push_back(r);
  }
  const auto m = evaluate_trajectory(rows, ref);
  ASSERT_GT(m.nees_samples, 19000);
  EXPECT_NEAR(m.nees_mean, 3.0, 0.1);
  EXPECT_NEAR(m.nees_within_q95_share, 0.95, 0.006);
  EXPECT_GT(m.pl_bounded_share, 0.997);
  // An optimistic covariance (a quarter of the truth) shows: NEES ≈ 12.
  for (auto& r : rows) {
    r.cov_xx_m2 /= 4;
    r.cov_xy_m2 /= 4;
    r.cov_yy_m2 /= 4;
    r.cov_yaw_rad2 /= 4;
    r.pl_lat_m /= 2;
  }
  const auto o = evaluate_trajectory(rows, ref);
  EXPECT_NEAR(o.nees_mean, 12.0, 0.4);
  EXPECT_LT(o.nees_within_q95_share, 0.6);
  EXPECT_LT(o.pl_bounded_share, 0.9);
}

TEST(TrajectoryEval, ProtectionLevelsSurviveTheCsv) {
  const polmap::test::TestDir dir("trajectory-csv");
  const auto path = dir.path() / "t.csv";
  {
    TrajectoryCsvWriter w(path);
    TrajectoryRow r;
    r.time_s = 1.5;
    r.status = "tracking";
    r.lat_deg = 48.4;
    r.lon_deg = 9.99;
    r.pl_lat_m = 0.1234;
    w.write(r);
    w.close();
  }
  const auto rows = read_trajectory_csv(path);
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_DOUBLE_EQ(rows[0].pl_lat_m, 0.1234);
}

}  // namespace
}  // namespace polmap::eval
