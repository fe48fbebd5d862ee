// SqliteMapStore: the embedded MapStore (see sqlite_store.hpp for the
// connection, transaction and crash-safety rules, schema/store.sql for the DDL).
#include "polmap/mapping_service/sqlite_store.hpp"

#include <openssl/evp.h>
#include <sqlite3.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <ctime>
#include <cstdio>
#include <fstream>
#include <mutex>
#include <random>
#include <set>
#include <unordered_map>
#include <unordered_set>

#include "polmap/schema/json.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;

// ===================================================================== schema
// Keep in sync with schema/store.sql (tests/mapping_service/sqlite_store_test.cpp
// checks that the file contains every statement below verbatim).
namespace {

constexpr std::string_view kBootstrapSql =
    R"sql(CREATE TABLE IF NOT EXISTS schema_migrations (
  version    INTEGER PRIMARY KEY,
  name       TEXT NOT NULL,
  applied_at TEXT NOT NULL
);)sql";

constexpr std::string_view kMigration1 = R"sql(CREATE TABLE drives (
  id            INTEGER PRIMARY KEY,
  drive_id      TEXT NOT NULL UNIQUE,
  content_hash  TEXT NOT NULL UNIQUE,
  vehicle_id    TEXT NOT NULL,
  start_time_s  REAL NOT NULL,
  end_time_s    REAL NOT NULL,
  min_lat_deg   REAL NOT NULL,
  min_lon_deg   REAL NOT NULL,
  max_lat_deg   REAL NOT NULL,
  max_lon_deg   REAL NOT NULL,
  pol_level     TEXT NOT NULL,
  distance_m    REAL NOT NULL,
  num_points    INTEGER NOT NULL,
  num_lines     INTEGER NOT NULL,
  manifest_json TEXT NOT NULL,
  package_path  TEXT NOT NULL,
  package_bytes INTEGER NOT NULL,
  ingested_at   TEXT NOT NULL
);
CREATE VIRTUAL TABLE drives_rtree USING rtree(id, min_lat, max_lat, min_lon, max_lon);
CREATE TRIGGER drives_rtree_delete AFTER DELETE ON drives BEGIN
  DELETE FROM drives_rtree WHERE id = old.id;
END;

CREATE TABLE candidates (
  id          INTEGER PRIMARY KEY,
  drive       INTEGER NOT NULL REFERENCES drives(id) ON DELETE CASCADE,
  kind        INTEGER NOT NULL CHECK (kind IN (0, 1)),
  lat_deg     REAL NOT NULL,
  lon_deg     REAL NOT NULL,
  x_m         REAL NOT NULL,
  y_m         REAL NOT NULL,
  end_lat_deg REAL,
  end_lon_deg REAL,
  end_x_m     REAL,
  end_y_m     REAL,
  strength    REAL NOT NULL,
  power_db    REAL,
  scattering  INTEGER,
  num_cells   INTEGER
);
CREATE INDEX candidates_drive ON candidates(drive);
CREATE VIRTUAL TABLE candidates_rtree USING rtree(id, min_lat, max_lat, min_lon, max_lon);
CREATE TRIGGER candidates_rtree_delete AFTER DELETE ON candidates BEGIN
  DELETE FROM candidates_rtree WHERE id = old.id;
END;

CREATE TABLE map_versions (
  version         INTEGER PRIMARY KEY,
  status          TEXT NOT NULL CHECK (status IN ('building', 'published', 'failed')),
  created_at      TEXT NOT NULL,
  published_at    TEXT,
  parameters_json TEXT NOT NULL,
  statistics_json TEXT,
  error           TEXT
);
CREATE TABLE current_map (
  id      INTEGER PRIMARY KEY CHECK (id = 1),
  version INTEGER NOT NULL REFERENCES map_versions(version)
);
CREATE TRIGGER current_map_insert BEFORE INSERT ON current_map
WHEN (SELECT status FROM map_versions WHERE version = new.version) IS NOT 'published' BEGIN
  SELECT RAISE(ABORT, 'current map version must be published');
END;
CREATE TRIGGER current_map_update BEFORE UPDATE ON current_map
WHEN (SELECT status FROM map_versions WHERE version = new.version) IS NOT 'published' BEGIN
  SELECT RAISE(ABORT, 'current map version must be published');
END;

CREATE TABLE landmarks (
  id             INTEGER PRIMARY KEY,
  version        INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  key            INTEGER NOT NULL,
  kind           INTEGER NOT NULL CHECK (kind IN (0, 1)),
  lat_deg        REAL NOT NULL,
  lon_deg        REAL NOT NULL,
  polyline_json  TEXT,
  scattering     INTEGER NOT NULL DEFAULT 0,
  support_drives INTEGER NOT NULL,
  spread_m       REAL NOT NULL
);
CREATE INDEX landmarks_version ON landmarks(version, kind);
CREATE VIRTUAL TABLE landmarks_rtree USING rtree(id, min_lat, max_lat, min_lon, max_lon);
CREATE TRIGGER landmarks_rtree_delete AFTER DELETE ON landmarks BEGIN
  DELETE FROM landmarks_rtree WHERE id = old.id;
END;

CREATE TABLE landmark_support (
  landmark  INTEGER NOT NULL REFERENCES landmarks(id) ON DELETE CASCADE,
  candidate INTEGER NOT NULL REFERENCES candidates(id) ON DELETE CASCADE,
  PRIMARY KEY (landmark, candidate)
) WITHOUT ROWID;
CREATE INDEX landmark_support_candidate ON landmark_support(candidate);

