// Drive package writer fed by the radar front end (CovarianceGridmap tiles, processed drives).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>
#include <set>

#include "package_internal.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/drive_processor.hpp"
#include "polmap/radar/line_extractor.hpp"
#include "polmap/radar/point_extractor.hpp"

namespace polmap::mapping {

namespace fs = std::filesystem;

namespace detail {
DriveManifest prepare_manifest(DriveManifest m, const PackageWriteOptions& options);
DriveManifest finish_package(DriveManifest m, const DrivePackage& values, const fs::path& tmp,
                             const fs::path& dir, const PackageWriteOptions& options);
std::vector<std::pair<std::string, std::string>> tiff_metadata(const DriveManifest& m);
GridmapInfo gridmap_info(int width, int height, double origin_x_m, double origin_y_m, int q,
                         double noise_power, const PackageWriteOptions& options);
GridmapTiffSpec tiff_spec(const DriveManifest& m, const PackageWriteOptions& options);
void check_package_destination(const fs::path& dir, bool overwrite);
util::ScopedTempDir make_package_temp_dir(const fs::path& dir);
}  // namespace detail

namespace {

/// Adds one tile's cells (count, layer-major layers, hits; kTileSizeCells² each) to a
/// mapping-mode gridmap of the map's level and cell size.
void merge_tile_cells(radar::CovarianceGridmap& map, int tx, int ty,
                      std::span<const std::uint32_t> count,
                      std::span<const std::complex<float>> layers,
                      std::span<const std::uint32_t> hits) {
  constexpr int ts = radar::kTileSizeCells;
  const double cs = map.cell_size_m();
  const int q = pol_dimension(map.level());
  radar::CovarianceTileView v;
  v.tile_x = tx;
  v.tile_y = ty;
  v.size_cells = ts;
  v.origin_x_m = tx * ts * cs;
  v.origin_y_m = ty * ts * cs;
  v.cell_size_m = cs;
  v.level = map.level();
  v.q = q;
  v.num_layers = q * (q + 1) / 2;
  v.count = count;
  v.layers = layers;
  v.hits = hits;
  map.merge_tile(v);
}

}  // namespace

DriveManifest write_drive_package(const DrivePackage& pkg, const radar::CovarianceGridmap& gridmap,
                                  const fs::path& dir, const PackageWriteOptions& options) {
  detail::ensure_gdal();
  DriveManifest m = detail::prepare_manifest(pkg.manifest, options);
  if (gridmap.level() != m.pol_level) {
    throw ValidationError("write_drive_package: gridmap level '" +
                          std::string(to_string(gridmap.level())) + "' differs from pol_level '" +
                          std::string(to_string(m.pol_level)) + "'");
  }
  const double cs = gridmap.cell_size_m();
  if (std::abs(cs - m.cell_size_m) > 1e-9 * m.cell_size_m) {
    throw ValidationError("write_drive_package: gridmap cell size differs from cell_size_m");
  }
  detail::check_package_destination(dir, options.overwrite);
  const int q = pol_dimension(m.pol_level);
  const int bs = detail::kGridmapBlockSize;

  radar::CellBox bounds = gridmap.bounds();
  if (bounds.empty()) bounds = {0, 0, 1, 1};  // an empty drive: one empty cell at the origin
  const int width = bounds.width();
  const int height = bounds.height();
  m.has_gridmap = !(options.format_version >= 2 && options.landmarks_only);
  m.gridmap = detail::gridmap_info(width, height, bounds.min_ix * cs, bounds.max_iy * cs, q,
                                   gridmap.noise_power(), options);

  // GeoTIFF blocks touched by allocated tiles, in row-major block order (deterministic).
  std::set<std::pair<int, int>> blocks;  // (by, bx)
  const int ts = radar::kTileSizeCells;
  for (const auto& [tx, ty] : gridmap.tile_indices()) {
    const int c0 = std::max(tx * ts, bounds.min_ix) - bounds.min_ix;
    const int c1 = std::min((tx + 1) * ts, bounds.max_ix) - bounds.min_ix - 1;
    const int r0 = bounds.max_iy - std::min((ty + 1) * ts, bounds.max_iy);
    const int r1 = bounds.max_iy - 1 - std::max(ty * ts, bounds.min_iy);
    for (int by = r0 / bs; by <= r1 / bs; ++by) {
      for (int bx = c0 / bs; bx <= c1 / bs; ++bx) blocks.insert({by, bx});
    }
  }

  const util::ScopedTempDir staging = detail::make_package_temp_dir(dir);
  const fs::path& tmp = staging.path();
  if (!m.has_gridmap) return detail::finish_package(std::move(m), pkg, tmp, dir, options);
  {
    const detail::GridmapTiffSpec spec = detail::tiff_spec(m, options);
    detail::GridmapTiffWriter writer((tmp / kGridmapFileName).string(), spec);
    detail::GridmapBlockBuffer block(writer.num_bands());
    std::optional<GridmapCodec> codec;
    if (m.gridmap.compact) codec.emplace(q, m.gridmap.noise_power, m.gridmap.codec);
    const int L = q * (q + 1) / 2;
    std::vector<std::uint16_t> codes(static_cast<std::size_t>(2 + 1 + q * q));
    std::vector<std::complex<float>> cell(static_cast<std::size_t>(L));
    for (const auto& [by, bx] : blocks) {
      // Cell box of this block (north-up rows: row r <-> iy = max_iy - 1 - r).
      radar::CellBox box;
      box.min_ix = bounds.min_ix + bx * bs;
      box.max_ix = std::min(box.min_ix + bs, bounds.max_ix);
      box.max_iy = bounds.max_iy - by * bs;
      box.min_iy = std::max(box.max_iy - bs, bounds.min_iy);
      const radar::CovarianceRaster r = gridmap.raster(box);
      const std::size_t plane = r.plane_size();
      block.clear();
      for (int iy = box.min_iy; iy < box.max_iy; ++iy) {
        const int row = box.max_iy - 1 - iy;
        for (int ix = box.min_ix; ix < box.max_ix; ++ix) {
          const std::size_t src =
              static_cast<std::size_t>(iy - box.min_iy) * box.width() + (ix - box.min_ix);
          const std::size_t dst = static_cast<std::size_t>(row) * bs + (ix - box.min_ix);
          const std::uint32_t n = r.count[src];
          if (n == 0) continue;
          if (codec) {
            for (int l = 0; l < L; ++l) cell[l] = r.layers[l * plane + src];
            codec->encode_cell(n, r.hits[src], cell, codes);
            for (int b = 0; b < codec->codes_per_cell(); ++b) block.band(b)[dst] = codes[b];
            continue;
          }
          block.band(0)[dst] = static_cast<float>(std::min(n, detail::kMaxExactCount));
          int band = 1;
          int layer = 0;
          for (int i = 0; i < q; ++i) {
            for (int j = i; j < q; ++j, ++layer) {
              const std::complex<float> v = r.layers[layer * plane + src];
              block.band(band++)[dst] = v.real();
              if (i != j) block.band(band++)[dst] = v.imag();
            }
          }
        }
      }
      writer.write_block(bx, by, block);
    }
    writer.close();
    return detail::finish_package(std::move(m), pkg, tmp, dir, options);  // renames tmp
  }
}

DriveManifest write_drive_package(const radar::DriveProcessingResult& result, const fs::path& dir,
                                  const PackageWriteOptions& options) {
  const RecordingHeader& h = result.header;
  DrivePackage pkg;
  DriveManifest& m = pkg.manifest;
  m.drive_id = h.drive_id;
  m.vehicle_id = h.vehicle_id;
  m.world = h.world;
  m.origin = result.frame.origin();
  m.crs_proj = result.frame.proj_string();
  m.sensors = h.sensors;
  m.pol_level = result.gridmap.level();
  m.cell_size_m = result.gridmap.cell_size_m();
  m.distance_m = result.stats.distance_m;
  m.producer = h.producer.empty() ? "polmap" : "polmap (recording: " + h.producer + ")";
  pkg.points = result.points;
  pkg.lines = result.lines;
  // The package's trajectory is strictly time-ordered (as the pose interpolation used it):
  // repeated or out-of-order samples of the log are dropped.
  pkg.trajectory.reserve(result.trajectory.size());
  for (const auto& s : result.trajectory) {
    if (pkg.trajectory.empty() || s.time_s > pkg.trajectory.back().time_s) {
      pkg.trajectory.push_back(s);
    }
  }
  if (!pkg.trajectory.empty()) {
    m.start_time_s = pkg.trajectory.front().time_s;
    m.end_time_s = pkg.trajectory.back().time_s;
  } else {
    m.start_time_s = m.end_time_s = h.start_time_s;
  }
  return write_drive_package(pkg, result.gridmap, dir, options);
}

radar::CovarianceGridmap read_covariance_gridmap(const DrivePackage& pkg) {
  if (!pkg.manifest.has_gridmap) {
    throw NotFoundError("read_covariance_gridmap: the package has no gridmap (landmarks only)");
  }
  radar::GridmapConfig cfg;
  cfg.cell_size_m = pkg.manifest.cell_size_m;
  cfg.level = pkg.manifest.pol_level;
  radar::CovarianceGridmap map(cfg);
  if (pkg.manifest.gridmap.compact) map.set_noise_power(pkg.manifest.gridmap.noise_power);
  const int q = pol_dimension(cfg.level);
  const int L = q * (q + 1) / 2;
  const double cs = cfg.cell_size_m;
  constexpr int ts = radar::kTileSizeCells;
  std::vector<std::uint32_t> count(ts * ts), hits(ts * ts);
  std::vector<std::complex<float>> layers(static_cast<std::size_t>(L) * ts * ts);
  for_each_gridmap_block(pkg, [&](const GridmapRaster& b) {
    // Block cell (col, row) is map cell (ix0 + col, iy_top - row); the raster is aligned to
    // the map's cell grid (schema/drive_package.md), so the indices are exact integers.
    const int ix0 = static_cast<int>(std::lround(b.origin_x_m / cs));
    const int iy_top = static_cast<int>(std::lround(b.origin_y_m / cs)) - 1;
    const int iy_bottom = iy_top - b.height + 1;
    const auto floor_div = [](int a, int d) { return a >= 0 ? a / d : -((-a + d - 1) / d); };
    for (int ty = floor_div(iy_bottom, ts); ty <= floor_div(iy_top, ts); ++ty) {
      for (int tx = floor_div(ix0, ts); tx <= floor_div(ix0 + b.width - 1, ts); ++tx) {
        std::fill(count.begin(), count.end(), 0U);
        std::fill(hits.begin(), hits.end(), 0U);
        std::fill(layers.begin(), layers.end(), std::complex<float>{});
        bool any = false;
        for (int r = 0; r < ts; ++r) {
          const int iy = ty * ts + r;
          const int row = iy_top - iy;
          if (row < 0 || row >= b.height) continue;
          for (int c = 0; c < ts; ++c) {
            const int col = tx * ts + c - ix0;
            if (col < 0 || col >= b.width) continue;
            const std::size_t src = static_cast<std::size_t>(row) * b.width + col;
            if (b.count[src] == 0) continue;
            any = true;
            const std::size_t dst = static_cast<std::size_t>(r) * ts + c;
            count[dst] = b.count[src];
            hits[dst] = b.hits.empty() ? b.count[src] : b.hits[src];
            for (int l = 0; l < L; ++l) {
              layers[static_cast<std::size_t>(l) * ts * ts + dst] =
                  std::complex<float>(b.layers[l][src]);
            }
          }
        }
        if (any) merge_tile_cells(map, tx, ty, count, layers, hits);
      }
    }
  });
  return map;
}

radar::CovarianceGridmap compact_round_trip(const radar::CovarianceGridmap& gridmap,
                                            const GridmapCodecConfig& codec_cfg) {
  radar::GridmapConfig cfg;
  cfg.cell_size_m = gridmap.cell_size_m();
  cfg.level = gridmap.level();
  radar::CovarianceGridmap out(cfg);
  out.set_noise_power(gridmap.noise_power());
  if (!(gridmap.noise_power() > 0.0)) {
    throw ValidationError("compact_round_trip: the gridmap has no noise power");
  }
  const int q = pol_dimension(cfg.level);
  const int L = q * (q + 1) / 2;
  const GridmapCodec codec(q, gridmap.noise_power(), codec_cfg);
  constexpr int ts = radar::kTileSizeCells;
  std::vector<std::uint32_t> count(ts * ts), hits(ts * ts);
  std::vector<std::complex<float>> layers(static_cast<std::size_t>(L) * ts * ts);
  std::vector<std::complex<float>> cell(static_cast<std::size_t>(L));
  std::vector<std::uint16_t> codes(static_cast<std::size_t>(codec.codes_per_cell()));
  for (const auto& [tx, ty] : gridmap.tile_indices()) {
    const radar::CellBox box{tx * ts, ty * ts, (tx + 1) * ts, (ty + 1) * ts};
    const radar::CovarianceRaster r = gridmap.raster(box);
    const std::size_t plane = r.plane_size();
    std::fill(count.begin(), count.end(), 0U);
    std::fill(hits.begin(), hits.end(), 0U);
    std::fill(layers.begin(), layers.end(), std::complex<float>{});
    bool any = false;
    for (std::size_t i = 0; i < plane; ++i) {
      if (r.count[i] == 0) continue;
      for (int l = 0; l < L; ++l) cell[l] = r.layers[l * plane + i];
      codec.encode_cell(r.count[i], r.hits[i], cell, codes);
      // As the reader does it: decoded in double, stored as float (block_to_raster,
      // read_covariance_gridmap).
      const GridmapCodec::Cell d = codec.decode_cell(codes);
      if (d.n == 0) continue;
      any = true;
      count[i] = d.n;
      hits[i] = d.hits;
      for (int l = 0; l < L; ++l) layers[l * plane + i] = std::complex<float>(d.layers[l]);
    }
    if (any) merge_tile_cells(out, tx, ty, count, layers, hits);
  }
  return out;
}

void extract_candidates_as_sent(radar::DriveProcessingResult& result,
                                const radar::DriveProcessingConfig& cfg,
                                const GridmapCodecConfig& codec) {
  if (!cfg.extract_points && !cfg.extract_lines) return;
  using Clock = std::chrono::steady_clock;
  const auto t_start = Clock::now();
  const radar::CovarianceGridmap sent = compact_round_trip(result.gridmap, codec);
  if (cfg.extract_points) {
    const auto t0 = Clock::now();
    result.points = radar::extract_points(sent, cfg.points);
    result.stats.points_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  }
  if (cfg.extract_lines) {
    const auto t0 = Clock::now();
    result.lines = radar::extract_lines(sent, cfg.lines);
    result.stats.lines_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  }
  result.stats.total_seconds += std::chrono::duration<double>(Clock::now() - t_start).count();
}

bool sends_compact_gridmap(const PackageWriteOptions& options) {
  return options.format_version >= 2 && !options.landmarks_only;
}

radar::DriveProcessingResult process_drive_for_package(
    RecordSource& source, radar::DriveProcessingConfig cfg, const PackageWriteOptions& options,
    const std::function<void(double time_s)>& progress) {
  const bool as_sent = sends_compact_gridmap(options);
  const bool points = cfg.extract_points, lines = cfg.extract_lines;
  if (as_sent) cfg.extract_points = cfg.extract_lines = false;
  radar::DriveProcessingResult result = radar::process_drive(source, cfg, progress);
  if (!as_sent) return result;
  cfg.extract_points = points;
  cfg.extract_lines = lines;
  extract_candidates_as_sent(result, cfg, options.codec);
  return result;
}

}  // namespace polmap::mapping
