#include "polmap/eval/map_geometry.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <utility>

namespace polmap::eval {

std::vector<Eigen::Vector2d> truth_point_objects(const sim::World& world) {
  std::vector<Eigen::Vector2d> out;
  for (const auto& o : world.objects) {
    if (!o.permanent || o.geometry_m.size() != 1) continue;
    using C = sim::ObjectClass;
    switch (o.cls) {
      case C::LampPole:
      case C::SignPole:
      case C::SignPlate:
      case C::TrafficLight:
      case C::Pole:
      case C::GuardrailPost:
      case C::GuidePost:
      case C::TreeTrunk:
      case C::FacadeRecess:
      case C::FacadeCorner:
      case C::FencePost:
        out.push_back(o.geometry_m[0]);
        break;
      default:
        break;
    }
  }
  return out;
}

namespace {

using Pairs = std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>>;  // (map, truth)

// Least-squares rigid transform truth ~ R map + t. In 2-D the optimal rotation has a closed
// form: theta = atan2(sum of cross products, sum of dot products) of the centred pairs.
std::pair<Eigen::Matrix2d, Eigen::Vector2d> rigid_fit(const Pairs& pairs) {
  Eigen::Vector2d cm = Eigen::Vector2d::Zero(), cg = Eigen::Vector2d::Zero();
  for (const auto& [m, g] : pairs) cm += m, cg += g;
  cm /= static_cast<double>(pairs.size());
  cg /= static_cast<double>(pairs.size());
  double sin_sum = 0.0, cos_sum = 0.0;
  for (const auto& [m, g] : pairs) {
    const Eigen::Vector2d a = m - cm, b = g - cg;
    cos_sum += a.dot(b);
    sin_sum += a.x() * b.y() - a.y() * b.x();
  }
  const double th = std::atan2(sin_sum, cos_sum);
  Eigen::Matrix2d R;
  R << std::cos(th), -std::sin(th), std::sin(th), std::cos(th);
  return {R, cg - R * cm};
}

double rms_after(const Pairs& pairs, const Eigen::Matrix2d& R, const Eigen::Vector2d& t) {
  double s2 = 0.0;
  for (const auto& [m, g] : pairs) s2 += (R * m + t - g).squaredNorm();
  return pairs.empty() ? 0.0 : std::sqrt(s2 / static_cast<double>(pairs.size()));
}

}  // namespace

MapGeometry map_geometry(std::span<const Eigen::Vector2d> map_m,
                         std::span<const Eigen::Vector2d> truth_m, const MapGeometryConfig& cfg) {
  MapGeometry g;
  if (map_m.empty() || truth_m.empty()) return g;
  // Coarse start: the mode of truth - map displacements (blurred 3 x 3 histogram).
  const int half = static_cast<int>(std::ceil(cfg.vote_radius_m / cfg.vote_cell_m));
  const int size = 2 * half + 1;
  std::vector<double> hist(static_cast<std::size_t>(size * size), 0.0);
  const double r2 = cfg.vote_radius_m * cfg.vote_radius_m;
  for (const auto& m : map_m) {
    for (const auto& t : truth_m) {
      const Eigen::Vector2d d = t - m;
      if (d.squaredNorm() > r2) continue;
      const int x = static_cast<int>(std::lround(d.x() / cfg.vote_cell_m)) + half;
      const int y = static_cast<int>(std::lround(d.y() / cfg.vote_cell_m)) + half;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const int xx = x + dx, yy = y + dy;
          if (xx >= 0 && yy >= 0 && xx < size && yy < size) {
            hist[static_cast<std::size_t>(yy * size + xx)] += (dx == 0 && dy == 0) ? 2.0 : 1.0;
          }
        }
      }
    }
  }
  const auto best = static_cast<int>(std::max_element(hist.begin(), hist.end()) - hist.begin());
  Eigen::Matrix2d R = Eigen::Matrix2d::Identity();
  Eigen::Vector2d t((best % size - half) * cfg.vote_cell_m, (best / size - half) * cfg.vote_cell_m);
  Pairs pairs;
  for (const double gate : cfg.gates_m) {
    pairs.clear();
    for (const auto& m : map_m) {
      const Eigen::Vector2d p = R * m + t;
      double bd = gate * gate;
      const Eigen::Vector2d* bt = nullptr;
      for (const auto& tr : truth_m) {
        const double d2 = (tr - p).squaredNorm();
        if (d2 < bd) bd = d2, bt = &tr;
      }
      if (bt != nullptr) pairs.emplace_back(m, *bt);
    }
    if (pairs.size() < 3) return g;
    std::tie(R, t) = rigid_fit(pairs);
  }
  g.status = MapGeometry::Status::Ok;
  g.matched = static_cast<int>(pairs.size());
  g.R_truth_map = R;
  g.t_truth_map_m = t;
  g.yaw_truth_map_rad = std::atan2(R(1, 0), R(0, 0));
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& [m, tr] : pairs) mean += tr - m;
  g.offset_m = (mean / static_cast<double>(pairs.size())).norm();
  g.raw_rms_m = rms_after(pairs, Eigen::Matrix2d::Identity(), Eigen::Vector2d::Zero());
  g.global_rms_m = rms_after(pairs, R, t);
  // Per window: the same pairs, each window fitted on its own.
  std::map<std::pair<long, long>, Pairs> windows;
  for (const auto& pr : pairs) {
    windows[{std::lround(std::floor(pr.first.x() / cfg.window_m)),
             std::lround(std::floor(pr.first.y() / cfg.window_m))}]
        .push_back(pr);
  }
  double s2 = 0.0;
  std::size_t n = 0;
  for (const auto& [key, wp] : windows) {
    if (static_cast<int>(wp.size()) < cfg.min_window_matches) continue;
    const auto [Rw, tw] = rigid_fit(wp);
    const double r = rms_after(wp, Rw, tw);
    s2 += r * r * static_cast<double>(wp.size());
    n += wp.size();
    ++g.windows;
  }
  g.window_rms_m = n > 0 ? std::sqrt(s2 / static_cast<double>(n)) : 0.0;
  return g;
}

}  // namespace polmap::eval
