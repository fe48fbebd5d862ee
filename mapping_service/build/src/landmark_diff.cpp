// Landmark changes between two map versions (see landmark_diff.hpp).
#include "polmap/mapping_service/landmark_diff.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <tuple>

#include "polmap/mapping_service/polyline_distance.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping {
namespace {

std::vector<Eigen::Vector2d> samples(const std::vector<Eigen::Vector2d>& pl, double step) {
  std::vector<Eigen::Vector2d> out;
  for (std::size_t i = 0; i + 1 < pl.size(); ++i) {
    const int n = std::max(1, static_cast<int>(std::ceil((pl[i + 1] - pl[i]).norm() / step)));
    for (int k = 0; k < n; ++k) {
      out.push_back(pl[i] + (pl[i + 1] - pl[i]) * (static_cast<double>(k) / n));
    }
  }
  if (!pl.empty()) out.push_back(pl.back());
  return out;
}

/// Symmetric mean distance of the samples of each polyline to the other.
double line_distance(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
                     double step) {
  double sum = 0.0;
  std::size_t n = 0;
  for (const auto& p : samples(a, step)) sum += point_polyline_distance(p, b), ++n;
  for (const auto& p : samples(b, step)) sum += point_polyline_distance(p, a), ++n;
  return n ? sum / static_cast<double>(n) : 0.0;
}

struct Item {
  std::int64_t key = 0;
  std::vector<GeoPoint> geo;
  std::vector<Eigen::Vector2d> m;
  Eigen::Vector2d lo, hi;  ///< bounding box, metres
};

std::vector<Item> items(const LandmarkSet& s, bool lines, const tiles::LocalFrame& f) {
  std::vector<Item> out;
  auto add = [&](std::int64_t key, std::vector<GeoPoint> geo) {
    Item it;
    it.key = key;
    for (const auto& g : geo) it.m.push_back(f.to_local(g));
    it.lo = it.hi = it.m.front();
    for (const auto& p : it.m) it.lo = it.lo.cwiseMin(p), it.hi = it.hi.cwiseMax(p);
    it.geo = std::move(geo);
    out.push_back(std::move(it));
  };
  if (lines) {
    for (const auto& l : s.lines) {
      if (!l.polyline.empty()) add(l.key, l.polyline);
    }
  } else {
    for (const auto& p : s.points) add(p.key, {p.position});
  }
  return out;
}

/// One kind (points or lines): key matches, then nearest pairs within the radius.
void diff_kind(const std::vector<Item>& from, const std::vector<Item>& to, bool is_line,
               const LandmarkDiffConfig& cfg, LandmarkDiff& out) {
  std::multiset<std::int64_t> from_keys;
  for (const auto& f : from) from_keys.insert(f.key);
  std::vector<const Item*> old_left, new_left;
  {
    std::multiset<std::int64_t> to_keys;
    for (const auto& t : to) to_keys.insert(t.key);
    for (const auto& t : to) {
      if (auto it = from_keys.find(t.key); it != from_keys.end()) {
        from_keys.erase(it);
        ++out.unchanged;
      } else {
        new_left.push_back(&t);
      }
    }
    for (const auto& f : from) {
      if (auto it = to_keys.find(f.key); it != to_keys.end()) {
        to_keys.erase(it);
      } else {
        old_left.push_back(&f);
      }
    }
  }
  // Candidate pairs through a grid of match_radius_m cells over the old items' boxes.
  const double cell = std::max(cfg.match_radius_m, 1e-3);
  std::map<std::pair<std::int64_t, std::int64_t>, std::vector<std::size_t>> grid;
  auto cell_of = [&](double v) { return static_cast<std::int64_t>(std::floor(v / cell)); };
  for (std::size_t i = 0; i < old_left.size(); ++i) {
    for (auto cx = cell_of(old_left[i]->lo.x()); cx <= cell_of(old_left[i]->hi.x()); ++cx) {
      for (auto cy = cell_of(old_left[i]->lo.y()); cy <= cell_of(old_left[i]->hi.y()); ++cy) {
        grid[{cx, cy}].push_back(i);
      }
    }
  }
  struct Pair {
    double d;
    std::size_t o, n;
  };
  std::vector<Pair> pairs;
  for (std::size_t n = 0; n < new_left.size(); ++n) {
    std::set<std::size_t> near;
    const Item& t = *new_left[n];
    for (auto cx = cell_of(t.lo.x()) - 1; cx <= cell_of(t.hi.x()) + 1; ++cx) {
      for (auto cy = cell_of(t.lo.y()) - 1; cy <= cell_of(t.hi.y()) + 1; ++cy) {
        if (auto it = grid.find({cx, cy}); it != grid.end())
          near.insert(it->second.begin(), it->second.end());
      }
    }
    for (std::size_t o : near) {
      const double d = is_line ? line_distance(old_left[o]->m, t.m, cfg.line_sample_m)
                               : (old_left[o]->m[0] - t.m[0]).norm();
      if (d <= cfg.match_radius_m) pairs.push_back({d, o, n});
    }
  }
  std::sort(pairs.begin(), pairs.end(), [&](const Pair& a, const Pair& b) {
    return std::tie(a.d, old_left[a.o]->key, new_left[a.n]->key) <
           std::tie(b.d, old_left[b.o]->key, new_left[b.n]->key);
  });
  std::vector<char> old_used(old_left.size(), 0), new_used(new_left.size(), 0);
  std::vector<LandmarkChange> changes;
  for (const Pair& p : pairs) {
    if (old_used[p.o] || new_used[p.n]) continue;
    old_used[p.o] = new_used[p.n] = 1;
    if (p.d < cfg.moved_min_m) {
      ++out.refined;
      continue;
    }
    LandmarkChange c;
    c.change = LandmarkChangeKind::Moved;
    c.is_line = is_line;
    c.key = new_left[p.n]->key;
    c.previous_key = old_left[p.o]->key;
    c.geometry = new_left[p.n]->geo;
    c.previous_geometry = old_left[p.o]->geo;
    c.distance_m = p.d;
    changes.push_back(std::move(c));
  }
  for (std::size_t n = 0; n < new_left.size(); ++n) {
    if (new_used[n]) continue;
    LandmarkChange c;
    c.change = LandmarkChangeKind::Added;
    c.is_line = is_line;
    c.key = new_left[n]->key;
    c.geometry = new_left[n]->geo;
    changes.push_back(std::move(c));
  }
  for (std::size_t o = 0; o < old_left.size(); ++o) {
    if (old_used[o]) continue;
    LandmarkChange c;
    c.change = LandmarkChangeKind::Retired;
    c.is_line = is_line;
    c.key = old_left[o]->key;
    c.geometry = old_left[o]->geo;
    changes.push_back(std::move(c));
  }
  std::sort(changes.begin(), changes.end(), [](const LandmarkChange& a, const LandmarkChange& b) {
    return std::tie(a.key, a.change) < std::tie(b.key, b.change);
  });
  out.changes.insert(out.changes.end(), std::make_move_iterator(changes.begin()),
                     std::make_move_iterator(changes.end()));
}

}  // namespace

LandmarkDiff diff_landmarks(const LandmarkSet& from, const LandmarkSet& to,
                            const LandmarkDiffConfig& cfg) {
  POLMAP_EXPECT(cfg.match_radius_m > 0.0 && cfg.moved_min_m >= 0.0 && cfg.line_sample_m > 0.0);
  GeoPoint origin{};
  bool found = false;
  for (const LandmarkSet* s : {&from, &to}) {
    if (found) break;
    if (!s->points.empty())
      origin = s->points.front().position, found = true;
    else if (!s->lines.empty() && !s->lines.front().polyline.empty())
      origin = s->lines.front().polyline.front(), found = true;
  }
  const tiles::LocalFrame frame(origin);
  LandmarkDiff out;
  diff_kind(items(from, false, frame), items(to, false, frame), false, cfg, out);
  diff_kind(items(from, true, frame), items(to, true, frame), true, cfg, out);
  return out;
}

}  // namespace polmap::mapping
