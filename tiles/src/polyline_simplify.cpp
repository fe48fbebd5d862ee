#include "polmap/tiles/polyline_simplify.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include "polmap/schema/errors.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::tiles {

std::vector<bool> douglas_peucker_keep(const std::vector<Eigen::Vector2d>& p, double tol_m,
                                       std::size_t window) {
  POLMAP_EXPECT(tol_m > 0.0);
  std::vector<bool> keep(p.size(), false);
  if (p.empty()) return keep;
  keep.front() = keep.back() = true;
  // Each window [a, b] is simplified on its own, its ends kept.
  const std::size_t step = window == 0 ? p.size() : window;
  std::vector<std::pair<std::size_t, std::size_t>> todo;
  for (std::size_t a = 0; a + 1 < p.size(); a += step) {
    const std::size_t b = std::min(p.size() - 1, a + step);
    keep[a] = keep[b] = true;
    todo.emplace_back(a, b);
  }
  while (!todo.empty()) {
    const auto [a, b] = todo.back();
    todo.pop_back();
    if (b <= a + 1) continue;
    const Eigen::Vector2d d = p[b] - p[a];
    const double len2 = d.squaredNorm();
    double worst = -1.0;
    std::size_t at = a;
    for (std::size_t i = a + 1; i < b; ++i) {
      // Distance to the segment, not to its line: a path that turns back (a U-turn, a
      // zig-zag) keeps the vertices beyond the chord's ends.
      const Eigen::Vector2d v = p[i] - p[a];
      const double t = len2 > 1e-18 ? std::clamp(v.dot(d) / len2, 0.0, 1.0) : 0.0;
      const double dist = (v - t * d).norm();
      if (dist > worst) {
        worst = dist;
        at = i;
      }
    }
    if (worst > tol_m) {
      keep[at] = true;
      todo.emplace_back(at, b);
      todo.emplace_back(a, at);
    }
  }
  return keep;
}

std::vector<GeoPoint> simplify_polyline(const std::vector<GeoPoint>& polyline, double tol_m,
                                        std::size_t window) {
  if (polyline.size() < 3) return polyline;
  const LocalFrame frame(polyline.front());
  std::vector<Eigen::Vector2d> xy;
  xy.reserve(polyline.size());
  for (const GeoPoint& g : polyline) xy.push_back(frame.to_local(g));
  const std::vector<bool> keep = douglas_peucker_keep(xy, tol_m, window);
  std::vector<GeoPoint> out;
  for (std::size_t i = 0; i < polyline.size(); ++i) {
    if (keep[i]) out.push_back(polyline[i]);
  }
  return out;
}

}  // namespace polmap::tiles
