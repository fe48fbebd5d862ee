// PostgresMapStore: map versions, landmarks, landmark changes, tiles.
#include <algorithm>
#include <set>

#include "postgres_store_impl.hpp"

namespace polmap::mapping {

// --------------------------------------------------------------------- map versions

std::int64_t PostgresMapStore::begin_map_version(const nlohmann::json& parameters) {
  Impl& I = *impl_;
  // The row and its build lock appear together (one transaction on the session connection,
  // whose session-level lock outlives the commit): no sweep can see the version without
  // its lock, so a free lock always means the builder is gone.
  std::lock_guard lock(I.session_mu);
  I.ensure_session();
  Connection& c = *I.session;
  std::int64_t version = 0;
  bool locked = false;
  try {
    pg::Transaction tx(c);
    c.run("SELECT pg_advisory_xact_lock($1, $2)", kLockClass, kWriteLock);
    version = Impl::next_id(c, "map_versions", "version");
    c.run(
        "INSERT INTO map_versions(version, status, created_at, parameters_json) VALUES ($1, "
        "'building', $2, $3::jsonb)",
        version, now_iso(), parameters.dump());
    // Never waits: this number locked elsewhere (a deleted version's builder still running)
    // only keeps the sweep off this version while that one runs.
    locked =
        c.run("SELECT pg_try_advisory_lock($1, $2)", kBuildLockClass, static_cast<int>(version))
            .i64(0, 0) != 0;
    tx.commit();
  } catch (...) {
    // A session-level lock taken in a transaction that rolled back is still held.
    if (locked && c.reusable()) {
      try {
        c.run("SELECT pg_advisory_unlock($1, $2)", kBuildLockClass, static_cast<int>(version));
      } catch (const Error&) {
      }
    }
    throw;
  }
  if (locked) I.held_builds.insert(version);
  return version;
}

void PostgresMapStore::Impl::put_landmarks_tx(Connection& c, std::int64_t version,
                                              std::span<const StoredPointLandmark> points,
                                              std::span<const StoredLineLandmark> lines) {
  for (const auto& l : lines) {
    if (l.polyline.size() < 2) {
      throw ValidationError("put_landmarks: line landmark with key " + std::to_string(l.key) +
                            " has fewer than 2 vertices");
    }
  }
  Impl::require_building(c, version);
  const std::size_t n = points.size() + lines.size();
  if (n == 0) return;
  const std::int64_t first = Impl::next_id(c, "landmarks", "id");
  std::vector<std::int64_t> id(n), key(n), support_drives(n);
  std::vector<int> kind(n), scattering(n);
  std::vector<double> lat(n), lon(n), spread(n);
  std::vector<std::string> wkb(n);
  std::vector<std::optional<std::string>> polyline(n);  // lines only
  std::vector<std::int64_t> link_landmark, link_candidate;
  auto support = [&](std::int64_t lid, const std::vector<std::int64_t>& cands) {
    std::vector<std::int64_t> u(cands);
    std::sort(u.begin(), u.end());
    u.erase(std::unique(u.begin(), u.end()), u.end());
    for (auto cand : u) {
      link_landmark.push_back(lid);
      link_candidate.push_back(cand);
    }
  };
  std::size_t i = 0;
  for (const auto& p : points) {
    id[i] = first + static_cast<std::int64_t>(i);
    key[i] = p.key;
    kind[i] = 0;
    lat[i] = p.position.lat_deg;
    lon[i] = p.position.lon_deg;
    scattering[i] = static_cast<int>(p.scattering);
    support_drives[i] = static_cast<std::int64_t>(p.support_drives);
    spread[i] = p.spread_m;
    wkb[i] = wkb_point(p.position.lat_deg, p.position.lon_deg);
    support(id[i], p.support);
    ++i;
  }
  for (const auto& l : lines) {
    nlohmann::json pl = nlohmann::json::array();
    for (const auto& g : l.polyline) pl.push_back({g.lat_deg, g.lon_deg});
    id[i] = first + static_cast<std::int64_t>(i);
    key[i] = l.key;
    kind[i] = 1;
    lat[i] = l.polyline.front().lat_deg;
    lon[i] = l.polyline.front().lon_deg;
    scattering[i] = 0;
    support_drives[i] = static_cast<std::int64_t>(l.support_drives);
    spread[i] = l.spread_m;
    wkb[i] = wkb_line(l.polyline);
    polyline[i] = pl.dump(-1, ' ', false, nlohmann::json::error_handler_t::strict);
    support(id[i], l.support);
    ++i;
  }
  Params p;
  p.add(version)
      .add_array(id)
      .add_array(key)
      .add_array(kind)
      .add_array(lat)
      .add_array(lon)
      .add_array(scattering)
      .add_array(support_drives)
      .add_array(spread)
      .add_bytea_array(wkb)
      .add_array(polyline);
  c.query(
      "INSERT INTO landmarks(id, version, key, kind, lat_deg, lon_deg, polyline_json, "
      "scattering, support_drives, spread_m, geom) SELECT u.id, $1, u.key, u.kind, u.lat, "
      "u.lon, u.pl::jsonb, u.sc, u.sd, u.sp, ST_GeomFromWKB(u.g, 4326) FROM "
      "unnest($2::bigint[], $3::bigint[], $4::int[], $5::float8[], $6::float8[], $7::int[], "
      "$8::bigint[], $9::float8[], $10::bytea[], $11::text[]) AS u(id, key, kind, lat, lon, "
      "sc, sd, sp, g, pl)",
      p);
  if (!link_landmark.empty()) {
    // A drive deleted while the build ran takes its candidates with it: their links are
    // skipped, as a later delete would remove them.
    Params q;
    q.add_array(link_landmark).add_array(link_candidate);
    c.query(
        "INSERT INTO landmark_support(landmark, candidate) SELECT u.l, u.c FROM "
        "unnest($1::bigint[], $2::bigint[]) AS u(l, c) WHERE EXISTS (SELECT 1 FROM "
        "candidates WHERE id = u.c)",
        q);
  }
}

void PostgresMapStore::put_landmarks(std::int64_t version,
                                     std::span<const StoredPointLandmark> points,
                                     std::span<const StoredLineLandmark> lines) {
  impl_->write([&](Connection& c) { Impl::put_landmarks_tx(c, version, points, lines); });
}

std::int64_t PostgresMapStore::copy_landmarks(std::int64_t from, std::int64_t to,
                                              std::span<const std::int64_t> except_ids) {
  return impl_->write([&](Connection& c) {
    Impl::require_published(c, from);
    Impl::require_building(c, to);
    const std::int64_t first = Impl::next_id(c, "landmarks", "id");
    Params p;
    p.add(first - 1).add(to).add(from).add_array(
        std::vector<std::int64_t>(except_ids.begin(), except_ids.end()));
    // New ids in the order of the old ones (as SQLite's one insert per landmark); a copy
    // shares its source's support links (support_of) instead of duplicating them.
    const Result r = c.query(
        "INSERT INTO landmarks(id, version, key, kind, lat_deg, lon_deg, polyline_json, "
        "scattering, support_drives, spread_m, support_of, geom) SELECT $1 + row_number() OVER "
        "(ORDER BY id), $2, key, kind, lat_deg, lon_deg, polyline_json, scattering, "
        "support_drives, spread_m, COALESCE(support_of, id), geom FROM landmarks WHERE version "
        "= $3 AND NOT (id = ANY($4::bigint[])) ORDER BY id",
        p);
    return r.affected();
  });
}

std::int64_t PostgresMapStore::copy_tiles(std::int64_t from, std::int64_t to, TileLayer layer,
                                          std::span<const tiles::TileKey> except_keys) {
  return impl_->write([&](Connection& c) {
    Impl::require_published(c, from);
    Impl::require_building(c, to);
    std::vector<int> z, x, y;
    for (const auto& k : except_keys) {
      z.push_back(k.z);
      x.push_back(k.x);
      y.push_back(k.y);
    }
    const std::string table = tile_table(layer);
    Params p;
    p.add(to).add(from).add_array(z).add_array(x).add_array(y);
    const Result r = c.query("INSERT INTO " + table +
                                 "(version, z, x, y, blob, num_points, num_lines) SELECT $1, t.z, "
                                 "t.x, t.y, t.blob, t.num_points, t.num_lines FROM " +
                                 table +
                                 " t WHERE t.version = $2 AND NOT EXISTS (SELECT 1 FROM "
                                 "unnest($3::int[], $4::int[], $5::int[]) AS e(z, x, y) WHERE "
                                 "e.z = t.z AND e.x = t.x AND e.y = t.y) ON CONFLICT DO NOTHING",
                             p);
    return r.affected();
  });
}

void PostgresMapStore::Impl::put_landmark_changes_tx(Connection& c, std::int64_t version,
                                                     std::span<const LandmarkChange> changes) {
  Impl::require_building(c, version);
  std::int64_t seq =
      c.run("SELECT COALESCE(MAX(seq), 0)::bigint FROM landmark_changes WHERE version = $1",
            version)
          .i64(0, 0);
  for (const LandmarkChange& ch : changes) {
    Params p;
    p.add(version)
        .add(++seq)
        .add(std::string(to_string(ch.change)))
        .add(ch.is_line ? 1 : 0)
        .add(ch.key)
        .add(ch.previous_key)
        .add(ch.distance_m)
        .add(geometry_json(ch.geometry).dump())
        .add(geometry_json(ch.previous_geometry).dump())
        .add(ch.reason.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace));
    c.query(
        "INSERT INTO landmark_changes(version, seq, change, kind, key, previous_key, "
        "distance_m, geometry_json, previous_geometry_json, reason_json) VALUES ($1, $2, $3, "
        "$4, $5, $6, $7, $8::jsonb, $9::jsonb, $10::jsonb)",
        p);
  }
}

