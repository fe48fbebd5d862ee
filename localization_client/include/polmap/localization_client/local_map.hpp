#pragma once
/// @file local_map.hpp
/// Local-map clustering (paper §III-E, first step): landmark candidate
/// observations collected within a temporal window in the odometry frame (pure
/// integrated ego-motion, never the localization result, so the local map
/// cannot reinforce its own errors) are grouped into clusters, one per
/// physical landmark, by connected components of a sparse distance graph built
/// with a k-d tree. Connected components (instead of Wilbers' nearest-cluster
/// assignment) tolerate more odometry drift inside the window, since a chain
/// of slightly drifting observations stays one cluster.
///
/// Clusters keep stable ids across re-clustering (the id of the previous
/// cluster that contributed most members), so temporal smoothing can count
/// associations per cluster over time.
#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <vector>

#include "polmap/localization_client/line_geometry.hpp"
#include "polmap/schema/landmark.hpp"
#include "polmap/schema/pose2.hpp"

namespace polmap::loc {

/// Edge rule of the line distance graph. Two segments are linked when
///   line_distance.hull_m <= hull_distance_m AND
///   line_distance.projection_m <= projection_distance_m AND
///   segment_distance <= gate_distance_m.
/// The third condition bounds the k-d tree query (segment midpoints within
/// (len_i + len_max) / 2 + gate_distance_m), so the fast path is exact, and it
/// keeps nearly collinear but far apart segments (two curbs 30 m apart on one
/// straight road) from linking through a tiny hull distance.
struct LineLinkConfig {
  double hull_distance_m = 0.25;       ///< local observations are noisier than consensus' 0.09 m
  double projection_distance_m = 1.5;  ///< paper §IV-B d_prj
  double gate_distance_m = 1.5;        ///< Euclidean segment distance bound
};

/// Parameters of the local map.
struct LocalMapConfig {
  /// Observations older than (latest time - window_s) are dropped. 8 s at
  /// 10 m/s covers 80 m, about the radar's reach, while odometry drift over
  /// the window stays well below the link distance.
  double window_s = 8.0;
  /// Point observations closer than this are linked (k-d tree radius). Larger
  /// than the consensus' 0.3 m because repeated extractions of one landmark from
  /// a sliding-window gridmap jitter by a cell or two plus odometry drift.
  double point_link_distance_m = 0.5;
  LineLinkConfig line_link;
  /// Centroids weight each observation by 1 / (σ0² + (σ_az · range)²): far
  /// candidates are laterally less precise (azimuth resolution ~3°) and far
  /// point targets sometimes split into two candidates ~0.5 m apart.
  double centroid_sigma0_m = 0.05;
  double centroid_sigma_azimuth_rad = 0.01;
};

/// One point candidate as observed at one extraction time, odometry frame.
struct PointObservation {
  double time_s = 0.0;
  std::uint64_t extraction_index = 0;  ///< which add() call produced it
  Eigen::Vector2d position_odom_m = Eigen::Vector2d::Zero();
  double range_m = 0.0;  ///< distance from the vehicle at extraction (0 if unknown)
  ScatteringClass scattering = ScatteringClass::Unknown;
  double strength = 0.0;
};

/// One line candidate as observed at one extraction time, odometry frame.
struct LineObservation {
  double time_s = 0.0;
  std::uint64_t extraction_index = 0;
  Segment2 segment_odom_m;
  double strength = 0.0;
};

/// A group of point observations believed to be one landmark.
struct PointCluster {
  std::uint64_t id = 0;  ///< stable across re-clustering (see file comment)
  /// Precision-weighted mean of the members (LocalMapConfig).
  Eigen::Vector2d centroid_odom_m = Eigen::Vector2d::Zero();
  int num_observations = 0;
  double first_time_s = 0.0;
  double last_time_s = 0.0;
  /// True when an observation of the latest add() belongs to the cluster.
  bool observed_latest = false;
  std::vector<std::size_t> members;  ///< indices into LocalMap::point_observations()
};

/// A group of line observations believed to be one line landmark.
struct LineCluster {
  std::uint64_t id = 0;
  Segment2 segment_odom_m;  ///< merge_segments() of the members
  int num_observations = 0;
  double first_time_s = 0.0;
  double last_time_s = 0.0;
  bool observed_latest = false;
  std::vector<std::size_t> members;  ///< indices into LocalMap::line_observations()
};

/// Connected-component labels of the point distance graph (edge when the
/// distance is <= link_distance_m). Labels are 0..K-1, numbered in order of
/// each component's smallest member index. k-d tree fast path.
[[nodiscard]] std::vector<int> cluster_points(std::span<const Eigen::Vector2d> points,
                                              double link_distance_m);

/// Connected-component labels of the line distance graph (LineLinkConfig),
/// numbered like cluster_points(). k-d tree over midpoints as the fast path.
[[nodiscard]] std::vector<int> cluster_segments(std::span<const Segment2> segments,
                                                const LineLinkConfig& cfg);

/// True when two segments are linked by the rule of LineLinkConfig.
[[nodiscard]] bool segments_linked(const Segment2& s, const Segment2& t, const LineLinkConfig& cfg);

/// The windowed local map. Not thread-safe; one per Localizer.
class LocalMap {
 public:
  explicit LocalMap(LocalMapConfig cfg = {});

