// The support rule of fleet consensus (consensus.hpp, SupportRule / judge_support):
// share of the passes in view, the recent window that lets new objects in, and
// retirement after misses of several vehicles, all in drive-time order.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "polmap/mapping_service/consensus.hpp"

namespace polmap::mapping {
namespace {

/// Pass k (drive k + 1) at time 1000 * (k + 1), vehicle vehicle_of(k), along the x axis.
template <typename VehicleOf>
std::vector<DrivePass> passes(int n, VehicleOf vehicle_of) {
  std::vector<DrivePass> out;
  for (int k = 0; k < n; ++k) {
    DrivePass p;
    p.drive = k + 1;
    p.start_time_s = 1000.0 * (k + 1);
    p.vehicle = vehicle_of(k);
    p.view_range_m = 30.0;
    p.path_m = {{-50.0, 0.0}, {50.0, 0.0}};
    out.push_back(p);
  }
  return out;
}

std::vector<std::int64_t> drives(int first, int last) {
  std::vector<std::int64_t> d;
  for (int i = first; i <= last; ++i) d.push_back(i);
  return d;
}

const Eigen::Vector2d kPlace(5.0, 4.0);

SupportVerdict judge(const std::vector<DrivePass>& p, const std::vector<std::int64_t>& support,
                     const SupportRule& rule = {}) {
  const VisibilityIndex view(p);
  return judge_support(&view, std::span(&kPlace, 1), support, rule);
}

TEST(SupportRule, RemovedObjectIsRetiredAfterMissesOfSeveralVehicles) {
  const auto p = passes(12, [](int k) { return k % 3; });
  const SupportVerdict v = judge(p, drives(1, 6));  // seen by the first six, then gone
  EXPECT_EQ(v.status, SupportVerdict::Status::Retired);
  EXPECT_EQ(v.drives_in_view, 12U);
  EXPECT_EQ(v.miss_streak, 6U);
  EXPECT_EQ(v.miss_streak_vehicles, 3U);
  EXPECT_DOUBLE_EQ(v.last_support_time_s, 6000.0);
}

TEST(SupportRule, OneVehicleCannotRetireALandmarkAlone) {
  // The six latest passes are all vehicle 9 (a faulty sensor, or a vehicle whose
  // view is blocked): the landmark stays.
  const auto p = passes(12, [](int k) { return k < 6 ? k % 3 : 9; });
  const SupportVerdict v = judge(p, drives(1, 6));
  EXPECT_EQ(v.status, SupportVerdict::Status::Accepted);
  EXPECT_EQ(v.miss_streak, 6U);
  EXPECT_EQ(v.miss_streak_vehicles, 1U);
}

TEST(SupportRule, ShortMissStreaksDoNotRetire) {
  SupportRule rule;
  rule.recent_passes = 8;  // recent: passes 5..12, support 5, 6, 7 = 3 < 4
  const auto p = passes(12, [](int k) { return k % 4; });
  const SupportVerdict v = judge(p, drives(1, 7), rule);
  EXPECT_EQ(v.miss_streak, 5U);
  EXPECT_EQ(v.status, SupportVerdict::Status::Retired);
  const SupportVerdict w = judge(p, drives(1, 8), rule);  // streak 4 < retire_min_misses
  EXPECT_EQ(w.miss_streak, 4U);
  EXPECT_EQ(w.status, SupportVerdict::Status::Accepted);
}

TEST(SupportRule, NewObjectIsAcceptedOnceRecentPassesSeeIt) {
  SupportRule rule;
  rule.recent_passes = 8;
  const auto p = passes(46, [](int k) { return k % 5; });
  // It appeared with drive 41; the six passes since all saw it.
  const SupportVerdict v = judge(p, drives(41, 46), rule);
  EXPECT_EQ(v.status, SupportVerdict::Status::Accepted);
  EXPECT_EQ(v.recent_passes, 8U);
  EXPECT_EQ(v.recent_support, 6U);
  // Three of the latest eight: not yet.
  EXPECT_EQ(judge(p, drives(44, 46), rule).status, SupportVerdict::Status::Rejected);
}

TEST(SupportRule, ClutterOfAFewOfManyDrivesIsRejected) {
  const auto p = passes(40, [](int k) { return k % 7; });
  const SupportVerdict v = judge(p, {3, 17, 31});
  EXPECT_EQ(v.status, SupportVerdict::Status::Rejected);
  EXPECT_EQ(v.drives_in_view, 40U);
}

TEST(SupportRule, DecisionsFollowDriveTimeNotUploadOrder) {
  auto p = passes(12, [](int k) { return k % 3; });
  std::mt19937 rng(11);
  for (int trial = 0; trial < 5; ++trial) {
    std::shuffle(p.begin(), p.end(), rng);  // the order drives were uploaded in
    const SupportVerdict v = judge(p, drives(1, 6));
    EXPECT_EQ(v.status, SupportVerdict::Status::Retired);
    EXPECT_EQ(v.miss_streak, 6U);
  }
  // The same support in the latest drives instead: accepted.
  EXPECT_EQ(judge(p, drives(7, 12)).status, SupportVerdict::Status::Accepted);
}

TEST(SupportRule, WithoutVisibilityTheFixedCountDecides) {
  EXPECT_EQ(
      judge_support(nullptr, std::span(&kPlace, 1), std::vector<std::int64_t>{4, 9}, {}).status,
      SupportVerdict::Status::Accepted);
  EXPECT_EQ(judge_support(nullptr, std::span(&kPlace, 1), std::vector<std::int64_t>{4}, {}).status,
            SupportVerdict::Status::Rejected);
}

}  // namespace
}  // namespace polmap::mapping
