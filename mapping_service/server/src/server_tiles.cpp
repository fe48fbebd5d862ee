// Tile endpoints: localization tiles, MVT, TileJSON, fleet gridmap PNG tiles.

#include <algorithm>
#include <cmath>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/landmark_mvt.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/localization_tile.hpp"
#include "polmap/tiles/mvt.hpp"
#include "polmap/tiles/polyline_simplify.hpp"
#include "polmap/util/gzip.hpp"
#include "polmap/util/sha256.hpp"
#include "server_impl.hpp"

namespace polmap::mapping {
namespace {

constexpr const char* kImmutable = "public, max-age=31536000, immutable";

std::optional<tiles::TileKey> parse_key(const httplib::Request& req) {
  const std::string s = std::string(req.matches[1]) + "/" + std::string(req.matches[2]) + "/" +
                        std::string(req.matches[3]);
  return tiles::parse_tile_key(s);
}

std::string key_cache_id(const tiles::TileKey& k) { return tiles::to_string(k); }

/// Douglas-Peucker in pieces of at most kSimplifyPiece vertices. Each piece keeps its end
/// vertices, so every dropped vertex is still within tol_m of the kept line; the worst
/// case, a zig-zag whose farthest vertex is always next to the split, costs
/// O(n * kSimplifyPiece) instead of O(n^2) (100000 hostile samples: 11 s before).
constexpr std::size_t kSimplifyPiece = 1024;
std::vector<GeoPoint> simplify_in_pieces(const std::vector<GeoPoint>& line, double tol_m) {
  if (line.size() <= kSimplifyPiece) return tiles::simplify_polyline(line, tol_m);
  std::vector<GeoPoint> out;
  for (std::size_t a = 0; a + 1 < line.size(); a += kSimplifyPiece - 1) {
    const std::size_t b = std::min(line.size(), a + kSimplifyPiece);
    const std::vector<GeoPoint> piece(line.begin() + static_cast<std::ptrdiff_t>(a),
                                      line.begin() + static_cast<std::ptrdiff_t>(b));
    const std::vector<GeoPoint> kept = tiles::simplify_polyline(piece, tol_m);
    // The first vertex of a piece is the last of the one before.
    out.insert(out.end(), kept.begin() + (out.empty() ? 0 : 1), kept.end());
  }
  return out;
}

}  // namespace

std::shared_ptr<const std::vector<GeoPoint>> Server::Impl::drive_trajectory(
    const DriveRecord& drive) {
  {
    std::lock_guard lock(trajectory_mutex);
    if (auto it = trajectories.find(drive.content_hash); it != trajectories.end())
      return it->second;
  }
  // From the store's validated, decimated copy: the server never re-opens package files
  // to draw a map.
  std::vector<GeoPoint> raw;
  try {
    for (const TrajectorySample& t : store.drive_trajectory(drive.drive_id)) {
      raw.push_back({t.lat_deg, t.lon_deg, 0.0});
    }
  } catch (const NotFoundError&) {  // deleted meanwhile: nothing to draw
  }
  auto out = std::make_shared<std::vector<GeoPoint>>(simplify_in_pieces(raw, 0.25));
  std::lock_guard lock(trajectory_mutex);
  return trajectories.try_emplace(drive.content_hash, std::move(out)).first->second;
}

std::string Server::Impl::tile_cache_control(bool is_explicit) const {
  return is_explicit ? std::string(kImmutable)
                     : "public, max-age=" + std::to_string(cfg.current_tile_max_age_s) +
                           ", must-revalidate";
}

bool Server::Impl::reply_not_modified(const httplib::Request& req, httplib::Response& res,
                                      const std::string& etag, const std::string& cache_control) {
  const std::string inm = req.get_header_value("If-None-Match");
  if (inm.empty() || !http::if_none_match_matches(inm, etag)) return false;
  res.status = 304;
  res.set_header("ETag", etag);
  res.set_header("Cache-Control", cache_control);
  return true;
}

// ---- localization tiles
void Server::Impl::get_localization_tile(const httplib::Request& req, httplib::Response& res) {
  set_route("tiles");
  const auto key = parse_key(req);
  if (!key) {
    metrics.tile_served("localization", 400);
    return reply_error(res, 400,
                       "malformed tile address '" + req.path.substr(10) +
                           "': expected z/x/y with 0 <= x, y < 2^z, z <= 24",
                       "z/x/y");
  }
  bool is_explicit = false;
  const auto idx = resolve_version(req, res, is_explicit);
  if (!idx) return metrics.tile_served("localization", res.status);
  if (key->z != tiles::kLocalizationZoom) {
    metrics.tile_served("localization", 404);
    return reply_error(
        res, 404,
        "localization tiles exist at zoom " + std::to_string(tiles::kLocalizationZoom) + " only",
        "z");
  }
  const std::string cache_control = tile_cache_control(is_explicit);
  const auto it = idx->localization.find(*key);
  if (it == idx->localization.end()) {
    if (idx->covered.count(*key) != 0) {
      // Inside the map, no landmarks: a cacheable "empty" answer.
      res.status = 204;
      res.set_header("Cache-Control", cache_control);
      return metrics.tile_served("localization", 204);
    }
    metrics.tile_served("localization", 404);
    res.set_header("X-Polmap-Coverage", "outside");  // the one 404 clients may remember
    return reply_error(res, 404,
                       "tile " + tiles::to_string(*key) +
                           " is outside the coverage of map version " +
                           std::to_string(idx->version));
  }
  // Conditional request: answered from the version index, no payload access.
  const std::string etag = "\"" + it->second.etag + "\"";
  if (reply_not_modified(req, res, etag, cache_control)) {
    return metrics.tile_served("localization", 304);
  }
  const std::string ck = "L/" + std::to_string(idx->version) + "/" + key_cache_id(*key);
  auto blob = cache.get(ck);
  if (!blob) {
    const auto tile = store.get_tile(idx->version, TileLayer::Localization, *key);
    if (!tile) {
      metrics.tile_served("localization", 404);
      return reply_error(res, 404, "tile " + tiles::to_string(*key) + " vanished from the store");
    }
    auto b = std::make_shared<http::CachedBlob>();
    b->body = tile->payload;
    b->etag = "\"" + tile->etag + "\"";
    b->content_type = std::string(tiles::kLocalizationTileMediaType);
    // The payload is already deflated: no gzip variant.
    cache.put(ck, b);
    blob = std::move(b);
  }
  metrics.tile_served("localization", reply_blob(req, res, *blob, cache_control));
}

// ---- Mapbox Vector Tiles for GIS viewers
void Server::Impl::get_mvt_tile(const httplib::Request& req, httplib::Response& res) {
  set_route("mvt");
  const auto key = parse_key(req);
  if (!key) {
    metrics.tile_served("mvt", 400);
    return reply_error(res, 400, "malformed tile address: expected z/x/y.mvt", "z/x/y");
  }
  if (key->z < cfg.mvt_min_zoom || key->z > cfg.mvt_max_zoom) {
    metrics.tile_served("mvt", 404);
    return reply_error(res, 404,
                       "vector tiles are served for zoom " + std::to_string(cfg.mvt_min_zoom) +
                           ".." + std::to_string(cfg.mvt_max_zoom),
                       "z");
  }
  // Landmarks of a version (explicit, else current); trajectories of the stored drives
  // are shown even before the first map exists.
  std::shared_ptr<const VersionIndex> idx;
  bool is_explicit = false;
  if (req.has_param("version") || current_version()) {
    idx = resolve_version(req, res, is_explicit);
    if (!idx) return metrics.tile_served("mvt", res.status);
  }
  const std::int64_t version = idx ? idx->version : 0;
  // Trajectories are personal data: only for keys that may read drives.
  const auto reader = authenticate(req);
  const bool with_trajectories = reader && allows(*reader, Access::ReadDrives);
  const tiles::MvtOptions opt;
  const tiles::GeoBox box =
      buffered_tile_bounds(*key, static_cast<double>(opt.buffer) / opt.extent + 0.01);
  // The cache key names the content, so every replica on one store gives the same bytes:
  // the version's landmarks (immutable) and, with trajectories, the drives in the box.
  const std::vector<DriveRecord> drives =
      with_trajectories ? store.drives_in(box) : std::vector<DriveRecord>{};
  std::string ck = std::string(with_trajectories ? "VT/" : "V/") + std::to_string(version) + "/" +
                   key_cache_id(*key);
  if (with_trajectories) {
    util::Sha256 h;
    for (const DriveRecord& d : drives) h.update(d.content_hash);
    ck += "/" + h.hex().substr(0, 16);
  }
  auto blob = cache.get(ck);
  if (!blob) {
    LandmarkMvtLayers layers;
    tiles::MvtLayer trajectories{"trajectories", {}};
    if (idx) layers = landmark_mvt_layers(store.landmarks_in(version, box), version);
    std::uint64_t fid = 1;
    for (const DriveRecord& d : drives) {
      const auto traj = drive_trajectory(d);
      if (traj->size() < 2) continue;
      trajectories.features.push_back({fid++,
                                       tiles::MvtGeometryType::LineString,
                                       {*traj},
                                       {{"drive_id", d.drive_id}, {"vehicle_id", d.vehicle_id}}});
    }
    auto b = std::make_shared<http::CachedBlob>();
    b->body = tiles::encode_mvt(*key, {layers.points, layers.lines, trajectories}, opt);
    if (!b->body.empty()) {
      b->gzip_body = util::gzip_compress(b->body);
      b->etag = "\"" + content_etag(b->body).substr(0, 32) + "\"";
    }
    b->content_type = std::string(tiles::kMvtMediaType);
    cache.put(ck, b);
    blob = std::move(b);
  }
  // With trajectories the tile is one reader's: never in a shared cache.
  const std::string cache_control =
      with_trajectories ? "private, max-age=60" : "public, max-age=60";
  if (blob->body.empty()) {
    res.status = 204;  // no features: viewers treat 204 as an empty tile
    res.set_header("Cache-Control", cache_control);
    return metrics.tile_served("mvt", 204);
  }
  metrics.tile_served("mvt", reply_blob(req, res, *blob, cache_control));
  res.set_header("Vary", "Authorization");  // the trajectories layer depends on the key
}

// ---- TileJSON 3.0 describing the MVT layers
void Server::Impl::get_tilejson(const httplib::Request& req, httplib::Response& res) {
  set_route("tilejson");
  std::shared_ptr<const VersionIndex> idx;
  bool is_explicit = false;
  if (req.has_param("version") || current_version()) {
    idx = resolve_version(req, res, is_explicit);
    if (!idx) return;
  }
  std::string base = cfg.public_url;
  if (base.empty()) {
    base = cfg.tls_cert_file.empty() ? "http://" : "https://";
    base += req.get_header_value("Host");
  }
  while (!base.empty() && base.back() == '/') base.pop_back();
  const std::string query = is_explicit ? "?version=" + std::to_string(idx->version) : "";
  std::optional<tiles::GeoBox> bounds = idx ? idx->bounds : std::nullopt;
  if (!bounds) {
    for (const DriveRecord& d : store.list_drives()) {
      if (!bounds) {
        bounds = d.bbox;
      } else {
        bounds->min_lat_deg = std::min(bounds->min_lat_deg, d.bbox.min_lat_deg);
        bounds->min_lon_deg = std::min(bounds->min_lon_deg, d.bbox.min_lon_deg);
        bounds->max_lat_deg = std::max(bounds->max_lat_deg, d.bbox.max_lat_deg);
        bounds->max_lon_deg = std::max(bounds->max_lon_deg, d.bbox.max_lon_deg);
      }
    }
  }
  const tiles::GeoBox b = bounds.value_or(tiles::GeoBox{-85.0511, -180, 85.0511, 180});
  const int center_zoom = std::clamp(16, cfg.mvt_min_zoom, cfg.mvt_max_zoom);
  nlohmann::json layers = landmark_vector_layers_json();
  layers.push_back({{"id", "trajectories"},
                    {"description", "trajectories of the stored drives (simplified to 0.25 m)"},
                    {"fields", {{"drive_id", "String"}, {"vehicle_id", "String"}}}});
  nlohmann::json j{
      {"tilejson", "3.0.0"},
      {"name", "polmap radar landmarks"},
      {"description", "Consensus radar landmarks (points, lines) and drive trajectories"},
      {"version", "1.0.0"},
      {"attribution", "polmap"},
      {"scheme", "xyz"},
      {"tiles", {base + "/v1/mvt/{z}/{x}/{y}.mvt" + query}},
      {"minzoom", cfg.mvt_min_zoom},
      {"maxzoom", cfg.mvt_max_zoom},
      {"bounds", {b.min_lon_deg, b.min_lat_deg, b.max_lon_deg, b.max_lat_deg}},
      {"center",
       {0.5 * (b.min_lon_deg + b.max_lon_deg), 0.5 * (b.min_lat_deg + b.max_lat_deg), center_zoom}},
      {"vector_layers", layers},
  };
  if (idx) {
    j["polmap"] = {
        {"map_version", idx->version},
        {"localization_tiles", base + "/v1/tiles/{z}/{x}/{y}" + query},
        {"localization_zoom", tiles::kLocalizationZoom},
        {"gridmap_tiles", base + "/v1/gridmap/{z}/{x}/{y}.png" + query},
        {"gridmap_mechanism_tiles", base + "/v1/gridmap/mechanism/{z}/{x}/{y}.png" + query}};
  }
  res.status = 200;
  res.set_content(j.dump(), kJson);
  res.set_header("Cache-Control", is_explicit ? "public, max-age=3600" : "public, max-age=60");
}

// ---- fleet gridmap raster tiles
void Server::Impl::get_gridmap_tile(const httplib::Request& req, httplib::Response& res) {
  serve_gridmap_layer(req, res, TileLayer::Gridmap);
}

void Server::Impl::get_gridmap_mechanism_tile(const httplib::Request& req, httplib::Response& res) {
  serve_gridmap_layer(req, res, TileLayer::GridmapMechanism);
}

void Server::Impl::serve_gridmap_layer(const httplib::Request& req, httplib::Response& res,
                                       TileLayer layer) {
  const bool mech = layer == TileLayer::GridmapMechanism;
  const char* name = mech ? "gridmap_mechanism" : "gridmap";
  set_route(name);
  const auto key = parse_key(req);
  if (!key) {
    metrics.tile_served(name, 400);
    return reply_error(res, 400, "malformed tile address: expected z/x/y.png", "z/x/y");
  }
  bool is_explicit = false;
  const auto idx = resolve_version(req, res, is_explicit);
  if (!idx) return metrics.tile_served(name, res.status);
  const std::string cache_control = tile_cache_control(is_explicit);
  const auto& layer_tiles = mech ? idx->gridmap_mechanism : idx->gridmap;
  if (layer_tiles.empty()) {
    metrics.tile_served(name, 404);
    return reply_error(res, 404,
                       "map version " + std::to_string(idx->version) + " has no fleet gridmap");
  }
  // The stored tile, or for zooms beyond the base zoom its base-zoom ancestor (over-zoom).
  tiles::TileKey source = *key;
  if (key->z > idx->gridmap_max_zoom && key->z <= idx->gridmap_max_zoom + 6) {
    const int dz = key->z - idx->gridmap_max_zoom;
    source = {idx->gridmap_max_zoom, key->x >> dz, key->y >> dz};
  }
  const auto it = layer_tiles.find(source);
  if (it == layer_tiles.end()) {
    res.status = 204;  // transparent: no drive observed this area
    res.set_header("Cache-Control", cache_control);
    return metrics.tile_served(name, 204);
  }
  std::string etag = "\"" + it->second.etag;
  if (source != *key)
    etag +=
        "-" + std::to_string(key->z) + "-" + std::to_string(key->x) + "-" + std::to_string(key->y);
  etag += "\"";
  if (reply_not_modified(req, res, etag, cache_control)) {
    return metrics.tile_served(name, 304);
  }
  const std::string ck =
      (mech ? "GM/" : "G/") + std::to_string(idx->version) + "/" + key_cache_id(*key);
  auto blob = cache.get(ck);
  if (!blob) {
    const auto tile = store.get_tile(idx->version, layer, source);
    if (!tile) {
      metrics.tile_served(name, 404);
      return reply_error(res, 404, "gridmap tile vanished from the store");
    }
    auto b = std::make_shared<http::CachedBlob>();
    b->body = source == *key ? gridmap_png(tile->payload)
                             : gridmap_overzoom_png(tile->payload, source, *key);
    b->etag = etag;
    b->content_type = "image/png";
    cache.put(ck, b);
    blob = std::move(b);
  }
  metrics.tile_served(name, reply_blob(req, res, *blob, cache_control));
}

void Server::Impl::register_tile_routes() {
  using Handler = void (Server::Impl::*)(const httplib::Request&, httplib::Response&);
  auto route = [this](Handler h) {
    return [this, h](const httplib::Request& req, httplib::Response& res) { (this->*h)(req, res); };
  };
  http.Get(R"(/v1/tiles/([^/]+)/([^/]+)/([^/]+))", route(&Impl::get_localization_tile));
  http.Get(R"(/v1/mvt/([^/]+)/([^/]+)/([^/.]+)\.mvt)", route(&Impl::get_mvt_tile));
  http.Get("/v1/tilejson.json", route(&Impl::get_tilejson));
  http.Get(R"(/v1/gridmap/([^/]+)/([^/]+)/([^/.]+)\.png)", route(&Impl::get_gridmap_tile));
  http.Get(R"(/v1/gridmap/mechanism/([^/]+)/([^/]+)/([^/.]+)\.png)",
           route(&Impl::get_gridmap_mechanism_tile));
}

}  // namespace polmap::mapping
