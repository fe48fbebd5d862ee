// Landmark consensus (paper §III-D). The only translation unit of polmap that
// includes CGAL (it is slow to compile): robust line intersections for end snapping.
#include "polmap/mapping_service/consensus.hpp"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/intersections.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <nanoflann.hpp>
#include <numeric>
#include <set>
#include <unordered_map>

#include "polmap/mapping_service/polyline_distance.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using CPoint = K::Point_2;

/// Union-find with path halving and union by size.
class UnionFind {
 public:
  explicit UnionFind(std::size_t n) : parent_(n), size_(n, 1) {
    std::iota(parent_.begin(), parent_.end(), std::size_t{0});
  }
  std::size_t find(std::size_t i) {
    while (parent_[i] != i) {
      parent_[i] = parent_[parent_[i]];
      i = parent_[i];
    }
    return i;
  }
  void unite(std::size_t a, std::size_t b) {
    a = find(a);
    b = find(b);
    if (a == b) return;
    if (size_[a] < size_[b]) std::swap(a, b);
    parent_[b] = a;
    size_[a] += size_[b];
  }

 private:
  std::vector<std::size_t> parent_;
  std::vector<std::size_t> size_;
};

/// Groups of indices (each ascending), ordered by their smallest member:
/// deterministic for a given (sorted) input.
std::vector<std::vector<std::size_t>> components(UnionFind& uf, std::size_t n) {
  std::vector<std::vector<std::size_t>> groups;
  std::vector<std::size_t> group_of_root(n, std::numeric_limits<std::size_t>::max());
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t r = uf.find(i);
    if (group_of_root[r] == std::numeric_limits<std::size_t>::max()) {
      group_of_root[r] = groups.size();
      groups.emplace_back();
    }
    groups[group_of_root[r]].push_back(i);
  }
  return groups;
}

template <typename T>
std::vector<T> sorted_by_id(std::span<const T> in) {
  std::vector<T> v(in.begin(), in.end());
  std::stable_sort(v.begin(), v.end(),
                   [](const T& a, const T& b) { return a.candidate_id < b.candidate_id; });
  return v;
}

// ---------------------------------------------------------------- points

struct PointCloud {
  const std::vector<TaggedPointCandidate>* pts;
  [[nodiscard]] std::size_t kdtree_get_point_count() const { return pts->size(); }
  [[nodiscard]] double kdtree_get_pt(std::size_t i, std::size_t dim) const {
    return (*pts)[i].candidate.position_m[static_cast<int>(dim)];
  }
  template <class BBox>
  bool kdtree_get_bbox(BBox& /*bb*/) const {
    return false;
  }
};

ScatteringClass majority_class(const std::vector<TaggedPointCandidate>& pts,
                               const std::vector<std::size_t>& members) {
  std::array<int, 4> votes{};
  for (std::size_t i : members) ++votes[static_cast<std::size_t>(pts[i].candidate.scattering) & 3U];
  int best = 0;
  for (std::size_t c = 1; c < 4; ++c) best = std::max(best, votes[c]);
  if (best == 0) return ScatteringClass::Unknown;
  int winners = 0;
  std::size_t winner = 0;
  for (std::size_t c = 1; c < 4; ++c) {
    if (votes[c] == best) {
      ++winners;
      winner = c;
    }
  }
  return winners == 1 ? static_cast<ScatteringClass>(winner) : ScatteringClass::Mixed;
}

/// Distinct drives of a group, ascending.
template <typename T>
std::vector<std::int64_t> group_drives(const std::vector<T>& items,
                                       const std::vector<std::size_t>& group) {
  std::vector<std::int64_t> drives;
  drives.reserve(group.size());
  for (std::size_t i : group) drives.push_back(items[i].drive);
  std::sort(drives.begin(), drives.end());
  drives.erase(std::unique(drives.begin(), drives.end()), drives.end());
  return drives;
}

/// A group to judge: members and where the landmark would be.
struct PointGroup {
  std::vector<std::size_t> members;
  Eigen::Vector2d position_m = Eigen::Vector2d::Zero();
};

/// Mean of the members within `radius` of `at`, iterated from `at` (flat-kernel mean
/// shift); `at` if none is that close.
Eigen::Vector2d mean_shift(const std::vector<TaggedPointCandidate>& pts,
                           const std::vector<std::size_t>& members, Eigen::Vector2d at,
                           double radius) {
  const double r2 = radius * radius;
  for (int it = 0; it < 20; ++it) {
    Eigen::Vector2d sum = Eigen::Vector2d::Zero();
    int n = 0;
    for (std::size_t i : members) {
      if ((pts[i].candidate.position_m - at).squaredNorm() <= r2) {
        sum += pts[i].candidate.position_m;
        ++n;
      }
    }
    if (n == 0) return at;
    const Eigen::Vector2d next = sum / n;
    const double moved = (next - at).norm();
    at = next;
    if (moved < 1e-4) break;
  }
  return at;
}

