#pragma once
/// @file line_filter.hpp
/// Precision of fleet line consensus: line landmarks that are not walls, facades, curbs,
/// guardrails or fences, judged after line consensus (consensus.hpp) and before the point
/// filter (point_filter.hpp, which uses the line landmarks as reflectors and surfaces).
///
/// Under realistic radar errors (the simulator's `--realism realistic`: multipath and
/// overhead structures) three kinds of repeatable but wrong line landmarks survive the
/// support rule (simulated urban route, 64 drives: 0.07 of the line length, README "Fleet
/// map production"):
///  - overhead structures: a sign gantry or bridge beam across the road returns at its
///    slant range, and the gridmap shows a line across the road. Every pass drove under it.
///    A line that the supporting drives' own paths cross cannot stand at ground level: the
///    vehicles drove through it (OverheadRule).
///  - range streaks: multipath off a facade behind a strong object (a pole, a trunk)
///    arrives along the line of sight at a range between the direct and the mirrored path,
///    so the gridmap shows a short streak pointing at the road that straddles the reflector,
///    in some passes and not others (it needs the geometry of the moment). A wall or curb
///    does not pass through another wall, and a side street's curb seen along the line of
///    sight ends where the road's curb is rather than crossing it: a short radial line that
///    crosses another line landmark well inside its own extent is such a streak
///    (RangeStreakRule).
///  - returns beyond the modelled view (e.g. images behind facades, 16–18 m off the route)
///    that a few drives saw: judged against every pass that came as close as their
///    supporters did, as points are (OutOfViewLineRule; point_filter.hpp OutOfViewRule).
///
/// Pure core: values in, values out; positions in the consensus frame (metres).
///
/// Usage:
///   LineConsensusResult lc = consensus_lines(tl, cfg.lines, &view);
///   const LineFilterResult lf = filter_line_landmarks(lc, tl, &view, cfg.lines.filter);
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "polmap/mapping_service/visibility.hpp"

namespace polmap::mapping {

struct LineConsensusResult;
struct TaggedLineCandidate;

/// Lines that the supporting drives drove through (see the file comment).
struct OverheadRule {
  bool enabled = true;
  /// Removed when the paths of at least this share of its supporting drives cross it ...
  double min_crossing_share = 0.5;
  /// ... and of at least this many drives (one drive's bad trajectory cannot remove a curb).
  int min_crossing_drives = 2;
};

/// Short lines along the line of sight from the road (see the file comment).
struct RangeStreakRule {
  bool enabled = true;
  /// Judged: lines no longer than this (a side street's wall or curb seen from the
  /// crossing is usually longer; the simulated streaks are 2–9 m) ...
  double max_length_m = 10.0;
  /// ... whose direction is within this angle of the line of sight from the nearest point of
  /// the passes' paths to the line's middle (30°; the simulated streaks: 3–36°, every true
  /// line of the urban route: 84–90°).
  double max_line_of_sight_angle_rad = 0.5236;
  /// ... and that cross another line landmark (a reflector; its segments extended by
  /// `reflector_margin_m`, as a mapped wall often goes on past its landmark's ends) at least
  /// `min_overhang_m` inside both of their own ends (an L-shaped corner meets the other line
  /// at an end) ...
  double reflector_margin_m = 1.0;
  double min_overhang_m = 0.75;
  /// ... need more than this share of the passes that had them in view. 1.0 (default): none is
  /// kept, a streak seen in every pass is still a streak (the simulated urban route with 4
  /// drives has streaks seen by all 4; line precision 0.944 at 0.9, 0.960 at 1.0, recall
  /// 0.974 and 0.973; no other world or fleet size changed but for precision gains).
  /// Lower values keep what nearly every pass saw (streaks 0.50–0.89 of 64 passes).
  double min_detection_share = 1.0;
};

/// Lines outside the view model of most of their supporters (point_filter.hpp
/// OutOfViewRule, with the distance of a path to the line's vertices and middle).
struct OutOfViewLineRule {
  bool enabled = true;
  double min_view_fraction = 0.5;
};

/// Settings of filter_line_landmarks.
struct LineFilterConfig {
  OverheadRule overhead;
  RangeStreakRule range_streaks;
  OutOfViewLineRule out_of_view;
};

/// What the filter measured for one line landmark (index = input landmark index).
struct LineEvidence {
  enum class Verdict { Kept, Overhead, RangeStreak, OutOfView };
  Verdict verdict = Verdict::Kept;
  std::uint32_t support = 0;          ///< distinct supporting drives
  std::uint32_t passes_in_view = 0;   ///< at any vertex or the middle, supporters included
  std::uint32_t crossing_drives = 0;  ///< supporting drives whose path crosses the line
  double length_m = 0.0;
  /// Angle between the line and the line of sight from the nearest path point to its middle
  /// (radians in [0, π/2]; -1: no path known).
  double line_of_sight_angle_rad = -1.0;
  /// RangeStreakRule: index of the line landmark it straddles (-1: none, or not judged).
  std::int64_t straddled_line = -1;
  /// OutOfViewLineRule: passes at least as close as the farthest supporting drive (0: not
  /// judged).
  std::uint32_t passes_as_close = 0;
};

struct LineFilterResult {
  std::vector<LineEvidence> evidence;  ///< per input landmark
  std::size_t overhead = 0;            ///< removed by OverheadRule
  std::size_t range_streaks = 0;       ///< removed by RangeStreakRule
  std::size_t out_of_view = 0;         ///< removed by OutOfViewLineRule
};

/// Removes overhead structures, range streaks and out-of-view returns from `lines`
/// (landmarks, support, verdicts; ids renumbered). `candidates`: the candidates `lines` was
/// built from (support ids refer to them). `view == nullptr`: nothing is judged (every rule
/// needs the passes' paths).
LineFilterResult filter_line_landmarks(LineConsensusResult& lines,
                                       std::span<const TaggedLineCandidate> candidates,
                                       const VisibilityIndex* view,
                                       const LineFilterConfig& cfg = {});

}  // namespace polmap::mapping
