// Line consensus: hull/projection distances, merging of re-observed walls,
// separation of parallel walls, curves as polylines within the error bound,
// snapping of crossing / nearly crossing ends, ends where enough drives end (not at
// the farthest member end).
#include <gtest/gtest.h>

#include <algorithm>
#include <numbers>
#include <random>

#include "polmap/mapping_service/consensus.hpp"

namespace polmap::mapping {
namespace {

TaggedLineCandidate seg(std::int64_t id, std::int64_t drive, Eigen::Vector2d a, Eigen::Vector2d b) {
  TaggedLineCandidate c;
  c.candidate_id = id;
  c.drive = drive;
  c.candidate.start_m = a;
  c.candidate.end_m = b;
  return c;
}

double dist_to_polyline(const Eigen::Vector2d& p, const std::vector<Eigen::Vector2d>& pl) {
  double best = 1e300;
  for (std::size_t i = 0; i + 1 < pl.size(); ++i) {
    const Eigen::Vector2d ab = pl[i + 1] - pl[i];
    const double t = std::clamp((p - pl[i]).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (p - (pl[i] + t * ab)).norm());
  }
  return best;
}

TEST(ConsensusLines, PairDistances) {
  LineCandidate a{{0, 0}, {10, 0}, 1};
  LineCandidate b{{0, 0.05}, {10, 0.05}, 1};
  auto d = line_pair_distance(a, b);
  EXPECT_NEAR(d.hull_m, 0.05, 1e-12);  // rectangle 10 x 0.05 / 10
  EXPECT_EQ(d.projection_m, 0.0);
  LineCandidate c{{12, 0}, {20, 0}, 1};  // collinear, 2 m gap
  d = line_pair_distance(a, c);
  EXPECT_NEAR(d.projection_m, 2.0, 1e-12);
  EXPECT_NEAR(d.hull_m, 0.0, 1e-12);
  LineCandidate rev{{20, 0.05}, {12, 0.05}, 1};  // reversed direction does not matter
  EXPECT_NEAR(line_pair_distance(a, rev).projection_m, 2.0, 1e-9);
}

TEST(ConsensusLines, TwoNoisyObservationsOfAWallMergeToTheSpanningSegment) {
  const std::vector<TaggedLineCandidate> in{seg(1, 1, {0.1, 0.02}, {15.0, 0.03}),
                                            seg(2, 2, {20.2, -0.01}, {5.0, -0.02})};
  const auto r = consensus_lines(in);
  ASSERT_EQ(r.landmarks.size(), 1U);
  const auto& pl = r.landmarks[0].polyline_m;
  ASSERT_EQ(pl.size(), 2U);
  const Eigen::Vector2d lo = pl[0].x() < pl[1].x() ? pl[0] : pl[1];
  const Eigen::Vector2d hi = pl[0].x() < pl[1].x() ? pl[1] : pl[0];
  EXPECT_NEAR(lo.x(), 0.1, 0.01);
  EXPECT_NEAR(hi.x(), 20.2, 0.01);
  EXPECT_NEAR(lo.y(), 0.0, 0.03);
  EXPECT_NEAR(hi.y(), 0.0, 0.03);
  EXPECT_EQ(r.landmarks[0].support_drives, 2U);
  EXPECT_LT(r.landmarks[0].spread_m, 0.03);
  EXPECT_EQ(r.support[0], (std::vector<std::int64_t>{1, 2}));
}

TEST(ConsensusLines, ManyDrivesEndWhereMostOfThemEndNotAtTheFarthestEnd) {
  // A 10 m wall seen by 64 drives, ends with 0.1 m noise, every 8th drive running on
  // 0.5–1.5 m past the far end (a bright corner beside it), some drives seeing it in two
  // pieces. The landmark ends where half of the drives still cover it.
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 0.1), lat(0.0, 0.02);
  std::uniform_real_distribution<double> over(0.5, 1.5);
  std::vector<TaggedLineCandidate> in;
  std::int64_t id = 0;
  for (int d = 0; d < 64; ++d) {
    const double a = n(rng), b = 10.0 + n(rng) + (d % 8 == 0 ? over(rng) : 0.0);
    if (d % 5 == 0) {  // two pieces with a gap
      in.push_back(seg(id++, d, {a, lat(rng)}, {4.0, lat(rng)}));
      in.push_back(seg(id++, d, {4.6, lat(rng)}, {b, lat(rng)}));
    } else {
      in.push_back(seg(id++, d, {a, lat(rng)}, {b, lat(rng)}));
    }
  }
  const auto r = consensus_lines(in);
  ASSERT_EQ(r.landmarks.size(), 1U);
  const auto& pl = r.landmarks[0].polyline_m;
  ASSERT_EQ(pl.size(), 2U);
  const double lo = std::min(pl.front().x(), pl.back().x());
  const double hi = std::max(pl.front().x(), pl.back().x());
  EXPECT_LT(std::abs(lo), 0.1);
  EXPECT_LT(std::abs(hi - 10.0), 0.1);  // the farthest member end is at ~11.4 m
  EXPECT_LT(r.landmarks[0].spread_m, 0.05);
  // Share 0 (or a 2-drive group): the union of the members, as the paper.
  LineConsensusConfig cfg;
  cfg.extent_min_drive_share = 0.0;
  const auto u = consensus_lines(in, cfg);
  ASSERT_EQ(u.landmarks.size(), 1U);
  EXPECT_GT(std::max(u.landmarks[0].polyline_m.front().x(), u.landmarks[0].polyline_m.back().x()),
            11.0);
  const std::vector<TaggedLineCandidate> two{seg(0, 1, {0.0, 0.0}, {8.0, 0.0}),
                                             seg(1, 2, {2.0, 0.03}, {10.0, 0.03})};
  const auto t = consensus_lines(two);
  ASSERT_EQ(t.landmarks.size(), 1U);
  EXPECT_NEAR(std::min(t.landmarks[0].polyline_m.front().x(), t.landmarks[0].polyline_m.back().x()),
              0.0, 0.01);
  EXPECT_NEAR(std::max(t.landmarks[0].polyline_m.front().x(), t.landmarks[0].polyline_m.back().x()),
              10.0, 0.01);
}

TEST(ConsensusLines, SingleDriveAndDistantCollinearSegmentsDoNotMerge) {
  // Same drive twice: never a landmark.
  EXPECT_TRUE(
      consensus_lines(std::vector{seg(1, 1, {0, 0}, {10, 0}), seg(2, 1, {0, 0.01}, {10, 0.01})})
          .landmarks.empty());
  // Collinear with a 1.4 m gap merges, with 1.6 m it does not.
  EXPECT_EQ(consensus_lines(std::vector{seg(1, 1, {0, 0}, {10, 0}), seg(2, 2, {11.4, 0}, {20, 0})})
                .landmarks.size(),
            1U);
  EXPECT_EQ(consensus_lines(std::vector{seg(1, 1, {0, 0}, {10, 0}), seg(2, 2, {11.6, 0}, {20, 0})})
                .landmarks.size(),
            0U);
}

TEST(ConsensusLines, ParallelLinesHalfAMetreApartStaySeparate) {
  const std::vector<TaggedLineCandidate> in{
      seg(1, 1, {0, 0.00}, {30, 0.01}), seg(2, 2, {1, -0.01}, {29, 0.00}),  // curb
      seg(3, 1, {0, 0.50}, {30, 0.51}), seg(4, 2, {2, 0.49}, {31, 0.50})};  // wall behind it
  const auto r = consensus_lines(in);
  ASSERT_EQ(r.landmarks.size(), 2U);
  EXPECT_EQ(r.support[0], (std::vector<std::int64_t>{1, 2}));
  EXPECT_EQ(r.support[1], (std::vector<std::int64_t>{3, 4}));
  EXPECT_NEAR(r.landmarks[1].polyline_m[0].y() - r.landmarks[0].polyline_m[0].y(), 0.5, 0.02);
}

TEST(ConsensusLines, CurveBecomesAPolylineWithinTheErrorBound) {
  // A 90° kerb arc of radius 15 m seen by two drives as 1.5 m chords, with the
  // chords of drive 2 shifted by half a chord and 1 cm noise.
  const double R = 15.0;
  const Eigen::Vector2d c(100.0, 200.0);
  auto arc = [&](double t) {
    return Eigen::Vector2d(c + R * Eigen::Vector2d(std::cos(t), std::sin(t)));
  };
  const double dt = 1.5 / R;
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 0.01);
  std::vector<TaggedLineCandidate> in;
  std::int64_t id = 0;
  for (int d = 0; d < 2; ++d) {
    for (double t = d * dt / 2; t + dt <= std::numbers::pi / 2 + 1e-9; t += dt) {
      in.push_back(seg(id++, d + 1, arc(t) + Eigen::Vector2d(n(rng), n(rng)),
                       arc(t + dt) + Eigen::Vector2d(n(rng), n(rng))));
    }
  }
  LineConsensusConfig cfg;
  const auto r = consensus_lines(in, cfg);
  ASSERT_EQ(r.landmarks.size(), 1U);
  const auto& pl = r.landmarks[0].polyline_m;
  EXPECT_GT(pl.size(), 4U);
  EXPECT_EQ(r.stats.polylines, 1U);
  // No shortcut: the true arc (over the span both drives saw) stays within the
  // bound (+ chord sagitta of the inputs and noise) of the polyline...
  const double sagitta = R * (1 - std::cos(dt / 2));
  for (double t = dt; t <= std::numbers::pi / 2 - dt; t += 0.01) {
    EXPECT_LT(dist_to_polyline(arc(t), pl), cfg.polyline_max_error_m + sagitta + 0.03) << t;
  }
  // ... and every vertex lies on the arc.
  for (const auto& v : pl) EXPECT_NEAR((v - c).norm(), R, cfg.polyline_max_error_m);
}

