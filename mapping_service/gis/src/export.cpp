// GIS export (GDAL/OGR): landmarks as GeoPackage / GeoJSON / Shapefile, gridmaps as GeoTIFF.
#include "polmap/mapping_service/export.hpp"

#include <cpl_conv.h>
#include <gdal_priv.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>

#include <cmath>
#include <limits>
#include <numbers>
#include <set>

#include "gdal_output.hpp"
#include "polmap/mapping_service/detail/gdal.hpp"
#include "polmap/mapping_service/detail/gridmap_tiff.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/fleet_gridmap.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/util/file.hpp"

namespace polmap::mapping {

namespace fs = std::filesystem;

std::string_view to_string(ExportFormat f) {
  switch (f) {
    case ExportFormat::GeoPackage:
      return "gpkg";
    case ExportFormat::GeoJson:
      return "geojson";
    case ExportFormat::Shapefile:
      return "shp";
    case ExportFormat::GeoTiff:
      return "gtiff";
    case ExportFormat::MergedGridmapCog:
      return "cog";
  }
  return "gpkg";
}

std::optional<ExportFormat> parse_export_format(std::string_view s) {
  for (auto f : {ExportFormat::GeoPackage, ExportFormat::GeoJson, ExportFormat::Shapefile,
                 ExportFormat::GeoTiff, ExportFormat::MergedGridmapCog}) {
    if (to_string(f) == s) return f;
  }
  return std::nullopt;
}

std::string_view export_content_type(ExportFormat f) {
  switch (f) {
    case ExportFormat::GeoPackage:
      return "application/geopackage+sqlite3";
    case ExportFormat::GeoJson:
      return "application/geo+json";
    case ExportFormat::Shapefile:
      return "application/zip";
    case ExportFormat::GeoTiff:
    case ExportFormat::MergedGridmapCog:
      return "image/tiff";
  }
  return "application/octet-stream";
}

std::string_view export_file_extension(ExportFormat f) {
  switch (f) {
    case ExportFormat::GeoPackage:
      return ".gpkg";
    case ExportFormat::GeoJson:
      return ".geojson";
    case ExportFormat::Shapefile:
      return ".zip";
    case ExportFormat::GeoTiff:
    case ExportFormat::MergedGridmapCog:
      return ".tif";
  }
  return "";
}

namespace {

using detail::GdalErrorCapture;
using gis_detail::close_dataset;
using gis_detail::driver;
using gis_detail::remove_file;
using gis_detail::total_size;

constexpr const char* kShapefileExts[] = {".shp", ".shx", ".dbf", ".prj", ".cpg"};

bool finite_geo(const GeoPoint& p) {
  return std::isfinite(p.lat_deg) && std::isfinite(p.lon_deg) && std::abs(p.lat_deg) <= 90.0 &&
         std::abs(p.lon_deg) <= 180.0;
}

double polyline_length_m(const std::vector<GeoPoint>& pl) {
  if (pl.size() < 2) return 0.0;
  const tiles::LocalFrame frame(pl.front());
  double len = 0.0;
  for (std::size_t i = 1; i < pl.size(); ++i) {
    len += (frame.to_local(pl[i]) - frame.to_local(pl[i - 1])).norm();
  }
  return len;
}

void check_landmarks(const LandmarkSet& lm) {
  for (std::size_t i = 0; i < lm.points.size(); ++i) {
    if (!finite_geo(lm.points[i].position)) {
      throw ValidationError("export: point landmark " + std::to_string(lm.points[i].id) +
                            ": position not a finite WGS84 coordinate");
    }
  }
  for (const auto& l : lm.lines) {
    if (l.polyline.size() < 2) {
      throw ValidationError("export: line landmark " + std::to_string(l.id) +
                            ": fewer than 2 vertices");
    }
    for (const auto& p : l.polyline) {
      if (!finite_geo(p)) {
        throw ValidationError("export: line landmark " + std::to_string(l.id) +
                              ": vertex not a finite WGS84 coordinate");
      }
    }
  }
}

OGRSpatialReference wgs84_lonlat() {
  OGRSpatialReference srs;
  srs.importFromEPSG(4326);
  srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  return srs;
}

void add_fields(OGRLayer* layer, bool points, bool lines, bool layer_field,
                const std::string& out) {
  std::vector<std::pair<const char*, OGRFieldType>> fields;
  if (layer_field) fields.push_back({"layer", OFTString});
  fields.insert(fields.end(), {{"id", OFTInteger64},
                               {"key", OFTInteger64},
                               {"support", OFTInteger},
                               {"members", OFTInteger},
                               {"spread_m", OFTReal},
                               {"version", OFTInteger64}});
  if (points) fields.push_back({"scattering", OFTString});
  if (lines) {
    fields.push_back({"length_m", OFTReal});
    fields.push_back({"vertices", OFTInteger});
  }
  for (const auto& [name, type] : fields) {
    OGRFieldDefn def(name, type);
    if (type == OFTString) def.SetWidth(16);
    if (layer->CreateField(&def) != OGRERR_NONE) {
      throw IoError(out + ": cannot create field " + name);
    }
  }
}

void write_point_features(OGRLayer* layer, const std::vector<StoredPointLandmark>& pts,
                          std::int64_t version, bool layer_field, const std::string& out) {
  OGRFeature f(layer->GetLayerDefn());
  for (const auto& p : pts) {
    f.SetFID(OGRNullFID);
    if (layer_field) f.SetField("layer", "points");
    f.SetField("id", static_cast<GIntBig>(p.id));
    f.SetField("key", static_cast<GIntBig>(p.key));
    f.SetField("support", static_cast<int>(p.support_drives));
    f.SetField("members", static_cast<int>(p.support.size()));
    f.SetField("spread_m", p.spread_m);
    f.SetField("version", static_cast<GIntBig>(version));
    f.SetField("scattering", std::string(to_string(p.scattering)).c_str());
    if (f.GetFieldIndex("length_m") >= 0) f.SetFieldNull(f.GetFieldIndex("length_m"));
    if (f.GetFieldIndex("vertices") >= 0) f.SetFieldNull(f.GetFieldIndex("vertices"));
    OGRPoint g(p.position.lon_deg, p.position.lat_deg);
    f.SetGeometry(&g);
    if (layer->CreateFeature(&f) != OGRERR_NONE) {
      throw IoError(out + ": cannot write point landmark " + std::to_string(p.id));
    }
  }
}

void write_line_features(OGRLayer* layer, const std::vector<StoredLineLandmark>& lines,
                         std::int64_t version, bool layer_field, const std::string& out) {
  OGRFeature f(layer->GetLayerDefn());
  for (const auto& l : lines) {
    f.SetFID(OGRNullFID);
    if (layer_field) f.SetField("layer", "lines");
    f.SetField("id", static_cast<GIntBig>(l.id));
    f.SetField("key", static_cast<GIntBig>(l.key));
    f.SetField("support", static_cast<int>(l.support_drives));
    f.SetField("members", static_cast<int>(l.support.size()));
    f.SetField("spread_m", l.spread_m);
    f.SetField("version", static_cast<GIntBig>(version));
    if (f.GetFieldIndex("scattering") >= 0) f.SetFieldNull(f.GetFieldIndex("scattering"));
    f.SetField("length_m", polyline_length_m(l.polyline));
    f.SetField("vertices", static_cast<int>(l.polyline.size()));
    OGRLineString g;
    for (const auto& p : l.polyline) g.addPoint(p.lon_deg, p.lat_deg);
    f.SetGeometry(&g);
    if (layer->CreateFeature(&f) != OGRERR_NONE) {
      throw IoError(out + ": cannot write line landmark " + std::to_string(l.id));
    }
  }
}

/// Writes the two Shapefile sets into directory `dir`; returns the files written.
std::vector<fs::path> write_shapefiles(const LandmarkSet& lm, const fs::path& dir,
                                       std::int64_t version) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw IoError(dir.string() + ": cannot create: " + ec.message());
  for (const char* layer : {"points", "lines"}) {
    for (const char* ext : kShapefileExts) remove_file(dir / (std::string(layer) + ext));
  }
  GdalErrorCapture capture;
  const std::string out = dir.string();
  GDALDatasetUniquePtr ds(
      driver("ESRI Shapefile")->Create(out.c_str(), 0, 0, 0, GDT_Unknown, nullptr));
  if (!ds) throw IoError(out + ": cannot create Shapefile dataset: " + capture.last_message());
  OGRSpatialReference srs = wgs84_lonlat();
  const char* opts[] = {"ENCODING=UTF-8", nullptr};
  OGRLayer* lp = ds->CreateLayer("points", &srs, wkbPoint, const_cast<char**>(opts));
  OGRLayer* ll = ds->CreateLayer("lines", &srs, wkbLineString, const_cast<char**>(opts));
  if (lp == nullptr || ll == nullptr) throw IoError(out + ": cannot create Shapefile layers");
  add_fields(lp, true, false, false, out);
  add_fields(ll, false, true, false, out);
  write_point_features(lp, lm.points, version, false, out);
  write_line_features(ll, lm.lines, version, false, out);
  close_dataset(std::move(ds), capture, out);
  std::vector<fs::path> files;
  for (const char* layer : {"points", "lines"}) {
    for (const char* ext : kShapefileExts) {
      const fs::path p = dir / (std::string(layer) + ext);
      if (fs::exists(p)) files.push_back(p);
    }
  }
  return files;
}

/// Packs files (flat) into a zip archive with GDAL's zip writer.
void write_zip(const std::vector<fs::path>& files, const fs::path& zip) {
  remove_file(zip);
  GdalErrorCapture capture;
  void* h = CPLCreateZip(zip.c_str(), nullptr);
  if (h == nullptr) throw IoError(zip.string() + ": cannot create zip: " + capture.last_message());
  bool ok = true;
  for (const auto& f : files) {
    const std::string data = util::read_file_bytes(f);
    ok = ok && CPLCreateFileInZip(h, f.filename().c_str(), nullptr) == CE_None &&
         CPLWriteFileInZip(h, data.data(), static_cast<int>(data.size())) == CE_None &&
         CPLCloseFileInZip(h) == CE_None;
  }
  ok = (CPLCloseZip(h) == CE_None) && ok;
  if (!ok) throw IoError(zip.string() + ": cannot write zip: " + capture.last_message());
}

bool ends_with_zip(const fs::path& p) {
  std::string s = p.filename().string();
  for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s.size() > 4 && s.ends_with(".zip");
}

}  // namespace

