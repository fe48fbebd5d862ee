// Precision of fleet point consensus: line and surface peaks, temporary and sliding objects,
// out-of-view returns and mirror images (point_filter.hpp).
#include "polmap/mapping_service/point_filter.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <span>
#include <unordered_map>
#include <utility>

#include "polmap/mapping_service/consensus.hpp"
#include "polmap/mapping_service/polyline_distance.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {

double log_choose(int n, int k) {
  return std::lgamma(n + 1.0) - std::lgamma(k + 1.0) - std::lgamma(n - k + 1.0);
}

/// Nearest line landmark piece: distance and unit direction of the nearest segment.
struct NearestLine {
  double distance_m = std::numeric_limits<double>::infinity();
  Eigen::Vector2d direction = Eigen::Vector2d::UnitX();
  std::size_t line = 0;  ///< index of the line landmark
};

/// Indices in a uniform grid of square cells; a query visits the 3x3 cells around a point,
/// so it finds everything within one cell size of it.
class CellIndex {
 public:
  explicit CellIndex(double cell) : cell_(cell) {}
  /// Index i in every cell the box [lo, hi] touches.
  void add(const Eigen::Vector2d& lo, const Eigen::Vector2d& hi, std::size_t i) {
    const auto [x0, y0] = key(lo);
    const auto [x1, y1] = key(hi);
    for (auto x = x0; x <= x1; ++x) {
      for (auto y = y0; y <= y1; ++y) cells_[pack(x, y)].push_back(i);
    }
  }
  /// fn(i) for every index in the 3x3 cells around p (an index in two cells comes twice).
  template <class Fn>
  void for_each_near(const Eigen::Vector2d& p, Fn&& fn) const {
    const auto [cx, cy] = key(p);
    for (std::int64_t dx = -1; dx <= 1; ++dx) {
      for (std::int64_t dy = -1; dy <= 1; ++dy) {
        const auto it = cells_.find(pack(cx + dx, cy + dy));
        if (it == cells_.end()) continue;
        for (std::size_t i : it->second) fn(i);
      }
    }
  }

 private:
  [[nodiscard]] std::pair<std::int64_t, std::int64_t> key(const Eigen::Vector2d& p) const {
    return {static_cast<std::int64_t>(std::floor(p.x() / cell_)),
            static_cast<std::int64_t>(std::floor(p.y() / cell_))};
  }
  static std::uint64_t pack(std::int64_t x, std::int64_t y) {
    return (static_cast<std::uint64_t>(x) << 32U) ^ (static_cast<std::uint64_t>(y) & 0xffffffffU);
  }
  double cell_;
  std::unordered_map<std::uint64_t, std::vector<std::size_t>> cells_;
};

/// Line segments in a uniform grid for nearest-segment queries within a radius.
class SegmentGrid {
 public:
  SegmentGrid(const LineConsensusResult& lines, double cell) : index_(cell) {
    for (std::size_t li = 0; li < lines.landmarks.size(); ++li) {
      const auto& l = lines.landmarks[li];
      for (std::size_t i = 0; i + 1 < l.polyline_m.size(); ++i) {
        const Eigen::Vector2d a = l.polyline_m[i], b = l.polyline_m[i + 1];
        index_.add(a.cwiseMin(b), a.cwiseMax(b), segs_.size());
        segs_.push_back({a, b});
        seg_line_.push_back(li);
      }
    }
  }
  /// Calls fn(a, b) for every segment within `radius` of p (radius <= the cell size).
  template <class Fn>
  void for_each_within(const Eigen::Vector2d& p, double radius, Fn&& fn) const {
    std::vector<std::size_t> seen;
    index_.for_each_near(p, [&](std::size_t s) {
      const auto& [a, b] = segs_[s];
      if ((b - a).squaredNorm() <= 0.0 || point_segment_distance(p, a, b) > radius) return;
      if (std::find(seen.begin(), seen.end(), s) != seen.end()) return;  // in two cells
      seen.push_back(s);
      fn(a, b);
    });
  }
  /// Nearest segment within one cell of p (cell >= the query radius).
  [[nodiscard]] NearestLine nearest(const Eigen::Vector2d& p) const {
    NearestLine out;
    index_.for_each_near(p, [&](std::size_t s) {
      const auto& [a, b] = segs_[s];
      const double d = point_segment_distance(p, a, b);
      if (d < out.distance_m && (b - a).norm() > 0.0) {
        out.distance_m = d;
        out.direction = (b - a).normalized();
        out.line = seg_line_[s];
      }
    });
    return out;
  }

