#pragma once
/// @file graph.hpp
/// Sliding-window factor graph (paper §III-F) solved with Ceres.
///
/// Variables: poses T_map_vehicle (position block + yaw block, yaw on an angle
/// manifold) and landmark nodes in the map frame (R²): one node per associated
/// point landmark (shared by all its observations in the window) and two nodes
/// per line observation (its end points, paper Fig. 8).
/// Factors (residuals in graph_factors.hpp, σ from the paper's §IV-B / Table II):
///  - odometry between consecutive poses, σ_t = 0.05 m, σ_φ = 0.01 rad;
///  - bearing-range observations in the vehicle frame, σ_φ = 0.03 rad, σ_r = 0.5 m
///    (Huber-robustified, see GraphConfig);
///  - point-landmark priors at the map position, σ = 0.1 m;
///  - line end-point priors at the orthogonal projection of the observed end
///    point (placed with the pose estimate at insertion time) onto the map
///    line, σ = 0.1 m across and 10σ along the line;
///  - pose priors where the caller adds them (last pose when under-constrained).
/// The window is kept by truncation (no marginalization): poses older than
/// the window are dropped with their factors, landmark nodes without
/// observations are dropped too.
///
/// Every solve() rebuilds a ceres::Problem over the stored nodes, warm-started
/// from the previous solution. The covariance of the latest pose is computed
/// with ceres::Covariance (SPARSE_QR on the robustified Jacobian at the
/// optimum), i.e. the marginal covariance of that pose given every factor in
/// the window, in the tangent space (x_m, y_m, yaw_rad).
#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <vector>

#include "polmap/localization_client/line_geometry.hpp"
#include "polmap/schema/pose2.hpp"

namespace polmap::loc {

/// Noise and solver parameters. Defaults: paper §IV-B / Table II, except
/// the odometry factor: the paper's 0.05 m / 0.01 rad per factor are far looser
/// than our radar odometry over one factor (0.3 s at the default extraction
/// rate: yaw-rate error 0.12-0.22 deg/s -> 0.0006-0.0012 rad, drift 0.1 % of
/// ~3 m -> 3 mm; `polmap egomotion`). With the paper's values a few biased
/// bearings rotate the window freely at low speed and standstill; with these
/// the demo drive's lateral RMSE halves (0.098 -> 0.045 m) and rotation RMSE
/// drops from 0.41 to 0.16 deg (README figures).
struct GraphConfig {
  double odometry_sigma_translation_m = 0.02;  ///< per odometry factor, both axes
  double odometry_sigma_yaw_rad = 0.002;
  double bearing_sigma_rad = 0.03;
  double range_sigma_m = 0.5;
  double point_prior_sigma_m = 0.1;
  double line_prior_sigma_m = 0.1;  ///< across the line
  double line_along_factor = 10.0;  ///< along the line: line_along_factor * σ
  /// Poses older than (latest pose time - window_s) are truncated.
  double window_s = 8.0;
  /// Huber threshold on whitened observation residuals (in σ). A wrong
  /// association that survived smoothing then pulls linearly, not
  /// quadratically. 0 disables the robust loss.
  double observation_huber_sigma = 2.0;
  int max_iterations = 15;
  bool compute_covariance = true;
};

/// Result of one solve.
struct GraphSolution {
  enum class Status {
    Ok,            ///< converged or stopped at the iteration limit with a usable result
    NoPoses,       ///< the window is empty
    SolverFailed,  ///< Ceres reported failure; the stored estimate is unchanged
  };
  Status status = Status::NoPoses;
  double time_s = 0.0;                                   ///< time of the latest pose
  Pose2 T_map_vehicle;                                   ///< latest pose
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();  ///< (x_m, y_m, yaw_rad)
  bool covariance_valid = false;  ///< false when the Jacobian was rank deficient
  double solve_time_s = 0.0;      ///< wall time of optimization + covariance
  int iterations = 0;
  double initial_cost = 0.0;
  double final_cost = 0.0;
  int num_poses = 0;
  int num_point_landmarks = 0;
  int num_line_nodes = 0;
  int num_observation_factors = 0;
  int num_pose_priors = 0;
};

/// The sliding-window graph. Not thread-safe.
class SlidingWindowGraph {
 public:
  using PoseKey = std::uint64_t;

  explicit SlidingWindowGraph(GraphConfig cfg = {});
  ~SlidingWindowGraph();
  SlidingWindowGraph(const SlidingWindowGraph&) = delete;
  SlidingWindowGraph& operator=(const SlidingWindowGraph&) = delete;