/// A connected component of many drives may chain neighbouring objects (two poles
/// 0.5 m apart whose candidates' noise tails touch) and collect clutter at its rim. Its
/// modes are found with a flat-kernel mean shift of radius d_p / 2 started from the
/// densest cells of a 5 cm histogram; members go to the nearest mode within d_p (others
/// support nothing); each mode is positioned at the mean of its members within d_p / 2
/// of it. Small groups stay whole with the plain mean (the paper's rule for two or three
/// drives is kept exactly).
std::vector<PointGroup> split_modes(const std::vector<TaggedPointCandidate>& pts,
                                    const std::vector<std::size_t>& g, std::size_t drives,
                                    const PointConsensusConfig& cfg) {
  PointGroup whole;
  whole.members = g;
  for (std::size_t i : g) whole.position_m += pts[i].candidate.position_m;
  whole.position_m /= static_cast<double>(g.size());
  if (static_cast<int>(drives) < cfg.split_min_drives || g.size() > cfg.split_max_members) {
    return {whole};
  }
  const double h = 0.5 * cfg.max_pair_distance_m;
  const double cell = h / 3.0;
  // The histogram is anchored at the group's first candidate (lowest id), not at the
  // frame origin: the modes found must not depend on where the region's frame is
  // centred (which moves with every candidate of the region, lines included).
  const Eigen::Vector2d origin = pts[*std::min_element(g.begin(), g.end())].candidate.position_m;
  std::map<std::pair<std::int64_t, std::int64_t>, int> hist;
  for (std::size_t i : g) {
    const Eigen::Vector2d p = pts[i].candidate.position_m - origin;
    ++hist[{static_cast<std::int64_t>(std::floor(p.x() / cell)),
            static_cast<std::int64_t>(std::floor(p.y() / cell))}];
  }
  // Density of a cell: members within 3 cells (= h) in the box around it.
  std::vector<std::pair<int, std::pair<std::int64_t, std::int64_t>>> dens;
  for (const auto& [c, n] : hist) {
    int d = 0;
    for (std::int64_t dx = -3; dx <= 3; ++dx) {
      for (std::int64_t dy = -3; dy <= 3; ++dy) {
        if (auto it = hist.find({c.first + dx, c.second + dy}); it != hist.end()) d += it->second;
      }
    }
    dens.push_back({d, c});
  }
  std::sort(dens.begin(), dens.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  std::vector<Eigen::Vector2d> modes;
  const int min_density = std::max(2, cfg.support.min_drives);
  for (const auto& [d, c] : dens) {
    if (d < min_density) break;
    const Eigen::Vector2d start =
        origin + Eigen::Vector2d((c.first + 0.5) * cell, (c.second + 0.5) * cell);
    // A cell already within a found mode's kernel leads to that mode.
    bool covered = false;
    for (const auto& m : modes) covered = covered || (m - start).norm() < h;
    if (covered) continue;
    const Eigen::Vector2d m = mean_shift(pts, g, start, h);
    // Modes closer than d_p are one object seen from different sides (a facade corner's
    // two faces: modes 0.23-0.28 m apart at 16 drives of the simulated urban route, both
    // kept before as two landmarks); farther modes are separate objects.
    bool dup = false;
    for (const auto& o : modes) dup = dup || (o - m).norm() < cfg.max_pair_distance_m;
    if (!dup) modes.push_back(m);
  }
  if (modes.size() <= 1) {
    if (!modes.empty()) whole.position_m = modes[0];
    return {whole};
  }
  std::vector<PointGroup> out(modes.size());
  const double r2 = cfg.max_pair_distance_m * cfg.max_pair_distance_m;
  for (std::size_t i : g) {
    const auto& p = pts[i].candidate.position_m;
    std::size_t best = modes.size();
    double best_d2 = r2;
    for (std::size_t k = 0; k < modes.size(); ++k) {
      const double d2 = (modes[k] - p).squaredNorm();
      if (d2 < best_d2) best_d2 = d2, best = k;
    }
    if (best < modes.size()) out[best].members.push_back(i);
  }
  for (std::size_t k = 0; k < modes.size(); ++k) {
    out[k].position_m = mean_shift(pts, out[k].members, modes[k], h);
  }
  std::erase_if(out, [](const PointGroup& pg) { return pg.members.empty(); });
  return out;
}

PointConsensusResult finish_points(const std::vector<TaggedPointCandidate>& pts,
                                   const std::vector<std::pair<std::size_t, std::size_t>>& edges,
                                   const PointConsensusConfig& cfg, const VisibilityIndex* view) {
  PointConsensusResult out;
  out.stats.candidates = pts.size();
  out.stats.pairs = edges.size();
  UnionFind uf(pts.size());
  for (const auto& [a, b] : edges) uf.unite(a, b);
  const auto groups = components(uf, pts.size());
  out.stats.groups = groups.size();
  for (const auto& component : groups) {
    const std::vector<std::int64_t> component_drives = group_drives(pts, component);
    if (static_cast<int>(component_drives.size()) < cfg.support.min_drives) {
      ++out.stats.rejected_groups;
      continue;
    }
    const std::vector<PointGroup> parts = split_modes(pts, component, component_drives.size(), cfg);
    out.stats.split_groups += parts.size() > 1 ? 1 : 0;
    for (const PointGroup& part : parts) {
      const auto& g = part.members;
      const std::vector<std::int64_t> drives = group_drives(pts, g);
      const Eigen::Vector2d& at = part.position_m;
      const SupportVerdict verdict = judge_support(view, std::span(&at, 1), drives, cfg.support);
      if (static_cast<int>(drives.size()) < cfg.support.min_drives ||
          verdict.status == SupportVerdict::Status::Rejected) {
        ++out.stats.rejected_groups;
        continue;
      }
      double ss = 0.0;
      for (std::size_t i : g) ss += (pts[i].candidate.position_m - at).squaredNorm();
      PointLandmark lm;
      lm.id = static_cast<std::int64_t>(out.landmarks.size());
      lm.position_m = at;
      lm.scattering = majority_class(pts, g);
      lm.support_drives = static_cast<std::uint32_t>(drives.size());
      lm.spread_m = std::sqrt(ss / static_cast<double>(g.size()));
      if (verdict.status == SupportVerdict::Status::Retired) {
        ++out.stats.retired_groups;
        lm.id = static_cast<std::int64_t>(out.retired.size());
        out.retired.push_back(lm);
        out.retired_verdicts.push_back(verdict);
        continue;
      }
      out.landmarks.push_back(lm);
      std::vector<std::int64_t> support;
      support.reserve(g.size());
      for (std::size_t i : g) support.push_back(pts[i].candidate_id);
      std::sort(support.begin(), support.end());
      out.support.push_back(std::move(support));
      out.verdicts.push_back(verdict);
      out.stats.largest_group = std::max(out.stats.largest_group, g.size());
    }
  }
  return out;
}

// ---------------------------------------------------------------- lines

struct Seg {
  Eigen::Vector2d a, b;
  std::int64_t drive = 0;
  [[nodiscard]] Eigen::Vector2d dir() const { return b - a; }
  [[nodiscard]] double length() const { return (b - a).norm(); }
};

/// Ramer–Douglas–Peucker: keeps the dense line's end points and inserts the
/// farthest vertex until every dense vertex is within eps of the result.
void rdp(const std::vector<Eigen::Vector2d>& pts, std::size_t lo, std::size_t hi, double eps,
         std::vector<char>& keep) {
  if (hi <= lo + 1) return;
  double worst = -1.0;
  std::size_t worst_i = lo;
  for (std::size_t i = lo + 1; i < hi; ++i) {
    const double d = point_segment_distance(pts[i], pts[lo], pts[hi]);
    if (d > worst) {
      worst = d;
      worst_i = i;
    }
  }
  if (worst > eps) {
    keep[worst_i] = 1;
    rdp(pts, lo, worst_i, eps, keep);
    rdp(pts, worst_i, hi, eps, keep);
  }
}

/// Samples along member segments (always both end points), spacing <= s.
std::vector<Eigen::Vector2d> sample_members(const std::vector<Seg>& segs, double s) {
  std::vector<Eigen::Vector2d> out;
  for (const Seg& g : segs) {
    const int n = std::max(1, static_cast<int>(std::ceil(g.length() / s)));
    for (int k = 0; k <= n; ++k) out.push_back(g.a + (g.b - g.a) * (static_cast<double>(k) / n));
  }
  return out;
}

struct MergedLine {
  std::vector<Eigen::Vector2d> polyline;
  double spread_m = 0.0;
};

/// The part of direction `dir` (through `o`) that at least
/// max(1, ceil(cfg.extent_min_drive_share × drives)) distinct drives' segments cover,
/// projected: [lo, hi] between the outermost such places (inner gaps kept). The extreme
/// member ends are the tails of the end-position noise and move outward as drives
/// accumulate; the covered part does not. Empty (lo > hi) if no place is covered
/// that often.
std::pair<double, double> covered_extent(const std::vector<Seg>& segs, const Eigen::Vector2d& o,
                                         const Eigen::Vector2d& dir,
                                         const LineConsensusConfig& cfg) {
  std::map<std::int64_t, std::vector<std::pair<double, double>>> by_drive;
  double tmin = std::numeric_limits<double>::infinity(), tmax = -tmin;
  for (const Seg& g : segs) {
    const double ta = (g.a - o).dot(dir), tb = (g.b - o).dot(dir);
    by_drive[g.drive].emplace_back(std::min(ta, tb), std::max(ta, tb));
    tmin = std::min(tmin, std::min(ta, tb));
    tmax = std::max(tmax, std::max(ta, tb));
  }
  const int need = std::max(
      1, static_cast<int>(
             std::ceil(cfg.extent_min_drive_share * static_cast<double>(by_drive.size()) - 1e-9)));
  // Events of each drive's union of intervals; sweep for the count of drives covering.
  std::vector<std::pair<double, int>> ev;
  for (auto& [drive, iv] : by_drive) {
    std::sort(iv.begin(), iv.end());
    double lo = iv.front().first, hi = iv.front().second;
    for (std::size_t k = 1; k <= iv.size(); ++k) {
      if (k < iv.size() && iv[k].first <= hi) {
        hi = std::max(hi, iv[k].second);
        continue;
      }
      ev.emplace_back(lo, +1);
      ev.emplace_back(hi, -1);
      if (k < iv.size()) lo = iv[k].first, hi = iv[k].second;
    }
  }
  // Openings before closings at the same place: touching pieces count as covering it.
  std::sort(ev.begin(), ev.end(), [](const auto& x, const auto& y) {
    return x.first != y.first ? x.first < y.first : x.second > y.second;
  });
  double lo = tmax, hi = tmin;
  int count = 0;
  for (const auto& [t, delta] : ev) {
    const int before = count;
    count += delta;
    if (count >= need && before < need) lo = std::min(lo, t);
    if (before >= need && count < need) hi = std::max(hi, t);
  }
  return {lo, hi};
}

MergedLine merge_group(const std::vector<Seg>& segs, const LineConsensusConfig& cfg) {
  // Principal direction: eigenvector of the length-weighted direction scatter
  // (axial: a segment and its reverse count the same).
  double sxx = 0, sxy = 0, syy = 0, wsum = 0;
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  for (const Seg& g : segs) {
    const double l = g.length();
    if (l <= 0.0) continue;
    const Eigen::Vector2d u = g.dir() / l;
    sxx += l * u.x() * u.x();
    sxy += l * u.x() * u.y();
    syy += l * u.y() * u.y();
    centroid += l * 0.5 * (g.a + g.b);
    wsum += l;
  }
  if (wsum <= 0.0) {  // all degenerate: a point-like "line"
    for (const Seg& g : segs) centroid += g.a;
    centroid /= static_cast<double>(segs.size());
    return {{centroid, centroid}, 0.0};
  }
  centroid /= wsum;
  const double theta = 0.5 * std::atan2(2.0 * sxy, sxx - syy);
  const Eigen::Vector2d d(std::cos(theta), std::sin(theta));
  double tmin = std::numeric_limits<double>::infinity(), tmax = -tmin;
  for (const Seg& g : segs) {
    for (const auto& p : {g.a, g.b}) {
      const double t = (p - centroid).dot(d);
      tmin = std::min(tmin, t);
      tmax = std::max(tmax, t);
    }
  }
  if (const auto [lo, hi] = covered_extent(segs, centroid, d, cfg); lo < hi) tmin = lo, tmax = hi;
  // Member samples within the covered extent (the rest are the ends' noise tails).
  std::vector<Eigen::Vector2d> samples;
  for (const auto& p : sample_members(segs, cfg.curve_sample_spacing_m)) {
    const double t = (p - centroid).dot(d);
    if (t >= tmin - 1e-9 && t <= tmax + 1e-9) samples.push_back(p);
  }
  MergedLine out;
  out.polyline = {centroid + tmin * d, centroid + tmax * d};
  double worst = 0.0;
  for (const auto& p : samples) worst = std::max(worst, point_polyline_distance(p, out.polyline));

  if (worst > cfg.polyline_max_error_m) {
    // Curve: centre line from bins along the chord between the two mutually
    // farthest samples, then RDP with the error bound. Works for curves that
    // turn by less than ~150° (the chord parameter must stay monotonic). The
    // extent is the covered one along the chord, from all member samples again.
    samples = sample_members(segs, cfg.curve_sample_spacing_m);
    std::size_t ia = 0;
    double far = -1.0;
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const double r = (samples[i] - centroid).squaredNorm();
      if (r > far) far = r, ia = i;
    }
    std::size_t ib = ia;
    far = -1.0;
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const double r = (samples[i] - samples[ia]).squaredNorm();
      if (r > far) far = r, ib = i;
    }
    const Eigen::Vector2d chord_o = samples[ia];
    const Eigen::Vector2d chord_d = (samples[ib] - samples[ia]).normalized();
    if (const auto [lo, hi] = covered_extent(segs, chord_o, chord_d, cfg); lo < hi) {
      std::erase_if(samples, [&](const Eigen::Vector2d& p) {
        const double t = (p - chord_o).dot(chord_d);
        return t < lo - 1e-9 || t > hi + 1e-9;
      });
      // Extreme retained samples along the chord.
      for (std::size_t i = 0; i < samples.size(); ++i) {
        const double t = (samples[i] - chord_o).dot(chord_d);
        if (t < (samples[ia] - chord_o).dot(chord_d) || i == 0) ia = i;
        if (t > (samples[ib] - chord_o).dot(chord_d) || i == 0) ib = i;
      }
    }
    const double t0 = (samples[ia] - chord_o).dot(chord_d);
    const double chord_len = (samples[ib] - chord_o).dot(chord_d) - t0;
    const double bin = cfg.curve_sample_spacing_m;
    const int nbins = std::max(1, static_cast<int>(std::ceil(chord_len / bin)) + 1);
    std::vector<Eigen::Vector2d> sum(static_cast<std::size_t>(nbins), Eigen::Vector2d::Zero());
    std::vector<int> cnt(static_cast<std::size_t>(nbins), 0);
    for (const auto& p : samples) {
      const double t = (p - chord_o).dot(chord_d) - t0;
      const int k = std::clamp(static_cast<int>(std::floor(t / bin + 0.5)), 0, nbins - 1);
      sum[static_cast<std::size_t>(k)] += p;
      ++cnt[static_cast<std::size_t>(k)];
    }
    std::vector<Eigen::Vector2d> dense;
    for (int k = 0; k < nbins; ++k) {
      if (cnt[static_cast<std::size_t>(k)] > 0) {
        dense.push_back(sum[static_cast<std::size_t>(k)] / cnt[static_cast<std::size_t>(k)]);
      }
    }
    if (dense.size() >= 2) {
      // Bin means sit up to half a bin inside the group's ends: extend the end
      // vertices along their end tangents to the extreme samples' projections.
      auto extend = [&](const Eigen::Vector2d& inner, Eigen::Vector2d& end,
                        const Eigen::Vector2d& extreme) {
        const Eigen::Vector2d tdir = (end - inner).normalized();
        const double s = (extreme - end).dot(tdir);
        if (s > 0.0) end += s * tdir;
      };
      extend(dense[1], dense.front(), samples[ia]);
      extend(dense[dense.size() - 2], dense.back(), samples[ib]);
      std::vector<char> keep(dense.size(), 0);
      keep.front() = keep.back() = 1;
      rdp(dense, 0, dense.size() - 1, cfg.polyline_max_error_m, keep);
      out.polyline.clear();
      for (std::size_t i = 0; i < dense.size(); ++i) {
        if (keep[i]) out.polyline.push_back(dense[i]);
      }
    }
  }
  double ss = 0.0;
  for (const auto& p : samples) {
    const double r = point_polyline_distance(p, out.polyline);
    ss += r * r;
  }
  out.spread_m = samples.empty() ? 0.0 : std::sqrt(ss / static_cast<double>(samples.size()));
  return out;
}

