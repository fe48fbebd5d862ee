// SqliteMapStore: map versions, landmarks, tiles, statistics.
#include <algorithm>
#include <cmath>
#include <random>
#include <set>
#include <unordered_map>
#include <unordered_set>

#include "polmap/schema/json.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/util/text.hpp"
#include "sqlite_store_impl.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;

// --------------------------------------------------------------------- map versions

std::int64_t SqliteMapStore::begin_map_version(const nlohmann::json& parameters) {
  return impl_->write([&](Connection& c) {
    c.stmt(
         "INSERT INTO map_versions(status, created_at, parameters_json) VALUES ('building', ?1, "
         "?2)")
        .bind(1, now_iso())
        .bind(2, parameters.dump())
        .run();
    return c.last_id();
  });
}

void SqliteMapStore::Impl::put_landmarks_tx(Connection& c, std::int64_t version,
                                            std::span<const StoredPointLandmark> points,
                                            std::span<const StoredLineLandmark> lines) {
  Impl::require_building(c, version);
  const std::string ins =
      "INSERT INTO landmarks(version, key, kind, lat_deg, lon_deg, polyline_json, scattering, "
      "support_drives, spread_m) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)";
  // A drive deleted while the build ran (an erasure request, retention) takes its
  // candidates with it: their links are skipped, as a later delete would remove them.
  const std::string sup =
      "INSERT INTO landmark_support(landmark, candidate) SELECT ?1, ?2 "
      "WHERE EXISTS (SELECT 1 FROM candidates WHERE id = ?2)";
  auto support = [&](std::int64_t id, const std::vector<std::int64_t>& cands) {
    std::vector<std::int64_t> u(cands);
    std::sort(u.begin(), u.end());
    u.erase(std::unique(u.begin(), u.end()), u.end());
    for (auto cand : u) c.stmt(sup).bind(1, id).bind(2, cand).run();
  };
  for (const auto& p : points) {
    c.stmt(ins)
        .bind(1, version)
        .bind(2, p.key)
        .bind(3, 0)
        .bind(4, p.position.lat_deg)
        .bind(5, p.position.lon_deg)
        .bind_null(6)
        .bind(7, static_cast<int>(p.scattering))
        .bind(8, static_cast<std::int64_t>(p.support_drives))
        .bind(9, p.spread_m)
        .run();
    const auto id = c.last_id();
    insert_rtree(c, "landmarks_rtree", id, p.position.lat_deg, p.position.lat_deg,
                 p.position.lon_deg, p.position.lon_deg);
    support(id, p.support);
  }
  for (const auto& l : lines) {
    if (l.polyline.size() < 2) {
      throw ValidationError("put_landmarks: line landmark with key " + std::to_string(l.key) +
                            " has fewer than 2 vertices");
    }
    nlohmann::json pl = nlohmann::json::array();
    double lat0 = 90, lat1 = -90, lon0 = 180, lon1 = -180;
    for (const auto& g : l.polyline) {
      pl.push_back({g.lat_deg, g.lon_deg});
      lat0 = std::min(lat0, g.lat_deg);
      lat1 = std::max(lat1, g.lat_deg);
      lon0 = std::min(lon0, g.lon_deg);
      lon1 = std::max(lon1, g.lon_deg);
    }
    c.stmt(ins)
        .bind(1, version)
        .bind(2, l.key)
        .bind(3, 1)
        .bind(4, l.polyline.front().lat_deg)
        .bind(5, l.polyline.front().lon_deg)
        .bind(6, pl.dump(-1, ' ', false, nlohmann::json::error_handler_t::strict))
        .bind(7, 0)
        .bind(8, static_cast<std::int64_t>(l.support_drives))
        .bind(9, l.spread_m)
        .run();
    const auto id = c.last_id();
    insert_rtree(c, "landmarks_rtree", id, lat0, lat1, lon0, lon1);
    support(id, l.support);
  }
}

void SqliteMapStore::put_landmarks(std::int64_t version,
                                   std::span<const StoredPointLandmark> points,
                                   std::span<const StoredLineLandmark> lines) {
  impl_->write([&](Connection& c) { Impl::put_landmarks_tx(c, version, points, lines); });
}

