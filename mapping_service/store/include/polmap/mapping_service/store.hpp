#pragma once
/// @file store.hpp
/// The mapping service's storage interface: drives (ingested packages and
/// their landmark candidates), map versions with their landmarks, and the
/// tiles served to vehicles. SqliteMapStore (sqlite_store.hpp) is the embedded
/// default; PostgresMapStore (postgres_store.hpp) the PostgreSQL/PostGIS backend that
/// several replicas share; open_map_store (open_store.hpp) picks one from a --db string.
///
/// Usage (HTTP server, CLI):
///   SqliteMapStore store("/var/lib/polmap/map.db");
///   PutDriveResult r = store.put_drive(pkg, pkg_path, sha256_hex);  // idempotent
///   if (auto v = store.current_map_version()) {
///     if (auto tile = store.get_tile(*v, key)) reply(tile->payload, tile->etag);
///   }
///   MapBuilder{}.build(store, MapBuildRequest{});   // map_builder.hpp
///
/// Identity: a drive is named by its manifest drive_id (unique in a store) and
/// its content hash (SHA-256 hex of the uploaded bytes, unique). `DriveRecord::row`
/// is the store's internal key, used for candidates and consensus support.
///
/// Threading: every method of an implementation is safe to call concurrently
/// from any number of threads (the HTTP server is multithreaded). Readers see
/// committed data only, and only PUBLISHED map versions: a version being built
/// is invisible to landmark/tile reads until publish_map_version() commits.
///
/// Errors: NotFoundError (unknown drive/version, or a version not published),
/// ConflictError (drive_id already present with different content),
/// ValidationError (bad arguments), StorageFullError (no space left for a write),
/// IoError (other database or file system failures).
#include <array>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/mapping_service/drive_package.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/geo.hpp"
#include "polmap/schema/landmark.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::mapping {

/// Tolerance of MapStore::drive_path (metres).
inline constexpr double kDrivePathToleranceM = 0.25;

/// The request conflicts with stored state (HTTP 409), e.g. a drive_id that is
/// already stored with a different content hash.
class ConflictError : public ValidationError {
 public:
  using ValidationError::ValidationError;
};

/// errors.hpp's: the store throws it for SQLITE_FULL, ENOSPC and EDQUOT.
using polmap::StorageFullError;

/// A geodetic box in degrees (WGS84). Antimeridian-crossing boxes
/// (min_lon_deg > max_lon_deg) are queried as their two halves.
using GeoBox = tiles::GeoBox;

/// One ingested drive.
struct DriveRecord {
  std::int64_t row = 0;      ///< store key (candidates.drive, consensus drive id)
  std::string drive_id;      ///< manifest drive_id, unique per store
  std::string content_hash;  ///< SHA-256 hex of the package bytes, unique
  std::string vehicle_id;
  double start_time_s = 0.0;
  double end_time_s = 0.0;
  GeoBox bbox;  ///< of trajectory and candidates
  PolLevel pol_level = PolLevel::Full;
  double distance_m = 0.0;
  std::int64_t num_points = 0;  ///< point candidates stored
  std::int64_t num_lines = 0;   ///< line candidates stored
  /// What the store keeps of the validated manifest, with "positioning" (median reported
  /// horizontal and heading accuracy and the most common solution type of the validated
  /// trajectory; absent for drives stored before it was kept: survey-grade).
  nlohmann::json manifest;
  std::filesystem::path package_path;  ///< absolute path of the stored package copy
  std::string ingested_at;             ///< ISO 8601 UTC, e.g. "2024-05-01T12:00:00Z"
};

/// Outcome of put_drive. AlreadyPresent: same content hash stored before
/// (nothing was changed; `drive` is the existing record).
struct PutDriveResult {
  enum class Status { Inserted, AlreadyPresent };
  Status status = Status::Inserted;
  DriveRecord drive;
};

/// A stored point candidate: geodetic position plus the drive-frame original.
struct StoredPointCandidate {
  std::int64_t id = 0;       ///< candidate id (unique over points and lines)
  std::int64_t drive = 0;    ///< DriveRecord::row
  GeoPoint position;         ///< WGS84 (alt_m 0)
  PointCandidate candidate;  ///< position_m in the drive's frame
};

/// A stored line candidate.
struct StoredLineCandidate {
  std::int64_t id = 0;
  std::int64_t drive = 0;
  GeoPoint start;
  GeoPoint end;
  LineCandidate candidate;  ///< in the drive's frame
};