/// Snaps crossing / nearly crossing end edges of different lines to their
/// intersection (each end at most once, smallest total move first).
std::size_t snap_ends(std::vector<LineLandmark>& lines, const LineConsensusConfig& cfg) {
  struct End {
    std::size_t line;
    bool back;
  };
  std::vector<End> ends;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    if (lines[i].polyline_m.size() < 2) continue;
    ends.push_back({i, false});
    ends.push_back({i, true});
  }
  auto vertex = [&](const End& e) -> Eigen::Vector2d& {
    auto& pl = lines[e.line].polyline_m;
    return e.back ? pl.back() : pl.front();
  };
  auto inner = [&](const End& e) -> const Eigen::Vector2d& {
    const auto& pl = lines[e.line].polyline_m;
    return e.back ? pl[pl.size() - 2] : pl[1];
  };
  // Both ends move at most snap_max_gap_m, so they are within twice that.
  const double cell = std::max(2.0 * cfg.snap_max_gap_m, 1e-3);
  std::unordered_map<std::uint64_t, std::vector<std::size_t>> grid;
  auto key = [](std::int64_t cx, std::int64_t cy) {
    return (static_cast<std::uint64_t>(cx) << 32) ^ static_cast<std::uint64_t>(cy & 0xffffffff);
  };
  for (std::size_t k = 0; k < ends.size(); ++k) {
    const Eigen::Vector2d& v = vertex(ends[k]);
    grid[key(static_cast<std::int64_t>(std::floor(v.x() / cell)),
             static_cast<std::int64_t>(std::floor(v.y() / cell)))]
        .push_back(k);
  }
  struct Snap {
    double cost;
    std::size_t a, b;
    Eigen::Vector2d p;
  };
  std::vector<Snap> snaps;
  for (std::size_t k = 0; k < ends.size(); ++k) {
    const Eigen::Vector2d va = vertex(ends[k]);
    const auto cx = static_cast<std::int64_t>(std::floor(va.x() / cell));
    const auto cy = static_cast<std::int64_t>(std::floor(va.y() / cell));
    for (std::int64_t dx = -1; dx <= 1; ++dx) {
      for (std::int64_t dy = -1; dy <= 1; ++dy) {
        auto it = grid.find(key(cx + dx, cy + dy));
        if (it == grid.end()) continue;
        for (std::size_t m : it->second) {
          if (m <= k || ends[m].line == ends[k].line) continue;
          const Eigen::Vector2d ia = inner(ends[k]), ib = inner(ends[m]);
          const Eigen::Vector2d vb = vertex(ends[m]);
          const Eigen::Vector2d da = (va - ia), db = (vb - ib);
          const double la = da.norm(), lb = db.norm();
          if (la <= 0.0 || lb <= 0.0) continue;
          const double sin_angle = std::abs(da.x() * db.y() - da.y() * db.x()) / (la * lb);
          if (sin_angle < std::sin(cfg.snap_min_angle_rad)) continue;
          const auto res =
              CGAL::intersection(K::Line_2(CPoint(ia.x(), ia.y()), CPoint(va.x(), va.y())),
                                 K::Line_2(CPoint(ib.x(), ib.y()), CPoint(vb.x(), vb.y())));
          if (!res) continue;
          const CPoint* ip = boost::get<CPoint>(&*res);
          if (ip == nullptr) continue;
          const Eigen::Vector2d p(CGAL::to_double(ip->x()), CGAL::to_double(ip->y()));
          const double ma = (p - va).norm(), mb = (p - vb).norm();
          if (ma > cfg.snap_max_gap_m || mb > cfg.snap_max_gap_m) continue;
          // The end may move along its edge, never past (or close to) its inner vertex.
          if ((p - ia).dot(da) / (la * la) < 0.1 || (p - ib).dot(db) / (lb * lb) < 0.1) continue;
          snaps.push_back({ma + mb, k, m, p});
        }
      }
    }
  }
  std::sort(snaps.begin(), snaps.end(), [](const Snap& x, const Snap& y) {
    return std::tie(x.cost, x.a, x.b) < std::tie(y.cost, y.a, y.b);
  });
  std::vector<char> used(ends.size(), 0);
  std::size_t moved = 0;
  for (const Snap& s : snaps) {
    if (used[s.a] || used[s.b]) continue;
    used[s.a] = used[s.b] = 1;
    vertex(ends[s.a]) = s.p;
    vertex(ends[s.b]) = s.p;
    moved += 2;
  }
  return moved;
}

}  // namespace

