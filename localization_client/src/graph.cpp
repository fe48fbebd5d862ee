// The one translation unit of the graph that includes Ceres (slow to compile).
#include "polmap/localization_client/graph.hpp"

#include <ceres/ceres.h>

#include <algorithm>
#include <chrono>
#include <set>

#include "polmap/localization_client/graph_factors.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::loc {
namespace {

/// Yaw kept in [-pi, pi) by the manifold's Plus (Ceres pose_graph_2d's
/// AngleManifold), so the solver never sees a jump of 2 pi.
struct AngleManifold {
  template <typename T>
  bool Plus(const T* x_rad, const T* delta_rad, T* x_plus_delta_rad) const {
    *x_plus_delta_rad = normalize_angle(*x_rad + *delta_rad);
    return true;
  }
  template <typename T>
  bool Minus(const T* y_rad, const T* x_rad, T* y_minus_x_rad) const {
    *y_minus_x_rad = normalize_angle(*y_rad - *x_rad);
    return true;
  }
};

Eigen::Matrix3d odometry_sqrt_information(const GraphConfig& cfg, const Eigen::Vector3d& extra) {
  const double t = cfg.odometry_sigma_translation_m, y = cfg.odometry_sigma_yaw_rad;
  return Eigen::Vector3d(1.0 / std::hypot(t, extra.x()), 1.0 / std::hypot(t, extra.y()),
                         1.0 / std::hypot(y, extra.z()))
      .asDiagonal();
}

Eigen::Vector2d to_bearing_range(const Eigen::Vector2d& p_vehicle) {
  return {std::atan2(p_vehicle.y(), p_vehicle.x()), p_vehicle.norm()};
}

}  // namespace

SlidingWindowGraph::SlidingWindowGraph(GraphConfig cfg) : cfg_(cfg) {}
SlidingWindowGraph::~SlidingWindowGraph() = default;

SlidingWindowGraph::PoseKey SlidingWindowGraph::add_pose(
    double time_s, const Pose2& T_map_vehicle_guess, const std::optional<Pose2>& T_prev_this,
    const Eigen::Vector3d& extra_odometry_sigma) {
  POLMAP_EXPECT(extra_odometry_sigma.minCoeff() >= 0.0);
  POLMAP_EXPECT(poses_.empty() || time_s > poses_.rbegin()->second.time_s);
  const PoseKey key = next_key_++;
  PoseNode& n = poses_[key];
  n.time_s = time_s;
  n.position[0] = T_map_vehicle_guess.x_m;
  n.position[1] = T_map_vehicle_guess.y_m;
  n.yaw[0] = wrap_angle_rad(T_map_vehicle_guess.yaw_rad);
  if (poses_.size() > 1) n.T_prev_this = T_prev_this;
  n.extra_odometry_sigma = extra_odometry_sigma;
  return key;
}

void SlidingWindowGraph::add_point_observation(PoseKey pose, std::int64_t landmark_id,
                                               const Eigen::Vector2d& landmark_map_m,
                                               const Eigen::Vector2d& observed_vehicle_m) {
  POLMAP_EXPECT(poses_.contains(pose));
  auto [it, inserted] = points_.try_emplace(landmark_id);
  if (inserted) {
    it->second.position[0] = landmark_map_m.x();
    it->second.position[1] = landmark_map_m.y();
    it->second.prior_m = landmark_map_m;
  }
  const Eigen::Vector2d br = to_bearing_range(observed_vehicle_m);
  point_obs_.push_back({pose, landmark_id, br.x(), br.y()});
}

void SlidingWindowGraph::add_line_observation(PoseKey pose, std::int64_t line_id,
                                              const Segment2& observed_vehicle_m,
                                              const Segment2& map_segment_m) {
  const auto it = poses_.find(pose);
  POLMAP_EXPECT(it != poses_.end());
  const Pose2 T{it->second.position[0], it->second.position[1], it->second.yaw[0]};
  auto rec = std::make_unique<LineObservationRecord>();
  rec->pose = pose;
  rec->line_id = line_id;
  const Eigen::Vector2d u = map_segment_m.direction();
  rec->sqrt_information =
      line_prior_sqrt_information(u, cfg_.line_prior_sigma_m, cfg_.line_along_factor);
  const Eigen::Vector2d ends[2] = {observed_vehicle_m.a_m, observed_vehicle_m.b_m};
  for (int k = 0; k < 2; ++k) {
    const Eigen::Vector2d br = to_bearing_range(ends[k]);
    rec->bearing_rad[k] = br.x();
    rec->range_m[k] = br.y();
    // Orthogonal projection onto the map line (not clamped to the segment:
    // an observation may extend past a map segment's end; along the line the
    // prior is weak anyway).
    const Eigen::Vector2d p_map = T * ends[k];
    rec->prior_m[k] = map_segment_m.a_m + u * u.dot(p_map - map_segment_m.a_m);
    rec->node[k][0] = rec->prior_m[k].x();
    rec->node[k][1] = rec->prior_m[k].y();
  }
  line_obs_.push_back(std::move(rec));
}

