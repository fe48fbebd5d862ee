// The merged PreCFAR gridmap as a Cloud Optimized GeoTIFF (export.hpp).
#include <gdal_priv.h>
#include <ogr_spatialref.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>

#include "gdal_output.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/export.hpp"
#include "polmap/mapping_service/gridmap_sums_codec.hpp"
#include "polmap/util/file.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;
using gis_detail::close_dataset;
using gis_detail::driver;
using gis_detail::GdalErrorCapture;
using gis_detail::remove_file;
using gis_detail::total_size;

std::vector<std::string> merged_gridmap_band_names(PolLevel level) {
  std::vector<std::string> names = gridmap_band_names(level);
  names.insert(names.begin() + 1, {"hits", "noise_power"});
  return names;
}

ExportSummary export_merged_gridmap_cog(const MapStore& store, const std::optional<GeoBox>& bbox,
                                        std::optional<PolLevel> level, const fs::path& out) {
  // Which sum tiles: inside the box, of the requested level (or the level most tiles have).
  std::map<int, std::vector<GridmapSumRow>> by_level;
  for (auto& r : store.gridmap_sum_keys(std::nullopt)) {
    if (bbox && !tiles::tile_bounds({kGridmapSumZoom, r.x, r.y}).intersects(*bbox)) continue;
    by_level[r.level].push_back(std::move(r));
  }
  if (level) {
    std::erase_if(by_level, [&](const auto& kv) { return kv.first != static_cast<int>(*level); });
  }
  if (by_level.empty()) {
    throw NotFoundError(std::string("the store has no merged gridmap") +
                        (level ? " of level " + std::string(to_string(*level)) : "") +
                        (bbox ? " in the box" : ""));
  }
  auto best = by_level.begin();
  for (auto it = by_level.begin(); it != by_level.end(); ++it) {
    if (it->second.size() > best->second.size()) best = it;
  }
  const auto lvl = static_cast<PolLevel>(best->first);
  const std::vector<GridmapSumRow>& keys = best->second;
  int x0 = std::numeric_limits<int>::max(), y0 = x0, x1 = -1, y1 = -1;
  for (const auto& k : keys) {
    x0 = std::min(x0, k.x);
    x1 = std::max(x1, k.x);
    y0 = std::min(y0, k.y);
    y1 = std::max(y1, k.y);
  }
  constexpr int kPx = kSumTileCells;
  const std::int64_t w = static_cast<std::int64_t>(x1 - x0 + 1) * kPx;
  const std::int64_t h = static_cast<std::int64_t>(y1 - y0 + 1) * kPx;
  if (w > std::numeric_limits<int>::max() / 2 || h > std::numeric_limits<int>::max() / 2) {
    throw ValidationError("export: merged gridmap extent too large for one GeoTIFF; use --bbox");
  }
  constexpr double kHalf = std::numbers::pi * 6378137.0;  // EPSG:3857 half world
  const double tile_m = 2.0 * kHalf / static_cast<double>(tiles::tiles_per_side(kGridmapSumZoom));
  const std::vector<std::string> names = merged_gridmap_band_names(lvl);
  const int bands = static_cast<int>(names.size());

  // A sparse tiled GeoTIFF first (one 256 × 256 block per sum tile, absent blocks cost
  // nothing), then the COG driver copies it block by block, adding overviews: memory stays
  // at a few blocks whatever the extent.
  remove_file(out);
  const util::ScopedTempDir tmp = util::ScopedTempDir::create(
      out.parent_path().empty() ? fs::path(".") : out.parent_path(), ".merged-gridmap");
  const std::string staging = (tmp.path() / "staging.tif").string();
  GdalErrorCapture capture;
  detail::ScopedGdalConfig no_pam("GDAL_PAM_ENABLED", "NO");
  {
    const char* opts[] = {"TILED=YES",       "BLOCKXSIZE=256", "BLOCKYSIZE=256",
                          "COMPRESS=ZSTD",   "PREDICTOR=3",    "SPARSE_OK=TRUE",
                          "INTERLEAVE=BAND", "BIGTIFF=YES",    nullptr};
    GDALDatasetUniquePtr ds(driver("GTiff")->Create(staging.c_str(), static_cast<int>(w),
                                                    static_cast<int>(h), bands, GDT_Float32,
                                                    const_cast<char**>(opts)));
    if (!ds) throw IoError(staging + ": cannot create GeoTIFF: " + capture.last_message());
    double gt[6] = {-kHalf + x0 * tile_m, tile_m / kPx, 0.0,
                    kHalf - y0 * tile_m,  0.0,          -tile_m / kPx};
    ds->SetGeoTransform(gt);
    OGRSpatialReference srs;
    srs.importFromEPSG(3857);
    ds->SetSpatialRef(&srs);
    for (int b = 0; b < bands; ++b) {
      GDALRasterBand* band = ds->GetRasterBand(b + 1);
      band->SetNoDataValue(std::numeric_limits<double>::quiet_NaN());
      band->SetDescription(names[static_cast<std::size_t>(b)].c_str());
    }
    ds->SetMetadataItem("POLMAP_LAYER",
                        "merged PreCFAR gridmap: N = sum of looks over all drives, hits = sum "
                        "of looks with a stored bin, the other bands the mean noise power and "
                        "the fleet covariance sum(N C) / sum(N)");
    ds->SetMetadataItem("POLMAP_POL_LEVEL", std::string(to_string(lvl)).c_str());
    ds->SetMetadataItem("POLMAP_SUM_ZOOM", std::to_string(kGridmapSumZoom).c_str());
    std::vector<float> block(static_cast<std::size_t>(kPx) * kPx);
    for (const auto& k : keys) {
      const auto rows = store.gridmap_sums_in(k.x, k.y, k.x, k.y);
      const auto row = std::find_if(rows.begin(), rows.end(),
                                    [&](const GridmapSumRow& r) { return r.level == k.level; });
      if (row == rows.end()) continue;  // removed meanwhile
      const GridmapSumTile t = decode_gridmap_sum_tile(
          row->data, "gridmap sum tile " + std::to_string(k.x) + "/" + std::to_string(k.y));
      if (t.empty()) continue;
      for (int b = 0; b < bands; ++b) {
        for (int y = 0; y < kPx; ++y) {
          for (int x = 0; x < kPx; ++x) {
            const float n = t.at(0, x, y);
            float& v = block[static_cast<std::size_t>(y) * kPx + x];
            if (!(n > 0.0F)) {
              v = std::numeric_limits<float>::quiet_NaN();
            } else {
              v = b <= 1 ? t.at(b, x, y) : t.at(b, x, y) / n;  // N and hits are sums
            }
          }
        }
        if (ds->GetRasterBand(b + 1)->WriteBlock(k.x - x0, k.y - y0, block.data()) != CE_None) {
          throw IoError(staging + ": cannot write block: " + capture.last_message());
        }
      }
    }
    close_dataset(std::move(ds), capture, staging);
  }
  {
    GDALDatasetUniquePtr src(GDALDataset::Open(staging.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
    if (!src) throw IoError(staging + ": cannot reopen: " + capture.last_message());
    const char* opts[] = {"COMPRESS=ZSTD",
                          "PREDICTOR=YES",
                          "BLOCKSIZE=256",
                          "OVERVIEWS=AUTO",
                          "OVERVIEW_RESAMPLING=AVERAGE",
                          "SPARSE_OK=TRUE",
                          "BIGTIFF=YES",
                          nullptr};
    const std::string path = out.string();
    GDALDatasetUniquePtr cog(driver("COG")->CreateCopy(path.c_str(), src.get(), FALSE,
                                                       const_cast<char**>(opts), nullptr, nullptr));
    if (!cog) throw IoError(path + ": cannot write COG: " + capture.last_message());
    close_dataset(std::move(cog), capture, path);
  }
  ExportSummary summary;
  summary.gridmap_tiles = keys.size();
  summary.files = {out};
  summary.bytes = total_size(summary.files);
  return summary;
}

}  // namespace polmap::mapping