// ---------------------------------------------------------------- public

int required_support(int min_drives, double min_view_fraction, std::size_t passes_in_view) {
  // The small epsilon keeps e.g. 0.5 * 4 at 2 against rounding.
  const double share = std::ceil(min_view_fraction * static_cast<double>(passes_in_view) - 1e-9);
  return std::max(min_drives, static_cast<int>(share));
}

SupportVerdict judge_support(const VisibilityIndex* view, std::span<const Eigen::Vector2d> places,
                             std::span<const std::int64_t> support_drives_sorted,
                             const SupportRule& rule) {
  POLMAP_EXPECT(rule.min_drives >= 1 && rule.min_view_fraction >= 0.0 &&
                rule.min_view_fraction <= 1.0 && rule.recent_passes >= 1);
  SupportVerdict v;
  v.support_drives = static_cast<std::uint32_t>(support_drives_sorted.size());
  v.drives_in_view = v.support_drives;
  const auto supported = [&](std::int64_t drive) {
    return std::binary_search(support_drives_sorted.begin(), support_drives_sorted.end(), drive);
  };
  if (view == nullptr) {
    v.status = static_cast<int>(v.support_drives) >= rule.min_drives
                   ? SupportVerdict::Status::Accepted
                   : SupportVerdict::Status::Rejected;
    return v;
  }
  // Passes in view, in drive-time order (VisibilityIndex keeps passes sorted by time).
  std::vector<std::size_t> passes;
  for (const auto& p : places) {
    const auto in = view->passes_in_view(p);
    passes.insert(passes.end(), in.begin(), in.end());
  }
  std::sort(passes.begin(), passes.end());
  passes.erase(std::unique(passes.begin(), passes.end()), passes.end());
  const auto& all = view->passes();
  // Supporting drives without a pass in view (no trajectory, or outside the range
  // model) had it in view all the same; their time is unknown, so they count for the
  // all-time rule only.
  std::vector<std::int64_t> seen_drives;
  for (std::size_t i : passes) seen_drives.push_back(all[i].drive);
  std::sort(seen_drives.begin(), seen_drives.end());
  seen_drives.erase(std::unique(seen_drives.begin(), seen_drives.end()), seen_drives.end());
  std::size_t extra = 0;
  for (std::int64_t d : support_drives_sorted) {
    if (!std::binary_search(seen_drives.begin(), seen_drives.end(), d)) ++extra;
  }
  v.drives_in_view = static_cast<std::uint32_t>(seen_drives.size() + extra);
  const bool all_time = static_cast<int>(v.support_drives) >=
                        required_support(rule.min_drives, rule.min_view_fraction, v.drives_in_view);
  // Recent window: the latest passes in view (one per drive: a drive's pass appears once).
  std::vector<std::size_t> recent;
  std::set<std::int64_t> recent_drives;
  for (auto it = passes.rbegin(); it != passes.rend(); ++it) {
    if (static_cast<int>(recent.size()) >= rule.recent_passes) break;
    if (recent_drives.insert(all[*it].drive).second) recent.push_back(*it);
  }
  v.recent_passes = static_cast<std::uint32_t>(recent.size());
  for (std::size_t i : recent) v.recent_support += supported(all[i].drive) ? 1U : 0U;
  std::set<std::int64_t> streak_vehicles;
  for (std::size_t i : recent) {  // latest first
    if (supported(all[i].drive)) {
      v.last_support_time_s = all[i].start_time_s;
      break;
    }
    ++v.miss_streak;
    streak_vehicles.insert(all[i].vehicle);
  }
  v.miss_streak_vehicles = static_cast<std::uint32_t>(streak_vehicles.size());
  const bool recent_ok =
      extra == 0 ? static_cast<int>(v.recent_support) >=
                       required_support(rule.min_drives, rule.min_view_fraction, recent.size())
                 : false;
  const bool retire = static_cast<int>(v.miss_streak) >= rule.retire_min_misses &&
                      static_cast<int>(v.miss_streak_vehicles) >= rule.retire_min_vehicles;
  if (!retire && (recent_ok || all_time)) {
    v.status = SupportVerdict::Status::Accepted;
  } else if (retire && (recent_ok || all_time)) {
    v.status = SupportVerdict::Status::Retired;
  } else {
    v.status = SupportVerdict::Status::Rejected;
  }
  return v;
}

