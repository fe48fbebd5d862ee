#pragma once
// PostgresMapStore internals shared by its source files (postgres_store.cpp: open,
// migrations, sweep, statistics; postgres_store_drives.cpp: drives and candidates;
// postgres_store_maps.cpp: map versions, landmarks, tiles; postgres_store_uploads.cpp;
// postgres_store_gridmap.cpp). Not installed.
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "pg_db.hpp"
#include "polmap/mapping_service/postgres_store.hpp"
#include "store_common.hpp"

namespace polmap::mapping {
namespace pg_store_detail {

using namespace store_detail;  // NOLINT: internal header of one target
using pg::Bytea;
using pg::Connection;
using pg::Null;
using pg::Params;
using pg::Result;

/// Advisory lock keys (two int4 form): class kLockClass holds the store-wide locks,
/// kBuildLockClass one lock per map version being built.
inline constexpr int kLockClass = 0x706d6170;  // "pmap"
inline constexpr int kBuildLockClass = kLockClass + 1;
inline constexpr int kWriteLock = 1;      ///< transaction-level: every write
inline constexpr int kMigrationLock = 2;  ///< transaction-level: migrations at open
inline constexpr int kOwnerLock = 3;      ///< session-level: the store's owner

inline constexpr const char* kDriveColumns =
    "id, drive_id, content_hash, vehicle_id, start_time_s, end_time_s, min_lat_deg, min_lon_deg, "
    "max_lat_deg, max_lon_deg, pol_level, distance_m, num_points, num_lines, manifest_json, "
    "package_path, ingested_at";

/// Well-known binary (little-endian) of a point and of a line string, x = lon, y = lat.
std::string wkb_point(double lat_deg, double lon_deg);
std::string wkb_line(const std::vector<GeoPoint>& vertices);

}  // namespace pg_store_detail

using namespace pg_store_detail;  // NOLINT: internal header of one target

struct PostgresMapStore::Impl {
  std::string conninfo;
  std::string description;  ///< host:port/db as user (no password)
  std::filesystem::path package_dir;
  std::filesystem::path uploads_dir;
  PostgresStoreOptions opt;
  mutable std::mutex pool_mu;
  mutable std::vector<std::unique_ptr<Connection>> idle;
  /// The session connection: holds the owner lock and the locks of running builds.
  std::mutex session_mu;
  std::unique_ptr<Connection> session;
  bool owner = false;
  std::set<std::int64_t> held_builds;  ///< versions whose build lock the session holds

  /// A pooled connection, returned on destruction (dropped if it is broken or still in a
  /// transaction).
  class Lease {
   public:
    Lease(const Impl& impl, std::unique_ptr<Connection> c) : impl_(impl), c_(std::move(c)) {}
    ~Lease() {
      if (!c_->reusable()) return;
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
    return Lease(*this, std::make_unique<Connection>(conninfo, description));
  }

  /// Runs fn(conn) in a write transaction holding the store's write lock.
  template <typename F>
  auto write(F&& fn) {
    Lease c = lease();
    pg::Transaction tx(*c);
    c->run("SELECT pg_advisory_xact_lock($1, $2)", kLockClass, kWriteLock);
    if constexpr (std::is_void_v<decltype(fn(*c))>) {
      fn(*c);
      tx.commit();
    } else {
      auto r = fn(*c);
      tx.commit();
      return r;
    }
  }

  /// Runs fn(conn) in a read-write transaction without the store's write lock (for row
  /// locks that must not queue behind a long write: claiming build jobs).
  template <typename F>
  auto transact(F&& fn) {
    Lease c = lease();
    pg::Transaction tx(*c);
    auto r = fn(*c);
    tx.commit();
    return r;
  }

  /// Runs fn(conn) in a read-only transaction (one consistent snapshot).
  template <typename F>
  auto read(F&& fn) const {
    Lease c = lease();
    pg::Transaction tx(*c, pg::Transaction::Mode::Snapshot);
    auto r = fn(*c);
    tx.commit();
    return r;
  }

  /// MAX(column) + 1 of a table (under the write lock): ids as SQLite assigns rowids.
  static std::int64_t next_id(Connection& c, const char* table, const char* column) {
    return c.run(std::string("SELECT COALESCE(MAX(") + column + "), 0) FROM " + table).i64(0, 0) +
           1;
  }

  /// Bootstrap and pending migrations, then the package directory setting.
  void migrate_and_configure();
  /// Crash leftovers (owner only): temp dirs and package dirs without a drives row, session
  /// files without a row, abandoned builds.
  void sweep_orphans();