  /// Adds one extraction's candidates (odometry frame) taken at time_s with
  /// the vehicle at T_odom_vehicle (for the observations' ranges), drops
  /// observations older than time_s - window_s and re-clusters.
  void add(double time_s, const Pose2& T_odom_vehicle, std::span<const PointCandidate> points_odom,
           std::span<const LineCandidate> lines_odom);
  /// Same without a vehicle pose: all observations weigh the same.
  void add(double time_s, std::span<const PointCandidate> points_odom,
           std::span<const LineCandidate> lines_odom);
  /// Drops everything (e.g. after the odometry was reset).
  void clear();

  [[nodiscard]] const std::vector<PointObservation>& point_observations() const { return points_; }
  [[nodiscard]] const std::vector<LineObservation>& line_observations() const { return lines_; }
  [[nodiscard]] const std::vector<PointCluster>& point_clusters() const { return point_clusters_; }
  [[nodiscard]] const std::vector<LineCluster>& line_clusters() const { return line_clusters_; }
  /// Cluster index (into point_clusters()) of point observation i.
  [[nodiscard]] int point_cluster_of(std::size_t i) const { return point_label_[i]; }
  [[nodiscard]] int line_cluster_of(std::size_t i) const { return line_label_[i]; }
  [[nodiscard]] std::uint64_t latest_extraction_index() const { return next_extraction_ - 1; }
  [[nodiscard]] const LocalMapConfig& config() const { return cfg_; }

  /// The clusters as seen from observations taken at or after since_s only: point
  /// centroids (same weights as point_clusters()) and merged segments recomputed from
  /// those members, clusters without such members dropped, ids, first/last times of the
  /// kept members and observed_latest kept. Members index point_observations() /
  /// line_observations() as in the full clusters. A view with since_s at or before the
  /// window's start equals the full clusters.
  struct View {
    std::vector<PointCluster> points;
    std::vector<LineCluster> lines;
  };
  [[nodiscard]] View recent(double since_s) const;

 private:
  void add_impl(double time_s, const Pose2* T_odom_vehicle,
                std::span<const PointCandidate> points_odom,
                std::span<const LineCandidate> lines_odom);
  void recluster();
  /// Fills c (members, times, observed_latest, centroid or merged segment) from the
  /// observations among `members` taken at or after since_s; false when there are none.
  /// One rule for the clusters and for recent().
  bool summarize(std::span<const std::size_t> members, double since_s, std::uint64_t latest,
                 PointCluster& c) const;
  bool summarize(std::span<const std::size_t> members, double since_s, std::uint64_t latest,
                 LineCluster& c) const;

  LocalMapConfig cfg_;
  std::vector<PointObservation> points_;
  std::vector<LineObservation> lines_;
  std::vector<std::uint64_t> point_prev_id_;  ///< cluster id each observation had; 0 = new
  std::vector<std::uint64_t> line_prev_id_;
  std::vector<int> point_label_, line_label_;
  std::vector<PointCluster> point_clusters_;
  std::vector<LineCluster> line_clusters_;
  std::uint64_t next_extraction_ = 1;
  std::uint64_t next_cluster_id_ = 1;
};

}  // namespace polmap::loc