CREATE TABLE tile_blobs (
  id        INTEGER PRIMARY KEY,
  etag      TEXT NOT NULL UNIQUE,
  payload   BLOB NOT NULL,
  byte_size INTEGER NOT NULL
);
CREATE TABLE tiles (
  version    INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  z          INTEGER NOT NULL,
  x          INTEGER NOT NULL,
  y          INTEGER NOT NULL,
  blob       INTEGER NOT NULL REFERENCES tile_blobs(id),
  num_points INTEGER NOT NULL DEFAULT 0,
  num_lines  INTEGER NOT NULL DEFAULT 0,
  PRIMARY KEY (version, z, x, y)
) WITHOUT ROWID;
CREATE INDEX tiles_blob ON tiles(blob);
CREATE TABLE gridmap_tiles (
  version    INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  z          INTEGER NOT NULL,
  x          INTEGER NOT NULL,
  y          INTEGER NOT NULL,
  blob       INTEGER NOT NULL REFERENCES tile_blobs(id),
  num_points INTEGER NOT NULL DEFAULT 0,
  num_lines  INTEGER NOT NULL DEFAULT 0,
  PRIMARY KEY (version, z, x, y)
) WITHOUT ROWID;
CREATE INDEX gridmap_tiles_blob ON gridmap_tiles(blob);)sql";

constexpr std::string_view kMigration2 = R"sql(CREATE TABLE drive_trajectories (
  drive         INTEGER PRIMARY KEY REFERENCES drives(id) ON DELETE CASCADE,
  min_spacing_m REAL NOT NULL,
  samples_json  TEXT NOT NULL
);)sql";

/// Trajectory decimation for drive_trajectories: a sample is kept when it is
/// this far from the last kept one (or kTrajectoryMaxGapS later).
constexpr double kTrajectorySpacingM = 1.0;
constexpr double kTrajectoryMaxGapS = 5.0;

std::string now_iso() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

// ===================================================================== sqlite wrapper

[[noreturn]] void throw_db(sqlite3* db, const std::string& what) {
  throw IoError("sqlite: " + what + ": " + (db ? sqlite3_errmsg(db) : "out of memory"));
}

/// A prepared statement borrowed from a connection's cache; reset on destruction.
class Stmt {
 public:
  Stmt(sqlite3* db, sqlite3_stmt* s) : db_(db), s_(s) {}
  ~Stmt() {
    sqlite3_reset(s_);
    sqlite3_clear_bindings(s_);
  }
  Stmt(const Stmt&) = delete;
  Stmt& operator=(const Stmt&) = delete;

  Stmt& bind(int i, std::int64_t v) {
    check(sqlite3_bind_int64(s_, i, v));
    return *this;
  }
  Stmt& bind(int i, int v) { return bind(i, static_cast<std::int64_t>(v)); }
  Stmt& bind(int i, double v) {
    check(sqlite3_bind_double(s_, i, v));
    return *this;
  }
  Stmt& bind(int i, std::string_view v) {
    check(sqlite3_bind_text(s_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT));
    return *this;
  }
  Stmt& bind(int i, const char* v) { return bind(i, std::string_view(v)); }
  Stmt& bind(int i, const std::string& v) { return bind(i, std::string_view(v)); }
  Stmt& bind_blob(int i, std::string_view v) {
    check(sqlite3_bind_blob(s_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT));
    return *this;
  }
  Stmt& bind_null(int i) {
    check(sqlite3_bind_null(s_, i));
    return *this;
  }
  /// True while a row is available.
  bool step() {
    const int rc = sqlite3_step(s_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    throw_db(db_, std::string("step '") + sqlite3_sql(s_) + "'");
  }
  void run() {
    while (step()) {
    }
  }
  [[nodiscard]] std::int64_t i64(int c) const { return sqlite3_column_int64(s_, c); }
  [[nodiscard]] double f64(int c) const { return sqlite3_column_double(s_, c); }
  [[nodiscard]] bool is_null(int c) const { return sqlite3_column_type(s_, c) == SQLITE_NULL; }
  [[nodiscard]] std::string text(int c) const {
    const auto* p = sqlite3_column_text(s_, c);
    return p ? std::string(reinterpret_cast<const char*>(p),
                           static_cast<std::size_t>(sqlite3_column_bytes(s_, c)))
             : std::string();
  }
  [[nodiscard]] std::string blob(int c) const {
    const void* p = sqlite3_column_blob(s_, c);
    const int n = sqlite3_column_bytes(s_, c);
    return p ? std::string(static_cast<const char*>(p), static_cast<std::size_t>(n)) : std::string();
  }

 private:
  void check(int rc) {
    if (rc != SQLITE_OK) throw_db(db_, "bind");
  }
  sqlite3* db_;
  sqlite3_stmt* s_;
};

class Connection {
 public:
  Connection(const fs::path& path, int busy_timeout_ms) {
    const int rc = sqlite3_open_v2(path.c_str(), &db_,
                                   SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX,
                                   nullptr);
    if (rc != SQLITE_OK) {
      std::string msg = db_ ? sqlite3_errmsg(db_) : "out of memory";
      sqlite3_close(db_);
      throw IoError("cannot open map store database " + path.string() + ": " + msg);
    }
    sqlite3_busy_timeout(db_, busy_timeout_ms);
    exec("PRAGMA foreign_keys = ON");
    exec("PRAGMA journal_mode = WAL");
    exec("PRAGMA synchronous = NORMAL");
  }
  ~Connection() {
    for (auto& [sql, s] : cache_) sqlite3_finalize(s);
    sqlite3_close(db_);
  }
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  void exec(std::string_view sql) {
    char* err = nullptr;
    const std::string s(sql);
    if (sqlite3_exec(db_, s.c_str(), nullptr, nullptr, &err) != SQLITE_OK) {
      std::string msg = err ? err : "unknown error";
      sqlite3_free(err);
      throw IoError("sqlite: " + msg + " (in: " + s.substr(0, 80) + ")");
    }
  }
  Stmt stmt(const std::string& sql) {
    auto it = cache_.find(sql);
    if (it == cache_.end()) {
      sqlite3_stmt* s = nullptr;
      if (sqlite3_prepare_v3(db_, sql.c_str(), static_cast<int>(sql.size()),
                             SQLITE_PREPARE_PERSISTENT, &s, nullptr) != SQLITE_OK) {
        throw_db(db_, "prepare '" + sql + "'");
      }
      it = cache_.emplace(sql, s).first;
    }
    return Stmt(db_, it->second);
  }
  [[nodiscard]] std::int64_t last_id() const { return sqlite3_last_insert_rowid(db_); }
  [[nodiscard]] int changes() const { return sqlite3_changes(db_); }