std::int64_t SqliteMapStore::copy_landmarks(std::int64_t from, std::int64_t to,
                                            std::span<const std::int64_t> except_ids) {
  return impl_->write([&](Connection& c) {
    Impl::require_published(c, from);
    Impl::require_building(c, to);
    c.exec(
        "CREATE TEMP TABLE IF NOT EXISTS copy_except(id INTEGER PRIMARY KEY); "
        "DELETE FROM copy_except;");
    for (std::int64_t id : except_ids) {
      c.stmt("INSERT OR IGNORE INTO copy_except(id) VALUES (?1)").bind(1, id).run();
    }
    std::vector<std::int64_t> old_ids;
    {
      auto s = c.stmt(
          "SELECT id FROM landmarks WHERE version = ?1 AND id NOT IN (SELECT id FROM "
          "copy_except) ORDER BY id");
      s.bind(1, from);
      while (s.step()) old_ids.push_back(s.i64(0));
    }
    // A copy shares its source's support links (support_of) instead of duplicating them:
    // an incremental build costs what it changes, not what it keeps.
    for (std::int64_t old_id : old_ids) {
      c.stmt(
           "INSERT INTO landmarks(version, key, kind, lat_deg, lon_deg, polyline_json, "
           "scattering, support_drives, spread_m, support_of) SELECT ?1, key, kind, lat_deg, "
           "lon_deg, polyline_json, scattering, support_drives, spread_m, COALESCE(support_of, "
           "id) FROM landmarks WHERE id = ?2")
          .bind(1, to)
          .bind(2, old_id)
          .run();
      c.stmt(
           "INSERT INTO landmarks_rtree(id, min_lat, max_lat, min_lon, max_lon) SELECT ?1, "
           "min_lat, max_lat, min_lon, max_lon FROM landmarks_rtree WHERE id = ?2")
          .bind(1, c.last_id())
          .bind(2, old_id)
          .run();
    }
    c.exec("DELETE FROM copy_except;");
    return static_cast<std::int64_t>(old_ids.size());
  });
}

std::int64_t SqliteMapStore::copy_tiles(std::int64_t from, std::int64_t to, TileLayer layer,
                                        std::span<const tiles::TileKey> except_keys) {
  return impl_->write([&](Connection& c) {
    Impl::require_published(c, from);
    Impl::require_building(c, to);
    c.exec(
        "CREATE TEMP TABLE IF NOT EXISTS copy_tile_except(z INTEGER, x INTEGER, y INTEGER, "
        "PRIMARY KEY (z, x, y)); DELETE FROM copy_tile_except;");
    for (const auto& k : except_keys) {
      c.stmt("INSERT OR IGNORE INTO copy_tile_except(z, x, y) VALUES (?1, ?2, ?3)")
          .bind(1, k.z)
          .bind(2, k.x)
          .bind(3, k.y)
          .run();
    }
    const std::string table = tile_table(layer);
    // OR IGNORE: a build job run again after its worker died copies what is already there.
    c.stmt("INSERT OR IGNORE INTO " + table +
           "(version, z, x, y, blob, num_points, num_lines) SELECT ?1, t.z, t.x, t.y, t.blob, "
           "t.num_points, t.num_lines FROM " +
           table +
           " t WHERE t.version = ?2 AND NOT EXISTS (SELECT 1 FROM copy_tile_except e WHERE "
           "e.z = t.z AND e.x = t.x AND e.y = t.y)")
        .bind(1, to)
        .bind(2, from)
        .run();
    const auto n = static_cast<std::int64_t>(c.changes());
    c.exec("DELETE FROM copy_tile_except;");
    return n;
  });
}

void SqliteMapStore::Impl::put_landmark_changes_tx(Connection& c, std::int64_t version,
                                                   std::span<const LandmarkChange> changes) {
  Impl::require_building(c, version);
  std::int64_t seq = 0;
  {
    auto s = c.stmt("SELECT COALESCE(MAX(seq), 0) FROM landmark_changes WHERE version = ?1");
    s.bind(1, version);
    if (s.step()) seq = s.i64(0);
  }
  const std::string ins =
      "INSERT INTO landmark_changes(version, seq, change, kind, key, previous_key, distance_m, "
      "geometry_json, previous_geometry_json, reason_json) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, "
      "?8, ?9, ?10)";
  for (const LandmarkChange& ch : changes) {
    c.stmt(ins)
        .bind(1, version)
        .bind(2, ++seq)
        .bind(3, std::string(to_string(ch.change)))
        .bind(4, ch.is_line ? 1 : 0)
        .bind(5, ch.key)
        .bind(6, ch.previous_key)
        .bind(7, ch.distance_m)
        .bind(8, geometry_json(ch.geometry).dump())
        .bind(9, geometry_json(ch.previous_geometry).dump())
        .bind(10, ch.reason.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace))
        .run();
  }
}