  /// Session-level lock of a running build (released by publish/fail or by the connection's
  /// end, so the sweep can tell a running build from an abandoned one).
  void unlock_build(std::int64_t version);
  /// Reconnects a broken session connection and takes its locks again (the owner lock if
  /// this object owned the store, the locks of the builds it runs). Caller holds
  /// session_mu.
  void ensure_session();
  /// Fails every Building version whose build lock is free and that has no job left.
  std::vector<std::int64_t> fail_abandoned_builds_tx(Connection& c, std::string_view error);

  // Writes inside a transaction the caller holds (the public methods wrap each in one;
  // complete_build_job puts a job's whole output in one).
  static void put_landmarks_tx(Connection& c, std::int64_t version,
                               std::span<const StoredPointLandmark> points,
                               std::span<const StoredLineLandmark> lines);
  static void put_landmark_changes_tx(Connection& c, std::int64_t version,
                                      std::span<const LandmarkChange> changes);
  static void put_tiles_tx(Connection& c, std::int64_t version, TileLayer layer,
                           std::span<const TileWrite> tiles_in);
  static BuildJob build_job_from_row(const Result& r, int i);

  static void drop_failed_content(Connection& c) {
    c.exec(
        "DELETE FROM landmarks WHERE version IN (SELECT version FROM map_versions WHERE status = "
        "'failed'); "
        "DELETE FROM tiles WHERE version IN (SELECT version FROM map_versions WHERE status = "
        "'failed'); "
        "DELETE FROM gridmap_tiles WHERE version IN (SELECT version FROM map_versions WHERE "
        "status = 'failed'); "
        "DELETE FROM landmark_changes WHERE version IN (SELECT version FROM map_versions WHERE "
        "status = 'failed'); "
        "DELETE FROM gridmap_mechanism_tiles WHERE version IN (SELECT version FROM map_versions "
        "WHERE status = 'failed'); "
        "UPDATE build_jobs SET state = 'failed', error = 'the map version failed' WHERE state "
        "IN ('pending', 'running') AND version IN (SELECT version FROM map_versions WHERE "
        "status = 'failed');");
    gc_blobs(c);
  }

  static void gc_blobs(Connection& c) {
    c.exec(
        "DELETE FROM tile_blobs b WHERE NOT EXISTS (SELECT 1 FROM tiles t WHERE t.blob = b.id) "
        "AND NOT EXISTS (SELECT 1 FROM gridmap_tiles t WHERE t.blob = b.id) AND NOT EXISTS "
        "(SELECT 1 FROM gridmap_mechanism_tiles t WHERE t.blob = b.id)");
  }

  DriveRecord drive_from_row(const Result& r, int i) const {
    DriveRecord d;
    d.row = r.i64(i, 0);
    d.drive_id = r.text(i, 1);
    d.content_hash = r.text(i, 2);
    d.vehicle_id = r.text(i, 3);
    d.start_time_s = r.f64(i, 4);
    d.end_time_s = r.f64(i, 5);
    d.bbox = {r.f64(i, 6), r.f64(i, 7), r.f64(i, 8), r.f64(i, 9)};
    d.pol_level = parse_pol_level(r.text(i, 10)).value_or(PolLevel::Full);
    d.distance_m = r.f64(i, 11);
    d.num_points = r.i64(i, 12);
    d.num_lines = r.i64(i, 13);
    d.manifest = nlohmann::json::parse(r.text(i, 14), nullptr, false);
    d.package_path = package_dir / r.text(i, 15);
    d.ingested_at = r.text(i, 16);
    return d;
  }

  std::optional<DriveRecord> drive_where(Connection& c, const std::string& where,
                                         std::string_view value) const {
    const Result r =
        c.run(std::string("SELECT ") + kDriveColumns + " FROM drives WHERE " + where, value);
    if (r.empty()) return std::nullopt;
    return drive_from_row(r, 0);
  }

  static std::optional<MapVersionStatus> version_status(Connection& c, std::int64_t v) {
    const Result r = c.run("SELECT status FROM map_versions WHERE version = $1", v);
    if (r.empty()) return std::nullopt;
    return parse_status(r.text(0, 0));
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
      throw NotFoundError(
          "map version " + std::to_string(v) +
          (st ? " is not published (" + std::string(to_string(*st)) + ")" : " does not exist"));
    }
  }

  void hook(std::string_view stage) const {
    if (opt.fault_hook) opt.fault_hook(stage);
  }
};

}  // namespace polmap::mapping
