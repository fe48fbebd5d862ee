#pragma once
/// @file matcher.hpp
/// Landmark-based map matching (paper §III-E, after Wilbers): finds the
/// transform T_map_odom that places the local map's clusters (odometry frame)
/// onto the map landmarks, and the associations cluster -> map landmark.
///
/// Algorithm:
///  1. Gate. The prior is the predicted vehicle pose T_map_vehicle with its
///     covariance (x_m, y_m, yaw_rad); gating the VEHICLE pose (not T_map_odom)
///     keeps yaw uncertainty pivoting about the vehicle instead of the far-away
///     odometry origin. A cluster's map candidates are the map points within
///     its predicted position's gate radius.
///  2. Candidates. For pairs of well-observed anchor clusters (l1, l2) with a
///     baseline >= min_pair_baseline_m, and map candidates (m1, m2) whose
///     distance agrees with |l1 - l2| within pair_distance_tolerance_m, the
///     rigid transform mapping l1 -> m1, l2 -> m2 is a candidate if its vehicle
///     pose passes the Mahalanobis gate. The prior itself is always a candidate.
///     Near-duplicates (same pose within a quantum) are scored once.
///     Second generator (robust when most clusters have no map counterpart,
///     where random anchor pairs rarely hit two real landmarks): for yaw
///     hypotheses across the gate (yaw_step_rad apart, rotating the predicted
///     local map about the predicted vehicle position), every cluster votes for
///     the translations that would put it onto each map point inside its gate
///     (2-D histogram, vote_cell_m bins, 3×3 peak sum); the strongest peaks
///     over all yaws become candidates. A correlative scan in the spirit of
///     Olson's, costing clusters × gated map points per yaw.
///  3. Score = Σ_points w_i min(d_i / d_trunc, 1)², d_i the distance to the
///     nearest map point, w_i = min(1, observations / 3): a local cluster
///     without a map counterpart costs the full penalty 1 whatever the
///     transform, so partial overlap and outliers add a constant and cannot
///     pull the optimum; matching few clusters well cannot beat matching many.
///  4. The best distinct candidates (non-maximum suppression) are refined by
///     ICP-style Gauss-Newton on point-to-point and line end-point-to-line
///     residuals in both directions, then rescored with lines (Σ w_line
///     min((hull + projection) / d_line_trunc, 1)²) and the unmatched map
///     landmarks (paper: "additional cost for unmatched landmarks"): every map
///     point near the observed area costs its truncated distance to the
///     nearest cluster. This map -> local term is what keeps clutter (speckle
///     of foliage around a tree trunk, parts of parked cars: candidates that
///     are in no map) from pulling the transform: clutter near landmarks can
///     lower the local -> map cost of a wrong transform, never the map -> local
///     cost, which is smallest when every landmark sits on a cluster.
///  5. The best refined candidate wins; the runner-up distinct candidate's cost
///     measures ambiguity (repetitive post rows).
/// Associations of the winner: mutual nearest neighbours (the cluster's
/// nearest map point has that cluster as its nearest cluster) within the
/// association distance, hence injective.
#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "polmap/localization_client/line_geometry.hpp"
#include "polmap/localization_client/local_map.hpp"
#include "polmap/schema/landmark.hpp"
#include "polmap/schema/pose2.hpp"

namespace polmap::loc {

/// Map landmarks in the client's map frame, indexed for matching.
class MapIndex {
 public:
  /// One straight edge of a line landmark's polyline.
  struct LineEdge {
    std::size_t line = 0;  ///< index into lines()
    int edge = 0;          ///< edge k joins polyline vertices k and k+1
    Segment2 segment_m;
  };

  MapIndex();
  MapIndex(std::vector<PointLandmark> points, std::vector<LineLandmark> lines);
  ~MapIndex();
  MapIndex(MapIndex&&) noexcept;
  MapIndex& operator=(MapIndex&&) noexcept;

  [[nodiscard]] const std::vector<PointLandmark>& points() const { return points_; }
  [[nodiscard]] const std::vector<LineLandmark>& lines() const { return lines_; }
  [[nodiscard]] const std::vector<LineEdge>& edges() const { return edges_; }
  [[nodiscard]] bool empty() const { return points_.empty() && lines_.empty(); }

  /// Indices of map points within radius_m of q.
  void points_within(const Eigen::Vector2d& q, double radius_m,
                     std::vector<std::size_t>& out) const;
  /// Nearest map point (index, distance), nullopt if there are no points.
  [[nodiscard]] std::optional<std::pair<std::size_t, double>> nearest_point(
      const Eigen::Vector2d& q) const;
  /// nearest_point() if within max_m (inclusive), else nullopt; much cheaper for
  /// queries far from every landmark.
  [[nodiscard]] std::optional<std::pair<std::size_t, double>> nearest_point_within(
      const Eigen::Vector2d& q, double max_m) const;
  /// Indices of edges that may lie within radius_m of q (a superset: every
  /// edge whose Euclidean distance to q is <= radius_m is included).
  void edges_near(const Eigen::Vector2d& q, double radius_m, std::vector<std::size_t>& out) const;
  /// Lookup by landmark id.
  [[nodiscard]] const PointLandmark* find_point(std::int64_t id) const;
  [[nodiscard]] const LineLandmark* find_line(std::int64_t id) const;

