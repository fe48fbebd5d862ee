// Local-map clustering: the k-d tree connected components equal a brute-force
// all-pairs reference; the windowed LocalMap keeps stable cluster ids and
// truncates old observations; its recent() view equals clusters rebuilt from the recent
// observations alone.
#include "polmap/localization_client/local_map.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <functional>
#include <numeric>
#include <random>

namespace polmap::loc {
namespace {

/// Brute-force components: depth-first search over all pairs.
std::vector<int> brute_force_components(
    std::size_t n, const std::function<bool(std::size_t, std::size_t)>& linked) {
  std::vector<int> label(n, -1);
  int next = 0;
  for (std::size_t s = 0; s < n; ++s) {
    if (label[s] >= 0) continue;
    std::vector<std::size_t> stack{s};
    label[s] = next;
    while (!stack.empty()) {
      const std::size_t i = stack.back();
      stack.pop_back();
      for (std::size_t j = 0; j < n; ++j) {
        if (label[j] < 0 && linked(i, j)) {
          label[j] = next;
          stack.push_back(j);
        }
      }
    }
    ++next;
  }
  return label;
}

TEST(ClusterPoints, EqualsBruteForceOnRandomClouds) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 30; ++trial) {
    const int n = 50 + trial * 20;
    const double extent = 5.0 + trial;
    std::uniform_real_distribution<double> u(0.0, extent);
    std::vector<Eigen::Vector2d> pts;
    for (int i = 0; i < n; ++i) pts.emplace_back(u(rng), u(rng));
    // Exact duplicates and points exactly at the link distance are edge cases.
    pts.push_back(pts[0]);
    pts.push_back(pts[1] + Eigen::Vector2d(0.5, 0.0));
    for (double link : {0.2, 0.5, 1.0}) {
      const auto fast = cluster_points(pts, link);
      const auto ref = brute_force_components(pts.size(), [&](std::size_t i, std::size_t j) {
        return (pts[i] - pts[j]).norm() <= link;
      });
      ASSERT_EQ(fast, ref) << "trial " << trial << " link " << link;
    }
  }
}

TEST(ClusterSegments, EqualsBruteForceOnRandomSegments) {
  std::mt19937 rng(11);
  const LineLinkConfig cfg{};
  for (int trial = 0; trial < 20; ++trial) {
    std::uniform_real_distribution<double> u(0.0, 60.0), len(0.5, 12.0), ang(-3.2, 3.2),
        jitter(-0.15, 0.15);
    std::vector<Segment2> segs;
    // A few "true" lines observed repeatedly in pieces, plus random clutter.
    for (int l = 0; l < 6; ++l) {
      const Eigen::Vector2d o(u(rng), u(rng));
      const double a = ang(rng);
      const Eigen::Vector2d d(std::cos(a), std::sin(a));
      for (int k = 0; k < 8; ++k) {
        const double s0 = 20.0 * (u(rng) / 60.0), s1 = s0 + len(rng);
        const Eigen::Vector2d n(-d.y(), d.x());
        segs.push_back({o + s0 * d + jitter(rng) * n, o + s1 * d + jitter(rng) * n});
      }
    }
    for (int k = 0; k < 40; ++k) {
      const Eigen::Vector2d a(u(rng), u(rng));
      const double t = ang(rng);
      segs.push_back({a, a + len(rng) * Eigen::Vector2d(std::cos(t), std::sin(t))});
    }
    const auto fast = cluster_segments(segs, cfg);
    const auto ref = brute_force_components(segs.size(), [&](std::size_t i, std::size_t j) {
      return i != j && segments_linked(segs[i], segs[j], cfg);
    });
    ASSERT_EQ(fast, ref) << "trial " << trial;
    // Not trivial: some lines actually merged.
    EXPECT_LT(*std::max_element(fast.begin(), fast.end()) + 1, static_cast<int>(segs.size()));
  }
}

