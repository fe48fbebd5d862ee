#include "polmap/localization_client/matcher.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <unordered_set>

#include "kdtree.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::loc {

// ---------------------------------------------------------------------------
// MapIndex

namespace {
/// Edge sample spacing for the edge k-d tree: a point within r of an edge is
/// within r + spacing / 2 of one of its samples.
constexpr double kEdgeSampleSpacingM = 2.0;
}  // namespace

struct MapIndex::Trees {
  detail::KdTree2 points;
  detail::KdTree2 edge_samples;
  Trees(std::vector<Eigen::Vector2d> p, std::vector<Eigen::Vector2d> s)
      : points(std::move(p)), edge_samples(std::move(s)) {}
};

MapIndex::MapIndex() : MapIndex({}, {}) {}
MapIndex::~MapIndex() = default;
MapIndex::MapIndex(MapIndex&&) noexcept = default;
MapIndex& MapIndex::operator=(MapIndex&&) noexcept = default;

MapIndex::MapIndex(std::vector<PointLandmark> points, std::vector<LineLandmark> lines)
    : points_(std::move(points)), lines_(std::move(lines)) {
  std::vector<Eigen::Vector2d> pts, samples;
  pts.reserve(points_.size());
  for (std::size_t i = 0; i < points_.size(); ++i) {
    pts.push_back(points_[i].position_m);
    point_by_id_[points_[i].id] = i;
  }
  for (std::size_t li = 0; li < lines_.size(); ++li) {
    line_by_id_[lines_[li].id] = li;
    const auto& poly = lines_[li].polyline_m;
    for (std::size_t k = 0; k + 1 < poly.size(); ++k) {
      const Segment2 seg{poly[k], poly[k + 1]};
      const std::size_t e = edges_.size();
      edges_.push_back({li, static_cast<int>(k), seg});
      const int n = std::max(1, static_cast<int>(std::ceil(seg.length_m() / kEdgeSampleSpacingM)));
      for (int s = 0; s <= n; ++s) {
        samples.push_back(seg.a_m + (seg.b_m - seg.a_m) * (static_cast<double>(s) / n));
        sample_edge_.push_back(e);
      }
    }
  }
  trees_ = std::make_unique<Trees>(std::move(pts), std::move(samples));
}

void MapIndex::points_within(const Eigen::Vector2d& q, double radius_m,
                             std::vector<std::size_t>& out) const {
  trees_->points.radius(q, radius_m, out);
}

std::optional<std::pair<std::size_t, double>> MapIndex::nearest_point(
    const Eigen::Vector2d& q) const {
  if (points_.empty()) return std::nullopt;
  return trees_->points.nearest(q);
}

std::optional<std::pair<std::size_t, double>> MapIndex::nearest_point_within(
    const Eigen::Vector2d& q, double max_m) const {
  return trees_->points.nearest_within(q, max_m);
}

void MapIndex::edges_near(const Eigen::Vector2d& q, double radius_m,
                          std::vector<std::size_t>& out) const {
  std::vector<std::size_t> hits;
  trees_->edge_samples.radius(q, radius_m + 0.5 * kEdgeSampleSpacingM + 1e-9, hits);
  out.clear();
  for (std::size_t h : hits) out.push_back(sample_edge_[h]);
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
}

const PointLandmark* MapIndex::find_point(std::int64_t id) const {
  const auto it = point_by_id_.find(id);
  return it == point_by_id_.end() ? nullptr : &points_[it->second];
}

const LineLandmark* MapIndex::find_line(std::int64_t id) const {
  const auto it = line_by_id_.find(id);
  return it == line_by_id_.end() ? nullptr : &lines_[it->second];
}

// ---------------------------------------------------------------------------
// Matching

std::string_view to_string(MatchResult::Status s) {
  switch (s) {
    case MatchResult::Status::Ok:
      return "ok";
    case MatchResult::Status::TooFewClusters:
      return "too_few_clusters";
    case MatchResult::Status::NoCandidate:
      return "no_candidate";
    case MatchResult::Status::TooFewMatches:
      return "too_few_matches";
    case MatchResult::Status::Ambiguous:
      return "ambiguous";
  }
  return "unknown";
}