 private:
  sqlite3* db_ = nullptr;
  std::unordered_map<std::string, sqlite3_stmt*> cache_;
};

// ===================================================================== helpers

bool is_hex(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) {
    return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
  });
}

/// Splits an antimeridian-crossing box into two ordinary ones.
std::vector<GeoBox> split_box(const GeoBox& b) {
  if (!b.crosses_antimeridian()) return {b};
  GeoBox east = b, west = b;
  east.max_lon_deg = 180.0;
  west.min_lon_deg = -180.0;
  return {east, west};
}

bool box_contains(const GeoBox& b, double lat, double lon) {
  for (const GeoBox& p : split_box(b)) {
    if (lat >= p.min_lat_deg && lat <= p.max_lat_deg && lon >= p.min_lon_deg && lon <= p.max_lon_deg) {
      return true;
    }
  }
  return false;
}

bool box_intersects(const GeoBox& b, double lat0, double lon0, double lat1, double lon1) {
  for (const GeoBox& p : split_box(b)) {
    if (lat1 >= p.min_lat_deg && lat0 <= p.max_lat_deg && lon1 >= p.min_lon_deg &&
        lon0 <= p.max_lon_deg) {
      return true;
    }
  }
  return false;
}

/// R*Tree coordinates are 32-bit floats; SQLite rounds bounds outward, so the
/// index returns a superset and the exact filter is applied on the REAL columns.
void insert_rtree(Connection& c, const char* table, std::int64_t id, double min_lat, double max_lat,
                  double min_lon, double max_lon) {
  c.stmt(std::string("INSERT INTO ") + table +
         "(id, min_lat, max_lat, min_lon, max_lon) VALUES (?1, ?2, ?3, ?4, ?5)")
      .bind(1, id)
      .bind(2, min_lat)
      .bind(3, max_lat)
      .bind(4, min_lon)
      .bind(5, max_lon)
      .run();
}

nlohmann::json manifest_json(const DriveManifest& m) {
  nlohmann::json j;
  j["format_version"] = m.format_version;
  j["drive_id"] = m.drive_id;
  j["vehicle_id"] = m.vehicle_id;
  j["start_time_s"] = m.start_time_s;
  j["end_time_s"] = m.end_time_s;
  j["origin"] = m.origin;
  j["crs_proj"] = m.crs_proj;
  j["sensors"] = m.sensors;
  j["pol_level"] = std::string(to_string(m.pol_level));
  j["cell_size_m"] = m.cell_size_m;
  j["distance_m"] = m.distance_m;
  j["producer"] = m.producer;
  return j;
}

std::int64_t dir_bytes(const fs::path& p) {
  std::error_code ec;
  if (fs::is_regular_file(p, ec)) return static_cast<std::int64_t>(fs::file_size(p, ec));
  std::int64_t n = 0;
  for (auto it = fs::recursive_directory_iterator(p, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    if (it->is_regular_file(ec)) n += static_cast<std::int64_t>(it->file_size(ec));
  }
  return n;
}

const char* tile_table(TileLayer layer) {
  return layer == TileLayer::Localization ? "tiles" : "gridmap_tiles";
}

MapVersionStatus parse_status(const std::string& s) {
  if (s == "published") return MapVersionStatus::Published;
  if (s == "failed") return MapVersionStatus::Failed;
  return MapVersionStatus::Building;
}

constexpr const char* kDriveColumns =
    "id, drive_id, content_hash, vehicle_id, start_time_s, end_time_s, min_lat_deg, min_lon_deg, "
    "max_lat_deg, max_lon_deg, pol_level, distance_m, num_points, num_lines, manifest_json, "
    "package_path, ingested_at";

}  // namespace

std::string_view to_string(MapVersionStatus s) {
  switch (s) {
    case MapVersionStatus::Published: return "published";
    case MapVersionStatus::Failed: return "failed";
    default: return "building";
  }
}

std::string content_etag(std::string_view payload) {
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int n = 0;
  if (EVP_Digest(payload.data(), payload.size(), md, &n, EVP_sha256(), nullptr) != 1) {
    throw Error("SHA-256 failed");
  }
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out(2 * n, '0');
  for (unsigned i = 0; i < n; ++i) {
    out[2 * i] = kHex[md[i] >> 4];
    out[2 * i + 1] = kHex[md[i] & 15];
  }
  return out;
}

const std::vector<StoreMigration>& sqlite_store_migrations() {
  static const std::vector<StoreMigration> m{
      {0, "bootstrap", kBootstrapSql},
      {1, "initial schema", kMigration1},
      {2, "decimated drive trajectories", kMigration2},
  };
  return m;
}