void SlidingWindowGraph::add_pose_prior(PoseKey pose, const Pose2& T_map_vehicle,
                                        const Eigen::Matrix3d& covariance) {
  const auto it = poses_.find(pose);
  POLMAP_EXPECT(it != poses_.end());
  it->second.priors.push_back({T_map_vehicle, sqrt_information_from_covariance(covariance)});
}

void SlidingWindowGraph::clear_pose_priors() {
  for (auto& [k, n] : poses_) n.priors.clear();
}

void SlidingWindowGraph::truncate_before(double time_s) {
  std::set<PoseKey> removed;
  for (auto it = poses_.begin(); it != poses_.end() && it->second.time_s < time_s;) {
    removed.insert(it->first);
    it = poses_.erase(it);
  }
  if (removed.empty()) return;
  // The new first pose has no predecessor any more.
  if (!poses_.empty()) poses_.begin()->second.T_prev_this.reset();
  std::erase_if(point_obs_, [&](const auto& o) { return removed.contains(o.pose); });
  std::erase_if(line_obs_, [&](const auto& o) { return removed.contains(o->pose); });
  std::set<std::int64_t> referenced;
  for (const auto& o : point_obs_) referenced.insert(o.landmark_id);
  std::erase_if(points_, [&](const auto& kv) { return !referenced.contains(kv.first); });
}

void SlidingWindowGraph::clear() {
  poses_.clear();
  points_.clear();
  point_obs_.clear();
  line_obs_.clear();
}

