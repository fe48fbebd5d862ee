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
/// Fleet scale: given a VisibilityIndex (visibility.hpp), a group also needs the
/// support of a share of the drives that passed it with the place in view, and a
/// landmark that recent passes of several vehicles miss is retired (SupportRule).
/// With few drives this is the paper's fixed count; with many, chance
/// coincidences of single-drive clutter (a handful of drives out of hundreds)
/// stay below it while permanent objects, seen by most passes, stay above.
///
/// Usage:
///   std::vector<TaggedPointCandidate> pts = ...;   // all drives, region frame
///   PointConsensusResult r = consensus_points(pts, PointConsensusConfig{});
///   for (size_t i = 0; i < r.landmarks.size(); ++i) use(r.landmarks[i], r.support[i]);
#include <cstdint>
#include <span>
#include <vector>

#include "polmap/mapping_service/line_filter.hpp"
#include "polmap/mapping_service/point_filter.hpp"
#include "polmap/mapping_service/visibility.hpp"
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

/// When a group of candidates is a landmark (SupportRule, judge_support). The
/// defaults make a fleet of 2–5 drives behave as the paper (2 distinct drives) and
/// keep precision as drives accumulate.
///
/// With a VisibilityIndex, the passes that had the group in view are ordered by
/// drive start time (not upload order), and:
///  - all-time rule: support >= required(all passes in view);
///  - recent rule: support among the last `recent_passes` passes in view >=
///    required(those passes) — a new object is accepted once recent drives see it;
///  - miss streak: the most recent passes in view that did NOT support the group, and
///    their distinct vehicles.
/// A miss streak of at least `retire_min_misses` passes from at least
/// `retire_min_vehicles` distinct vehicles retires the group (one vehicle, e.g. with
/// a faulty sensor, cannot retire a landmark alone). Otherwise it is accepted if the
/// recent or the all-time rule holds. Retired: one of the rules holds but the streak
/// retires it (it was a landmark; recent passes of several vehicles no longer see it).
/// required(n) = max(min_drives, ceil(min_view_fraction * n)).
/// Without a VisibilityIndex: accepted iff support >= min_drives.
struct SupportRule {
  /// Distinct drives a group needs in any case: N_p,thres / N_l,thres (paper §IV-B).
  int min_drives = 2;
  /// Share of the passes in view that must support it. 0.5: a permanent object
  /// detected in most passes is kept, clutter coinciding in a few of many drives and
  /// temporary objects present in fewer than half of the passes are not.
  double min_view_fraction = 0.5;
  /// The recent rule's window (passes in view, latest by drive time).
  int recent_passes = 32;
  /// A landmark is retired after at least this many consecutive recent misses ...
  int retire_min_misses = 5;
  /// ... by at least this many distinct vehicles.
  int retire_min_vehicles = 2;
};

/// Support a group needs among n passes: max(min_drives, ceil(min_view_fraction * n)).
int required_support(int min_drives, double min_view_fraction, std::size_t passes_in_view);

/// The verdict on one group (see SupportRule).
struct SupportVerdict {
  enum class Status { Accepted, Rejected, Retired };
  Status status = Status::Rejected;
  std::uint32_t support_drives = 0;  ///< distinct drives among the members
  std::uint32_t drives_in_view = 0;  ///< passes in view, supporting drives included
  std::uint32_t recent_passes = 0;   ///< passes in the recent window
  std::uint32_t recent_support = 0;  ///< of those, supporting
  std::uint32_t miss_streak = 0;     ///< latest consecutive passes in view without support
  std::uint32_t miss_streak_vehicles = 0;
  double last_support_time_s = 0.0;  ///< start time of the latest supporting pass (0: unknown)
};

/// Judges a group with distinct supporting drives `support_drives_sorted` (ascending)
/// at `places` (the drives that had any of them in view count). view == nullptr: the
/// fixed min_drives rule.
SupportVerdict judge_support(const VisibilityIndex* view, std::span<const Eigen::Vector2d> places,
                             std::span<const std::int64_t> support_drives_sorted,
                             const SupportRule& rule);