struct CandidateSet {
  std::vector<StoredPointCandidate> points;
  std::vector<StoredLineCandidate> lines;
};

enum class MapVersionStatus { Building, Published, Failed };
std::string_view to_string(MapVersionStatus s);

/// A map version. Published versions are immutable snapshots.
struct MapVersionInfo {
  std::int64_t version = 0;
  MapVersionStatus status = MapVersionStatus::Building;
  std::string created_at;     ///< ISO 8601 UTC
  std::string published_at;   ///< empty unless published
  nlohmann::json parameters;  ///< build request: region, excluded drives, config, notes
  nlohmann::json statistics;  ///< build statistics (null until finished)
  std::string error;          ///< why it failed (status Failed)
  bool current = false;       ///< the version served by default
};

/// A consensus point landmark of a map version, geodetic.
struct StoredPointLandmark {
  std::int64_t id = 0;   ///< row id (assigned by the store; ignored on write)
  std::int64_t key = 0;  ///< stable id: hash of the quantized geometry (same
                         ///< landmark in two versions -> same key); used in tiles
  GeoPoint position;
  ScatteringClass scattering = ScatteringClass::Unknown;
  std::uint32_t support_drives = 0;
  double spread_m = 0.0;
  std::vector<std::int64_t> support;  ///< candidate ids
};

/// A consensus line landmark (polyline, >= 2 vertices), geodetic.
struct StoredLineLandmark {
  std::int64_t id = 0;
  std::int64_t key = 0;
  std::vector<GeoPoint> polyline;
  std::uint32_t support_drives = 0;
  double spread_m = 0.0;
  std::vector<std::int64_t> support;
};

struct LandmarkSet {
  std::vector<StoredPointLandmark> points;
  std::vector<StoredLineLandmark> lines;
};

/// How a landmark changed from the previous map version (landmark_diff.hpp).
enum class LandmarkChangeKind { Added, Moved, Retired };
std::string_view to_string(LandmarkChangeKind k);
/// Parses "added" | "moved" | "retired"; nullopt otherwise.
std::optional<LandmarkChangeKind> parse_landmark_change_kind(std::string_view s);

/// One landmark change, recorded with the map version that made it.
struct LandmarkChange {
  LandmarkChangeKind change = LandmarkChangeKind::Added;
  bool is_line = false;
  /// Key in the new version (Added, Moved); the retired landmark's key (Retired).
  std::int64_t key = 0;
  std::int64_t previous_key = 0;            ///< Moved: the old key; otherwise 0
  std::vector<GeoPoint> geometry;           ///< new geometry; Retired: the old one
  std::vector<GeoPoint> previous_geometry;  ///< Moved: the old geometry; otherwise empty
  double distance_m = 0.0;                  ///< Moved: how far (metres)
  /// Why, as the builder judged it: {"rule": "...", "support_drives": k,
  /// "drives_in_view": n, ...}; null when not recorded.
  nlohmann::json reason;
};

/// Tile layers kept per map version.
enum class TileLayer {
  Localization,      ///< localization tiles (tiles/localization_tile.hpp), z = kLocalizationZoom
  Gridmap,           ///< fleet gridmap amplitude tiles (fleet_gridmap.hpp)
  GridmapMechanism,  ///< fleet gridmap scattering-mechanism tiles (fleet_gridmap.hpp)
};

/// A tile to store with a map version. Blobs are content-addressed by etag:
/// reuse_blob = true stores only the reference to an existing blob with that
/// etag (an unchanged tile of the previous version; payload may be empty).
struct TileWrite {
  tiles::TileKey key;
  std::string etag;  ///< lower-case SHA-256 hex of payload (content_etag())
  std::string payload;
  bool reuse_blob = false;
  std::int32_t num_points = 0;  ///< informative (listing, stats)
  std::int32_t num_lines = 0;
};

/// Tile listing entry (no payload).
struct TileInfo {
  tiles::TileKey key;
  std::string etag;
  std::int64_t byte_size = 0;
  std::int32_t num_points = 0;
  std::int32_t num_lines = 0;
};

/// A stored tile.
struct StoredTile {
  tiles::TileKey key;
  std::string etag;  ///< strong ETag value (unquoted SHA-256 hex of payload)
  std::string payload;
};