void PostgresMapStore::put_landmark_changes(std::int64_t version,
                                            std::span<const LandmarkChange> changes) {
  impl_->write([&](Connection& c) { Impl::put_landmark_changes_tx(c, version, changes); });
}

std::vector<LandmarkChange> PostgresMapStore::landmark_changes(std::int64_t version) const {
  return impl_->read([&](Connection& c) {
    Impl::require_published(c, version);
    std::vector<LandmarkChange> out;
    const Result s = c.run(
        "SELECT change, kind, key, previous_key, distance_m, geometry_json, "
        "previous_geometry_json, reason_json FROM landmark_changes WHERE version = $1 ORDER BY "
        "seq",
        version);
    for (int i = 0; i < s.rows(); ++i) {
      LandmarkChange ch;
      ch.change = parse_landmark_change_kind(s.text(i, 0)).value_or(LandmarkChangeKind::Added);
      ch.is_line = s.i64(i, 1) != 0;
      ch.key = s.i64(i, 2);
      ch.previous_key = s.i64(i, 3);
      ch.distance_m = s.f64(i, 4);
      ch.geometry = geometry_from_json(nlohmann::json::parse(s.text(i, 5), nullptr, false));
      ch.previous_geometry =
          geometry_from_json(nlohmann::json::parse(s.text(i, 6), nullptr, false));
      ch.reason = nlohmann::json::parse(s.text(i, 7), nullptr, false);
      if (ch.reason.is_discarded()) ch.reason = nullptr;
      out.push_back(std::move(ch));
    }
    return out;
  });
}

