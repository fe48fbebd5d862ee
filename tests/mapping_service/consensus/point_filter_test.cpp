// Precision filters of fleet point consensus (point_filter.hpp): temporary objects
// (neighbouring landmarks present and absent together) and line peaks, checked against
// brute-force references (the hypergeometric tail by enumeration of all drive subsets,
// the 2×2 tables by counting drives).
#include "polmap/mapping_service/point_filter.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <map>
#include <random>
#include <set>

#include "polmap/mapping_service/consensus.hpp"

namespace polmap::mapping {
namespace {

VisibilityIndex passes_along_x(int n) {
  std::vector<DrivePass> passes;
  for (int d = 0; d < n; ++d) {
    DrivePass p;
    p.drive = d + 1;
    p.view_range_m = 30.0;
    p.start_time_s = 1000.0 * (d + 1);
    p.vehicle = d % 7;
    p.path_m = {{-100.0, 0.0}, {100.0, 0.0}};
    passes.push_back(p);
  }
  return VisibilityIndex(std::move(passes));
}

/// Appends a candidate of drive d at p; its id is its index in `in`.
void add_candidate(std::vector<TaggedPointCandidate>& in, std::int64_t d,
                   const Eigen::Vector2d& p) {
  TaggedPointCandidate c;
  c.candidate_id = static_cast<std::int64_t>(in.size());
  c.drive = d;
  c.candidate.position_m = p;
  in.push_back(c);
}

/// Brute force: P(X >= both) by enumerating which `col` of the n passes the second
/// landmark is detected in (n small), the first being detected in the first `row`.
double fisher_bruteforce(int both, int first_only, int second_only, int neither) {
  const int n = both + first_only + second_only + neither;
  const int row = both + first_only, col = both + second_only;
  std::size_t total = 0, tail = 0;
  for (std::uint32_t mask = 0; mask < (1U << n); ++mask) {
    if (std::popcount(mask) != col) continue;
    ++total;
    const int x = std::popcount(mask & ((1U << row) - 1U));
    if (x >= both) ++tail;
  }
  return static_cast<double>(tail) / static_cast<double>(total);
}

TEST(FisherPositive, MatchesEnumeration) {
  for (int a = 0; a <= 5; ++a) {
    for (int b = 0; b <= 4; ++b) {
      for (int c = 0; c <= 4; ++c) {
        for (int d = 0; d <= 4; ++d) {
          if (a + b + c + d == 0 || a + b + c + d > 16) continue;
          EXPECT_NEAR(fisher_positive_p(a, b, c, d), fisher_bruteforce(a, b, c, d), 1e-9)
              << a << " " << b << " " << c << " " << d;
        }
      }
    }
  }
  // Independent-looking table: no evidence; perfectly associated: strong evidence.
  EXPECT_GT(fisher_positive_p(9, 1, 1, 0), 0.5);
  EXPECT_LT(fisher_positive_p(10, 0, 0, 6), 1e-3);
}

/// A street scene over n drives: a parked car (4 scattering centres in a 4 × 1.8 m box)
/// present in each drive with probability 0.6 and then detected per centre with 0.95;
/// permanent objects detected independently with 0.85: a lone pole, and a sign pole
/// with its plate 1.5 m apart.
struct Scene {
  std::vector<TaggedPointCandidate> candidates;
  std::vector<Eigen::Vector2d> car_centres{{20.0, -3.0}, {23.5, -3.0}, {20.3, -4.6}, {23.2, -4.6}};
  std::vector<Eigen::Vector2d> permanent{{-15.0, 5.0}, {40.0, 6.0}, {41.5, 6.0}};
  std::set<std::int64_t> car_present;
};

Scene make_scene(int n, unsigned seed, double car_presence = 0.6) {
  Scene s;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.04);
  std::int64_t id = 0;
  auto add = [&](std::int64_t drive, const Eigen::Vector2d& p) {
    TaggedPointCandidate c;
    c.candidate_id = id++;
    c.drive = drive;
    c.candidate.position_m = p + Eigen::Vector2d(noise(rng), noise(rng));
    s.candidates.push_back(c);
  };
  for (int d = 1; d <= n; ++d) {
    const bool car = u01(rng) < car_presence;
    if (car) s.car_present.insert(d);
    for (const auto& c : s.car_centres) {
      if (car && u01(rng) < 0.95) add(d, c);
    }
    for (const auto& p : s.permanent) {
      if (u01(rng) < 0.85) add(d, p);
    }
  }
  return s;
}

bool has_landmark_near(const PointConsensusResult& r, const Eigen::Vector2d& p) {
  return std::any_of(r.landmarks.begin(), r.landmarks.end(),
                     [&](const PointLandmark& l) { return (l.position_m - p).norm() < 0.2; });
}

TEST(PointFilter, ParkedCarPresentInSixtyPercentIsRejectedPermanentObjectsKept) {
  for (int n : {16, 64, 256}) {
    for (unsigned seed : {1U, 2U, 3U}) {
      const Scene s = make_scene(n, seed);
      const VisibilityIndex view = passes_along_x(n);
      PointConsensusResult pc = consensus_points(s.candidates, {}, &view);
      // Without the filter the car centres are landmarks (present and detected in more
      // than half of the drives).
      std::size_t car_before = 0;
      for (const auto& c : s.car_centres) car_before += has_landmark_near(pc, c) ? 1 : 0;
      const PointFilterResult f = filter_point_landmarks(pc, LineConsensusResult{}, s.candidates,
                                                         &view, PointFilterConfig{});
      for (const auto& c : s.car_centres) {
        EXPECT_FALSE(has_landmark_near(pc, c)) << "n " << n << " seed " << seed;
      }
      for (const auto& p : s.permanent) {
        EXPECT_TRUE(has_landmark_near(pc, p)) << "n " << n << " seed " << seed;
      }
      EXPECT_EQ(f.temporary, car_before);
      EXPECT_EQ(pc.landmarks.size(), s.permanent.size());
      EXPECT_EQ(pc.support.size(), pc.landmarks.size());
      for (std::size_t i = 0; i < pc.landmarks.size(); ++i) {
        EXPECT_EQ(pc.landmarks[i].id, static_cast<std::int64_t>(i));
      }
    }
  }
}

TEST(PointFilter, EvidenceMatchesBruteForceTables) {
  const int n = 32;
  const Scene s = make_scene(n, 7);
  const VisibilityIndex view = passes_along_x(n);
  PointConsensusResult pc = consensus_points(s.candidates, {}, &view);
  const PointConsensusResult before = pc;
  PointFilterConfig cfg;
  cfg.co_presence.enabled = false;  // measure only
  const PointFilterResult f =
      filter_point_landmarks(pc, LineConsensusResult{}, s.candidates, &view, cfg);
  ASSERT_EQ(f.evidence.size(), before.landmarks.size());
  std::map<std::int64_t, std::int64_t> drive_of;
  for (const auto& c : s.candidates) drive_of[c.candidate_id] = c.drive;
  std::vector<std::set<std::int64_t>> support(before.landmarks.size());
  for (std::size_t i = 0; i < before.landmarks.size(); ++i) {
    for (auto id : before.support[i]) support[i].insert(drive_of[id]);
  }
  for (std::size_t i = 0; i < before.landmarks.size(); ++i) {
    EXPECT_EQ(f.evidence[i].passes_in_view, static_cast<std::uint32_t>(n));
    EXPECT_EQ(f.evidence[i].support, support[i].size());
    double best = 1.0;
    for (std::size_t j = 0; j < before.landmarks.size(); ++j) {
      if (j == i || (before.landmarks[j].position_m - before.landmarks[i].position_m).norm() >=
                        PointFilterConfig{}.co_presence.neighbour_radius_m) {
        continue;
      }
      int a = 0, b = 0, c = 0, d = 0;
      for (int drive = 1; drive <= n; ++drive) {
        const bool si = support[i].contains(drive), sj = support[j].contains(drive);
        (si ? (sj ? a : b) : (sj ? c : d)) += 1;
      }
      if (a == 0 || d == 0) continue;
      best = std::min(best, fisher_positive_p(a, b, c, d));
    }
    EXPECT_NEAR(f.evidence[i].co_presence_p, best, 1e-12);
  }
  EXPECT_EQ(pc.landmarks.size(), before.landmarks.size());  // disabled: nothing removed
}

TEST(PointFilter, FewPassesOnlyPerfectCoPresenceCounts) {
  // Four drives: the car is there in drives 1 and 3 with all centres detected; the sign
  // pole and plate are missed together once (drive 4) but the plate also in drive 2.
  const VisibilityIndex view = passes_along_x(4);
  std::vector<TaggedPointCandidate> in;
  auto add = [&](std::int64_t d, const Eigen::Vector2d& p) { add_candidate(in, d, p); };
  for (int d : {1, 3}) {
    add(d, {20.0, -3.0});
    add(d, {22.5, -3.0});
  }
  for (int d : {1, 2, 3}) add(d, {40.0, 6.0});
  for (int d : {1, 3}) add(d, {41.5, 6.0});
  PointConsensusResult pc = consensus_points(in, {}, &view);
  ASSERT_EQ(pc.landmarks.size(), 4U);
  const PointFilterResult f = filter_point_landmarks(pc, LineConsensusResult{}, in, &view);
  EXPECT_EQ(f.temporary, 2U);
  EXPECT_TRUE(has_landmark_near(pc, {40.0, 6.0}));
  EXPECT_TRUE(has_landmark_near(pc, {41.5, 6.0}));
  EXPECT_FALSE(has_landmark_near(pc, {20.0, -3.0}));
}

TEST(PointFilter, PermanentObjectsDetectedByNearlyAllPassesAreKept) {
  // Two permanent neighbours detected in 90 % of 64 passes, their misses sharing an
  // occluder (the same passes): associated, but above max_detection_share.
  const int n = 64;
  const VisibilityIndex view = passes_along_x(n);
  std::vector<TaggedPointCandidate> in;
  std::int64_t id = 0;
  for (int d = 1; d <= n; ++d) {
    if (d % 16 == 0) continue;  // occluded together (60 of 64 detected)
    for (const Eigen::Vector2d& p : {Eigen::Vector2d(5.0, 5.0), Eigen::Vector2d(6.0, 5.0)}) {
      TaggedPointCandidate c;
      c.candidate_id = id++;
      c.drive = d;
      c.candidate.position_m = p;
      in.push_back(c);
    }
  }
  PointConsensusResult pc = consensus_points(in, {}, &view);
  ASSERT_EQ(pc.landmarks.size(), 2U);
  const PointFilterResult f = filter_point_landmarks(pc, LineConsensusResult{}, in, &view);
  EXPECT_EQ(f.temporary, 0U);
  EXPECT_EQ(pc.landmarks.size(), 2U);
  EXPECT_LT(f.evidence[0].co_presence_p, 1e-5);  // associated all the same: 1 / C(64, 4)
}

TEST(PointFilter, LinePeaksOnACurbGoPoleBesideItStays) {
  // A curb along y = -3 (a line landmark) with repeatable peaks whose candidates scatter
  // along it; a pole 0.35 m behind the curb with isotropic noise.
  const int n = 16;
  const VisibilityIndex view = passes_along_x(n);
  std::mt19937 rng(3);
  std::normal_distribution<double> along(0.0, 0.07), iso(0.0, 0.03);
  std::vector<TaggedPointCandidate> in;
  auto add = [&](std::int64_t d, const Eigen::Vector2d& p) { add_candidate(in, d, p); };
  const std::vector<double> peaks{-20.0, -5.0, 12.0};
  const Eigen::Vector2d pole(3.0, -3.35);
  for (int d = 1; d <= n; ++d) {
    for (double x : peaks) add(d, {x + along(rng), -3.0 + 0.3 * iso(rng)});
    add(d, pole + Eigen::Vector2d(iso(rng), iso(rng)));
  }
  LineConsensusResult lines;
  LineLandmark curb;
  curb.polyline_m = {{-40.0, -3.0}, {40.0, -3.0}};
  lines.landmarks.push_back(curb);
  PointConsensusResult pc = consensus_points(in, {}, &view);
  const PointConsensusResult before = pc;
  ASSERT_GE(pc.landmarks.size(), peaks.size() + 1);
  PointFilterConfig cfg;
  cfg.line_peaks.enabled = true;
  const PointFilterResult f = filter_point_landmarks(pc, lines, in, &view, cfg);
  EXPECT_EQ(f.line_peaks, before.landmarks.size() - 1);
  ASSERT_EQ(pc.landmarks.size(), 1U);
  EXPECT_LT((pc.landmarks[0].position_m - pole).norm(), 0.05);
  // The measured distances and spreads against a direct computation over the members.
  std::map<std::int64_t, Eigen::Vector2d> at;
  for (const auto& c : in) at[c.candidate_id] = c.candidate.position_m;
  for (std::size_t i = 0; i < before.landmarks.size(); ++i) {
    const Eigen::Vector2d m = before.landmarks[i].position_m;
    EXPECT_NEAR(f.evidence[i].line_distance_m, std::abs(m.y() + 3.0), 1e-9);
    double sa = 0.0, sc = 0.0;
    for (auto id : before.support[i]) {
      sa += std::pow(at[id].x() - m.x(), 2);
      sc += std::pow(at[id].y() - m.y(), 2);
    }
    const auto k = static_cast<double>(before.support[i].size());
    EXPECT_NEAR(f.evidence[i].along_spread_m, std::sqrt(sa / k), 1e-9);
    EXPECT_NEAR(f.evidence[i].across_spread_m, std::sqrt(sc / k), 1e-9);
  }
}

TEST(PointFilter, OddPeaksInsideAWallNeedMostPassesCornersRecessesAndPolesDoNot) {
  // Four passes along x; a facade (line landmark) along y = -5 with a bend at x = 0.
  const int n = 4;
  const VisibilityIndex view = passes_along_x(n);
  std::vector<TaggedPointCandidate> in;
  std::int64_t id = 0;
  auto object = [&](Eigen::Vector2d p, ScatteringClass cls, int drives) {
    for (int d = 1; d <= drives; ++d) {
      TaggedPointCandidate c;
      c.candidate_id = id++;
      c.drive = d;
      c.candidate.position_m = p + Eigen::Vector2d(0.01 * d, -0.01 * d);
      c.candidate.scattering = cls;
      in.push_back(c);
    }
  };
  object({10.0, -5.0}, ScatteringClass::Odd, 2);   // 0: wall peak, 2 of 4: removed
  object({-10.0, -5.0}, ScatteringClass::Odd, 3);  // 1: 3 of 4 (> 0.6): kept
  object({20.0, -5.0}, ScatteringClass::Even, 2);  // 2: recess (even): kept
  object({0.4, -5.0}, ScatteringClass::Odd, 2);    // 3: at the bend (a corner): kept
  object({5.0, -3.0}, ScatteringClass::Odd, 2);    // 4: a pole 2 m in front: kept
  object({-20.0, -4.8}, ScatteringClass::Odd, 2);  // 5: 0.2 m off the wall: removed
  LineConsensusResult lines;
  LineLandmark wall;
  wall.polyline_m = {{-40.0, -5.0}, {0.0, -5.0}, {40.0, -5.2}};
  lines.landmarks.push_back(wall);
  PointConsensusResult pc = consensus_points(in, {}, &view);
  ASSERT_EQ(pc.landmarks.size(), 6U);
  std::vector<Eigen::Vector2d> before;
  for (const auto& l : pc.landmarks) before.push_back(l.position_m);
  const PointFilterResult f = filter_point_landmarks(pc, lines, in, &view);
  EXPECT_EQ(f.surface_peaks, 2U);
  using V = PointEvidence::Verdict;
  std::vector<V> expect(6, V::Kept);
  for (std::size_t i = 0; i < before.size(); ++i) {
    const Eigen::Vector2d p = before[i];
    // Objects were added in order; consensus keeps candidate-id order.
    EXPECT_NEAR(
        f.evidence[i].vertex_distance_m,
        std::min({(p - Eigen::Vector2d(-40, -5)).norm(), (p - Eigen::Vector2d(0, -5)).norm(),
                  (p - Eigen::Vector2d(40, -5.2)).norm()}),
        1e-9);
  }
  EXPECT_EQ(f.evidence[0].verdict, V::SurfacePeak);
  EXPECT_EQ(f.evidence[5].verdict, V::SurfacePeak);
  for (std::size_t i : {1U, 2U, 3U, 4U}) EXPECT_EQ(f.evidence[i].verdict, V::Kept) << i;
  EXPECT_EQ(pc.landmarks.size(), 4U);
  // Off: everything stays.
  PointConsensusResult again = consensus_points(in, {}, &view);
  PointFilterConfig off;
  off.surface_peaks.enabled = false;
  EXPECT_EQ(filter_point_landmarks(again, lines, in, &view, off).surface_peaks, 0U);
  EXPECT_EQ(again.landmarks.size(), 6U);
}

TEST(PointFilter, DisabledByDefaultLinePeakRuleKeepsEverything) {
  const int n = 6;
  const VisibilityIndex view = passes_along_x(n);
  std::vector<TaggedPointCandidate> in;
  std::int64_t id = 0;
  for (int d = 1; d <= n; ++d) {
    TaggedPointCandidate c;
    c.candidate_id = id++;
    c.drive = d;
    c.candidate.position_m = {0.1 * d - 0.35, -3.0};  // elongated along the curb
    in.push_back(c);
  }
  LineConsensusResult lines;
  LineLandmark curb;
  curb.polyline_m = {{-40.0, -3.0}, {40.0, -3.0}};
  lines.landmarks.push_back(curb);
  PointConsensusResult pc = consensus_points(in, {}, &view);
  ASSERT_EQ(pc.landmarks.size(), 1U);
  PointFilterConfig cfg;  // the defaults, but for the sliding rule, which this group meets
  cfg.sliding.enabled = false;
  const PointFilterResult f = filter_point_landmarks(pc, lines, in, &view, cfg);
  EXPECT_EQ(f.line_peaks, 0U);
  EXPECT_EQ(pc.landmarks.size(), 1U);
  EXPECT_GT(f.evidence[0].along_spread_m, 3.0 * f.evidence[0].across_spread_m);
}

TEST(PointFilter, SupportBeyondTheModelledViewIsJudgedAgainstPassesAsClose) {
  // 40 drives along the x axis with a modelled view range of 10 m. Clutter 14 m off the
  // path seen by 2 of them: outside every pass's modelled view, so the support rule's
  // denominator is its own two supporters and it is accepted; every pass came as close,
  // so the filter needs 20. A far object seen by 30 of the 40 stays.
  const int n = 40;
  std::vector<DrivePass> passes;
  for (int d = 0; d < n; ++d) {
    DrivePass p;
    p.drive = d + 1;
    p.view_range_m = 10.0;
    p.start_time_s = 1000.0 * (d + 1);
    p.vehicle = d % 5;
    p.path_m = {{-100.0, 0.0}, {100.0, 0.0}};
    passes.push_back(p);
  }
  const VisibilityIndex view(std::move(passes));
  std::vector<TaggedPointCandidate> in;
  auto add = [&](std::int64_t d, const Eigen::Vector2d& p) { add_candidate(in, d, p); };
  add(3, {5.0, 14.0});
  add(17, {5.05, 14.0});
  for (int d = 1; d <= 30; ++d) add(d, {-30.0, -14.0});
  PointConsensusResult pc = consensus_points(in, {}, &view);
  ASSERT_EQ(pc.landmarks.size(), 2U);  // the support rule accepts both
  const PointFilterResult f = filter_point_landmarks(pc, LineConsensusResult{}, in, &view);
  EXPECT_EQ(f.out_of_view, 1U);
  ASSERT_EQ(pc.landmarks.size(), 1U);
  EXPECT_LT((pc.landmarks[0].position_m - Eigen::Vector2d(-30.0, -14.0)).norm(), 0.01);
  for (const auto& e : f.evidence) EXPECT_EQ(e.passes_as_close, static_cast<std::uint32_t>(n));
  // A fleet of two (the leave-one-out studies) is unchanged.
  const VisibilityIndex two([] {
    std::vector<DrivePass> p(2);
    for (int d = 0; d < 2; ++d) {
      p[d].drive = d == 0 ? 3 : 17;
      p[d].view_range_m = 10.0;
      p[d].path_m = {{-100.0, 0.0}, {100.0, 0.0}};
    }
    return p;
  }());
  std::vector<TaggedPointCandidate> pair(in.begin(), in.begin() + 2);
  PointConsensusResult pc2 = consensus_points(pair, {}, &two);
  ASSERT_EQ(pc2.landmarks.size(), 1U);
  EXPECT_EQ(filter_point_landmarks(pc2, LineConsensusResult{}, pair, &two).out_of_view, 0U);
  EXPECT_EQ(pc2.landmarks.size(), 1U);
}

TEST(PointFilter, ObjectsStandingElsewhereEachDriveSlideAlongTheRoadAndGo) {
  // 16 passes along the x axis. A bin stands within +-0.25 m of its place along the road in
  // each drive it is there (12 of 16): its candidates chain into one group of 12 drives
  // that the support rule accepts, with an RMS spread along the road of ~0.14 m. Poles
  // with 4 cm and 8 cm of isotropic noise stay, and so does an object sliding ACROSS the
  // road (the rule judges spread along the direction of travel only).
  const int n = 16;
  const VisibilityIndex view = passes_along_x(n);
  for (unsigned seed : {1U, 2U, 3U, 4U}) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> noise(0.0, 1.0);
    std::vector<TaggedPointCandidate> in;
    auto add = [&](std::int64_t d, const Eigen::Vector2d& p) { add_candidate(in, d, p); };
    const Eigen::Vector2d bin(10.0, -4.0), across(30.0, 5.0), pole(-20.0, 6.0), wide(45.0, -6.0);
    for (int d = 1; d <= n; ++d) {
      // Evenly spread shifts (one per drive, shuffled by the seed) keep the chain joined.
      const double s_along = -0.25 + 0.5 * ((d * 7 + static_cast<int>(seed)) % 12) / 11.0;
      if (d <= 12) add(d, bin + Eigen::Vector2d(s_along, 0.01 * noise(rng)));
      if (d <= 12) add(d, across + Eigen::Vector2d(0.01 * noise(rng), s_along));
      add(d, pole + 0.04 * Eigen::Vector2d(noise(rng), noise(rng)));
      add(d, wide + 0.08 * Eigen::Vector2d(noise(rng), noise(rng)));
    }
    PointConsensusResult pc = consensus_points(in, {}, &view);
    ASSERT_EQ(pc.landmarks.size(), 4U) << "seed " << seed;  // all four pass the support rule
    PointConsensusResult unfiltered = pc;
    const PointFilterResult f = filter_point_landmarks(pc, LineConsensusResult{}, in, &view);
    EXPECT_EQ(f.sliding, 1U) << "seed " << seed;
    EXPECT_FALSE(has_landmark_near(pc, bin));
    for (const auto& p : {across, pole, wide}) EXPECT_TRUE(has_landmark_near(pc, p));
    // The evidence: along/across the road (x, y here) against the members' own spread.
    for (std::size_t i = 0; i < unfiltered.landmarks.size(); ++i) {
      double sx = 0.0, sy = 0.0;
      for (std::int64_t cid : unfiltered.support[i]) {
        const Eigen::Vector2d dd = in[static_cast<std::size_t>(cid)].candidate.position_m -
                                   unfiltered.landmarks[i].position_m;
        sx += dd.x() * dd.x();
        sy += dd.y() * dd.y();
      }
      const double m = static_cast<double>(unfiltered.support[i].size());
      EXPECT_NEAR(f.evidence[i].along_road_spread_m, std::sqrt(sx / m), 1e-12);
      EXPECT_NEAR(f.evidence[i].across_road_spread_m, std::sqrt(sy / m), 1e-12);
      const bool is_bin = (unfiltered.landmarks[i].position_m - bin).norm() < 0.2;
      EXPECT_EQ(f.evidence[i].verdict == PointEvidence::Verdict::Sliding, is_bin);
    }
    // Without a view there is no road direction: nothing is judged.
    PointConsensusResult no_view = unfiltered;
    EXPECT_EQ(filter_point_landmarks(no_view, LineConsensusResult{}, in, nullptr).sliding, 0U);
    // Disabled, or with fewer supporting drives than the rule needs: kept.
    PointFilterConfig off;
    off.sliding.enabled = false;
    PointConsensusResult kept = unfiltered;
    EXPECT_EQ(filter_point_landmarks(kept, LineConsensusResult{}, in, &view, off).sliding, 0U);
    EXPECT_TRUE(has_landmark_near(kept, bin));
    PointFilterConfig strict;
    strict.sliding.min_support_drives = 13;
    PointConsensusResult few = unfiltered;
    EXPECT_EQ(filter_point_landmarks(few, LineConsensusResult{}, in, &view, strict).sliding, 0U);
  }
}

