// Merged PreCFAR gridmap sums (grid and planes in gridmap_sums.hpp).
#include "polmap/mapping_service/gridmap_sums.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <span>

#include "polmap/mapping_service/fleet_gridmap.hpp"
#include "polmap/schema/errors.hpp"
#include "raster_blocks.hpp"

namespace polmap::mapping {
namespace {
constexpr int kChunkArea = kSumChunkCells * kSumChunkCells;
}  // namespace

int gridmap_sum_planes(PolLevel level) {
  const int q = pol_dimension(level);
  return 3 + q + q * (q - 1);  // N, hits, N·σ², q real diagonals, q(q-1)/2 complex off-diagonals
}

GridmapSumTile::GridmapSumTile(PolLevel level)
    : level_(level), planes_(gridmap_sum_planes(level)) {}

bool GridmapSumTile::empty() const {
  return std::none_of(chunks_.begin(), chunks_.end(), [](const auto& c) { return c != nullptr; });
}

float* GridmapSumTile::chunk(int c) {
  POLMAP_EXPECT(c >= 0 && c < kSumChunksPerSide * kSumChunksPerSide);
  auto& ch = chunks_[static_cast<std::size_t>(c)];
  if (!ch) {
    ch = std::make_unique<float[]>(static_cast<std::size_t>(planes_) * kChunkArea);
    std::fill_n(ch.get(), static_cast<std::size_t>(planes_) * kChunkArea, 0.0F);
  }
  return ch.get();
}

float GridmapSumTile::at(int p, int x, int y) const {
  POLMAP_EXPECT(p >= 0 && p < planes_ && x >= 0 && x < kSumTileCells && y >= 0 &&
                y < kSumTileCells);
  const float* ch = chunk((y / kSumChunkCells) * kSumChunksPerSide + x / kSumChunkCells);
  if (ch == nullptr) return 0.0F;
  return ch[static_cast<std::size_t>(p) * kChunkArea +
            static_cast<std::size_t>(y % kSumChunkCells) * kSumChunkCells + x % kSumChunkCells];
}

void GridmapSumTile::add(int x, int y, double w, const double* values) {
  float* ch = chunk((y / kSumChunkCells) * kSumChunksPerSide + x / kSumChunkCells);
  const std::size_t i =
      static_cast<std::size_t>(y % kSumChunkCells) * kSumChunkCells + x % kSumChunkCells;
  for (int p = 0; p < planes_; ++p) {
    ch[static_cast<std::size_t>(p) * kChunkArea + i] += static_cast<float>(w * values[p]);
  }
}

void GridmapSumTile::add(const GridmapSumTile& other) {
  POLMAP_EXPECT(other.level_ == level_);
  for (int c = 0; c < kSumChunksPerSide * kSumChunksPerSide; ++c) {
    const float* src = other.chunk(c);
    if (src == nullptr) continue;
    float* dst = chunk(c);
    for (std::size_t i = 0; i < static_cast<std::size_t>(planes_) * kChunkArea; ++i) {
      dst[i] += src[i];
    }
  }
}

void GridmapSumTile::subtract(const GridmapSumTile& other, float n_floor_looks) {
  POLMAP_EXPECT(other.level_ == level_);
  // N, hits, N·σ² and the diagonal N·C_ii (file comment of gridmap_sums.hpp).
  std::vector<int> non_negative_planes{0, 1, 2};
  const int q = pol_dimension(level_);
  for (int a = 0, p = 3; a < q; ++a) {
    for (int b = a; b < q; ++b) {
      if (a == b) non_negative_planes.push_back(p);
      p += a == b ? 1 : 2;
    }
  }
  for (int c = 0; c < kSumChunksPerSide * kSumChunksPerSide; ++c) {
    const float* src = other.chunk(c);
    if (src == nullptr) continue;
    float* dst = chunk(c);
    for (std::size_t i = 0; i < static_cast<std::size_t>(planes_) * kChunkArea; ++i) {
      dst[i] -= src[i];
    }
    for (std::size_t cell = 0; cell < static_cast<std::size_t>(kChunkArea); ++cell) {
      if (dst[cell] < n_floor_looks) {  // plane 0: N
        for (int p = 0; p < planes_; ++p) {
          dst[static_cast<std::size_t>(p) * kChunkArea + cell] = 0.0F;
        }
        continue;
      }
      // Sums of non-negative terms stay non-negative (float residue of what was taken out).
      for (const int p : non_negative_planes) {
        float& v = dst[static_cast<std::size_t>(p) * kChunkArea + cell];
        v = std::max(v, 0.0F);
      }
    }
  }
}

void splat_gridmap(const GridmapRaster& r, const tiles::LocalFrame& frame, PolLevel level,
                   GridmapSumTiles& out, const GridmapWarp& warp) {
  if (r.width <= 0 || r.height <= 0) return;
  POLMAP_EXPECT(r.count.size() == static_cast<std::size_t>(r.width) * r.height);
  POLMAP_EXPECT(static_cast<int>(r.layers.size()) == r.q * (r.q + 1) / 2);
  POLMAP_EXPECT(pol_dimension(level) == r.q);
  const int planes = gridmap_sum_planes(level);
  std::vector<double> v(static_cast<std::size_t>(planes));
  constexpr int kPx = kSumTileCells;
  const std::int64_t world_px = tiles::tiles_per_side(kGridmapSumZoom) * kPx;
  // Global grid coordinates (cell units; cell (i, j) spans [i, i+1) × [j, j+1)) of a
  // drive cell centre.
  auto grid_of = [&](double col, double row) {
    const Eigen::Vector2d xy(r.origin_x_m + (col + 0.5) * r.cell_size_m,
                             r.origin_y_m - (row + 0.5) * r.cell_size_m);
    const GeoPoint g = frame.to_geo(warp ? warp(xy) : xy);
    const auto m = tiles::to_mercator_tiles(g.lat_deg, g.lon_deg, kGridmapSumZoom);
    return Eigen::Vector2d(m.x * kPx, m.y * kPx);
  };
  GridmapSumTile* tile = nullptr;
  GridmapSumKey tile_key{level, -1, -1};
  auto add_at = [&](std::int64_t gx, std::int64_t gy, double w) {
    if (w <= 0.0 || gy < 0 || gy >= world_px) return;
    gx = ((gx % world_px) + world_px) % world_px;
    const GridmapSumKey key{level, static_cast<int>(gx / kPx), static_cast<int>(gy / kPx)};
    if (key != tile_key) {
      tile = &out.try_emplace(key, level).first->second;
      tile_key = key;
    }
    tile->add(static_cast<int>(gx % kPx), static_cast<int>(gy % kPx), w, v.data());
  };
  detail::for_each_observed_block(
      r, grid_of,
      [&](int r0, int c0, int rr1, int c1, const Eigen::Vector2d& p0, const Eigen::Vector2d& dc,
          const Eigen::Vector2d& dr) {
        for (int row = r0; row < rr1; ++row) {
          for (int col = c0; col < c1; ++col) {
            const std::size_t i = static_cast<std::size_t>(row) * r.width + col;
            const double n = r.count[i];
            if (n == 0) continue;
            // Format 1 packages carry no hits: every look counts as one.
            v[0] = 1.0;
            v[1] = r.hits.empty() ? 1.0 : static_cast<double>(r.hits[i]) / n;
            v[2] = r.noise_power;
            std::size_t p = 3;
            for (int a = 0; a < r.q; ++a) {
              for (int b = a; b < r.q; ++b) {
                const cdouble c = r.layers[static_cast<std::size_t>(r.layer_index(r.q, a, b))][i];
                v[p++] = c.real();
                if (a != b) v[p++] = c.imag();
              }
            }
            // Bilinear weights of the four grid cells whose centres surround the point.
            const Eigen::Vector2d g = p0 + (col - c0) * dc + (row - r0) * dr;
            const double fx = g.x() - 0.5, fy = g.y() - 0.5;
            const auto x0 = static_cast<std::int64_t>(std::floor(fx));
            const auto y0 = static_cast<std::int64_t>(std::floor(fy));
            const double ax = fx - static_cast<double>(x0), ay = fy - static_cast<double>(y0);
            add_at(x0, y0, n * (1 - ax) * (1 - ay));
            add_at(x0 + 1, y0, n * ax * (1 - ay));
            add_at(x0, y0 + 1, n * (1 - ax) * ay);
            add_at(x0 + 1, y0 + 1, n * ax * ay);
          }
        }
      });
}

MergedCell merged_cell(const GridmapSumTile& tile, int x, int y) {
  MergedCell m;
  const int q = pol_dimension(tile.level());
  m.layers.assign(static_cast<std::size_t>(q * (q + 1) / 2), cdouble{0.0, 0.0});
  m.n = tile.at(0, x, y);
  if (!(m.n > 0.0)) {
    m.n = 0.0;
    return m;
  }
  m.hits = tile.at(1, x, y);
  m.noise_power = tile.at(2, x, y) / m.n;
  int p = 3;
  std::size_t l = 0;
  for (int a = 0; a < q; ++a) {
    for (int b = a; b < q; ++b) {
      const double re = tile.at(p++, x, y);
      const double im = a != b ? tile.at(p++, x, y) : 0.0;
      m.layers[l++] = cdouble{re / m.n, im / m.n};
    }
  }
  return m;
}

CellPowers cell_powers(const GridmapSumTile& tile, int x, int y) {
  // Per-cell hot path of the raster rendering: no allocation (at most 6 layers).
  CellPowers out;
  const double n = tile.at(0, x, y);
  if (!(n > 0.0)) return out;
  const int q = pol_dimension(tile.level());
  std::array<cdouble, 6> layers{};
  int p = 3;
  std::size_t l = 0;
  double trace = 0.0;
  for (int a = 0; a < q; ++a) {
    for (int b = a; b < q; ++b) {
      const double re = tile.at(p++, x, y) / n;
      const double im = a != b ? tile.at(p++, x, y) / n : 0.0;
      layers[l++] = cdouble{re, im};
      if (a == b) trace += re;
    }
  }
  const auto [odd, even] = cell_mechanism_powers(std::span<const cdouble>(layers.data(), l),
                                                 tile.level(), tile.at(2, x, y) / n);
  out.n = n;
  out.n_power = n * std::max(0.0, trace);
  out.n_odd = n * odd;
  out.n_even = n * even;
  return out;
}

}  // namespace polmap::mapping