void SqliteMapStore::put_landmark_changes(std::int64_t version,
                                          std::span<const LandmarkChange> changes) {
  impl_->write([&](Connection& c) { Impl::put_landmark_changes_tx(c, version, changes); });
}

std::vector<LandmarkChange> SqliteMapStore::landmark_changes(std::int64_t version) const {
  return impl_->read([&](Connection& c) {
    Impl::require_published(c, version);
    std::vector<LandmarkChange> out;
    auto s = c.stmt(
        "SELECT change, kind, key, previous_key, distance_m, geometry_json, "
        "previous_geometry_json, reason_json FROM landmark_changes WHERE version = ?1 ORDER BY "
        "seq");
    s.bind(1, version);
    while (s.step()) {
      LandmarkChange ch;
      ch.change = parse_landmark_change_kind(s.text(0)).value_or(LandmarkChangeKind::Added);
      ch.is_line = s.i64(1) != 0;
      ch.key = s.i64(2);
      ch.previous_key = s.i64(3);
      ch.distance_m = s.f64(4);
      ch.geometry = geometry_from_json(nlohmann::json::parse(s.text(5), nullptr, false));
      ch.previous_geometry = geometry_from_json(nlohmann::json::parse(s.text(6), nullptr, false));
      ch.reason = nlohmann::json::parse(s.text(7), nullptr, false);
      if (ch.reason.is_discarded()) ch.reason = nullptr;
      out.push_back(std::move(ch));
    }
    return out;
  });
}

void SqliteMapStore::Impl::put_tiles_tx(Connection& c, std::int64_t version, TileLayer layer,
                                        std::span<const TileWrite> tiles_in) {
  Impl::require_building(c, version);
  for (const auto& t : tiles_in) {
    if (!tiles::is_valid(t.key)) {
      throw ValidationError("put_tiles: invalid tile key " + tiles::to_string(t.key));
    }
    std::int64_t blob = 0;
    if (!t.reuse_blob) {
      const std::string etag = content_etag(t.payload);
      if (!t.etag.empty() && t.etag != etag) {
        throw ValidationError("put_tiles: tile " + tiles::to_string(t.key) +
                              ": etag does not match the payload's SHA-256");
      }
      c.stmt(
           "INSERT INTO tile_blobs(etag, payload, byte_size) VALUES (?1, ?2, ?3) "
           "ON CONFLICT(etag) DO NOTHING")
          .bind(1, etag)
          .bind_blob(2, t.payload)
          .bind(3, static_cast<std::int64_t>(t.payload.size()))
          .run();
      auto s = c.stmt("SELECT id FROM tile_blobs WHERE etag = ?1");
      s.bind(1, etag);
      if (s.step()) blob = s.i64(0);
    } else {
      auto s = c.stmt("SELECT id FROM tile_blobs WHERE etag = ?1");
      s.bind(1, t.etag);
      if (!s.step()) {
        throw ValidationError("put_tiles: tile " + tiles::to_string(t.key) +
                              ": no stored blob with etag " + t.etag + " to reuse");
      }
      blob = s.i64(0);
    }
    c.stmt(std::string("INSERT OR REPLACE INTO ") + tile_table(layer) +
           "(version, z, x, y, blob, num_points, num_lines) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)")
        .bind(1, version)
        .bind(2, t.key.z)
        .bind(3, t.key.x)
        .bind(4, t.key.y)
        .bind(5, blob)
        .bind(6, t.num_points)
        .bind(7, t.num_lines)
        .run();
  }
}

void SqliteMapStore::put_tiles(std::int64_t version, TileLayer layer,
                               std::span<const TileWrite> tiles_in) {
  impl_->write([&](Connection& c) { Impl::put_tiles_tx(c, version, layer, tiles_in); });
}

void SqliteMapStore::publish_map_version(std::int64_t version, const nlohmann::json& statistics,
                                         bool make_current) {
  impl_->write([&](Connection& c) {
    Impl::require_building(c, version);
    c.stmt(
         "UPDATE map_versions SET status = 'published', published_at = ?1, statistics_json = ?2 "
         "WHERE version = ?3")
        .bind(1, now_iso())
        .bind(2, statistics.dump())
        .bind(3, version)
        .run();
    // A partitioned build's publish job is done with the version (one transaction).
    c.stmt(
         "UPDATE build_jobs SET state = 'done', lease_until = 0 WHERE version = ?1 AND kind = "
         "'publish' AND state = 'running'")
        .bind(1, version)
        .run();
    if (make_current) {
      c.stmt(
           "INSERT INTO current_map(id, version) VALUES (1, ?1) "
           "ON CONFLICT(id) DO UPDATE SET version = excluded.version")
          .bind(1, version)
          .run();
    }
  });
}