TEST(PointFilter, MirrorImagesBehindAReflectorGoRealObjectsBehindItStay) {
  // Eight passes along y = 0; a wall (line landmark) along y = 5 from x = -30 to 30.
  const int n = 8;
  const VisibilityIndex view = passes_along_x(n);
  std::vector<TaggedPointCandidate> in;
  auto object = [&](Eigen::Vector2d p, int drives) {
    for (int d = 1; d <= drives; ++d) {
      add_candidate(in, d, p + Eigen::Vector2d(0.01 * (d % 3), -0.01 * (d % 2)));
    }
  };
  object({10.0, 3.0}, 8);   // 0: a pole 2 m in front of the wall
  object({10.0, 7.0}, 8);   // 1: its image 2 m behind the wall: removed
  object({-10.0, 2.0}, 6);  // 2: another pole, seen by 6 passes
  object({-10.0, 8.0}, 5);  // 3: its image (the pole's image is weaker): removed
  object({20.0, 9.0}, 5);   // 4: behind the wall, nothing at its image (20, 1): kept
  object({0.0, 9.0}, 5);    // 5: behind the wall; its image (0, 1) has 1 drive only: kept
  object({0.0, 1.0}, 1);
  object({40.0, 9.0}, 5);   // 6: beyond the wall's end: no reflector there, kept
  object({40.0, 1.0}, 5);   // 7: (the object at 6's would-be image)
  object({70.0, 5.0}, 8);   // 8: a pole in front of a second wall at y = 20 ...
  object({70.0, 35.0}, 8);  // 9: ... and its image, beyond every pass's 30 m view: removed
  LineConsensusResult lines;
  LineLandmark wall;
  wall.polyline_m = {{-30.0, 5.0}, {30.0, 5.0}};
  lines.landmarks.push_back(wall);
  wall.polyline_m = {{60.0, 20.0}, {80.0, 20.0}};
  lines.landmarks.push_back(wall);
  PointConsensusResult pc = consensus_points(in, {}, &view);
  ASSERT_EQ(pc.landmarks.size(), 10U);  // the single-drive candidate at (0, 1) makes none
  std::vector<Eigen::Vector2d> before;
  for (const auto& l : pc.landmarks) before.push_back(l.position_m);
  auto index_of = [&](const Eigen::Vector2d& p) {
    for (std::size_t i = 0; i < before.size(); ++i) {
      if ((before[i] - p).norm() < 0.1) return i;
    }
    ADD_FAILURE() << "no landmark at " << p.transpose();
    return std::size_t{0};
  };
  const PointFilterResult f = filter_point_landmarks(pc, lines, in, &view);
  using V = PointEvidence::Verdict;
  EXPECT_EQ(f.mirror_ghosts, 3U);
  EXPECT_EQ(f.evidence[index_of({70.0, 35.0})].verdict, V::MirrorGhost);  // seen from its
  EXPECT_EQ(f.evidence[index_of({70.0, 35.0})].passes_in_view, 8U);       // supporters' paths
  EXPECT_EQ(f.evidence[index_of({10.0, 7.0})].verdict, V::MirrorGhost);
  EXPECT_EQ(f.evidence[index_of({10.0, 7.0})].mirror_image_drives, 8U);
  EXPECT_EQ(f.evidence[index_of({-10.0, 8.0})].verdict, V::MirrorGhost);
  EXPECT_EQ(f.evidence[index_of({-10.0, 8.0})].mirror_image_drives, 6U);
  for (const Eigen::Vector2d& p :
       {Eigen::Vector2d(10.0, 3.0), Eigen::Vector2d(-10.0, 2.0), Eigen::Vector2d(20.0, 9.0),
        Eigen::Vector2d(0.0, 9.0), Eigen::Vector2d(40.0, 9.0), Eigen::Vector2d(40.0, 1.0),
        Eigen::Vector2d(70.0, 5.0)}) {
    EXPECT_EQ(f.evidence[index_of(p)].verdict, V::Kept) << p.transpose();
    EXPECT_TRUE(has_landmark_near(pc, p)) << p.transpose();
  }
  EXPECT_EQ(pc.landmarks.size(), 7U);

  // The same scene seen from beyond the wall (passes along y = 10): now the objects in
  // front of the wall are the images' side, and only an object on the far side whose
  // image is populated can go: (10, 3) has its image (10, 7) populated by 8 drives.
  std::vector<DrivePass> far;
  for (int d = 1; d <= n; ++d) {
    DrivePass p;
    p.drive = d;
    p.view_range_m = 30.0;
    p.start_time_s = 1000.0 * d;
    p.path_m = {{-100.0, 10.0}, {100.0, 10.0}};
    far.push_back(p);
  }
  const VisibilityIndex far_view(std::move(far));
  PointConsensusResult again = consensus_points(in, {}, &far_view);
  const PointFilterResult g = filter_point_landmarks(again, lines, in, &far_view);
  EXPECT_EQ(g.evidence[index_of({10.0, 3.0})].verdict, V::MirrorGhost);
  EXPECT_EQ(g.evidence[index_of({10.0, 7.0})].verdict, V::Kept);

  // Off, or without passes: nothing is judged.
  PointConsensusResult off_result = consensus_points(in, {}, &view);
  PointFilterConfig off;
  off.mirror_ghosts.enabled = false;
  EXPECT_EQ(filter_point_landmarks(off_result, lines, in, &view, off).mirror_ghosts, 0U);
  PointConsensusResult no_view = consensus_points(in, {}, nullptr);
  EXPECT_EQ(filter_point_landmarks(no_view, lines, in, nullptr).mirror_ghosts, 0U);
}

}  // namespace
}  // namespace polmap::mapping
