// The sliding-window graph recovers a synthetic trajectory from biased, noisy
// odometry plus bearing-range landmark observations far better than odometry
// alone; its covariance is consistent; truncation bounds the window.
#include "polmap/localization_client/graph.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <set>

namespace polmap::loc {
namespace {

struct Sim {
  std::vector<Pose2> truth;  ///< T_map_vehicle at each pose time
  std::vector<double> time_s;
  std::vector<Eigen::Vector2d> landmarks;
};

Sim make_sim(std::mt19937& rng, int steps, double dt) {
  Sim s;
  Pose2 T{0.0, 0.0, 0.3};
  for (int k = 0; k < steps; ++k) {
    s.truth.push_back(T);
    s.time_s.push_back(k * dt);
    const double v = 10.0, w = 0.15 * std::sin(0.05 * k);
    T = T * integrate_motion(v, w, dt);
  }
  std::uniform_real_distribution<double> side(-25.0, 25.0);
  for (int k = 0; k < steps; k += 3) {
    const Pose2& P = s.truth[k];
    s.landmarks.push_back(P * Eigen::Vector2d(0.0, side(rng)));
  }
  return s;
}

TEST(SlidingWindowGraph, BeatsDeadReckoningOnSyntheticDrive) {
  std::mt19937 rng(5);
  const double dt = 0.2;
  const Sim sim = make_sim(rng, 250, dt);  // 50 s, 500 m
  std::normal_distribution<double> n01(0.0, 1.0);
  GraphConfig cfg;
  cfg.window_s = 6.0;
  // This odometry is much worse than the radar odometry the defaults are tuned
  // for (2 % scale error on 2 m steps, 1 mrad bias): the factors say so.
  cfg.odometry_sigma_translation_m = 0.05;
  cfg.odometry_sigma_yaw_rad = 0.01;
  SlidingWindowGraph graph(cfg);

  Pose2 dead_reckoning = sim.truth[0];
  Pose2 estimate = sim.truth[0];
  double se_graph = 0.0, se_dr = 0.0, nees_sum = 0.0;
  int n_eval = 0, n_nees = 0;
  std::optional<SlidingWindowGraph::PoseKey> prev;
  for (std::size_t k = 0; k < sim.truth.size(); ++k) {
    std::optional<Pose2> odo;
    Pose2 guess = estimate;
    if (k > 0) {
      const Pose2 d = sim.truth[k - 1].inverse() * sim.truth[k];
      // Biased odometry: 2 % scale error, 0.001 rad yaw bias per step (5 mrad/s), noise.
      odo = Pose2{d.x_m * 1.02 + 0.02 * n01(rng), d.y_m + 0.02 * n01(rng),
                  d.yaw_rad + 0.001 + 0.002 * n01(rng)};
      dead_reckoning = dead_reckoning * *odo;
      guess = estimate * *odo;
    }
    const auto key = graph.add_pose(sim.time_s[k], guess, odo);
    if (k == 0) {
      graph.add_pose_prior(key, sim.truth[0], Eigen::Vector3d(0.01, 0.01, 1e-4).asDiagonal());
    }
    // Observations of landmarks in range and field of view.
    const Pose2 inv = sim.truth[k].inverse();
    for (std::size_t i = 0; i < sim.landmarks.size(); ++i) {
      const Eigen::Vector2d q = inv * sim.landmarks[i];
      const double r = q.norm(), b = std::atan2(q.y(), q.x());
      if (r > 60.0 || r < 2.0 || std::abs(b) > 1.2) continue;
      const double rn = r + 0.1 * n01(rng), bn = b + 0.01 * n01(rng);
      const Eigen::Vector2d map_pos = sim.landmarks[i] + 0.05 * Eigen::Vector2d(n01(rng), n01(rng));
      graph.add_point_observation(key, static_cast<std::int64_t>(i), map_pos,
                                  rn * Eigen::Vector2d(std::cos(bn), std::sin(bn)));
    }
    graph.truncate_before(sim.time_s[k] - cfg.window_s);
    const GraphSolution sol = graph.solve();
    ASSERT_EQ(sol.status, GraphSolution::Status::Ok);
    EXPECT_LE(sol.num_poses, static_cast<int>(cfg.window_s / dt) + 1);
    estimate = sol.T_map_vehicle;
    const Eigen::Vector3d e(estimate.x_m - sim.truth[k].x_m, estimate.y_m - sim.truth[k].y_m,
                            wrap_angle_rad(estimate.yaw_rad - sim.truth[k].yaw_rad));
    se_graph += e.head<2>().squaredNorm();
    se_dr += (dead_reckoning.translation() - sim.truth[k].translation()).squaredNorm();
    ++n_eval;
    if (sol.covariance_valid && k > 30) {
      nees_sum += e.dot(sol.covariance.inverse() * e);
      ++n_nees;
    }
    prev = key;
  }
  const double rmse_graph = std::sqrt(se_graph / n_eval);
  const double rmse_dr = std::sqrt(se_dr / n_eval);
  RecordProperty("rmse_graph_m", std::to_string(rmse_graph));
  RecordProperty("rmse_dead_reckoning_m", std::to_string(rmse_dr));
  std::printf("RMSE graph %.3f m, dead reckoning %.3f m, mean NEES %.2f\n", rmse_graph, rmse_dr,
              n_nees ? nees_sum / n_nees : -1.0);
  EXPECT_LT(rmse_graph, 0.25);
  EXPECT_GT(rmse_dr, 5.0);
  ASSERT_GT(n_nees, 100);
  // The paper's σ values are conservative for this simulation's noise, so the
  // covariance may be pessimistic, but it must not be overconfident.
  EXPECT_LT(nees_sum / n_nees, 6.0);
}

TEST(SlidingWindowGraph, PriorOnlyCovarianceEqualsPrior) {
  SlidingWindowGraph graph;
  const auto k = graph.add_pose(0.0, {1.0, 2.0, 0.5}, std::nullopt);
  Eigen::Matrix3d cov;
  cov << 0.09, 0.02, 0.001, 0.02, 0.04, -0.002, 0.001, -0.002, 0.0025;
  graph.add_pose_prior(k, {1.1, 1.9, 0.45}, cov);
  const GraphSolution sol = graph.solve();
  ASSERT_EQ(sol.status, GraphSolution::Status::Ok);
  ASSERT_TRUE(sol.covariance_valid);
  EXPECT_NEAR(sol.T_map_vehicle.x_m, 1.1, 1e-6);
  EXPECT_NEAR(sol.T_map_vehicle.yaw_rad, 0.45, 1e-6);
  EXPECT_TRUE(sol.covariance.isApprox(cov, 1e-6)) << sol.covariance;
}

TEST(SlidingWindowGraph, OdometryChainPropagatesCovariance) {
  // Prior on the first pose, pure odometry after it: the last pose's position
  // variance grows with every factor (σ_t² per step plus lever-arm yaw terms).
  SlidingWindowGraph graph;
  Pose2 T{0, 0, 0};
  auto k = graph.add_pose(0.0, T, std::nullopt);
  graph.add_pose_prior(k, T, Eigen::Vector3d(0.01, 0.01, 1e-4).asDiagonal());
  double last_var = 0.0;
  for (int i = 1; i <= 5; ++i) {
    const Pose2 d{1.0, 0.0, 0.0};
    T = T * d;
    k = graph.add_pose(i, T, d);
    const auto sol = graph.solve();
    ASSERT_TRUE(sol.covariance_valid);
    EXPECT_GT(sol.covariance(1, 1), last_var);
    last_var = sol.covariance(1, 1);
    const double sigma_t = GraphConfig{}.odometry_sigma_translation_m;
    EXPECT_NEAR(sol.covariance(0, 0), 0.01 + i * sigma_t * sigma_t, 1e-9);
  }
}

TEST(SlidingWindowGraph, LineObservationConstrainsAcrossOnly) {
  // One pose held by a weak prior, one observed line parallel to the x axis:
  // the across-line (y) error is corrected, the along-line (x) error is not.
  SlidingWindowGraph graph;
  const Pose2 truth{0.0, 0.0, 0.0};
  const Pose2 guess{0.5, 0.5, 0.0};
  const auto k = graph.add_pose(0.0, guess, std::nullopt);
  graph.add_pose_prior(k, guess, Eigen::Vector3d(4.0, 4.0, 1e-6).asDiagonal());
  const Segment2 map_line{{-20.0, 5.0}, {40.0, 5.0}};
  const Segment2 observed{{5.0, 5.0}, {25.0, 5.0}};  // vehicle frame = map frame at truth
  graph.add_line_observation(k, 7, observed, map_line);
  (void)truth;
  const auto sol = graph.solve();
  ASSERT_EQ(sol.status, GraphSolution::Status::Ok);
  EXPECT_NEAR(sol.T_map_vehicle.y_m, 0.0, 0.05);
  EXPECT_NEAR(sol.T_map_vehicle.x_m, 0.5, 0.05);
  ASSERT_TRUE(sol.covariance_valid);
  // Across: the 0.1 m end-point priors plus bearing noise (0.03 rad at 7-25 m)
  // give σ_y ≈ 0.35 m; along: only the weak 10σ priors and the 2 m pose prior.
  EXPECT_LT(sol.covariance(1, 1), 0.2);
  EXPECT_GT(sol.covariance(0, 0), 3.0 * sol.covariance(1, 1));
}

TEST(SlidingWindowGraph, TruncationDropsOldPosesAndOrphanLandmarks) {
  SlidingWindowGraph graph;
  Pose2 T{0, 0, 0};
  auto k0 = graph.add_pose(0.0, T, std::nullopt);
  graph.add_point_observation(k0, 1, {10, 0}, {10, 0});
  auto k1 = graph.add_pose(1.0, T * Pose2{1, 0, 0}, Pose2{1, 0, 0});
  graph.add_point_observation(k1, 2, {10, 5}, {9, 5});
  EXPECT_EQ(graph.num_point_landmarks(), 2);
  graph.truncate_before(0.5);
  EXPECT_EQ(graph.num_poses(), 1);
  EXPECT_FALSE(graph.pose(k0).has_value());
  EXPECT_EQ(graph.num_point_landmarks(), 1);
  EXPECT_EQ(graph.num_point_landmarks_since(0.0), 1);
}

TEST(SlidingWindowGraph, CountsLandmarksObservedSinceATime) {
  // What the localizer asks before it lets the pose prior go: landmarks of recent poses.
  SlidingWindowGraph graph;
  const Pose2 T{0, 0, 0};
  const Segment2 map_line{{-20.0, 5.0}, {40.0, 5.0}};
  const auto k0 = graph.add_pose(0.0, T, std::nullopt);
  graph.add_point_observation(k0, 1, {10, 0}, {10, 0});
  graph.add_point_observation(k0, 2, {10, 5}, {10, 5});
  graph.add_line_observation(k0, 7, {{5.0, 5.0}, {25.0, 5.0}}, map_line);
  const auto k1 = graph.add_pose(3.0, T * Pose2{30, 0, 0}, Pose2{30, 0, 0});
  graph.add_point_observation(k1, 2, {-20, 5}, {10, 5});
  graph.add_line_observation(k1, 7, {{-25.0, 5.0}, {5.0, 5.0}}, map_line);
  graph.add_line_observation(k1, 8, {{-5.0, -5.0}, {5.0, -5.0}}, {{20.0, -5.0}, {40.0, -5.0}});
  EXPECT_EQ(graph.num_point_landmarks(), 2);
  EXPECT_EQ(graph.num_point_landmarks_since(0.0), 2);
  EXPECT_EQ(graph.num_point_landmarks_since(1.0), 1);  // landmark 2, seen again at 3 s
  EXPECT_EQ(graph.num_point_landmarks_since(3.5), 0);
  EXPECT_EQ(graph.num_line_observations(), 3);
  EXPECT_EQ(graph.num_line_observations_since(1.0), 2);
  EXPECT_EQ(graph.num_line_observations_since(3.5), 0);
}

}  // namespace
}  // namespace polmap::loc

