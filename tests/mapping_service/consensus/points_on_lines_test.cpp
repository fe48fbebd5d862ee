// Point landmarks that are parts of line landmarks (a peak on a curb or a facade) are
// removed; points beside a line, near its ends (corners) or with the rule off are kept.
#include <gtest/gtest.h>

#include "polmap/mapping_service/consensus.hpp"

namespace polmap::mapping {
namespace {

PointConsensusResult points_at(const std::vector<Eigen::Vector2d>& at) {
  PointConsensusResult r;
  for (std::size_t i = 0; i < at.size(); ++i) {
    PointLandmark lm;
    lm.id = static_cast<std::int64_t>(i);
    lm.position_m = at[i];
    r.landmarks.push_back(lm);
    r.support.push_back({static_cast<std::int64_t>(100 + i)});
    SupportVerdict v;
    v.support_drives = static_cast<std::uint32_t>(i + 2);
    r.verdicts.push_back(v);
  }
  return r;
}

LineConsensusResult an_l_shaped_wall() {
  LineConsensusResult l;
  LineLandmark lm;
  lm.polyline_m = {{0.0, 0.0}, {20.0, 0.0}, {20.0, 10.0}};
  l.landmarks.push_back(lm);
  return l;
}

TEST(PointsOnLines, PartsOfALineAreRemovedOthersKeptInOrder) {
  PointConsensusResult pts = points_at({{10.0, 0.1},    // on the first edge
                                        {10.0, 0.4},    // beside it
                                        {0.5, 0.05},    // at the start: a wall end
                                        {20.1, 5.0},    // on the second edge
                                        {20.05, 0.1},   // at the corner vertex: kept
                                        {19.5, 9.6}});  // near the end vertex
  EXPECT_EQ(remove_points_on_lines(pts, an_l_shaped_wall()), 2U);
  ASSERT_EQ(pts.landmarks.size(), 4U);
  const std::vector<Eigen::Vector2d> kept{{10.0, 0.4}, {0.5, 0.05}, {20.05, 0.1}, {19.5, 9.6}};
  const std::vector<std::int64_t> support{101, 102, 104, 105};
  for (std::size_t i = 0; i < kept.size(); ++i) {
    EXPECT_EQ(pts.landmarks[i].position_m, kept[i]) << i;
    EXPECT_EQ(pts.landmarks[i].id, static_cast<std::int64_t>(i));
    EXPECT_EQ(pts.support[i], std::vector<std::int64_t>{support[i]});
    EXPECT_EQ(pts.verdicts[i].support_drives, static_cast<std::uint32_t>(support[i] - 98));
  }
  EXPECT_EQ(pts.stats.on_lines, 2U);
}

TEST(PointsOnLines, OnlyCornersProtectInnerVertices) {
  // A straight polyline with a needless inner vertex: no corner there, points on it go.
  LineConsensusResult straight;
  LineLandmark lm;
  lm.polyline_m = {{0.0, 0.0}, {10.0, 0.02}, {20.0, 0.0}};
  straight.landmarks.push_back(lm);
  PointConsensusResult pts = points_at({{10.0, 0.1}, {20.0, 2.0}});
  EXPECT_EQ(remove_points_on_lines(pts, straight), 1U);
  // The L's corner protects within 1 m only: 2 m along the second edge is removed.
  EXPECT_EQ(remove_points_on_lines(pts, an_l_shaped_wall()), 1U);
  EXPECT_TRUE(pts.landmarks.empty());
}

TEST(PointsOnLines, DisabledByAZeroDistance) {
  PointConsensusResult pts = points_at({{10.0, 0.0}});
  PointConsensusConfig cfg;
  cfg.on_line_max_distance_m = 0.0;
  EXPECT_EQ(remove_points_on_lines(pts, an_l_shaped_wall(), cfg), 0U);
  EXPECT_EQ(pts.landmarks.size(), 1U);
}

}  // namespace
}  // namespace polmap::mapping