PointConsensusResult consensus_points(std::span<const TaggedPointCandidate> candidates,
                                      const PointConsensusConfig& cfg,
                                      const VisibilityIndex* view) {
  POLMAP_EXPECT(cfg.max_pair_distance_m > 0.0);
  const auto pts = sorted_by_id(candidates);
  std::vector<std::pair<std::size_t, std::size_t>> edges;
  if (!pts.empty()) {
    using Tree =
        nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, PointCloud>,
                                            PointCloud, 2, std::size_t>;
    PointCloud cloud{&pts};
    Tree tree(2, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    tree.buildIndex();
    const double r2 = cfg.max_pair_distance_m * cfg.max_pair_distance_m;
    std::vector<std::pair<std::size_t, double>> hits;
    nanoflann::SearchParams params;
    params.sorted = false;
    for (std::size_t i = 0; i < pts.size(); ++i) {
      hits.clear();
      const double q[2] = {pts[i].candidate.position_m.x(), pts[i].candidate.position_m.y()};
      // Search slightly wider, then apply the exact strict test below (the
      // tree's own comparison must not decide the d_p boundary).
      tree.radiusSearch(q, r2 * (1.0 + 1e-9), hits, params);
      for (const auto& [j, d2] : hits) {
        if (j <= i || pts[j].drive == pts[i].drive) continue;
        if ((pts[j].candidate.position_m - pts[i].candidate.position_m).squaredNorm() < r2) {
          edges.emplace_back(i, j);
        }
      }
    }
  }
  return finish_points(pts, edges, cfg, view);
}

PointConsensusResult consensus_points_bruteforce(std::span<const TaggedPointCandidate> candidates,
                                                 const PointConsensusConfig& cfg,
                                                 const VisibilityIndex* view) {
  const auto pts = sorted_by_id(candidates);
  const double r2 = cfg.max_pair_distance_m * cfg.max_pair_distance_m;
  std::vector<std::pair<std::size_t, std::size_t>> edges;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    for (std::size_t j = i + 1; j < pts.size(); ++j) {
      if (pts[i].drive == pts[j].drive) continue;
      if ((pts[j].candidate.position_m - pts[i].candidate.position_m).squaredNorm() < r2) {
        edges.emplace_back(i, j);
      }
    }
  }
  return finish_points(pts, edges, cfg, view);
}

