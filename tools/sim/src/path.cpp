#include "polmap/sim/path.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "polmap/schema/errors.hpp"
#include "polmap/schema/pose2.hpp"

namespace polmap::sim {

Path Path::from_curvature(const Eigen::Vector2d& start, double yaw0_rad, double length_m,
                          const std::function<double(double)>& kappa_of_s, double step_m) {
  POLMAP_EXPECT(length_m > 0 && step_m > 0);
  Path p;
  p.step_ = step_m;
  const auto n = static_cast<std::size_t>(std::ceil(length_m / step_m));
  p.pts_.reserve(n + 1);
  double x = start.x(), y = start.y(), yaw = yaw0_rad;
  for (std::size_t i = 0; i <= n; ++i) {
    const double s = static_cast<double>(i) * step_m;
    const double k = kappa_of_s(s);
    p.pts_.push_back({s, x, y, wrap_angle_rad(yaw), k});
    // Midpoint integration of heading, exact chord for the position step.
    const double k_mid = kappa_of_s(s + 0.5 * step_m);
    const double yaw_mid = yaw + 0.5 * k_mid * step_m;
    x += step_m * std::cos(yaw_mid);
    y += step_m * std::sin(yaw_mid);
    yaw += k_mid * step_m;
  }
  return p;
}

Path Path::from_polyline(const std::vector<Eigen::Vector2d>& in, double step_m, double smooth_m) {
  POLMAP_EXPECT(in.size() >= 2 && step_m > 0);
  // Cumulative length of the input.
  std::vector<double> cum(in.size(), 0.0);
  for (std::size_t i = 1; i < in.size(); ++i) cum[i] = cum[i - 1] + (in[i] - in[i - 1]).norm();
  const double total = cum.back();
  POLMAP_EXPECT(total > step_m);
  const auto n = static_cast<std::size_t>(std::floor(total / step_m));
  std::vector<Eigen::Vector2d> res;
  res.reserve(n + 1);
  std::size_t seg = 0;
  for (std::size_t i = 0; i <= n; ++i) {
    const double s = static_cast<double>(i) * step_m;
    while (seg + 2 < in.size() && cum[seg + 1] < s) ++seg;
    const double len = cum[seg + 1] - cum[seg];
    const double t = len > 0 ? std::clamp((s - cum[seg]) / len, 0.0, 1.0) : 0.0;
    res.push_back(in[seg] + t * (in[seg + 1] - in[seg]));
  }
  // Smooth positions (moving average) so polyline corners become arcs; keep ends. Beyond
  // an end the curve continues as its point reflection through the end point, so the
  // full window applies up to the end, the end point stays where it is and the curve is
  // straight there (a window shrinking to nothing at the ends left the last metres'
  // corners in the path: heading kinks a vehicle cannot drive, whose heading then
  // disagreed with the yaw rate from the curvature).
  const int half = std::max(1, static_cast<int>(std::lround(0.5 * smooth_m / step_m)));
  const int last = static_cast<int>(res.size()) - 1;
  const auto extended = [&](int j) -> Eigen::Vector2d {
    if (j < 0) return 2.0 * res.front() - res[std::min(-j, last)];
    if (j > last) return 2.0 * res.back() - res[std::max(2 * last - j, 0)];
    return res[j];
  };
  std::vector<Eigen::Vector2d> sm(res.size());
  for (int i = 0; i <= last; ++i) {
    Eigen::Vector2d acc = Eigen::Vector2d::Zero();
    for (int j = i - half; j <= i + half; ++j) acc += extended(j);
    sm[i] = acc / (2 * half + 1);
  }
  // Re-parameterise the smoothed curve by arc length (the smoothing shortens corners).
  std::vector<double> c2(sm.size(), 0.0);
  for (std::size_t i = 1; i < sm.size(); ++i) c2[i] = c2[i - 1] + (sm[i] - sm[i - 1]).norm();
  std::vector<Eigen::Vector2d> pts;
  const auto m = static_cast<std::size_t>(std::floor(c2.back() / step_m));
  seg = 0;
  for (std::size_t i = 0; i <= m; ++i) {
    const double s = static_cast<double>(i) * step_m;
    while (seg + 2 < sm.size() && c2[seg + 1] < s) ++seg;
    const double len = c2[seg + 1] - c2[seg];
    const double t = len > 0 ? std::clamp((s - c2[seg]) / len, 0.0, 1.0) : 0.0;
    pts.push_back(sm[seg] + t * (sm[seg + 1] - sm[seg]));
  }
  Path p;
  p.step_ = step_m;
  p.pts_.resize(pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const std::size_t a = i == 0 ? 0 : i - 1, b = std::min(pts.size() - 1, i + 1);
    const Eigen::Vector2d d = pts[b] - pts[a];
    p.pts_[i] = {static_cast<double>(i) * step_m, pts[i].x(), pts[i].y(), std::atan2(d.y(), d.x()),
                 0.0};
  }
  // Curvature from heading differences over a window of +-1 m.
  const int kw = std::max(1, static_cast<int>(std::lround(1.0 / step_m)));
  for (std::size_t i = 0; i < p.pts_.size(); ++i) {
    const int a = std::max(0, static_cast<int>(i) - kw);
    const int b = std::min(static_cast<int>(p.pts_.size()) - 1, static_cast<int>(i) + kw);
    if (b > a) {
      p.pts_[i].kappa_1pm =
          wrap_angle_rad(p.pts_[b].yaw_rad - p.pts_[a].yaw_rad) / ((b - a) * step_m);
    }
  }
  return p;
}

PathPoint Path::at(double s) const {
  POLMAP_EXPECT(!pts_.empty());
  if (s <= 0) return pts_.front();
  const double f = s / step_;
  const auto i = static_cast<std::size_t>(f);
  if (i + 1 >= pts_.size()) return pts_.back();
  const double t = f - static_cast<double>(i);
  const PathPoint& a = pts_[i];
  const PathPoint& b = pts_[i + 1];
  return {s, a.x_m + t * (b.x_m - a.x_m), a.y_m + t * (b.y_m - a.y_m),
          wrap_angle_rad(a.yaw_rad + t * wrap_angle_rad(b.yaw_rad - a.yaw_rad)),
          a.kappa_1pm + t * (b.kappa_1pm - a.kappa_1pm)};
}

Eigen::Vector2d Path::offset_point(double s, double lateral) const {
  const PathPoint p = at(s);
  return {p.x_m - lateral * std::sin(p.yaw_rad), p.y_m + lateral * std::cos(p.yaw_rad)};
}

std::vector<Eigen::Vector2d> Path::offset_polyline(double s0, double s1, double lateral,
                                                   double max_step) const {
  std::vector<Eigen::Vector2d> out;
  if (s1 <= s0) return out;
  double s = s0;
  out.push_back(offset_point(s, lateral));
  while (s < s1) {
    const double k = std::abs(at(s).kappa_1pm);
    // Keep the chord error below ~2 cm: step <= sqrt(8 * 0.02 / kappa).
    const double step = k > 1e-6 ? std::min(max_step, std::sqrt(0.16 / k)) : max_step;
    s = std::min(s1, s + std::max(0.2, step));
    out.push_back(offset_point(s, lateral));
  }
  return out;
}

Path Path::displaced(const std::function<double(double)>& lateral_of_s) const {
  std::vector<Eigen::Vector2d> pts;
  pts.reserve(pts_.size());
  for (const auto& p : pts_) pts.push_back(offset_point(p.s_m, lateral_of_s(p.s_m)));
  return from_polyline(pts, step_, 0.5);
}

double Path::project(const Eigen::Vector2d& q) const {
  double best = std::numeric_limits<double>::max(), best_s = 0;
  for (const auto& p : pts_) {
    const double d = (Eigen::Vector2d(p.x_m, p.y_m) - q).squaredNorm();
    if (d < best) {
      best = d;
      best_s = p.s_m;
    }
  }
  return best_s;
}

}  // namespace polmap::sim