void SqliteMapStore::fail_map_version(std::int64_t version, std::string_view error) {
  impl_->write([&](Connection& c) {
    const auto st = Impl::version_status(c, version);
    if (!st) throw NotFoundError("map version " + std::to_string(version) + " does not exist");
    if (*st == MapVersionStatus::Published) {
      throw ValidationError("map version " + std::to_string(version) +
                            " is published and cannot fail");
    }
    c.stmt("UPDATE map_versions SET status = 'failed', error = ?1 WHERE version = ?2")
        .bind(1, error)
        .bind(2, version)
        .run();
    Impl::drop_failed_content(c);
  });
}

// SQLite holds no lock a crashed process would release, so a running build cannot be
// told from an abandoned one here; the sweep at open (after orphan_grace_s) finds them.
std::vector<std::int64_t> SqliteMapStore::fail_abandoned_builds() { return {}; }

void SqliteMapStore::set_current_map_version(std::int64_t version) {
  impl_->write([&](Connection& c) {
    Impl::require_published(c, version);
    c.stmt(
         "INSERT INTO current_map(id, version) VALUES (1, ?1) "
         "ON CONFLICT(id) DO UPDATE SET version = excluded.version")
        .bind(1, version)
        .run();
  });
}

bool SqliteMapStore::delete_map_version(std::int64_t version) {
  return impl_->write([&](Connection& c) {
    {
      auto s = c.stmt("SELECT version FROM current_map WHERE id = 1");
      if (s.step() && s.i64(0) == version) {
        throw ConflictError("map version " + std::to_string(version) +
                            " is current and cannot be deleted");
      }
    }
    // Landmarks of later versions that share this version's support links (copies of an
    // incremental build) inherit them: the first copy takes the links, the others point
    // at it.
    std::vector<std::int64_t> shared;
    {
      auto s = c.stmt(
          "SELECT l.id FROM landmarks l WHERE l.version = ?1 AND EXISTS (SELECT 1 FROM "
          "landmarks r WHERE r.support_of = l.id)");
      s.bind(1, version);
      while (s.step()) shared.push_back(s.i64(0));
    }
    for (std::int64_t l : shared) {
      std::int64_t heir = 0;
      {
        // Prefer a published heir (a Building version may still fail and drop its rows).
        auto s = c.stmt(
            "SELECT l.id FROM landmarks l JOIN map_versions v ON v.version = l.version WHERE "
            "l.support_of = ?1 ORDER BY v.status != 'published', l.id LIMIT 1");
        s.bind(1, l);
        if (s.step()) heir = s.i64(0);
      }
      c.stmt("UPDATE landmark_support SET landmark = ?1 WHERE landmark = ?2")
          .bind(1, heir)
          .bind(2, l)
          .run();
      c.stmt("UPDATE landmarks SET support_of = NULL WHERE id = ?1").bind(1, heir).run();
      c.stmt("UPDATE landmarks SET support_of = ?1 WHERE support_of = ?2")
          .bind(1, heir)
          .bind(2, l)
          .run();
    }
    c.stmt("DELETE FROM map_versions WHERE version = ?1").bind(1, version).run();
    const bool deleted = c.changes() > 0;
    Impl::gc_blobs(c);
    return deleted;
  });
}

std::optional<std::int64_t> SqliteMapStore::current_map_version() const {
  return impl_->read([](Connection& c) -> std::optional<std::int64_t> {
    auto s = c.stmt("SELECT version FROM current_map WHERE id = 1");
    if (!s.step()) return std::nullopt;
    return s.i64(0);
  });
}

namespace {
constexpr const char* kVersionSelect =
    "SELECT v.version, v.status, v.created_at, v.published_at, v.parameters_json, "
    "v.statistics_json, v.error, (SELECT version FROM current_map WHERE id = 1) = v.version "
    "FROM map_versions v";

MapVersionInfo version_from_row(Stmt& s) {
  MapVersionInfo v;
  v.version = s.i64(0);
  v.status = parse_status(s.text(1));
  v.created_at = s.text(2);
  v.published_at = s.text(3);
  v.parameters = nlohmann::json::parse(s.text(4), nullptr, false);
  v.statistics = s.is_null(5) ? nlohmann::json() : nlohmann::json::parse(s.text(5), nullptr, false);
  v.error = s.text(6);
  v.current = s.i64(7) != 0;
  return v;
}
}  // namespace