/// Point consensus parameters. Defaults: paper §IV-B.
struct PointConsensusConfig {
  /// Candidates of different drives closer than this (strictly) are joined: d_p,thres.
  double max_pair_distance_m = 0.3;
  SupportRule support;
  /// Groups of at least this many drives are split at their density modes (mean
  /// shift, radius d_p / 2; modes closer than d_p are one) and each mode positioned by
  /// the mean of its members
  /// within d_p / 2 (robust to clutter at the rim); smaller groups keep the paper's
  /// plain mean.
  int split_min_drives = 8;
  /// Larger groups (a pathological clutter chain) are not split (bounded work).
  std::size_t split_max_members = 20000;
  /// Line peaks and temporary objects removed after line consensus (point_filter.hpp;
  /// applied by the map builder through filter_point_landmarks, not by consensus_points).
  PointFilterConfig filter;
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
  /// Judged at the merged line's vertices and midpoint (the drives that had any of
  /// them in view).
  SupportRule support;
  /// A merged group whose member end points deviate more than this from the
  /// straight merged segment is a curve and becomes a polyline; the polyline
  /// is refined RDP-style until no member sample is farther than this from
  /// it (the error bound of "no shortcut").
  double polyline_max_error_m = 0.1;
  /// A merged line spans the part of it that at least
  /// max(1, ceil(extent_min_drive_share × its drives)) distinct drives' candidates
  /// cover, not the extreme member ends: those are the tails of the end-position noise
  /// and move outward as drives accumulate (simulated urban route, 64 drives: landmark
  /// ends 0.3–1.9 m beyond facade and curb ends, the median member end within 0.3 m).
  /// 0.5: the support rule's share; groups of 1–2 drives keep the union.
  double extent_min_drive_share = 0.5;
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
  /// Overhead structures, range streaks and out-of-view returns removed after line
  /// consensus (line_filter.hpp; applied by the map builder through filter_line_landmarks,
  /// before the point filter, not by consensus_lines).
  LineFilterConfig filter;
};

/// Point consensus outcome. landmarks[i] is supported by candidates support[i].
struct PointConsensusResult {
  std::vector<PointLandmark> landmarks;            ///< id = index in this vector
  std::vector<std::vector<std::int64_t>> support;  ///< candidate ids, ascending
  std::vector<SupportVerdict> verdicts;            ///< verdicts[i] for landmarks[i]
  /// Groups the rule retired (SupportVerdict::Status::Retired), as landmarks would be.
  std::vector<PointLandmark> retired;
  std::vector<SupportVerdict> retired_verdicts;
  struct Stats {
    std::size_t candidates = 0;
    std::size_t pairs = 0;            ///< cross-drive edges
    std::size_t groups = 0;           ///< connected components (incl. singletons)
    std::size_t rejected_groups = 0;  ///< groups below the required support
    std::size_t retired_groups = 0;
    std::size_t split_groups = 0;   ///< components split into several modes
    std::size_t largest_group = 0;  ///< members of the largest accepted group
  } stats;
};

/// Line consensus outcome. landmarks[i] is supported by candidates support[i].
struct LineConsensusResult {
  std::vector<LineLandmark> landmarks;  ///< id = index in this vector
  std::vector<std::vector<std::int64_t>> support;
  std::vector<SupportVerdict> verdicts;
  std::vector<LineLandmark> retired;
  std::vector<SupportVerdict> retired_verdicts;
  struct Stats {
    std::size_t candidates = 0;
    std::size_t pairs = 0;  ///< joining pairs found (pairs already joined are not tested)
    std::size_t groups = 0;
    std::size_t rejected_groups = 0;
    std::size_t retired_groups = 0;
    std::size_t polylines = 0;     ///< landmarks with more than two vertices
    std::size_t snapped_ends = 0;  ///< line ends moved to an intersection
  } stats;
};

/// Points: k-d tree (nanoflann) radius search, cross-drive pairs closer than
/// max_pair_distance_m, connected components (union-find), groups with at
/// least min_drives distinct drives (and the SupportRule with a view); components
/// of many drives split at their modes (PointConsensusConfig::split_min_drives).
/// Landmark position = mean of members (modes: trimmed mean),
/// support_drives = distinct drives, spread_m = RMS distance to the mean,
/// scattering = majority class of members (Unknown ignored unless all are;
/// ties -> Mixed).
/// `view`: the drives' passes (nullptr: the fixed min_drives rule alone; SupportRule).
PointConsensusResult consensus_points(std::span<const TaggedPointCandidate> candidates,
                                      const PointConsensusConfig& cfg = {},
                                      const VisibilityIndex* view = nullptr);

/// Lines: pairs of cross-drive segments with hull distance < max_hull_distance_m
/// and projection distance < max_projection_distance_m (found through a grid
/// over bounding boxes grown by max_projection_distance_m), connected
/// components, groups with >= min_drives drives. A straight group merges to
/// the segment along the group's principal (length-weighted) direction, through
/// the length-weighted centroid, over the part that enough of its drives cover
/// (LineConsensusConfig::extent_min_drive_share); a curved group becomes a
/// polyline (see LineConsensusConfig::polyline_max_error_m). Finally end edges
/// that cross or nearly cross are snapped to their intersection. spread_m = RMS
/// distance of member samples (every curve_sample_spacing_m along each member,
/// within that extent) to the merged polyline, before snapping.
LineConsensusResult consensus_lines(std::span<const TaggedLineCandidate> candidates,
                                    const LineConsensusConfig& cfg = {},
                                    const VisibilityIndex* view = nullptr);

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
                                                 const PointConsensusConfig& cfg = {},
                                                 const VisibilityIndex* view = nullptr);

}  // namespace polmap::mapping