TEST(LocalMap, ClustersRepeatedObservationsWithStableIds) {
  LocalMapConfig cfg;
  cfg.window_s = 2.0;
  LocalMap map(cfg);
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.05);
  const std::vector<Eigen::Vector2d> landmarks{{0, 0}, {5, 0}, {5, 5}};
  std::vector<std::uint64_t> first_ids;
  for (int step = 0; step < 10; ++step) {
    std::vector<PointCandidate> pts;
    for (const auto& l : landmarks) {
      PointCandidate c;
      c.position_m = l + Eigen::Vector2d(noise(rng), noise(rng));
      pts.push_back(c);
    }
    const LineCandidate line{{0, -3}, {10, -3.02}, 1.0};
    map.add(0.5 * step, pts, std::span<const LineCandidate>(&line, 1));
    ASSERT_EQ(map.point_clusters().size(), 3U);
    ASSERT_EQ(map.line_clusters().size(), 1U);
    std::vector<std::uint64_t> ids;
    for (const auto& c : map.point_clusters()) {
      ids.push_back(c.id);
      EXPECT_TRUE(c.observed_latest);
      EXPECT_LT((c.centroid_odom_m - landmarks[&c - &map.point_clusters()[0]]).norm(), 0.1);
    }
    if (step == 0) first_ids = ids;
    EXPECT_EQ(ids, first_ids) << "ids must survive re-clustering and truncation";
    // Window 2 s at 0.5 s steps: at most 5 extractions (t - 2 ... t inclusive).
    EXPECT_LE(map.point_clusters()[0].num_observations, 5);
    EXPECT_GE(map.point_clusters()[0].first_time_s, 0.5 * step - cfg.window_s);
  }
  EXPECT_EQ(map.point_clusters()[0].num_observations, 5);
}

TEST(LocalMap, NewLandmarkGetsNewIdAndOldOneExpires) {
  LocalMapConfig cfg;
  cfg.window_s = 1.0;
  LocalMap map(cfg);
  PointCandidate a, b;
  a.position_m = {0, 0};
  b.position_m = {10, 0};
  map.add(0.0, std::span<const PointCandidate>(&a, 1), {});
  const auto id_a = map.point_clusters().at(0).id;
  map.add(0.5, std::span<const PointCandidate>(&b, 1), {});
  ASSERT_EQ(map.point_clusters().size(), 2U);
  map.add(2.0, std::span<const PointCandidate>(&b, 1), {});
  ASSERT_EQ(map.point_clusters().size(), 1U);  // a expired (older than 1 s)
  EXPECT_NE(map.point_clusters()[0].id, id_a);
  EXPECT_EQ(map.point_clusters()[0].num_observations, 1);  // b at 0.5 expired too
}

TEST(LocalMap, SplitClusterKeepsIdOnLargerPart) {
  // Observations linked through a bridge point; when the bridge expires the
  // cluster splits and the part with more previous members keeps the id.
  LocalMapConfig cfg;
  cfg.window_s = 1.0;
  cfg.point_link_distance_m = 0.5;
  LocalMap map(cfg);
  std::vector<PointCandidate> first(3);
  first[0].position_m = {0.0, 0};
  first[1].position_m = {0.4, 0};  // bridge
  first[2].position_m = {0.8, 0};
  map.add(0.0, first, {});
  ASSERT_EQ(map.point_clusters().size(), 1U);
  const auto id = map.point_clusters()[0].id;
  std::vector<PointCandidate> second(3);
  second[0].position_m = {0.8, 0.01};
  second[1].position_m = {0.8, -0.01};
  second[2].position_m = {0.0, 0.01};
  map.add(0.9, second, {});
  ASSERT_EQ(map.point_clusters().size(), 1U);
  map.add(1.5, {}, {});  // the first extraction (with the bridge) expires
  ASSERT_EQ(map.point_clusters().size(), 2U);
  const auto& c0 = map.point_clusters()[0];
  const auto& c1 = map.point_clusters()[1];
  const auto& bigger = c0.num_observations > c1.num_observations ? c0 : c1;
  const auto& smaller = c0.num_observations > c1.num_observations ? c1 : c0;
  EXPECT_EQ(bigger.id, id);
  EXPECT_NE(smaller.id, id);
  EXPECT_FALSE(bigger.observed_latest);
}

