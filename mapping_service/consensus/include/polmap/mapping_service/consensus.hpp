#pragma once
/// @file consensus.hpp
/// Landmark consensus over the candidates of many drives (paper §III-D,
/// parameters §IV-B). Pure core: values in, values out, no I/O, deterministic
/// (the result does not depend on the order of the input: candidates are
/// processed in candidate-id order).
///
/// All positions are metres in ONE common metric frame (the map builder uses
/// a tiles::LocalFrame at the region's centre). Each candidate carries the id
/// of the drive that produced it: edges of the proximity graph only join
/// candidates of DIFFERENT drives, and a group becomes a landmark only when
/// it holds candidates of at least `min_drives` distinct drives, so objects
/// seen in one drive only (parked cars, bins: "temporary objects") never
/// become landmarks.
///
/// Usage:
///   std::vector<TaggedPointCandidate> pts = ...;   // all drives, region frame
///   PointConsensusResult r = consensus_points(pts, PointConsensusConfig{});
///   for (size_t i = 0; i < r.landmarks.size(); ++i) use(r.landmarks[i], r.support[i]);
#include <cstdint>
#include <span>
#include <vector>

#include "polmap/schema/landmark.hpp"

namespace polmap::mapping {

/// A point candidate of one drive, positioned in the consensus frame.
struct TaggedPointCandidate {
  std::int64_t candidate_id = 0;  ///< unique per candidate (store row id)
  std::int64_t drive = 0;         ///< drive identity (store row id)
  PointCandidate candidate;       ///< position_m in the consensus frame
};

/// A line candidate of one drive, positioned in the consensus frame.
struct TaggedLineCandidate {
  std::int64_t candidate_id = 0;
  std::int64_t drive = 0;
  LineCandidate candidate;  ///< start_m / end_m in the consensus frame
};

/// Point consensus parameters. Defaults: paper §IV-B.
struct PointConsensusConfig {
  /// Candidates of different drives closer than this (strictly) are joined: d_p,thres.
  double max_pair_distance_m = 0.3;
  /// A group needs candidates of at least this many distinct drives: N_p,thres.
  int min_drives = 2;
};

/// Line consensus parameters. The first three are the paper's (§IV-B); the
/// rest are ours (the paper names the steps but gives no values).
struct LineConsensusConfig {
  /// Convex-hull distance d_l,ch,thres: area of the convex hull of both
  /// segments' end points divided by their merged length (a mean spread).
  double max_hull_distance_m = 0.09;
  /// Projection distance d_l,prj,thres: gap between the two segments'
  /// intervals projected onto their common direction (0 if they overlap).
  double max_projection_distance_m = 1.5;
  int min_drives = 2;
  /// A merged group whose member end points deviate more than this from the
  /// straight merged segment is a curve and becomes a polyline; the polyline
  /// is refined RDP-style until no member sample is farther than this from
  /// it (the error bound of "no shortcut").
  double polyline_max_error_m = 0.1;
  /// Spacing of samples along member segments when building a curve's
  /// centre line (bins of this width along the curve are averaged).
  double curve_sample_spacing_m = 0.25;
  /// Ends of two different line landmarks whose end edges cross, or would
  /// cross after extending/shortening each end by at most this much, are
  /// snapped to the intersection point.
  double snap_max_gap_m = 1.0;
  /// Snapping only between end edges meeting at more than this angle (nearly
  /// parallel edges have ill-conditioned intersections; 20°).
  double snap_min_angle_rad = 0.35;
};

/// Point consensus outcome. landmarks[i] is supported by candidates support[i].
struct PointConsensusResult {
  std::vector<PointLandmark> landmarks;            ///< id = index in this vector
  std::vector<std::vector<std::int64_t>> support;  ///< candidate ids, ascending
  struct Stats {
    std::size_t candidates = 0;
    std::size_t pairs = 0;            ///< cross-drive edges
    std::size_t groups = 0;           ///< connected components (incl. singletons)
    std::size_t rejected_groups = 0;  ///< groups with < min_drives drives
    std::size_t largest_group = 0;    ///< members of the largest accepted group
  } stats;
};

/// Line consensus outcome. landmarks[i] is supported by candidates support[i].
struct LineConsensusResult {
  std::vector<LineLandmark> landmarks;  ///< id = index in this vector
  std::vector<std::vector<std::int64_t>> support;
  struct Stats {
    std::size_t candidates = 0;
    std::size_t pairs = 0;
    std::size_t groups = 0;
    std::size_t rejected_groups = 0;
    std::size_t polylines = 0;     ///< landmarks with more than two vertices
    std::size_t snapped_ends = 0;  ///< line ends moved to an intersection
  } stats;
};

/// Points: k-d tree (nanoflann) radius search, cross-drive pairs closer than
/// max_pair_distance_m, connected components (union-find), groups with at
/// least min_drives distinct drives. Landmark position = mean of members,
/// support_drives = distinct drives, spread_m = RMS distance to the mean,
/// scattering = majority class of members (Unknown ignored unless all are;
/// ties -> Mixed).
PointConsensusResult consensus_points(std::span<const TaggedPointCandidate> candidates,
                                      const PointConsensusConfig& cfg = {});

/// Lines: pairs of cross-drive segments with hull distance < max_hull_distance_m
/// and projection distance < max_projection_distance_m (found through a grid
/// over bounding boxes grown by max_projection_distance_m), connected
/// components, groups with >= min_drives drives. A straight group merges to
/// the segment spanned by the farthest projections of its members' end
/// points onto the group's principal (length-weighted) direction, through the
/// length-weighted centroid; a curved group becomes a polyline (see
/// LineConsensusConfig::polyline_max_error_m). Finally end edges that cross
/// or nearly cross are snapped to their intersection. spread_m = RMS distance
/// of member samples (every curve_sample_spacing_m along each member) to the
/// merged polyline, before snapping.
LineConsensusResult consensus_lines(std::span<const TaggedLineCandidate> candidates,
                                    const LineConsensusConfig& cfg = {});

/// Pair measures of the line consensus, exposed for tests and the matcher.
struct LinePairDistance {
  double hull_m = 0.0;        ///< convex-hull area / merged length
  double projection_m = 0.0;  ///< gap between projected intervals (0 if overlapping)
};
/// Common direction = length-weighted mean of the two (sign-aligned) segment
/// directions; merged length = extent of the four end points along it.
LinePairDistance line_pair_distance(const LineCandidate& a, const LineCandidate& b);

/// Brute-force O(n²) reference of consensus_points (tests only).
PointConsensusResult consensus_points_bruteforce(std::span<const TaggedPointCandidate> candidates,
                                                 const PointConsensusConfig& cfg = {});

}  // namespace polmap::mapping
