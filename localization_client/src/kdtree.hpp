#pragma once
// Private: a 2-D k-d tree (nanoflann) over a vector of points, for radius and
// nearest-neighbour queries. Not part of the public API (nanoflann is a
// private dependency of polmap_localization_client).
#include <Eigen/Core>
#include <memory>
#include <nanoflann.hpp>
#include <optional>
#include <utility>
#include <vector>

namespace polmap::loc::detail {

class KdTree2 {
 public:
  explicit KdTree2(std::vector<Eigen::Vector2d> points) : cloud_{std::move(points)} {
    index_ = std::make_unique<Index>(2, cloud_, nanoflann::KDTreeSingleIndexAdaptorParams(10));
    if (!cloud_.pts.empty()) index_->buildIndex();
  }
  KdTree2(const KdTree2&) = delete;
  KdTree2& operator=(const KdTree2&) = delete;

  [[nodiscard]] std::size_t size() const { return cloud_.pts.size(); }
  [[nodiscard]] const Eigen::Vector2d& point(std::size_t i) const { return cloud_.pts[i]; }

  /// Indices of all points within radius_m of q (inclusive), unsorted.
  void radius(const Eigen::Vector2d& q, double radius_m, std::vector<std::size_t>& out) const {
    out.clear();
    if (cloud_.pts.empty()) return;
    std::vector<std::pair<std::size_t, double>> hits;
    nanoflann::SearchParams params;
    params.sorted = false;
    const double query[2] = {q.x(), q.y()};
    // nanoflann's L2 metric works on squared distances; pad by one ulp-ish so
    // points exactly at the radius are kept (matches a <= brute-force test).
    index_->radiusSearch(query, radius_m * radius_m * (1.0 + 1e-12) + 1e-18, hits, params);
    out.reserve(hits.size());
    for (const auto& h : hits) out.push_back(h.first);
  }

  /// Nearest point: (index, distance); index = size() if empty.
  [[nodiscard]] std::pair<std::size_t, double> nearest(const Eigen::Vector2d& q) const {
    if (cloud_.pts.empty()) return {0, 0.0};
    std::size_t idx = 0;
    double d2 = 0.0;
    nanoflann::KNNResultSet<double, std::size_t> rs(1);
    rs.init(&idx, &d2);
    const double query[2] = {q.x(), q.y()};
    index_->findNeighbors(rs, query, nanoflann::SearchParams());
    return {idx, std::sqrt(d2)};
  }

  /// Nearest point if one lies within max_m of q (inclusive): the same point as
  /// nearest(), but the search prunes every branch beyond max_m, which is most of the
  /// tree for a query far from every point.
  [[nodiscard]] std::optional<std::pair<std::size_t, double>> nearest_within(
      const Eigen::Vector2d& q, double max_m) const {
    if (cloud_.pts.empty()) return std::nullopt;
    std::size_t idx = 0;
    double d2 = 0.0;
    nanoflann::KNNResultSet<double, std::size_t> rs(1);
    rs.init(&idx, &d2);
    // The bound: only closer points are added. Padded like radius(), so a point at
    // exactly max_m (whose squared distance may round either way) is kept.
    d2 = max_m * max_m * (1.0 + 1e-12) + 1e-18;
    const double query[2] = {q.x(), q.y()};
    index_->findNeighbors(rs, query, nanoflann::SearchParams());
    if (rs.size() == 0) return std::nullopt;
    return std::pair{idx, std::sqrt(d2)};
  }

 private:
  struct Cloud {
    std::vector<Eigen::Vector2d> pts;
    [[nodiscard]] std::size_t kdtree_get_point_count() const { return pts.size(); }
    [[nodiscard]] double kdtree_get_pt(std::size_t i, std::size_t dim) const { return pts[i][dim]; }
    template <class BBox>
    bool kdtree_get_bbox(BBox& /*bb*/) const {
      return false;
    }
  };
  using Index = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Cloud>,
                                                    Cloud, 2, std::size_t>;
  Cloud cloud_;
  std::unique_ptr<Index> index_;
};

}  // namespace polmap::loc::detail