/// Figures for /metrics.
/// A stored sum tile of the merged PreCFAR gridmap (gridmap_sums.hpp in polmap_consensus
/// defines the grid and gridmap_sums_codec.hpp the bytes; the store keeps them opaque).
struct GridmapSumRow {
  int level = 0;  ///< PolLevel code
  int x = 0;      ///< z20 tile column
  int y = 0;      ///< z20 tile row
  std::string data;
  /// Map version whose build wrote the bytes last (which tiles changed since a version).
  std::int64_t updated_by = 0;
};

/// A drive whose gridmap is in the sums (or was, until its removal is committed).
struct GridmapSumInput {
  std::string content_hash;  ///< the drive's package hash (stable across stores and replicas)
  std::int64_t tiles = 0;    ///< sum tiles it touched
  /// How its gridmap was placed into the sums (opaque to the store; the builder's
  /// drive_placement.hpp): empty = as uploaded.
  std::string placement;
};

/// What a commit_gridmap_sums changes besides tile bytes.
struct GridmapSumInputChange {
  enum class Kind { Add, Remove, None };
  Kind kind = Kind::None;
  std::string content_hash;
  /// Add: the sum tiles the drive touched, as (level, x, y).
  std::vector<std::array<int, 3>> cover;
  /// Add: how its gridmap was placed (GridmapSumInput::placement).
  std::string placement;
};

struct StoreStats {
  std::int64_t drives = 0;
  std::int64_t point_candidates = 0;
  std::int64_t line_candidates = 0;
  std::int64_t map_versions = 0;
  std::optional<std::int64_t> current_version;
  std::int64_t current_point_landmarks = 0;
  std::int64_t current_line_landmarks = 0;
  std::int64_t current_tiles = 0;
  std::int64_t tile_blobs = 0;
  std::int64_t tile_blob_bytes = 0;
  std::int64_t database_bytes = 0;
  std::int64_t drive_store_bytes = 0;
};

/// A resumable upload in progress (POST /v1/uploads): the package's bytes arrive in chunks
/// appended to `file`; the first `offset_bytes` of them are durable and acknowledged. The
/// session lives in the store, so any replica sharing the store can continue it.
/// The answer the last chunk of a completed upload session got (POST /v1/drives' answer:
/// stored, already present, or refused for good), kept until the session expires so that a
/// client whose connection dropped before it arrived can ask again.
struct UploadOutcome {
  int http_status = 0;   ///< 200-499
  std::string location;  ///< the Location header sent with it, or empty
  std::string body;      ///< the JSON body sent with it
};

struct UploadSession {
  std::string id;                  ///< 32 lower-case hex digits (128 random bits)
  std::string owner;               ///< fingerprint of the API key that created it, never the key
  std::uint64_t length_bytes = 0;  ///< declared size of the whole package
  std::uint64_t offset_bytes = 0;  ///< bytes received, fsynced and acknowledged (<= length)
  std::string sha256;              ///< declared SHA-256 hex of the whole package, or empty
  std::string created_at;          ///< ISO 8601 UTC
  std::string expires_at;          ///< ISO 8601 UTC; the session may be swept from then on
  std::filesystem::path file;      ///< absolute path of the session's byte file
  /// Set once the upload completed (complete_upload_session); its byte file is gone then.
  std::optional<UploadOutcome> outcome;
};

/// What create_upload_session needs. The per-owner limits are checked in the same
/// transaction that inserts the session, so concurrent creates cannot exceed them.
struct UploadSessionRequest {
  std::string owner;               ///< key fingerprint (non-empty)
  std::uint64_t length_bytes = 0;  ///< > 0 and <= INT64_MAX
  std::string sha256;              ///< empty or 64 lower-case hex digits
  std::chrono::system_clock::time_point now = std::chrono::system_clock::now();
  /// Seconds from `now` until the session expires (> 0).
  std::int64_t ttl_s = 24 * 3600;
  /// The owner's unexpired sessions may be at most this many, including the new one.
  std::size_t max_sessions_per_owner = 4;
  /// ... and declare at most this many bytes in all, including the new one.
  std::uint64_t max_bytes_per_owner = 2ull << 30;
};

/// Outcome of create_upload_session: Created (session filled in) or the limit that refused
/// it; open_sessions / open_bytes are the owner's unexpired sessions before the request.
struct CreateUploadSessionResult {
  enum class Status { Created, TooManySessions, TooManyBytes };
  Status status = Status::Created;
  UploadSession session;
  std::size_t open_sessions = 0;
  std::uint64_t open_bytes = 0;
};