 private:
  CellIndex index_;
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> segs_;
  std::vector<std::size_t> seg_line_;
};

/// RMS spread of a landmark's candidates along unit direction u and across it, about p
/// (m = 0: no candidate found).
struct AlongAcross {
  double along_m = 0.0;
  double across_m = 0.0;
  std::size_t m = 0;
};
AlongAcross spread_along(std::span<const std::int64_t> support_ids,
                         const std::unordered_map<std::int64_t, const TaggedPointCandidate*>& by_id,
                         const Eigen::Vector2d& p, const Eigen::Vector2d& u) {
  const Eigen::Vector2d w(-u.y(), u.x());
  double sa = 0.0, sc = 0.0;
  AlongAcross out;
  for (std::int64_t id : support_ids) {
    const auto it = by_id.find(id);
    if (it == by_id.end()) continue;
    const Eigen::Vector2d d = it->second->candidate.position_m - p;
    sa += d.dot(u) * d.dot(u);
    sc += d.dot(w) * d.dot(w);
    ++out.m;
  }
  if (out.m > 0) {
    out.along_m = std::sqrt(sa / static_cast<double>(out.m));
    out.across_m = std::sqrt(sc / static_cast<double>(out.m));
  }
  return out;
}

/// Point candidates in a uniform grid: the distinct drives with a candidate within a radius.
class CandidateGrid {
 public:
  CandidateGrid(std::span<const TaggedPointCandidate> candidates, double cell)
      : cands_(candidates), index_(cell) {
    for (std::size_t i = 0; i < candidates.size(); ++i) {
      const Eigen::Vector2d& p = candidates[i].candidate.position_m;
      index_.add(p, p, i);
    }
  }
  /// Distinct drives with a candidate within radius (<= the cell size) of p.
  [[nodiscard]] std::size_t drives_within(const Eigen::Vector2d& p, double radius) const {
    std::vector<std::int64_t> drives;
    index_.for_each_near(p, [&](std::size_t i) {
      if ((cands_[i].candidate.position_m - p).norm() <= radius) drives.push_back(cands_[i].drive);
    });
    std::sort(drives.begin(), drives.end());
    return static_cast<std::size_t>(std::unique(drives.begin(), drives.end()) - drives.begin());
  }

 private:
  std::span<const TaggedPointCandidate> cands_;
  CellIndex index_;
};

/// Which side of the line through a and b p lies on (sign of the cross product).
double side_of(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& p) {
  const Eigen::Vector2d ab = b - a, ap = p - a;
  return ab.x() * ap.y() - ab.y() * ap.x();
}

}  // namespace

double fisher_positive_p(int both, int first_only, int second_only, int neither) {
  POLMAP_EXPECT(both >= 0 && first_only >= 0 && second_only >= 0 && neither >= 0);
  const int n = both + first_only + second_only + neither;
  const int row = both + first_only;   // first detected
  const int col = both + second_only;  // second detected
  const int hi = std::min(row, col);
  const double denom = log_choose(n, col);
  double p = 0.0;
  for (int x = both; x <= hi; ++x) {
    if (col - x > n - row) continue;
    p += std::exp(log_choose(row, x) + log_choose(n - row, col - x) - denom);
  }
  return std::min(1.0, p);
}

