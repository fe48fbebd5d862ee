// The streaming pCFAR (extract_points(map), row by row from the tiles) against the
// straightforward version (extract_points_reference: one dense raster per chunk): the
// same candidates, bit for bit, on sliding-window maps of a moving sensor over static
// points and speckle (three polarimetric levels), on mapping-mode maps spread over
// several chunks, read_row() returns exactly what raster() holds, and cells_above()
// lists every cell above a power floor.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <random>
#include <set>

#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/point_extractor.hpp"

namespace polmap::radar {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

/// One frame of a sensor at T_map_sensor seeing static point scatterers (3 range bins
/// each, amplitude falling with range) and random floor exceedances (speckle).
PolSpectrum render(std::mt19937& rng, const Pose2& T_map_sensor,
                   const std::vector<Eigen::Vector2d>& points) {
  PolSpectrum s;
  s.range_bin_m = 0.075;
  s.num_range_bins = 534;  // 40 m
  s.noise_sigma = 0.5F;
  for (int k = 0; k < 61; ++k)
    s.azimuth_bins_rad.push_back(static_cast<float>((-60.0 + 2.0 * k) * kDeg));
  std::normal_distribution<float> n(0.0F, 0.5F);
  std::map<std::pair<int, int>, SpectrumCell> cells;
  auto add = [&](int rb, int az, float amp, float phase) {
    if (rb < 0 || rb >= s.num_range_bins || az < 0 || az >= 61) return;
    SpectrumCell& c = cells[{az, rb}];
    c.range_bin = static_cast<std::uint16_t>(rb);
    c.azimuth_bin = static_cast<std::uint16_t>(az);
    c.s[0] += std::polar(amp, phase) + cfloat(n(rng), n(rng));
    c.s[1] += std::polar(0.3F * amp, phase + 1.0F) + cfloat(n(rng), n(rng));
    c.s[2] += std::polar(0.3F * amp, phase + 1.0F) + cfloat(n(rng), n(rng));
    c.s[3] += std::polar(-amp, -phase) + cfloat(n(rng), n(rng));
  };
  const Pose2 T_sensor_map = T_map_sensor.inverse();
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector2d p = T_sensor_map * points[i];
    const double r = p.norm(), az = std::atan2(p.y(), p.x()) / kDeg;
    if (az < -61.0 || az > 61.0) continue;
    const int rb = static_cast<int>(std::lround(r / s.range_bin_m));
    const int ab = static_cast<int>(std::lround((az + 60.0) / 2.0));
    const float amp = static_cast<float>(60.0 / std::max(r, 3.0));
    for (int d = -1; d <= 1; ++d) add(rb + d, ab, d == 0 ? amp : 0.4F * amp, 0.3F * i);
  }
  std::uniform_int_distribution<int> rbin(0, s.num_range_bins - 1), abin(0, 60);
  for (int k = 0; k < 400; ++k) add(rbin(rng), abin(rng), 1.5F, 0.0F);
  for (auto& [key, c] : cells) s.cells.push_back(c);
  return s;
}

CovarianceGridmap sliding_window_map(PolLevel level, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-30.0, 60.0), lateral(-15.0, 15.0);
  std::vector<Eigen::Vector2d> points;
  for (int i = 0; i < 60; ++i) points.emplace_back(u(rng), lateral(rng));
  CovarianceGridmap map(GridmapConfig{0.1, level, 2.0, 0.0});
  for (int k = 0; k < 40; ++k) {  // 4 s at 10 Hz, 8 m/s along a gentle curve
    const double t = 0.1 * k;
    const Pose2 T_map_sensor{8.0 * t, 0.5 * t * t, 0.05 * t};
    map.add(render(rng, T_map_sensor, points), T_map_sensor, t);
  }
  return map;
}

void expect_same(const std::vector<PointCandidate>& fast, const std::vector<PointCandidate>& ref) {
  ASSERT_EQ(fast.size(), ref.size());
  for (std::size_t i = 0; i < ref.size(); ++i) {
    EXPECT_EQ(fast[i].position_m, ref[i].position_m) << i;
    EXPECT_EQ(fast[i].strength, ref[i].strength) << i;
    EXPECT_EQ(fast[i].num_cells, ref[i].num_cells) << i;
    EXPECT_EQ(fast[i].power_db, ref[i].power_db) << i;
    EXPECT_EQ(fast[i].scattering, ref[i].scattering) << i;
  }
}

TEST(PointExtractorStream, EqualsReferenceOnSlidingWindowMapsAtEveryLevel) {
  for (PolLevel level : {PolLevel::Full, PolLevel::DualLLLR, PolLevel::SingleLR}) {
    const CovarianceGridmap map = sliding_window_map(level, 3);
    ASSERT_GT(map.noise_power(), 0.0);
    const auto ref = extract_points_reference(map);
    EXPECT_GE(ref.size(), level == PolLevel::SingleLR ? 5U : 20U) << "level " << int(level);
    expect_same(extract_points(map), ref);
  }
}

TEST(PointExtractorStream, EqualsReferenceWithoutLineAwarenessAndSmallChunks) {
  const CovarianceGridmap map = sliding_window_map(PolLevel::Full, 5);
  PointExtractorConfig cfg;
  cfg.line_aware = false;
  cfg.chunk_tiles = 2;  // many chunk borders through the scene
  const auto ref = extract_points_reference(map, cfg);
  EXPECT_GE(ref.size(), 20U);
  expect_same(extract_points(map, cfg), ref);
}

