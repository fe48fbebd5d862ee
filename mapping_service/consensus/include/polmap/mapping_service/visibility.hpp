#pragma once
/// @file visibility.hpp
/// Which drives had a place in view: the denominator of fleet-scale consensus.
/// A fixed "seen by >= 2 drives" rule lets chance coincidences of single-drive
/// clutter become landmarks once many drives pass a place; judging support
/// against the number of drives that passed with the place in view keeps
/// precision as the fleet grows (consensus.hpp, PointConsensusConfig::min_view_fraction).
///
/// Model: a drive had point p in view when its trajectory passes within its view
/// range of p. The view range of a drive is what its own candidates show: a
/// quantile of their distances from its trajectory (estimate_view_range_m), so a
/// vehicle with short-range sensors is not blamed for missing far landmarks.
/// Occlusion is not modelled (a drive on a parallel street behind a building counts
/// as having had the far side in view when it is within range); the fraction rule's
/// margin absorbs that.
///
/// Pure core: values in, values out; positions in the consensus frame (metres).
///
/// Usage:
///   std::vector<DrivePass> passes = ...;            // one per drive, consensus frame
///   const VisibilityIndex view(std::move(passes));
///   std::vector<std::int64_t> d = view.drives_in_view({12.0, -3.5});
#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <span>
#include <unordered_map>
#include <vector>

namespace polmap::mapping {

/// One drive's pass through the consensus region.
struct DrivePass {
  std::int64_t drive = 0;               ///< drive identity (TaggedPointCandidate::drive)
  std::vector<Eigen::Vector2d> path_m;  ///< trajectory positions, consensus frame, in time order
  double view_range_m = 0.0;            ///< <= 0: VisibilityConfig::default_view_range_m
  double start_time_s = 0.0;            ///< drive start (UNIX time), for time-ordered decisions
  std::int64_t vehicle = 0;             ///< vehicle identity (distinct vehicles for retirement)
};

/// Visibility model settings. Defaults suit the front radars of the paper's vehicle.
struct VisibilityConfig {
  /// Range used for a drive whose own range could not be estimated (no candidates).
  double default_view_range_m = 30.0;
  /// Estimated ranges are clamped to [min_view_range_m, max_view_range_m].
  double min_view_range_m = 5.0;
  double max_view_range_m = 80.0;
  /// Quantile of a drive's candidate distances from its trajectory ...
  double range_quantile = 0.9;
  /// ... times this margin is its range: the farthest landmarks a drive detects lie at
  /// the quantile by construction, and a pass that missed one of them had it in view.
  double range_margin = 1.25;
  /// Paths are simplified to this tolerance before indexing (shorter queries).
  double simplify_tolerance_m = 0.5;
  /// Cell edge of the spatial index.
  double cell_m = 32.0;
};

/// A drive's view range from its own candidates: range_margin times the range_quantile
/// quantile of their distances from its path (clamped), or the default if there are none.
double estimate_view_range_m(std::span<const Eigen::Vector2d> path_m,
                             std::span<const Eigen::Vector2d> candidate_positions_m,
                             const VisibilityConfig& cfg = {});

/// Spatial index of drive passes: which drives had a point in view.
class VisibilityIndex {
 public:
  explicit VisibilityIndex(std::vector<DrivePass> passes, const VisibilityConfig& cfg = {});

  /// Drives (DrivePass::drive, ascending, distinct) whose path comes within their
  /// view range of p.
  [[nodiscard]] std::vector<std::int64_t> drives_in_view(const Eigen::Vector2d& p) const;
  /// Indices into passes() of the same drives (ascending = drive-time order).
  [[nodiscard]] std::vector<std::size_t> passes_in_view(const Eigen::Vector2d& p) const;
  /// Unit direction (sign arbitrary) of the path piece nearest to p among the passes that
  /// had p in view: the direction of the road there. nullopt when no pass had p in view.
  [[nodiscard]] std::optional<Eigen::Vector2d> nearest_path_direction(
      const Eigen::Vector2d& p) const;
  /// The point of that nearest path piece closest to p: where the road is, seen from p.
  [[nodiscard]] std::optional<Eigen::Vector2d> nearest_path_point(const Eigen::Vector2d& p) const;
  /// The point of the paths of `drives` (ascending) nearest to p, whether or not they had p in
  /// view (a return beyond every pass's modelled view: its supporters saw it from there).
  /// nullopt: none of them has a path here.
  [[nodiscard]] std::optional<Eigen::Vector2d> nearest_path_point(
      const Eigen::Vector2d& p, std::span<const std::int64_t> drives) const;
  /// Drives (ascending, distinct) whose (simplified) path crosses or touches the segment
  /// [a, b].
  [[nodiscard]] std::vector<std::int64_t> drives_crossing(const Eigen::Vector2d& a,
                                                          const Eigen::Vector2d& b) const;
  /// How many passes come at least as close to `places` as the farthest of `drives`
  /// (ascending) does, a pass's distance being its path's nearest approach to any of them:
  /// the denominator of a return beyond the modelled view (point_filter.hpp OutOfViewRule).
  /// nullopt: one of `drives` has no pass here (it cannot be said how close it came).
  [[nodiscard]] std::optional<std::size_t> count_passes_as_close(
      std::span<const Eigen::Vector2d> places, std::span<const std::int64_t> drives) const;
  [[nodiscard]] std::size_t count_in_view(const Eigen::Vector2d& p) const {
    return passes_in_view(p).size();
  }
  /// The passes sorted by (start_time_s, drive).
  [[nodiscard]] const std::vector<DrivePass>& passes() const { return passes_; }
  [[nodiscard]] bool empty() const { return passes_.empty(); }

 private:
  struct Piece {
    std::uint32_t pass;
    Eigen::Vector2d a, b;
  };
  /// The pieces indexed in p's cell (every piece within its pass's range of p is there).
  [[nodiscard]] const std::vector<Piece>* pieces_at(const Eigen::Vector2d& p) const;
  /// The nearest non-degenerate piece among the passes that had p in view (nullptr: none).
  [[nodiscard]] const Piece* nearest_piece(const Eigen::Vector2d& p) const;
  std::vector<DrivePass> passes_;
  std::vector<double> range_m_;
  double cell_m_;
  std::unordered_map<std::uint64_t, std::vector<Piece>> cells_;
};

}  // namespace polmap::mapping