namespace polmap::loc {
namespace {

// An odometry factor's extra sigma (side slip) adds in quadrature to the configured one:
// a pose linked only by odometry to a pinned pose has exactly that lateral variance.
TEST(SlidingWindowGraph, ExtraOdometrySigmaAddsInQuadrature) {
  GraphConfig cfg;
  for (const double extra_m : {0.0, 0.05}) {
    SlidingWindowGraph graph(cfg);
    const auto k0 = graph.add_pose(0.0, {0.0, 0.0, 0.0}, std::nullopt);
    graph.add_pose_prior(k0, {0.0, 0.0, 0.0}, Eigen::Vector3d(1e-8, 1e-8, 1e-10).asDiagonal());
    (void)graph.add_pose(0.3, {3.0, 0.0, 0.0}, Pose2{3.0, 0.0, 0.0},
                         Eigen::Vector3d(0.0, extra_m, 0.0));
    const GraphSolution sol = graph.solve();
    ASSERT_TRUE(sol.covariance_valid);
    const double want = std::pow(std::hypot(cfg.odometry_sigma_translation_m, extra_m), 2);
    EXPECT_NEAR(sol.covariance(1, 1), want, 0.01 * want) << "extra " << extra_m;
    EXPECT_NEAR(sol.covariance(0, 0), std::pow(cfg.odometry_sigma_translation_m, 2), 1e-6);
  }
}

}  // namespace
}  // namespace polmap::loc