// ===================================================================== Impl

struct SqliteMapStore::Impl {
  fs::path path;
  fs::path drives_dir;
  SqliteStoreOptions opt;
  mutable std::mutex pool_mu;
  mutable std::vector<std::unique_ptr<Connection>> idle;
  mutable std::mutex write_mu;  // in-process writers queue here, not on SQLITE_BUSY

  /// A pooled connection, returned on destruction.
  class Lease {
   public:
    Lease(const Impl& impl, std::unique_ptr<Connection> c) : impl_(impl), c_(std::move(c)) {}
    ~Lease() {
      std::lock_guard lock(impl_.pool_mu);
      if (impl_.idle.size() < impl_.opt.max_idle_connections) impl_.idle.push_back(std::move(c_));
    }
    Lease(const Lease&) = delete;
    Lease& operator=(const Lease&) = delete;
    Connection* operator->() { return c_.get(); }
    Connection& operator*() { return *c_; }

   private:
    const Impl& impl_;
    std::unique_ptr<Connection> c_;
  };

  Lease lease() const {
    {
      std::lock_guard lock(pool_mu);
      if (!idle.empty()) {
        auto c = std::move(idle.back());
        idle.pop_back();
        return Lease(*this, std::move(c));
      }
    }
    return Lease(*this, std::make_unique<Connection>(path, opt.busy_timeout_ms));
  }

  /// Runs fn(conn) in a write transaction (BEGIN IMMEDIATE ... COMMIT).
  template <typename F>
  auto write(F&& fn) {
    std::lock_guard lock(write_mu);
    Lease c = lease();
    c->exec("BEGIN IMMEDIATE");
    try {
      if constexpr (std::is_void_v<decltype(fn(*c))>) {
        fn(*c);
        c->exec("COMMIT");
      } else {
        auto r = fn(*c);
        c->exec("COMMIT");
        return r;
      }
    } catch (...) {
      try {
        c->exec("ROLLBACK");
      } catch (...) {  // nothing to roll back: the error came from COMMIT itself
      }
      throw;
    }
  }

  /// Runs fn(conn) in a read transaction (one consistent snapshot).
  template <typename F>
  auto read(F&& fn) const {
    Lease c = lease();
    c->exec("BEGIN");
    try {
      auto r = fn(*c);
      c->exec("COMMIT");
      return r;
    } catch (...) {
      try {
        c->exec("ROLLBACK");
      } catch (...) {
      }
      throw;
    }
  }

  void migrate() {
    std::lock_guard lock(write_mu);
    Lease c = lease();
    c->exec(kBootstrapSql);
    c->exec("BEGIN IMMEDIATE");
    try {
      std::int64_t have = 0;
      {
        auto s = c->stmt("SELECT COALESCE(MAX(version), 0) FROM schema_migrations");
        if (s.step()) have = s.i64(0);
      }
      for (const auto& m : sqlite_store_migrations()) {
        if (m.version == 0 || m.version <= have) continue;
        c->exec(m.sql);
        c->stmt("INSERT INTO schema_migrations(version, name, applied_at) VALUES (?1, ?2, ?3)")
            .bind(1, m.version)
            .bind(2, m.name)
            .bind(3, now_iso())
            .run();
      }
      c->exec("COMMIT");
    } catch (...) {
      c->exec("ROLLBACK");
      throw;
    }
  }

