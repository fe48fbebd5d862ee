#pragma once
/// @file point_filter.hpp
/// Precision of fleet point consensus: point landmarks that are not permanent point
/// objects, judged after point and line consensus (consensus.hpp).
///
/// Repeatable but wrong point landmarks survive the support rule in a realistic fleet
/// (README "Fleet map production"):
///  - line peaks: peaks of a curb or facade return that the front end finds in most
///    passes. They lie on a consensus LINE landmark and their candidates scatter
///    ALONG the line (where on the line the peak falls depends on the viewing
///    geometry) much more than across it. A pole beside a curb is off the line by its
///    radius and its candidates scatter isotropically: it stays (LinePeakRule).
///  - temporary objects (parked cars, bins): present in some drives and absent in
///    others. The scattering centres of one car are detected together in the drives
///    the car is there and missed together in the others; misses of distinct
///    permanent objects are independent. Two neighbouring landmarks whose support
///    sets are associated beyond chance (one-sided Fisher exact test on the passes
///    that had both in view) and which neither is detected by nearly all passes are
///    parts of one temporary object (CoPresenceRule). The test's power grows with
///    the number of passes, so precision holds as the fleet grows; with very few
///    passes only perfect co-presence (two or more shared misses, no discordant pass)
///    counts.
///  - mirror images: multipath off a wall, facade or guardrail shows a strong object a
///    second time behind the reflector, at the same place in every pass. A landmark
///    behind a line landmark whose mirror image across it holds candidates of enough
///    drives on the road's side is removed (MirrorGhostRule).
/// Surface peaks, objects that stand elsewhere each drive (sliding) and returns beyond
/// the modelled view have rules of their own below.
///
/// Pure core: values in, values out; positions in the consensus frame (metres).
///
/// Usage:
///   PointConsensusResult pc = consensus_points(tp, cfg.points, &view);
///   const LineConsensusResult lc = consensus_lines(tl, cfg.lines, &view);
///   const PointFilterResult f = filter_point_landmarks(pc, lc, tp, &view, cfg.points.filter);
#include <cstdint>
#include <span>
#include <vector>

#include "polmap/mapping_service/visibility.hpp"