TEST(ConsensusLines, NearlyCrossingEndsSnapToTheIntersection) {
  // An L-shaped building corner at (10, 0): wall A stops 0.4 m short of the
  // corner, wall B starts 0.4 m above it. Each seen by two drives.
  std::vector<TaggedLineCandidate> in{
      seg(1, 1, {0, 0}, {9.6, 0}), seg(2, 2, {0.2, 0.01}, {9.6, 0.01}),
      seg(3, 1, {10, 0.4}, {10, 10}), seg(4, 2, {10.01, 0.4}, {10.01, 9})};
  auto r = consensus_lines(in);
  ASSERT_EQ(r.landmarks.size(), 2U);
  EXPECT_EQ(r.stats.snapped_ends, 2U);
  const Eigen::Vector2d corner(10.005, 0.005);
  EXPECT_LT((r.landmarks[0].polyline_m.back() - corner).norm(), 0.02);
  EXPECT_LT((r.landmarks[1].polyline_m.front() - corner).norm(), 0.02);

  // Crossing ends (overshoot by 0.3 m) are shortened to the intersection.
  in = {seg(1, 1, {0, 0}, {10.3, 0}), seg(2, 2, {0, 0}, {10.3, 0}), seg(3, 1, {10, -0.3}, {10, 10}),
        seg(4, 2, {10, -0.3}, {10, 10})};
  r = consensus_lines(in);
  ASSERT_EQ(r.landmarks.size(), 2U);
  EXPECT_LT((r.landmarks[0].polyline_m.back() - Eigen::Vector2d(10, 0)).norm(), 1e-9);
  EXPECT_LT((r.landmarks[1].polyline_m.front() - Eigen::Vector2d(10, 0)).norm(), 1e-9);

  // Ends 3 m short of each other are left alone.
  in = {seg(1, 1, {0, 0}, {7, 0}), seg(2, 2, {0, 0}, {7, 0}), seg(3, 1, {10, 3}, {10, 10}),
        seg(4, 2, {10, 3}, {10, 10})};
  r = consensus_lines(in);
  EXPECT_EQ(r.stats.snapped_ends, 0U);
  EXPECT_EQ(r.landmarks[0].polyline_m.back(), Eigen::Vector2d(7, 0));
}

