// Detectors on the merged gridmap (merged_gridmap_extract.hpp).
#include "polmap/mapping_service/merged_gridmap_extract.hpp"

#include <cmath>
#include <map>

#include "polmap/mapping_service/gridmap_sums_codec.hpp"
#include "polmap/radar/covariance_gridmap.hpp"

namespace polmap::mapping {

MergedExtraction extract_from_merged_gridmap(const MapStore& store, const GeoBox& region,
                                             const MergedExtractionConfig& cfg) {
  MergedExtraction out;
  const auto nw = tiles::to_mercator_tiles(region.max_lat_deg, region.min_lon_deg, kGridmapSumZoom);
  const auto se = tiles::to_mercator_tiles(region.min_lat_deg, region.max_lon_deg, kGridmapSumZoom);
  const auto rows = store.gridmap_sums_in(static_cast<int>(nw.x), static_cast<int>(nw.y),
                                          static_cast<int>(se.x), static_cast<int>(se.y));
  std::map<int, int> per_level;
  for (const auto& r : rows) ++per_level[r.level];
  if (cfg.level) std::erase_if(per_level, [&](auto& kv) { return kv.first != int(*cfg.level); });
  if (per_level.empty()) return out;
  auto best = per_level.begin();
  for (auto it = per_level.begin(); it != per_level.end(); ++it) {
    if (it->second > best->second) best = it;
  }
  out.level = static_cast<PolLevel>(best->first);
  out.status = MergedExtraction::Status::Ok;

  // Region frame: X0, Y0 = the sum grid's NW cell of the region.
  const std::int64_t X0 = static_cast<std::int64_t>(nw.x) * kSumTileCells;
  const std::int64_t Y0 = static_cast<std::int64_t>(nw.y) * kSumTileCells;
  const double mid_lat = 0.5 * (region.min_lat_deg + region.max_lat_deg);
  const double cell_m =
      2.0 * M_PI * 6378137.0 /
      (static_cast<double>(tiles::tiles_per_side(kGridmapSumZoom)) * kSumTileCells) *
      std::cos(mid_lat * M_PI / 180.0);
  radar::GridmapConfig gc;
  gc.cell_size_m = cell_m;
  gc.level = out.level;
  radar::CovarianceGridmap map(gc);
  const int q = pol_dimension(out.level);
  const int L = q * (q + 1) / 2;
  constexpr int ts = radar::kTileSizeCells;
  static_assert(kSumTileCells % ts == 0);
  std::vector<std::uint32_t> count(ts * ts), hits(ts * ts);
  std::vector<std::complex<float>> layers(static_cast<std::size_t>(L) * ts * ts);
  double n_sum = 0.0, noise_sum = 0.0;
  for (const auto& r : rows) {
    if (r.level != best->first) continue;
    const GridmapSumTile t = decode_gridmap_sum_tile(
        r.data, "gridmap sum tile " + std::to_string(r.x) + "/" + std::to_string(r.y));
    ++out.sum_tiles;
    // Sum tile cells (cx, cy) -> global (X, Y) -> map cell (ix, iy) = (X − X0, Y0 − 1 − Y).
    for (int by = 0; by < kSumTileCells / ts; ++by) {
      for (int bx = 0; bx < kSumTileCells / ts; ++bx) {
        const std::int64_t gx0 = static_cast<std::int64_t>(r.x) * kSumTileCells + bx * ts;
        const std::int64_t gy0 = static_cast<std::int64_t>(r.y) * kSumTileCells + by * ts;
        // The radar tile holding these cells: ix0 = gx0 − X0; its rows run south to north.
        const auto ix0 = static_cast<int>(gx0 - X0);
        const auto iy_top = static_cast<int>(Y0 - 1 - gy0);
        const int tx = ix0 / ts;  // ix0 >= 0 and a multiple of ts
        const int ty = (iy_top - (ts - 1)) >= 0 ? (iy_top - (ts - 1)) / ts
                                                : -((-(iy_top - (ts - 1)) + ts - 1) / ts);
        std::fill(count.begin(), count.end(), 0U);
        std::fill(hits.begin(), hits.end(), 0U);
        std::fill(layers.begin(), layers.end(), std::complex<float>{});
        bool any = false;
        for (int cy = 0; cy < ts; ++cy) {
          for (int cx = 0; cx < ts; ++cx) {
            const MergedCell m = merged_cell(t, bx * ts + cx, by * ts + cy);
            if (m.n < 0.5) continue;
            any = true;
            const int iy = iy_top - cy;
            const int row = iy - ty * ts;
            const std::size_t dst = static_cast<std::size_t>(row) * ts + cx;
            count[dst] = static_cast<std::uint32_t>(std::lround(m.n));
            hits[dst] = std::min(count[dst], static_cast<std::uint32_t>(std::lround(m.hits)));
            for (int l = 0; l < L; ++l) {
              layers[static_cast<std::size_t>(l) * ts * ts + dst] =
                  std::complex<float>(m.layers[static_cast<std::size_t>(l)]);
            }
            n_sum += m.n;
            noise_sum += m.n * m.noise_power;
          }
        }
        if (!any) continue;
        radar::CovarianceTileView v;
        v.tile_x = tx;
        v.tile_y = ty;
        v.size_cells = ts;
        v.origin_x_m = tx * ts * cell_m;
        v.origin_y_m = ty * ts * cell_m;
        v.cell_size_m = cell_m;
        v.level = out.level;
        v.q = q;
        v.num_layers = L;
        v.count = count;
        v.layers = layers;
        v.hits = hits;
        map.merge_tile(v);
      }
    }
  }
  out.noise_power = n_sum > 0.0 ? noise_sum / n_sum : 0.0;
  map.set_noise_power(out.noise_power);
  auto to_geo = [&](const Eigen::Vector2d& p) {
    const double X = static_cast<double>(X0) + p.x() / cell_m;
    const double Y = static_cast<double>(Y0) - p.y() / cell_m;
    return tiles::from_mercator_tiles(X / kSumTileCells, Y / kSumTileCells, kGridmapSumZoom);
  };
  out.point_candidates = radar::extract_points(map, cfg.points);
  for (const auto& p : out.point_candidates) {
    const GeoPoint g = to_geo(p.position_m);
    if (region.contains(g.lat_deg, g.lon_deg)) out.points.push_back(g);
  }
  for (const auto& l : radar::extract_lines(map, cfg.lines)) {
    out.lines.emplace_back(to_geo(l.start_m), to_geo(l.end_m));
  }
  return out;
}

}  // namespace polmap::mapping
