#pragma once
/// @file sqlite_store.hpp
/// The embedded MapStore: one SQLite database file plus a drive store
/// directory beside it.
///
///   <db>                 SQLite database (schema/store.sql), WAL mode
///   <db>-wal, <db>-shm   SQLite's write-ahead log (do not delete while open)
///   <db>.drives/<sha256>/<package files>   ingested packages, by content hash
///   <db>.uploads/<session id>              bytes of resumable uploads in progress
///
/// Connections: a small pool. Each call takes an idle connection (or opens a
/// new one), so concurrent readers run in parallel on their own connections
/// and read a consistent snapshot (WAL). Writers take an in-process write
/// mutex and `BEGIN IMMEDIATE`, so they never deadlock on lock upgrades;
/// other processes writing the same file wait up to busy_timeout_ms.
/// Every connection: `PRAGMA foreign_keys = ON`, `journal_mode = WAL`,
/// `synchronous = NORMAL` (durable across process crashes; the last
/// transactions may roll back on power loss, never corrupt), busy timeout.
///
/// Schema migrations run on open, in one transaction, recorded in
/// `schema_migrations`; reopening an up-to-date database changes nothing.
///
/// Packages are stored as their member files only (an archive given to put_drive is
/// unpacked by our ustar reader first), so GDAL never reads an archive of the store.
/// Crash safety of put_drive: files are copied into `<db>.drives/.tmp-*`,
/// rows inserted in a transaction, the directory renamed to its final name,
/// then the transaction commits; any failure rolls back and removes the files.
/// After a hard crash between rename and commit, the orphaned directory (no
/// drives row) is removed by the next open (older than orphan_grace_s), as is an upload
/// session file without its row (a crash between creating the file and the commit).
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/mapping_service/store.hpp"
#include "polmap/mapping_service/store_migrations.hpp"

namespace polmap::mapping {

struct SqliteStoreOptions {
  /// How long a statement waits for another process's write lock.
  int busy_timeout_ms = 10000;
  /// Idle connections kept open for reuse (more are opened on demand).
  std::size_t max_idle_connections = 8;
  /// Drive store directory; empty = "<db path>.drives".
  std::filesystem::path drive_store_dir;
  /// Upload session directory; empty = "<db path>.uploads".
  std::filesystem::path upload_session_dir;
  /// Orphaned drive store entries (crash leftovers) older than this are
  /// removed on open. 0 removes all (tests; single-process use).
  double orphan_grace_s = 600.0;
  /// Test hook: called at the named stages of put_drive ("files_copied",
  /// "rows_inserted", "files_renamed"); throwing from it simulates a crash
  /// at that point. Empty in production.
  std::function<void(std::string_view stage)> fault_hook;
};

/// What opening the store did to packages stored as upload archives by older versions
/// (`<drives>/<hash>/<name>.tar`, once read through GDAL's /vsitar/): each is unpacked by
/// our ustar reader into member files and re-validated by today's rules; one that no
/// longer validates is removed from the store, its archive kept in
/// `<drives>/quarantine/<hash>.tar` for inspection.
struct ArchiveMigrationReport {
  std::size_t migrated = 0;              ///< archives replaced by their member files
  std::vector<std::string> quarantined;  ///< "DRIVE_ID: reason", one per removed drive
};

/// The migrations this build applies, ascending: schema/store.sql, embedded at build
/// time, cut at its section headers ("-- bootstrap ...", "-- migration N: name") by
/// parse_store_migrations (store_migrations.hpp).
const std::vector<StoreMigration>& sqlite_store_migrations();

class SqliteMapStore final : public MapStore {
 public:
  /// Opens (creating if needed) the database and drive store, applies
  /// pending migrations. Throws IoError if the file cannot be opened.
  /// The first opener holds an exclusive lock on `<db>.lock` for its lifetime (the
  /// owner) and alone sweeps crash leftovers; later openers (another process, an export)
  /// read and write but never sweep, so they cannot fail the owner's running build.
  explicit SqliteMapStore(const std::filesystem::path& db_path, SqliteStoreOptions options = {});
  ~SqliteMapStore() override;
  SqliteMapStore(const SqliteMapStore&) = delete;
  SqliteMapStore& operator=(const SqliteMapStore&) = delete;

  [[nodiscard]] const std::filesystem::path& path() const;
  [[nodiscard]] const std::filesystem::path& drive_store_dir() const;
  [[nodiscard]] const std::filesystem::path& upload_session_dir() const;
  /// True if this object holds the owner lock (see the constructor).
  [[nodiscard]] bool owns_store() const;
  /// What the owner's open did to archive-stored packages (empty for other openers).
  [[nodiscard]] const ArchiveMigrationReport& archive_migration() const;
  /// Schema version of the open database (highest applied migration).
  [[nodiscard]] int schema_version() const;
  /// Value of a PRAGMA on a pooled connection (tests: "journal_mode", "foreign_keys").
  [[nodiscard]] std::string pragma(std::string_view name) const;

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
