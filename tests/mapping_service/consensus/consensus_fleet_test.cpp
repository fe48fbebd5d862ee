// Fleet-scale consensus: support judged against the drives that had a place in view
// (consensus.hpp, visibility.hpp). Chance coincidences of clutter from a few of many
// drives are rejected; permanent objects seen by most passes are kept; small fleets
// keep the paper's fixed count.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "polmap/mapping_service/consensus.hpp"

namespace polmap::mapping {
namespace {

/// n drives along the x axis from -100 to 100 m, view range 30 m.
VisibilityIndex passes_along_x(int n, std::int64_t first_drive = 1) {
  std::vector<DrivePass> passes;
  for (int d = 0; d < n; ++d) {
    DrivePass p;
    p.drive = first_drive + d;
    p.view_range_m = 30.0;
    p.path_m = {{-100.0, 0.0}, {100.0, 0.0}};
    passes.push_back(p);
  }
  return VisibilityIndex(std::move(passes));
}

TaggedPointCandidate cand(std::int64_t id, std::int64_t drive, Eigen::Vector2d p) {
  TaggedPointCandidate c;
  c.candidate_id = id;
  c.drive = drive;
  c.candidate.position_m = p;
  return c;
}

TEST(RequiredSupport, FixedCountForSmallFleetsShareForLargeOnes) {
  EXPECT_EQ(required_support(2, 0.5, 0), 2);
  EXPECT_EQ(required_support(2, 0.5, 3), 2);
  EXPECT_EQ(required_support(2, 0.5, 4), 2);
  EXPECT_EQ(required_support(2, 0.5, 5), 3);
  EXPECT_EQ(required_support(2, 0.5, 64), 32);
  EXPECT_EQ(required_support(2, 0.3, 10), 3);
  EXPECT_EQ(required_support(2, 0.0, 256), 2);
  EXPECT_EQ(required_support(3, 0.1, 10), 3);
}

TEST(ConsensusFleet, ClutterCoincidenceOfFewOfManyDrivesIsRejected) {
  const VisibilityIndex view = passes_along_x(40);
  std::vector<TaggedPointCandidate> in;
  std::int64_t id = 0;
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.04);
  // A pole at (10, 5) detected by 36 of the 40 drives.
  for (int d = 1; d <= 36; ++d) in.push_back(cand(id++, d, {10 + noise(rng), 5 + noise(rng)}));
  // Clutter of three drives that happens to coincide at (-20, 8).
  for (int d = 1; d <= 3; ++d) in.push_back(cand(id++, d, {-20 + 0.05 * d, 8.0}));
  const auto fixed = consensus_points(in);
  EXPECT_EQ(fixed.landmarks.size(), 2U);  // the fixed count keeps the coincidence
  const auto fleet = consensus_points(in, {}, &view);
  ASSERT_EQ(fleet.landmarks.size(), 1U);
  EXPECT_NEAR(fleet.landmarks[0].position_m.x(), 10.0, 0.03);
  EXPECT_EQ(fleet.landmarks[0].support_drives, 36U);
  EXPECT_EQ(fleet.verdicts[0].drives_in_view, 40U);
  EXPECT_EQ(fleet.stats.rejected_groups, 1U);
}

TEST(ConsensusFleet, PlacesFewDrivesPassedKeepThePapersFixedCount) {
  // 40 drives pass x in [-100, 100]; only 2 of them drove on to (300, 0).
  std::vector<DrivePass> passes;
  for (int d = 1; d <= 40; ++d) {
    DrivePass p;
    p.drive = d;
    p.view_range_m = 30.0;
    p.path_m = {{-100.0, 0.0}, {d <= 2 ? 320.0 : 100.0, 0.0}};
    passes.push_back(p);
  }
  const VisibilityIndex view(std::move(passes));
  const std::vector<TaggedPointCandidate> in{cand(1, 1, {300, 6}), cand(2, 2, {300.1, 6})};
  const auto r = consensus_points(in, {}, &view);
  ASSERT_EQ(r.landmarks.size(), 1U);
  EXPECT_EQ(r.verdicts[0].drives_in_view, 2U);
}

TEST(ConsensusFleet, SupportingDrivesCountAsInViewWhateverTheRangeModel) {
  // Two drives pass 30 m away with a 10 m range model but did detect the object: the
  // denominator includes them (it is never smaller than the support).
  std::vector<DrivePass> passes;
  for (int d = 1; d <= 2; ++d) {
    DrivePass p;
    p.drive = d;
    p.view_range_m = 10.0;
    p.path_m = {{-100.0, 0.0}, {100.0, 0.0}};
    passes.push_back(p);
  }
  const VisibilityIndex view(std::move(passes));
  const std::vector<TaggedPointCandidate> in{cand(1, 1, {0, 30}), cand(2, 2, {0.1, 30})};
  const auto r = consensus_points(in, {}, &view);
  ASSERT_EQ(r.landmarks.size(), 1U);
  EXPECT_EQ(r.verdicts[0].drives_in_view, 2U);
}

TEST(ConsensusFleet, ShareThresholdIsConfigurable) {
  const VisibilityIndex view = passes_along_x(10);
  std::vector<TaggedPointCandidate> in;
  for (int d = 1; d <= 4; ++d) in.push_back(cand(d, d, {0.01 * d, 3.0}));  // 4 of 10
  PointConsensusConfig cfg;
  cfg.support.min_view_fraction = 0.5;
  EXPECT_TRUE(consensus_points(in, cfg, &view).landmarks.empty());
  cfg.support.min_view_fraction = 0.4;
  EXPECT_EQ(consensus_points(in, cfg, &view).landmarks.size(), 1U);
  EXPECT_EQ(consensus_points_bruteforce(in, cfg, &view).landmarks.size(), 1U);
}

TEST(ConsensusFleet, LinesAreJudgedAgainstTheDrivesThatPassedThem) {
  const VisibilityIndex view = passes_along_x(30);
  auto line = [](std::int64_t id, std::int64_t drive, double y) {
    TaggedLineCandidate l;
    l.candidate_id = id;
    l.drive = drive;
    l.candidate.start_m = {-10.0, y};
    l.candidate.end_m = {10.0, y};
    return l;
  };
  std::vector<TaggedLineCandidate> in;
  std::int64_t id = 0;
  for (int d = 1; d <= 27; ++d) in.push_back(line(id++, d, 9.0 + 0.002 * d));  // a wall
  for (int d = 1; d <= 3; ++d) in.push_back(line(id++, d, -6.0 + 0.002 * d));  // coincidence
  EXPECT_EQ(consensus_lines(in).landmarks.size(), 2U);
  const auto r = consensus_lines(in, {}, &view);
  ASSERT_EQ(r.landmarks.size(), 1U);
  EXPECT_NEAR(r.landmarks[0].polyline_m.front().y(), 9.03, 0.01);
  EXPECT_EQ(r.verdicts[0].drives_in_view, 30U);
  EXPECT_EQ(r.stats.rejected_groups, 1U);
}

}  // namespace
}  // namespace polmap::mapping

