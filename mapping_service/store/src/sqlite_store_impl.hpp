#pragma once
// SqliteMapStore internals shared by its source files (sqlite_store.cpp: open,
// migrations, statistics; sqlite_store_drives.cpp: drives and candidates;
// sqlite_store_maps.cpp: map versions, landmarks, tiles). Not installed.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/util/file.hpp"
#include "sqlite_db.hpp"
#include "store_common.hpp"

namespace polmap::mapping {
namespace sqlite_store_detail {

using sqlite::Connection;
using sqlite::Stmt;
using namespace store_detail;  // NOLINT: internal header of one target

inline constexpr const char* kDriveColumns =
    "id, drive_id, content_hash, vehicle_id, start_time_s, end_time_s, min_lat_deg, min_lon_deg, "
    "max_lat_deg, max_lon_deg, pol_level, distance_m, num_points, num_lines, manifest_json, "
    "package_path, ingested_at";

/// R*Tree coordinates are 32-bit floats; SQLite rounds bounds outward, so the
/// index returns a superset and the exact filter is applied on the REAL columns.
void insert_rtree(Connection& c, const char* table, std::int64_t id, double min_lat, double max_lat,
                  double min_lon, double max_lon);

}  // namespace sqlite_store_detail

using namespace sqlite_store_detail;  // NOLINT: internal header of one target

struct SqliteMapStore::Impl {
  std::filesystem::path path;
  std::filesystem::path drives_dir;
  std::filesystem::path uploads_dir;  ///< upload session files
  SqliteStoreOptions opt;
  mutable std::mutex pool_mu;
  mutable std::vector<std::unique_ptr<Connection>> idle;
  mutable std::mutex write_mu;            // in-process writers queue here, not on SQLITE_BUSY
  std::unique_ptr<util::FileLock> owner;  ///< <db>.lock, held by the store's owner

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
    sqlite::Transaction tx(*c, sqlite::Transaction::Mode::Immediate);
    if constexpr (std::is_void_v<decltype(fn(*c))>) {
      fn(*c);
      tx.commit();
    } else {
      auto r = fn(*c);
      tx.commit();
      return r;
    }
  }

  /// Runs fn(conn) in a read transaction (one consistent snapshot).
  template <typename F>
  auto read(F&& fn) const {
    Lease c = lease();
    sqlite::Transaction tx(*c);
    auto r = fn(*c);
    tx.commit();
    return r;
  }

  /// Applies the bootstrap statement, then every pending migration in one transaction.
  void migrate();

  /// Crash leftovers: temp dirs, package dirs without a drives row, and map
  /// versions stuck in 'building', all older than the grace period.
  void sweep_orphans();

  // Writes inside a transaction the caller holds (the public methods wrap each in one;
  // complete_build_job puts a job's whole output in one).
  static void put_landmarks_tx(Connection& c, std::int64_t version,
                               std::span<const StoredPointLandmark> points,
                               std::span<const StoredLineLandmark> lines);
  static void put_landmark_changes_tx(Connection& c, std::int64_t version,
                                      std::span<const LandmarkChange> changes);
  static void put_tiles_tx(Connection& c, std::int64_t version, TileLayer layer,
                           std::span<const TileWrite> tiles_in);
  static BuildJob build_job_from_row(Stmt& s);

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
        "DELETE FROM tile_blobs WHERE id NOT IN (SELECT blob FROM tiles) AND id NOT IN (SELECT "
        "blob FROM gridmap_tiles) AND id NOT IN (SELECT blob FROM gridmap_mechanism_tiles)");
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
      throw NotFoundError(
          "map version " + std::to_string(v) +
          (st ? " is not published (" + std::string(to_string(*st)) + ")" : " does not exist"));
    }
  }

  /// Unpacks archive-stored packages of older versions (owner only; see
  /// ArchiveMigrationReport). Defined with the drives.
  void migrate_archived_packages();
  ArchiveMigrationReport archive_report;

  void hook(std::string_view stage) const {
    if (opt.fault_hook) opt.fault_hook(stage);
  }
};

}  // namespace polmap::mapping