ExportSummary export_landmarks(const LandmarkSet& lm, ExportFormat format, const fs::path& out,
                               const LandmarkExportOptions& options) {
  check_landmarks(lm);
  ExportSummary summary;
  summary.points = lm.points.size();
  summary.lines = lm.lines.size();
  const std::int64_t version = options.map_version;
  const std::string path = out.string();
  switch (format) {
    case ExportFormat::GeoPackage: {
      remove_file(out);
      GdalErrorCapture capture;
      GDALDatasetUniquePtr ds(driver("GPKG")->Create(path.c_str(), 0, 0, 0, GDT_Unknown, nullptr));
      if (!ds) throw IoError(path + ": cannot create GeoPackage: " + capture.last_message());
      OGRSpatialReference srs = wgs84_lonlat();
      OGRLayer* lp = ds->CreateLayer("points", &srs, wkbPoint, nullptr);
      OGRLayer* ll = ds->CreateLayer("lines", &srs, wkbLineString, nullptr);
      if (lp == nullptr || ll == nullptr) throw IoError(path + ": cannot create layers");
      add_fields(lp, true, false, false, path);
      add_fields(ll, false, true, false, path);
      if (ds->StartTransaction() != OGRERR_NONE) throw IoError(path + ": cannot start transaction");
      write_point_features(lp, lm.points, version, false, path);
      write_line_features(ll, lm.lines, version, false, path);
      if (ds->CommitTransaction() != OGRERR_NONE) throw IoError(path + ": cannot commit");
      close_dataset(std::move(ds), capture, path);
      summary.files = {out};
      break;
    }
    case ExportFormat::GeoJson: {
      remove_file(out);
      GdalErrorCapture capture;
      GDALDatasetUniquePtr ds(
          driver("GeoJSON")->Create(path.c_str(), 0, 0, 0, GDT_Unknown, nullptr));
      if (!ds) throw IoError(path + ": cannot create GeoJSON: " + capture.last_message());
      OGRSpatialReference srs = wgs84_lonlat();
      const char* opts[] = {"RFC7946=YES", "COORDINATE_PRECISION=8", nullptr};
      OGRLayer* l = ds->CreateLayer("landmarks", &srs, wkbUnknown, const_cast<char**>(opts));
      if (l == nullptr) throw IoError(path + ": cannot create layer");
      add_fields(l, true, true, true, path);
      write_point_features(l, lm.points, version, true, path);
      write_line_features(l, lm.lines, version, true, path);
      close_dataset(std::move(ds), capture, path);
      summary.files = {out};
      break;
    }
    case ExportFormat::Shapefile: {
      if (ends_with_zip(out)) {
        const util::ScopedTempDir tmp = util::ScopedTempDir::create("polmap_shp");
        write_zip(write_shapefiles(lm, tmp.path(), version), out);
        summary.files = {out};
      } else {
        summary.files = write_shapefiles(lm, out, version);
      }
      break;
    }
    case ExportFormat::GeoTiff:
    case ExportFormat::MergedGridmapCog:
      throw ValidationError(
          "export_landmarks: landmarks cannot be written as GeoTIFF "
          "(use export_mercator_gridmap_geotiff or export_merged_gridmap_cog for gridmaps)");
  }
  summary.bytes = total_size(summary.files);
  return summary;
}