  /// Crash leftovers: temp dirs, package dirs without a drives row, and map
  /// versions stuck in 'building', all older than the grace period.
  void sweep_orphans() {
    std::set<std::string> known;
    read([&](Connection& c) {
      auto s = c.stmt("SELECT content_hash FROM drives");
      while (s.step()) known.insert(s.text(0));
      return 0;
    });
    const auto now = fs::file_time_type::clock::now();
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(drives_dir, ec)) {
      const std::string name = e.path().filename().string();
      const bool tmp = name.starts_with(".tmp-");
      if (!tmp && known.contains(name)) continue;
      if (!tmp && !is_hex(name)) continue;  // not ours
      const auto age = std::chrono::duration<double>(now - e.last_write_time(ec)).count();
      if (age >= opt.orphan_grace_s) fs::remove_all(e.path(), ec);
    }
    write([&](Connection& c) {
      char grace_modifier[48];
      std::snprintf(grace_modifier, sizeof grace_modifier, "-%lld seconds",
                    static_cast<long long>(std::ceil(opt.orphan_grace_s)));
      c.stmt(
           "UPDATE map_versions SET status = 'failed', error = 'interrupted (found building on open)' "
           "WHERE status = 'building' AND created_at <= strftime('%Y-%m-%dT%H:%M:%SZ', 'now', ?1)")
          .bind(1, grace_modifier)
          .run();
      drop_failed_content(c);
    });
  }

  static void drop_failed_content(Connection& c) {
    c.exec(
        "DELETE FROM landmarks WHERE version IN (SELECT version FROM map_versions WHERE status = "
        "'failed'); "
        "DELETE FROM tiles WHERE version IN (SELECT version FROM map_versions WHERE status = "
        "'failed'); "
        "DELETE FROM gridmap_tiles WHERE version IN (SELECT version FROM map_versions WHERE "
        "status = 'failed');");
    gc_blobs(c);
  }

  static void gc_blobs(Connection& c) {
    c.exec(
        "DELETE FROM tile_blobs WHERE id NOT IN (SELECT blob FROM tiles) AND id NOT IN (SELECT "
        "blob FROM gridmap_tiles)");
  }

  DriveRecord drive_from_row(Stmt& s) const {
    DriveRecord d;
    d.row = s.i64(0);
    d.drive_id = s.text(1);
    d.content_hash = s.text(2);
    d.vehicle_id = s.text(3);
    d.start_time_s = s.f64(4);
    d.end_time_s = s.f64(5);
    d.bbox = {s.f64(6), s.f64(7), s.f64(8), s.f64(9)};
    d.pol_level = parse_pol_level(s.text(10)).value_or(PolLevel::Full);
    d.distance_m = s.f64(11);
    d.num_points = s.i64(12);
    d.num_lines = s.i64(13);
    d.manifest = nlohmann::json::parse(s.text(14), nullptr, false);
    d.package_path = drives_dir / s.text(15);
    d.ingested_at = s.text(16);
    return d;
  }

  std::optional<DriveRecord> drive_where(Connection& c, const std::string& where,
                                         std::string_view value) const {
    auto s = c.stmt(std::string("SELECT ") + kDriveColumns + " FROM drives WHERE " + where);
    s.bind(1, value);
    if (!s.step()) return std::nullopt;
    return drive_from_row(s);
  }

  static std::optional<MapVersionStatus> version_status(Connection& c, std::int64_t v) {
    auto s = c.stmt("SELECT status FROM map_versions WHERE version = ?1");
    s.bind(1, v);
    if (!s.step()) return std::nullopt;
    return parse_status(s.text(0));
  }

  static void require_building(Connection& c, std::int64_t v) {
    const auto st = version_status(c, v);
    if (!st) throw NotFoundError("map version " + std::to_string(v) + " does not exist");
    if (*st != MapVersionStatus::Building) {
      throw ValidationError("map version " + std::to_string(v) + " is " +
                            std::string(to_string(*st)) + ", not building");
    }
  }

  static void require_published(Connection& c, std::int64_t v) {
    const auto st = version_status(c, v);
    if (!st || *st != MapVersionStatus::Published) {
      throw NotFoundError("map version " + std::to_string(v) +
                          (st ? " is not published (" + std::string(to_string(*st)) + ")"
                              : " does not exist"));
    }
  }

  void hook(std::string_view stage) const {
    if (opt.fault_hook) opt.fault_hook(stage);
  }
};

// ===================================================================== SqliteMapStore

SqliteMapStore::SqliteMapStore(const fs::path& db_path, SqliteStoreOptions options)
    : impl_(std::make_unique<Impl>()) {
  impl_->path = db_path;
  impl_->opt = std::move(options);
  impl_->drives_dir = impl_->opt.drive_store_dir.empty() ? fs::path(db_path.string() + ".drives")
                                                         : impl_->opt.drive_store_dir;
  std::error_code ec;
  if (db_path.has_parent_path()) fs::create_directories(db_path.parent_path(), ec);
  fs::create_directories(impl_->drives_dir, ec);
  if (ec) throw IoError("cannot create drive store " + impl_->drives_dir.string() + ": " + ec.message());
  impl_->migrate();
  impl_->sweep_orphans();
}

SqliteMapStore::~SqliteMapStore() = default;

const fs::path& SqliteMapStore::path() const { return impl_->path; }
const fs::path& SqliteMapStore::drive_store_dir() const { return impl_->drives_dir; }

int SqliteMapStore::schema_version() const {
  return impl_->read([](Connection& c) {
    auto s = c.stmt("SELECT COALESCE(MAX(version), 0) FROM schema_migrations");
    return s.step() ? static_cast<int>(s.i64(0)) : 0;
  });
}

std::string SqliteMapStore::pragma(std::string_view name) const {
  auto c = impl_->lease();
  auto s = c->stmt("PRAGMA " + std::string(name));
  return s.step() ? s.text(0) : std::string();
}

// --------------------------------------------------------------------- drives

