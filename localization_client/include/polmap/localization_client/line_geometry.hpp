#pragma once
/// @file line_geometry.hpp
/// Planar segment geometry shared by local-map clustering, matching and the
/// graph's line factors: the line distance of the paper (§III-D, Werber et al.),
/// segment merging, projections.
///
/// Line distance (our reading of the paper; the line consensus uses the same measures):
/// the reference axis is the direction of the longer segment;
///  - convex-hull distance = area of the convex hull of the four end points
///    divided by the merged length (extent of all end points along the axis),
///    i.e. the mean lateral spread of the pair (0 for collinear segments);
///  - projection distance = gap between the two segments' intervals projected
///    onto the axis (0 when they overlap).
#include <Eigen/Core>
#include <span>

namespace polmap::loc {

/// A straight segment from a_m to b_m (metres, in the frame named by its owner).
struct Segment2 {
  Eigen::Vector2d a_m = Eigen::Vector2d::Zero();
  Eigen::Vector2d b_m = Eigen::Vector2d::Zero();

  [[nodiscard]] double length_m() const { return (b_m - a_m).norm(); }
  [[nodiscard]] Eigen::Vector2d midpoint_m() const { return 0.5 * (a_m + b_m); }
  /// Unit direction a -> b; (1, 0) for a degenerate segment.
  [[nodiscard]] Eigen::Vector2d direction() const {
    const Eigen::Vector2d d = b_m - a_m;
    const double n = d.norm();
    return n > 1e-12 ? Eigen::Vector2d(d / n) : Eigen::Vector2d(1.0, 0.0);
  }
};

/// Both parts of the line distance (see file comment).
struct LineDistance {
  double hull_m = 0.0;        ///< convex-hull area / merged length
  double projection_m = 0.0;  ///< gap of the projected intervals, 0 if overlapping
  [[nodiscard]] double sum_m() const { return hull_m + projection_m; }
};

/// Line distance of two segments (symmetric).
[[nodiscard]] LineDistance line_distance(const Segment2& s, const Segment2& t);

/// Area of the convex hull of up to a few dozen points (Andrew's monotone chain).
[[nodiscard]] double convex_hull_area(std::span<const Eigen::Vector2d> points);

/// Closest point of segment s to p, and its parameter t in [0, 1] (a + t (b - a)).
struct SegmentProjection {
  Eigen::Vector2d point_m = Eigen::Vector2d::Zero();
  double t = 0.0;
  double distance_m = 0.0;
};
[[nodiscard]] SegmentProjection project_onto_segment(const Eigen::Vector2d& p, const Segment2& s);

/// Euclidean distance between two segments (0 if they intersect).
[[nodiscard]] double segment_distance(const Segment2& s, const Segment2& t);

/// Merges a group of roughly collinear segments into one: the axis is the
/// length-weighted mean direction (doubled-angle average, so a -> b and b -> a
/// agree) through the length-weighted centroid of the midpoints; the merged
/// segment spans the extreme projections of all end points (the "longest
/// distance between all mutual projection points" of the paper). The result's
/// direction follows the first segment's orientation.
[[nodiscard]] Segment2 merge_segments(std::span<const Segment2> segments);

}  // namespace polmap::loc