ExportSummary export_mercator_gridmap_geotiff(
    int zoom, std::span<const tiles::TileKey> keys,
    const std::function<std::vector<float>(const tiles::TileKey&)>& load_db, const fs::path& out) {
  if (keys.empty()) throw NotFoundError("export: no gridmap tiles to export");
  std::set<std::pair<int, int>> order;  // (y, x)
  int x0 = std::numeric_limits<int>::max(), y0 = x0, x1 = -1, y1 = -1;
  for (const auto& k : keys) {
    POLMAP_EXPECT(k.z == zoom && tiles::is_valid(k));
    order.insert({k.y, k.x});
    x0 = std::min(x0, k.x);
    x1 = std::max(x1, k.x);
    y0 = std::min(y0, k.y);
    y1 = std::max(y1, k.y);
  }
  constexpr int kPx = kGridmapTilePixels;
  const std::int64_t w = static_cast<std::int64_t>(x1 - x0 + 1) * kPx;
  const std::int64_t h = static_cast<std::int64_t>(y1 - y0 + 1) * kPx;
  if (w > std::numeric_limits<int>::max() || h > std::numeric_limits<int>::max()) {
    throw ValidationError("export: gridmap extent too large for one GeoTIFF; use --bbox");
  }
  // EPSG:3857: the world square is +-pi R with R = 6378137 m.
  constexpr double kHalf = std::numbers::pi * 6378137.0;
  const double tile_m = 2.0 * kHalf / static_cast<double>(tiles::tiles_per_side(zoom));
  const double px_m = tile_m / kPx;

  remove_file(out);
  GdalErrorCapture capture;
  detail::ScopedGdalConfig no_pam("GDAL_PAM_ENABLED", "NO");
  const char* opts[] = {"TILED=YES",   "BLOCKXSIZE=256", "BLOCKYSIZE=256",   "COMPRESS=DEFLATE",
                        "PREDICTOR=3", "SPARSE_OK=TRUE", "BIGTIFF=IF_SAFER", nullptr};
  const std::string path = out.string();
  GDALDatasetUniquePtr ds(driver("GTiff")->Create(path.c_str(), static_cast<int>(w),
                                                  static_cast<int>(h), 1, GDT_Float32,
                                                  const_cast<char**>(opts)));
  if (!ds) throw IoError(path + ": cannot create GeoTIFF: " + capture.last_message());
  double gt[6] = {-kHalf + x0 * tile_m, px_m, 0.0, kHalf - y0 * tile_m, 0.0, -px_m};
  ds->SetGeoTransform(gt);
  OGRSpatialReference srs;
  srs.importFromEPSG(3857);
  ds->SetSpatialRef(&srs);
  GDALRasterBand* band = ds->GetRasterBand(1);
  band->SetNoDataValue(std::numeric_limits<double>::quiet_NaN());
  band->SetDescription("power_db");
  ds->SetMetadataItem("POLMAP_LAYER", "fleet gridmap: mean power 10 log10(sum N tr C / sum N), dB");
  ds->SetMetadataItem("POLMAP_ZOOM", std::to_string(zoom).c_str());
  ExportSummary summary;
  for (const auto& [y, x] : order) {
    std::vector<float> db = load_db({zoom, x, y});
    if (db.size() != static_cast<std::size_t>(kPx) * kPx) {
      throw FormatError("export: gridmap tile " + std::to_string(zoom) + "/" + std::to_string(x) +
                        "/" + std::to_string(y) + " is not 256 x 256 pixels");
    }
    if (band->WriteBlock(x - x0, y - y0, db.data()) != CE_None) {
      throw IoError(path + ": cannot write tile: " + capture.last_message());
    }
    ++summary.gridmap_tiles;
  }
  close_dataset(std::move(ds), capture, path);
  summary.files = {out};
  summary.bytes = total_size(summary.files);
  return summary;
}

