// Consumer of an installed polmap (tools/check-install): public headers only,
// linked against polmap::localization_client and polmap::tile_fetcher.
#include <cmath>
#include <cstdio>
#include <exception>
#include <string>
#include <utility>

#include "polmap/localization_client/localizer.hpp"
#include "polmap/localization_client/tile_fetcher.hpp"
#include "polmap/localization_client/tile_source.hpp"
#include "polmap/schema/radar_spec.hpp"
#include "polmap/tiles/localization_tile.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace {

int failures = 0;

void check(bool ok, const char* what) {
  std::printf("%s: %s\n", ok ? "ok  " : "FAIL", what);
  if (!ok) ++failures;
}

}  // namespace

int main() try {
  using namespace polmap;

  // Tile codec (polmap::tiles, GeographicLib through tile_center).
  tiles::LocalizationTile tile;
  tile.key = tiles::tile_at(48.5, 9.05, tiles::kLocalizationZoom);
  tile.map_version = 7;
  PointLandmark point;
  point.id = 42;
  point.position_m = {12.345, -6.789};
  point.scattering = ScatteringClass::Even;
  point.support_drives = 3;
  tile.points.push_back(point);
  LineLandmark line;
  line.id = 5;
  line.polyline_m = {{-10.0, 2.0}, {10.0, 2.5}};
  line.support_drives = 2;
  tile.lines.push_back(line);

  const std::string bytes = tiles::encode_localization_tile(tile);
  const tiles::LocalizationTile decoded = tiles::decode_localization_tile(bytes, "consumer");
  check(decoded.key == tile.key, "decoded tile key");
  check(decoded.map_version == 7, "decoded map version");
  check(decoded.points.size() == 1 && decoded.points[0].id == 42 &&
            std::abs(decoded.points[0].position_m.x() - 12.345) <= 0.0025 &&
            std::abs(decoded.points[0].position_m.y() + 6.789) <= 0.0025,
        "decoded point landmark within the 5 mm quantum");
  check(decoded.lines.size() == 1 && decoded.lines[0].polyline_m.size() == 2,
        "decoded line landmark");

  // Localizer with the default configuration over an in-memory tile source.
  loc::InMemoryTileSource source;
  source.put(decoded);
  // The installed headers' defaults (documented in localizer.hpp) and a non-default
  // value round-trip through the library.
  loc::LocalizerConfig lcfg;
  check(lcfg.gridmap.window_s == 2.0 && lcfg.extract_every_n_cycles >= 1,
        "default localizer config");
  lcfg.lines_every_n_extractions = 7;
  loc::Localizer localizer(lcfg, default_front_mounts(), source);
  check(localizer.config().lines_every_n_extractions == 7, "localizer keeps its config");
  const GeoPoint centre = tiles::tile_center(tile.key);
  localizer.set_initial_pose(GeoPose{centre, 0.0}, 5.0, 0.1);
  check(localizer.map_frame().has_value() &&
            std::abs(localizer.map_frame()->origin().lat_deg - centre.lat_deg) < 1e-12,
        "map frame at the initial pose");
  SensorFrame frame;  // no detections: no ego-motion yet, so no pose
  frame.sensor_id = 0;
  frame.time_s = 0.1;
  const loc::LocalizationOutput out = localizer.process(frame);
  check(!out.has_pose && out.status == loc::LocalizationOutput::Status::Initializing &&
            loc::to_string(out.status) == "initializing",
        "empty frame: initializing, no pose");

  // Tile fetcher (HTTP client, cpp-httplib) offline: memory only, no server.
  loc::TileFetcher fetcher(loc::TileFetcherConfig{});
  check(!fetcher.tile(tile.key).has_value(), "offline fetcher: miss");
  check(fetcher.stats().memory_misses == 1, "offline fetcher: one memory miss");

  std::printf("%s\n",
              failures == 0 ? "polmap consumer: all checks passed" : "polmap consumer: FAILED");
  return failures == 0 ? 0 : 1;
} catch (const std::exception& e) {
  std::printf("polmap consumer: exception: %s\n", e.what());
  return 1;
}
