#pragma once
/// @file smoothing.hpp
/// Temporal smoothing of map-matching associations (paper §III-E, last step).
/// Each local cluster counts how often each map landmark was associated with
/// it over time; the smoothed association is the maximum-weight bipartite
/// matching of the count matrix, so it is injective: a map landmark serves at
/// most one cluster (Wilbers' per-cluster arg-max would keep both when an
/// outlier cluster sometimes steals a landmark from its true cluster).
#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <utility>
#include <vector>

namespace polmap::loc {

/// A (row, column) pair of an assignment.
struct Assignment {
  int row = 0;
  int col = 0;
};

/// Minimum-cost assignment of a rectangular cost matrix (Hungarian algorithm,
/// Kuhn-Munkres with potentials, O(n^2 m) for n = min(rows, cols),
/// m = max(rows, cols)). Every row (if rows <= cols) or every column (otherwise)
/// is assigned; result sorted by row.
[[nodiscard]] std::vector<Assignment> min_cost_assignment(const Eigen::MatrixXd& cost);

/// Maximum-weight bipartite matching: a set of (row, col) pairs, each row and
/// each column at most once, maximizing the sum of weights. Pairs with weight
/// <= 0 are never returned (leaving a vertex unmatched is free). Sorted by row.
[[nodiscard]] std::vector<Assignment> max_weight_matching(const Eigen::MatrixXd& weight);

/// Parameters of the association smoother.
struct SmoothingConfig {
  /// Smoothed associations need at least this many (decayed) votes, so one
  /// lucky match of a new cluster does not enter the graph.
  double min_count = 2.0;
  /// Each update multiplies old counts by this factor (1 = pure counting as in
  /// the paper); slightly below 1 lets a corrected association win after a
  /// long wrong streak without waiting for the cluster to expire.
  double decay = 0.98;
};

/// One association of a local cluster with a map landmark.
struct ClusterAssociation {
  std::uint64_t cluster_id = 0;
  std::int64_t landmark_id = 0;
  double count = 0.0;  ///< smoothed: the (decayed) vote count behind it
};

/// Accumulates association votes per (cluster id, landmark id) and returns
/// the injective smoothed associations. Points and lines use separate
/// instances (their ids live in different spaces).
class AssociationSmoother {
 public:
  explicit AssociationSmoother(SmoothingConfig cfg = {});

  /// Adds one matching result's associations (one vote each).
  void add_votes(const std::vector<std::pair<std::uint64_t, std::int64_t>>& cluster_landmark);
  /// Forgets clusters that no longer exist in the local map.
  void retain_clusters(const std::vector<std::uint64_t>& alive_cluster_ids);
  void clear() { counts_.clear(); }

  /// Injective associations (max-weight bipartite matching over the counts),
  /// each with count >= min_count. Sorted by cluster id.
  [[nodiscard]] std::vector<ClusterAssociation> smoothed() const;
  [[nodiscard]] double count(std::uint64_t cluster_id, std::int64_t landmark_id) const;

 private:
  SmoothingConfig cfg_;
  std::map<std::uint64_t, std::map<std::int64_t, double>> counts_;
};

}  // namespace polmap::loc
