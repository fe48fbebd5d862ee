#pragma once
/// @file postgres_store.hpp
/// The scale-out MapStore: PostgreSQL 15 + PostGIS 3 for the rows, a shared directory
/// for the files. Several processes ("replicas", e.g. HTTP servers behind one load
/// balancer) may open the same database and package directory at once; each sees the
/// others' committed writes.
///
///   database (conninfo)            schema/store_postgres.sql: the tables of store.sql with
///                                  PostGIS geometries (GiST) instead of R*Tree side tables
///   <package_dir>/<sha256>/...     ingested packages, by content hash (as <db>.drives/)
///   <package_dir>/uploads/<id>     bytes of resumable uploads in progress (as <db>.uploads/)
///
/// package_dir must be one directory that every replica reaches under the same path (NFS,
/// a shared volume): it is recorded in the database (table store_settings) at the first
/// open, so later opens need not name it, and an open naming another directory is refused.
///
/// Connections: a pool, one libpq connection per thread in use (idle ones kept for reuse).
/// Readers run in a REPEATABLE READ READ ONLY transaction (one consistent snapshot) and
/// never wait for writers. Writers take one transaction-level advisory lock per store
/// (pg_advisory_xact_lock), so writes are serialized across threads and replicas as
/// SQLite's are within one file: ids are assigned as SQLite assigns rowids (MAX + 1, the
/// same numbers for the same calls), the per-owner upload quota is checked and the session
/// inserted under that lock, and no two writers deadlock. put_drive copies the package
/// before it takes the lock and is idempotent by the UNIQUE content hash
/// (INSERT ... ON CONFLICT), also between replicas.
///
/// Schema migrations run on open in one transaction under pg_advisory_xact_lock, recorded in
/// schema_migrations; concurrent openers wait for each other, and reopening an up-to-date
/// database changes nothing. Migration 1 runs `CREATE EXTENSION IF NOT EXISTS postgis`: the
/// role needs that right, or PostGIS is installed in the database beforehand.
///
/// Crash safety of put_drive and upload sessions as in SqliteMapStore (files durable
/// before the row commits; a failed transaction leaves no files; leftovers of a crash
/// swept at open by the store's owner, after orphan_grace_s). The owner is the one opener
/// that holds a session-level advisory lock (pg_try_advisory_lock) for its lifetime. A map
/// build holds a session-level advisory lock on its version from the transaction that
/// creates the version until it is published or failed, so the sweep (at open, and
/// fail_abandoned_builds, which the server runs every few seconds) fails exactly the builds
/// whose process is gone (a replica's long build is never failed by another replica). A
/// session connection that broke is reopened and its locks taken again at the next build
/// or sweep.
///
/// Errors: as store.hpp. PostgreSQL cannot store the NUL character in text or jsonb (nor
/// invalid UTF-8): such a value is a ValidationError here (SQLite stores it).
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/mapping_service/store.hpp"
#include "polmap/mapping_service/store_migrations.hpp"

namespace polmap::mapping {

struct PostgresStoreOptions {
  /// libpq connection string: a URL (postgresql://user@host:port/dbname?...) or key=value
  /// pairs ("host=... dbname=..."). Never part of a message or log line (it may hold a
  /// password); messages name host, port, database and user only.
  std::string conninfo;
  /// The shared package directory (absolute or relative to the working directory; created if
  /// missing). Required at the first open of a database; later opens may leave it empty
  /// (the recorded one is used) or must name the recorded one.
  std::filesystem::path package_dir;
  /// Idle connections kept open for reuse (more are opened on demand).
  std::size_t max_idle_connections = 8;
  /// Orphaned package directories and session files (crash leftovers) older than this are
  /// removed at open by the owner. 0 removes all (tests). Abandoned builds need no grace:
  /// their free lock tells them apart.
  double orphan_grace_s = 600.0;
  /// Test hook: called at the named stages of put_drive ("files_copied", "rows_inserted",
  /// "files_renamed"); throwing from it simulates a crash at that point.
  std::function<void(std::string_view stage)> fault_hook;
};

/// The migrations this build applies, ascending: schema/store_postgres.sql, embedded at
/// build time, cut by parse_store_migrations.
const std::vector<StoreMigration>& postgres_store_migrations();

class PostgresMapStore final : public MapStore {
 public:
  /// Connects, applies pending migrations, records or checks the package directory and, if
  /// this is the store's owner, sweeps crash leftovers. Throws IoError if the database
  /// cannot be reached, ValidationError if package_dir is missing at the first open or
  /// differs from the recorded one.
  explicit PostgresMapStore(PostgresStoreOptions options);
  ~PostgresMapStore() override;
  PostgresMapStore(const PostgresMapStore&) = delete;
  PostgresMapStore& operator=(const PostgresMapStore&) = delete;

