// Temporal smoothing: the Hungarian algorithm equals brute-force optimum
// assignment / maximum-weight matching on small random instances, results are
// injective, and the smoother resolves the paper's "stolen landmark" case.
#include "polmap/localization_client/smoothing.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <functional>
#include <numeric>
#include <random>
#include <set>

namespace polmap::loc {
namespace {

/// Best total over all partial injective matchings (rows may stay unmatched).
double brute_force_max_weight(const Eigen::MatrixXd& w) {
  const int n = static_cast<int>(w.rows()), m = static_cast<int>(w.cols());
  std::vector<bool> used(m, false);
  std::function<double(int)> rec = [&](int r) -> double {
    if (r == n) return 0.0;
    double best = rec(r + 1);  // row r unmatched
    for (int c = 0; c < m; ++c) {
      if (used[c]) continue;
      used[c] = true;
      best = std::max(best, w(r, c) + rec(r + 1));
      used[c] = false;
    }
    return best;
  };
  return rec(0);
}

/// Minimum over complete assignments of the smaller side.
double brute_force_min_cost(const Eigen::MatrixXd& cost) {
  const Eigen::MatrixXd a = cost.rows() <= cost.cols() ? cost : Eigen::MatrixXd(cost.transpose());
  std::vector<int> cols(a.cols());
  std::iota(cols.begin(), cols.end(), 0);
  double best = std::numeric_limits<double>::infinity();
  // Enumerate injective maps rows -> cols via permutations of cols.
  std::sort(cols.begin(), cols.end());
  do {
    double s = 0.0;
    for (int r = 0; r < a.rows(); ++r) s += a(r, cols[r]);
    best = std::min(best, s);
  } while (std::next_permutation(cols.begin(), cols.end()));
  return best;
}

void expect_injective(const std::vector<Assignment>& as) {
  std::set<int> rows, cols;
  for (const auto& a : as) {
    EXPECT_TRUE(rows.insert(a.row).second) << "row used twice";
    EXPECT_TRUE(cols.insert(a.col).second) << "column used twice";
  }
}

/// Adds `rounds` matching results, each with the one association (cluster, landmark).
void vote(AssociationSmoother& s, int rounds, std::uint64_t cluster, std::int64_t landmark) {
  for (int i = 0; i < rounds; ++i) s.add_votes({{cluster, landmark}});
}

TEST(Hungarian, MinCostEqualsBruteForce) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-5.0, 10.0);
  for (int trial = 0; trial < 300; ++trial) {
    const int r = 1 + trial % 6, c = 1 + (trial / 6) % 6;
    Eigen::MatrixXd cost(r, c);
    for (int i = 0; i < r; ++i)
      for (int j = 0; j < c; ++j) cost(i, j) = std::round(u(rng));  // ties on purpose
    const auto as = min_cost_assignment(cost);
    ASSERT_EQ(static_cast<int>(as.size()), std::min(r, c));
    expect_injective(as);
    double s = 0.0;
    for (const auto& a : as) s += cost(a.row, a.col);
    EXPECT_NEAR(s, brute_force_min_cost(cost), 1e-9) << "trial " << trial;
  }
}

TEST(Hungarian, MaxWeightMatchingEqualsBruteForce) {
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int trial = 0; trial < 300; ++trial) {
    const int r = 1 + trial % 6, c = 1 + (trial / 7) % 6;
    Eigen::MatrixXd w(r, c);
    for (int i = 0; i < r; ++i) {
      for (int j = 0; j < c; ++j) {
        // Sparse count-like weights with zeros and negatives (never chosen).
        const double x = u(rng);
        w(i, j) = x < 0.4 ? 0.0 : (x < 0.5 ? -3.0 : std::floor(10.0 * u(rng)));
      }
    }
    const auto as = max_weight_matching(w);
    expect_injective(as);
    double s = 0.0;
    for (const auto& a : as) {
      EXPECT_GT(w(a.row, a.col), 0.0);
      s += w(a.row, a.col);
    }
    EXPECT_NEAR(s, brute_force_max_weight(w), 1e-9) << "trial " << trial;
  }
}

TEST(Hungarian, EmptyAndDegenerate) {
  EXPECT_TRUE(max_weight_matching(Eigen::MatrixXd(0, 3)).empty());
  EXPECT_TRUE(max_weight_matching(Eigen::MatrixXd(3, 0)).empty());
  EXPECT_TRUE(max_weight_matching(Eigen::MatrixXd::Zero(3, 3)).empty());
}

TEST(AssociationSmoother, StolenLandmarkGoesToTheStrongerCluster) {
  // Cluster 1 (a real landmark) is associated with map landmark 100 ten times;
  // cluster 2 (no counterpart in the map) is wrongly associated with 100 three
  // times and with 200 twice. Per-cluster arg-max would give both clusters
  // landmark 100; the injective smoothing gives 100 to cluster 1 and lets
  // cluster 2 take its second choice.
  AssociationSmoother s(SmoothingConfig{.min_count = 2.0, .decay = 1.0});
  vote(s, 10, 1, 100);
  vote(s, 3, 2, 100);
  vote(s, 2, 2, 200);
  vote(s, 1, 3, 300);  // single vote: below min_count
  const auto out = s.smoothed();
  ASSERT_EQ(out.size(), 2U);
  EXPECT_EQ(out[0].cluster_id, 1U);
  EXPECT_EQ(out[0].landmark_id, 100);
  EXPECT_DOUBLE_EQ(out[0].count, 10.0);
  EXPECT_EQ(out[1].cluster_id, 2U);
  EXPECT_EQ(out[1].landmark_id, 200);

  s.retain_clusters({2, 3});
  const auto after = s.smoothed();
  ASSERT_EQ(after.size(), 1U);
  EXPECT_EQ(after[0].cluster_id, 2U);
  EXPECT_EQ(after[0].landmark_id, 100);  // 100 is free now and has more votes
}

TEST(AssociationSmoother, DecayLetsACorrectedAssociationWin) {
  AssociationSmoother s(SmoothingConfig{.min_count = 2.0, .decay = 0.9});
  vote(s, 10, 1, 100);
  vote(s, 12, 1, 200);
  const auto out = s.smoothed();
  ASSERT_EQ(out.size(), 1U);
  EXPECT_EQ(out[0].landmark_id, 200);
  EXPECT_LT(s.count(1, 100), 10.0 * std::pow(0.9, 12) + 1e-9);
}

}  // namespace
}  // namespace polmap::loc