TEST(ConsensusLines, ManyWallsScaleAndStayDeterministic) {
  // 2000 short walls on a grid, each seen by 3 drives: all found, fast.
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 0.01);
  std::vector<TaggedLineCandidate> in;
  std::int64_t id = 0;
  for (int i = 0; i < 2000; ++i) {
    const Eigen::Vector2d a(20.0 * (i % 50), 20.0 * (i / 50));
    for (int d = 0; d < 3; ++d) {
      in.push_back(seg(id++, d, a + Eigen::Vector2d(n(rng), n(rng)),
                       a + Eigen::Vector2d(8 + n(rng), n(rng))));
    }
  }
  std::shuffle(in.begin(), in.end(), rng);
  const auto r = consensus_lines(in);
  EXPECT_EQ(r.landmarks.size(), 2000U);
  std::shuffle(in.begin(), in.end(), rng);
  EXPECT_EQ(consensus_lines(in).support, r.support);
}

}  // namespace
}  // namespace polmap::mapping

namespace polmap::mapping {
namespace {

/// Area of the convex hull of points (Andrew's monotone chain), the reference.
double hull_area(std::vector<Eigen::Vector2d> p) {
  std::sort(p.begin(), p.end(), [](const auto& a, const auto& b) {
    return a.x() != b.x() ? a.x() < b.x() : a.y() < b.y();
  });
  auto cross = [](const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
  };
  std::vector<Eigen::Vector2d> h(2 * p.size());
  std::size_t k = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    while (k >= 2 && cross(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  for (std::size_t i = p.size() - 1, t = k + 1; i-- > 0;) {
    while (k >= t && cross(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  h.resize(k > 0 ? k - 1 : 0);
  double area = 0.0;
  for (std::size_t i = 0; i < h.size(); ++i) {
    const auto& a = h[i];
    const auto& b = h[(i + 1) % h.size()];
    area += a.x() * b.y() - a.y() * b.x();
  }
  return 0.5 * std::abs(area);
}

TEST(LinePairDistance, HullAreaEqualsAConvexHullReference) {
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u(-5.0, 5.0);
  for (int trial = 0; trial < 2000; ++trial) {
    LineCandidate a, b;
    a.start_m = {1000.0 + u(rng), -2000.0 + u(rng)};
    a.end_m = {1000.0 + u(rng), -2000.0 + u(rng)};
    b.start_m = {1000.0 + u(rng), -2000.0 + u(rng)};
    b.end_m = trial % 5 == 0 ? (a.start_m + a.end_m) / 2.0  // inside: a triangle hull
                             : Eigen::Vector2d(1000.0 + u(rng), -2000.0 + u(rng));
    const auto d = line_pair_distance(a, b);
    // merged length along the common direction (as line_pair_distance defines it)
    Eigen::Vector2d ua = a.end_m - a.start_m, ub = b.end_m - b.start_m;
    if (ua.dot(ub) < 0.0) ub = -ub;
    const Eigen::Vector2d dir = (ua + ub).normalized();
    double lo = 1e300, hi = -1e300;
    for (const auto& p : {a.start_m, a.end_m, b.start_m, b.end_m}) {
      lo = std::min(lo, p.dot(dir));
      hi = std::max(hi, p.dot(dir));
    }
    const double expect = hull_area({a.start_m - a.start_m, a.end_m - a.start_m,
                                     b.start_m - a.start_m, b.end_m - a.start_m}) /
                          (hi - lo);
    ASSERT_NEAR(d.hull_m, expect, 1e-9 * std::max(1.0, expect)) << trial;
  }
}

}  // namespace
}  // namespace polmap::mapping