void PostgresMapStore::Impl::put_tiles_tx(Connection& c, std::int64_t version, TileLayer layer,
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
      c.run(
          "INSERT INTO tile_blobs(etag, payload, byte_size) VALUES ($1, $2, $3) "
          "ON CONFLICT (etag) DO NOTHING",
          etag, Bytea{t.payload}, static_cast<std::int64_t>(t.payload.size()));
      blob = c.run("SELECT id FROM tile_blobs WHERE etag = $1", etag).i64(0, 0);
    } else {
      const Result r = c.run("SELECT id FROM tile_blobs WHERE etag = $1", t.etag);
      if (r.empty()) {
        throw ValidationError("put_tiles: tile " + tiles::to_string(t.key) +
                              ": no stored blob with etag " + t.etag + " to reuse");
      }
      blob = r.i64(0, 0);
    }
    c.run(std::string("INSERT INTO ") + tile_table(layer) +
              "(version, z, x, y, blob, num_points, num_lines) VALUES ($1, $2, $3, $4, $5, $6, "
              "$7) ON CONFLICT (version, z, x, y) DO UPDATE SET blob = excluded.blob, "
              "num_points = excluded.num_points, num_lines = excluded.num_lines",
          version, t.key.z, t.key.x, t.key.y, blob, static_cast<int>(t.num_points),
          static_cast<int>(t.num_lines));
  }
}