namespace {

Eigen::Vector2d perp(const Eigen::Vector2d& v) { return {-v.y(), v.x()}; }

/// Rigid transform with l1 -> m1, l2 -> m2 (rotation from the pair
/// directions, translation aligning the midpoints).
Pose2 transform_from_pairs(const Eigen::Vector2d& l1, const Eigen::Vector2d& l2,
                           const Eigen::Vector2d& m1, const Eigen::Vector2d& m2) {
  const Eigen::Vector2d dl = l2 - l1, dm = m2 - m1;
  const double yaw = wrap_angle_rad(std::atan2(dm.y(), dm.x()) - std::atan2(dl.y(), dl.x()));
  Pose2 T{0.0, 0.0, yaw};
  const Eigen::Vector2d t = 0.5 * (m1 + m2) - T.rotation() * (0.5 * (l1 + l2));
  T.x_m = t.x();
  T.y_m = t.y();
  return T;
}

struct Candidate {
  Pose2 T_map_odom;
  Pose2 T_map_vehicle;
  double cost = 0.0;
};

class Scorer {
 public:
  Scorer(std::span<const PointCluster> points, std::span<const LineCluster> lines,
         const MapIndex& map, const MatchPrior& prior, const MatcherConfig& cfg)
      : points_(points), lines_(lines), map_(map), prior_(prior), cfg_(cfg) {
    std::vector<Eigen::Vector2d> centroids;
    for (const auto& c : points_) {
      weights_.push_back(std::min(1.0, c.num_observations / 3.0));
      centroids.push_back(c.centroid_odom_m);
    }
    for (const auto& c : lines_) {
      line_weights_.push_back(cfg_.line_weight * std::min(1.0, c.num_observations / 3.0));
    }
    clusters_tree_ = std::make_unique<detail::KdTree2>(std::move(centroids));
  }

  /// Fixes the map points of the map -> local term: those with a cluster
  /// within coverage_radius_m + gate_radius_m under the prior transform.
  void set_region(const Pose2& T_prior, double gate_radius_m, double view_radius_m) {
    region_.clear();
    if (points_.empty() || cfg_.map_to_local_weight <= 0.0) return;
    const Pose2 inv = T_prior.inverse();
    std::vector<std::size_t> near;
    const Eigen::Vector2d v = T_prior * prior_.T_odom_vehicle.translation();
    map_.points_within(v, view_radius_m, near);
    for (std::size_t m : near) {
      if (clusters_tree_->nearest_within(inv * map_.points()[m].position_m,
                                         cfg_.coverage_radius_m + gate_radius_m)) {
        region_.push_back(m);
      }
    }
  }

  /// Map -> local term (see file comment).
  [[nodiscard]] double map_cost(const Pose2& T) const {
    if (region_.empty()) return 0.0;
    const Pose2 inv = T.inverse();
    const double itr = 1.0 / cfg_.point_truncation_m;
    double cost = 0.0;
    // Truncated at 1: only a cluster within the truncation distance changes the term.
    for (std::size_t m : region_) {
      const auto nn = clusters_tree_->nearest_within(inv * map_.points()[m].position_m,
                                                     cfg_.point_truncation_m);
      const double d = nn ? std::min(nn->second * itr, 1.0) : 1.0;
      cost += d * d;
    }
    return cfg_.map_to_local_weight * cost;
  }

  [[nodiscard]] double point_cost(const Pose2& T) const {
    double cost = 0.0;
    const double inv = 1.0 / cfg_.point_truncation_m;
    for (std::size_t i = 0; i < points_.size(); ++i) {
      const auto nn =
          map_.nearest_point_within(T * points_[i].centroid_odom_m, cfg_.point_truncation_m);
      const double d = nn ? std::min(nn->second * inv, 1.0) : 1.0;
      cost += weights_[i] * d * d;
    }
    return cost;
  }

  /// Best map edge for a transformed line cluster (by hull + projection).
  [[nodiscard]] std::optional<std::pair<std::size_t, LineDistance>> best_edge(
      const Segment2& s_map, double max_sum_m) const {
    map_.edges_near(s_map.midpoint_m(), 0.5 * s_map.length_m() + max_sum_m, edge_buf_);
    std::optional<std::pair<std::size_t, LineDistance>> best;
    for (std::size_t e : edge_buf_) {
      const LineDistance d = line_distance(s_map, map_.edges()[e].segment_m);
      if (d.sum_m() <= max_sum_m && (!best || d.sum_m() < best->second.sum_m())) best = {{e, d}};
    }
    return best;
  }

  [[nodiscard]] static Segment2 apply(const Pose2& T, const Segment2& s) {
    return {T * s.a_m, T * s.b_m};
  }