namespace polmap::mapping {
namespace {

TEST(ConsensusFleet, ChainedNeighboursOfManyDrivesAreSplitAtTheirModes) {
  // Two poles 0.45 m apart, each seen by 30 drives with 6 cm noise: with so many
  // candidates, noise tails chain them into one component; it holds two objects.
  std::mt19937 rng(2);
  std::normal_distribution<double> noise(0.0, 0.06);
  std::vector<TaggedPointCandidate> in;
  std::int64_t id = 0;
  for (int d = 1; d <= 30; ++d) {
    in.push_back(cand(id++, d, {noise(rng), noise(rng)}));
    in.push_back(cand(id++, d, {0.45 + noise(rng), noise(rng)}));
  }
  PointConsensusConfig whole;
  whole.split_min_drives = 1000;  // never split: the chained component stays one
  const auto chained = consensus_points(in, whole);
  ASSERT_EQ(chained.landmarks.size(), 1U);
  const auto r = consensus_points(in);
  ASSERT_EQ(r.landmarks.size(), 2U);
  EXPECT_EQ(r.stats.split_groups, 1U);
  std::vector<double> xs{r.landmarks[0].position_m.x(), r.landmarks[1].position_m.x()};
  std::sort(xs.begin(), xs.end());
  EXPECT_NEAR(xs[0], 0.0, 0.03);
  EXPECT_NEAR(xs[1], 0.45, 0.03);
  for (const auto& lm : r.landmarks) EXPECT_GE(lm.support_drives, 25U);
}

TEST(ConsensusFleet, ClutterAtTheRimDoesNotPullAManyDriveLandmark) {
  std::mt19937 rng(4);
  std::normal_distribution<double> noise(0.0, 0.03);
  std::vector<TaggedPointCandidate> in;
  std::int64_t id = 0;
  for (int d = 1; d <= 40; ++d) in.push_back(cand(id++, d, {noise(rng), noise(rng)}));
  // Six clutter candidates of other drives chained on one side, 0.2–0.45 m away.
  for (int k = 0; k < 6; ++k) in.push_back(cand(id++, 100 + k, {0.2 + 0.05 * k, 0.0}));
  // All 46 drives passed; the clutter's six are far below half of them.
  std::vector<DrivePass> passes;
  for (std::int64_t d : {1, 100}) {
    const VisibilityIndex part = passes_along_x(d == 1 ? 40 : 6, d);
    passes.insert(passes.end(), part.passes().begin(), part.passes().end());
  }
  const VisibilityIndex view(std::move(passes));
  PointConsensusConfig plain;
  plain.split_min_drives = 1000;
  const auto p = consensus_points(in, plain, &view);
  const auto r = consensus_points(in, {}, &view);
  ASSERT_EQ(p.landmarks.size(), 1U);
  ASSERT_EQ(r.landmarks.size(), 1U);
  double truth_x = 0.0;
  for (int i = 0; i < 40; ++i) truth_x += in[static_cast<std::size_t>(i)].candidate.position_m.x();
  truth_x /= 40.0;
  // The plain mean moves by ~6 * 0.325 / 46 = 4 cm; the mode stays on the pole.
  EXPECT_GT(std::abs(p.landmarks[0].position_m.x() - truth_x), 0.03);
  EXPECT_LT(std::abs(r.landmarks[0].position_m.x() - truth_x), 0.01);
}

}  // namespace
}  // namespace polmap::mapping