LinePairDistance line_pair_distance(const LineCandidate& a, const LineCandidate& b) {
  Eigen::Vector2d ua = a.end_m - a.start_m;
  Eigen::Vector2d ub = b.end_m - b.start_m;
  if (ua.dot(ub) < 0.0) ub = -ub;
  Eigen::Vector2d d = ua + ub;  // length-weighted mean direction
  if (d.squaredNorm() <= 1e-24) {
    d = Eigen::Vector2d(1.0, 0.0);
  } else {
    d.normalize();
  }
  const double ta0 = a.start_m.dot(d), ta1 = a.end_m.dot(d);
  const double tb0 = b.start_m.dot(d), tb1 = b.end_m.dot(d);
  const double alo = std::min(ta0, ta1), ahi = std::max(ta0, ta1);
  const double blo = std::min(tb0, tb1), bhi = std::max(tb0, tb1);
  LinePairDistance out;
  out.projection_m = std::max(0.0, std::max(alo, blo) - std::min(ahi, bhi));
  const double merged = std::max(ahi, bhi) - std::min(alo, blo);
  // Hull in coordinates relative to a's start: keeps the area well conditioned far from
  // the frame origin. The convex hull of four points is the largest of their three
  // quadrilaterals (shoelace; a crossed or concave one is smaller) and four triangles (one
  // point inside the others' triangle): closed form, no allocation, no hull algorithm
  // (this runs for every candidate pair of a fleet).
  const Eigen::Vector2d o = a.start_m;
  const std::array<Eigen::Vector2d, 4> p{Eigen::Vector2d::Zero(), a.end_m - o, b.start_m - o,
                                         b.end_m - o};
  auto cross = [](const Eigen::Vector2d& u, const Eigen::Vector2d& v) {
    return u.x() * v.y() - u.y() * v.x();
  };
  auto quad = [&](int i, int j, int k, int l) {
    return 0.5 *
           std::abs(cross(p[i], p[j]) + cross(p[j], p[k]) + cross(p[k], p[l]) + cross(p[l], p[i]));
  };
  auto tri = [&](int i, int j, int k) { return 0.5 * std::abs(cross(p[j] - p[i], p[k] - p[i])); };
  const double area = std::max({quad(0, 1, 2, 3), quad(0, 2, 1, 3), quad(0, 1, 3, 2), tri(0, 1, 2),
                                tri(0, 1, 3), tri(0, 2, 3), tri(1, 2, 3)});
  if (merged <= 1e-12) {
    out.hull_m = (b.start_m - a.start_m).norm();
  } else {
    out.hull_m = area / merged;
  }
  return out;
}

