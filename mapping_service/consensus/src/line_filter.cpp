// Precision of fleet line consensus: overhead structures, range streaks and out-of-view
// returns (line_filter.hpp).
#include "polmap/mapping_service/line_filter.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <unordered_map>
#include <utility>

#include "polmap/mapping_service/consensus.hpp"
#include "polmap/mapping_service/polyline_distance.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {

double polyline_length(const std::vector<Eigen::Vector2d>& pl) {
  double s = 0.0;
  for (std::size_t k = 0; k + 1 < pl.size(); ++k) s += (pl[k + 1] - pl[k]).norm();
  return s;
}

/// The point halfway along the polyline.
Eigen::Vector2d arc_middle(const std::vector<Eigen::Vector2d>& pl, double length_m) {
  double rest = 0.5 * length_m;
  for (std::size_t k = 0; k + 1 < pl.size(); ++k) {
    const double l = (pl[k + 1] - pl[k]).norm();
    if (l > 0.0 && rest <= l) return pl[k] + (pl[k + 1] - pl[k]) * (rest / l);
    rest -= l;
  }
  return pl.back();
}

/// Points along the polyline no farther apart than step_m (its vertices included).
std::vector<Eigen::Vector2d> samples(const std::vector<Eigen::Vector2d>& pl, double step_m) {
  std::vector<Eigen::Vector2d> out;
  for (std::size_t k = 0; k + 1 < pl.size(); ++k) {
    const int n = std::max(1, static_cast<int>(std::ceil((pl[k + 1] - pl[k]).norm() / step_m)));
    for (int s = 0; s < n; ++s) out.push_back(pl[k] + (pl[k + 1] - pl[k]) * (double(s) / n));
  }
  out.push_back(pl.back());
  return out;
}

std::size_t count_in(std::span<const std::int64_t> sorted, std::span<const std::int64_t> of) {
  std::size_t n = 0;
  for (std::int64_t d : of) n += std::binary_search(sorted.begin(), sorted.end(), d) ? 1U : 0U;
  return n;
}

/// Where the segment [a, b] crosses [c, d]: the parameters (t along a–b, u along c–d) of the
/// crossing of their lines; nullopt when they are parallel.
std::optional<std::pair<double, double>> line_crossing(const Eigen::Vector2d& a,
                                                       const Eigen::Vector2d& b,
                                                       const Eigen::Vector2d& c,
                                                       const Eigen::Vector2d& d) {
  const Eigen::Vector2d r = b - a, s = d - c, q = c - a;
  const double den = r.x() * s.y() - r.y() * s.x();
  if (std::abs(den) <= 1e-12 * r.norm() * s.norm()) return std::nullopt;
  return std::pair{(q.x() * s.y() - q.y() * s.x()) / den, (q.x() * r.y() - q.y() * r.x()) / den};
}

/// The first line landmark other than `self` that the polyline crosses at least `overhang_m`
/// inside its own ends (arc length), the other's segments extended by `margin_m`; -1: none.
std::int64_t straddled_line(const LineConsensusResult& lines, std::size_t self, double length_m,
                            double margin_m, double overhang_m) {
  const std::vector<Eigen::Vector2d>& pl = lines.landmarks[self].polyline_m;
  double s0 = 0.0;  // arc length at the start of the current own segment
  for (std::size_t k = 0; k + 1 < pl.size(); ++k) {
    const double lk = (pl[k + 1] - pl[k]).norm();
    for (std::size_t j = 0; j < lines.landmarks.size() && lk > 0.0; ++j) {
      if (j == self) continue;
      const std::vector<Eigen::Vector2d>& other = lines.landmarks[j].polyline_m;
      for (std::size_t m = 0; m + 1 < other.size(); ++m) {
        const double lm = (other[m + 1] - other[m]).norm();
        if (lm <= 0.0) continue;
        const auto tu = line_crossing(pl[k], pl[k + 1], other[m], other[m + 1]);
        if (!tu) continue;
        const double at = s0 + tu->first * lk;  // arc length of the crossing on the own line
        if (tu->first < 0.0 || tu->first > 1.0 || at < overhang_m || at > length_m - overhang_m)
          continue;
        if (tu->second * lm < -margin_m || (tu->second - 1.0) * lm > margin_m) continue;
        return static_cast<std::int64_t>(j);
      }
    }
    s0 += lk;
  }
  return -1;
}

void sort_unique(std::vector<std::int64_t>& v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
}

}  // namespace