  /// Points + lines + unmatched-map penalty.
  [[nodiscard]] double full_cost(const Pose2& T) const {
    double cost = point_cost(T);
    if (cfg_.use_lines) {
      const double inv = 1.0 / cfg_.line_truncation_m;
      for (std::size_t j = 0; j < lines_.size(); ++j) {
        const auto be = best_edge(apply(T, lines_[j].segment_odom_m), cfg_.line_truncation_m);
        const double d = be ? std::min(be->second.sum_m() * inv, 1.0) : 1.0;
        cost += line_weights_[j] * d * d;
      }
    }
    return cost + map_cost(T);
  }

  /// ICP-style Gauss-Newton on point-to-point and end-point-to-line residuals,
  /// linearized about the vehicle position so yaw pivots there.
  [[nodiscard]] Pose2 refine(Pose2 T) const {
    const Eigen::Vector2d c_odom = prior_.T_odom_vehicle.translation();
    for (int it = 0; it < cfg_.refine_iterations; ++it) {
      const Eigen::Vector2d c_map = T * c_odom;
      Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
      Eigen::Vector3d g = Eigen::Vector3d::Zero();
      int n = 0;
      for (std::size_t i = 0; i < points_.size(); ++i) {
        const Eigen::Vector2d p = T * points_[i].centroid_odom_m;
        const auto nn = map_.nearest_point_within(p, cfg_.point_truncation_m);
        if (!nn) continue;
        const Eigen::Vector2d r = p - map_.points()[nn->first].position_m;
        Eigen::Matrix<double, 2, 3> J;
        J << 1, 0, perp(p - c_map).x(), 0, 1, perp(p - c_map).y();
        H += weights_[i] * J.transpose() * J;
        g += weights_[i] * J.transpose() * r;
        ++n;
      }
      if (!region_.empty()) {
        const Pose2 inv = T.inverse();
        for (std::size_t m : region_) {
          const Eigen::Vector2d& pm = map_.points()[m].position_m;
          const auto within = clusters_tree_->nearest_within(inv * pm, cfg_.point_truncation_m);
          if (!within) continue;
          const auto& nn = *within;
          const Eigen::Vector2d p = T * points_[nn.first].centroid_odom_m;
          const Eigen::Vector2d r = p - pm;
          Eigen::Matrix<double, 2, 3> J;
          J << 1, 0, perp(p - c_map).x(), 0, 1, perp(p - c_map).y();
          const double w = cfg_.map_to_local_weight * weights_[nn.first];
          H += w * J.transpose() * J;
          g += w * J.transpose() * r;
          ++n;
        }
      }
      if (cfg_.use_lines) {
        for (std::size_t j = 0; j < lines_.size(); ++j) {
          const Segment2 s = apply(T, lines_[j].segment_odom_m);
          const auto be = best_edge(s, cfg_.line_truncation_m);
          if (!be) continue;
          const Segment2& e = map_.edges()[be->first].segment_m;
          const Eigen::Vector2d nrm = perp(e.direction());
          for (const Eigen::Vector2d& q : {s.a_m, s.b_m}) {
            const double r = nrm.dot(q - e.a_m);
            Eigen::RowVector3d J;
            J << nrm.x(), nrm.y(), nrm.dot(perp(q - c_map));
            H += line_weights_[j] * J.transpose() * J;
            g += line_weights_[j] * J.transpose() * r;
          }
          ++n;
        }
      }
      if (n == 0) break;
      // Tiny damping keeps directions no residual constrains (a lone straight
      // curb along the road) at their current value.
      H.diagonal().array() += 1e-6 * (H.trace() / 3.0 + 1e-3);
      const Eigen::Vector3d delta = -H.ldlt().solve(g);
      if (!delta.allFinite()) break;
      const Pose2 D{0.0, 0.0, delta.z()};
      const Eigen::Vector2d t = c_map + delta.head<2>() - D.rotation() * c_map;
      T = Pose2{t.x(), t.y(), delta.z()} * T;
      if (delta.head<2>().norm() < 1e-4 && std::abs(delta.z()) < 1e-5) break;
    }
    return T;
  }

