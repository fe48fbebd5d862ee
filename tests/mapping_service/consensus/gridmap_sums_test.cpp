// The merged gridmap's sum tiles: splatting conserves every plane's total, puts a cell's
// weight on the four grid cells around its Web-Mercator position with bilinear weights,
// merging two drives gives their N-weighted mean covariance, and the raster layers
// rendered from sums agree with those accumulated from the drive rasters directly.
#include "polmap/mapping_service/gridmap_sums.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "polmap/mapping_service/fleet_gridmap.hpp"
#include "polmap/mapping_service/gridmap_sums_codec.hpp"

namespace polmap::mapping {
namespace {

const GeoPoint kOrigin{48.78, 9.18, 0.0};

/// A random full-polarimetric raster (Hermitian PSD cells), some cells unobserved.
GridmapRaster random_raster(int w, int h, std::uint32_t seed, double x0 = -3.0, double y0 = 4.0) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_int_distribution<int> looks(0, 40);
  GridmapRaster r;
  r.q = 3;
  r.width = w;
  r.height = h;
  r.origin_x_m = x0;
  r.origin_y_m = y0;
  r.noise_power = 0.25;
  r.count.resize(static_cast<std::size_t>(w) * h);
  r.hits.resize(r.count.size());
  r.layers.assign(6, std::vector<cdouble>(r.count.size()));
  for (std::size_t i = 0; i < r.count.size(); ++i) {
    const int n = looks(rng);
    r.count[i] = n < 5 ? 0 : static_cast<std::uint32_t>(n);
    r.hits[i] = r.count[i] / 3;
    Eigen::Vector3cd v({g(rng), g(rng)}, {g(rng), g(rng)}, {g(rng), g(rng)});
    const Eigen::Matrix3cd c = v * v.adjoint();
    int l = 0;
    for (int a = 0; a < 3; ++a)
      for (int b = a; b < 3; ++b) r.layers[static_cast<std::size_t>(l++)][i] = c(a, b);
  }
  return r;
}

/// Σ over all tiles and cells of plane p.
double plane_total(const GridmapSumTiles& tiles, int p) {
  double s = 0.0;
  for (const auto& [k, t] : tiles)
    for (int y = 0; y < kSumTileCells; ++y)
      for (int x = 0; x < kSumTileCells; ++x) s += t.at(p, x, y);
  return s;
}

TEST(GridmapSums, PlanesPerLevel) {
  EXPECT_EQ(gridmap_sum_planes(PolLevel::Full), 12);
  EXPECT_EQ(gridmap_sum_planes(PolLevel::DualLLLR), 7);
  EXPECT_EQ(gridmap_sum_planes(PolLevel::DualHHVV), 7);
  EXPECT_EQ(gridmap_sum_planes(PolLevel::SingleRR), 4);
}

TEST(GridmapSums, SplattingConservesEveryPlanesTotal) {
  // 300 × 300 cells (30 m): spans several 25 m sum tiles, so tile borders are crossed.
  const GridmapRaster r = random_raster(300, 300, 3);
  GridmapSumTiles tiles;
  splat_gridmap(r, tiles::LocalFrame(kOrigin), PolLevel::Full, tiles);
  EXPECT_GE(tiles.size(), 4U);
  // Reference totals straight from the raster: Σ N, Σ hits, Σ N σ², Σ N C_ij.
  std::vector<double> ref(12, 0.0);
  for (std::size_t i = 0; i < r.count.size(); ++i) {
    const double n = r.count[i];
    ref[0] += n;
    ref[1] += r.hits[i];
    ref[2] += n * r.noise_power;
    int p = 3, l = 0;
    for (int a = 0; a < 3; ++a) {
      for (int b = a; b < 3; ++b, ++l) {
        ref[static_cast<std::size_t>(p++)] += n * r.layers[static_cast<std::size_t>(l)][i].real();
        if (a != b)
          ref[static_cast<std::size_t>(p++)] += n * r.layers[static_cast<std::size_t>(l)][i].imag();
      }
    }
  }
  for (int p = 0; p < 12; ++p) {
    EXPECT_NEAR(plane_total(tiles, p), ref[static_cast<std::size_t>(p)],
                1e-5 * std::max(1.0, std::abs(ref[static_cast<std::size_t>(p)])))
        << "plane " << p;
  }
}

TEST(GridmapSums, OneCellLandsBilinearlyAroundItsMercatorPosition) {
  GridmapRaster r = random_raster(1, 1, 5, 7.3, -2.1);
  r.count[0] = 100;
  const tiles::LocalFrame frame(kOrigin);
  GridmapSumTiles tiles;
  splat_gridmap(r, frame, PolLevel::Full, tiles);
  // The straightforward reference: the cell centre's global grid coordinate.
  const GeoPoint c = frame.to_geo(Eigen::Vector2d(7.3 + 0.05, -2.1 - 0.05));
  const auto m = tiles::to_mercator_tiles(c.lat_deg, c.lon_deg, kGridmapSumZoom);
  const double gx = m.x * kSumTileCells - 0.5, gy = m.y * kSumTileCells - 0.5;
  const double x0 = std::floor(gx), y0 = std::floor(gy);
  const double ax = gx - x0, ay = gy - y0;
  double total = 0.0;
  for (int dy = 0; dy < 2; ++dy) {
    for (int dx = 0; dx < 2; ++dx) {
      const auto X = static_cast<std::int64_t>(x0) + dx, Y = static_cast<std::int64_t>(y0) + dy;
      const GridmapSumKey key{PolLevel::Full, static_cast<int>(X / kSumTileCells),
                              static_cast<int>(Y / kSumTileCells)};
      const double w = (dx ? ax : 1 - ax) * (dy ? ay : 1 - ay);
      const auto it = tiles.find(key);
      const double got = it == tiles.end() ? 0.0
                                           : it->second.at(0, static_cast<int>(X % kSumTileCells),
                                                           static_cast<int>(Y % kSumTileCells));
      EXPECT_NEAR(got, 100.0 * w, 1e-3) << dx << "," << dy;
      total += got;
    }
  }
  EXPECT_NEAR(total, 100.0, 1e-3);
}

TEST(GridmapSums, MergingTwoDrivesGivesTheirCountWeightedMeanCovariance) {
  // Two drives observing the same place with different covariances and looks.
  GridmapRaster a = random_raster(40, 40, 11), b = random_raster(40, 40, 12);
  for (auto& n : a.count) n = 10;
  for (auto& n : b.count) n = 30;
  b.noise_power = 0.5;
  const tiles::LocalFrame frame(kOrigin);
  GridmapSumTiles sa, sb;
  splat_gridmap(a, frame, PolLevel::Full, sa);
  splat_gridmap(b, frame, PolLevel::Full, sb);
  GridmapSumTiles both;  // tiles are move-only: merged by add
  for (const auto& [k, t] : sa) both.try_emplace(k, k.level).first->second.add(t);
  for (const auto& [k, t] : sb) both.try_emplace(k, k.level).first->second.add(t);
  int checked = 0;
  for (const auto& [k, t] : both) {
    for (int y = 0; y < kSumTileCells; ++y) {
      for (int x = 0; x < kSumTileCells; ++x) {
        const MergedCell m = merged_cell(t, x, y);
        if (m.n <= 0.0) continue;
        const MergedCell ma = sa.contains(k) ? merged_cell(sa.at(k), x, y) : MergedCell{};
        const MergedCell mb = sb.contains(k) ? merged_cell(sb.at(k), x, y) : MergedCell{};
        EXPECT_NEAR(m.n, ma.n + mb.n, 1e-3);
        EXPECT_NEAR(m.hits, ma.hits + mb.hits, 1e-3);
        EXPECT_NEAR(m.noise_power, (ma.n * 0.25 + mb.n * 0.5) / m.n, 1e-5);
        for (std::size_t l = 0; l < m.layers.size(); ++l) {
          const cdouble ref = ((ma.n > 0 ? ma.n * ma.layers[l] : cdouble{}) +
                               (mb.n > 0 ? mb.n * mb.layers[l] : cdouble{})) /
                              m.n;
          EXPECT_NEAR(std::abs(m.layers[l] - ref), 0.0, 1e-4 * (1.0 + std::abs(ref)));
        }
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1000);
}

TEST(GridmapSums, SubtractingADriveLeavesTheOthersAndClearsWhatOnlyItSaw) {
  // Two overlapping drives; b is taken out again by subtraction. Drive a stored no bins, so
  // the hits left are b's float residue, which must not go below 0.
  GridmapRaster a = random_raster(60, 60, 21);
  const GridmapRaster b = random_raster(60, 60, 22, 2.0, 1.0);
  std::fill(a.hits.begin(), a.hits.end(), 0U);
  const tiles::LocalFrame frame(kOrigin);
  GridmapSumTiles sa, sb, both;
  splat_gridmap(a, frame, PolLevel::Full, sa);
  splat_gridmap(b, frame, PolLevel::Full, sb);
  for (const auto& [k, t] : sa) both.try_emplace(k, k.level).first->second.add(t);
  for (const auto& [k, t] : sb) both.try_emplace(k, k.level).first->second.add(t);
  for (const auto& [k, t] : sb) both.at(k).subtract(t);
  int only_b = 0, shared = 0;
  for (const auto& [k, t] : both) {
    for (int y = 0; y < kSumTileCells; ++y) {
      for (int x = 0; x < kSumTileCells; ++x) {
        const double na = sa.contains(k) ? sa.at(k).at(0, x, y) : 0.0;
        const double nb = sb.contains(k) ? sb.at(k).at(0, x, y) : 0.0;
        for (int p = 0; p < t.planes(); ++p) {
          const double want = sa.contains(k) ? sa.at(k).at(p, x, y) : 0.0;
          if (na < 1e-3) {
            EXPECT_EQ(t.at(p, x, y), 0.0F);  // cleared, not float residue
          } else {
            EXPECT_NEAR(t.at(p, x, y), want, 1e-4 * (1.0 + std::abs(want)));
          }
        }
        only_b += na < 1e-3 && nb > 0.0 ? 1 : 0;
        shared += na >= 1e-3 && nb > 0.0 ? 1 : 0;
      }
    }
  }
  EXPECT_GT(only_b, 100);  // the test covers both kinds of cell
  EXPECT_GT(shared, 100);
  // What is left is a valid sum tile (the codec rejects negative counts).
  for (const auto& [k, t] : both) {
    EXPECT_NO_THROW((void)decode_gridmap_sum_tile(encode_gridmap_sum_tile(t), "left"));
  }
}

TEST(GridmapSums, RasterFromSumsMatchesRasterFromTheDrive) {
  // The same drive rendered two ways: straight from its raster (nearest base pixel) and
  // through the merged sums (bilinear splat at z20, 4 × 4 cells per z18 pixel). Totals per
  // tile agree exactly; mean power agrees inside uniformly observed areas.
  GridmapRaster r = random_raster(200, 200, 21);
  for (auto& n : r.count) n = 20;
  for (auto& layer : r.layers) {
    for (auto& c : layer) c = {std::abs(c.real()) + 1.0, 0.0};  // smooth-ish, positive
  }
  const tiles::LocalFrame frame(kOrigin);
  FleetGridmapAccumulator direct, merged;
  direct.add(r, frame, PolLevel::Full);
  GridmapSumTiles sums;
  splat_gridmap(r, frame, PolLevel::Full, sums);
  for (const auto& [k, t] : sums) merged.add_sums(k, t);
  ASSERT_EQ(direct.num_base_tiles(), merged.num_base_tiles());
  double n_direct = 0.0, n_merged = 0.0;
  const auto m = tiles::to_mercator_tiles(kOrigin.lat_deg, kOrigin.lon_deg, 18);
  const tiles::TileKey key{18, static_cast<int>(m.x), static_cast<int>(m.y)};
  for (int y = 0; y < 256; ++y) {
    for (int x = 0; x < 256; ++x) {
      n_direct += direct.count(key, x, y);
      n_merged += merged.count(key, x, y);
    }
  }
  EXPECT_NEAR(n_merged, n_direct, 1e-4 * n_direct);
  // Mean power over the tile (power-weighted averages of the same cells).
  double p_direct = 0.0, p_merged = 0.0;
  for (int y = 0; y < 256; ++y) {
    for (int x = 0; x < 256; ++x) {
      if (auto p = direct.mean_power(key, x, y)) p_direct += *p * direct.count(key, x, y);
      if (auto p = merged.mean_power(key, x, y)) p_merged += *p * merged.count(key, x, y);
    }
  }
  EXPECT_NEAR(p_merged, p_direct, 1e-4 * p_direct);
}

}  // namespace
}  // namespace polmap::mapping
