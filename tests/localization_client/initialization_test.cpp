// The initialization rule on sequences of match results: which matches count, when a
// streak starts, continues, ends, and when it is ready to start tracking. The sequences
// replay what `polmap study --world rural --realism realistic` showed on a guardrail
// (candidates one post spacing apart within 1-3 cost units, flipping) and on a
// landmark-poor stretch (counting matches separated by matches of 4-5 associations); the
// relocalization check's confirmation on the checks that re-anchored or failed to.
#include "polmap/localization_client/initialization.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <optional>

namespace polmap::loc {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

MatchResult match(MatchResult::Status status, int points, double cost,
                  std::optional<double> runner_up_cost, const Pose2& T_map_odom) {
  MatchResult m;
  m.status = status;
  m.cost = cost;
  m.runner_up_cost = runner_up_cost;
  m.T_map_odom = T_map_odom;
  for (int i = 0; i < points; ++i) m.points.push_back({static_cast<std::uint64_t>(i), i, 0.1});
  return m;
}

/// A strong (counting) match at T_map_odom: 12 associations, margin 5.
MatchResult strong(const Pose2& T_map_odom) {
  return match(MatchResult::Status::Ok, 12, 200.0, 205.0, T_map_odom);
}

/// The vehicle driving along the odometry x axis: its pose after d metres.
Pose2 vehicle_at(double d_m) { return Pose2{d_m, 0.0, 0.0}; }

const Pose2 kTruth{500.0, -200.0, 0.3};

TEST(Initialization, CountsOnlyClearlyUnambiguousMatchesWithEnoughAssociations) {
  const InitializationConfig cfg;
  EXPECT_TRUE(counts_for_initialization(match(MatchResult::Status::Ok, 6, 100, 103, kTruth), cfg));
  EXPECT_FALSE(
      counts_for_initialization(match(MatchResult::Status::Ok, 6, 100, 102.9, kTruth), cfg));
  EXPECT_FALSE(counts_for_initialization(match(MatchResult::Status::Ok, 5, 100, 110, kTruth), cfg));
  EXPECT_FALSE(counts_for_initialization(
      match(MatchResult::Status::Ambiguous, 30, 100, 100.5, kTruth), cfg));
  // No distinct alternative at all: the margin is unbounded.
  EXPECT_TRUE(
      counts_for_initialization(match(MatchResult::Status::Ok, 6, 100, std::nullopt, kTruth), cfg));
  EXPECT_TRUE(std::isinf(clear_margin(match(MatchResult::Status::Ok, 6, 1, std::nullopt, kTruth))));
  EXPECT_DOUBLE_EQ(clear_margin(match(MatchResult::Status::Ok, 6, 100, 102.5, kTruth)), 2.5);
}

TEST(Initialization, PosesAgreeAtTheVehicleNotAtTheOdometryOrigin) {
  const InitializationConfig cfg;
  const Pose2 T_odom_vehicle = vehicle_at(200.0);
  const Pose2 a = kTruth;
  // 0.5 deg about the vehicle: the vehicle pose moves by 0.5 deg only -> agree.
  const Pose2 T_map_vehicle = a * T_odom_vehicle;
  const Pose2 about_vehicle =
      Pose2{T_map_vehicle.x_m, T_map_vehicle.y_m, T_map_vehicle.yaw_rad + 0.5 * kDeg} *
      T_odom_vehicle.inverse();
  EXPECT_TRUE(poses_agree(a, about_vehicle, T_odom_vehicle, cfg));
  // 0.5 deg about the odometry origin, 200 m behind: the vehicle moves 1.75 m -> disagree.
  const Pose2 about_origin{a.x_m, a.y_m, a.yaw_rad + 0.5 * kDeg};
  EXPECT_FALSE(poses_agree(a, about_origin, T_odom_vehicle, cfg));
  // Beyond the yaw tolerance (1 deg) at the vehicle -> disagree.
  const Pose2 turned =
      Pose2{T_map_vehicle.x_m, T_map_vehicle.y_m, T_map_vehicle.yaw_rad + 1.2 * kDeg} *
      T_odom_vehicle.inverse();
  EXPECT_FALSE(poses_agree(a, turned, T_odom_vehicle, cfg));
}

TEST(Initialization, ReadyOnlyAfterConfirmationsOverTheMinimumTravel) {
  InitializationStreak s;
  EXPECT_EQ(s.add(strong(kTruth), vehicle_at(0.0), 0.0), InitializationStreak::Step::Started);
  EXPECT_FALSE(s.ready(0.0));  // one match is no confirmation
  EXPECT_EQ(s.add(strong(kTruth), vehicle_at(5.0), 5.0), InitializationStreak::Step::Confirmed);
  EXPECT_EQ(s.add(strong(kTruth), vehicle_at(10.0), 10.0), InitializationStreak::Step::Confirmed);
  EXPECT_EQ(s.confirmations(), 3);
  EXPECT_FALSE(s.ready(10.0)) << "agreement over 10 m is not enough";
  const Pose2 later{kTruth.x_m + 0.1, kTruth.y_m, kTruth.yaw_rad};
  EXPECT_EQ(s.add(strong(later), vehicle_at(20.0), 20.0), InitializationStreak::Step::Confirmed);
  const auto T = s.ready(20.0);
  ASSERT_TRUE(T);
  EXPECT_DOUBLE_EQ(T->x_m, later.x_m) << "the streak hands over its latest counting match";
  s.reset();
  EXPECT_FALSE(s.ready(20.0));
}

TEST(Initialization, WeakAgreeingMatchesCarryTheStreakAcrossALandmarkPoorStretch) {
  // Two counting matches, then matches of 4-5 associations at the same pose: the
  // streak continues and is ready once it spans 20 m (rural seed 7: without this the
  // gate grew to 19 m and a match 6 m off won 10 s later).
  InitializationStreak s;
  s.add(strong(kTruth), vehicle_at(0.0), 0.0);
  s.add(strong(kTruth), vehicle_at(7.0), 7.0);
  const Pose2 near{kTruth.x_m + 0.2, kTruth.y_m - 0.1, kTruth.yaw_rad + 0.3 * kDeg};
  EXPECT_EQ(s.add(match(MatchResult::Status::Ok, 5, 200, 202, near), vehicle_at(14.0), 14.0),
            InitializationStreak::Step::Continued);
  EXPECT_FALSE(s.ready(14.0));
  EXPECT_EQ(s.add(match(MatchResult::Status::TooFewMatches, 2, 200, std::nullopt, near),
                  vehicle_at(21.0), 21.0),
            InitializationStreak::Step::Continued);
  const auto T = s.ready(21.0);
  ASSERT_TRUE(T);
  EXPECT_DOUBLE_EQ(T->x_m, kTruth.x_m) << "weak matches do not move the streak's pose";
  EXPECT_EQ(s.confirmations(), 2);

  // The same start, but a weak match elsewhere ends the streak.
  InitializationStreak t;
  t.add(strong(kTruth), vehicle_at(0.0), 0.0);
  t.add(strong(kTruth), vehicle_at(7.0), 7.0);
  const Pose2 elsewhere{kTruth.x_m + 5.0, kTruth.y_m, kTruth.yaw_rad};
  EXPECT_EQ(t.add(match(MatchResult::Status::Ok, 5, 200, 202, elsewhere), vehicle_at(14.0), 14.0),
            InitializationStreak::Step::Ended);
  EXPECT_EQ(t.add(strong(kTruth), vehicle_at(21.0), 21.0), InitializationStreak::Step::Started);
  EXPECT_FALSE(t.ready(21.0));
  // A match without any pose ends it too.
  EXPECT_EQ(t.add(match(MatchResult::Status::NoCandidate, 0, 0, std::nullopt, kTruth),
                  vehicle_at(22.0), 22.0),
            InitializationStreak::Step::Ended);
}

TEST(Initialization, AnAliasOnAPostRowWithSmallMarginsNeverStartsTracking) {
  // Guardrail posts every 3.66 m: the best match flips between the truth and the truth
  // one spacing ahead with 40+ associations and margins of 1-2.7 (rural seed 1 drive 2).
  // None counts, so no streak forms over 200 m of driving.
  InitializationStreak s;
  const double margins[] = {1.6, 1.17, 1.03, 1.96, 0.54, 1.26, 2.29, 2.69, 1.64, 2.21, 1.12};
  double d = 0.0;
  for (int k = 0; d < 200.0; ++k, d += 7.0) {
    const Pose2 T_odom_vehicle = vehicle_at(d);
    const Pose2 truth_vehicle = kTruth * T_odom_vehicle;
    const Pose2 alias_vehicle = truth_vehicle * Pose2{3.66, 0.0, 0.0};
    const Pose2 best = (k % 3 == 0 ? alias_vehicle : truth_vehicle) * T_odom_vehicle.inverse();
    const double cost = 250.0;
    const auto step = s.add(match(MatchResult::Status::Ok, 40 + k % 7, cost,
                                  cost + margins[k % std::size(margins)], best),
                            T_odom_vehicle, d);
    EXPECT_EQ(step, InitializationStreak::Step::Ended) << "at " << d << " m";
    EXPECT_FALSE(s.ready(d));
  }
}

TEST(Initialization, ACountingMatchThatDisagreesStartsANewStreak) {
  InitializationStreak s;
  s.add(strong(kTruth), vehicle_at(0.0), 0.0);
  s.add(strong(kTruth), vehicle_at(10.0), 10.0);
  const Pose2 other{kTruth.x_m, kTruth.y_m + 5.0, kTruth.yaw_rad};
  EXPECT_EQ(s.add(strong(other), vehicle_at(15.0), 15.0), InitializationStreak::Step::Started);
  EXPECT_EQ(s.confirmations(), 1);
  EXPECT_FALSE(s.ready(25.0)) << "the old streak's confirmations are gone";
  EXPECT_EQ(s.add(strong(other), vehicle_at(30.0), 30.0), InitializationStreak::Step::Confirmed);
  EXPECT_FALSE(s.ready(30.0)) << "the new streak spans 15 m only";
  const auto T = s.ready(35.0);
  ASSERT_TRUE(T);
  EXPECT_DOUBLE_EQ(T->y_m, other.y_m);
}

TEST(Relocalization, ReAnchorsOnTwoAgreeingChecksThatClearlyBeatTracking) {
  RelocalizationConfirmation r;
  // 45 wide against 33 tracking associations, margin 5 (rural seed 6 drive 3 at 19.7 s).
  EXPECT_FALSE(r.add(strong(kTruth), 5, true, vehicle_at(300.0))) << "one check is not enough";
  EXPECT_TRUE(r.pending());
  // The next check, 80 m later, 0.5 m and 0.5 deg from the first: confirmed.
  const Pose2 T_map_vehicle = kTruth * vehicle_at(380.0);
  const Pose2 second =
      Pose2{T_map_vehicle.x_m + 0.5, T_map_vehicle.y_m, T_map_vehicle.yaw_rad + 0.5 * kDeg} *
      vehicle_at(380.0).inverse();
  const auto T = r.add(strong(second), 5, true, vehicle_at(380.0));
  ASSERT_TRUE(T);
  EXPECT_DOUBLE_EQ(T->x_m, second.x_m) << "re-anchors at the confirming check's transform";
  EXPECT_FALSE(r.pending());

  // 2 m and 1.4 deg apart (what that drive's two checks gave in a curve): not confirmed
  // with the defaults; a wider tolerance (tried: it also confirmed guardrail aliases)
  // would.
  RelocalizationConfirmation strict;
  const Pose2 far =
      Pose2{T_map_vehicle.x_m + 2.0, T_map_vehicle.y_m, T_map_vehicle.yaw_rad + 1.4 * kDeg} *
      vehicle_at(380.0).inverse();
  strict.add(strong(kTruth), 5, true, vehicle_at(300.0));
  EXPECT_FALSE(strict.add(strong(far), 5, true, vehicle_at(380.0)));
  EXPECT_TRUE(strict.pending()) << "the second check is the new candidate";
  RelocalizationConfirmation wide({}, RelocalizationConfig{3, 2.5, 0.035});
  wide.add(strong(kTruth), 5, true, vehicle_at(300.0));
  EXPECT_TRUE(wide.add(strong(far), 5, true, vehicle_at(380.0)));
}

TEST(Relocalization, IgnoresChecksThatDoNotClearlyBeatTrackingOrAreNotAway) {
  const Pose2 T_odom_vehicle = vehicle_at(100.0);
  {
    // Margins of 1.2 and 1.5 with 6 associations against 2 (urban seed 10 drive 1, out of a
    // degraded stretch): Ok for the matcher, but they do not count.
    RelocalizationConfirmation r;
    EXPECT_FALSE(
        r.add(match(MatchResult::Status::Ok, 6, 65.5, 66.7, kTruth), 2, true, T_odom_vehicle));
    EXPECT_FALSE(r.pending());
    EXPECT_FALSE(
        r.add(match(MatchResult::Status::Ok, 6, 128.5, 130.0, kTruth), 2, true, T_odom_vehicle));
  }
  {
    // Clearly better but fewer than 3 more associations than tracking.
    RelocalizationConfirmation r;
    EXPECT_FALSE(r.add(strong(kTruth), 10, true, T_odom_vehicle));
    EXPECT_FALSE(r.pending());
  }
  {
    // Clearly better but where the estimate already is: nothing to re-anchor.
    RelocalizationConfirmation r;
    EXPECT_FALSE(r.add(strong(kTruth), 2, false, T_odom_vehicle));
    EXPECT_FALSE(r.pending());
  }
  {
    // Two candidates 5 m apart do not confirm each other; the second becomes the candidate.
    RelocalizationConfirmation r;
    EXPECT_FALSE(r.add(strong(kTruth), 2, true, T_odom_vehicle));
    const Pose2 other{kTruth.x_m, kTruth.y_m + 5.0, kTruth.yaw_rad};
    EXPECT_FALSE(r.add(strong(other), 2, true, T_odom_vehicle));
    EXPECT_TRUE(r.pending());
    const auto T = r.add(strong(other), 2, true, T_odom_vehicle);
    ASSERT_TRUE(T);
    EXPECT_DOUBLE_EQ(T->y_m, other.y_m);
  }
  {
    // A failed check in between clears the candidate.
    RelocalizationConfirmation r;
    EXPECT_FALSE(r.add(strong(kTruth), 2, true, T_odom_vehicle));
    EXPECT_FALSE(r.add(match(MatchResult::Status::Ambiguous, 30, 100, 100.5, kTruth), 2, true,
                       T_odom_vehicle));
    EXPECT_FALSE(r.pending());
  }
}

}  // namespace
}  // namespace polmap::loc