LineConsensusResult consensus_lines(std::span<const TaggedLineCandidate> candidates,
                                    const LineConsensusConfig& cfg, const VisibilityIndex* view) {
  POLMAP_EXPECT(cfg.max_projection_distance_m >= 0.0 && cfg.max_hull_distance_m > 0.0);
  POLMAP_EXPECT(cfg.curve_sample_spacing_m > 0.0 && cfg.polyline_max_error_m > 0.0);
  const auto lines = sorted_by_id(candidates);
  LineConsensusResult out;
  out.stats.candidates = lines.size();

  // Grid over bounding boxes grown by the projection threshold: two segments
  // whose grown boxes do not overlap are never tested (they are more than
  // 2 * max_projection_distance_m apart along x or y).
  const double grow = cfg.max_projection_distance_m + cfg.max_hull_distance_m;
  const double cell = std::max(4.0, 2.0 * grow);
  struct Box {
    double x0, y0, x1, y1;
  };
  std::vector<Box> boxes(lines.size());
  std::map<std::pair<std::int64_t, std::int64_t>, std::vector<std::size_t>> grid;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const auto& c = lines[i].candidate;
    boxes[i] = {
        std::min(c.start_m.x(), c.end_m.x()) - grow, std::min(c.start_m.y(), c.end_m.y()) - grow,
        std::max(c.start_m.x(), c.end_m.x()) + grow, std::max(c.start_m.y(), c.end_m.y()) + grow};
    const auto cx0 = static_cast<std::int64_t>(std::floor(boxes[i].x0 / cell));
    const auto cx1 = static_cast<std::int64_t>(std::floor(boxes[i].x1 / cell));
    const auto cy0 = static_cast<std::int64_t>(std::floor(boxes[i].y0 / cell));
    const auto cy1 = static_cast<std::int64_t>(std::floor(boxes[i].y1 / cell));
    for (auto cx = cx0; cx <= cx1; ++cx) {
      for (auto cy = cy0; cy <= cy1; ++cy) grid[{cx, cy}].push_back(i);
    }
  }
  UnionFind uf(lines.size());
  for (const auto& [c, members] : grid) {
    for (std::size_t p = 0; p < members.size(); ++p) {
      for (std::size_t q = p + 1; q < members.size(); ++q) {
        const std::size_t i = members[p], j = members[q];
        if (lines[i].drive == lines[j].drive) continue;
        const Box& a = boxes[i];
        const Box& b = boxes[j];
        const double ix0 = std::max(a.x0, b.x0), iy0 = std::max(a.y0, b.y0);
        if (ix0 > std::min(a.x1, b.x1) || iy0 > std::min(a.y1, b.y1)) continue;
        // Test each pair once: in the cell holding its boxes' overlap corner.
        if (static_cast<std::int64_t>(std::floor(ix0 / cell)) != c.first ||
            static_cast<std::int64_t>(std::floor(iy0 / cell)) != c.second) {
          continue;
        }
        // Already joined through other pairs: the components do not change, so the
        // (costly) pair test is skipped. In a dense fleet most pairs of one wall are.
        if (uf.find(i) == uf.find(j)) continue;
        const auto dist = line_pair_distance(lines[i].candidate, lines[j].candidate);
        if (dist.hull_m < cfg.max_hull_distance_m &&
            dist.projection_m < cfg.max_projection_distance_m) {
          ++out.stats.pairs;
          uf.unite(i, j);
        }
      }
    }
  }
  const auto groups = components(uf, lines.size());
  out.stats.groups = groups.size();
  for (const auto& g : groups) {
    const std::vector<std::int64_t> drives = group_drives(lines, g);
    if (static_cast<int>(drives.size()) < cfg.support.min_drives) {
      ++out.stats.rejected_groups;
      continue;
    }
    std::vector<Seg> segs;
    std::vector<std::int64_t> support;
    for (std::size_t i : g) {
      segs.push_back({lines[i].candidate.start_m, lines[i].candidate.end_m, lines[i].drive});
      support.push_back(lines[i].candidate_id);
    }
    MergedLine merged = merge_group(segs, cfg);
    std::vector<Eigen::Vector2d> places = merged.polyline;
    places.push_back(0.5 * (merged.polyline.front() + merged.polyline.back()));
    const SupportVerdict verdict = judge_support(view, places, drives, cfg.support);
    if (verdict.status == SupportVerdict::Status::Rejected) {
      ++out.stats.rejected_groups;
      continue;
    }
    LineLandmark lm;
    lm.id = static_cast<std::int64_t>(out.landmarks.size());
    lm.polyline_m = std::move(merged.polyline);
    lm.support_drives = static_cast<std::uint32_t>(drives.size());
    lm.spread_m = merged.spread_m;
    if (verdict.status == SupportVerdict::Status::Retired) {
      ++out.stats.retired_groups;
      lm.id = static_cast<std::int64_t>(out.retired.size());
      out.retired.push_back(std::move(lm));
      out.retired_verdicts.push_back(verdict);
      continue;
    }
    if (lm.polyline_m.size() > 2) ++out.stats.polylines;
    out.landmarks.push_back(std::move(lm));
    out.support.push_back(std::move(support));
    out.verdicts.push_back(verdict);
  }
  out.stats.snapped_ends = snap_ends(out.landmarks, cfg);
  return out;
}

}  // namespace polmap::mapping
