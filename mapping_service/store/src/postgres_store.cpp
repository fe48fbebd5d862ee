// PostgresMapStore: the PostgreSQL/PostGIS MapStore (see postgres_store.hpp for the
// connection, locking and crash-safety rules; schema/store_postgres.sql, embedded at build
// time, for the DDL). This file: open, migrations, package directory setting, crash sweep,
// statistics, WKB; drives and candidates in postgres_store_drives.cpp, map versions and
// published content in postgres_store_maps.cpp, upload sessions in
// postgres_store_uploads.cpp, the merged gridmap's sums in postgres_store_gridmap.cpp.
#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <set>

#include "polmap/util/text.hpp"
#include "postgres_store_impl.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;

namespace pg_store_detail {

extern const std::string_view kPostgresStoreSql;  // generated from schema/store_postgres.sql

namespace {
void put_u32(std::string& out, std::uint32_t v) {
  static_assert(std::endian::native == std::endian::little, "WKB is written little-endian");
  out.append(reinterpret_cast<const char*>(&v), 4);
}
void put_f64(std::string& out, double v) { out.append(reinterpret_cast<const char*>(&v), 8); }
}  // namespace

std::string wkb_point(double lat_deg, double lon_deg) {
  std::string out(1, '\1');  // little-endian
  put_u32(out, 1);           // Point
  put_f64(out, lon_deg);
  put_f64(out, lat_deg);
  return out;
}

std::string wkb_line(const std::vector<GeoPoint>& vertices) {
  std::string out(1, '\1');
  put_u32(out, 2);  // LineString
  put_u32(out, static_cast<std::uint32_t>(vertices.size()));
  for (const auto& v : vertices) {
    put_f64(out, v.lon_deg);
    put_f64(out, v.lat_deg);
  }
  return out;
}

}  // namespace pg_store_detail

const std::vector<StoreMigration>& postgres_store_migrations() {
  static const std::vector<StoreMigration> m =
      parse_store_migrations(kPostgresStoreSql, "schema/store_postgres.sql");
  return m;
}

namespace {
constexpr std::string_view kFoundBuildingOnOpen = "interrupted (found building on open)";
constexpr std::string_view kBuilderGone = "interrupted (the process building it is gone)";

/// Absolute, normalized, without a trailing separator: the form recorded in the database.
fs::path normalized_dir(const fs::path& p) {
  fs::path a = fs::absolute(p).lexically_normal();
  std::string s = a.string();
  while (s.size() > 1 && s.back() == '/') s.pop_back();
  return s;
}
}  // namespace

void PostgresMapStore::Impl::migrate_and_configure() {
  Lease c = lease();
  pg::Transaction tx(*c);
  // Concurrent openers (replicas starting together) wait here for each other.
  c->run("SELECT pg_advisory_xact_lock($1, $2)", kLockClass, kMigrationLock);
  const auto& migrations = postgres_store_migrations();
  c->exec(migrations.front().sql);
  const std::int64_t have =
      c->run("SELECT COALESCE(MAX(version), 0)::bigint FROM schema_migrations").i64(0, 0);
  for (const auto& m : migrations) {
    if (m.version == 0 || m.version <= have) continue;
    c->exec(m.sql);
    c->run("INSERT INTO schema_migrations(version, name, applied_at) VALUES ($1, $2, $3)",
           m.version, m.name, now_iso());
  }
  // The package directory: recorded at the first open, the same for every later one.
  const Result r = c->run("SELECT value FROM store_settings WHERE key = 'package_dir'");
  if (r.empty()) {
    if (opt.package_dir.empty()) {
      throw ValidationError("the PostgreSQL store " + description +
                            " is opened for the first time: it needs a package directory "
                            "(--package-dir DIR, shared by every replica)");
    }
    package_dir = normalized_dir(opt.package_dir);
    c->run("INSERT INTO store_settings(key, value) VALUES ('package_dir', $1)",
           package_dir.string());
  } else {
    package_dir = r.text(0, 0);
    if (!opt.package_dir.empty() && normalized_dir(opt.package_dir) != package_dir) {
      throw ValidationError("the PostgreSQL store " + description + " keeps its packages in " +
                            package_dir.string() + ", not in " +
                            normalized_dir(opt.package_dir).string() +
                            " (leave --package-dir out or name that directory)");
    }
  }
  tx.commit();
}