/// Partitioned map builds (schema/build_jobs.md): a Building version's work as jobs that
/// build workers claim under a lease. Kinds: "region" (landmarks, changes and localization
/// tiles of one region, the tile `region`), "gridmap" (the merged gridmap stage),
/// "publish" (claimable once every other job of its version is done).
enum class BuildJobState { Pending, Running, Done, Failed };
std::string_view to_string(BuildJobState s);

/// A job to enqueue.
struct BuildJobSpec {
  std::string kind;       ///< "region" | "gridmap" | "publish"
  tiles::TileKey region;  ///< region jobs: the region's tile; otherwise {0, 0, 0}
  nlohmann::json spec;    ///< what the worker needs beyond the version's parameters
};

/// A job as stored; `attempt` counts claims and fences a worker whose lease was lost.
struct BuildJob {
  std::int64_t id = 0;
  std::int64_t version = 0;
  std::string kind;
  tiles::TileKey region;
  nlohmann::json spec;
  BuildJobState state = BuildJobState::Pending;
  int attempt = 0;
  std::string worker;         ///< who holds or last held it
  double lease_left_s = 0.0;  ///< running: seconds until the lease expires (may be < 0)
  nlohmann::json result;      ///< done: the job's statistics
  std::string error;          ///< failed: why
};

/// What a job leaves in its Building version, committed in one transaction with the
/// job's completion (a worker killed before it leaves nothing).
struct BuildJobOutput {
  std::vector<StoredPointLandmark> points;
  std::vector<StoredLineLandmark> lines;
  std::vector<LandmarkChange> changes;
  std::vector<TileWrite> localization_tiles;
  nlohmann::json result;  ///< the job's statistics
};

/// A stored localization run report (POST /v1/runs; schema/localization_run.md): what the
/// list shows, without the samples (the canonical report is read with
/// localization_run_body).
struct LocalizationRunRecord {
  std::int64_t id = 0;      ///< assigned by the store (ignored on write)
  std::string received_at;  ///< ISO 8601 UTC
  std::string vehicle_id;   ///< of the key that sent it ("" when the key names none)
  std::int64_t map_version = 0;
  std::string label;
  std::int64_t samples = 0;
  GeoBox bounds;
  nlohmann::json summary;  ///< computed by the server from the validated samples
};

/// A run's samples binned into one Web-Mercator tile of zoom `z` (the fleet-wide
/// localization quality layer). Sums, so that cells of many runs add up; aggregated over
/// runs by localization_run_cells, which also fills `runs`.
struct LocalizationRunCell {
  int z = 0, x = 0, y = 0;
  std::int64_t samples = 0;        ///< samples of tracking/degraded/lost status
  std::int64_t degraded = 0;       ///< of them degraded or lost
  std::int64_t evaluated = 0;      ///< of them with an error against a reference
  double sum_sigma_lat_m = 0.0;    ///< Σ lateral 1-σ of the samples
  double sum_err_lat2_m2 = 0.0;    ///< Σ lateral error² of the evaluated samples
  double max_abs_err_lat_m = 0.0;  ///< max |lateral error|
  std::int64_t runs = 0;           ///< aggregated: distinct runs in the cell
  std::int64_t map_version = 0;    ///< aggregated: the newest map version of those runs
};

/// Which stored runs a quality cell sums (MapStore::localization_run_cells).
enum class RunCellRuns {
  All,  ///< every stored run
  /// Per cell, only the runs that localized against the newest map version among that
  /// cell's runs: a place a later map version changed shows how it localizes now, not the
  /// runs against the map it replaced.
  NewestMapVersion,
};

/// A stored HD-map comparison of a published map version (`polmap compare-hdmap --store`,
/// hdmap_compare.hpp computes it): keyed by (version, name). The store keeps the JSON as
/// given and does not interpret it.
struct HdMapComparisonRecord {
  std::int64_t version = 0;
  /// Names the HD map: 1..64 characters of [A-Za-z0-9._-], not starting with '.' (used in
  /// URLs).
  std::string name;
  std::string hdmap_file;   ///< the HD map file as the operator named it (informative)
  std::string created_at;   ///< ISO 8601 UTC, set by the store on put
  nlohmann::json summary;   ///< metrics and parameters (hdmap_compare.hpp to_json and more)
  nlohmann::json features;  ///< the GeoJSON FeatureCollection; null in listings
};

/// True if `name` is a valid HdMapComparisonRecord::name.
[[nodiscard]] bool is_valid_hdmap_comparison_name(std::string_view name);

