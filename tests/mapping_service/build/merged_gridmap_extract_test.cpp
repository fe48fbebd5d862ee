// pCFAR on the merged gridmap: a scatterer seen by eight single-look drives is found in
// their merged gridmap at its true WGS84 position (the grid's frame and the Mercator
// inverse are right), and nothing is found in the merged gridmap of pure noise.
#include "polmap/mapping_service/merged_gridmap_extract.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <random>

#include "polmap/mapping_service/gridmap_sums_codec.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {

const GeoPoint kOrigin{48.78, 9.18, 0.0};

/// One drive's full-polarimetric raster around kOrigin: each cell's C is the mean of
/// `looks` complex Gaussian snapshots of noise (σ² = 1 per component) plus, within 0.15 m
/// of `target_m`, a scatterer of power `target_power` per component.
GridmapRaster drive(std::uint32_t seed, int looks, const Eigen::Vector2d& target_m,
                    double target_power) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, std::sqrt(0.5));
  GridmapRaster r;
  r.q = 3;
  r.width = r.height = 120;
  r.origin_x_m = -6.0;
  r.origin_y_m = 6.0;
  r.noise_power = 1.0;
  r.count.assign(static_cast<std::size_t>(r.width) * r.height, static_cast<std::uint32_t>(looks));
  r.hits = r.count;
  r.layers.assign(6, std::vector<cdouble>(r.count.size()));
  for (int row = 0; row < r.height; ++row) {
    for (int col = 0; col < r.width; ++col) {
      const std::size_t i = static_cast<std::size_t>(row) * r.width + col;
      const Eigen::Vector2d c(r.origin_x_m + (col + 0.5) * 0.1, r.origin_y_m - (row + 0.5) * 0.1);
      const double a = (c - target_m).norm() < 0.15 ? std::sqrt(target_power) : 0.0;
      Eigen::Matrix3cd sum = Eigen::Matrix3cd::Zero();
      for (int k = 0; k < looks; ++k) {
        Eigen::Vector3cd v;
        for (int j = 0; j < 3; ++j) v(j) = {g(rng), g(rng)};
        v += a * Eigen::Vector3cd(1.0, 0.0, 1.0);  // an even-bounce-like return
        sum += v * v.adjoint();
      }
      sum /= looks;
      int l = 0;
      for (int p = 0; p < 3; ++p)
        for (int q = p; q < 3; ++q) r.layers[static_cast<std::size_t>(l++)][i] = sum(p, q);
    }
  }
  return r;
}

void put_sums(SqliteMapStore& store, const std::vector<GridmapRaster>& drives) {
  GridmapSumTiles sums;
  for (const auto& d : drives) splat_gridmap(d, tiles::LocalFrame(kOrigin), PolLevel::Full, sums);
  std::vector<GridmapSumRow> rows;
  for (const auto& [k, t] : sums) {
    rows.push_back({static_cast<int>(k.level), k.x, k.y, encode_gridmap_sum_tile(t), 0});
  }
  store.commit_gridmap_sums(1, rows, {});
}

GeoBox around_origin() {
  const tiles::LocalFrame f(kOrigin);
  const GeoPoint sw = f.to_geo(Eigen::Vector2d(-5.0, -5.0)),
                 ne = f.to_geo(Eigen::Vector2d(5.0, 5.0));
  return {sw.lat_deg, sw.lon_deg, ne.lat_deg, ne.lon_deg};
}

TEST(MergedGridmapExtract, FindsAWeakScattererInTheMergedGridmapAtItsPosition) {
  const Eigen::Vector2d target(1.23, -0.87);
  polmap::test::TestDir tmp("merged_extract");
  SqliteMapStore store(tmp.path() / "map.db");
  std::vector<GridmapRaster> drives;
  for (std::uint32_t d = 0; d < 8; ++d) drives.push_back(drive(10 + d, 1, target, 20.0));
  put_sums(store, drives);
  const MergedExtraction x = extract_from_merged_gridmap(store, around_origin());
  ASSERT_EQ(x.status, MergedExtraction::Status::Ok);
  EXPECT_EQ(x.level, PolLevel::Full);
  EXPECT_NEAR(x.noise_power, 1.0, 1e-6);
  ASSERT_FALSE(x.points.empty());
  const tiles::LocalFrame f(kOrigin);
  double best = 1e9;
  for (const auto& p : x.points) best = std::min(best, (f.to_local(p) - target).norm());
  EXPECT_LT(best, 0.05);
  EXPECT_EQ(x.points.size(), 1U);
}

TEST(MergedGridmapExtract, PureNoiseGivesNoPointsAndAnEmptyStoreNoGridmap) {
  polmap::test::TestDir tmp("merged_extract");
  SqliteMapStore store(tmp.path() / "map.db");
  EXPECT_EQ(extract_from_merged_gridmap(store, around_origin()).status,
            MergedExtraction::Status::NoGridmap);
  std::vector<GridmapRaster> drives;
  for (std::uint32_t d = 0; d < 8; ++d) drives.push_back(drive(30 + d, 4, {0, 0}, 0.0));
  put_sums(store, drives);
  const MergedExtraction x = extract_from_merged_gridmap(store, around_origin());
  ASSERT_EQ(x.status, MergedExtraction::Status::Ok);
  EXPECT_TRUE(x.points.empty()) << x.points.size();
}

}  // namespace
}  // namespace polmap::mapping
