// Visibility of places from drive passes (see visibility.hpp).
#include "polmap/mapping_service/visibility.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>

#include "polmap/mapping_service/polyline_distance.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/tiles/polyline_simplify.hpp"

namespace polmap::mapping {
namespace {

/// Douglas–Peucker in windows of 1024 edges (tiles::douglas_peucker_keep): a hostile
/// zig-zag path costs linear, not quadratic, time. eps 0 keeps every vertex.
std::vector<Eigen::Vector2d> simplify(std::span<const Eigen::Vector2d> pts, double eps) {
  if (pts.size() <= 2 || eps <= 0.0) return {pts.begin(), pts.end()};
  const std::vector<Eigen::Vector2d> in(pts.begin(), pts.end());
  const std::vector<bool> keep = tiles::douglas_peucker_keep(in, eps, 1024);
  std::vector<Eigen::Vector2d> out;
  for (std::size_t i = 0; i < in.size(); ++i) {
    if (keep[i]) out.push_back(in[i]);
  }
  return out;
}

std::uint64_t cell_key(std::int64_t cx, std::int64_t cy) {
  return (static_cast<std::uint64_t>(cx) << 32) ^ (static_cast<std::uint64_t>(cy) & 0xffffffffU);
}

}  // namespace

double estimate_view_range_m(std::span<const Eigen::Vector2d> path_m,
                             std::span<const Eigen::Vector2d> candidate_positions_m,
                             const VisibilityConfig& cfg) {
  POLMAP_EXPECT(cfg.range_quantile > 0.0 && cfg.range_quantile <= 1.0 && cfg.range_margin > 0.0);
  if (path_m.empty() || candidate_positions_m.empty()) return cfg.default_view_range_m;
  // The simplified path keeps every candidate's distance within the tolerance, and a
  // single-drive index answers each distance in O(local pieces).
  DrivePass pass;
  pass.path_m = simplify(path_m, cfg.simplify_tolerance_m);
  pass.view_range_m = cfg.max_view_range_m;
  const VisibilityIndex index({pass}, cfg);
  std::vector<double> d;
  d.reserve(candidate_positions_m.size());
  for (const auto& c : candidate_positions_m) {
    // Outside the maximum range: count as the maximum (clamped below anyway).
    d.push_back(index.count_in_view(c) == 0 ? cfg.max_view_range_m
                                            : point_polyline_distance(c, pass.path_m));
  }
  const auto k = static_cast<std::size_t>(
      std::min<double>(static_cast<double>(d.size() - 1),
                       std::floor(cfg.range_quantile * static_cast<double>(d.size() - 1))));
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(k), d.end());
  return std::clamp(cfg.range_margin * d[k], cfg.min_view_range_m, cfg.max_view_range_m);
}