/// A drive that supports a landmark (through its stored candidates).
struct LandmarkDriveInfo {
  std::string drive_id;
  std::string vehicle_id;
  double start_time_s = 0.0;  ///< recording clock, as in the manifest
  double end_time_s = 0.0;
  std::string ingested_at;      ///< ISO 8601 UTC
  std::int64_t candidates = 0;  ///< of its candidates that support the landmark
};

/// One step of a landmark's history: a recorded change of a published version.
struct LandmarkHistoryEntry {
  std::int64_t version = 0;
  std::string published_at;  ///< of that version
  LandmarkChange change;
  /// True for the version where the chain begins when no change was recorded there (the
  /// first map version records none): the landmark was there, added by that build.
  bool inferred = false;
};

/// A landmark of a published version with its provenance (GET /v1/maps/{v}/landmarks/{key}).
struct LandmarkDetail {
  std::int64_t version = 0;
  std::int64_t key = 0;
  bool is_line = false;
  std::vector<GeoPoint> geometry;                         ///< one point, or the polyline
  ScatteringClass scattering = ScatteringClass::Unknown;  ///< points; Unknown for lines
  std::uint32_t support_drives = 0;                       ///< as the consensus counted them
  double spread_m = 0.0;
  /// The drives still stored whose candidates support it (deleted drives took their
  /// support links with them), by start time, then drive id.
  std::vector<LandmarkDriveInfo> drives;
  /// Newest first: the changes that made it, following moved changes back through their
  /// previous_key, over published versions <= version.
  std::vector<LandmarkHistoryEntry> history;
};

/// Strong ETag of a payload: lower-case SHA-256 hex (64 chars).
std::string content_etag(std::string_view payload);

/// Abstract store. See the file comment for threading and error rules.
class MapStore {
 public:
  virtual ~MapStore() = default;

  // ------------------------------------------------------------ drives
  /// Ingests a validated package: copies `package_location` (the .tar file or
  /// the package directory) into the drive store and inserts the drive and
  /// its candidates in one transaction. All or nothing: a failure at any
  /// point leaves neither rows nor files behind. Idempotent by content hash.
  /// `content_hash`: lower-case hex SHA-256 of the package bytes.
  virtual PutDriveResult put_drive(const DrivePackage& package,
                                   const std::filesystem::path& package_location,
                                   const std::string& content_hash) = 0;
  [[nodiscard]] virtual std::vector<DriveRecord> list_drives() const = 0;
  [[nodiscard]] virtual std::optional<DriveRecord> get_drive(std::string_view drive_id) const = 0;
  [[nodiscard]] virtual std::optional<DriveRecord> find_drive_by_hash(
      std::string_view content_hash) const = 0;
  /// The drive's trajectory, decimated at ingest to one sample per metre
  /// travelled (at least one per 5 s; first and last kept); only time, lat/lon,
  /// yaw, speed and yaw rate are kept (yaw rate NaN for drives stored before it was,
  /// 2026-12-05). NotFoundError for unknown drives.
  [[nodiscard]] virtual std::vector<TrajectorySample> drive_trajectory(
      std::string_view drive_id) const = 0;
  /// The drive's path: its whole trajectory's positions simplified by Douglas–Peucker to
  /// kDrivePathToleranceM (kept at ingest as packed doubles: what map builds read, cheap
  /// to decode for long drives). NotFoundError for unknown drives.
  [[nodiscard]] virtual std::vector<GeoPoint> drive_path(std::string_view drive_id) const = 0;
  /// Drives whose bounding box intersects the box.
  [[nodiscard]] virtual std::vector<DriveRecord> drives_in(const GeoBox& box) const = 0;
  /// Removes the drive's rows (candidates, support links of old map versions)
  /// and files. Published map versions keep their landmarks. False if unknown.
  virtual bool delete_drive(std::string_view drive_id) = 0;

  // ------------------------------------------------------------ candidates
  /// Candidates inside `region` (points inside, lines whose bounding box
  /// intersects; all if nullopt) of all drives except `excluded_drive_ids`
  /// (manifest drive ids). Ordered by candidate id.
  [[nodiscard]] virtual CandidateSet candidates_in(
      const std::optional<GeoBox>& region,
      std::span<const std::string> excluded_drive_ids = {}) const = 0;