PutDriveResult SqliteMapStore::put_drive(const DrivePackage& package,
                                         const fs::path& package_location,
                                         const std::string& content_hash) {
  Impl& I = *impl_;
  if (!is_hex(content_hash) || content_hash.size() < 16 || content_hash.size() > 128) {
    throw ValidationError("put_drive: content hash must be lower-case hex, got '" + content_hash +
                          "'");
  }
  const DriveManifest& m = package.manifest;
  if (m.drive_id.empty()) throw ValidationError("put_drive: manifest.json: field 'drive_id' is empty");
  if (auto existing = find_drive_by_hash(content_hash)) {
    return {PutDriveResult::Status::AlreadyPresent, *existing};
  }
  if (auto same_name = get_drive(m.drive_id)) {
    throw ConflictError("drive '" + m.drive_id + "' is already stored with content hash " +
                        same_name->content_hash + " (upload has " + content_hash + ")");
  }
  std::error_code ec;
  if (package_location.empty() || !fs::exists(package_location, ec)) {
    throw IoError("put_drive: package location '" + package_location.string() + "' does not exist");
  }

  // Geodetic coordinates of everything (drive frame -> WGS84) and the bbox.
  const tiles::LocalFrame frame(m.origin);
  GeoBox bbox{90.0, 180.0, -90.0, -180.0};
  auto grow = [&](double lat, double lon) {
    bbox.min_lat_deg = std::min(bbox.min_lat_deg, lat);
    bbox.max_lat_deg = std::max(bbox.max_lat_deg, lat);
    bbox.min_lon_deg = std::min(bbox.min_lon_deg, lon);
    bbox.max_lon_deg = std::max(bbox.max_lon_deg, lon);
  };
  std::vector<GeoPoint> point_geo;
  point_geo.reserve(package.points.size());
  for (const auto& p : package.points) {
    point_geo.push_back(frame.to_geo(p.position_m));
    grow(point_geo.back().lat_deg, point_geo.back().lon_deg);
  }
  std::vector<std::pair<GeoPoint, GeoPoint>> line_geo;
  line_geo.reserve(package.lines.size());
  for (const auto& l : package.lines) {
    line_geo.emplace_back(frame.to_geo(l.start_m), frame.to_geo(l.end_m));
    grow(line_geo.back().first.lat_deg, line_geo.back().first.lon_deg);
    grow(line_geo.back().second.lat_deg, line_geo.back().second.lon_deg);
  }
  for (const auto& t : package.trajectory) grow(t.lat_deg, t.lon_deg);
  if (bbox.min_lat_deg > bbox.max_lat_deg) bbox = {m.origin.lat_deg, m.origin.lon_deg,
                                                   m.origin.lat_deg, m.origin.lon_deg};

  // 1. Files into a temp dir of the drive store (same file system: rename is atomic).
  const std::string rand_suffix = std::to_string(std::random_device{}());
  const fs::path tmp = I.drives_dir / (".tmp-" + content_hash + "-" + rand_suffix);
  const fs::path final_dir = I.drives_dir / content_hash;
  std::string rel_path = content_hash;
  bool renamed = false;
  auto cleanup = [&] {
    std::error_code e2;
    fs::remove_all(tmp, e2);
    if (renamed) fs::remove_all(final_dir, e2);
  };
  try {
    fs::create_directories(tmp);
    if (fs::is_directory(package_location)) {
      fs::copy(package_location, tmp, fs::copy_options::recursive);
    } else {
      const std::string fname = package_location.filename().string();
      fs::copy_file(package_location, tmp / fname);
      rel_path += "/" + fname;
    }
    const std::int64_t bytes = dir_bytes(tmp);
    I.hook("files_copied");

    // 2. Rows, rename, commit: one transaction.
    const auto result = I.write([&](Connection& c) -> std::optional<DriveRecord> {
      // Re-check under the write lock: another thread may have stored it meanwhile.
      if (auto existing = I.drive_where(c, "content_hash = ?1", content_hash)) return existing;
      if (auto same = I.drive_where(c, "drive_id = ?1", m.drive_id)) {
        throw ConflictError("drive '" + m.drive_id + "' is already stored with content hash " +
                            same->content_hash);
      }
      c.stmt(
           "INSERT INTO drives(drive_id, content_hash, vehicle_id, start_time_s, end_time_s, "
           "min_lat_deg, min_lon_deg, max_lat_deg, max_lon_deg, pol_level, distance_m, num_points, "
           "num_lines, manifest_json, package_path, package_bytes, ingested_at) VALUES "
           "(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17)")
          .bind(1, m.drive_id)
          .bind(2, content_hash)
          .bind(3, m.vehicle_id)
          .bind(4, m.start_time_s)
          .bind(5, m.end_time_s)
          .bind(6, bbox.min_lat_deg)
          .bind(7, bbox.min_lon_deg)
          .bind(8, bbox.max_lat_deg)
          .bind(9, bbox.max_lon_deg)
          .bind(10, to_string(m.pol_level))
          .bind(11, m.distance_m)
          .bind(12, static_cast<std::int64_t>(package.points.size()))
          .bind(13, static_cast<std::int64_t>(package.lines.size()))
          .bind(14, manifest_json(m).dump())
          .bind(15, rel_path)
          .bind(16, bytes)
          .bind(17, now_iso())
          .run();
      const std::int64_t drive_row = c.last_id();
      insert_rtree(c, "drives_rtree", drive_row, bbox.min_lat_deg, bbox.max_lat_deg,
                   bbox.min_lon_deg, bbox.max_lon_deg);
      const std::string ins =
          "INSERT INTO candidates(drive, kind, lat_deg, lon_deg, x_m, y_m, end_lat_deg, "
          "end_lon_deg, end_x_m, end_y_m, strength, power_db, scattering, num_cells) VALUES "
          "(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14)";
      for (std::size_t i = 0; i < package.points.size(); ++i) {
        const auto& p = package.points[i];
        const auto& g = point_geo[i];
        c.stmt(ins)
            .bind(1, drive_row)
            .bind(2, 0)
            .bind(3, g.lat_deg)
            .bind(4, g.lon_deg)
            .bind(5, p.position_m.x())
            .bind(6, p.position_m.y())
            .bind_null(7)
            .bind_null(8)
            .bind_null(9)
            .bind_null(10)
            .bind(11, p.strength)
            .bind(12, p.power_db)
            .bind(13, static_cast<int>(p.scattering))
            .bind(14, static_cast<std::int64_t>(p.num_cells))
            .run();
        insert_rtree(c, "candidates_rtree", c.last_id(), g.lat_deg, g.lat_deg, g.lon_deg,
                     g.lon_deg);
      }
      for (std::size_t i = 0; i < package.lines.size(); ++i) {
        const auto& l = package.lines[i];
        const auto& [a, b] = line_geo[i];
        c.stmt(ins)
            .bind(1, drive_row)
            .bind(2, 1)
            .bind(3, a.lat_deg)
            .bind(4, a.lon_deg)
            .bind(5, l.start_m.x())
            .bind(6, l.start_m.y())
            .bind(7, b.lat_deg)
            .bind(8, b.lon_deg)
            .bind(9, l.end_m.x())
            .bind(10, l.end_m.y())
            .bind(11, l.strength)
            .bind_null(12)
            .bind_null(13)
            .bind_null(14)
            .run();
        insert_rtree(c, "candidates_rtree", c.last_id(), std::min(a.lat_deg, b.lat_deg),
                     std::max(a.lat_deg, b.lat_deg), std::min(a.lon_deg, b.lon_deg),
                     std::max(a.lon_deg, b.lon_deg));
      }
      {
        nlohmann::json samples = nlohmann::json::array();
        const TrajectorySample* last = nullptr;
        for (std::size_t i = 0; i < package.trajectory.size(); ++i) {
          const auto& t = package.trajectory[i];
          bool keep = last == nullptr || i + 1 == package.trajectory.size() ||
                      t.time_s - last->time_s >= kTrajectoryMaxGapS;
          if (!keep) {
            const double dn = (t.lat_deg - last->lat_deg) * 111320.0;
            const double de = (t.lon_deg - last->lon_deg) * 111320.0 *
                              std::cos(t.lat_deg * 3.14159265358979 / 180.0);
            keep = dn * dn + de * de >= kTrajectorySpacingM * kTrajectorySpacingM;
          }
          if (!keep) continue;
          samples.push_back({t.time_s, t.lat_deg, t.lon_deg, t.yaw_enu_rad, t.speed_mps});
          last = &t;
        }
        c.stmt(
             "INSERT INTO drive_trajectories(drive, min_spacing_m, samples_json) VALUES (?1, ?2, "
             "?3)")
            .bind(1, drive_row)
            .bind(2, kTrajectorySpacingM)
            .bind(3, samples.dump())
            .run();
      }
      I.hook("rows_inserted");
      std::error_code e;
      if (fs::exists(final_dir, e)) fs::remove_all(final_dir, e);  // crash leftover
      fs::rename(tmp, final_dir);
      renamed = true;
      I.hook("files_renamed");
      return std::nullopt;
    });
    if (result) {  // raced with an identical upload
      cleanup();
      return {PutDriveResult::Status::AlreadyPresent, *result};
    }
  } catch (...) {
    cleanup();
    throw;
  }
  auto rec = get_drive(m.drive_id);
  if (!rec) throw IoError("put_drive: drive '" + m.drive_id + "' vanished after insert");
  return {PutDriveResult::Status::Inserted, *rec};
}

