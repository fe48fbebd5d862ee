#include "polmap/localization_client/line_geometry.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

namespace polmap::loc {
namespace {

double cross(const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
}

bool segments_intersect(const Segment2& s, const Segment2& t) {
  const double d1 = cross(t.a_m, t.b_m, s.a_m);
  const double d2 = cross(t.a_m, t.b_m, s.b_m);
  const double d3 = cross(s.a_m, s.b_m, t.a_m);
  const double d4 = cross(s.a_m, s.b_m, t.b_m);
  return ((d1 > 0) != (d2 > 0)) && ((d3 > 0) != (d4 > 0)) && d1 != 0 && d2 != 0 && d3 != 0 &&
         d4 != 0;
}

}  // namespace

double convex_hull_area(std::span<const Eigen::Vector2d> points) {
  if (points.size() < 3) return 0.0;
  std::vector<Eigen::Vector2d> p(points.begin(), points.end());
  std::sort(p.begin(), p.end(), [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  std::vector<Eigen::Vector2d> hull(2 * p.size());
  std::size_t k = 0;
  for (const auto& q : p) {  // lower hull
    while (k >= 2 && cross(hull[k - 2], hull[k - 1], q) <= 0) --k;
    hull[k++] = q;
  }
  for (std::size_t i = p.size() - 1, lower = k + 1; i-- > 0;) {  // upper hull
    while (k >= lower && cross(hull[k - 2], hull[k - 1], p[i]) <= 0) --k;
    hull[k++] = p[i];
  }
  if (k < 4) return 0.0;  // fewer than three distinct hull vertices
  double twice_area = 0.0;
  for (std::size_t i = 0; i + 1 < k; ++i) {
    twice_area += hull[i].x() * hull[i + 1].y() - hull[i + 1].x() * hull[i].y();
  }
  return 0.5 * std::abs(twice_area);
}

LineDistance line_distance(const Segment2& s, const Segment2& t) {
  // The longer segment defines the axis; ties resolved by argument order would
  // make the distance asymmetric, so compare lengths with a stable rule.
  const bool s_longer = s.length_m() >= t.length_m();
  const Segment2& ref = s_longer ? s : t;
  const Eigen::Vector2d u = ref.direction();
  const Eigen::Vector2d o = ref.a_m;
  auto proj = [&](const Eigen::Vector2d& p) { return u.dot(p - o); };
  const double s0 = proj(s.a_m), s1 = proj(s.b_m), t0 = proj(t.a_m), t1 = proj(t.b_m);
  const double s_lo = std::min(s0, s1), s_hi = std::max(s0, s1);
  const double t_lo = std::min(t0, t1), t_hi = std::max(t0, t1);
  const double merged = std::max(s_hi, t_hi) - std::min(s_lo, t_lo);
  LineDistance d;
  d.projection_m = std::max(0.0, std::max(s_lo, t_lo) - std::min(s_hi, t_hi));
  const std::array<Eigen::Vector2d, 4> pts{s.a_m, s.b_m, t.a_m, t.b_m};
  d.hull_m = merged > 1e-9 ? convex_hull_area(pts) / merged : 0.0;
  return d;
}

SegmentProjection project_onto_segment(const Eigen::Vector2d& p, const Segment2& s) {
  const Eigen::Vector2d d = s.b_m - s.a_m;
  const double len2 = d.squaredNorm();
  SegmentProjection r;
  r.t = len2 > 1e-18 ? std::clamp((p - s.a_m).dot(d) / len2, 0.0, 1.0) : 0.0;
  r.point_m = s.a_m + r.t * d;
  r.distance_m = (p - r.point_m).norm();
  return r;
}

double segment_distance(const Segment2& s, const Segment2& t) {
  if (segments_intersect(s, t)) return 0.0;
  return std::min(
      {project_onto_segment(s.a_m, t).distance_m, project_onto_segment(s.b_m, t).distance_m,
       project_onto_segment(t.a_m, s).distance_m, project_onto_segment(t.b_m, s).distance_m});
}

Segment2 merge_segments(std::span<const Segment2> segments) {
  if (segments.empty()) return {};
  if (segments.size() == 1) return segments.front();
  // Doubled-angle mean: direction is an axis, not an orientation.
  double c2 = 0.0, s2 = 0.0, wsum = 0.0;
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  for (const auto& seg : segments) {
    const double w = std::max(seg.length_m(), 1e-6);
    const Eigen::Vector2d d = seg.direction();
    const double a = std::atan2(d.y(), d.x());
    c2 += w * std::cos(2.0 * a);
    s2 += w * std::sin(2.0 * a);
    centroid += w * seg.midpoint_m();
    wsum += w;
  }
  centroid /= wsum;
  const double axis = 0.5 * std::atan2(s2, c2);
  Eigen::Vector2d u(std::cos(axis), std::sin(axis));
  if (u.dot(segments.front().direction()) < 0) u = -u;
  double lo = 0.0, hi = 0.0;
  bool first = true;
  for (const auto& seg : segments) {
    for (const Eigen::Vector2d& p : {seg.a_m, seg.b_m}) {
      const double t = u.dot(p - centroid);
      if (first) {
        lo = hi = t;
        first = false;
      }
      lo = std::min(lo, t);
      hi = std::max(hi, t);
    }
  }
  return {centroid + lo * u, centroid + hi * u};
}

}  // namespace polmap::loc