std::optional<MapVersionInfo> SqliteMapStore::get_map_version(std::int64_t version) const {
  return impl_->read([&](Connection& c) -> std::optional<MapVersionInfo> {
    auto s = c.stmt(std::string(kVersionSelect) + " WHERE v.version = ?1");
    s.bind(1, version);
    if (!s.step()) return std::nullopt;
    return version_from_row(s);
  });
}

std::vector<MapVersionInfo> SqliteMapStore::list_map_versions() const {
  return impl_->read([&](Connection& c) {
    std::vector<MapVersionInfo> out;
    auto s = c.stmt(std::string(kVersionSelect) + " ORDER BY v.version");
    while (s.step()) out.push_back(version_from_row(s));
    return out;
  });
}

// --------------------------------------------------------------------- published content

LandmarkSet SqliteMapStore::landmarks_in(std::int64_t version, const std::optional<GeoBox>& box,
                                         bool with_support) const {
  return impl_->read([&](Connection& c) {
    Impl::require_published(c, version);
    LandmarkSet out;
    const std::string cols =
        "SELECT l.id, l.key, l.kind, l.lat_deg, l.lon_deg, l.polyline_json, l.scattering, "
        "l.support_drives, l.spread_m, COALESCE(l.support_of, l.id) FROM landmarks l";
    std::set<std::int64_t> seen;
    auto take = [&](Stmt& s) {
      const std::int64_t id = s.i64(0);
      if (!seen.insert(id).second) return;
      std::vector<std::int64_t> support;
      if (with_support) {
        auto q =
            c.stmt("SELECT candidate FROM landmark_support WHERE landmark = ?1 ORDER BY candidate");
        q.bind(1, s.i64(9));  // a copied landmark's links are its source's
        while (q.step()) support.push_back(q.i64(0));
      }
      if (s.i64(2) == 0) {
        StoredPointLandmark p;
        p.id = id;
        p.key = s.i64(1);
        p.position = {s.f64(3), s.f64(4), 0.0};
        if (box && !box_contains(*box, p.position.lat_deg, p.position.lon_deg)) return;
        p.scattering = static_cast<ScatteringClass>(s.i64(6) & 3);
        p.support_drives = static_cast<std::uint32_t>(s.i64(7));
        p.spread_m = s.f64(8);
        p.support = std::move(support);
        out.points.push_back(std::move(p));
      } else {
        StoredLineLandmark l;
        l.id = id;
        l.key = s.i64(1);
        const auto pl = nlohmann::json::parse(s.text(5));
        double lat0 = 90, lat1 = -90, lon0 = 180, lon1 = -180;
        for (const auto& v : pl) {
          const GeoPoint g{v.at(0).get<double>(), v.at(1).get<double>(), 0.0};
          lat0 = std::min(lat0, g.lat_deg);
          lat1 = std::max(lat1, g.lat_deg);
          lon0 = std::min(lon0, g.lon_deg);
          lon1 = std::max(lon1, g.lon_deg);
          l.polyline.push_back(g);
        }
        if (box && !box_intersects(*box, lat0, lon0, lat1, lon1)) return;
        l.support_drives = static_cast<std::uint32_t>(s.i64(7));
        l.spread_m = s.f64(8);
        l.support = std::move(support);
        out.lines.push_back(std::move(l));
      }
    };
    if (!box) {
      auto s = c.stmt(cols + " WHERE l.version = ?1 ORDER BY l.id");
      s.bind(1, version);
      while (s.step()) take(s);
    } else {
      for (const GeoBox& b : split_box(*box)) {
        auto s = c.stmt(cols +
                        " JOIN landmarks_rtree r ON r.id = l.id WHERE l.version = ?1 AND "
                        "r.max_lat >= ?2 AND r.min_lat <= ?3 AND r.max_lon >= ?4 AND "
                        "r.min_lon <= ?5 ORDER BY l.id");
        s.bind(1, version)
            .bind(2, b.min_lat_deg)
            .bind(3, b.max_lat_deg)
            .bind(4, b.min_lon_deg)
            .bind(5, b.max_lon_deg);
        while (s.step()) take(s);
      }
      auto by_id = [](const auto& a, const auto& b) { return a.id < b.id; };
      std::sort(out.points.begin(), out.points.end(), by_id);
      std::sort(out.lines.begin(), out.lines.end(), by_id);
    }
    return out;
  });
}