std::vector<DriveRecord> SqliteMapStore::list_drives() const {
  return impl_->read([&](Connection& c) {
    std::vector<DriveRecord> out;
    auto s = c.stmt(std::string("SELECT ") + kDriveColumns + " FROM drives ORDER BY id");
    while (s.step()) out.push_back(impl_->drive_from_row(s));
    return out;
  });
}

std::optional<DriveRecord> SqliteMapStore::get_drive(std::string_view drive_id) const {
  return impl_->read([&](Connection& c) { return impl_->drive_where(c, "drive_id = ?1", drive_id); });
}

std::optional<DriveRecord> SqliteMapStore::find_drive_by_hash(std::string_view content_hash) const {
  return impl_->read(
      [&](Connection& c) { return impl_->drive_where(c, "content_hash = ?1", content_hash); });
}

std::vector<TrajectorySample> SqliteMapStore::drive_trajectory(std::string_view drive_id) const {
  return impl_->read([&](Connection& c) {
    std::vector<TrajectorySample> out;
    auto d = impl_->drive_where(c, "drive_id = ?1", drive_id);
    if (!d) throw NotFoundError("drive '" + std::string(drive_id) + "' is not in the store");
    auto s = c.stmt("SELECT samples_json FROM drive_trajectories WHERE drive = ?1");
    s.bind(1, d->row);
    if (!s.step()) return out;  // ingested before migration 2
    for (const auto& v : nlohmann::json::parse(s.text(0))) {
      TrajectorySample t;
      t.time_s = v.at(0).get<double>();
      t.lat_deg = v.at(1).get<double>();
      t.lon_deg = v.at(2).get<double>();
      t.yaw_enu_rad = v.at(3).get<double>();
      t.speed_mps = v.at(4).get<double>();
      out.push_back(t);
    }
    return out;
  });
}

std::vector<DriveRecord> SqliteMapStore::drives_in(const GeoBox& box) const {
  return impl_->read([&](Connection& c) {
    std::vector<DriveRecord> out;
    std::set<std::int64_t> seen;
    for (const GeoBox& b : split_box(box)) {
      auto s = c.stmt(std::string("SELECT ") + kDriveColumns +
                      " FROM drives WHERE id IN (SELECT id FROM drives_rtree WHERE max_lat >= ?1 "
                      "AND min_lat <= ?2 AND max_lon >= ?3 AND min_lon <= ?4) ORDER BY id");
      s.bind(1, b.min_lat_deg).bind(2, b.max_lat_deg).bind(3, b.min_lon_deg).bind(4, b.max_lon_deg);
      while (s.step()) {
        DriveRecord d = impl_->drive_from_row(s);
        if (seen.insert(d.row).second &&
            box_intersects(box, d.bbox.min_lat_deg, d.bbox.min_lon_deg, d.bbox.max_lat_deg,
                           d.bbox.max_lon_deg)) {
          out.push_back(std::move(d));
        }
      }
    }
    std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.row < b.row; });
    return out;
  });
}

bool SqliteMapStore::delete_drive(std::string_view drive_id) {
  std::optional<fs::path> files;
  impl_->write([&](Connection& c) {
    auto d = impl_->drive_where(c, "drive_id = ?1", drive_id);
    if (!d) return;
    c.stmt("DELETE FROM drives WHERE id = ?1").bind(1, d->row).run();
    files = impl_->drives_dir / d->content_hash;
  });
  if (!files) return false;
  std::error_code ec;
  fs::remove_all(*files, ec);  // after commit; a failure leaves an orphan swept on open
  return true;
}