void PostgresMapStore::put_tiles(std::int64_t version, TileLayer layer,
                                 std::span<const TileWrite> tiles_in) {
  impl_->write([&](Connection& c) { Impl::put_tiles_tx(c, version, layer, tiles_in); });
}

void PostgresMapStore::publish_map_version(std::int64_t version, const nlohmann::json& statistics,
                                           bool make_current) {
  impl_->write([&](Connection& c) {
    Impl::require_building(c, version);
    c.run(
        "UPDATE map_versions SET status = 'published', published_at = $1, statistics_json = "
        "$2::jsonb WHERE version = $3",
        now_iso(), statistics.dump(), version);
    // A partitioned build's publish job is done with the version (one transaction).
    c.run(
        "UPDATE build_jobs SET state = 'done', lease_until = 0 WHERE version = $1 AND kind = "
        "'publish' AND state = 'running'",
        version);
    if (make_current) {
      c.run(
          "INSERT INTO current_map(id, version) VALUES (1, $1) "
          "ON CONFLICT (id) DO UPDATE SET version = excluded.version",
          version);
    }
  });
  impl_->unlock_build(version);
}

void PostgresMapStore::fail_map_version(std::int64_t version, std::string_view error) {
  impl_->write([&](Connection& c) {
    const auto st = Impl::version_status(c, version);
    if (!st) throw NotFoundError("map version " + std::to_string(version) + " does not exist");
    if (*st == MapVersionStatus::Published) {
      throw ValidationError("map version " + std::to_string(version) +
                            " is published and cannot fail");
    }
    c.run("UPDATE map_versions SET status = 'failed', error = $1 WHERE version = $2", error,
          version);
    Impl::drop_failed_content(c);
  });
  impl_->unlock_build(version);
}

void PostgresMapStore::set_current_map_version(std::int64_t version) {
  impl_->write([&](Connection& c) {
    Impl::require_published(c, version);
    c.run(
        "INSERT INTO current_map(id, version) VALUES (1, $1) "
        "ON CONFLICT (id) DO UPDATE SET version = excluded.version",
        version);
  });
}

bool PostgresMapStore::delete_map_version(std::int64_t version) {
  const bool deleted = impl_->write([&](Connection& c) {
    {
      const Result r = c.run("SELECT version FROM current_map WHERE id = 1");
      if (!r.empty() && r.i64(0, 0) == version) {
        throw ConflictError("map version " + std::to_string(version) +
                            " is current and cannot be deleted");
      }
    }
    // Landmarks of later versions that share this version's support links (copies of an
    // incremental build) inherit them: the first copy takes the links, the others point
    // at it.
    const Result shared = c.run(
        "SELECT l.id FROM landmarks l WHERE l.version = $1 AND EXISTS (SELECT 1 FROM "
        "landmarks r WHERE r.support_of = l.id) ORDER BY l.id",
        version);
    for (int i = 0; i < shared.rows(); ++i) {
      const std::int64_t l = shared.i64(i, 0);
      // Prefer a published heir (a Building version may still fail and drop its rows).
      const std::int64_t heir =
          c.run(
               "SELECT l.id FROM landmarks l JOIN map_versions v ON v.version = l.version WHERE "
               "l.support_of = $1 ORDER BY v.status <> 'published', l.id LIMIT 1",
               l)
              .i64(0, 0);
      c.run("UPDATE landmark_support SET landmark = $1 WHERE landmark = $2", heir, l);
      c.run("UPDATE landmarks SET support_of = NULL WHERE id = $1", heir);
      c.run("UPDATE landmarks SET support_of = $1 WHERE support_of = $2", heir, l);
    }
    const bool gone = c.run("DELETE FROM map_versions WHERE version = $1", version).affected() > 0;
    Impl::gc_blobs(c);
    return gone;
  });
  if (deleted) impl_->unlock_build(version);
  return deleted;
}

