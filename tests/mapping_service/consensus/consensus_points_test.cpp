// Point consensus (paper §III-D): cross-drive pairs closer than d_p, connected
// components, >= N_p drives; k-d tree result checked against brute force; the modes of
// a many-drive group do not depend on where the frame's origin is.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "polmap/mapping_service/consensus.hpp"

namespace polmap::mapping {
namespace {

TaggedPointCandidate cand(std::int64_t id, std::int64_t drive, double x, double y,
                          ScatteringClass cls = ScatteringClass::Odd) {
  TaggedPointCandidate c;
  c.candidate_id = id;
  c.drive = drive;
  c.candidate.position_m = {x, y};
  c.candidate.scattering = cls;
  return c;
}

TEST(ConsensusPoints, SingleDriveObjectsNeverBecomeLandmarks) {
  // A parked car seen five times in one drive: no consensus.
  std::vector<TaggedPointCandidate> in;
  for (int i = 0; i < 5; ++i) in.push_back(cand(i, 7, 3.0 + 0.01 * i, 4.0));
  const auto r = consensus_points(in);
  EXPECT_TRUE(r.landmarks.empty());
  EXPECT_EQ(r.stats.pairs, 0U);
  EXPECT_EQ(r.stats.rejected_groups, 5U);
}

TEST(ConsensusPoints, ReobservedPointMergesToTheMean) {
  const std::vector<TaggedPointCandidate> in{cand(10, 1, 10.00, 20.00), cand(11, 2, 10.10, 20.00),
                                             cand(12, 3, 10.05, 20.09)};
  const auto r = consensus_points(in);
  ASSERT_EQ(r.landmarks.size(), 1U);
  const auto& lm = r.landmarks[0];
  EXPECT_NEAR(lm.position_m.x(), 10.05, 1e-12);
  EXPECT_NEAR(lm.position_m.y(), 20.03, 1e-12);
  EXPECT_EQ(lm.support_drives, 3U);
  const double ss = 0.05 * 0.05 + 0.03 * 0.03 + 0.05 * 0.05 + 0.03 * 0.03 + 0.06 * 0.06;
  EXPECT_NEAR(lm.spread_m, std::sqrt(ss / 3.0), 1e-12);
  EXPECT_EQ(lm.scattering, ScatteringClass::Odd);
  EXPECT_EQ(r.support[0], (std::vector<std::int64_t>{10, 11, 12}));
}

TEST(ConsensusPoints, RespectsTheDistanceThreshold) {
  for (const auto& [d, merged] :
       {std::pair{0.29, true}, std::pair{0.31, false}, std::pair{0.2999999, true}}) {
    const std::vector<TaggedPointCandidate> in{cand(1, 1, 100.0, -50.0),
                                               cand(2, 2, 100.0 + d * 0.6, -50.0 + d * 0.8)};
    EXPECT_EQ(consensus_points(in).landmarks.size(), merged ? 1U : 0U) << d;
    EXPECT_EQ(consensus_points_bruteforce(in).landmarks.size(), merged ? 1U : 0U) << d;
  }
  PointConsensusConfig wide;
  wide.max_pair_distance_m = 0.5;
  EXPECT_EQ(
      consensus_points(std::vector{cand(1, 1, 0, 0), cand(2, 2, 0.45, 0)}, wide).landmarks.size(),
      1U);
}

TEST(ConsensusPoints, PairsOnlyAcrossDrives) {
  // Drive 1 has two points 0.2 m apart (no edge between them); drive 2 sees
  // only the second one.
  const std::vector<TaggedPointCandidate> in{cand(1, 1, 0.0, 0.0), cand(2, 1, 0.2, 0.0),
                                             cand(3, 2, 0.45, 0.0)};
  const auto r = consensus_points(in);
  ASSERT_EQ(r.landmarks.size(), 1U);
  EXPECT_NEAR(r.landmarks[0].position_m.x(), (0.2 + 0.45) / 2, 1e-12);
  EXPECT_EQ(r.support[0], (std::vector<std::int64_t>{2, 3}));
  EXPECT_EQ(r.stats.pairs, 1U);
}

TEST(ConsensusPoints, MinDrivesAndMajorityClass) {
  const std::vector<TaggedPointCandidate> in{
      cand(1, 1, 0, 0, ScatteringClass::Even), cand(2, 2, 0.1, 0, ScatteringClass::Even),
      cand(3, 3, 0.1, 0.1, ScatteringClass::Odd), cand(4, 4, 0, 0.1, ScatteringClass::Unknown)};
  PointConsensusConfig three;
  three.support.min_drives = 3;
  const auto r = consensus_points(in, three);
  ASSERT_EQ(r.landmarks.size(), 1U);
  EXPECT_EQ(r.landmarks[0].scattering, ScatteringClass::Even);
  three.support.min_drives = 5;
  EXPECT_TRUE(consensus_points(in, three).landmarks.empty());
  // Tie between classes -> Mixed.
  const std::vector<TaggedPointCandidate> tie{cand(1, 1, 0, 0, ScatteringClass::Even),
                                              cand(2, 2, 0.1, 0, ScatteringClass::Odd)};
  EXPECT_EQ(consensus_points(tie).landmarks[0].scattering, ScatteringClass::Mixed);
}

TEST(ConsensusPoints, SplitModesDoNotDependOnTheFrameOrigin) {
  // Bimodal clusters of 16 drives (two objects 0.34 m apart, chained into one component
  // by the candidates' noise): the builder's frame is centred on its region's candidates,
  // so the same candidates arrive shifted by an arbitrary offset; the landmarks must shift
  // with them and nothing else.
  std::mt19937 rng(11);
  std::normal_distribution<double> n(0.0, 0.04);
  std::vector<TaggedPointCandidate> in;
  std::int64_t id = 0;
  for (int k = 0; k < 20; ++k) {
    const Eigen::Vector2d c(3.0 * k, 0.5 * k);
    for (int d = 0; d < 16; ++d) {
      const double along = (d % 2 == 0 ? -0.17 : 0.17) + n(rng);
      in.push_back(cand(id++, d, c.x() + along, c.y() + n(rng)));
    }
  }
  const auto ref = consensus_points(in);
  ASSERT_GT(ref.stats.split_groups, 0U);
  for (const Eigen::Vector2d& off :
       {Eigen::Vector2d(0.0123, -0.0371), Eigen::Vector2d(-0.031, 0.017),
        Eigen::Vector2d(1234.5678, -876.5432)}) {
    std::vector<TaggedPointCandidate> moved = in;
    for (auto& c : moved) c.candidate.position_m += off;
    const auto r = consensus_points(moved);
    ASSERT_EQ(r.landmarks.size(), ref.landmarks.size()) << off.transpose();
    for (std::size_t i = 0; i < r.landmarks.size(); ++i) {
      EXPECT_LT((r.landmarks[i].position_m - off - ref.landmarks[i].position_m).norm(), 1e-6);
      EXPECT_EQ(r.support[i], ref.support[i]);
    }
  }
}

TEST(ConsensusPoints, ModesCloserThanThePairDistanceAreOneLandmark) {
  // A facade corner seen from its two faces: 16 drives, two modes 0.24 m apart (the
  // simulated urban route gave 0.23-0.28 m). One object: one landmark between them.
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 0.03);
  std::vector<TaggedPointCandidate> in;
  std::int64_t id = 0;
  for (int d = 0; d < 16; ++d) {
    const double along = (d < 10 ? -0.12 : 0.12) + n(rng);
    in.push_back(cand(id++, d, along, n(rng)));
  }
  const auto r = consensus_points(in);
  ASSERT_EQ(r.landmarks.size(), 1U);
  EXPECT_EQ(r.stats.split_groups, 0U);
  EXPECT_LT(std::abs(r.landmarks[0].position_m.y()), 0.05);
  EXPECT_LT(std::abs(r.landmarks[0].position_m.x()), 0.15);
}

TEST(ConsensusPoints, KdTreeEqualsBruteForceOnRandomSets) {
  std::mt19937 rng(42);
  for (int trial = 0; trial < 6; ++trial) {
    // Urban-like: objects re-observed with 10 cm noise by some drives, plus clutter.
    std::normal_distribution<double> noise(0.0, 0.1);
    std::uniform_real_distribution<double> u(-40.0, 40.0);
    std::uniform_int_distribution<int> drive(1, 6);
    std::vector<TaggedPointCandidate> in;
    std::int64_t id = 0;
    for (int o = 0; o < 300; ++o) {
      const double x = u(rng), y = u(rng);
      const int seen = std::uniform_int_distribution<int>(1, 5)(rng);
      for (int k = 0; k < seen; ++k)
        in.push_back(cand(id++, drive(rng), x + noise(rng), y + noise(rng)));
    }
    for (int k = 0; k < 500; ++k) in.push_back(cand(id++, drive(rng), u(rng), u(rng)));
    std::shuffle(in.begin(), in.end(), rng);
    const auto fast = consensus_points(in);
    const auto ref = consensus_points_bruteforce(in);
    ASSERT_EQ(fast.landmarks.size(), ref.landmarks.size());
    EXPECT_EQ(fast.support, ref.support);
    EXPECT_EQ(fast.stats.pairs, ref.stats.pairs);
    for (std::size_t i = 0; i < fast.landmarks.size(); ++i) {
      EXPECT_EQ(fast.landmarks[i].position_m, ref.landmarks[i].position_m);
      EXPECT_EQ(fast.landmarks[i].support_drives, ref.landmarks[i].support_drives);
    }
    EXPECT_GT(fast.landmarks.size(), 100U);
    // Deterministic: input order does not matter.
    std::shuffle(in.begin(), in.end(), rng);
    const auto again = consensus_points(in);
    EXPECT_EQ(again.support, fast.support);
  }
}

}  // namespace
}  // namespace polmap::mapping
