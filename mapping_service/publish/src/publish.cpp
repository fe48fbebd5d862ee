// Static, signed publication of a map version (publish.hpp).
#include "polmap/mapping_service/publish.hpp"

#include <sqlite3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <nlohmann/json.hpp>
#include <set>
#include <variant>
#include <vector>

#include "polmap/mapping_service/landmark_mvt.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/tiles/publication_manifest.hpp"
#include "polmap/util/ed25519.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/gzip.hpp"
#include "polmap/util/sha256.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;
namespace {

std::string utc_now_iso() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

/// Every tile key at zoom z that a landmark touches (points: the tile holding them; lines:
/// the tiles of each segment's bounding box), with a margin of one tile around points near
/// edges left to the MVT buffer.
std::set<tiles::TileKey> landmark_tiles(const LandmarkSet& lm, int z) {
  std::set<tiles::TileKey> out;
  for (const auto& p : lm.points)
    out.insert(tiles::tile_at(p.position.lat_deg, p.position.lon_deg, z));
  for (const auto& l : lm.lines) {
    for (std::size_t i = 0; i + 1 < l.polyline.size(); ++i) {
      const auto a = tiles::tile_at(l.polyline[i].lat_deg, l.polyline[i].lon_deg, z);
      const auto b = tiles::tile_at(l.polyline[i + 1].lat_deg, l.polyline[i + 1].lon_deg, z);
      for (int x = std::min(a.x, b.x); x <= std::max(a.x, b.x); ++x) {
        for (int y = std::min(a.y, b.y); y <= std::max(a.y, b.y); ++y) out.insert({z, x, y});
      }
    }
  }
  return out;
}

/// Landmark vector tiles of a version: key -> encoded MVT (empty tiles left out).
std::map<tiles::TileKey, std::string> mvt_tiles(const MapStore& store, std::int64_t version,
                                                const LandmarkSet& all, int z0, int z1) {
  std::map<tiles::TileKey, std::string> out;
  const tiles::MvtOptions opt;
  for (int z = z0; z <= z1; ++z) {
    for (const auto& key : landmark_tiles(all, z)) {
      const LandmarkSet lm = store.landmarks_in(
          version, buffered_tile_bounds(key, static_cast<double>(opt.buffer) / opt.extent + 0.01));
      const LandmarkMvtLayers layers = landmark_mvt_layers(lm, version);
      std::string body = tiles::encode_mvt(key, {layers.points, layers.lines}, opt);
      if (!body.empty()) out.emplace(key, std::move(body));
    }
  }
  return out;
}

/// Writes bytes to a new file, creating its directory.
void put_file(const fs::path& path, std::string_view bytes) {
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  if (ec) throw IoError(path.parent_path().string() + ": cannot create: " + ec.message());
  util::write_file_bytes(path, bytes);
}

nlohmann::json tilejson(std::int64_t version, const std::optional<tiles::GeoBox>& bounds,
                        const PublishOptions& o) {
  const tiles::GeoBox b = bounds.value_or(tiles::GeoBox{-85.0511, -180, 85.0511, 180});
  return {{"tilejson", "3.0.0"},
          {"name", "polmap radar landmarks, map version " + std::to_string(version)},
          {"attribution", "polmap"},
          {"scheme", "xyz"},
          {"tiles", {"mvt/{z}/{x}/{y}.mvt"}},
          {"minzoom", o.mvt_min_zoom},
          {"maxzoom", o.mvt_max_zoom},
          {"bounds", {b.min_lon_deg, b.min_lat_deg, b.max_lon_deg, b.max_lat_deg}},
          {"center",
           {0.5 * (b.min_lon_deg + b.max_lon_deg), 0.5 * (b.min_lat_deg + b.max_lat_deg),
            std::clamp(16, o.mvt_min_zoom, o.mvt_max_zoom)}},
          {"vector_layers", landmark_vector_layers_json()},
          {"polmap",
           {{"map_version", version},
            {"localization_tiles", "loc/{z}/{x}/{y}.pmt"},
            {"localization_zoom", tiles::kLocalizationZoom},
            {"gridmap_tiles", "gridmap/{z}/{x}/{y}.png"},
            {"gridmap_mechanism_tiles", "gridmap/mechanism/{z}/{x}/{y}.png"},
            {"manifest", "manifest.json"}}}};
}

std::optional<tiles::GeoBox> landmark_bounds(const LandmarkSet& lm) {
  std::optional<tiles::GeoBox> b;
  auto add = [&](const GeoPoint& p) {
    if (!b) {
      b = tiles::GeoBox{p.lat_deg, p.lon_deg, p.lat_deg, p.lon_deg};
      return;
    }
    b->min_lat_deg = std::min(b->min_lat_deg, p.lat_deg);
    b->max_lat_deg = std::max(b->max_lat_deg, p.lat_deg);
    b->min_lon_deg = std::min(b->min_lon_deg, p.lon_deg);
    b->max_lon_deg = std::max(b->max_lon_deg, p.lon_deg);
  };
  for (const auto& p : lm.points) add(p.position);
  for (const auto& l : lm.lines)
    for (const auto& p : l.polyline) add(p);
  return b;
}

class Sqlite {
 public:
  explicit Sqlite(const fs::path& path) {
    if (sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr) !=
        SQLITE_OK) {
      const std::string msg = db_ ? sqlite3_errmsg(db_) : "out of memory";
      sqlite3_close(db_);
      throw IoError(path.string() + ": cannot create MBTiles: " + msg);
    }
    path_ = path.string();
  }
  ~Sqlite() { sqlite3_close(db_); }
  Sqlite(const Sqlite&) = delete;
  Sqlite& operator=(const Sqlite&) = delete;
  void exec(const char* sql) {
    char* err = nullptr;
    if (sqlite3_exec(db_, sql, nullptr, nullptr, &err) != SQLITE_OK) {
      const std::string msg = err ? err : "?";
      sqlite3_free(err);
      throw IoError(path_ + ": " + msg);
    }
  }
  /// Runs `sql` once with text/blob/int parameters.
  void run(const char* sql, const std::vector<std::variant<std::int64_t, std::string>>& params,
           const std::vector<bool>& is_blob = {}) {
    sqlite3_stmt* st = nullptr;
    if (sqlite3_prepare_v2(db_, sql, -1, &st, nullptr) != SQLITE_OK) {
      throw IoError(path_ + ": " + sqlite3_errmsg(db_));
    }
    for (std::size_t i = 0; i < params.size(); ++i) {
      const int idx = static_cast<int>(i) + 1;
      if (const auto* v = std::get_if<std::int64_t>(&params[i])) {
        sqlite3_bind_int64(st, idx, *v);
      } else {
        const auto& s = std::get<std::string>(params[i]);
        if (i < is_blob.size() && is_blob[i]) {
          sqlite3_bind_blob(st, idx, s.data(), static_cast<int>(s.size()), SQLITE_TRANSIENT);
        } else {
          sqlite3_bind_text(st, idx, s.data(), static_cast<int>(s.size()), SQLITE_TRANSIENT);
        }
      }
    }
    const int rc = sqlite3_step(st);
    sqlite3_finalize(st);
    if (rc != SQLITE_DONE) throw IoError(path_ + ": " + sqlite3_errmsg(db_));
  }

