// SqliteMapStore: the embedded MapStore (see sqlite_store.hpp for the connection,
// transaction and crash-safety rules; schema/store.sql, embedded at build time, for the
// DDL). This file: open, migrations, crash sweep, helpers; drives and candidates in
// sqlite_store_drives.cpp, map versions and published content in sqlite_store_maps.cpp.
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <set>

#include "polmap/schema/json.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/sha256.hpp"
#include "polmap/util/text.hpp"
#include "sqlite_store_impl.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;

namespace sqlite_store_detail {

extern const std::string_view kStoreSql;  // store_sql.cpp, generated from schema/store.sql

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

}  // namespace sqlite_store_detail

const std::vector<StoreMigration>& sqlite_store_migrations() {
  static const std::vector<StoreMigration> m = parse_store_migrations(kStoreSql);
  return m;
}

void SqliteMapStore::Impl::migrate() {
  std::lock_guard lock(write_mu);
  Lease c = lease();
  const auto& migrations = sqlite_store_migrations();
  c->exec(migrations.front().sql);
  sqlite::Transaction tx(*c, sqlite::Transaction::Mode::Immediate);
  std::int64_t have = 0;
  {
    auto s = c->stmt("SELECT COALESCE(MAX(version), 0) FROM schema_migrations");
    if (s.step()) have = s.i64(0);
  }
  for (const auto& m : migrations) {
    if (m.version == 0 || m.version <= have) continue;
    c->exec(m.sql);
    c->stmt("INSERT INTO schema_migrations(version, name, applied_at) VALUES (?1, ?2, ?3)")
        .bind(1, m.version)
        .bind(2, m.name)
        .bind(3, now_iso())
        .run();
  }
  tx.commit();
}

void SqliteMapStore::Impl::sweep_orphans() {
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
    if (!tmp && !util::is_lower_hex(name)) continue;  // not ours
    const auto age = std::chrono::duration<double>(now - e.last_write_time(ec)).count();
    if (age >= opt.orphan_grace_s) fs::remove_all(e.path(), ec);
  }
  // Upload session files without a row: a crash between creating the file and the commit.
  std::set<std::string> sessions;
  read([&](Connection& c) {
    auto s = c.stmt("SELECT file_path FROM upload_sessions");
    while (s.step()) sessions.insert(s.text(0));
    return 0;
  });
  for (const auto& e : fs::directory_iterator(uploads_dir, ec)) {
    const std::string name = e.path().filename().string();
    if (sessions.contains(name) || name.size() != 32 || !util::is_lower_hex(name)) continue;
    const auto age = std::chrono::duration<double>(now - e.last_write_time(ec)).count();
    if (age >= opt.orphan_grace_s) fs::remove(e.path(), ec);
  }
  write([&](Connection& c) {
    char grace_modifier[48];
    std::snprintf(grace_modifier, sizeof grace_modifier, "-%lld seconds",
                  static_cast<long long>(std::ceil(opt.orphan_grace_s)));
    c.stmt(
         "UPDATE map_versions SET status = 'failed', error = 'interrupted (found building on "
         "open)' "
         "WHERE status = 'building' AND created_at <= strftime('%Y-%m-%dT%H:%M:%SZ', 'now', ?1) "
         // A partitioned build with jobs left is queued for build workers, not interrupted.
         "AND NOT EXISTS (SELECT 1 FROM build_jobs j WHERE j.version = map_versions.version "
         "AND j.state IN ('pending', 'running'))")
        .bind(1, grace_modifier)
        .run();
    drop_failed_content(c);
  });
}

SqliteMapStore::SqliteMapStore(const fs::path& db_path, SqliteStoreOptions options)
    : impl_(std::make_unique<Impl>()) {
  impl_->path = db_path;
  impl_->opt = std::move(options);
  impl_->drives_dir = impl_->opt.drive_store_dir.empty() ? fs::path(db_path.string() + ".drives")
                                                         : impl_->opt.drive_store_dir;
  impl_->uploads_dir = impl_->opt.upload_session_dir.empty()
                           ? fs::path(db_path.string() + ".uploads")
                           : impl_->opt.upload_session_dir;
  std::error_code ec;
  if (db_path.has_parent_path()) fs::create_directories(db_path.parent_path(), ec);
  fs::create_directories(impl_->drives_dir, ec);
  if (ec)
    throw IoError("cannot create drive store " + impl_->drives_dir.string() + ": " + ec.message());
  fs::create_directories(impl_->uploads_dir, ec);
  if (ec) {
    throw IoError("cannot create upload session directory " + impl_->uploads_dir.string() + ": " +
                  ec.message());
  }
  impl_->migrate();
  // Only the process that owns the store sweeps: a second process opening it (an export,
  // a CLI read) must never fail the owner's running build or delete its staging files.
  impl_->owner = std::make_unique<util::FileLock>(db_path.string() + ".lock");
  if (impl_->owner->try_acquire()) {
    impl_->migrate_archived_packages();  // before the sweep: it must see the archives
    impl_->sweep_orphans();
  }
}

bool SqliteMapStore::owns_store() const { return impl_->owner && impl_->owner->held(); }

const ArchiveMigrationReport& SqliteMapStore::archive_migration() const {
  return impl_->archive_report;
}

SqliteMapStore::~SqliteMapStore() = default;

const fs::path& SqliteMapStore::path() const { return impl_->path; }
const fs::path& SqliteMapStore::drive_store_dir() const { return impl_->drives_dir; }
const fs::path& SqliteMapStore::upload_session_dir() const { return impl_->uploads_dir; }

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

}  // namespace polmap::mapping
