// Drive package writer fed by the radar front end (CovarianceGridmap tiles, processed drives).
#include <algorithm>
#include <set>

#include "package_internal.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/drive_processor.hpp"

namespace polmap::mapping {

namespace fs = std::filesystem;

namespace detail {
DriveManifest prepare_manifest(DriveManifest m, const PackageWriteOptions& options);
DriveManifest finish_package(DriveManifest m, const DrivePackage& values, const fs::path& tmp,
                             const fs::path& dir, const PackageWriteOptions& options);
std::vector<std::pair<std::string, std::string>> tiff_metadata(const DriveManifest& m);
void check_package_destination(const fs::path& dir, bool overwrite);
util::ScopedTempDir make_package_temp_dir(const fs::path& dir);
}  // namespace detail

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
  m.gridmap = {width,
               height,
               bounds.min_ix * cs,
               bounds.max_iy * cs,
               1 + q * q,
               detail::kGridmapBlockSize,
               std::clamp(options.mantissa_bits, 1, 23)};

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
  {
    detail::GridmapTiffSpec spec;
    spec.width = width;
    spec.height = height;
    spec.origin_x_m = m.gridmap.origin_x_m;
    spec.origin_y_m = m.gridmap.origin_y_m;
    spec.cell_size_m = cs;
    spec.level = m.pol_level;
    spec.crs_proj = m.crs_proj;
    spec.deflate_level = options.deflate_level;
    spec.mantissa_bits = std::clamp(options.mantissa_bits, 1, 23);
    spec.metadata = detail::tiff_metadata(m);
    detail::GridmapTiffWriter writer((tmp / kGridmapFileName).string(), spec);
    detail::GridmapBlockBuffer block(writer.num_bands());
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

}  // namespace polmap::mapping