std::optional<std::int64_t> PostgresMapStore::current_map_version() const {
  return impl_->read([](Connection& c) -> std::optional<std::int64_t> {
    const Result r = c.run("SELECT version FROM current_map WHERE id = 1");
    if (r.empty()) return std::nullopt;
    return r.i64(0, 0);
  });
}

namespace {
constexpr const char* kVersionSelect =
    "SELECT v.version, v.status, v.created_at, v.published_at, v.parameters_json, "
    "v.statistics_json, v.error, COALESCE((SELECT version FROM current_map WHERE id = 1) = "
    "v.version, false) FROM map_versions v";

MapVersionInfo version_from_row(const Result& s, int i) {
  MapVersionInfo v;
  v.version = s.i64(i, 0);
  v.status = parse_status(s.text(i, 1));
  v.created_at = s.text(i, 2);
  v.published_at = s.text(i, 3);
  v.parameters = nlohmann::json::parse(s.text(i, 4), nullptr, false);
  v.statistics =
      s.is_null(i, 5) ? nlohmann::json() : nlohmann::json::parse(s.text(i, 5), nullptr, false);
  v.error = s.text(i, 6);
  v.current = s.i64(i, 7) != 0;
  return v;
}
}  // namespace

std::optional<MapVersionInfo> PostgresMapStore::get_map_version(std::int64_t version) const {
  return impl_->read([&](Connection& c) -> std::optional<MapVersionInfo> {
    const Result r = c.run(std::string(kVersionSelect) + " WHERE v.version = $1", version);
    if (r.empty()) return std::nullopt;
    return version_from_row(r, 0);
  });
}

std::vector<MapVersionInfo> PostgresMapStore::list_map_versions() const {
  return impl_->read([&](Connection& c) {
    std::vector<MapVersionInfo> out;
    const Result r = c.run(std::string(kVersionSelect) + " ORDER BY v.version");
    for (int i = 0; i < r.rows(); ++i) out.push_back(version_from_row(r, i));
    return out;
  });
}

// --------------------------------------------------------------------- published content

