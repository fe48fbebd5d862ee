// `polmap export --db FILE --format gpkg|geojson|shp|gtiff|cog --out FILE [--version V]
//  [--bbox MINLON,MINLAT,MAXLON,MAXLAT]`: writes a published map version of a local store
// as GIS files (mapping_service/export.hpp): landmarks as GeoPackage (layers points,
// lines), GeoJSON (one FeatureCollection) or Shapefile (points.* + lines.*; a zip when
// --out ends in .zip, else a directory), or the fleet gridmap as a GeoTIFF (EPSG:3857, dB),
// or (cog) the store's merged covariance gridmap as a multi-band Cloud Optimized GeoTIFF.
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <sstream>
#include <string>

#include "command.hpp"
#include "map_db.hpp"
#include "polmap/mapping_service/export.hpp"
#include "polmap/mapping_service/open_store.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::cli {
namespace {

struct ExportOptions {
  std::string db;
  std::string format;
  std::string out;
  std::int64_t version = 0;  // 0 = current
  std::string bbox;
};

std::optional<mapping::GeoBox> parse_bbox(const std::string& s) {
  if (s.empty()) return std::nullopt;
  std::stringstream ss(s);
  double v[4];
  char comma = 0;
  for (int i = 0; i < 4; ++i) {
    if (!(ss >> v[i]) || (i < 3 && (!(ss >> comma) || comma != ','))) {
      throw ValidationError("--bbox '" + s + "': expected MINLON,MINLAT,MAXLON,MAXLAT in degrees");
    }
  }
  std::string rest;
  if (ss >> rest) throw ValidationError("--bbox '" + s + "': trailing characters");
  for (double x : v) {
    if (!std::isfinite(x)) throw ValidationError("--bbox '" + s + "': not finite");
  }
  if (std::abs(v[1]) > 90 || std::abs(v[3]) > 90 || std::abs(v[0]) > 180 || std::abs(v[2]) > 180 ||
      v[1] > v[3]) {
    throw ValidationError("--bbox '" + s + "': outside WGS84 range or min > max latitude");
  }
  return mapping::GeoBox{v[1], v[0], v[3], v[2]};
}

void run(const ExportOptions& o) {
  const auto format = mapping::parse_export_format(o.format);
  if (!format) {
    throw ValidationError("--format '" + o.format + "': expected gpkg, geojson, shp, gtiff or cog");
  }
  const auto bbox = parse_bbox(o.bbox);
  require_map_db(o.db);
  const auto opened = mapping::open_map_store(o.db);
  mapping::MapStore& store = *opened;
  const std::int64_t version = map_version_or_current(store, o.db, o.version);
  const auto s = mapping::export_map(store, version, *format, bbox, o.out);
  if (*format == mapping::ExportFormat::MergedGridmapCog) {
    std::printf("merged gridmap of the store: %llu sum tiles -> %s (%llu bytes, COG)\n",
                static_cast<unsigned long long>(s.gridmap_tiles), o.out.c_str(),
                static_cast<unsigned long long>(s.bytes));
  } else if (*format == mapping::ExportFormat::GeoTiff) {
    std::printf("map version %lld: fleet gridmap, %llu tiles -> %s (%llu bytes)\n",
                static_cast<long long>(version), static_cast<unsigned long long>(s.gridmap_tiles),
                o.out.c_str(), static_cast<unsigned long long>(s.bytes));
  } else {
    std::printf(
        "map version %lld: %llu point and %llu line landmarks -> %s (%zu file%s, %llu bytes)\n",
        static_cast<long long>(version), static_cast<unsigned long long>(s.points),
        static_cast<unsigned long long>(s.lines), o.out.c_str(), s.files.size(),
        s.files.size() == 1 ? "" : "s", static_cast<unsigned long long>(s.bytes));
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<ExportOptions>();
  CLI::App* cmd = app.add_subcommand(
      "export",
      "Export a map version's landmarks (gpkg, geojson, shp), its fleet gridmap (gtiff) or the "
      "store's merged covariance gridmap (cog)");
  cmd->add_option(
         "--db", opts->db,
         "Map store: a SQLite database file, or a PostgreSQL URL (postgresql://USER@HOST:PORT/DB)")
      ->required();
  cmd->add_option("--format", opts->format, "gpkg | geojson | shp | gtiff | cog")->required();
  cmd->add_option("--out", opts->out,
                  "Output file (.gpkg, .geojson, .tif; shp: .zip or a directory)")
      ->required();
  cmd->add_option("--version", opts->version, "Published map version (default: current)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--bbox", opts->bbox, "Only this box: MINLON,MINLAT,MAXLON,MAXLAT (degrees)");
  cmd->callback([opts] { run(*opts); });
}

}  // namespace
POLMAP_REGISTER_COMMAND(export, setup);
}  // namespace polmap::cli