VisibilityIndex::VisibilityIndex(std::vector<DrivePass> passes, const VisibilityConfig& cfg)
    : passes_(std::move(passes)), cell_m_(cfg.cell_m) {
  POLMAP_EXPECT(cfg.cell_m > 0.0 && cfg.simplify_tolerance_m >= 0.0);
  POLMAP_EXPECT(passes_.size() < std::numeric_limits<std::uint32_t>::max());
  // Drive-time order: consensus decisions follow when drives happened, not upload order.
  std::stable_sort(passes_.begin(), passes_.end(), [](const DrivePass& a, const DrivePass& b) {
    return std::tie(a.start_time_s, a.drive) < std::tie(b.start_time_s, b.drive);
  });
  range_m_.reserve(passes_.size());
  for (std::size_t i = 0; i < passes_.size(); ++i) {
    const DrivePass& p = passes_[i];
    const double range = p.view_range_m > 0.0 ? p.view_range_m : cfg.default_view_range_m;
    range_m_.push_back(range);
    std::vector<Eigen::Vector2d> path = simplify(p.path_m, cfg.simplify_tolerance_m);
    if (path.size() == 1) path.push_back(path[0]);
    for (std::size_t k = 0; k + 1 < path.size(); ++k) {
      // Pieces no longer than a cell keep the grown boxes small for diagonal segments.
      const Eigen::Vector2d a = path[k], b = path[k + 1];
      const int n = std::max(1, static_cast<int>(std::ceil((b - a).norm() / cell_m_)));
      for (int s = 0; s < n; ++s) {
        const Eigen::Vector2d pa = a + (b - a) * (static_cast<double>(s) / n);
        const Eigen::Vector2d pb = a + (b - a) * (static_cast<double>(s + 1) / n);
        const auto cx0 =
            static_cast<std::int64_t>(std::floor((std::min(pa.x(), pb.x()) - range) / cell_m_));
        const auto cx1 =
            static_cast<std::int64_t>(std::floor((std::max(pa.x(), pb.x()) + range) / cell_m_));
        const auto cy0 =
            static_cast<std::int64_t>(std::floor((std::min(pa.y(), pb.y()) - range) / cell_m_));
        const auto cy1 =
            static_cast<std::int64_t>(std::floor((std::max(pa.y(), pb.y()) + range) / cell_m_));
        for (auto cx = cx0; cx <= cx1; ++cx) {
          for (auto cy = cy0; cy <= cy1; ++cy) {
            auto& v = cells_[cell_key(cx, cy)];
            // Consecutive pieces of one pass often land in the same cell: keep them all
            // (the query stops at the first piece in range).
            v.push_back({static_cast<std::uint32_t>(i), pa, pb});
          }
        }
      }
    }
  }
}

const std::vector<VisibilityIndex::Piece>* VisibilityIndex::pieces_at(
    const Eigen::Vector2d& p) const {
  const auto it = cells_.find(cell_key(static_cast<std::int64_t>(std::floor(p.x() / cell_m_)),
                                       static_cast<std::int64_t>(std::floor(p.y() / cell_m_))));
  return it == cells_.end() ? nullptr : &it->second;
}