GraphSolution SlidingWindowGraph::solve() {
  GraphSolution sol;
  sol.num_poses = static_cast<int>(poses_.size());
  sol.num_point_landmarks = static_cast<int>(points_.size());
  sol.num_line_nodes = static_cast<int>(2 * line_obs_.size());
  sol.num_observation_factors = static_cast<int>(point_obs_.size() + 2 * line_obs_.size());
  if (poses_.empty()) return sol;
  const auto t0 = std::chrono::steady_clock::now();

  ceres::Problem::Options popt;
  popt.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(popt);
  ceres::AutoDiffManifold<AngleManifold, 1, 1> angle_manifold;
  auto robust = [&]() -> ceres::LossFunction* {
    return cfg_.observation_huber_sigma > 0 ? new ceres::HuberLoss(cfg_.observation_huber_sigma)
                                            : nullptr;
  };

  PoseNode* prev = nullptr;
  for (auto& [key, n] : poses_) {
    problem.AddParameterBlock(n.position, 2);
    problem.AddParameterBlock(n.yaw, 1, &angle_manifold);
    if (prev != nullptr && n.T_prev_this) {
      auto* cost = new ceres::AutoDiffCostFunction<OdometryResidual, 3, 2, 1, 2, 1>(
          new OdometryResidual(n.T_prev_this->x_m, n.T_prev_this->y_m, n.T_prev_this->yaw_rad,
                               odometry_sqrt_information(cfg_, n.extra_odometry_sigma)));
      problem.AddResidualBlock(cost, nullptr, prev->position, prev->yaw, n.position, n.yaw);
    }
    for (const auto& pr : n.priors) {
      auto* cost = new ceres::AutoDiffCostFunction<PosePriorResidual, 3, 2, 1>(
          new PosePriorResidual(pr.mean.x_m, pr.mean.y_m, pr.mean.yaw_rad, pr.sqrt_information));
      problem.AddResidualBlock(cost, nullptr, n.position, n.yaw);
      ++sol.num_pose_priors;
    }
    prev = &n;
  }
  const Eigen::Matrix2d point_sqrt_info = Eigen::Matrix2d::Identity() / cfg_.point_prior_sigma_m;
  for (auto& [id, l] : points_) {
    auto* cost = new ceres::AutoDiffCostFunction<PointPriorResidual, 2, 2>(
        new PointPriorResidual(l.prior_m, point_sqrt_info));
    problem.AddResidualBlock(cost, nullptr, l.position);
  }
  for (const auto& o : point_obs_) {
    PoseNode& n = poses_.at(o.pose);
    auto* cost =
        new ceres::AutoDiffCostFunction<BearingRangeResidual, 2, 2, 1, 2>(new BearingRangeResidual(
            o.bearing_rad, o.range_m, cfg_.bearing_sigma_rad, cfg_.range_sigma_m));
    problem.AddResidualBlock(cost, robust(), n.position, n.yaw, points_.at(o.landmark_id).position);
  }
  for (auto& o : line_obs_) {
    PoseNode& n = poses_.at(o->pose);
    for (int k = 0; k < 2; ++k) {
      auto* obs = new ceres::AutoDiffCostFunction<BearingRangeResidual, 2, 2, 1, 2>(
          new BearingRangeResidual(o->bearing_rad[k], o->range_m[k], cfg_.bearing_sigma_rad,
                                   cfg_.range_sigma_m));
      problem.AddResidualBlock(obs, robust(), n.position, n.yaw, o->node[k]);
      auto* prior = new ceres::AutoDiffCostFunction<PointPriorResidual, 2, 2>(
          new PointPriorResidual(o->prior_m[k], o->sqrt_information));
      problem.AddResidualBlock(prior, nullptr, o->node[k]);
    }
  }

  ceres::Solver::Options options;
  options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  options.max_num_iterations = cfg_.max_iterations;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  options.minimizer_progress_to_stdout = false;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  sol.iterations = static_cast<int>(summary.iterations.size());
  sol.initial_cost = summary.initial_cost;
  sol.final_cost = summary.final_cost;
  auto& last = poses_.rbegin()->second;
  sol.time_s = last.time_s;
  sol.T_map_vehicle = {last.position[0], last.position[1], wrap_angle_rad(last.yaw[0])};
  if (!summary.IsSolutionUsable()) {
    sol.status = GraphSolution::Status::SolverFailed;
  } else {
    sol.status = GraphSolution::Status::Ok;
    if (cfg_.compute_covariance) {
      ceres::Covariance::Options copt;
      copt.algorithm_type = ceres::SPARSE_QR;
      copt.num_threads = 1;
      ceres::Covariance covariance(copt);
      const std::vector<const double*> blocks{last.position, last.yaw};
      std::vector<std::pair<const double*, const double*>> pairs{
          {last.position, last.position}, {last.position, last.yaw}, {last.yaw, last.yaw}};
      if (covariance.Compute(pairs, &problem)) {
        double c[9];
        if (covariance.GetCovarianceMatrixInTangentSpace(blocks, c)) {
          sol.covariance = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(c);
          sol.covariance_valid = true;
        }
      }
    }
  }
  sol.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return sol;
}

std::optional<Pose2> SlidingWindowGraph::pose(PoseKey key) const {
  const auto it = poses_.find(key);
  if (it == poses_.end()) return std::nullopt;
  return Pose2{it->second.position[0], it->second.position[1], wrap_angle_rad(it->second.yaw[0])};
}

std::optional<SlidingWindowGraph::PoseKey> SlidingWindowGraph::latest_pose() const {
  if (poses_.empty()) return std::nullopt;
  return poses_.rbegin()->first;
}

int SlidingWindowGraph::num_poses() const { return static_cast<int>(poses_.size()); }
int SlidingWindowGraph::num_point_landmarks() const { return static_cast<int>(points_.size()); }
int SlidingWindowGraph::num_line_observations() const { return static_cast<int>(line_obs_.size()); }

int SlidingWindowGraph::num_point_landmarks_since(double time_s) const {
  std::set<std::int64_t> ids;
  for (const auto& o : point_obs_) {
    if (poses_.at(o.pose).time_s >= time_s) ids.insert(o.landmark_id);
  }
  return static_cast<int>(ids.size());
}

int SlidingWindowGraph::num_line_observations_since(double time_s) const {
  return static_cast<int>(std::count_if(line_obs_.begin(), line_obs_.end(), [&](const auto& o) {
    return poses_.at(o->pose).time_s >= time_s;
  }));
}

}  // namespace polmap::loc