  void associations(const Pose2& T, MatchResult& out) const {
    // Points: mutual nearest neighbours within the association distance.
    out.points.clear();
    const Pose2 inv = T.inverse();
    for (std::size_t i = 0; i < points_.size(); ++i) {
      const auto nn = map_.nearest_point(T * points_[i].centroid_odom_m);
      if (!nn || nn->second > cfg_.association_distance_m) continue;
      const auto back = clusters_tree_->nearest(inv * map_.points()[nn->first].position_m);
      if (back.first != i) continue;
      out.points.push_back({points_[i].id, map_.points()[nn->first].id, nn->second});
    }
    out.lines.clear();
    if (!cfg_.use_lines) return;
    for (const auto& c : lines_) {
      const auto be = best_edge(apply(T, c.segment_odom_m), cfg_.line_association_distance_m);
      if (!be) continue;
      const auto& e = map_.edges()[be->first];
      out.lines.push_back({c.id, map_.lines()[e.line].id, e.edge, be->second});
    }
  }

 private:
  std::span<const PointCluster> points_;
  std::span<const LineCluster> lines_;
  const MapIndex& map_;
  const MatchPrior& prior_;
  const MatcherConfig& cfg_;
  std::vector<double> weights_, line_weights_;
  std::unique_ptr<detail::KdTree2> clusters_tree_;
  std::vector<std::size_t> region_;  ///< map points of the map -> local term
  mutable std::vector<std::size_t> edge_buf_;
};

bool distinct(const Pose2& a, const Pose2& b, const MatcherConfig& cfg) {
  return (a.translation() - b.translation()).norm() > cfg.distinct_translation_m ||
         std::abs(wrap_angle_rad(a.yaw_rad - b.yaw_rad)) > cfg.distinct_yaw_rad;
}

}  // namespace