std::vector<std::size_t> VisibilityIndex::passes_in_view(const Eigen::Vector2d& p) const {
  std::vector<std::size_t> out;
  const std::vector<Piece>* pieces = pieces_at(p);
  if (pieces == nullptr) return out;
  std::uint32_t last = std::numeric_limits<std::uint32_t>::max();
  bool last_in = false;
  for (const Piece& piece : *pieces) {
    // Pieces of a pass are contiguous in the cell's list (inserted pass by pass).
    if (piece.pass == last && last_in) continue;
    if (piece.pass != last) last_in = false;
    last = piece.pass;
    if (point_segment_distance(p, piece.a, piece.b) <= range_m_[piece.pass]) {
      last_in = true;
      out.push_back(piece.pass);
    }
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

const VisibilityIndex::Piece* VisibilityIndex::nearest_piece(const Eigen::Vector2d& p) const {
  const std::vector<Piece>* pieces = pieces_at(p);
  if (pieces == nullptr) return nullptr;
  double best = std::numeric_limits<double>::infinity();
  const Piece* out = nullptr;
  for (const Piece& piece : *pieces) {
    if ((piece.b - piece.a).squaredNorm() <= 0.0) continue;
    const double d = point_segment_distance(p, piece.a, piece.b);
    if (d <= range_m_[piece.pass] && d < best) {
      best = d;
      out = &piece;
    }
  }
  return out;
}

std::optional<Eigen::Vector2d> VisibilityIndex::nearest_path_direction(
    const Eigen::Vector2d& p) const {
  const Piece* piece = nearest_piece(p);
  if (piece == nullptr) return std::nullopt;
  return (piece->b - piece->a).normalized();
}

std::optional<Eigen::Vector2d> VisibilityIndex::nearest_path_point(const Eigen::Vector2d& p) const {
  const Piece* piece = nearest_piece(p);
  if (piece == nullptr) return std::nullopt;
  const Eigen::Vector2d ab = piece->b - piece->a;
  const double t = std::clamp((p - piece->a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
  return piece->a + t * ab;
}

std::vector<std::int64_t> VisibilityIndex::drives_in_view(const Eigen::Vector2d& p) const {
  std::vector<std::int64_t> out;
  for (std::size_t i : passes_in_view(p)) out.push_back(passes_[i].drive);
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

std::optional<Eigen::Vector2d> VisibilityIndex::nearest_path_point(
    const Eigen::Vector2d& p, std::span<const std::int64_t> drives) const {
  std::optional<Eigen::Vector2d> best;
  double best_d = std::numeric_limits<double>::infinity();
  for (const DrivePass& pass : passes_) {
    if (!std::binary_search(drives.begin(), drives.end(), pass.drive)) continue;
    for (std::size_t k = 0; k < pass.path_m.size(); ++k) {
      const Eigen::Vector2d a = pass.path_m[k];
      const Eigen::Vector2d b = k + 1 < pass.path_m.size() ? pass.path_m[k + 1] : a;
      const Eigen::Vector2d ab = b - a;
      const double l2 = ab.squaredNorm();
      const double t = l2 > 0.0 ? std::clamp((p - a).dot(ab) / l2, 0.0, 1.0) : 0.0;
      const Eigen::Vector2d q = a + t * ab;
      if ((q - p).norm() < best_d) {
        best_d = (q - p).norm();
        best = q;
      }
    }
  }
  return best;
}

std::vector<std::int64_t> VisibilityIndex::drives_crossing(const Eigen::Vector2d& a,
                                                           const Eigen::Vector2d& b) const {
  // A piece that crosses [a, b] is within its pass's range of the crossing point, so it is
  // indexed in that point's cell, one of the cells the segment's box touches.
  std::vector<std::size_t> hit;
  const Eigen::Vector2d lo = a.cwiseMin(b), hi = a.cwiseMax(b);
  const auto cx0 = static_cast<std::int64_t>(std::floor(lo.x() / cell_m_));
  const auto cx1 = static_cast<std::int64_t>(std::floor(hi.x() / cell_m_));
  const auto cy0 = static_cast<std::int64_t>(std::floor(lo.y() / cell_m_));
  const auto cy1 = static_cast<std::int64_t>(std::floor(hi.y() / cell_m_));
  for (auto cx = cx0; cx <= cx1; ++cx) {
    for (auto cy = cy0; cy <= cy1; ++cy) {
      const auto it = cells_.find(cell_key(cx, cy));
      if (it == cells_.end()) continue;
      for (const Piece& piece : it->second) {
        if (segments_intersect(a, b, piece.a, piece.b)) hit.push_back(piece.pass);
      }
    }
  }
  std::vector<std::int64_t> out;
  for (std::size_t i : hit) out.push_back(passes_[i].drive);
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

std::optional<std::size_t> VisibilityIndex::count_passes_as_close(
    std::span<const Eigen::Vector2d> places, std::span<const std::int64_t> drives) const {
  std::vector<double> dist(passes_.size(), std::numeric_limits<double>::infinity());
  for (std::size_t k = 0; k < passes_.size(); ++k) {
    for (const Eigen::Vector2d& q : places) {
      dist[k] = std::min(dist[k], point_polyline_distance(q, passes_[k].path_m));
    }
  }
  double bar = 0.0;
  for (std::int64_t d : drives) {
    const auto it = std::find_if(passes_.begin(), passes_.end(),
                                 [&](const DrivePass& q) { return q.drive == d; });
    if (it == passes_.end()) return std::nullopt;
    bar = std::max(bar, dist[static_cast<std::size_t>(it - passes_.begin())]);
  }
  std::size_t close = 0;
  for (double d : dist) close += d <= bar + 1e-9 ? 1U : 0U;
  return close;
}

}  // namespace polmap::mapping
