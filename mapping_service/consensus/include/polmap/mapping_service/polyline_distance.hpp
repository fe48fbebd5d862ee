#pragma once
/// @file polyline_distance.hpp
/// Euclidean distance of a point to a segment and to a polyline (metres, any one
/// metric frame). Shared by consensus, visibility and the landmark diff.
#include <Eigen/Core>
#include <algorithm>
#include <limits>
#include <span>

namespace polmap::mapping {

/// Distance from p to the segment [a, b] (to a when the segment is degenerate).
inline double point_segment_distance(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                                     const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double l2 = ab.squaredNorm();
  if (l2 <= 0.0) return (p - a).norm();
  const double t = std::clamp((p - a).dot(ab) / l2, 0.0, 1.0);
  return (p - (a + t * ab)).norm();
}

/// Whether the segments [a, b] and [c, d] have a point in common (touching counts; collinear
/// overlapping segments count).
inline bool segments_intersect(const Eigen::Vector2d& a, const Eigen::Vector2d& b,
                               const Eigen::Vector2d& c, const Eigen::Vector2d& d) {
  auto cross = [](const Eigen::Vector2d& o, const Eigen::Vector2d& p, const Eigen::Vector2d& q) {
    return (p.x() - o.x()) * (q.y() - o.y()) - (p.y() - o.y()) * (q.x() - o.x());
  };
  const double d1 = cross(c, d, a), d2 = cross(c, d, b), d3 = cross(a, b, c), d4 = cross(a, b, d);
  if (((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0)))
    return true;
  // Touching or collinear: an end point on the other segment.
  return (d1 == 0 && point_segment_distance(a, c, d) == 0.0) ||
         (d2 == 0 && point_segment_distance(b, c, d) == 0.0) ||
         (d3 == 0 && point_segment_distance(c, a, b) == 0.0) ||
         (d4 == 0 && point_segment_distance(d, a, b) == 0.0);
}

/// Distance from p to a polyline (one vertex: to it; none: +infinity).
inline double point_polyline_distance(const Eigen::Vector2d& p,
                                      std::span<const Eigen::Vector2d> polyline) {
  if (polyline.size() == 1) return (p - polyline[0]).norm();
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i + 1 < polyline.size(); ++i) {
    best = std::min(best, point_segment_distance(p, polyline[i], polyline[i + 1]));
  }
  return best;
}

}  // namespace polmap::mapping