MatchResult match_local_map(std::span<const PointCluster> points_odom,
                            std::span<const LineCluster> lines_odom, const MapIndex& map,
                            const MatchPrior& prior, const MatcherConfig& cfg) {
  MatchResult result;
  if (points_odom.empty() && (lines_odom.empty() || !cfg.use_lines)) {
    result.status = MatchResult::Status::TooFewClusters;
    return result;
  }
  const Pose2 prior_vehicle = prior.T_map_odom * prior.T_odom_vehicle;
  const Eigen::Matrix3d info = prior.covariance.inverse();
  auto gate_ok = [&](const Pose2& T_map_vehicle) {
    const Eigen::Vector3d d(T_map_vehicle.x_m - prior_vehicle.x_m,
                            T_map_vehicle.y_m - prior_vehicle.y_m,
                            wrap_angle_rad(T_map_vehicle.yaw_rad - prior_vehicle.yaw_rad));
    return d.dot(info * d) <= cfg.gate_chi2;
  };

  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(prior.covariance.topLeftCorner<2, 2>());
  const double var_xy = std::max(es.eigenvalues().maxCoeff(), 0.0);
  const double var_yaw = std::max(prior.covariance(2, 2), 0.0);
  const double k = std::sqrt(cfg.gate_chi2);
  Scorer scorer(points_odom, lines_odom, map, prior, cfg);
  // Map points near the observed area (radar range plus margin around the vehicle).
  scorer.set_region(prior.T_map_odom,
                    std::min(k * std::sqrt(var_xy + var_yaw * 60.0 * 60.0), cfg.max_gate_radius_m),
                    90.0);
  std::vector<Candidate> candidates;
  std::unordered_set<std::uint64_t> seen;
  auto consider = [&](const Pose2& T) {
    const Pose2 Tv = T * prior.T_odom_vehicle;
    if (!gate_ok(Tv)) return;
    // Quantized vehicle pose as a duplicate key (0.1 m, ~0.06°).
    const auto q = [](double v, double step) {
      return static_cast<std::uint64_t>(static_cast<std::int64_t>(std::floor(v / step)) & 0x1FFFFF);
    };
    const std::uint64_t key =
        (q(Tv.x_m, 0.1) << 42) | (q(Tv.y_m, 0.1) << 21) | q(Tv.yaw_rad, 0.001);
    if (!seen.insert(key).second) return;
    candidates.push_back({T, Tv, scorer.point_cost(T) + scorer.map_cost(T)});
  };
  consider(prior.T_map_odom);

  // Anchors: the most-observed clusters.
  std::vector<std::size_t> anchors;
  for (std::size_t i = 0; i < points_odom.size(); ++i) {
    if (points_odom[i].num_observations >= cfg.min_anchor_observations) anchors.push_back(i);
  }
  std::stable_sort(anchors.begin(), anchors.end(), [&](std::size_t a, std::size_t b) {
    return points_odom[a].num_observations > points_odom[b].num_observations;
  });
  if (anchors.size() > static_cast<std::size_t>(cfg.max_anchor_clusters)) {
    anchors.resize(cfg.max_anchor_clusters);
  }
  // Map candidates per anchor inside its predicted position's gate radius.
  std::vector<std::vector<std::size_t>> cand(anchors.size());
  for (std::size_t a = 0; a < anchors.size(); ++a) {
    const Eigen::Vector2d p = prior.T_map_odom * points_odom[anchors[a]].centroid_odom_m;
    const double lever2 = (p - prior_vehicle.translation()).squaredNorm();
    const double r = std::min(k * std::sqrt(var_xy + var_yaw * lever2), cfg.max_gate_radius_m) +
                     cfg.pair_distance_tolerance_m;
    map.points_within(p, r, cand[a]);
  }
  bool capped = false;
  for (std::size_t a = 0; a < anchors.size() && !capped; ++a) {
    for (std::size_t b = a + 1; b < anchors.size() && !capped; ++b) {
      const Eigen::Vector2d& l1 = points_odom[anchors[a]].centroid_odom_m;
      const Eigen::Vector2d& l2 = points_odom[anchors[b]].centroid_odom_m;
      const double dl = (l2 - l1).norm();
      if (dl < cfg.min_pair_baseline_m) continue;
      for (std::size_t m1 : cand[a]) {
        for (std::size_t m2 : cand[b]) {
          if (m1 == m2) continue;
          const Eigen::Vector2d& p1 = map.points()[m1].position_m;
          const Eigen::Vector2d& p2 = map.points()[m2].position_m;
          if (std::abs((p2 - p1).norm() - dl) > cfg.pair_distance_tolerance_m) continue;
          consider(transform_from_pairs(l1, l2, p1, p2));
          if (static_cast<int>(candidates.size()) >= cfg.max_candidates) capped = true;
        }
      }
    }
  }
  if (cfg.use_voting && !capped && !points_odom.empty() && !map.points().empty()) {
    // Correlative generator: per yaw hypothesis, clusters vote for translations.
    const double yaw_half = k * std::sqrt(var_yaw);
    int n_yaw = static_cast<int>(std::floor(yaw_half / cfg.yaw_step_rad));
    const int max_half = std::max(0, (cfg.max_yaw_hypotheses - 1) / 2);
    const double step = n_yaw > max_half ? yaw_half / std::max(max_half, 1) : cfg.yaw_step_rad;
    n_yaw = std::min(n_yaw, max_half);
    const Eigen::Vector2d v = prior_vehicle.translation();
    std::vector<Eigen::Vector2d> predicted;
    std::vector<double> lever;
    for (const auto& c : points_odom) {
      predicted.push_back(prior.T_map_odom * c.centroid_odom_m);
      lever.push_back((predicted.back() - v).norm());
    }
    struct Peak {
      double votes;
      double dyaw;
      Eigen::Vector2d dt;
    };
    std::vector<Peak> peaks;
    // Translation histogram: a dense grid over the gate (every vote's offset lies within
    // r of zero), cleared through the list of touched bins, visited in row-major order.
    const double gate = k * std::sqrt(var_xy);
    const double r =
        (std::isfinite(gate) ? std::min(gate, cfg.max_gate_radius_m) : cfg.max_gate_radius_m) +
        cfg.pair_distance_tolerance_m;
    const double inv_cell = 1.0 / cfg.vote_cell_m;
    const int half = static_cast<int>(std::ceil(r * inv_cell)) + 2;  // + the 3×3 border
    const int side = 2 * half + 1;
    std::vector<double> hist(static_cast<std::size_t>(side) * side, 0.0);
    std::vector<int> touched;
    std::vector<std::size_t> near;
    for (int iy = -n_yaw; iy <= n_yaw; ++iy) {
      const double dyaw = iy * step;
      const Eigen::Matrix2d R = Pose2{0, 0, dyaw}.rotation();
      for (int b : touched) hist[b] = 0.0;
      touched.clear();
      for (std::size_t i = 0; i < points_odom.size(); ++i) {
        const Eigen::Vector2d p = R * (predicted[i] - v) + v;
        // Gate radius of the translation (rotation is fixed per hypothesis).
        map.points_within(p, r, near);
        const double w = std::min(1.0, points_odom[i].num_observations / 3.0);
        for (std::size_t m : near) {
          const Eigen::Vector2d dt = map.points()[m].position_m - p;
          const int bx = static_cast<int>(std::floor(dt.x() * inv_cell)) + half;
          const int by = static_cast<int>(std::floor(dt.y() * inv_cell)) + half;
          POLMAP_EXPECT(bx >= 1 && by >= 1 && bx < side - 1 && by < side - 1);
          const int b = by * side + bx;
          if (hist[b] == 0.0) touched.push_back(b);
          hist[b] += w;
        }
      }
      std::sort(touched.begin(), touched.end());
      // Peaks of the 3×3 neighbourhood sums (an offset may straddle bins);
      // the best few distinct ones per yaw, so a second mode (a repetitive
      // post row) survives as a runner-up.
      constexpr int kPeaksPerYaw = 3;
      std::vector<Peak> best;
      for (int b : touched) {
        const int bx = b % side, by = b / side;
        double sum = 0.0;
        for (int dx = -1; dx <= 1; ++dx) {
          for (int dy = -1; dy <= 1; ++dy) sum += hist[(by + dy) * side + bx + dx];
        }
        if (best.size() == kPeaksPerYaw && sum <= best.back().votes) continue;
        const Peak pk{sum, dyaw,
                      Eigen::Vector2d((bx - half + 0.5) * cfg.vote_cell_m,
                                      (by - half + 0.5) * cfg.vote_cell_m)};
        // Replace a weaker peak nearby, else insert.
        bool merged = false;
        for (auto& b : best) {
          if ((b.dt - pk.dt).norm() <= cfg.distinct_translation_m) {
            if (pk.votes > b.votes) b = pk;
            merged = true;
            break;
          }
        }
        if (!merged) best.push_back(pk);
        std::sort(best.begin(), best.end(),
                  [](const Peak& a, const Peak& b) { return a.votes > b.votes; });
        if (best.size() > kPeaksPerYaw) best.resize(kPeaksPerYaw);
      }
      peaks.insert(peaks.end(), best.begin(), best.end());
    }
    std::sort(peaks.begin(), peaks.end(),
              [](const Peak& a, const Peak& b) { return a.votes > b.votes; });
    if (peaks.size() > static_cast<std::size_t>(cfg.vote_peaks)) peaks.resize(cfg.vote_peaks);
    for (const Peak& pk : peaks) {
      // p -> R(dyaw) (p - v) + v + dt, composed onto the prior.
      const Pose2 D{0.0, 0.0, pk.dyaw};
      const Eigen::Vector2d t = v + pk.dt - D.rotation() * v;
      consider(Pose2{t.x(), t.y(), pk.dyaw} * prior.T_map_odom);
    }
  }
  result.candidates_scored = static_cast<int>(candidates.size());
  if (candidates.empty()) {
    result.status = MatchResult::Status::NoCandidate;
    return result;
  }

  // Non-maximum suppression, then refine the best distinct candidates.
  std::sort(candidates.begin(), candidates.end(),
            [](const Candidate& a, const Candidate& b) { return a.cost < b.cost; });
  std::vector<Candidate> top;
  for (const auto& c : candidates) {
    if (static_cast<int>(top.size()) >= cfg.refine_top_k) break;
    bool dup = false;
    for (const auto& t : top) dup = dup || !distinct(c.T_map_vehicle, t.T_map_vehicle, cfg);
    if (!dup) top.push_back(c);
  }
  for (auto& c : top) {
    const Pose2 refined = scorer.refine(c.T_map_odom);
    const Pose2 Tv = refined * prior.T_odom_vehicle;
    // A refinement that walked out of the gate keeps its unrefined pose.
    if (gate_ok(Tv)) {
      c.T_map_odom = refined;
      c.T_map_vehicle = Tv;
    }
    c.cost = scorer.full_cost(c.T_map_odom);
  }
  std::sort(top.begin(), top.end(),
            [](const Candidate& a, const Candidate& b) { return a.cost < b.cost; });
  const Candidate& best = top.front();
  for (std::size_t i = 1; i < top.size(); ++i) {
    if (distinct(top[i].T_map_vehicle, best.T_map_vehicle, cfg)) {
      result.runner_up_cost = top[i].cost;
      break;
    }
  }
  result.T_map_odom = best.T_map_odom;
  result.cost = best.cost;
  scorer.associations(best.T_map_odom, result);
  if (result.effective_matches() < cfg.min_point_matches) {
    result.status = MatchResult::Status::TooFewMatches;
  } else if (result.runner_up_cost && *result.runner_up_cost - best.cost < cfg.ambiguity_margin) {
    result.status = MatchResult::Status::Ambiguous;
  } else {
    result.status = MatchResult::Status::Ok;
  }
  return result;
}

}  // namespace polmap::loc
