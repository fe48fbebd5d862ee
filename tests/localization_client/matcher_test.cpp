// Map matching finds the true transform on synthetic landmark sets with
// outliers, missed landmarks and partial overlap, from a GNSS-grade prior
// (3 m, 3°); flags ambiguity on a periodic post row; lines fix the lateral
// offset where there are no points.
#include "polmap/localization_client/matcher.hpp"

#include <gtest/gtest.h>

#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <set>

namespace polmap::loc {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

struct Scene {
  std::vector<PointLandmark> map_points;
  std::vector<LineLandmark> map_lines;
  std::vector<PointCluster> clusters;
  std::vector<LineCluster> line_clusters;
  std::map<std::uint64_t, std::int64_t> truth;  ///< inlier cluster id -> landmark id
  Pose2 T_map_odom_true;
  Pose2 T_odom_vehicle;
};

/// A road along x through a map of [0, map_end_x] with random posts/poles and
/// two curbs; the vehicle at vehicle_x looks ahead 60 m.
Scene make_scene(std::mt19937& rng, double vehicle_x, double map_end_x, double outlier_share,
                 double miss_share) {
  Scene s;
  std::uniform_real_distribution<double> ux(0.0, map_end_x), uy(-25.0, 25.0), u01(0.0, 1.0);
  std::normal_distribution<double> n01(0.0, 1.0);
  const int n_points = static_cast<int>(map_end_x * 50.0 / 40.0);  // 1 per 40 m²
  for (int i = 0; i < n_points; ++i) {
    PointLandmark p;
    p.id = 1000 + i;
    p.position_m = {ux(rng), uy(rng)};
    if (std::abs(p.position_m.y()) < 7.0) continue;  // keep the road free
    s.map_points.push_back(p);
  }
  for (double side : {-6.5, 6.5}) {
    LineLandmark l;
    l.id = side < 0 ? 1 : 2;
    for (double x = 0.0; x <= map_end_x; x += 20.0) l.polyline_m.emplace_back(x, side);
    s.map_lines.push_back(l);
  }
  s.T_map_odom_true = {1234.5, -567.8, 1.1};
  const Pose2 T_map_vehicle{vehicle_x, 0.5, 2.0 * kDeg};
  s.T_odom_vehicle = s.T_map_odom_true.inverse() * T_map_vehicle;
  const Pose2 T_odom_map = s.T_map_odom_true.inverse();
  std::uint64_t next_id = 1;
  auto visible = [&](const Eigen::Vector2d& p_map) {
    const Eigen::Vector2d q = T_map_vehicle.inverse() * p_map;
    return q.norm() < 60.0 && std::abs(std::atan2(q.y(), q.x())) < 70.0 * kDeg;
  };
  std::uniform_int_distribution<int> nobs(1, 6);
  for (const auto& p : s.map_points) {
    if (!visible(p.position_m) || u01(rng) < miss_share) continue;
    PointCluster c;
    c.id = next_id++;
    c.centroid_odom_m = T_odom_map * p.position_m + 0.1 * Eigen::Vector2d(n01(rng), n01(rng));
    c.num_observations = nobs(rng);
    s.truth[c.id] = p.id;
    s.clusters.push_back(c);
  }
  const int n_outliers = static_cast<int>(outlier_share * s.clusters.size());
  std::uniform_real_distribution<double> fx(0.0, 60.0);
  for (int i = 0; i < n_outliers; ++i) {
    PointCluster c;
    c.id = next_id++;
    // Outliers anywhere in the field of view, including beyond the map's end
    // (partial overlap: the world continues where the map stops).
    const Eigen::Vector2d q(fx(rng), uy(rng));
    c.centroid_odom_m = s.T_odom_vehicle * q;
    c.num_observations = nobs(rng);
    s.clusters.push_back(c);
  }
  // Curb observations: two short pieces of each curb, within the map.
  for (double side : {-6.5, 6.5}) {
    for (double x0 : {10.0, 30.0}) {
      const Eigen::Vector2d a = T_map_vehicle.translation() + Eigen::Vector2d(x0, 0.0);
      if (a.x() + 15.0 > map_end_x) continue;
      LineCluster lc;
      lc.id = next_id++;
      lc.segment_odom_m = {T_odom_map * Eigen::Vector2d(a.x(), side + 0.05 * n01(rng)),
                           T_odom_map * Eigen::Vector2d(a.x() + 15.0, side + 0.05 * n01(rng))};
      lc.num_observations = 4;
      s.line_clusters.push_back(lc);
    }
  }
  return s;
}

/// Prior whose vehicle pose is off by (dx, dy, dyaw) in the map frame.
MatchPrior perturbed_prior(const Scene& s, double dx, double dy, double dyaw, double sigma_xy,
                           double sigma_yaw) {
  const Pose2 T_true_vehicle = s.T_map_odom_true * s.T_odom_vehicle;
  const Pose2 T_prior_vehicle{T_true_vehicle.x_m + dx, T_true_vehicle.y_m + dy,
                              T_true_vehicle.yaw_rad + dyaw};
  MatchPrior prior;
  prior.T_odom_vehicle = s.T_odom_vehicle;
  prior.T_map_odom = T_prior_vehicle * s.T_odom_vehicle.inverse();
  prior.covariance =
      Eigen::Vector3d(sigma_xy * sigma_xy, sigma_xy * sigma_xy, sigma_yaw * sigma_yaw).asDiagonal();
  return prior;
}

void expect_pose_near(const Scene& s, const Pose2& T_map_odom, double tol_m, double tol_rad) {
  const Pose2 est = T_map_odom * s.T_odom_vehicle;
  const Pose2 truth = s.T_map_odom_true * s.T_odom_vehicle;
  EXPECT_LT((est.translation() - truth.translation()).norm(), tol_m);
  EXPECT_LT(std::abs(wrap_angle_rad(est.yaw_rad - truth.yaw_rad)), tol_rad);
}

TEST(Matcher, FindsTrueTransformWithOutliersAndMisses) {
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> err(-1.0, 1.0);
  int ok = 0;
  for (int trial = 0; trial < 10; ++trial) {
    const Scene s = make_scene(rng, 100.0, 400.0, 0.3, 0.3);
    // GNSS-grade initial error: up to 3 m and 3° (the gate uses σ = 3 m, 3°).
    const MatchPrior prior =
        perturbed_prior(s, 3.0 * err(rng), 3.0 * err(rng), 3.0 * kDeg * err(rng), 3.0, 3.0 * kDeg);
    const MatchResult r =
        match_local_map(s.clusters, s.line_clusters, MapIndex(s.map_points, s.map_lines), prior);
    ASSERT_EQ(r.status, MatchResult::Status::Ok) << "trial " << trial << " " << to_string(r.status);
    ++ok;
    expect_pose_near(s, r.T_map_odom, 0.1, 0.2 * kDeg);
    int correct = 0, wrong_inlier = 0;
    for (const auto& m : r.points) {
      const auto it = s.truth.find(m.cluster_id);
      if (it == s.truth.end()) continue;  // an outlier that happens to sit on a landmark
      (it->second == m.landmark_id ? correct : wrong_inlier)++;
    }
    EXPECT_EQ(wrong_inlier, 0);
    EXPECT_GE(correct, static_cast<int>(0.9 * s.truth.size()));
    EXPECT_EQ(r.lines.size(), s.line_clusters.size());
    std::set<std::int64_t> used;
    for (const auto& m : r.points) EXPECT_TRUE(used.insert(m.landmark_id).second);
  }
  EXPECT_EQ(ok, 10);
}

TEST(Matcher, FindsTrueTransformInHeavyClutter) {
  // Four clutter clusters per real one (an urban local map against a sparse
  // pole map): random anchor pairs rarely hit two real landmarks, the
  // correlative generator still finds the peak.
  std::mt19937 rng(29);
  std::uniform_real_distribution<double> err(-1.0, 1.0);
  for (int trial = 0; trial < 5; ++trial) {
    const Scene s = make_scene(rng, 100.0, 400.0, 4.0, 0.3);
    const MatchPrior prior = perturbed_prior(s, 3.0 * err(rng), 3.0 * err(rng),
                                             (trial % 2 ? 3.0 : -3.0) * kDeg, 3.0, 3.0 * kDeg);
    const MatchResult r =
        match_local_map(s.clusters, s.line_clusters, MapIndex(s.map_points, s.map_lines), prior);
    EXPECT_NE(r.status, MatchResult::Status::NoCandidate);
    expect_pose_near(s, r.T_map_odom, 0.15, 0.25 * kDeg);
  }
}

TEST(Matcher, PartialOverlapAtTheMapBoundary) {
  // The vehicle drives towards the end of the map: about half of its field of
  // view has no map; the clusters there (outliers here) must not pull the match.
  std::mt19937 rng(23);
  for (int trial = 0; trial < 5; ++trial) {
    Scene s = make_scene(rng, 170.0, 200.0, 0.0, 0.2);
    // Add clusters beyond the map end, as real unmapped landmarks would be.
    std::uniform_real_distribution<double> ux(205.0, 230.0), uy(-25.0, 25.0);
    const Pose2 T_odom_map = s.T_map_odom_true.inverse();
    for (int i = 0; i < 25; ++i) {
      PointCluster c;
      c.id = 100000 + i;
      c.centroid_odom_m = T_odom_map * Eigen::Vector2d(ux(rng), uy(rng));
      c.num_observations = 5;
      s.clusters.push_back(c);
    }
    const MatchPrior prior = perturbed_prior(s, 2.0, -2.5, -2.0 * kDeg, 3.0, 3.0 * kDeg);
    const MatchResult r =
        match_local_map(s.clusters, s.line_clusters, MapIndex(s.map_points, s.map_lines), prior);
    ASSERT_EQ(r.status, MatchResult::Status::Ok) << to_string(r.status);
    // 12-24 landmarks, all 0-30 m ahead of the vehicle with 0.1 m noise: the
    // yaw lever arm makes the vehicle-pose error larger than with a full view.
    expect_pose_near(s, r.T_map_odom, 0.2, 0.3 * kDeg);
    EXPECT_EQ(r.points.size(), s.truth.size());
  }
}

TEST(Matcher, TrackingWithTightGateIsFastAndExact) {
  std::mt19937 rng(5);
  const Scene s = make_scene(rng, 100.0, 400.0, 0.3, 0.3);
  const MatchPrior prior = perturbed_prior(s, 0.2, -0.15, 0.3 * kDeg, 0.2, 0.5 * kDeg);
  const MapIndex map(s.map_points, s.map_lines);
  const MatchResult r = match_local_map(s.clusters, s.line_clusters, map, prior);
  ASSERT_EQ(r.status, MatchResult::Status::Ok);
  expect_pose_near(s, r.T_map_odom, 0.1, 0.2 * kDeg);
  EXPECT_LT(r.candidates_scored, 2000);
}

TEST(Matcher, PeriodicPostRowIsAmbiguousAlongTheRow) {
  // Posts every 3 m on one side only: shifting by one spacing fits as well.
  std::vector<PointLandmark> posts;
  for (int i = 0; i < 100; ++i) {
    PointLandmark p;
    p.id = i;
    p.position_m = {3.0 * i, 5.0};
    posts.push_back(p);
  }
  std::vector<PointCluster> clusters;
  for (int i = 30; i < 45; ++i) {
    PointCluster c;
    c.id = static_cast<std::uint64_t>(i);
    c.centroid_odom_m = {3.0 * i, 5.0};  // odometry frame = map frame here
    c.num_observations = 5;
    clusters.push_back(c);
  }
  MatchPrior prior;
  prior.T_odom_vehicle = {85.0, 0.0, 0.0};
  prior.T_map_odom = {1.0, 0.0, 0.0};
  prior.covariance = Eigen::Vector3d(9.0, 9.0, std::pow(3.0 * kDeg, 2)).asDiagonal();
  const MatchResult r = match_local_map(clusters, {}, MapIndex(posts, {}), prior);
  EXPECT_EQ(r.status, MatchResult::Status::Ambiguous) << to_string(r.status);
  ASSERT_TRUE(r.runner_up_cost.has_value());
}

TEST(Matcher, CurbsAloneCorrectLateralOffset) {
  std::vector<LineLandmark> curbs;
  for (double side : {-6.0, 6.0}) {
    LineLandmark l;
    l.id = side < 0 ? 1 : 2;
    l.polyline_m = {{0.0, side}, {200.0, side}};
    curbs.push_back(l);
  }
  std::vector<LineCluster> lines;
  for (double side : {-6.0, 6.0}) {
    LineCluster c;
    c.id = side < 0 ? 10 : 11;
    c.segment_odom_m = {{60.0, side}, {90.0, side}};
    c.num_observations = 5;
    lines.push_back(c);
  }
  MatchPrior prior;
  prior.T_odom_vehicle = {55.0, 0.0, 0.0};
  prior.T_map_odom = {0.7, 0.4, 0.0};  // truth is identity
  prior.covariance = Eigen::Vector3d(1.0, 1.0, 1e-4).asDiagonal();
  MatcherConfig cfg;
  cfg.min_point_matches = 1;
  const MatchResult r = match_local_map({}, lines, MapIndex({}, curbs), prior, cfg);
  ASSERT_EQ(r.lines.size(), 2U);
  EXPECT_NEAR(r.T_map_odom.y_m, 0.0, 0.02);  // across: corrected
  EXPECT_NEAR(r.T_map_odom.x_m, 0.7, 0.02);  // along: unobservable, kept
  EXPECT_NE(r.status, MatchResult::Status::TooFewClusters);
}

TEST(Matcher, EmptyInputs) {
  MatchPrior prior;
  EXPECT_EQ(match_local_map({}, {}, MapIndex(), prior).status, MatchResult::Status::TooFewClusters);
  PointCluster c;
  c.centroid_odom_m = {5, 5};
  c.num_observations = 3;
  const std::vector<PointCluster> one{c};
  const MatchResult r = match_local_map(one, {}, MapIndex(), prior);
  EXPECT_EQ(r.status, MatchResult::Status::TooFewMatches);
}

TEST(MapIndex, NearestWithinEqualsBruteForce) {
  // The bounded search of the scorer against a scan of every landmark.
  std::mt19937 rng(31);
  std::uniform_real_distribution<double> u(-50.0, 50.0);
  std::vector<PointLandmark> pts;
  for (int i = 0; i < 400; ++i) {
    PointLandmark p;
    p.id = i;
    p.position_m = {u(rng), 0.2 * u(rng)};
    pts.push_back(p);
  }
  const MapIndex map(pts, {});
  int found = 0;
  for (int k = 0; k < 2000; ++k) {
    const Eigen::Vector2d q(u(rng), 0.3 * u(rng));
    const double max_m = k % 2 == 0 ? 0.5 : 2.0;
    std::size_t best = 0;
    double best_d = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < pts.size(); ++i) {
      const double d = (pts[i].position_m - q).norm();
      if (d < best_d) {
        best_d = d;
        best = i;
      }
    }
    const auto nn = map.nearest_point_within(q, max_m);
    ASSERT_EQ(nn.has_value(), best_d <= max_m) << k;
    if (!nn) continue;
    ++found;
    EXPECT_EQ(nn->first, best) << k;
    EXPECT_NEAR(nn->second, best_d, 1e-12) << k;
    // On the boundary: a landmark exactly max_m away counts.
    EXPECT_TRUE(map.nearest_point_within(q, best_d).has_value()) << k;
  }
  EXPECT_GT(found, 300);
  EXPECT_LT(found, 1900);
}

}  // namespace
}  // namespace polmap::loc