namespace polmap::mapping {

struct PointConsensusResult;
struct LineConsensusResult;
struct TaggedPointCandidate;

/// Point landmarks on line landmarks that are line peaks (see the file comment).
struct LinePeakRule {
  /// Off by default: in the simulator (bench_map_build --world urban, 4 and 16 drives) the
  /// along/across spread does not separate curb and facade peaks from permanent objects
  /// (it removed as many true landmarks as false ones; README "Fleet map production").
  bool enabled = false;
  /// Examined: point landmarks within this distance of a line landmark (the curb's
  /// own returns; a pole beside a curb stands its radius or more off the line).
  double max_line_distance_m = 0.2;
  /// A line peak when the RMS spread of its candidates along the line is at least this
  /// many times the RMS spread across it ...
  double min_along_across_ratio = 1.5;
  /// ... and at least this (a point object's candidates scatter by the position noise,
  /// a few cm, in every direction).
  double min_along_spread_m = 0.05;
};

/// Odd-bounce peaks inside a line landmark: a wall's own specular (single-bounce) return
/// makes local maxima that pCFAR reports as points, at places that recur in some passes
/// and not others (the simulated urban route, 4 drives: 72 of 143 false point landmarks,
/// 57 of them supported by 2 of the 4 passes). An odd-bounce point on a surface cannot be
/// told from the surface by its class, so it must stand out in more of the passes that had
/// it in view than a free-standing object must. Even-bounce points on a wall (recesses,
/// dihedrals) and points near a line's vertices (facade corners, line ends) are judged
/// by the support rule alone. At 16 drives this removed 1 false and no true landmark;
/// requiring 0.75 instead would remove 3 true ones as well.
struct SurfacePeakRule {
  bool enabled = true;
  /// Examined: odd-bounce point landmarks within this distance of a line landmark (d_p)
  double max_line_distance_m = 0.3;
  /// ... and farther than this from each of that line's vertices (corners, ends).
  double min_vertex_distance_m = 1.0;
  /// They need more than this share of the passes in view (the support rule's 0.5 for
  /// other points; with 4 passes: 3 instead of 2).
  double min_detection_share = 0.6;
};

/// Neighbouring point landmarks present and absent together: one temporary object
/// (see the file comment).
struct CoPresenceRule {
  bool enabled = true;
  /// Landmarks closer than this are tested as parts of one object (a car is ~4.5 m).
  double neighbour_radius_m = 3.0;
  /// Association beyond chance: one-sided Fisher exact p-value at most this (the
  /// simulator's urban route, 16 drives: 0.05 removes 36 of 40 parked-car and bin
  /// landmarks and no permanent one; 0.01: 34).
  double max_p_value = 0.05;
  /// ... and strong: phi coefficient of the 2×2 table at least this (the centres of one
  /// car: ~0.8; permanent objects sharing an occluder now and then: weak association,
  /// which many passes would still make "significant").
  double min_phi = 0.5;
  /// With fewer passes in view of both than this, only perfect co-presence counts:
  /// both missed by at least `min_shared_misses` common passes and no pass with one and
  /// not the other (one shared miss is common among permanent neighbours detected in 90 %
  /// of the passes: the synthetic bench's 4-drive recall fell from 0.989 to 0.958).
  int min_passes_for_test = 6;
  int min_shared_misses = 2;
  /// A landmark detected by more than this share of its passes in view is kept whatever
  /// its neighbours (a permanent object seen by nearly every pass).
  double max_detection_share = 0.9;
};

/// Groups whose candidates slide along the road: objects that stand somewhere else along
/// their row in each drive (parked cars, bins) make chance groups of centres from different
/// days that happen to fall within d_p of each other, and their candidates spread along the
/// direction of travel over the whole association radius. The co-presence test cannot see
/// them (each chance group has its own support set). A permanent point object's candidates
/// scatter by the position noise, no more along the road than across it (the simulated urban
/// route, 16 drives: RMS along / across median 0.04 / 0.05 m, largest along 0.12 m; the
/// chance groups of parked cars moved by up to ±1 m: 0.13–0.16 m along, 0.03–0.10 m
/// across). Judged only with a VisibilityIndex (the road's direction is that of the
/// nearest pass) and only for groups of enough drives: the spread of 2–4 candidates is too
/// noisy to judge, and few drives rarely make chance groups of moving objects.
struct SlidingRule {
  bool enabled = true;
  /// Judged: landmarks supported by at least this many drives.
  int min_support_drives = 5;
  /// Removed when the RMS spread of the candidates along the road is at least this ...
  double min_along_spread_m = 0.125;
  /// ... and at least this many times the RMS spread across it.
  double min_along_across_ratio = 1.5;
  /// A landmark detected by more than this share of its passes in view is kept whatever its
  /// spread: no chance group of objects that move gathers nearly every pass, while a
  /// permanent object's group can pick up a neighbour's candidates at its rim (seed 2 of the
  /// urban route, 16 drives: two objects seen by 16 of 16 passes).
  double max_detection_share = 0.9;
};

/// Landmarks outside the view model of most passes. The support rule counts supporting
/// drives whose modelled view (VisibilityIndex) does not reach a place as having had it
/// in view, but nobody else: a rare return from beyond the usual range (the simulator:
/// clutter 12–16 m beside the route's start, seen by 2–5 of 256 drives) then has a
/// denominator of its own supporters. Such a landmark (fewer of its supporting drives
/// in modelled view than not) is judged again against every pass that came at least as
/// close to it as the farthest supporting drive's path did: it needs
/// max(2, ceil(min_view_fraction × those passes)) supporting drives.
struct OutOfViewRule {
  bool enabled = true;
  double min_view_fraction = 0.5;
};

/// Mirror images behind reflectors. A specular reflector (wall, facade, guardrail) shows a
/// strong object in front of it a second time at its mirror image behind it (the two-bounce
/// path: object, reflector, radar), and the image lies at the same place in every pass, so
/// the support rule keeps it like a real object. A point landmark on the far side of a line
/// landmark from the passes that had it in view, whose mirror image across that line lies
/// on the passes' side and holds candidates of enough drives, is such an image. Judged only
/// with a VisibilityIndex (the passes' side; a landmark beyond every pass's modelled view is
/// judged from its supporting drives' paths). Measured on the simulated urban route under
/// the realistic preset (multipath ghosts on; 16 drives): point precision 0.73 -> 0.91, no
/// true landmark removed (README "Fleet map production").
struct MirrorGhostRule {
  bool enabled = true;
  /// Reflectors examined: segments of line landmarks within this distance of the landmark
  /// (an image lies as far behind the reflector as its object stands in front of it).
  double max_reflector_distance_m = 20.0;
  /// The mirror point's foot must lie on the segment, or this far beyond its ends: a line
  /// landmark is the part of a wall the fleet mapped, and the wall (the reflector) often
  /// goes on past it (occluded ends). Simulated urban route, realistic preset, point
  /// precision with 16 drives (seed 1 / seed 2): 0.88 / 0.93 at 1 m, 0.91 at 5 m,
  /// 0.91 / 0.96 at 10 m, 0.92 at 20 m; recall the same at every margin.
  double segment_margin_m = 10.0;
  /// An image is at least this far from its object (a point on the line is not one).
  double min_image_offset_m = 1.0;
  /// The object at the image: candidates within this radius of it ...
  double image_radius_m = 0.3;
  /// ... of at least this many distinct drives, and at least this share of the landmark's
  /// supporting drives (an image needs its object's return).
  int min_image_drives = 2;
  double min_image_support_share = 0.25;
};

/// Settings of filter_point_landmarks.
struct PointFilterConfig {
  LinePeakRule line_peaks;
  SurfacePeakRule surface_peaks;
  CoPresenceRule co_presence;
  SlidingRule sliding;
  OutOfViewRule out_of_view;
  MirrorGhostRule mirror_ghosts;
};

/// What the filter measured for one point landmark (index = input landmark index).
struct PointEvidence {
  enum class Verdict { Kept, LinePeak, SurfacePeak, Temporary, Sliding, OutOfView, MirrorGhost };
  Verdict verdict = Verdict::Kept;
  double line_distance_m = -1.0;    ///< to the nearest line landmark (-1: none)
  double vertex_distance_m = -1.0;  ///< to that line's nearest vertex (-1: none)
  double along_spread_m = 0.0;      ///< RMS of candidates along that line
  double across_spread_m = 0.0;     ///< RMS of candidates across it
  std::uint32_t passes_in_view = 0;
  std::uint32_t support = 0;
  /// RMS of candidates along / across the road (nearest pass; both 0: no pass in view).
  double along_road_spread_m = 0.0;
  double across_road_spread_m = 0.0;
  double co_presence_p = 1.0;         ///< smallest Fisher p-value against a neighbour
  std::int64_t co_present_with = -1;  ///< that neighbour's input index
  /// OutOfViewRule: passes at least as close as the farthest supporting drive (0: not judged).
  std::uint32_t passes_as_close = 0;
  /// MirrorGhostRule: drives with candidates at the landmark's mirror image across the
  /// reflector that made it an image (0: not an image).
  std::uint32_t mirror_image_drives = 0;
};

struct PointFilterResult {
  std::vector<PointEvidence> evidence;  ///< per input landmark
  std::size_t line_peaks = 0;           ///< removed as line peaks
  std::size_t surface_peaks = 0;        ///< removed by SurfacePeakRule
  std::size_t temporary = 0;            ///< removed as temporary
  std::size_t sliding = 0;              ///< removed by SlidingRule
  std::size_t out_of_view = 0;          ///< removed by OutOfViewRule
  std::size_t mirror_ghosts = 0;        ///< removed by MirrorGhostRule
};

/// Removes line peaks, surface peaks, temporary and sliding objects, out-of-view returns and
/// mirror images from `points` (landmarks,
/// support, verdicts; ids renumbered). `candidates`: the candidates `points` was built from
/// (support ids refer to them). `view == nullptr`: passes in view = the union of all supporting
/// drives.
PointFilterResult filter_point_landmarks(PointConsensusResult& points,
                                         const LineConsensusResult& lines,
                                         std::span<const TaggedPointCandidate> candidates,
                                         const VisibilityIndex* view,
                                         const PointFilterConfig& cfg = {});

/// One-sided Fisher exact p-value of positive association in the 2×2 table
/// [[both, first only], [second only, neither]]: P(X >= both) under the hypergeometric
/// law with the table's margins.
double fisher_positive_p(int both, int first_only, int second_only, int neither);

}  // namespace polmap::mapping