  /// The package directory in use (absolute, as recorded in the database).
  [[nodiscard]] const std::filesystem::path& package_dir() const;
  /// <package_dir>/uploads.
  [[nodiscard]] const std::filesystem::path& upload_session_dir() const;
  /// Host, port, database and user of the connection (no password), for messages.
  [[nodiscard]] const std::string& description() const;
  /// True if this object holds the owner lock (see the file comment).
  [[nodiscard]] bool owns_store() const;
  /// Schema version of the open database (highest applied migration).
  [[nodiscard]] int schema_version() const;

  PutDriveResult put_drive(const DrivePackage& package,
                           const std::filesystem::path& package_location,
                           const std::string& content_hash) override;
  [[nodiscard]] std::vector<DriveRecord> list_drives() const override;
  [[nodiscard]] std::optional<DriveRecord> get_drive(std::string_view drive_id) const override;
  [[nodiscard]] std::optional<DriveRecord> find_drive_by_hash(
      std::string_view content_hash) const override;
  [[nodiscard]] std::vector<GeoPoint> drive_path(std::string_view drive_id) const override;
  [[nodiscard]] std::vector<TrajectorySample> drive_trajectory(
      std::string_view drive_id) const override;
  [[nodiscard]] std::vector<DriveRecord> drives_in(const GeoBox& box) const override;
  bool delete_drive(std::string_view drive_id) override;

  [[nodiscard]] CandidateSet candidates_in(
      const std::optional<GeoBox>& region,
      std::span<const std::string> excluded_drive_ids = {}) const override;

  std::int64_t begin_map_version(const nlohmann::json& parameters) override;
  void put_landmarks(std::int64_t version, std::span<const StoredPointLandmark> points,
                     std::span<const StoredLineLandmark> lines) override;
  std::int64_t copy_landmarks(std::int64_t from, std::int64_t to,
                              std::span<const std::int64_t> except_ids) override;
  std::int64_t copy_tiles(std::int64_t from, std::int64_t to, TileLayer layer,
                          std::span<const tiles::TileKey> except_keys) override;
  void put_landmark_changes(std::int64_t version, std::span<const LandmarkChange> changes) override;
  [[nodiscard]] std::vector<LandmarkChange> landmark_changes(std::int64_t version) const override;
  void put_tiles(std::int64_t version, TileLayer layer, std::span<const TileWrite> tiles) override;
  void publish_map_version(std::int64_t version, const nlohmann::json& statistics,
                           bool make_current = true) override;
  void fail_map_version(std::int64_t version, std::string_view error) override;
  std::vector<std::int64_t> fail_abandoned_builds() override;
  void set_current_map_version(std::int64_t version) override;
  bool delete_map_version(std::int64_t version) override;
  [[nodiscard]] std::optional<std::int64_t> current_map_version() const override;
  [[nodiscard]] std::optional<MapVersionInfo> get_map_version(std::int64_t version) const override;
  [[nodiscard]] std::vector<MapVersionInfo> list_map_versions() const override;

