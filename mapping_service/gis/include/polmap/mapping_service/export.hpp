#pragma once
/// @file export.hpp
/// GIS export of a map version (GDAL/OGR): consensus landmarks as GeoPackage,
/// GeoJSON or Shapefile, and the fleet gridmap as GeoTIFF.
///
/// Landmark files (all WGS84 / EPSG:4326, lon/lat axis order), one feature per landmark:
///   fields  id (Integer64, store row id), key (Integer64, stable landmark key),
///           support (Integer, distinct drives that saw it), members (Integer,
///           supporting candidates; 0 when exported without support lists),
///           spread_m (Real, RMS distance of members), version (Integer64, map version);
///           points also scattering (String: unknown/odd/even/mixed),
///           lines also length_m (Real) and vertices (Integer).
///   gpkg     one file, layers `points` (Point) and `lines` (LineString).
///   geojson  one RFC 7946 FeatureCollection holding both (Point and LineString
///            features; property `layer` = "points" | "lines"), coordinates to 1e-8°
///            (~1 mm). QGIS splits it into a point and a line layer on open.
///   shp      a Shapefile is one geometry type per file set, so two: points.{shp,shx,dbf,
///            prj,cpg} and lines.{...} (UTF-8). `out` ending in ".zip": both sets in one
///            zip archive (what the HTTP export serves); otherwise `out` is a directory
///            that receives the files. Field names are <= 10 characters, so the same
///            names are used in every format.
/// Fleet gridmap (`gtiff`): the map version's fleet gridmap layer (fleet_gridmap.hpp) at
/// its base zoom as a single-band Float32 GeoTIFF of mean power in dB, EPSG:3857, NaN =
/// no data; each XYZ tile is one 256 x 256 GeoTIFF block (DEFLATE, sparse), so a
/// city-sized export never holds more than one tile in memory. A drive-frame covariance
/// raster (GridmapRaster) exports with the drive package's band layout.
/// Merged gridmap (`cog`): the store's merged PreCFAR gridmap (gridmap_sums.hpp: the
/// covariance sums of all drives, store state rather than a version's) as a multi-band
/// Float32 Cloud Optimized GeoTIFF, EPSG:3857, pixels = the z20 sum grid (0.149 m ×
/// cos(lat)); bands N (Σ looks), hits (Σ looks with a stored bin), noise_power (Σ N σ² /
/// Σ N), then the fleet covariance
/// Σ N C / Σ N with the drive package's names (C_LL_LL, C_LL_LR.re, C_LL_LR.im, ...); NaN
/// where no drive looked. ZSTD with the floating-point predictor, 256 × 256 blocks,
/// AVERAGE overviews. One polarimetric level per file (the one with most tiles, or the
/// requested one).
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/mapping_service/drive_package.hpp"
#include "polmap/mapping_service/store.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::mapping {

enum class ExportFormat { GeoPackage, GeoJson, Shapefile, GeoTiff, MergedGridmapCog };

/// "gpkg", "geojson", "shp", "gtiff", "cog".
[[nodiscard]] std::string_view to_string(ExportFormat f);
[[nodiscard]] std::optional<ExportFormat> parse_export_format(std::string_view s);
/// MIME type of the single-file form: application/geopackage+sqlite3, application/geo+json,
/// application/zip (shp), image/tiff (gtiff, cog).
[[nodiscard]] std::string_view export_content_type(ExportFormat f);
/// File name extension of the single-file form: ".gpkg", ".geojson", ".zip", ".tif".
[[nodiscard]] std::string_view export_file_extension(ExportFormat f);

struct LandmarkExportOptions {
  /// Written into every feature's `version` field.
  std::int64_t map_version = 0;
};

/// What an export wrote.
struct ExportSummary {
  std::uint64_t points = 0;
  std::uint64_t lines = 0;
  std::uint64_t gridmap_tiles = 0;
  std::vector<std::filesystem::path> files;  ///< written files (a directory's members for shp)
  std::uint64_t bytes = 0;                   ///< total size of `files`
};

/// Writes landmarks (positions WGS84) in a vector format (not GeoTiff). Replaces `out`
/// (for a Shapefile directory: the points.* and lines.* files in it). Lines need >= 2
/// vertices; landmarks with non-finite coordinates are rejected (ValidationError).
/// Throws IoError when GDAL cannot write.
ExportSummary export_landmarks(const LandmarkSet& landmarks, ExportFormat format,
                               const std::filesystem::path& out,
                               const LandmarkExportOptions& options = {});

/// Writes Web-Mercator gridmap tiles of one zoom as a Float32 dB GeoTIFF (EPSG:3857,
/// NaN no data). `keys` (any order, all of zoom `zoom`) define the extent: the tile range
/// they span; load_db(key) returns the tile's 256 x 256 dB pixels (row-major, NaN
/// unobserved), called once per key in (y, x) order.
ExportSummary export_mercator_gridmap_geotiff(
    int zoom, std::span<const tiles::TileKey> keys,
    const std::function<std::vector<float>(const tiles::TileKey&)>& load_db,
    const std::filesystem::path& out);

/// Writes a covariance raster (drive or region frame `crs_proj`, level `level`) as a
/// GeoTIFF with the drive package's gridmap.tif band layout (schema/drive_package.md).
ExportSummary export_covariance_geotiff(const GridmapRaster& raster, PolLevel level,
                                        const std::string& crs_proj,
                                        const std::filesystem::path& out);

/// Band names of the merged-gridmap COG of a level (file comment).
[[nodiscard]] std::vector<std::string> merged_gridmap_band_names(PolLevel level);

/// Writes the store's merged gridmap inside `bbox` (all if nullopt) of `level` (the level
/// with most sum tiles if nullopt) as a COG (file comment). NotFoundError when there is
/// none; ValidationError when the extent exceeds one GeoTIFF.
ExportSummary export_merged_gridmap_cog(const MapStore& store, const std::optional<GeoBox>& bbox,
                                        std::optional<PolLevel> level,
                                        const std::filesystem::path& out);

/// Store-level export (CLI `polmap export`, `GET /v1/export`): landmarks of a published
/// map version inside `bbox` (all if nullopt) in a vector format, or (GeoTiff) the
/// version's fleet gridmap tiles at their base zoom intersecting `bbox`. Shapefile output
/// is a zip when `out` ends in ".zip", else a directory. Throws NotFoundError for an
/// unknown/unpublished version or a version without gridmap tiles (GeoTiff).
ExportSummary export_map(const MapStore& store, std::int64_t version, ExportFormat format,
                         const std::optional<GeoBox>& bbox, const std::filesystem::path& out);

}  // namespace polmap::mapping