 private:
  sqlite3* db_ = nullptr;
  std::string path_;
};

PublishResult write_mbtiles(const MapStore& store, std::int64_t version, const LandmarkSet& all,
                            const PublishOptions& o) {
  PublishResult r;
  r.map_version = version;
  const auto mvt = mvt_tiles(store, version, all, o.mvt_min_zoom, o.mvt_max_zoom);
  const fs::path tmp = o.out.string() + ".tmp";
  fs::remove(tmp);
  {
    Sqlite db(tmp);
    db.exec(
        "PRAGMA journal_mode = OFF; PRAGMA synchronous = OFF; BEGIN;"
        "CREATE TABLE metadata (name TEXT, value TEXT);"
        "CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER, "
        "tile_data BLOB);");
    const auto b = landmark_bounds(all).value_or(tiles::GeoBox{-85.0511, -180, 85.0511, 180});
    const nlohmann::json tj = tilejson(version, b, o);
    const std::vector<std::pair<std::string, std::string>> meta{
        {"name", tj["name"].get<std::string>()},
        {"format", "pbf"},
        {"type", "overlay"},
        {"version", "1"},
        {"description", "polmap consensus radar landmarks (points, lines)"},
        {"attribution", "polmap"},
        {"bounds", std::to_string(b.min_lon_deg) + "," + std::to_string(b.min_lat_deg) + "," +
                       std::to_string(b.max_lon_deg) + "," + std::to_string(b.max_lat_deg)},
        {"center", std::to_string(0.5 * (b.min_lon_deg + b.max_lon_deg)) + "," +
                       std::to_string(0.5 * (b.min_lat_deg + b.max_lat_deg)) + "," +
                       std::to_string(tj["center"][2].get<int>())},
        {"minzoom", std::to_string(o.mvt_min_zoom)},
        {"maxzoom", std::to_string(o.mvt_max_zoom)},
        {"json", nlohmann::json{{"vector_layers", tj["vector_layers"]}}.dump()},
        {"polmap_map_version", std::to_string(version)}};
    for (const auto& [k, v] : meta) {
      db.run("INSERT INTO metadata (name, value) VALUES (?1, ?2)", {k, v});
    }
    for (const auto& [key, body] : mvt) {
      const std::int64_t tms_row = tiles::tiles_per_side(key.z) - 1 - key.y;
      const std::string gz = util::gzip_compress(body);
      db.run("INSERT INTO tiles VALUES (?1, ?2, ?3, ?4)",
             {std::int64_t{key.z}, std::int64_t{key.x}, tms_row, gz}, {false, false, false, true});
      r.bytes += gz.size();
    }
    db.exec(
        "CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row);"
        "CREATE UNIQUE INDEX name ON metadata (name); COMMIT;");
  }
  util::sync_file(tmp);
  fs::rename(tmp, o.out);
  util::sync_directory(o.out.parent_path().empty() ? fs::path(".") : o.out.parent_path());
  r.tiles["mvt"] = mvt.size();
  r.bytes = fs::file_size(o.out);
  return r;
}

}  // namespace