LineFilterResult filter_line_landmarks(LineConsensusResult& lines,
                                       std::span<const TaggedLineCandidate> candidates,
                                       const VisibilityIndex* view, const LineFilterConfig& cfg) {
  POLMAP_EXPECT(cfg.overhead.min_crossing_share >= 0.0 && cfg.overhead.min_crossing_drives >= 1 &&
                cfg.range_streaks.max_length_m >= 0.0 &&
                cfg.range_streaks.max_line_of_sight_angle_rad >= 0.0 &&
                cfg.out_of_view.min_view_fraction >= 0.0);
  POLMAP_EXPECT(lines.support.size() == lines.landmarks.size());
  const std::size_t n = lines.landmarks.size();
  LineFilterResult out;
  out.evidence.resize(n);
  if (view == nullptr || view->empty()) return out;  // every rule needs the passes' paths
  std::unordered_map<std::int64_t, std::int64_t> drive_of;
  drive_of.reserve(candidates.size());
  for (const auto& c : candidates) drive_of[c.candidate_id] = c.drive;

  for (std::size_t i = 0; i < n; ++i) {
    const std::vector<Eigen::Vector2d>& pl = lines.landmarks[i].polyline_m;
    LineEvidence& ev = out.evidence[i];
    if (pl.size() < 2) continue;
    std::vector<std::int64_t> support;
    for (std::int64_t id : lines.support[i]) {
      if (const auto it = drive_of.find(id); it != drive_of.end()) support.push_back(it->second);
    }
    sort_unique(support);
    ev.support = static_cast<std::uint32_t>(support.size());
    ev.length_m = polyline_length(pl);
    const Eigen::Vector2d middle = arc_middle(pl, ev.length_m);
    // Passes in view as the support rule counts them: at any vertex or the middle.
    std::vector<std::int64_t> modelled;
    for (const Eigen::Vector2d& q : pl) {
      const auto v = view->drives_in_view(q);
      modelled.insert(modelled.end(), v.begin(), v.end());
    }
    const auto vm = view->drives_in_view(middle);
    modelled.insert(modelled.end(), vm.begin(), vm.end());
    sort_unique(modelled);
    std::vector<std::int64_t> in_view = modelled;
    in_view.insert(in_view.end(), support.begin(), support.end());
    sort_unique(in_view);
    ev.passes_in_view = static_cast<std::uint32_t>(in_view.size());

    // ------------------------------------------------------------ overhead
    std::vector<std::int64_t> crossing;
    for (std::size_t k = 0; k + 1 < pl.size(); ++k) {
      const auto c = view->drives_crossing(pl[k], pl[k + 1]);
      crossing.insert(crossing.end(), c.begin(), c.end());
    }
    sort_unique(crossing);
    ev.crossing_drives = static_cast<std::uint32_t>(count_in(crossing, support));
    const double need_crossing =
        std::max(static_cast<double>(cfg.overhead.min_crossing_drives),
                 std::ceil(cfg.overhead.min_crossing_share * support.size() - 1e-9));
    if (cfg.overhead.enabled && ev.crossing_drives > 0 && ev.crossing_drives >= need_crossing) {
      ev.verdict = LineEvidence::Verdict::Overhead;
    }

    // ------------------------------------------------------------ range streaks
    std::optional<Eigen::Vector2d> road = view->nearest_path_point(middle);
    if (!road) road = view->nearest_path_point(middle, support);
    if (road && (middle - *road).norm() > 1e-6 && (pl.back() - pl.front()).norm() > 0.0) {
      const Eigen::Vector2d los = (middle - *road).normalized();
      const Eigen::Vector2d dir = (pl.back() - pl.front()).normalized();
      ev.line_of_sight_angle_rad = std::acos(std::min(1.0, std::abs(los.dot(dir))));
      const RangeStreakRule& rule = cfg.range_streaks;
      if (ev.length_m <= rule.max_length_m &&
          ev.line_of_sight_angle_rad <= rule.max_line_of_sight_angle_rad) {
        ev.straddled_line =
            straddled_line(lines, i, ev.length_m, rule.reflector_margin_m, rule.min_overhang_m);
      }
      if (rule.enabled && ev.verdict == LineEvidence::Verdict::Kept && ev.straddled_line >= 0 &&
          static_cast<double>(support.size()) <=
              rule.min_detection_share * static_cast<double>(in_view.size())) {
        ev.verdict = LineEvidence::Verdict::RangeStreak;
      }
    }

    // ------------------------------------------------------------ out of view
    if (cfg.out_of_view.enabled && ev.verdict == LineEvidence::Verdict::Kept &&
        2 * count_in(modelled, support) < support.size()) {
      // Against every pass that came as close as the farthest supporting drive (as points).
      const std::vector<Eigen::Vector2d> along = samples(pl, 1.0);
      if (const auto close = view->count_passes_as_close(along, support)) {
        ev.passes_as_close = static_cast<std::uint32_t>(*close);
        const double need = std::max(
            2.0, std::ceil(cfg.out_of_view.min_view_fraction * static_cast<double>(*close) - 1e-9));
        if (static_cast<double>(support.size()) < need) {
          ev.verdict = LineEvidence::Verdict::OutOfView;
        }
      }
    }
  }

  // -------------------------------------------------------------- remove
  LineConsensusResult kept;
  kept.stats = lines.stats;
  kept.retired = std::move(lines.retired);
  kept.retired_verdicts = std::move(lines.retired_verdicts);
  for (std::size_t i = 0; i < n; ++i) {
    switch (out.evidence[i].verdict) {
      case LineEvidence::Verdict::Overhead:
        ++out.overhead;
        continue;
      case LineEvidence::Verdict::RangeStreak:
        ++out.range_streaks;
        continue;
      case LineEvidence::Verdict::OutOfView:
        ++out.out_of_view;
        continue;
      case LineEvidence::Verdict::Kept:
        break;
    }
    LineLandmark lm = std::move(lines.landmarks[i]);
    lm.id = static_cast<std::int64_t>(kept.landmarks.size());
    kept.landmarks.push_back(std::move(lm));
    kept.support.push_back(std::move(lines.support[i]));
    if (i < lines.verdicts.size()) kept.verdicts.push_back(lines.verdicts[i]);
  }
  kept.stats.rejected_groups += out.overhead + out.range_streaks + out.out_of_view;
  lines = std::move(kept);
  return out;
}

}  // namespace polmap::mapping