PointFilterResult filter_point_landmarks(PointConsensusResult& points,
                                         const LineConsensusResult& lines,
                                         std::span<const TaggedPointCandidate> candidates,
                                         const VisibilityIndex* view,
                                         const PointFilterConfig& cfg) {
  POLMAP_EXPECT(cfg.line_peaks.max_line_distance_m >= 0.0 &&
                cfg.surface_peaks.max_line_distance_m >= 0.0 &&
                cfg.surface_peaks.max_line_distance_m <= 2.0 &&  // the segment grid's reach
                cfg.co_presence.neighbour_radius_m > 0.0);
  const std::size_t n = points.landmarks.size();
  PointFilterResult out;
  out.evidence.resize(n);
  std::unordered_map<std::int64_t, const TaggedPointCandidate*> by_id;
  by_id.reserve(candidates.size());
  for (const auto& c : candidates) by_id[c.candidate_id] = &c;

  // Supporting drives (ascending) and passes in view (drives, ascending) per landmark.
  std::vector<std::vector<std::int64_t>> support(n), in_view(n);
  std::vector<std::int64_t> all_drives;
  for (std::size_t i = 0; i < n; ++i) {
    for (std::int64_t id : points.support[i]) {
      if (const auto it = by_id.find(id); it != by_id.end())
        support[i].push_back(it->second->drive);
    }
    std::sort(support[i].begin(), support[i].end());
    support[i].erase(std::unique(support[i].begin(), support[i].end()), support[i].end());
    all_drives.insert(all_drives.end(), support[i].begin(), support[i].end());
  }
  std::sort(all_drives.begin(), all_drives.end());
  all_drives.erase(std::unique(all_drives.begin(), all_drives.end()), all_drives.end());
  for (std::size_t i = 0; i < n; ++i) {
    std::vector<std::int64_t> v =
        view != nullptr ? view->drives_in_view(points.landmarks[i].position_m) : all_drives;
    v.insert(v.end(), support[i].begin(), support[i].end());  // supporters had it in view
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
    in_view[i] = std::move(v);
    out.evidence[i].passes_in_view = static_cast<std::uint32_t>(in_view[i].size());
    out.evidence[i].support = static_cast<std::uint32_t>(support[i].size());
  }

  // ---------------------------------------------------------------- line peaks
  if (!lines.landmarks.empty()) {  // measured always, applied when enabled
    const SegmentGrid grid(lines, std::max(4.0, 2.0 * cfg.line_peaks.max_line_distance_m));
    for (std::size_t i = 0; i < n; ++i) {
      const Eigen::Vector2d p = points.landmarks[i].position_m;
      const NearestLine nl = grid.nearest(p);
      PointEvidence& ev = out.evidence[i];
      if (!std::isfinite(nl.distance_m)) continue;
      ev.line_distance_m = nl.distance_m;
      double vd = std::numeric_limits<double>::infinity();
      for (const auto& v : lines.landmarks[nl.line].polyline_m) vd = std::min(vd, (v - p).norm());
      ev.vertex_distance_m = vd;
      const SurfacePeakRule& sp = cfg.surface_peaks;
      if (sp.enabled && points.landmarks[i].scattering == ScatteringClass::Odd &&
          nl.distance_m <= sp.max_line_distance_m && vd > sp.min_vertex_distance_m &&
          !in_view[i].empty() &&
          static_cast<double>(support[i].size()) <=
              sp.min_detection_share * static_cast<double>(in_view[i].size())) {
        ev.verdict = PointEvidence::Verdict::SurfacePeak;
      }
      const AlongAcross sp_line = spread_along(points.support[i], by_id, p, nl.direction);
      if (sp_line.m == 0) continue;
      ev.along_spread_m = sp_line.along_m;
      ev.across_spread_m = sp_line.across_m;
      if (cfg.line_peaks.enabled && ev.verdict == PointEvidence::Verdict::Kept &&
          nl.distance_m <= cfg.line_peaks.max_line_distance_m &&
          ev.along_spread_m >= cfg.line_peaks.min_along_spread_m &&
          ev.along_spread_m >= cfg.line_peaks.min_along_across_ratio * ev.across_spread_m) {
        ev.verdict = PointEvidence::Verdict::LinePeak;
      }
    }
  }

  // ---------------------------------------------------------------- co-presence
  if (n > 1) {  // measured always, applied when enabled
    const CoPresenceRule& rule = cfg.co_presence;
    const double r2 = rule.neighbour_radius_m * rule.neighbour_radius_m;
    // Grid of landmarks (cell = radius): neighbours are in the 3 × 3 cells around.
    std::unordered_map<std::uint64_t, std::vector<std::size_t>> cells;
    auto cell_of = [&](const Eigen::Vector2d& p) {
      return std::pair{static_cast<std::int64_t>(std::floor(p.x() / rule.neighbour_radius_m)),
                       static_cast<std::int64_t>(std::floor(p.y() / rule.neighbour_radius_m))};
    };
    auto pack = [](std::int64_t x, std::int64_t y) {
      return (static_cast<std::uint64_t>(x) << 32U) ^ (static_cast<std::uint64_t>(y) & 0xffffffffU);
    };
    for (std::size_t i = 0; i < n; ++i) {
      const auto [x, y] = cell_of(points.landmarks[i].position_m);
      cells[pack(x, y)].push_back(i);
    }
    auto share = [&](std::size_t i) {
      return in_view[i].empty()
                 ? 1.0
                 : static_cast<double>(support[i].size()) / static_cast<double>(in_view[i].size());
    };
    for (std::size_t i = 0; i < n; ++i) {
      const bool low_i = share(i) <= rule.max_detection_share;
      const Eigen::Vector2d p = points.landmarks[i].position_m;
      const auto [cx, cy] = cell_of(p);
      PointEvidence& ev = out.evidence[i];
      bool temporary = false;
      for (std::int64_t dx = -1; dx <= 1; ++dx) {
        for (std::int64_t dy = -1; dy <= 1; ++dy) {
          const auto it = cells.find(pack(cx + dx, cy + dy));
          if (it == cells.end()) continue;
          for (std::size_t j : it->second) {
            if (j == i || (points.landmarks[j].position_m - p).squaredNorm() >= r2) continue;
            // The 2×2 table over the passes that had both in view.
            int a = 0, b = 0, c = 0, d = 0;
            for (std::int64_t drive : in_view[i]) {
              if (!std::binary_search(in_view[j].begin(), in_view[j].end(), drive)) continue;
              const bool si = std::binary_search(support[i].begin(), support[i].end(), drive);
              const bool sj = std::binary_search(support[j].begin(), support[j].end(), drive);
              (si ? (sj ? a : b) : (sj ? c : d)) += 1;
            }
            if (a == 0 || d == 0) continue;  // never together, or never both absent
            const int common = a + b + c + d;
            const double pv = fisher_positive_p(a, b, c, d);
            if (pv < ev.co_presence_p) {
              ev.co_presence_p = pv;
              ev.co_present_with = static_cast<std::int64_t>(j);
            }
            // Effect size: the phi coefficient of the table (a permanent pair sharing a
            // few misses by chance, e.g. behind the same occluder, stays below it).
            const double den = std::sqrt(static_cast<double>(a + b) * (c + d) * (a + c) * (b + d));
            const double phi =
                den > 0.0 ? (static_cast<double>(a) * d - static_cast<double>(b) * c) / den : 0.0;
            const bool hit = common < rule.min_passes_for_test
                                 ? (b == 0 && c == 0 && d >= rule.min_shared_misses)
                                 : pv <= rule.max_p_value && phi >= rule.min_phi;
            temporary = temporary || (hit && low_i && share(j) <= rule.max_detection_share);
          }
        }
      }
      if (rule.enabled && temporary && ev.verdict == PointEvidence::Verdict::Kept) {
        ev.verdict = PointEvidence::Verdict::Temporary;
      }
    }
  }

  // ---------------------------------------------------------------- sliding
  if (view != nullptr && !view->empty()) {  // measured always, applied when enabled
    const SlidingRule& rule = cfg.sliding;
    for (std::size_t i = 0; i < n; ++i) {
      const Eigen::Vector2d p = points.landmarks[i].position_m;
      const std::optional<Eigen::Vector2d> road = view->nearest_path_direction(p);
      if (!road) continue;
      const AlongAcross sp_road = spread_along(points.support[i], by_id, p, *road);
      if (sp_road.m == 0) continue;
      PointEvidence& ev = out.evidence[i];
      ev.along_road_spread_m = sp_road.along_m;
      ev.across_road_spread_m = sp_road.across_m;
      if (rule.enabled && ev.verdict == PointEvidence::Verdict::Kept &&
          std::cmp_greater_equal(support[i].size(), rule.min_support_drives) &&
          static_cast<double>(support[i].size()) <=
              rule.max_detection_share * static_cast<double>(in_view[i].size()) &&
          ev.along_road_spread_m >= rule.min_along_spread_m &&
          ev.along_road_spread_m >= rule.min_along_across_ratio * ev.across_road_spread_m) {
        ev.verdict = PointEvidence::Verdict::Sliding;
      }
    }
  }

  // ---------------------------------------------------------------- out of view
  if (cfg.out_of_view.enabled && view != nullptr && !view->empty()) {
    for (std::size_t i = 0; i < n; ++i) {
      PointEvidence& ev = out.evidence[i];
      if (ev.verdict != PointEvidence::Verdict::Kept) continue;
      const Eigen::Vector2d p = points.landmarks[i].position_m;
      const std::vector<std::int64_t> modelled = view->drives_in_view(p);
      std::size_t supported_in_view = 0;
      for (std::int64_t d : support[i]) {
        supported_in_view += std::binary_search(modelled.begin(), modelled.end(), d) ? 1U : 0U;
      }
      if (2 * supported_in_view >= support[i].size()) continue;
      // Against every pass that came as close as the farthest supporting drive.
      const std::optional<std::size_t> as_close = view->count_passes_as_close({&p, 1}, support[i]);
      if (!as_close) continue;  // a supporter without trajectory: cannot say how close it came
      const std::size_t close = *as_close;
      ev.passes_as_close = static_cast<std::uint32_t>(close);
      const double need = std::max(
          2.0, std::ceil(cfg.out_of_view.min_view_fraction * static_cast<double>(close) - 1e-9));
      if (static_cast<double>(support[i].size()) < need) {
        ev.verdict = PointEvidence::Verdict::OutOfView;
      }
    }
  }

  // ---------------------------------------------------------------- mirror images
  if (const MirrorGhostRule& rule = cfg.mirror_ghosts;
      rule.enabled && view != nullptr && !view->empty() && !lines.landmarks.empty()) {
    const SegmentGrid reflectors(lines, rule.max_reflector_distance_m);
    const CandidateGrid cands(candidates, std::max(1.0, rule.image_radius_m));
    for (std::size_t i = 0; i < n; ++i) {
      PointEvidence& ev = out.evidence[i];
      if (ev.verdict != PointEvidence::Verdict::Kept) continue;
      const Eigen::Vector2d p = points.landmarks[i].position_m;
      std::optional<Eigen::Vector2d> road = view->nearest_path_point(p);
      if (!road) road = view->nearest_path_point(p, support[i]);
      if (!road) continue;
      const double need = std::max(
          static_cast<double>(rule.min_image_drives),
          std::ceil(rule.min_image_support_share * static_cast<double>(support[i].size()) - 1e-9));
      reflectors.for_each_within(
          p, rule.max_reflector_distance_m,
          [&](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
            if (ev.mirror_image_drives > 0) return;
            const double side_road = side_of(a, b, *road);
            // p behind the reflector, seen from the road.
            if (side_of(a, b, p) * side_road >= 0.0) return;
            const Eigen::Vector2d ab = b - a;
            const double len = ab.norm();
            const double t = (p - a).dot(ab) / (len * len);
            if (t * len < -rule.segment_margin_m || (t - 1.0) * len > rule.segment_margin_m) return;
            const Eigen::Vector2d foot = a + t * ab;
            const Eigen::Vector2d image = 2.0 * foot - p;
            if ((image - p).norm() < rule.min_image_offset_m) return;
            if (side_of(a, b, image) * side_road <= 0.0) return;
            const std::size_t drives = cands.drives_within(image, rule.image_radius_m);
            if (static_cast<double>(drives) >= need) {
              ev.mirror_image_drives = static_cast<std::uint32_t>(drives);
            }
          });
      if (ev.mirror_image_drives > 0) ev.verdict = PointEvidence::Verdict::MirrorGhost;
    }
  }

  // ---------------------------------------------------------------- remove
  PointConsensusResult kept_result;
  kept_result.stats = points.stats;
  kept_result.retired = std::move(points.retired);
  kept_result.retired_verdicts = std::move(points.retired_verdicts);
  for (std::size_t i = 0; i < n; ++i) {
    switch (out.evidence[i].verdict) {
      case PointEvidence::Verdict::LinePeak:
        ++out.line_peaks;
        continue;
      case PointEvidence::Verdict::SurfacePeak:
        ++out.surface_peaks;
        continue;
      case PointEvidence::Verdict::Temporary:
        ++out.temporary;
        continue;
      case PointEvidence::Verdict::Sliding:
        ++out.sliding;
        continue;
      case PointEvidence::Verdict::OutOfView:
        ++out.out_of_view;
        continue;
      case PointEvidence::Verdict::MirrorGhost:
        ++out.mirror_ghosts;
        continue;
      case PointEvidence::Verdict::Kept:
        break;
    }
    PointLandmark lm = points.landmarks[i];
    lm.id = static_cast<std::int64_t>(kept_result.landmarks.size());
    kept_result.landmarks.push_back(lm);
    kept_result.support.push_back(std::move(points.support[i]));
    if (i < points.verdicts.size()) kept_result.verdicts.push_back(points.verdicts[i]);
  }
  kept_result.stats.rejected_groups += out.line_peaks + out.surface_peaks + out.temporary +
                                       out.sliding + out.out_of_view + out.mirror_ghosts;
  points = std::move(kept_result);
  return out;
}

}  // namespace polmap::mapping
