#include "polmap/localization_client/local_map.hpp"

#include <algorithm>
#include <limits>
#include <map>
#include <numeric>

#include "kdtree.hpp"

namespace polmap::loc {
namespace {

struct UnionFind {
  explicit UnionFind(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  std::size_t find(std::size_t i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  }
  void unite(std::size_t a, std::size_t b) {
    a = find(a);
    b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
  std::vector<std::size_t> parent;
};

/// Canonical labels: components numbered by their smallest member index.
std::vector<int> labels_of(UnionFind& uf) {
  const std::size_t n = uf.parent.size();
  std::vector<int> label(n, -1), root_label(n, -1);
  int next = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t r = uf.find(i);
    if (root_label[r] < 0) root_label[r] = next++;
    label[i] = root_label[r];
  }
  return label;
}

/// Stable ids: each new component takes the previous id most of its members
/// had; when a previous cluster split, the part with the most of its members
/// keeps the id and the others get fresh ids.
template <class Cluster>
void assign_stable_ids(std::vector<Cluster>& clusters, const std::vector<std::uint64_t>& prev_id,
                       std::uint64_t& next_id) {
  struct Vote {
    std::size_t cluster;
    std::uint64_t id;
    int count;
  };
  std::vector<Vote> votes;
  for (std::size_t c = 0; c < clusters.size(); ++c) {
    std::map<std::uint64_t, int> counts;
    for (std::size_t m : clusters[c].members) {
      if (prev_id[m] != 0) ++counts[prev_id[m]];
    }
    for (const auto& [id, n] : counts) votes.push_back({c, id, n});
  }
  std::sort(votes.begin(), votes.end(), [](const Vote& a, const Vote& b) {
    return a.count != b.count ? a.count > b.count
                              : (a.id != b.id ? a.id < b.id : a.cluster < b.cluster);
  });
  std::vector<bool> done(clusters.size(), false);
  std::map<std::uint64_t, bool> taken;
  for (const Vote& v : votes) {
    if (done[v.cluster] || taken[v.id]) continue;
    clusters[v.cluster].id = v.id;
    done[v.cluster] = true;
    taken[v.id] = true;
  }
  for (std::size_t c = 0; c < clusters.size(); ++c) {
    if (!done[c]) clusters[c].id = next_id++;
  }
}

}  // namespace

bool segments_linked(const Segment2& s, const Segment2& t, const LineLinkConfig& cfg) {
  if (segment_distance(s, t) > cfg.gate_distance_m) return false;
  const LineDistance d = line_distance(s, t);
  return d.hull_m <= cfg.hull_distance_m && d.projection_m <= cfg.projection_distance_m;
}

std::vector<int> cluster_points(std::span<const Eigen::Vector2d> points, double link_distance_m) {
  UnionFind uf(points.size());
  detail::KdTree2 tree(std::vector<Eigen::Vector2d>(points.begin(), points.end()));
  std::vector<std::size_t> hits;
  for (std::size_t i = 0; i < points.size(); ++i) {
    tree.radius(points[i], link_distance_m, hits);
    for (std::size_t j : hits) {
      // The padded k-d radius may admit points a rounding error beyond the
      // threshold; the exact test keeps the result equal to brute force.
      if (j != i && (points[i] - points[j]).norm() <= link_distance_m) uf.unite(i, j);
    }
  }
  return labels_of(uf);
}

std::vector<int> cluster_segments(std::span<const Segment2> segments, const LineLinkConfig& cfg) {
  UnionFind uf(segments.size());
  std::vector<Eigen::Vector2d> mids;
  mids.reserve(segments.size());
  double max_len = 0.0;
  for (const auto& s : segments) {
    mids.push_back(s.midpoint_m());
    max_len = std::max(max_len, s.length_m());
  }
  detail::KdTree2 tree(mids);
  std::vector<std::size_t> hits;
  for (std::size_t i = 0; i < segments.size(); ++i) {
    // Any point of a segment is within len/2 of its midpoint, so linked
    // segments (distance <= gate) have midpoints within this radius.
    const double r = 0.5 * (segments[i].length_m() + max_len) + cfg.gate_distance_m + 1e-9;
    tree.radius(mids[i], r, hits);
    for (std::size_t j : hits) {
      if (j > i && uf.find(i) != uf.find(j) && segments_linked(segments[i], segments[j], cfg)) {
        uf.unite(i, j);
      }
    }
  }
  return labels_of(uf);
}

LocalMap::LocalMap(LocalMapConfig cfg) : cfg_(cfg) {}

void LocalMap::clear() {
  points_.clear();
  lines_.clear();
  point_prev_id_.clear();
  line_prev_id_.clear();
  point_label_.clear();
  line_label_.clear();
  point_clusters_.clear();
  line_clusters_.clear();
}

void LocalMap::add(double time_s, std::span<const PointCandidate> points_odom,
                   std::span<const LineCandidate> lines_odom) {
  add_impl(time_s, nullptr, points_odom, lines_odom);
}

void LocalMap::add(double time_s, const Pose2& T_odom_vehicle,
                   std::span<const PointCandidate> points_odom,
                   std::span<const LineCandidate> lines_odom) {
  add_impl(time_s, &T_odom_vehicle, points_odom, lines_odom);
}

void LocalMap::add_impl(double time_s, const Pose2* T_odom_vehicle,
                        std::span<const PointCandidate> points_odom,
                        std::span<const LineCandidate> lines_odom) {
  const std::uint64_t extraction = next_extraction_++;
  // Remember cluster ids before truncation so ids survive.
  for (std::size_t i = 0; i < points_.size(); ++i) {
    point_prev_id_[i] = point_clusters_[point_label_[i]].id;
  }
  for (std::size_t i = 0; i < lines_.size(); ++i) {
    line_prev_id_[i] = line_clusters_[line_label_[i]].id;
  }
  const double cutoff_s = time_s - cfg_.window_s;
  auto truncate = [cutoff_s](auto& obs, std::vector<std::uint64_t>& prev) {
    std::size_t w = 0;
    for (std::size_t r = 0; r < obs.size(); ++r) {
      if (obs[r].time_s >= cutoff_s) {
        obs[w] = obs[r];
        prev[w] = prev[r];
        ++w;
      }
    }
    obs.resize(w);
    prev.resize(w);
  };
  truncate(points_, point_prev_id_);
  truncate(lines_, line_prev_id_);
  for (const auto& p : points_odom) {
    const double range =
        T_odom_vehicle ? (p.position_m - T_odom_vehicle->translation()).norm() : 0.0;
    points_.push_back({time_s, extraction, p.position_m, range, p.scattering, p.strength});
    point_prev_id_.push_back(0);
  }
  for (const auto& l : lines_odom) {
    lines_.push_back({time_s, extraction, {l.start_m, l.end_m}, l.strength});
    line_prev_id_.push_back(0);
  }
  recluster();
}

void LocalMap::recluster() {
  const std::uint64_t latest = next_extraction_ - 1;
  constexpr double all = -std::numeric_limits<double>::infinity();
  const auto members_by_label = [](const std::vector<int>& label) {
    const int k = label.empty() ? 0 : *std::max_element(label.begin(), label.end()) + 1;
    std::vector<std::vector<std::size_t>> members(k);
    for (std::size_t i = 0; i < label.size(); ++i) members[label[i]].push_back(i);
    return members;
  };
  {
    std::vector<Eigen::Vector2d> pos;
    pos.reserve(points_.size());
    for (const auto& p : points_) pos.push_back(p.position_odom_m);
    point_label_ = cluster_points(pos, cfg_.point_link_distance_m);
    const auto members = members_by_label(point_label_);
    point_clusters_.assign(members.size(), {});
    for (std::size_t c = 0; c < members.size(); ++c) {
      summarize(members[c], all, latest, point_clusters_[c]);
    }
    assign_stable_ids(point_clusters_, point_prev_id_, next_cluster_id_);
  }
  {
    std::vector<Segment2> segs;
    segs.reserve(lines_.size());
    for (const auto& l : lines_) segs.push_back(l.segment_odom_m);
    line_label_ = cluster_segments(segs, cfg_.line_link);
    const auto members = members_by_label(line_label_);
    line_clusters_.assign(members.size(), {});
    for (std::size_t c = 0; c < members.size(); ++c) {
      summarize(members[c], all, latest, line_clusters_[c]);
    }
    assign_stable_ids(line_clusters_, line_prev_id_, next_cluster_id_);
  }
}

bool LocalMap::summarize(std::span<const std::size_t> members, double since_s, std::uint64_t latest,
                         PointCluster& c) const {
  const double s0 = cfg_.centroid_sigma0_m * cfg_.centroid_sigma0_m;
  const double saz = cfg_.centroid_sigma_azimuth_rad * cfg_.centroid_sigma_azimuth_rad;
  double wsum = 0.0;
  for (std::size_t i : members) {
    const PointObservation& o = points_[i];
    if (o.time_s < since_s) continue;
    if (c.members.empty()) c.first_time_s = c.last_time_s = o.time_s;
    c.members.push_back(i);
    const double w = 1.0 / (s0 + saz * o.range_m * o.range_m);
    c.centroid_odom_m += w * o.position_odom_m;
    wsum += w;
    c.first_time_s = std::min(c.first_time_s, o.time_s);
    c.last_time_s = std::max(c.last_time_s, o.time_s);
    c.observed_latest = c.observed_latest || o.extraction_index == latest;
  }
  if (c.members.empty()) return false;
  c.num_observations = static_cast<int>(c.members.size());
  c.centroid_odom_m /= wsum;
  return true;
}

bool LocalMap::summarize(std::span<const std::size_t> members, double since_s, std::uint64_t latest,
                         LineCluster& c) const {
  std::vector<Segment2> segs;
  for (std::size_t i : members) {
    const LineObservation& o = lines_[i];
    if (o.time_s < since_s) continue;
    if (c.members.empty()) c.first_time_s = c.last_time_s = o.time_s;
    c.members.push_back(i);
    segs.push_back(o.segment_odom_m);
    c.first_time_s = std::min(c.first_time_s, o.time_s);
    c.last_time_s = std::max(c.last_time_s, o.time_s);
    c.observed_latest = c.observed_latest || o.extraction_index == latest;
  }
  if (c.members.empty()) return false;
  c.num_observations = static_cast<int>(c.members.size());
  c.segment_odom_m = merge_segments(segs);
  return true;
}

LocalMap::View LocalMap::recent(double since_s) const {
  const std::uint64_t latest = next_extraction_ - 1;
  View v;
  for (const PointCluster& full : point_clusters_) {
    PointCluster c;
    c.id = full.id;
    if (summarize(full.members, since_s, latest, c)) v.points.push_back(std::move(c));
  }
  for (const LineCluster& full : line_clusters_) {
    LineCluster c;
    c.id = full.id;
    if (summarize(full.members, since_s, latest, c)) v.lines.push_back(std::move(c));
  }
  return v;
}

}  // namespace polmap::loc
