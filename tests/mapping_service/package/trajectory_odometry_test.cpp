// TrajectoryOdometry: the trapezoid integrals of yaw rate and speed, and whether two samples
// alone reproduce them, against direct sums.
#include "polmap/mapping_service/trajectory_odometry.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace polmap::mapping {
namespace {

std::vector<TrajectorySample> samples(double (*yaw_rate)(double), double (*speed)(double)) {
  std::vector<TrajectorySample> t;
  for (int i = 0; i <= 500; ++i) {
    TrajectorySample s;
    s.time_s = 0.01 * i;
    s.yaw_rate_rps = yaw_rate(s.time_s);
    s.speed_mps = speed(s.time_s);
    t.push_back(s);
  }
  return t;
}

TEST(TrajectoryOdometry, LinearRatesAreKeptByAnyPairAndCurvedOnesOnlyByNearOnes) {
  // Yaw rate and speed linear in time: the trapezoid over any two samples is exact.
  const auto linear = samples([](double t) { return 0.1 * t; }, [](double t) { return 2.0 + t; });
  const TrajectoryOdometry lo(linear);
  EXPECT_TRUE(lo.kept_by(0, 500, 1e-9, 1e-9));
  EXPECT_TRUE(lo.kept_by(123, 321, 1e-9, 1e-9));
  // A turn: over 5 s the pair misses the integral of 0.3 sin(2t) (|error| = |[-0.15 cos 2t]
  // - 2.5 (0 + 0.3 sin 10)| ~ 0.68 rad); over 0.02 s it does not.
  const auto turn =
      samples([](double t) { return 0.3 * std::sin(2.0 * t); }, [](double) { return 5.0; });
  const TrajectoryOdometry to(turn);
  EXPECT_FALSE(to.kept_by(0, 500, 0.0005, 0.02));
  EXPECT_TRUE(to.kept_by(100, 102, 0.0005, 0.02));
  // The same check, by hand, for the pair (0, 250): full-rate trapezoid sum against the pair.
  double full = 0.0;
  for (std::size_t i = 1; i <= 250; ++i) {
    full += 0.5 * (turn[i - 1].yaw_rate_rps + turn[i].yaw_rate_rps) * 0.01;
  }
  const double pair = 0.5 * (turn[0].yaw_rate_rps + turn[250].yaw_rate_rps) * 2.5;
  const double err = std::abs(pair - full);
  EXPECT_TRUE(to.kept_by(0, 250, err + 1e-9, 1.0));
  EXPECT_FALSE(to.kept_by(0, 250, err - 1e-6, 1.0));
}

}  // namespace
}  // namespace polmap::mapping