PublishResult publish_map_version(const MapStore& store, std::int64_t version,
                                  const PublishOptions& o) {
  const auto info = store.get_map_version(version);
  if (!info || info->status != MapVersionStatus::Published) {
    throw NotFoundError("map version " + std::to_string(version) + " is not published");
  }
  if (o.mvt_min_zoom < 0 || o.mvt_min_zoom > o.mvt_max_zoom || o.mvt_max_zoom > 22) {
    throw ValidationError("publish: vector tile zooms must satisfy 0 <= min <= max <= 22");
  }
  if (o.out.empty()) throw ValidationError("publish: no output path");
  auto progress = [&](const std::string& stage, double f) {
    if (o.progress) o.progress(stage, f);
  };
  progress("landmarks", 0.0);
  const LandmarkSet all = store.landmarks_in(version, std::nullopt, false);
  if (o.format == PublishFormat::MBTiles) {
    PublishResult r = write_mbtiles(store, version, all, o);
    progress("done", 1.0);
    return r;
  }
  if (o.private_key_pem.empty()) {
    throw ValidationError("publish: a directory publication is signed; give an Ed25519 key");
  }
  const std::string public_pem = util::ed25519_public_of(o.private_key_pem);  // validates it

  std::error_code ec;
  fs::create_directories(o.out, ec);
  if (ec) throw IoError(o.out.string() + ": cannot create: " + ec.message());
  util::ScopedTempDir staging(util::make_unique_dir(o.out, ".publishing"));
  const fs::path dir = staging.path();

  tiles::PublicationManifest m;
  m.map_version = version;
  m.created_at = utc_now_iso();
  m.key_id = util::ed25519_key_id(public_pem);
  m.bounds = landmark_bounds(all);
  PublishResult r;
  r.map_version = version;
  auto add_layer =
      [&](const std::string& name, const std::string& path, const std::string& media, int z0,
          int z1,
          const std::function<void(
              const std::function<void(const tiles::TileKey&, std::string_view)>&)>& each) {
        tiles::PublishedLayer l{name, path, media, z0, z1, {}};
        each([&](const tiles::TileKey& key, std::string_view bytes) {
          put_file(dir / tiles::published_tile_path(l, key), bytes);
          l.tiles.push_back({key, util::sha256_hex(bytes), bytes.size()});
          r.bytes += bytes.size();
        });
        r.tiles[name] = l.tiles.size();
        m.layers.push_back(std::move(l));
      };
  auto stored_layer = [&](TileLayer layer) {
    return [&store, version, layer](const auto& emit) {
      for (const auto& t : store.list_tiles(version, layer)) {
        const auto tile = store.get_tile(version, layer, t.key);
        if (tile) emit(t.key, tile->payload);
      }
    };
  };
  progress("localization tiles", 0.1);
  add_layer("localization", "loc/{z}/{x}/{y}.pmt", "application/x-polmap-localization-tile",
            tiles::kLocalizationZoom, tiles::kLocalizationZoom,
            stored_layer(TileLayer::Localization));
  progress("vector tiles", 0.3);
  add_layer("mvt", "mvt/{z}/{x}/{y}.mvt", std::string(tiles::kMvtMediaType), o.mvt_min_zoom,
            o.mvt_max_zoom, [&](const auto& emit) {
              for (const auto& [key, body] :
                   mvt_tiles(store, version, all, o.mvt_min_zoom, o.mvt_max_zoom)) {
                emit(key, body);
              }
            });
  if (o.gridmap) {
    progress("gridmap tiles", 0.7);
    int z0 = tiles::kMaxZoom, z1 = 0;
    for (const auto& t : store.list_tiles(version, TileLayer::Gridmap)) {
      z0 = std::min(z0, t.key.z);
      z1 = std::max(z1, t.key.z);
    }
    if (z0 <= z1) {
      add_layer("gridmap", "gridmap/{z}/{x}/{y}.png", "image/png", z0, z1,
                stored_layer(TileLayer::Gridmap));
      add_layer("gridmap_mechanism", "gridmap/mechanism/{z}/{x}/{y}.png", "image/png", z0, z1,
                stored_layer(TileLayer::GridmapMechanism));
    }
  }
  progress("manifest", 0.95);
  const std::string manifest = tiles::encode_publication_manifest(m);
  const std::string sig = util::ed25519_sign_hex(o.private_key_pem, manifest);
  r.manifest_sha256 = util::sha256_hex(manifest);
  r.dir = "v";  // built by appending: GCC 12 -O3 warns falsely (-Wrestrict) on "v" + ...
  r.dir += std::to_string(version);
  r.dir += '-';
  r.dir += r.manifest_sha256.substr(0, 16);
  put_file(dir / "manifest.json", manifest);
  put_file(dir / "manifest.sig", sig + "\n");
  put_file(dir / "public_key.pem", public_pem);
  put_file(dir / "tilejson.json", tilejson(version, m.bounds, o).dump(2));
  r.bytes += manifest.size() + sig.size() + 1 + public_pem.size();
  util::sync_tree(dir);
  // Commit: the directory under its content name, then the pointer.
  const fs::path final_dir = o.out / r.dir;
  if (fs::exists(final_dir)) {
    fs::remove_all(final_dir);  // the same content published again: replace it whole
  }
  fs::rename(dir, final_dir);
  staging.release();
  util::sync_directory(o.out);
  const std::string pointer =
      tiles::encode_publication_pointer({version, r.dir, r.manifest_sha256});
  const fs::path tmp_ptr = o.out / ".latest.json.tmp";
  util::write_file_bytes(tmp_ptr, pointer + "\n");
  util::sync_file(tmp_ptr);
  fs::rename(tmp_ptr, o.out / "latest.json");
  util::sync_directory(o.out);
  progress("done", 1.0);
  return r;
}

}  // namespace polmap::mapping
