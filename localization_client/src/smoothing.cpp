#include "polmap/localization_client/smoothing.hpp"

#include <algorithm>
#include <limits>
#include <set>

namespace polmap::loc {

std::vector<Assignment> min_cost_assignment(const Eigen::MatrixXd& cost) {
  const bool transpose = cost.rows() > cost.cols();
  const Eigen::MatrixXd a = transpose ? Eigen::MatrixXd(cost.transpose()) : cost;
  const int n = static_cast<int>(a.rows()), m = static_cast<int>(a.cols());
  std::vector<Assignment> out;
  if (n == 0) return out;
  // Kuhn-Munkres with row/column potentials u, v (1-based; column 0 is a
  // virtual column holding the row being inserted). Each row insertion runs a
  // Dijkstra-like search for the shortest augmenting path in reduced costs.
  constexpr double kInf = std::numeric_limits<double>::infinity();
  std::vector<double> u(n + 1, 0.0), v(m + 1, 0.0);
  std::vector<int> p(m + 1, 0), way(m + 1, 0);
  for (int i = 1; i <= n; ++i) {
    p[0] = i;
    int j0 = 0;
    std::vector<double> minv(m + 1, kInf);
    std::vector<bool> used(m + 1, false);
    do {
      used[j0] = true;
      const int i0 = p[j0];
      double delta = kInf;
      int j1 = 0;
      for (int j = 1; j <= m; ++j) {
        if (used[j]) continue;
        const double cur = a(i0 - 1, j - 1) - u[i0] - v[j];
        if (cur < minv[j]) {
          minv[j] = cur;
          way[j] = j0;
        }
        if (minv[j] < delta) {
          delta = minv[j];
          j1 = j;
        }
      }
      for (int j = 0; j <= m; ++j) {
        if (used[j]) {
          u[p[j]] += delta;
          v[j] -= delta;
        } else {
          minv[j] -= delta;
        }
      }
      j0 = j1;
    } while (p[j0] != 0);
    do {
      const int j1 = way[j0];
      p[j0] = p[j1];
      j0 = j1;
    } while (j0 != 0);
  }
  for (int j = 1; j <= m; ++j) {
    if (p[j] == 0) continue;
    out.push_back(transpose ? Assignment{j - 1, p[j] - 1} : Assignment{p[j] - 1, j - 1});
  }
  std::sort(out.begin(), out.end(),
            [](const Assignment& x, const Assignment& y) { return x.row < y.row; });
  return out;
}

std::vector<Assignment> max_weight_matching(const Eigen::MatrixXd& weight) {
  // Leaving a vertex unmatched costs nothing, so non-positive weights are
  // clamped to 0 and the problem becomes a complete assignment of -weight on
  // the (rectangular) matrix: every row or column of the smaller side gets a
  // partner, zero-weight partners are dropped afterwards.
  const Eigen::MatrixXd cost = -weight.cwiseMax(0.0);
  std::vector<Assignment> out;
  for (const Assignment& a : min_cost_assignment(cost)) {
    if (weight(a.row, a.col) > 0.0) out.push_back(a);
  }
  return out;
}

AssociationSmoother::AssociationSmoother(SmoothingConfig cfg) : cfg_(cfg) {}

void AssociationSmoother::add_votes(
    const std::vector<std::pair<std::uint64_t, std::int64_t>>& cluster_landmark) {
  if (cfg_.decay < 1.0) {
    for (auto it = counts_.begin(); it != counts_.end();) {
      for (auto jt = it->second.begin(); jt != it->second.end();) {
        jt->second *= cfg_.decay;
        jt = jt->second < 1e-3 ? it->second.erase(jt) : std::next(jt);
      }
      it = it->second.empty() ? counts_.erase(it) : std::next(it);
    }
  }
  for (const auto& [cluster, landmark] : cluster_landmark) counts_[cluster][landmark] += 1.0;
}

void AssociationSmoother::retain_clusters(const std::vector<std::uint64_t>& alive_cluster_ids) {
  const std::set<std::uint64_t> alive(alive_cluster_ids.begin(), alive_cluster_ids.end());
  for (auto it = counts_.begin(); it != counts_.end();) {
    it = alive.contains(it->first) ? std::next(it) : counts_.erase(it);
  }
}

double AssociationSmoother::count(std::uint64_t cluster_id, std::int64_t landmark_id) const {
  const auto it = counts_.find(cluster_id);
  if (it == counts_.end()) return 0.0;
  const auto jt = it->second.find(landmark_id);
  return jt == it->second.end() ? 0.0 : jt->second;
}

std::vector<ClusterAssociation> AssociationSmoother::smoothed() const {
  std::vector<std::uint64_t> clusters;
  std::vector<std::int64_t> landmarks;
  for (const auto& [c, per] : counts_) {
    bool any = false;
    for (const auto& [l, n] : per) {
      if (n >= cfg_.min_count) {
        landmarks.push_back(l);
        any = true;
      }
    }
    if (any) clusters.push_back(c);
  }
  std::sort(landmarks.begin(), landmarks.end());
  landmarks.erase(std::unique(landmarks.begin(), landmarks.end()), landmarks.end());
  std::vector<ClusterAssociation> out;
  if (clusters.empty()) return out;
  Eigen::MatrixXd w = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(clusters.size()),
                                            static_cast<Eigen::Index>(landmarks.size()));
  for (std::size_t r = 0; r < clusters.size(); ++r) {
    for (const auto& [l, n] : counts_.at(clusters[r])) {
      if (n < cfg_.min_count) continue;
      const auto c = std::lower_bound(landmarks.begin(), landmarks.end(), l) - landmarks.begin();
      w(static_cast<Eigen::Index>(r), c) = n;
    }
  }
  for (const Assignment& a : max_weight_matching(w)) {
    out.push_back({clusters[a.row], landmarks[a.col], w(a.row, a.col)});
  }
  return out;
}

}  // namespace polmap::loc