  // ------------------------------------------------------------ map versions
  /// Creates a version with status Building and returns its number (ascending).
  virtual std::int64_t begin_map_version(const nlohmann::json& parameters) = 0;
  /// Adds landmarks to a Building version (may be called repeatedly).
  virtual void put_landmarks(std::int64_t version, std::span<const StoredPointLandmark> points,
                             std::span<const StoredLineLandmark> lines) = 0;
  /// Copies the landmarks of published version `from` (with their support links) into
  /// Building version `to`, except those whose row ids are in `except_ids` (incremental
  /// builds: the landmarks outside the rebuilt area carry over unchanged). Returns the
  /// number copied.
  virtual std::int64_t copy_landmarks(std::int64_t from, std::int64_t to,
                                      std::span<const std::int64_t> except_ids) = 0;
  /// Copies the tiles of a layer of published version `from` into Building version `to`,
  /// except those at `except_keys` (the blobs are shared). Returns the number copied.
  virtual std::int64_t copy_tiles(std::int64_t from, std::int64_t to, TileLayer layer,
                                  std::span<const tiles::TileKey> except_keys) = 0;
  /// Records landmark changes of a Building version against its previous version (may
  /// be called repeatedly; kept in call order).
  virtual void put_landmark_changes(std::int64_t version,
                                    std::span<const LandmarkChange> changes) = 0;
  /// The changes a published version recorded (empty for a first version). Throws
  /// NotFoundError for unknown or unpublished versions.
  [[nodiscard]] virtual std::vector<LandmarkChange> landmark_changes(
      std::int64_t version) const = 0;
  /// Adds tiles of a layer to a Building version (may be called repeatedly).
  virtual void put_tiles(std::int64_t version, TileLayer layer,
                         std::span<const TileWrite> tiles) = 0;
  /// Building -> Published in one transaction, with statistics; with
  /// make_current the current pointer moves to this version in the same
  /// transaction (readers switch atomically from the old to the new map).
  virtual void publish_map_version(std::int64_t version, const nlohmann::json& statistics,
                                   bool make_current = true) = 0;
  /// Building -> Failed; drops the version's landmarks and tiles.
  virtual void fail_map_version(std::int64_t version, std::string_view error) = 0;
  /// Fails the Building versions whose builder is gone (its process ended without
  /// publishing or failing them; partitioned builds with jobs left are the workers' and
  /// kept) and returns their numbers. For backends that can tell a running build from an
  /// abandoned one while other processes use the store (PostgreSQL: a build holds a
  /// session lock from the moment its version exists); the others find abandoned builds
  /// when the store is opened and return none here (SQLite).
  virtual std::vector<std::int64_t> fail_abandoned_builds() = 0;
  /// Moves the current pointer to a published version (rollback).
  virtual void set_current_map_version(std::int64_t version) = 0;
  /// Deletes a non-current version with its landmarks and tiles (blobs no
  /// longer referenced are dropped). False if unknown.
  virtual bool delete_map_version(std::int64_t version) = 0;
  [[nodiscard]] virtual std::optional<std::int64_t> current_map_version() const = 0;
  [[nodiscard]] virtual std::optional<MapVersionInfo> get_map_version(
      std::int64_t version) const = 0;
  [[nodiscard]] virtual std::vector<MapVersionInfo> list_map_versions() const = 0;

  // ------------------------------------------------------------ published content
  /// Landmarks of a published version inside `box` (all if nullopt); points
  /// inside, lines whose bounding box intersects. Throws NotFoundError if the
  /// version is unknown or not published. with_support = false skips the
  /// support lists (one query per landmark; not needed for display).
  [[nodiscard]] virtual LandmarkSet landmarks_in(std::int64_t version,
                                                 const std::optional<GeoBox>& box,
                                                 bool with_support = true) const = 0;
  /// A tile of a published version, or nullopt when the version has no tile
  /// there (empty area). Throws NotFoundError for unknown/unpublished versions.
  [[nodiscard]] virtual std::optional<StoredTile> get_tile(std::int64_t version, TileLayer layer,
                                                           const tiles::TileKey& key) const = 0;
  /// ETag only (cheap conditional requests).
  [[nodiscard]] virtual std::optional<std::string> get_tile_etag(
      std::int64_t version, TileLayer layer, const tiles::TileKey& key) const = 0;
  /// All tiles of a version and layer (also usable on a Building version by
  /// its builder); ordered by (z, x, y).
  [[nodiscard]] virtual std::vector<TileInfo> list_tiles(std::int64_t version,
                                                         TileLayer layer) const = 0;