 private:
  struct Trees;
  std::vector<PointLandmark> points_;
  std::vector<LineLandmark> lines_;
  std::vector<LineEdge> edges_;
  std::unordered_map<std::int64_t, std::size_t> point_by_id_, line_by_id_;
  std::vector<std::size_t> sample_edge_;  ///< edge of each edge sample point
  std::unique_ptr<Trees> trees_;
};

/// Predicted pose and its uncertainty.
struct MatchPrior {
  Pose2 T_map_odom;      ///< predicted map <- odometry transform
  Pose2 T_odom_vehicle;  ///< current vehicle pose in the odometry frame
  /// Covariance of the predicted T_map_vehicle = T_map_odom * T_odom_vehicle
  /// in (x_m, y_m, yaw_rad).
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
};

/// Parameters of the matcher; defaults for the paper's radar and map density.
struct MatcherConfig {
  double gate_chi2 = 16.0;  ///< Mahalanobis² gate of a candidate's vehicle pose (3 DoF ≈ 99.9 %)
  /// Upper bound of the per-cluster search radius (translation part of the
  /// gate). After a long outage the covariance can be tens of metres; beyond
  /// ~40 m the voting cost explodes while the map offers only repetitions.
  double max_gate_radius_m = 40.0;
  double pair_distance_tolerance_m = 0.5;  ///< |d(l1,l2) - d(m1,m2)|: cluster noise + drift
  double min_pair_baseline_m = 3.0;        ///< short baselines give unstable yaw
  int max_anchor_clusters = 14;            ///< most-observed clusters used to make candidates
  int min_anchor_observations = 2;         ///< single sightings are too often noise
  int max_candidates = 20000;              ///< hard cap on scored candidates per call
  bool use_voting = true;                  ///< the correlative generator (see file comment)
  double yaw_step_rad = 0.005;             ///< ≈ 0.3°: 0.15 m lateral at 30 m range
  int max_yaw_hypotheses = 81;             ///< the step widens beyond this many
  double vote_cell_m = 0.25;               ///< translation histogram bin
  int vote_peaks = 24;                     ///< best (yaw, translation) peaks kept as candidates
  /// d_trunc. Small on purpose: clutter (foliage speckle, car parts) sits
  /// 0.3-2 m from real landmarks; a true match is within ~0.1 m.
  double point_truncation_m = 0.5;
  double line_truncation_m = 1.0;  ///< for hull + projection distance
  double line_weight = 1.0;        ///< weight of one line cluster vs one point cluster
  /// Weight of the map -> local term (see file comment, step 4): each map point
  /// near the observed area costs min(d / d_trunc, 1)², d = distance to its
  /// nearest transformed cluster. 0 disables it.
  double map_to_local_weight = 1.0;
  /// "Near the observed area": a cluster within this distance of the map point
  /// under the prior transform, plus the gate radius.
  double coverage_radius_m = 3.0;
  double association_distance_m = 0.4;       ///< point association after refinement
  double line_association_distance_m = 0.6;  ///< hull + projection, line association
  int refine_top_k = 6;
  int refine_iterations = 6;
  double distinct_translation_m = 1.0;  ///< candidates further apart are "distinct"
  double distinct_yaw_rad = 0.035;
  /// Match is Ok only when the runner-up distinct candidate costs at least
  /// this much more (in units of one fully unmatched cluster).
  double ambiguity_margin = 1.0;
  int min_point_matches = 3;  ///< fewer associations (lines count half) -> TooFewMatches
  bool use_lines = true;      ///< lines in refinement, rescoring and associations
};

/// A point cluster associated with a map point landmark.
struct PointMatch {
  std::uint64_t cluster_id = 0;
  std::int64_t landmark_id = 0;
  double distance_m = 0.0;  ///< after applying the matched transform
};

/// A line cluster associated with one edge of a map line landmark.
struct LineMatch {
  std::uint64_t cluster_id = 0;
  std::int64_t landmark_id = 0;
  int edge_index = 0;
  LineDistance distance;
};

/// Result of one matching call.
struct MatchResult {
  enum class Status {
    Ok,              ///< confident: enough associations and unambiguous
    TooFewClusters,  ///< not enough local clusters to form candidates
    NoCandidate,     ///< no transform candidate passed the gate
    TooFewMatches,   ///< the best candidate has fewer than min_point_matches associations
    Ambiguous,       ///< a distinct candidate scores nearly as well (result still filled)
  };
  Status status = Status::NoCandidate;
  Pose2 T_map_odom;  ///< best transform (valid unless TooFewClusters / NoCandidate)
  double cost = 0.0;
  std::optional<double> runner_up_cost;  ///< best distinct alternative, if any
  int candidates_scored = 0;
  std::vector<PointMatch> points;
  std::vector<LineMatch> lines;
  [[nodiscard]] double effective_matches() const {
    return static_cast<double>(points.size()) + 0.5 * static_cast<double>(lines.size());
  }
};

/// Matches the local map against the map (see file comment). Pure function.
[[nodiscard]] MatchResult match_local_map(std::span<const PointCluster> points_odom,
                                          std::span<const LineCluster> lines_odom,
                                          const MapIndex& map, const MatchPrior& prior,
                                          const MatcherConfig& cfg = {});

[[nodiscard]] std::string_view to_string(MatchResult::Status s);

}  // namespace polmap::loc