LandmarkSet PostgresMapStore::landmarks_in(std::int64_t version, const std::optional<GeoBox>& box,
                                           bool with_support) const {
  return impl_->read([&](Connection& c) {
    Impl::require_published(c, version);
    LandmarkSet out;
    // Support lists in the same query (one round trip, not one per landmark), ordered by
    // candidate as SQLite's.
    const std::string cols =
        std::string(
            "SELECT l.id, l.key, l.kind, l.lat_deg, l.lon_deg, "
            "l.polyline_json, l.scattering, l.support_drives, l.spread_m, ") +
        (with_support ? "ARRAY(SELECT s.candidate FROM landmark_support s WHERE "
                        "s.landmark = COALESCE(l.support_of, l.id) ORDER BY "
                        "s.candidate)::bigint[]"
                      : "NULL::bigint[]") +
        " FROM landmarks l";
    std::set<std::int64_t> seen;
    auto take = [&](const Result& s, int i) {
      const std::int64_t id = s.i64(i, 0);
      if (!seen.insert(id).second) return;
      std::vector<std::int64_t> support;
      if (with_support) support = s.i64_array(i, 9);
      if (s.i64(i, 2) == 0) {
        StoredPointLandmark p;
        p.id = id;
        p.key = s.i64(i, 1);
        p.position = {s.f64(i, 3), s.f64(i, 4), 0.0};
        if (box && !box_contains(*box, p.position.lat_deg, p.position.lon_deg)) return;
        p.scattering = static_cast<ScatteringClass>(s.i64(i, 6) & 3);
        p.support_drives = static_cast<std::uint32_t>(s.i64(i, 7));
        p.spread_m = s.f64(i, 8);
        p.support = std::move(support);
        out.points.push_back(std::move(p));
      } else {
        StoredLineLandmark l;
        l.id = id;
        l.key = s.i64(i, 1);
        const auto pl = nlohmann::json::parse(s.text(i, 5));
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
        l.support_drives = static_cast<std::uint32_t>(s.i64(i, 7));
        l.spread_m = s.f64(i, 8);
        l.support = std::move(support);
        out.lines.push_back(std::move(l));
      }
    };
    if (!box) {
      const Result r = c.run(cols + " WHERE l.version = $1 ORDER BY l.id", version);
      for (int i = 0; i < r.rows(); ++i) take(r, i);
    } else {
      for (const GeoBox& b : split_box(*box)) {
        const Result r = c.run(cols +
                                   " WHERE l.version = $1 AND l.geom && ST_MakeEnvelope($2, $3, "
                                   "$4, $5, 4326) ORDER BY l.id",
                               version, b.min_lon_deg, b.min_lat_deg, b.max_lon_deg, b.max_lat_deg);
        for (int i = 0; i < r.rows(); ++i) take(r, i);
      }
      auto by_id = [](const auto& a, const auto& b) { return a.id < b.id; };
      std::sort(out.points.begin(), out.points.end(), by_id);
      std::sort(out.lines.begin(), out.lines.end(), by_id);
    }
    return out;
  });
}

std::optional<StoredTile> PostgresMapStore::get_tile(std::int64_t version, TileLayer layer,
                                                     const tiles::TileKey& key) const {
  return impl_->read([&](Connection& c) -> std::optional<StoredTile> {
    Impl::require_published(c, version);
    const Result r =
        c.run(std::string("SELECT b.etag, b.payload FROM ") + tile_table(layer) +
                  " t JOIN tile_blobs b ON b.id = t.blob WHERE t.version = $1 AND t.z = $2 AND "
                  "t.x = $3 AND t.y = $4",
              version, key.z, key.x, key.y);
    if (r.empty()) return std::nullopt;
    return StoredTile{key, r.text(0, 0), r.bytes(0, 1)};
  });
}

std::optional<std::string> PostgresMapStore::get_tile_etag(std::int64_t version, TileLayer layer,
                                                           const tiles::TileKey& key) const {
  return impl_->read([&](Connection& c) -> std::optional<std::string> {
    Impl::require_published(c, version);
    const Result r =
        c.run(std::string("SELECT b.etag FROM ") + tile_table(layer) +
                  " t JOIN tile_blobs b ON b.id = t.blob WHERE t.version = $1 AND t.z = $2 AND "
                  "t.x = $3 AND t.y = $4",
              version, key.z, key.x, key.y);
    if (r.empty()) return std::nullopt;
    return r.text(0, 0);
  });
}

std::vector<TileInfo> PostgresMapStore::list_tiles(std::int64_t version, TileLayer layer) const {
  return impl_->read([&](Connection& c) {
    std::vector<TileInfo> out;
    const Result r = c.run(
        std::string("SELECT t.z, t.x, t.y, b.etag, b.byte_size, t.num_points, t.num_lines FROM ") +
            tile_table(layer) +
            " t JOIN tile_blobs b ON b.id = t.blob WHERE t.version = $1 ORDER BY t.z, t.x, t.y",
        version);
    for (int i = 0; i < r.rows(); ++i) {
      TileInfo t;
      t.key = {static_cast<int>(r.i64(i, 0)), static_cast<int>(r.i64(i, 1)),
               static_cast<int>(r.i64(i, 2))};
      t.etag = r.text(i, 3);
      t.byte_size = r.i64(i, 4);
      t.num_points = static_cast<std::int32_t>(r.i64(i, 5));
      t.num_lines = static_cast<std::int32_t>(r.i64(i, 6));
      out.push_back(std::move(t));
    }
    return out;
  });
}

}  // namespace polmap::mapping