  // ------------------------------------------------------------ upload sessions
  /// Creates a session and its empty byte file (durable before the row commits), unless
  /// the owner's unexpired sessions would exceed request's limits (status says which).
  /// ValidationError for an empty owner, a zero or oversized length, a malformed sha256 or
  /// a non-positive ttl.
  virtual CreateUploadSessionResult create_upload_session(const UploadSessionRequest& request) = 0;
  /// The session, expired or not (nullopt once deleted or swept). Callers compare
  /// expires_at themselves (an expired session is refused, not continued).
  [[nodiscard]] virtual std::optional<UploadSession> get_upload_session(
      std::string_view id) const = 0;
  /// Compare-and-set of the acknowledged offset: `from` -> `to` if the session exists and
  /// its offset is still `from` (false otherwise). Call only once bytes [from, to) of the
  /// file are durable. ValidationError unless from < to <= length_bytes.
  virtual bool advance_upload_offset(std::string_view id, std::uint64_t from, std::uint64_t to) = 0;
  /// Removes the session's row, then its file. False if unknown.
  virtual bool delete_upload_session(std::string_view id) = 0;
  /// Records the answer the session's upload got, then removes its byte file; the row stays
  /// until the session expires, and no longer counts against its owner's limits. False if
  /// unknown or already complete. ValidationError for a status outside 200-499.
  virtual bool complete_upload_session(std::string_view id, const UploadOutcome& outcome) = 0;
  /// Removes the sessions whose expires_at is at or before `now` (rows, then files), and
  /// only those; returns how many.
  virtual std::size_t sweep_expired_upload_sessions(std::chrono::system_clock::time_point now) = 0;

  // ------------------------------------------------------------ merged gridmap sums
  /// Drives whose gridmap is in the sums.
  [[nodiscard]] virtual std::vector<GridmapSumInput> gridmap_sum_inputs() const = 0;
  /// Sum tiles with x0 <= x <= x1 and y0 <= y <= y1 (all levels), with their bytes.
  [[nodiscard]] virtual std::vector<GridmapSumRow> gridmap_sums_in(int x0, int y0, int x1,
                                                                   int y1) const = 0;
  /// Keys (level, x, y; data empty) of all sum tiles, or of those written after map
  /// version `updated_after`.
  [[nodiscard]] virtual std::vector<GridmapSumRow> gridmap_sum_keys(
      std::optional<std::int64_t> updated_after) const = 0;
  /// The sum tiles a drive touched (level, x, y), and the drives that touched a sum tile.
  [[nodiscard]] virtual std::vector<std::array<int, 3>> gridmap_sum_cover(
      std::string_view content_hash) const = 0;
  [[nodiscard]] virtual std::vector<std::string> gridmap_sum_contributors(int level, int x,
                                                                          int y) const = 0;
  /// One transaction: writes the tiles' bytes (updated_by = version) and records the input
  /// change (a drive added with its cover, or removed with its cover rows). Adding a drive
  /// that is already an input is a ConflictError (its gridmap would count twice).
  virtual void commit_gridmap_sums(std::int64_t version, std::span<const GridmapSumRow> tiles,
                                   const GridmapSumInputChange& change) = 0;

  // ------------------------------------------------------------ build jobs
  /// Adds jobs to a Building version (one transaction). ValidationError for an unknown kind.
  virtual void enqueue_build_jobs(std::int64_t version, std::span<const BuildJobSpec> jobs) = 0;
  /// Claims the oldest claimable job: pending, or running with an expired lease (its
  /// worker is presumed dead), of a Building version; a publish job only once the other
  /// jobs of its version are done. Running, attempt + 1, leased for lease_s seconds to
  /// `worker`; of `version` only, when given. nullopt when there is none. PostgreSQL:
  /// SELECT ... FOR UPDATE SKIP LOCKED.
  virtual std::optional<BuildJob> claim_build_job(std::string_view worker, double lease_s,
                                                  std::optional<std::int64_t> version) = 0;
  /// Extends the lease of a job this worker holds (same attempt, still running). False
  /// when the lease was lost (expired and claimed again, or the version failed).
  virtual bool renew_build_job(std::int64_t job, int attempt, double lease_s) = 0;
  /// One transaction: writes the output into the job's version and marks the job done,
  /// if the job is still running with this attempt and its version is Building (false
  /// otherwise, and nothing is written).
  virtual bool complete_build_job(std::int64_t job, int attempt, const BuildJobOutput& output) = 0;
  /// Marks a job failed (same fencing as complete; false if the lease was lost).
  virtual bool fail_build_job(std::int64_t job, int attempt, std::string_view error) = 0;
  /// The jobs of a version, by id.
  [[nodiscard]] virtual std::vector<BuildJob> build_jobs(std::int64_t version) const = 0;