  [[nodiscard]] LandmarkSet landmarks_in(std::int64_t version, const std::optional<GeoBox>& box,
                                         bool with_support = true) const override;
  [[nodiscard]] std::optional<StoredTile> get_tile(std::int64_t version, TileLayer layer,
                                                   const tiles::TileKey& key) const override;
  [[nodiscard]] std::optional<std::string> get_tile_etag(std::int64_t version, TileLayer layer,
                                                         const tiles::TileKey& key) const override;
  [[nodiscard]] std::vector<TileInfo> list_tiles(std::int64_t version,
                                                 TileLayer layer) const override;

  CreateUploadSessionResult create_upload_session(const UploadSessionRequest& request) override;
  [[nodiscard]] std::optional<UploadSession> get_upload_session(std::string_view id) const override;
  bool advance_upload_offset(std::string_view id, std::uint64_t from, std::uint64_t to) override;
  bool delete_upload_session(std::string_view id) override;
  bool complete_upload_session(std::string_view id, const UploadOutcome& outcome) override;
  std::size_t sweep_expired_upload_sessions(std::chrono::system_clock::time_point now) override;

  [[nodiscard]] std::vector<GridmapSumInput> gridmap_sum_inputs() const override;
  [[nodiscard]] std::vector<GridmapSumRow> gridmap_sums_in(int x0, int y0, int x1,
                                                           int y1) const override;
  [[nodiscard]] std::vector<GridmapSumRow> gridmap_sum_keys(
      std::optional<std::int64_t> updated_after) const override;
  [[nodiscard]] std::vector<std::array<int, 3>> gridmap_sum_cover(
      std::string_view content_hash) const override;
  [[nodiscard]] std::vector<std::string> gridmap_sum_contributors(int level, int x,
                                                                  int y) const override;
  void commit_gridmap_sums(std::int64_t version, std::span<const GridmapSumRow> tiles,
                           const GridmapSumInputChange& change) override;

  void enqueue_build_jobs(std::int64_t version, std::span<const BuildJobSpec> jobs) override;
  std::optional<BuildJob> claim_build_job(std::string_view worker, double lease_s,
                                          std::optional<std::int64_t> version) override;
  bool renew_build_job(std::int64_t job, int attempt, double lease_s) override;
  bool complete_build_job(std::int64_t job, int attempt, const BuildJobOutput& output) override;
  bool fail_build_job(std::int64_t job, int attempt, std::string_view error) override;
  [[nodiscard]] std::vector<BuildJob> build_jobs(std::int64_t version) const override;
  std::int64_t put_localization_run(const LocalizationRunRecord& record,
                                    std::string_view canonical_body,
                                    std::span<const LocalizationRunCell> cells,
                                    std::size_t keep_newest) override;
  [[nodiscard]] std::vector<LocalizationRunRecord> list_localization_runs(
      std::size_t limit, std::string_view vehicle_id = {}) const override;
  [[nodiscard]] std::optional<LocalizationRunRecord> get_localization_run(
      std::int64_t id) const override;
  [[nodiscard]] std::optional<std::string> localization_run_body(std::int64_t id) const override;
  bool delete_localization_run(std::int64_t id) override;
  [[nodiscard]] std::vector<LocalizationRunCell> localization_run_cells(
      int z, int x0, int y0, int x1, int y1, std::size_t limit, RunCellRuns which) const override;
  void put_hdmap_comparison(const HdMapComparisonRecord& record) override;
  [[nodiscard]] std::vector<HdMapComparisonRecord> list_hdmap_comparisons(
      std::int64_t version) const override;
  [[nodiscard]] std::optional<HdMapComparisonRecord> get_hdmap_comparison(
      std::int64_t version, std::string_view name) const override;
  [[nodiscard]] std::optional<LandmarkDetail> landmark_detail(std::int64_t version,
                                                              std::int64_t key) const override;
  [[nodiscard]] StoreStats stats() const override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace polmap::mapping