void PostgresMapStore::Impl::unlock_build(std::int64_t version) {
  std::lock_guard lock(session_mu);
  held_builds.erase(version);
  if (!session || !session->reusable()) return;
  try {
    session->run("SELECT pg_advisory_unlock($1, $2)", kBuildLockClass, static_cast<int>(version));
  } catch (const Error&) {  // the lock goes with the connection anyway
  }
}

void PostgresMapStore::Impl::ensure_session() {
  if (session && session->reusable()) {
    try {
      session->exec("SELECT 1");  // a session the server ended shows only when used
      return;
    } catch (const Error&) {
    }
  }
  // The server ended the old session (network, restart) and with it every lock it held.
  // A build of ours that another replica failed meanwhile fails at its publish.
  session = std::make_unique<Connection>(conninfo, description);
  if (owner) {
    owner =
        session->run("SELECT pg_try_advisory_lock($1, $2)", kLockClass, kOwnerLock).i64(0, 0) != 0;
  }
  for (const std::int64_t v : held_builds) {
    session->run("SELECT pg_try_advisory_lock($1, $2)", kBuildLockClass, static_cast<int>(v));
  }
}

std::vector<std::int64_t> PostgresMapStore::Impl::fail_abandoned_builds_tx(Connection& c,
                                                                           std::string_view error) {
  // A version exists only with its builder's lock (begin_map_version takes both in one
  // transaction), so a free lock means the builder is gone.
  const Result r = c.run(
      "SELECT version FROM map_versions v WHERE status = 'building' "
      // A partitioned build with jobs left is queued for build workers, not interrupted.
      "AND NOT EXISTS (SELECT 1 FROM build_jobs j WHERE j.version = v.version AND j.state "
      "IN ('pending', 'running')) ORDER BY version");
  std::vector<std::int64_t> failed;
  for (int i = 0; i < r.rows(); ++i) {
    const std::int64_t v = r.i64(i, 0);
    const Result free =
        c.run("SELECT pg_try_advisory_xact_lock($1, $2)", kBuildLockClass, static_cast<int>(v));
    if (free.i64(0, 0) == 0) continue;  // its builder is still running
    c.run("UPDATE map_versions SET status = 'failed', error = $1 WHERE version = $2", error, v);
    failed.push_back(v);
  }
  if (!failed.empty()) drop_failed_content(c);
  return failed;
}

void PostgresMapStore::Impl::sweep_orphans() {
  std::set<std::string> known;
  read([&](Connection& c) {
    const Result r = c.run("SELECT content_hash FROM drives");
    for (int i = 0; i < r.rows(); ++i) known.insert(r.text(i, 0));
    return 0;
  });
  const auto now = fs::file_time_type::clock::now();
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(package_dir, ec)) {
    const std::string name = e.path().filename().string();
    const bool tmp = name.starts_with(".tmp-");
    if (!tmp && known.contains(name)) continue;
    if (!tmp && !util::is_lower_hex(name)) continue;  // not ours (uploads/, ...)
    const auto age = std::chrono::duration<double>(now - e.last_write_time(ec)).count();
    if (age >= opt.orphan_grace_s) fs::remove_all(e.path(), ec);
  }
  std::set<std::string> sessions;
  read([&](Connection& c) {
    const Result r = c.run("SELECT file_path FROM upload_sessions");
    for (int i = 0; i < r.rows(); ++i) sessions.insert(r.text(i, 0));
    return 0;
  });
  for (const auto& e : fs::directory_iterator(uploads_dir, ec)) {
    const std::string name = e.path().filename().string();
    if (sessions.contains(name) || name.size() != 32 || !util::is_lower_hex(name)) continue;
    const auto age = std::chrono::duration<double>(now - e.last_write_time(ec)).count();
    if (age >= opt.orphan_grace_s) fs::remove(e.path(), ec);
  }
  // Builds whose process is gone (their lock is free).
  write([&](Connection& c) { (void)fail_abandoned_builds_tx(c, kFoundBuildingOnOpen); });
}