  // ------------------------------------------------------------ localization runs
  /// Stores a validated run report: its record, its canonical bytes and its cells, in one
  /// transaction; then keeps only the newest `keep_newest` runs (older ones are deleted
  /// with their cells). Returns the new id.
  virtual std::int64_t put_localization_run(const LocalizationRunRecord& record,
                                            std::string_view canonical_body,
                                            std::span<const LocalizationRunCell> cells,
                                            std::size_t keep_newest) = 0;
  /// The newest runs first, at most `limit`; with `vehicle_id` non-empty only its runs.
  [[nodiscard]] virtual std::vector<LocalizationRunRecord> list_localization_runs(
      std::size_t limit, std::string_view vehicle_id = {}) const = 0;
  [[nodiscard]] virtual std::optional<LocalizationRunRecord> get_localization_run(
      std::int64_t id) const = 0;
  /// The canonical report bytes as stored; nullopt if the run is unknown.
  [[nodiscard]] virtual std::optional<std::string> localization_run_body(std::int64_t id) const = 0;
  /// Deletes a run and its cells; false if unknown.
  virtual bool delete_localization_run(std::int64_t id) = 0;
  /// The cells of zoom `z` within tile columns [x0, x1] and rows [y0, y1], summed over the
  /// stored runs `which` selects (`runs` = distinct runs), ordered by (x, y), at most `limit`.
  [[nodiscard]] virtual std::vector<LocalizationRunCell> localization_run_cells(
      int z, int x0, int y0, int x1, int y1, std::size_t limit, RunCellRuns which) const = 0;
  // ------------------------------------------------------------ HD-map comparisons
  /// Stores a comparison of a published version, replacing one of the same (version, name);
  /// created_at is set by the store. NotFoundError if the version is unknown or not
  /// published; ValidationError for an invalid name. Deleting the version deletes it.
  virtual void put_hdmap_comparison(const HdMapComparisonRecord& record) = 0;
  /// The comparisons of a published version, by name, without features. NotFoundError if
  /// the version is unknown or not published.
  [[nodiscard]] virtual std::vector<HdMapComparisonRecord> list_hdmap_comparisons(
      std::int64_t version) const = 0;
  /// One comparison with its features; nullopt if none of that name. NotFoundError if the
  /// version is unknown or not published.
  [[nodiscard]] virtual std::optional<HdMapComparisonRecord> get_hdmap_comparison(
      std::int64_t version, std::string_view name) const = 0;

  // ------------------------------------------------------------ landmark provenance
  /// The landmark with stable key `key` in a published version, its supporting drives and
  /// its history (LandmarkDetail); nullopt if the version has no landmark with that key.
  /// NotFoundError if the version is unknown or not published.
  [[nodiscard]] virtual std::optional<LandmarkDetail> landmark_detail(std::int64_t version,
                                                                      std::int64_t key) const = 0;

  [[nodiscard]] virtual StoreStats stats() const = 0;
};

// PostgreSQL/PostGIS backend (PostgresMapStore, postgres_store.hpp; docs/postgresql.md). The
// interface maps 1:1 onto the tables of schema/store.sql, in schema/store_postgres.sql:
//  - geometry columns are PostGIS `geometry` (SRID 4326: Point / LineString for candidates
//    and landmarks, the bounding-box Polygon for drives) with GiST indexes instead of the
//    SQLite R*Tree side tables; region queries use `geom && ST_MakeEnvelope(...)`, then the
//    same exact filter as SQLite's;
//  - JSON columns are `jsonb`, blobs `bytea`, times the same ISO 8601 text;
//  - put_drive: package files in a package directory every replica shares, under the content
//    hash, rows in one transaction; idempotency by the UNIQUE constraint on content_hash
//    (INSERT ... ON CONFLICT DO NOTHING RETURNING);
//  - writes serialized by one transaction-level advisory lock (ids as SQLite's; the upload
//    quota check and insert under it); readers in REPEATABLE READ READ ONLY snapshots;
//  - connections from a pool (libpq, one per thread in use);
//  - upload sessions: the same table; their files under <package_dir>/uploads.
// Not yet: partitioned builds (a `build_jobs(region, status, claimed_by)` table claimed with
// `SELECT ... FOR UPDATE SKIP LOCKED`; each job writes its region's tiles into the Building
// version, the last one publishes).

}  // namespace polmap::mapping
