// Covariance layers of the gridmap: C = 1/N Σ k k^H per cell is Hermitian and
// positive semi-definite, the tile view and cell access agree, and C equals the
// brute-force mean of the level vectors' outer products.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <numbers>
#include <random>

#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/polarimetry.hpp"

namespace polmap::radar {
namespace {

PolSpectrum dense_spectrum(std::mt19937& rng) {
  PolSpectrum s;
  s.range_bin_m = 0.075;
  s.num_range_bins = 120;
  for (int k = 0; k < 31; ++k) {
    s.azimuth_bins_rad.push_back(static_cast<float>((-45.0 + 3.0 * k) * std::numbers::pi / 180.0));
  }
  std::normal_distribution<float> n(0.0F, 1.0F);
  for (int k = 0; k < 31; ++k) {
    for (int i = 0; i < 120; ++i) {
      SpectrumCell c;
      c.azimuth_bin = static_cast<std::uint16_t>(k);
      c.range_bin = static_cast<std::uint16_t>(i);
      for (auto& v : c.s) v = cfloat(n(rng), n(rng));
      c.s[2] = c.s[1] + 0.1F * c.s[2];  // nearly reciprocal
      s.cells.push_back(c);
    }
  }
  return s;
}

class CovarianceLayers : public ::testing::TestWithParam<PolLevel> {};

TEST_P(CovarianceLayers, HermitianPsdAndViewsAgree) {
  std::mt19937 rng(1);
  GridmapConfig cfg;
  cfg.level = GetParam();
  CovarianceGridmap map(cfg);
  for (int f = 0; f < 6; ++f) {
    map.add(dense_spectrum(rng), {0.3 * f, 0.1 * f, 0.02 * f}, 0.1 * f);
  }
  const int q = pol_dimension(cfg.level);
  int checked = 0;
  map.for_each_tile([&](const CovarianceTileView& v) {
    EXPECT_EQ(v.q, q);
    EXPECT_EQ(v.num_layers, num_layers(q));
    for (int row = 0; row < v.size_cells; row += 3) {
      for (int col = 0; col < v.size_cells; col += 3) {
        const int ix = v.tile_x * v.size_cells + col, iy = v.tile_y * v.size_cells + row;
        EXPECT_EQ(v.count[row * v.size_cells + col], map.count(ix, iy));
        const Eigen::MatrixXcd c = v.covariance(col, row);
        const Eigen::MatrixXcd c2 = map.covariance(ix, iy);
        ASSERT_LE((c - c2).norm(), 1e-5 * (1.0 + c2.norm()));
        ASSERT_LE((c2 - c2.adjoint()).norm(), 1e-12);
        const Eigen::VectorXd ev =
            Eigen::SelfAdjointEigenSolver<Eigen::MatrixXcd>(c2).eigenvalues();
        ASSERT_GE(ev.minCoeff(), -1e-5 * (1.0 + c2.trace().real()));
        checked += v.count[row * v.size_cells + col] > 0;
      }
    }
  });
  EXPECT_GT(checked, 50);
}

TEST_P(CovarianceLayers, RasterOfAnUnalignedBoxEqualsCellAccess) {
  // raster() writes tiles straight into the box; a box that cuts tiles and reaches
  // beyond the data must hold exactly the per-cell N, hits and C (brute force).
  std::mt19937 rng(2);
  GridmapConfig cfg;
  cfg.level = GetParam();
  CovarianceGridmap map(cfg);
  // Keep a third of the cells: the rest of the footprint is observed (N > 0)
  // without a stored bin, as below a real sensor's noise floor.
  for (int f = 0; f < 4; ++f) {
    PolSpectrum s = dense_spectrum(rng);
    std::vector<SpectrumCell> kept;
    for (std::size_t i = 0; i < s.cells.size(); ++i) {
      if (rng() % 3 == 0) kept.push_back(s.cells[i]);
    }
    s.cells = std::move(kept);
    map.add(s, {0.2 * f, -0.1 * f, 0.03 * f}, 0.1 * f);
  }
  const CellBox all = map.bounds();
  const CellBox box{all.min_ix + 37, all.min_iy - 11, all.max_ix - 29, all.max_iy + 5};
  const CovarianceRaster r = map.raster(box);
  ASSERT_EQ(r.count.size(), r.plane_size());
  int observed = 0, observed_without_bin = 0;
  for (int iy = box.min_iy; iy < box.max_iy; ++iy) {
    for (int ix = box.min_ix; ix < box.max_ix; ++ix) {
      const std::size_t idx =
          static_cast<std::size_t>(iy - box.min_iy) * box.width() + (ix - box.min_ix);
      ASSERT_EQ(r.count[idx], map.count(ix, iy)) << ix << "," << iy;
      ASSERT_EQ(r.hits[idx], map.hits(ix, iy)) << ix << "," << iy;
      if (r.count[idx] == 0) {
        ASSERT_EQ(r.covariance(idx).norm(), 0.0);
        continue;
      }
      ++observed;
      observed_without_bin += r.hits[idx] == 0 ? 1 : 0;
      const Eigen::MatrixXcd c = map.covariance(ix, iy);
      ASSERT_LE((r.covariance(idx) - c).norm(), 1e-5 * (1.0 + c.norm())) << ix << "," << iy;
    }
  }
  EXPECT_GT(observed, 1000);
  EXPECT_GT(observed_without_bin, 100);
}

INSTANTIATE_TEST_SUITE_P(AllLevels, CovarianceLayers,
                         ::testing::Values(PolLevel::Full, PolLevel::DualLLLR, PolLevel::DualHHVV,
                                           PolLevel::SingleLR, PolLevel::SingleRR,
                                           PolLevel::SingleHH));

TEST(CovarianceLayers, CellSamplesAverageOuterProducts) {
  CovarianceGridmap map;
  std::mt19937 rng(2);
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::Matrix3cd sum = Eigen::Matrix3cd::Zero();
  for (int i = 0; i < 5; ++i) {
    Eigen::Vector3cd k;
    for (int j = 0; j < 3; ++j) k(j) = cdouble(n(rng), n(rng));
    std::vector<cdouble> kv(k.data(), k.data() + 3);
    map.add_cell_sample(-70, 130, kv);
    sum += k * k.adjoint();
  }
  EXPECT_EQ(map.count(-70, 130), 5U);
  EXPECT_LE((map.covariance(-70, 130) - sum / 5.0).norm(), 1e-5 * sum.norm());
  EXPECT_EQ(map.count(-69, 130), 0U);
}

TEST(CovarianceLayers, MergeTileReproducesMap) {
  std::mt19937 rng(4);
  CovarianceGridmap a;
  a.add(dense_spectrum(rng), {1.0, 2.0, 0.5}, 0.0);
  a.add(dense_spectrum(rng), {1.5, 2.0, 0.6}, 0.1);
  CovarianceGridmap b;
  a.for_each_tile([&](const CovarianceTileView& v) { b.merge_tile(v); });
  EXPECT_EQ(a.num_tiles(), b.num_tiles());
  const CellBox box = a.bounds();
  for (int iy = box.min_iy; iy < box.max_iy; iy += 5) {
    for (int ix = box.min_ix; ix < box.max_ix; ix += 5) {
      ASSERT_EQ(a.count(ix, iy), b.count(ix, iy));
      ASSERT_LE((a.covariance(ix, iy) - b.covariance(ix, iy)).norm(),
                1e-5 * (1.0 + a.covariance(ix, iy).norm()));
    }
  }
}

}  // namespace
}  // namespace polmap::radar
