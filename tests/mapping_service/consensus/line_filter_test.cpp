// Precision filters of fleet line consensus (line_filter.hpp): overhead structures the
// drives drove through, short radial range streaks, and returns beyond the modelled view,
// on hand-built street scenes whose verdicts follow from the geometry.
#include "polmap/mapping_service/line_filter.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "polmap/mapping_service/consensus.hpp"

namespace polmap::mapping {
namespace {

/// n passes east along y = 0 (x from -100 to 200), view range `range_m`.
std::vector<DrivePass> passes_along_x(int n, double range_m = 30.0) {
  std::vector<DrivePass> passes;
  for (int d = 1; d <= n; ++d) {
    DrivePass p;
    p.drive = d;
    p.view_range_m = range_m;
    p.start_time_s = 1000.0 * d;
    p.vehicle = d;
    p.path_m = {{-100.0, 0.0}, {200.0, 0.0}};
    passes.push_back(p);
  }
  return passes;
}

/// A scene: line landmarks with the drives that support them (one candidate per drive).
struct Scene {
  LineConsensusResult lines;
  std::vector<TaggedLineCandidate> candidates;

  /// Adds a line landmark from a to b supported by drives first..last.
  void add(const Eigen::Vector2d& a, const Eigen::Vector2d& b, int first, int last) {
    LineLandmark lm;
    lm.id = static_cast<std::int64_t>(lines.landmarks.size());
    lm.polyline_m = {a, b};
    lm.support_drives = static_cast<std::uint32_t>(last - first + 1);
    std::vector<std::int64_t> ids;
    for (int d = first; d <= last; ++d) {
      TaggedLineCandidate c;
      c.candidate_id = static_cast<std::int64_t>(candidates.size());
      c.drive = d;
      c.candidate.start_m = a;
      c.candidate.end_m = b;
      ids.push_back(c.candidate_id);
      candidates.push_back(c);
    }
    lines.landmarks.push_back(lm);
    lines.support.push_back(ids);
    SupportVerdict v;
    v.status = SupportVerdict::Status::Accepted;
    v.support_drives = lm.support_drives;
    lines.verdicts.push_back(v);
  }
};

using V = LineEvidence::Verdict;

TEST(LineFilter, ABeamAcrossTheRoadGoesCurbsAndFacadesBesideItStay) {
  Scene s;
  s.add({50, -8}, {50, 10}, 1, 16);     // 0: gantry beam across the road, every pass under it
  s.add({0, -3.5}, {40, -3.5}, 1, 16);  // 1: curb
  s.add({0, 7}, {40, 7}, 1, 16);        // 2: facade
  s.add({120, -2}, {120, 2}, 1, 5);     // 3: across the road, seen by 5 passes: still crossed
  const VisibilityIndex view(passes_along_x(16));
  LineConsensusResult lines = s.lines;
  const LineFilterResult r = filter_line_landmarks(lines, s.candidates, &view);
  ASSERT_EQ(r.evidence.size(), 4U);
  EXPECT_EQ(r.evidence[0].verdict, V::Overhead);
  EXPECT_EQ(r.evidence[0].crossing_drives, 16U);
  EXPECT_EQ(r.evidence[1].verdict, V::Kept);
  EXPECT_EQ(r.evidence[1].crossing_drives, 0U);
  EXPECT_EQ(r.evidence[2].verdict, V::Kept);
  EXPECT_EQ(r.evidence[3].verdict, V::Overhead);
  EXPECT_EQ(r.evidence[3].crossing_drives, 5U);  // only supporters count
  EXPECT_EQ(r.overhead, 2U);
  // Survivors renumbered with their support and verdicts.
  ASSERT_EQ(lines.landmarks.size(), 2U);
  EXPECT_EQ(lines.landmarks[0].id, 0);
  EXPECT_EQ(lines.landmarks[1].id, 1);
  EXPECT_TRUE(lines.landmarks[0].polyline_m[0].isApprox(Eigen::Vector2d(0, -3.5)));
  EXPECT_TRUE(lines.landmarks[1].polyline_m[0].isApprox(Eigen::Vector2d(0, 7)));
  EXPECT_EQ(lines.support[1], s.lines.support[2]);
  EXPECT_EQ(lines.verdicts.size(), 2U);
  EXPECT_EQ(lines.stats.rejected_groups, s.lines.stats.rejected_groups + 2U);
}

TEST(LineFilter, AFewBadPathsThroughACurbDoNotRemoveIt) {
  // The first k drives' trajectories swerve through the curb at y = -3.5 (positioning
  // errors); the curb is supported by all 8.
  auto verdict = [](int k, const LineFilterConfig& cfg) {
    std::vector<DrivePass> passes = passes_along_x(8);
    for (int d = 0; d < k; ++d)
      passes[d].path_m = {{-100, 0}, {10, 0}, {20, -5}, {30, 0}, {200, 0}};
    Scene s;
    s.add({0, -3.5}, {40, -3.5}, 1, 8);
    const VisibilityIndex view(std::move(passes));
    LineConsensusResult lines = s.lines;
    const LineFilterResult r = filter_line_landmarks(lines, s.candidates, &view, cfg);
    EXPECT_EQ(r.evidence[0].crossing_drives, static_cast<std::uint32_t>(k));
    EXPECT_EQ(lines.landmarks.size(), r.evidence[0].verdict == V::Kept ? 1U : 0U);
    return r.evidence[0].verdict;
  };
  const LineFilterConfig cfg;
  EXPECT_EQ(verdict(1, cfg), V::Kept);  // below min_crossing_drives
  EXPECT_EQ(verdict(3, cfg), V::Kept);  // below half of the supporters
  EXPECT_EQ(verdict(4, cfg), V::Overhead);
  LineFilterConfig off;
  off.overhead.enabled = false;
  EXPECT_EQ(verdict(8, off), V::Kept);
}

TEST(LineFilter, ShortRadialLinesThroughAReflectorAreStreaks) {
  Scene s;
  s.add({0, -7}, {120, -7}, 1, 16);        // 0: facade, the reflector
  s.add({60, -4}, {60, -9}, 1, 10);        // 1: streak through it, 10 of 16
  s.add({70, -4}, {70.5, -9}, 1, 16);      // 2: the same seen by every pass: still a streak
  s.add({80, -5}, {80, -20}, 1, 10);       // 3: 15 m: not judged
  s.add({90, -7.4}, {90, -12}, 1, 10);     // 4: a side street's curb from the facade line on
  s.add({100, -3}, {100, -6.5}, 1, 10);    // 5: radial, in front of the facade: crosses nothing
  s.add({30, -4}, {33, -9}, 1, 10);        // 6: through it, but 31° off the line of sight
  s.add({120.8, -4}, {120.8, -9}, 1, 10);  // 7: through the facade's end extended by 0.8 m
  s.add({122, -4}, {122, -9}, 1, 10);      // 8: 2 m past its end
  const VisibilityIndex view(passes_along_x(16));
  LineConsensusResult lines = s.lines;
  const LineFilterResult r = filter_line_landmarks(lines, s.candidates, &view);
  using Ev = LineEvidence;
  auto verdicts = [&](const LineFilterResult& f) {
    std::vector<Ev::Verdict> v;
    for (const Ev& e : f.evidence) v.push_back(e.verdict);
    return v;
  };
  EXPECT_EQ(verdicts(r),
            (std::vector<Ev::Verdict>{V::Kept, V::RangeStreak, V::RangeStreak, V::Kept, V::Kept,
                                      V::Kept, V::Kept, V::RangeStreak, V::Kept}));
  EXPECT_EQ(r.evidence[1].straddled_line, 0);
  EXPECT_NEAR(r.evidence[1].line_of_sight_angle_rad, 0.0, 1e-9);
  EXPECT_NEAR(r.evidence[1].length_m, 5.0, 1e-9);
  EXPECT_EQ(r.evidence[1].passes_in_view, 16U);
  EXPECT_EQ(r.evidence[1].support, 10U);
  // Line 2 straddles the facade too. From (70.25, 0) to the middle
  // (70.25, -6.5) the line of sight is straight down; the line leans by atan(0.5 / 5).
  EXPECT_EQ(r.evidence[2].straddled_line, 0);
  EXPECT_NEAR(r.evidence[2].line_of_sight_angle_rad, std::atan(0.1), 1e-9);
  EXPECT_EQ(r.evidence[3].straddled_line, -1);  // too long to be judged
  EXPECT_EQ(r.evidence[4].straddled_line, -1);  // meets the facade line outside itself
  EXPECT_EQ(r.evidence[5].straddled_line, -1);
  EXPECT_NEAR(r.evidence[0].line_of_sight_angle_rad, std::numbers::pi / 2.0, 1e-9);
  // Line 6: direction (3, -5), line of sight (0, -1) from (31.5, 0): atan(3 / 5) = 31°.
  EXPECT_NEAR(r.evidence[6].line_of_sight_angle_rad, std::atan(0.6), 1e-9);
  EXPECT_EQ(r.range_streaks, 3U);
  EXPECT_EQ(lines.landmarks.size(), 6U);
  // A share of 0.9 keeps what more than 90 % of the passes saw: line 2 (16 of 16).
  LineFilterConfig nearly_all;
  nearly_all.range_streaks.min_detection_share = 0.9;
  LineConsensusResult l1 = s.lines;
  const LineFilterResult r1 = filter_line_landmarks(l1, s.candidates, &view, nearly_all);
  EXPECT_EQ(r1.evidence[1].verdict, V::RangeStreak);
  EXPECT_EQ(r1.evidence[2].verdict, V::Kept);
  // A wider angle judges line 6 too; a share of 0.5 keeps the streaks (10 and 16 of 16 passes);
  // an overhang of 3.5 m
  // (more than line 1 has below the facade) keeps line 1.
  LineFilterConfig wide;
  wide.range_streaks.max_line_of_sight_angle_rad = 0.6;
  LineConsensusResult l2 = s.lines;
  EXPECT_EQ(filter_line_landmarks(l2, s.candidates, &view, wide).evidence[6].verdict,
            V::RangeStreak);
  LineFilterConfig lenient;
  lenient.range_streaks.min_detection_share = 0.5;
  LineConsensusResult l3 = s.lines;
  EXPECT_EQ(filter_line_landmarks(l3, s.candidates, &view, lenient).range_streaks, 0U);
  LineFilterConfig overhang;
  overhang.range_streaks.min_overhang_m = 3.5;
  LineConsensusResult l4 = s.lines;
  EXPECT_EQ(filter_line_landmarks(l4, s.candidates, &view, overhang).evidence[1].verdict, V::Kept);
}

TEST(LineFilter, ReturnsBeyondMostSupportersViewAreJudgedAgainstPassesAsClose) {
  // View ranges of 10 m; lines 16 m off the road (behind a facade, say) are out of every
  // pass's modelled view, so the support rule saw only their supporters.
  const VisibilityIndex view(passes_along_x(16, 10.0));
  Scene s;
  s.add({20, 16}, {24, 16}, 1, 2);   // 0: two of 16 passes that came as close
  s.add({40, 16}, {44, 16}, 1, 10);  // 1: ten of them
  s.add({60, 6}, {64, 6}, 1, 2);     // 2: in view: the support rule's business, not this one
  LineConsensusResult lines = s.lines;
  LineFilterConfig cfg;
  cfg.range_streaks.enabled = false;
  const LineFilterResult r = filter_line_landmarks(lines, s.candidates, &view, cfg);
  EXPECT_EQ(r.evidence[0].verdict, V::OutOfView);
  EXPECT_EQ(r.evidence[0].passes_as_close, 16U);
  EXPECT_EQ(r.evidence[0].passes_in_view, 2U);  // its supporters only
  EXPECT_EQ(r.evidence[1].verdict, V::Kept);
  EXPECT_EQ(r.evidence[1].passes_as_close, 16U);
  EXPECT_EQ(r.evidence[2].verdict, V::Kept);
  EXPECT_EQ(r.evidence[2].passes_as_close, 0U);  // not judged
  EXPECT_EQ(r.evidence[2].passes_in_view, 16U);
  EXPECT_EQ(r.out_of_view, 1U);
  // Only passes at least as close as the farthest supporter count: with the other 14
  // passes 30 m farther away, 2 supporters of 2 such passes stay.
  std::vector<DrivePass> far = passes_along_x(16, 10.0);
  for (std::size_t k = 2; k < far.size(); ++k) far[k].path_m = {{-100, -30}, {200, -30}};
  const VisibilityIndex far_view(std::move(far));
  LineConsensusResult l2 = s.lines;
  const LineFilterResult r2 = filter_line_landmarks(l2, s.candidates, &far_view, cfg);
  EXPECT_EQ(r2.evidence[0].passes_as_close, 2U);
  EXPECT_EQ(r2.evidence[0].verdict, V::Kept);
}

TEST(LineFilter, WithoutPassesNothingIsJudged) {
  Scene s;
  s.add({50, -8}, {50, 10}, 1, 16);
  s.add({60, -4}, {60, -9}, 1, 2);
  LineConsensusResult lines = s.lines;
  const LineFilterResult r = filter_line_landmarks(lines, s.candidates, nullptr);
  EXPECT_EQ(r.evidence.size(), 2U);
  EXPECT_EQ(r.evidence[0].verdict, V::Kept);
  EXPECT_EQ(lines.landmarks.size(), 2U);
  const VisibilityIndex empty(std::vector<DrivePass>{});
  EXPECT_EQ(filter_line_landmarks(lines, s.candidates, &empty).overhead, 0U);
  EXPECT_EQ(lines.landmarks.size(), 2U);
}

}  // namespace
}  // namespace polmap::mapping