TEST(LocalMap, RecentViewKeepsOnlyObservationsSinceItsStart) {
  // A landmark whose observations drift 0.1 m per extraction (a local map bent by the
  // odometry), a second one seen only early, and a line that drifts too.
  LocalMapConfig cfg;
  cfg.window_s = 10.0;
  LocalMap map(cfg);
  for (int step = 0; step < 7; ++step) {
    const double t = 0.5 * step;
    std::vector<PointCandidate> pts(1);
    pts[0].position_m = {0.05 * step, 0.0};
    if (step < 2) {
      pts.emplace_back();
      pts.back().position_m = {8.0, 3.0};
    }
    const LineCandidate line{{0, -3 + 0.02 * step}, {10, -3 + 0.02 * step}, 1.0};
    map.add(t, pts, std::span<const LineCandidate>(&line, 1));
  }
  ASSERT_EQ(map.point_clusters().size(), 2U);
  ASSERT_EQ(map.line_clusters().size(), 1U);

  // A view from before the window's start is the full map, to the bit.
  const LocalMap::View all = map.recent(-1.0);
  ASSERT_EQ(all.points.size(), 2U);
  for (std::size_t i = 0; i < all.points.size(); ++i) {
    EXPECT_EQ(all.points[i].id, map.point_clusters()[i].id);
    EXPECT_EQ(all.points[i].centroid_odom_m, map.point_clusters()[i].centroid_odom_m);
    EXPECT_EQ(all.points[i].members, map.point_clusters()[i].members);
  }
  ASSERT_EQ(all.lines.size(), 1U);
  EXPECT_EQ(all.lines[0].segment_odom_m.a_m, map.line_clusters()[0].segment_odom_m.a_m);
  EXPECT_EQ(all.lines[0].segment_odom_m.b_m, map.line_clusters()[0].segment_odom_m.b_m);

  // From t = 2 s: extractions 4, 5, 6 only; the early landmark is gone.
  const LocalMap::View recent = map.recent(2.0);
  ASSERT_EQ(recent.points.size(), 1U);
  const PointCluster& c = recent.points[0];
  const auto full = std::find_if(map.point_clusters().begin(), map.point_clusters().end(),
                                 [&](const PointCluster& f) { return f.id == c.id; });
  ASSERT_NE(full, map.point_clusters().end());
  EXPECT_LT(full->centroid_odom_m.norm(), 1.0) << "the drifting landmark keeps its id";
  EXPECT_EQ(c.num_observations, 3);
  EXPECT_DOUBLE_EQ(c.first_time_s, 2.0);
  EXPECT_DOUBLE_EQ(c.last_time_s, 3.0);
  EXPECT_TRUE(c.observed_latest);
  // Equal weights (no vehicle pose): the mean of 0.20, 0.25, 0.30.
  EXPECT_NEAR(c.centroid_odom_m.x(), 0.25, 1e-12);
  EXPECT_NEAR(full->centroid_odom_m.x(), 0.15, 1e-12);
  for (std::size_t i : c.members) EXPECT_GE(map.point_observations()[i].time_s, 2.0);
  ASSERT_EQ(recent.lines.size(), 1U);
  std::vector<Segment2> late;
  for (int step = 4; step < 7; ++step)
    late.push_back({{0, -3 + 0.02 * step}, {10, -3 + 0.02 * step}});
  const Segment2 expected = merge_segments(late);
  EXPECT_NEAR((recent.lines[0].segment_odom_m.a_m - expected.a_m).norm(), 0.0, 1e-12);
  EXPECT_NEAR((recent.lines[0].segment_odom_m.b_m - expected.b_m).norm(), 0.0, 1e-12);
  EXPECT_EQ(recent.lines[0].id, map.line_clusters()[0].id);

  // A start after the latest extraction leaves nothing.
  EXPECT_TRUE(map.recent(3.5).points.empty());
  EXPECT_TRUE(map.recent(3.5).lines.empty());
}

}  // namespace
}  // namespace polmap::loc