std::optional<StoredTile> SqliteMapStore::get_tile(std::int64_t version, TileLayer layer,
                                                   const tiles::TileKey& key) const {
  return impl_->read([&](Connection& c) -> std::optional<StoredTile> {
    Impl::require_published(c, version);
    auto s = c.stmt(std::string("SELECT b.etag, b.payload FROM ") + tile_table(layer) +
                    " t JOIN tile_blobs b ON b.id = t.blob WHERE t.version = ?1 AND t.z = ?2 AND "
                    "t.x = ?3 AND t.y = ?4");
    s.bind(1, version).bind(2, key.z).bind(3, key.x).bind(4, key.y);
    if (!s.step()) return std::nullopt;
    return StoredTile{key, s.text(0), s.blob(1)};
  });
}

std::optional<std::string> SqliteMapStore::get_tile_etag(std::int64_t version, TileLayer layer,
                                                         const tiles::TileKey& key) const {
  return impl_->read([&](Connection& c) -> std::optional<std::string> {
    Impl::require_published(c, version);
    auto s = c.stmt(std::string("SELECT b.etag FROM ") + tile_table(layer) +
                    " t JOIN tile_blobs b ON b.id = t.blob WHERE t.version = ?1 AND t.z = ?2 AND "
                    "t.x = ?3 AND t.y = ?4");
    s.bind(1, version).bind(2, key.z).bind(3, key.x).bind(4, key.y);
    if (!s.step()) return std::nullopt;
    return s.text(0);
  });
}

std::vector<TileInfo> SqliteMapStore::list_tiles(std::int64_t version, TileLayer layer) const {
  return impl_->read([&](Connection& c) {
    std::vector<TileInfo> out;
    auto s = c.stmt(std::string("SELECT t.z, t.x, t.y, b.etag, b.byte_size, t.num_points, "
                                "t.num_lines FROM ") +
                    tile_table(layer) +
                    " t JOIN tile_blobs b ON b.id = t.blob WHERE t.version = ?1 ORDER BY t.z, t.x, "
                    "t.y");
    s.bind(1, version);
    while (s.step()) {
      TileInfo t;
      t.key = {static_cast<int>(s.i64(0)), static_cast<int>(s.i64(1)), static_cast<int>(s.i64(2))};
      t.etag = s.text(3);
      t.byte_size = s.i64(4);
      t.num_points = static_cast<std::int32_t>(s.i64(5));
      t.num_lines = static_cast<std::int32_t>(s.i64(6));
      out.push_back(std::move(t));
    }
    return out;
  });
}

StoreStats SqliteMapStore::stats() const {
  return impl_->read([&](Connection& c) {
    StoreStats st;
    auto one = [&](const std::string& sql) -> std::int64_t {
      auto s = c.stmt(sql);
      return s.step() ? s.i64(0) : 0;
    };
    st.drives = one("SELECT COUNT(*) FROM drives");
    st.point_candidates = one("SELECT COUNT(*) FROM candidates WHERE kind = 0");
    st.line_candidates = one("SELECT COUNT(*) FROM candidates WHERE kind = 1");
    st.map_versions = one("SELECT COUNT(*) FROM map_versions");
    {
      auto s = c.stmt("SELECT version FROM current_map WHERE id = 1");
      if (s.step()) st.current_version = s.i64(0);
    }
    if (st.current_version) {
      const std::string v = std::to_string(*st.current_version);
      st.current_point_landmarks =
          one("SELECT COUNT(*) FROM landmarks WHERE version = " + v + " AND kind = 0");
      st.current_line_landmarks =
          one("SELECT COUNT(*) FROM landmarks WHERE version = " + v + " AND kind = 1");
      st.current_tiles = one("SELECT COUNT(*) FROM tiles WHERE version = " + v);
    }
    st.tile_blobs = one("SELECT COUNT(*) FROM tile_blobs");
    st.tile_blob_bytes = one("SELECT COALESCE(SUM(byte_size), 0) FROM tile_blobs");
    st.database_bytes =
        one("SELECT page_count * page_size FROM pragma_page_count, pragma_page_size");
    st.drive_store_bytes = one("SELECT COALESCE(SUM(package_bytes), 0) FROM drives");
    return st;
  });
}
}  // namespace polmap::mapping