TEST(PointExtractorStream, EqualsReferenceOnMappingModeMapWithoutNoiseFigure) {
  // add_cell_sample maps have no noise figure: the loading comes from the mean power
  // of the box, which the streaming path must compute the same way.
  CovarianceGridmap map;
  std::mt19937 rng(11);
  std::normal_distribution<double> n(0.0, std::sqrt(0.5));
  const std::vector<Eigen::Vector2d> posts{{12.34, 8.71}, {13.9, 11.2}, {51.2, 10.03}};
  for (int iy = 40; iy < 150; ++iy) {
    for (int ix = 60; ix < 560; ix += (iy % 7 == 0 ? 2 : 1)) {
      const Eigen::Vector2d c((ix + 0.5) * 0.1, (iy + 0.5) * 0.1);
      double a = 0.0;
      for (const auto& p : posts) a += 6.0 * std::exp(-25.0 * (c - p).squaredNorm());
      for (int look = 0; look < 8; ++look) {
        std::vector<cdouble> v(3);
        for (int i = 0; i < 3; ++i) v[i] = cdouble(n(rng), n(rng)) + a * (i == 1 ? 1.0 : 0.2);
        map.add_cell_sample(ix, iy, v);
      }
    }
  }
  ASSERT_EQ(map.noise_power(), 0.0);
  const auto ref = extract_points_reference(map);
  ASSERT_GE(ref.size(), posts.size());
  expect_same(extract_points(map), ref);
}

TEST(PointExtractorStream, EmptyMapGivesNothing) {
  const CovarianceGridmap map(GridmapConfig{0.1, PolLevel::Full, 2.0, 0.0});
  EXPECT_TRUE(extract_points(map).empty());
}

TEST(CovarianceGridmapReadRow, EqualsRaster) {
  const CovarianceGridmap map = sliding_window_map(PolLevel::Full, 7);
  const CellBox b = map.bounds();
  const CellBox box{b.min_ix - 5, b.min_iy - 5, b.max_ix + 5, b.max_iy + 5};
  const CovarianceRaster r = map.raster(box);
  const int w = box.width(), L = num_layers(3);
  std::vector<std::uint32_t> count(w), hits(w);
  std::vector<std::complex<float>> layers(static_cast<std::size_t>(w) * L);
  std::size_t observed = 0;
  for (int iy = box.min_iy; iy < box.max_iy; iy += 3) {
    map.read_row(iy, box.min_ix, box.max_ix, count, hits, layers);
    for (int x = 0; x < w; ++x) {
      const std::size_t idx = static_cast<std::size_t>(iy - box.min_iy) * w + x;
      ASSERT_EQ(count[x], r.count[idx]);
      ASSERT_EQ(hits[x], r.hits[idx]);
      for (int l = 0; l < L; ++l) ASSERT_EQ(layers[x * L + l], r.layer(l, idx));
      observed += count[x] > 0;
    }
  }
  EXPECT_GT(observed, 1000U);
}

TEST(CovarianceGridmapCellsAbove, HoldsEveryCellThatPassesTheFirstTestAndFewOthers) {
  // The first pass of the streaming pCFAR must not miss a cell the test would pass, and
  // is worth doing only if it keeps little else.
  const CovarianceGridmap map = sliding_window_map(PolLevel::Full, 9);
  const CellBox b = map.bounds();
  const CellBox box{b.min_ix + 7, b.min_iy - 5, b.max_ix - 9, b.max_iy + 5};  // cuts tiles
  const double floor = 30.0 * map.noise_power(), persistence = 0.05;
  const auto found = map.cells_above(box, floor, persistence, 2);
  std::set<std::pair<int, int>> cells;
  for (const auto& [ix, iy] : found) {
    ASSERT_TRUE(box.contains(ix, iy));
    ASSERT_TRUE(cells.emplace(ix, iy).second) << "twice: " << ix << " " << iy;
  }
  const int w = box.width(), L = num_layers(3);
  std::vector<std::uint32_t> count(w), hits(w);
  std::vector<std::complex<float>> layers(static_cast<std::size_t>(w) * L);
  std::size_t passing = 0, near_floor = 0;
  for (int iy = box.min_iy; iy < box.max_iy; ++iy) {
    map.read_row(iy, box.min_ix, box.max_ix, count, hits, layers);
    for (int x = 0; x < w; ++x) {
      float p = 0.0F;
      for (int i = 0; i < 3; ++i) p += layers[x * L + layer_index(3, i, i)].real();
      const bool listed = cells.count({box.min_ix + x, iy}) > 0;
      if (count[x] >= 2 && hits[x] >= persistence * count[x] && p > floor) {
        ++passing;
        ASSERT_TRUE(listed) << "missed " << box.min_ix + x << " " << iy;
      } else if (listed) {
        ++near_floor;
        // Listed without passing: only at the floor or the rounding of the hits.
        EXPECT_TRUE(p > 0.999 * floor || hits[x] + 1 >= persistence * count[x]);
      }
    }
  }
  EXPECT_GT(passing, 20U);  // the scene's points, not only empty cells
  EXPECT_LE(near_floor, passing / 10);
}

}  // namespace
}  // namespace polmap::radar