ExportSummary export_covariance_geotiff(const GridmapRaster& raster, PolLevel level,
                                        const std::string& crs_proj, const fs::path& out) {
  if (raster.q != pol_dimension(level) || raster.width < 1 || raster.height < 1) {
    throw ValidationError("export: covariance raster does not match its level or is empty");
  }
  remove_file(out);
  detail::GridmapTiffSpec spec;
  spec.width = raster.width;
  spec.height = raster.height;
  spec.origin_x_m = raster.origin_x_m;
  spec.origin_y_m = raster.origin_y_m;
  spec.cell_size_m = raster.cell_size_m;
  spec.level = level;
  spec.crs_proj = crs_proj;
  spec.metadata = {{"POLMAP_FORMAT", "polmap covariance gridmap"},
                   {"POLMAP_POL_LEVEL", std::string(to_string(level))}};
  detail::write_gridmap_tiff(raster, spec, out.string());
  ExportSummary summary;
  summary.files = {out};
  summary.bytes = total_size(summary.files);
  return summary;
}

ExportSummary export_map(const MapStore& store, std::int64_t version, ExportFormat format,
                         const std::optional<GeoBox>& bbox, const fs::path& out) {
  const auto info = store.get_map_version(version);
  if (!info || info->status != MapVersionStatus::Published) {
    throw NotFoundError("map version " + std::to_string(version) + " is not published");
  }
  if (format == ExportFormat::MergedGridmapCog) {
    // The store's merged gridmap (the sums every build keeps current), not the version's.
    return export_merged_gridmap_cog(store, bbox, std::nullopt, out);
  }
  if (format != ExportFormat::GeoTiff) {
    const LandmarkSet lm = store.landmarks_in(version, bbox, /*with_support=*/true);
    LandmarkExportOptions opts;
    opts.map_version = version;
    return export_landmarks(lm, format, out, opts);
  }
  // Fleet gridmap: the base-zoom tiles (the highest zoom stored) inside the box.
  const auto tiles_info = store.list_tiles(version, TileLayer::Gridmap);
  int zoom = -1;
  for (const auto& t : tiles_info) zoom = std::max(zoom, t.key.z);
  std::vector<tiles::TileKey> keys;
  for (const auto& t : tiles_info) {
    if (t.key.z != zoom) continue;
    if (bbox && !tiles::tile_bounds(t.key).intersects(*bbox)) continue;
    keys.push_back(t.key);
  }
  if (keys.empty()) {
    throw NotFoundError("map version " + std::to_string(version) + " has no fleet gridmap tiles" +
                        (bbox ? " in the box" : ""));
  }
  FleetGridmapConfig cfg;
  const auto& stats = info->statistics;
  if (stats.is_object() && stats.contains("gridmap") && stats["gridmap"].is_object()) {
    const auto& g = stats["gridmap"];
    if (g.contains("db_min") && g["db_min"].is_number()) cfg.db_min = g["db_min"].get<double>();
    if (g.contains("db_max") && g["db_max"].is_number()) cfg.db_max = g["db_max"].get<double>();
  }
  return export_mercator_gridmap_geotiff(
      zoom, keys,
      [&](const tiles::TileKey& key) {
        const auto tile = store.get_tile(version, TileLayer::Gridmap, key);
        if (!tile) throw NotFoundError("gridmap tile vanished during export");
        return decode_gridmap_png_db(tile->payload, cfg);
      },
      out);
}

}  // namespace polmap::mapping
