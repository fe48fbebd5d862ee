#include "polmap/eval/map_geometry.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <span>
#include <utility>
#include <vector>

#include "polmap/schema/errors.hpp"

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

using Pairs = std::vector<MapTruthPair>;

// Least-squares rigid transform truth ~ R map + t. In 2-D the optimal rotation has a closed
// form: theta = atan2(sum of cross products, sum of dot products) of the centred pairs.
std::pair<Eigen::Matrix2d, Eigen::Vector2d> rigid_fit(std::span<const MapTruthPair> pairs) {
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

// The mode of the displacements truth - (R m + t) within radius_m (blurred 3 x 3 histogram
// of cell_m cells); ties go to the smallest displacement.
Eigen::Vector2d voted_shift(std::span<const Eigen::Vector2d> map_m,
                            std::span<const Eigen::Vector2d> truth_m, const Eigen::Matrix2d& R,
                            const Eigen::Vector2d& t, double radius_m, double cell_m) {
  const int half = static_cast<int>(std::ceil(radius_m / cell_m));
  const int size = 2 * half + 1;
  std::vector<double> hist(static_cast<std::size_t>(size * size), 0.0);
  const double r2 = radius_m * radius_m;
  for (const auto& m : map_m) {
    const Eigen::Vector2d p = R * m + t;
    for (const auto& tr : truth_m) {
      const Eigen::Vector2d d = tr - p;
      if (d.squaredNorm() > r2) continue;
      const int x = static_cast<int>(std::lround(d.x() / cell_m)) + half;
      const int y = static_cast<int>(std::lround(d.y() / cell_m)) + half;
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
  std::size_t best = static_cast<std::size_t>(half * size + half);
  int best_r2 = 0;
  for (std::size_t i = 0; i < hist.size(); ++i) {
    const int x = static_cast<int>(i) % size - half, y = static_cast<int>(i) / size - half;
    if (hist[i] > hist[best] || (hist[i] == hist[best] && x * x + y * y < best_r2)) {
      best = i;
      best_r2 = x * x + y * y;
    }
  }
  return {(static_cast<int>(best) % size - half) * cell_m,
          (static_cast<int>(best) / size - half) * cell_m};
}

struct Fit {
  bool ok = false;
  Eigen::Matrix2d R = Eigen::Matrix2d::Identity();
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  Pairs pairs;  // the last round's matches
};

// Nearest-truth matching within each gate in turn, refitting after each round, from the
// start (R, t). Fails when a round keeps fewer than three pairs.
Fit match_and_fit(std::span<const Eigen::Vector2d> map_m, std::span<const Eigen::Vector2d> truth_m,
                  Eigen::Matrix2d R, Eigen::Vector2d t, std::span<const double> gates_m) {
  Fit f;
  for (const double gate : gates_m) {
    f.pairs.clear();
    for (const auto& m : map_m) {
      const Eigen::Vector2d p = R * m + t;
      double bd = gate * gate;
      const Eigen::Vector2d* bt = nullptr;
      for (const auto& tr : truth_m) {
        const double d2 = (tr - p).squaredNorm();
        if (d2 < bd) bd = d2, bt = &tr;
      }
      if (bt != nullptr) f.pairs.push_back({m, *bt});
    }
    if (f.pairs.size() < 3) return f;
    std::tie(R, t) = rigid_fit(f.pairs);
  }
  f.ok = true;
  f.R = R;
  f.t = t;
  return f;
}

}  // namespace

RigidFit2 fit_rigid(std::span<const MapTruthPair> pairs) {
  POLMAP_EXPECT(pairs.size() >= 2);
  RigidFit2 f;
  std::tie(f.R_truth_map, f.t_truth_map_m) = rigid_fit(pairs);
  f.pairs = static_cast<int>(pairs.size());
  return f;
}

std::optional<RigidFit2> local_rigid_fit(std::span<const MapTruthPair> pairs,
                                         const Eigen::Vector2d& centre_m, double window_m,
                                         int min_pairs) {
  std::vector<MapTruthPair> in;
  const double half = 0.5 * window_m;
  for (const MapTruthPair& p : pairs) {
    const Eigen::Vector2d d = p.truth_m - centre_m;
    if (std::abs(d.x()) <= half && std::abs(d.y()) <= half) in.push_back(p);
  }
  if (static_cast<int>(in.size()) < std::max(2, min_pairs)) return std::nullopt;
  return fit_rigid(in);
}

MapGeometry map_geometry(std::span<const Eigen::Vector2d> map_m,
                         std::span<const Eigen::Vector2d> truth_m, const MapGeometryConfig& cfg) {
  MapGeometry g;
  if (map_m.empty() || truth_m.empty()) return g;
  const Eigen::Matrix2d I = Eigen::Matrix2d::Identity();
  const Fit global = match_and_fit(
      map_m, truth_m, I,
      voted_shift(map_m, truth_m, I, Eigen::Vector2d::Zero(), cfg.vote_radius_m, cfg.vote_cell_m),
      cfg.gates_m);
  if (!global.ok) return g;
  const Eigen::Matrix2d R = global.R;
  const Eigen::Vector2d t = global.t;
  g.status = MapGeometry::Status::Ok;
  g.matched = static_cast<int>(global.pairs.size());
  g.R_truth_map = R;
  g.t_truth_map_m = t;
  g.yaw_truth_map_rad = std::atan2(R(1, 0), R(0, 0));
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& [m, tr] : global.pairs) mean += tr - m;
  g.offset_m = (mean / static_cast<double>(global.pairs.size())).norm();
  g.raw_rms_m = rms_after(global.pairs, I, Eigen::Vector2d::Zero());
  g.global_rms_m = rms_after(global.pairs, R, t);
  // Per window: all of the window's landmarks, matched afresh from the global fit (own vote,
  // own shrinking gates), so a section that the global fit matched badly is judged by what a
  // fit of its own can match, and its unmatched landmarks count against its share.
  std::map<std::pair<long, long>, std::vector<Eigen::Vector2d>> windows;
  for (const auto& m : map_m) {
    windows[{std::lround(std::floor(m.x() / cfg.window_m)),
             std::lround(std::floor(m.y() / cfg.window_m))}]
        .push_back(m);
  }
  double s2 = 0.0;
  std::size_t n_rms = 0, n_near = 0, n_matched = 0;
  g.worst_window_share = 1.0;
  for (const auto& [key, wm] : windows) {
    if (static_cast<int>(wm.size()) < cfg.min_window_landmarks) continue;
    MapWindowFit w;
    w.ix = key.first;
    w.iy = key.second;
    w.landmarks = static_cast<int>(wm.size());
    const Eigen::Vector2d shift =
        voted_shift(wm, truth_m, R, t, cfg.window_vote_radius_m, cfg.vote_cell_m);
    const Fit f = match_and_fit(wm, truth_m, R, t + shift, cfg.window_gates_m);
    // Near: within the widest global gate after the window's fit (its start when it failed).
    const Eigen::Matrix2d Rw = f.ok ? f.R : R;
    const Eigen::Vector2d tw = f.ok ? f.t : Eigen::Vector2d(t + shift);
    const double near2 = cfg.gates_m.front() * cfg.gates_m.front();
    for (const auto& m : wm) {
      const Eigen::Vector2d p = Rw * m + tw;
      const bool near = std::any_of(truth_m.begin(), truth_m.end(),
                                    [&](const auto& tr) { return (tr - p).squaredNorm() < near2; });
      w.near += near ? 1 : 0;
    }
    if (w.near < cfg.min_window_landmarks) {  // clutter and ghosts only, or broken
      ++g.windows_unfitted;
      continue;
    }
    if (f.ok) {
      w.matched = static_cast<int>(f.pairs.size());
      w.rms_m = rms_after(f.pairs, f.R, f.t);
      const Eigen::Matrix2d dR = f.R * R.transpose();
      w.yaw_rad = std::atan2(dR(1, 0), dR(0, 0));
      const Eigen::Vector2d centre((w.ix + 0.5) * cfg.window_m, (w.iy + 0.5) * cfg.window_m);
      w.shift_m = ((f.R * centre + f.t) - (R * centre + t)).norm();
      w.R_truth_map = f.R;
      w.t_truth_map_m = f.t;
      g.window_pairs.insert(g.window_pairs.end(), f.pairs.begin(), f.pairs.end());
      g.max_window_shift_m = std::max(g.max_window_shift_m, w.shift_m);
      s2 += w.rms_m * w.rms_m * static_cast<double>(w.matched);
      n_rms += static_cast<std::size_t>(w.matched);
    }
    n_near += static_cast<std::size_t>(w.near);
    n_matched += static_cast<std::size_t>(w.matched);
    g.worst_window_share = std::min(g.worst_window_share, w.share());
    g.window_fits.push_back(w);
  }
  g.windows = static_cast<int>(g.window_fits.size());
  if (g.windows == 0) g.worst_window_share = 0.0;
  g.window_rms_m = n_rms > 0 ? std::sqrt(s2 / static_cast<double>(n_rms)) : 0.0;
  g.window_matched_share =
      n_near > 0 ? static_cast<double>(n_matched) / static_cast<double>(n_near) : 0.0;
  return g;
}

}  // namespace polmap::eval