  /// Adds a pose at time_s (strictly after the previous one) initialized at
  /// T_map_vehicle_guess. With T_prev_this (relative motion from the previous
  /// pose, vehicle frames, integrated odometry) an odometry factor links it to
  /// the previous pose, with GraphConfig's sigmas plus `extra_odometry_sigma` (along, across,
  /// yaw; added in quadrature: e.g. side slip the odometry does not model).
  PoseKey add_pose(double time_s, const Pose2& T_map_vehicle_guess,
                   const std::optional<Pose2>& T_prev_this,
                   const Eigen::Vector3d& extra_odometry_sigma = Eigen::Vector3d::Zero());

  /// Observation of point landmark landmark_id (map position landmark_map_m,
  /// used for the prior when the landmark is new to the window) at
  /// observed_vehicle_m (candidate position in the vehicle frame of pose).
  void add_point_observation(PoseKey pose, std::int64_t landmark_id,
                             const Eigen::Vector2d& landmark_map_m,
                             const Eigen::Vector2d& observed_vehicle_m);

  /// Observation of a line landmark: the observed segment (vehicle frame of
  /// pose) associated with the map segment (map frame). Adds two end-point
  /// nodes with bearing-range factors and anisotropic priors at the
  /// projections of the end points (placed with the pose's current estimate).
  void add_line_observation(PoseKey pose, std::int64_t line_id, const Segment2& observed_vehicle_m,
                            const Segment2& map_segment_m);

  /// Unary prior on a pose (covariance in x_m, y_m, yaw_rad).
  void add_pose_prior(PoseKey pose, const Pose2& T_map_vehicle, const Eigen::Matrix3d& covariance);

  /// Removes every pose prior in the window (the Localizer keeps one prior at
  /// most: priors derived from one dead-reckoning chain are not independent).
  void clear_pose_priors();

  /// Drops poses older than time_s with their factors and orphaned nodes.
  void truncate_before(double time_s);
  void clear();

  /// Optimizes the window; on success the stored estimates are updated.
  GraphSolution solve();

  [[nodiscard]] std::optional<Pose2> pose(PoseKey key) const;
  [[nodiscard]] std::optional<PoseKey> latest_pose() const;
  [[nodiscard]] int num_poses() const;
  /// Distinct point landmarks and line observations in the window.
  [[nodiscard]] int num_point_landmarks() const;
  [[nodiscard]] int num_line_observations() const;
  /// Distinct point landmarks observed from poses at or after time_s.
  [[nodiscard]] int num_point_landmarks_since(double time_s) const;
  /// Line observations from poses at or after time_s.
  [[nodiscard]] int num_line_observations_since(double time_s) const;
  [[nodiscard]] const GraphConfig& config() const { return cfg_; }

 private:
  struct PoseNode {
    double time_s = 0.0;
    double position[2] = {0.0, 0.0};
    double yaw[1] = {0.0};
    std::optional<Pose2> T_prev_this;  ///< odometry from the previous pose
    Eigen::Vector3d extra_odometry_sigma = Eigen::Vector3d::Zero();  ///< along, across, yaw
    struct Prior {
      Pose2 mean;
      Eigen::Matrix3d sqrt_information;
    };
    std::vector<Prior> priors;
  };
  struct PointNode {
    double position[2] = {0.0, 0.0};
    Eigen::Vector2d prior_m = Eigen::Vector2d::Zero();
  };
  struct PointObservationRecord {
    PoseKey pose;
    std::int64_t landmark_id;
    double bearing_rad, range_m;
  };
  struct LineObservationRecord {
    PoseKey pose;
    std::int64_t line_id;
    double bearing_rad[2], range_m[2];
    double node[2][2];                 ///< end-point node positions (map frame)
    Eigen::Vector2d prior_m[2];        ///< projections onto the map line
    Eigen::Matrix2d sqrt_information;  ///< same for both end points
  };

  GraphConfig cfg_;
  std::map<PoseKey, PoseNode> poses_;  ///< ordered by key = by time
  std::map<std::int64_t, PointNode> points_;
  std::vector<PointObservationRecord> point_obs_;
  std::vector<std::unique_ptr<LineObservationRecord>> line_obs_;  ///< stable addresses
  PoseKey next_key_ = 1;
};

}  // namespace polmap::loc