PostgresMapStore::PostgresMapStore(PostgresStoreOptions options) : impl_(std::make_unique<Impl>()) {
  Impl& I = *impl_;
  I.opt = std::move(options);
  if (I.opt.conninfo.empty()) throw ValidationError("PostgresMapStore: empty conninfo");
  I.conninfo = I.opt.conninfo;
  I.description = pg::describe_conninfo(I.conninfo);
  I.migrate_and_configure();
  I.uploads_dir = I.package_dir / "uploads";
  std::error_code ec;
  fs::create_directories(I.package_dir, ec);
  if (ec) {
    throw IoError("cannot create package directory " + I.package_dir.string() + ": " +
                  ec.message());
  }
  fs::create_directories(I.uploads_dir, ec);
  if (ec) {
    throw IoError("cannot create upload session directory " + I.uploads_dir.string() + ": " +
                  ec.message());
  }
  // The owner (first opener still running) alone sweeps; it keeps the lock on its session
  // connection, which also holds the locks of the builds this object runs.
  I.session = std::make_unique<Connection>(I.conninfo, I.description);
  I.owner =
      I.session->run("SELECT pg_try_advisory_lock($1, $2)", kLockClass, kOwnerLock).i64(0, 0) != 0;
  if (I.owner) I.sweep_orphans();
}

PostgresMapStore::~PostgresMapStore() = default;

std::vector<std::int64_t> PostgresMapStore::fail_abandoned_builds() {
  {
    // Our own builds' locks must be held before another's are judged.
    std::lock_guard lock(impl_->session_mu);
    impl_->ensure_session();
  }
  return impl_->write(
      [&](Connection& c) { return impl_->fail_abandoned_builds_tx(c, kBuilderGone); });
}

const fs::path& PostgresMapStore::package_dir() const { return impl_->package_dir; }
const fs::path& PostgresMapStore::upload_session_dir() const { return impl_->uploads_dir; }
const std::string& PostgresMapStore::description() const { return impl_->description; }
bool PostgresMapStore::owns_store() const { return impl_->owner; }

int PostgresMapStore::schema_version() const {
  return impl_->read([](Connection& c) {
    return static_cast<int>(
        c.run("SELECT COALESCE(MAX(version), 0)::bigint FROM schema_migrations").i64(0, 0));
  });
}

StoreStats PostgresMapStore::stats() const {
  return impl_->read([&](Connection& c) {
    StoreStats st;
    const Result r = c.run(
        "SELECT (SELECT COUNT(*) FROM drives), "
        "(SELECT COUNT(*) FROM candidates WHERE kind = 0), "
        "(SELECT COUNT(*) FROM candidates WHERE kind = 1), "
        "(SELECT COUNT(*) FROM map_versions), "
        "(SELECT version FROM current_map WHERE id = 1), "
        "(SELECT COUNT(*) FROM tile_blobs), "
        "(SELECT COALESCE(SUM(byte_size), 0)::bigint FROM tile_blobs), "
        "(SELECT COALESCE(SUM(package_bytes), 0)::bigint FROM drives), "
        "(SELECT COALESCE(SUM(pg_total_relation_size(c.oid)), 0)::bigint FROM pg_class c JOIN "
        "pg_namespace n ON n.oid = c.relnamespace WHERE c.relkind = 'r' AND n.nspname = "
        "current_schema() AND c.relname = ANY(ARRAY['schema_migrations', 'store_settings', "
        "'drives', 'candidates', 'map_versions', 'current_map', 'landmarks', "
        "'landmark_support', 'landmark_changes', 'tile_blobs', 'tiles', 'gridmap_tiles', "
        "'gridmap_mechanism_tiles', 'drive_trajectories', 'upload_sessions', 'gridmap_sums', "
        "'gridmap_sum_inputs', 'gridmap_sum_cover']))");
    st.drives = r.i64(0, 0);
    st.point_candidates = r.i64(0, 1);
    st.line_candidates = r.i64(0, 2);
    st.map_versions = r.i64(0, 3);
    if (!r.is_null(0, 4)) st.current_version = r.i64(0, 4);
    st.tile_blobs = r.i64(0, 5);
    st.tile_blob_bytes = r.i64(0, 6);
    st.drive_store_bytes = r.i64(0, 7);
    st.database_bytes = r.i64(0, 8);
    if (st.current_version) {
      const Result l = c.run(
          "SELECT (SELECT COUNT(*) FROM landmarks WHERE version = $1 AND kind = 0), "
          "(SELECT COUNT(*) FROM landmarks WHERE version = $1 AND kind = 1), "
          "(SELECT COUNT(*) FROM tiles WHERE version = $1)",
          *st.current_version);
      st.current_point_landmarks = l.i64(0, 0);
      st.current_line_landmarks = l.i64(0, 1);
      st.current_tiles = l.i64(0, 2);
    }
    return st;
  });
}

}  // namespace polmap::mapping
