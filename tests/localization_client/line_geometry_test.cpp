// Line distance (hull + projection), hull area, projections and merging on
// configurations with known answers, plus symmetry on random pairs.
#include "polmap/localization_client/line_geometry.hpp"

#include <gtest/gtest.h>

#include <random>

namespace polmap::loc {
namespace {

TEST(LineGeometry, CollinearOverlappingSegmentsHaveZeroDistance) {
  const LineDistance d = line_distance({{0, 0}, {10, 0}}, {{5, 0}, {15, 0}});
  EXPECT_NEAR(d.hull_m, 0.0, 1e-12);
  EXPECT_NEAR(d.projection_m, 0.0, 1e-12);
}

TEST(LineGeometry, CollinearGapIsProjectionDistance) {
  const LineDistance d = line_distance({{0, 0}, {10, 0}}, {{12.5, 0}, {14, 0}});
  EXPECT_NEAR(d.hull_m, 0.0, 1e-12);
  EXPECT_NEAR(d.projection_m, 2.5, 1e-12);
}

TEST(LineGeometry, ParallelOffsetFullOverlapHullIsOffset) {
  // Rectangle 10 x 0.2: area 2, merged length 10 -> 0.2 m mean spread.
  const LineDistance d = line_distance({{0, 0}, {10, 0}}, {{10, 0.2}, {0, 0.2}});
  EXPECT_NEAR(d.hull_m, 0.2, 1e-12);
  EXPECT_NEAR(d.projection_m, 0.0, 1e-12);
}

TEST(LineGeometry, CrossingSegmentsHaveLargeHullDistance) {
  const LineDistance d = line_distance({{0, 0}, {10, 0}}, {{5, -5}, {5, 5}});
  EXPECT_NEAR(d.hull_m, 50.0 / 10.0, 1e-12);  // hull = rhombus of area 50
}

TEST(LineGeometry, SymmetricOnRandomPairs) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-20, 20);
  for (int i = 0; i < 200; ++i) {
    const Segment2 s{{u(rng), u(rng)}, {u(rng), u(rng)}};
    const Segment2 t{{u(rng), u(rng)}, {u(rng), u(rng)}};
    const LineDistance a = line_distance(s, t), b = line_distance(t, s);
    EXPECT_NEAR(a.hull_m, b.hull_m, 1e-9);
    EXPECT_NEAR(a.projection_m, b.projection_m, 1e-9);
    EXPECT_NEAR(segment_distance(s, t), segment_distance(t, s), 1e-12);
    // Reversing a segment's direction changes nothing.
    const LineDistance c = line_distance({s.b_m, s.a_m}, t);
    EXPECT_NEAR(a.hull_m, c.hull_m, 1e-9);
    EXPECT_NEAR(a.projection_m, c.projection_m, 1e-9);
  }
}

TEST(LineGeometry, HullAreaOfSquareWithInteriorPoints) {
  const std::vector<Eigen::Vector2d> pts{{0, 0}, {2, 0},     {2, 2}, {0, 2},
                                         {1, 1}, {0.5, 1.5}, {2, 1}};
  EXPECT_NEAR(convex_hull_area(pts), 4.0, 1e-12);
}

TEST(LineGeometry, ProjectionAndSegmentDistance) {
  const Segment2 s{{0, 0}, {10, 0}};
  const auto p = project_onto_segment({3, 4}, s);
  EXPECT_NEAR(p.t, 0.3, 1e-12);
  EXPECT_NEAR(p.distance_m, 4.0, 1e-12);
  EXPECT_NEAR(project_onto_segment({-3, 4}, s).distance_m, 5.0, 1e-12);  // clamped to a
  EXPECT_NEAR(segment_distance(s, {{5, -1}, {5, 1}}), 0.0, 1e-12);       // crossing
  EXPECT_NEAR(segment_distance(s, {{12, 0}, {14, 3}}), 2.0, 1e-12);
}

TEST(LineGeometry, MergeSpansAllMutualProjections) {
  const std::vector<Segment2> segs{
      {{0, 0}, {10, 0.1}}, {{18, 0.1}, {8, 0.0}}, {{20, 0.0}, {25, 0.1}}};
  const Segment2 m = merge_segments(segs);
  EXPECT_NEAR(m.a_m.x(), 0.0, 0.05);
  EXPECT_NEAR(m.b_m.x(), 25.0, 0.05);
  const Eigen::Vector2d n(-m.direction().y(), m.direction().x());
  for (const auto& seg : segs) {
    EXPECT_LT(std::abs(n.dot(seg.a_m - m.a_m)), 0.2);
    EXPECT_LT(std::abs(n.dot(seg.b_m - m.a_m)), 0.2);
  }
  EXPECT_GT(m.direction().x(), 0.99);  // follows the first segment's orientation
}

}  // namespace
}  // namespace polmap::loc