// --------------------------------------------------------------------- candidates

CandidateSet SqliteMapStore::candidates_in(const std::optional<GeoBox>& region,
                                           std::span<const std::string> excluded) const {
  return impl_->read([&](Connection& c) {
    std::unordered_set<std::int64_t> excluded_rows;
    for (const auto& name : excluded) {
      auto d = impl_->drive_where(c, "drive_id = ?1", name);
      if (!d) throw NotFoundError("excluded drive '" + name + "' is not in the store");
      excluded_rows.insert(d->row);
    }
    CandidateSet out;
    const std::string cols =
        "SELECT c.id, c.drive, c.kind, c.lat_deg, c.lon_deg, c.x_m, c.y_m, c.end_lat_deg, "
        "c.end_lon_deg, c.end_x_m, c.end_y_m, c.strength, c.power_db, c.scattering, c.num_cells "
        "FROM candidates c";
    auto take = [&](Stmt& s) {
      if (excluded_rows.contains(s.i64(1))) return;
      const double lat = s.f64(3), lon = s.f64(4);
      if (s.i64(2) == 0) {
        if (region && !box_contains(*region, lat, lon)) return;
        StoredPointCandidate p;
        p.id = s.i64(0);
        p.drive = s.i64(1);
        p.position = {lat, lon, 0.0};
        p.candidate.position_m = {s.f64(5), s.f64(6)};
        p.candidate.strength = s.f64(11);
        p.candidate.power_db = s.f64(12);
        p.candidate.scattering = static_cast<ScatteringClass>(s.i64(13) & 3);
        p.candidate.num_cells = static_cast<std::uint32_t>(s.i64(14));
        out.points.push_back(p);
      } else {
        const double lat1 = s.f64(7), lon1 = s.f64(8);
        if (region && !box_intersects(*region, std::min(lat, lat1), std::min(lon, lon1),
                                      std::max(lat, lat1), std::max(lon, lon1))) {
          return;
        }
        StoredLineCandidate l;
        l.id = s.i64(0);
        l.drive = s.i64(1);
        l.start = {lat, lon, 0.0};
        l.end = {lat1, lon1, 0.0};
        l.candidate.start_m = {s.f64(5), s.f64(6)};
        l.candidate.end_m = {s.f64(9), s.f64(10)};
        l.candidate.strength = s.f64(11);
        out.lines.push_back(l);
      }
    };
    if (!region) {
      auto s = c.stmt(cols + " ORDER BY c.id");
      while (s.step()) take(s);
    } else {
      for (const GeoBox& b : split_box(*region)) {
        auto s = c.stmt(cols +
                        " JOIN candidates_rtree r ON r.id = c.id WHERE r.max_lat >= ?1 AND "
                        "r.min_lat <= ?2 AND r.max_lon >= ?3 AND r.min_lon <= ?4 ORDER BY c.id");
        s.bind(1, b.min_lat_deg).bind(2, b.max_lat_deg).bind(3, b.min_lon_deg).bind(4, b.max_lon_deg);
        while (s.step()) take(s);
      }
      if (region->crosses_antimeridian()) {
        auto by_id = [](const auto& a, const auto& b) { return a.id < b.id; };
        auto same = [](const auto& a, const auto& b) { return a.id == b.id; };
        std::sort(out.points.begin(), out.points.end(), by_id);
        out.points.erase(std::unique(out.points.begin(), out.points.end(), same), out.points.end());
        std::sort(out.lines.begin(), out.lines.end(), by_id);
        out.lines.erase(std::unique(out.lines.begin(), out.lines.end(), same), out.lines.end());
      }
    }
    return out;
  });
}

// --------------------------------------------------------------------- map versions

std::int64_t SqliteMapStore::begin_map_version(const nlohmann::json& parameters) {
  return impl_->write([&](Connection& c) {
    c.stmt(
         "INSERT INTO map_versions(status, created_at, parameters_json) VALUES ('building', ?1, ?2)")
        .bind(1, now_iso())
        .bind(2, parameters.dump())
        .run();
    return c.last_id();
  });
}

void SqliteMapStore::put_landmarks(std::int64_t version, std::span<const StoredPointLandmark> points,
                                   std::span<const StoredLineLandmark> lines) {
  impl_->write([&](Connection& c) {
    Impl::require_building(c, version);
    const std::string ins =
        "INSERT INTO landmarks(version, key, kind, lat_deg, lon_deg, polyline_json, scattering, "
        "support_drives, spread_m) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)";
    const std::string sup = "INSERT INTO landmark_support(landmark, candidate) VALUES (?1, ?2)";
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
  });
}

void SqliteMapStore::put_tiles(std::int64_t version, TileLayer layer,
                               std::span<const TileWrite> tiles_in) {
  impl_->write([&](Connection& c) {
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
  });
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
        "l.support_drives, l.spread_m FROM landmarks l";
    std::set<std::int64_t> seen;
    auto take = [&](Stmt& s) {
      const std::int64_t id = s.i64(0);
      if (!seen.insert(id).second) return;
      std::vector<std::int64_t> support;
      if (with_support) {
        auto q = c.stmt("SELECT candidate FROM landmark_support WHERE landmark = ?1 ORDER BY candidate");
        q.bind(1, id);
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
    st.database_bytes = one("SELECT page_count * page_size FROM pragma_page_count, pragma_page_size");
    st.drive_store_bytes = one("SELECT COALESCE(SUM(package_bytes), 0) FROM drives");
    return st;
  });
}

}  // namespace polmap::mapping
