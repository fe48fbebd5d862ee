#pragma once
/// @file server.hpp
/// The mapping service's HTTP server (cpp-httplib): drive uploads, map builds,
/// localization tiles, and GIS views (MVT, TileJSON, gridmap PNG, export).
/// The API is described in schema/openapi.yaml; summary:
///
///   GET    /health                          liveness + store summary (JSON)
///   GET    /metrics                         Prometheus text format
///   POST   /v1/drives              (key)    upload a drive package (ustar archive)
///   POST   /v1/uploads             (key)    open a resumable upload (Upload-Length) -> 201
///   PATCH  /v1/uploads/{id}        (key)    append a chunk at Upload-Offset -> 204, or the
///                                           drive (201/200) once the last byte is in
///   HEAD   /v1/uploads/{id}        (key)    Upload-Offset / Upload-Length / Upload-Expires
///   DELETE /v1/uploads/{id}        (key)    abort a resumable upload
///   GET    /v1/drives                       list drives
///   GET    /v1/drives/{id}                  one drive (with manifest)
///   DELETE /v1/drives/{id}         (key)    remove a drive
///   POST   /v1/maps                (key)    start a map build -> 202 {version}
///   GET    /v1/maps                         list map versions
///   GET    /v1/maps/{version|current}       status and statistics
///   GET    /v1/tiles/{z}/{x}/{y}[?version=] localization tile (application/vnd.polmap.tile)
///   GET    /v1/mvt/{z}/{x}/{y}.mvt[?version=]  vector tile: points, lines, trajectories
///   GET    /v1/tilejson.json[?version=]     TileJSON 3.0 of the MVT layers
///   GET    /v1/gridmap/{z}/{x}/{y}.png[?version=]  fleet gridmap amplitude raster tile
///   GET    /v1/export?format=gpkg|geojson|shp[&bbox=..][&version=]  GIS export download
///   DELETE /v1/vehicles/{vehicle_id}/drives  (operator) erase every drive of a vehicle
///
/// Localization tiles: 200 with the payload (strong ETag, If-None-Match -> 304;
/// immutable caching for ?version=N, 60 s + must-revalidate for the current version),
/// 204 for a tile inside the version's coverage without landmarks (coverage = the
/// tiles holding landmarks plus a one-tile margin), 404 outside the coverage, for
/// zooms other than 16 and unknown/unpublished versions, 400 for a malformed z/x/y.
///
/// Access (docs/security.md): tiles, TileJSON, MVT landmark layers, map versions and
/// /health are public. Everything else needs `Authorization: Bearer KEY` with a key of
/// ServerConfig::api_keys (compared in constant time) whose role allows it: a vehicle
/// key uploads drives (of its own vehicle, if the key names one); a viewer key reads
/// drives, trajectories (the MVT trajectories layer) and /metrics; an operator key does
/// everything, including builds, deletes and exports. 401 without a valid key, 403 when
/// its role does not allow the request. Errors are JSON {"error": "...", "field": "..."}.
/// CORS headers only for ServerConfig::cors_allow_origin.
///
/// Threading: listen() blocks the calling thread and serves requests on a pool
/// of `threads` workers; map builds run one at a time on a background thread.
/// stop() may be called from any thread (e.g. a signal-waiting thread).
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

namespace polmap::mapping {

class MapStore;

/// What a key may do.
enum class KeyRole {
  Vehicle,   ///< upload drives (of `vehicle_id` only, when set) and report runs
  Viewer,    ///< read drives, trajectories and metrics
  Operator,  ///< everything: builds, deletes, exports, and what the others may do
};

/// One API key. Built from a bare string it is an operator key (the meaning keys had
/// before roles existed).
struct ApiKey {
  ApiKey() = default;
  ApiKey(std::string k) : key(std::move(k)) {}  // NOLINT: implicit on purpose (see above)
  ApiKey(const char* k) : key(k) {}             // NOLINT
  ApiKey(std::string k, KeyRole r, std::string vehicle = {})
      : key(std::move(k)), role(r), vehicle_id(std::move(vehicle)) {}
  std::string key;
  KeyRole role = KeyRole::Operator;
  /// Vehicle keys: the only manifest vehicle_id this key may upload (empty: any).
  std::string vehicle_id;
};

[[nodiscard]] std::string_view to_string(KeyRole role);

/// Server settings. Defaults are what `polmap serve` uses.
struct ServerConfig {
  /// Accepted keys. Empty: everything but the public reads is refused (401).
  std::vector<ApiKey> api_keys;
  /// When set, the keys are (re)read from this file whenever it changes (checked at most
  /// once a second), replacing api_keys: keys are added and revoked without a restart. A
  /// file that no longer parses keeps the previous keys (and is logged).
  std::filesystem::path api_key_file;
  /// Largest accepted upload body (413 beyond). 512 MiB: an hour of driving at
  /// the gridmap's 0.1 m cells is ~100–300 MiB of DEFLATE GeoTIFF.
  std::uint64_t max_upload_bytes = 512ull << 20;
  /// Resumable uploads (POST /v1/uploads, docs/security.md): a session expires this long
  /// after it was created (then PATCH and HEAD answer 410 and the sweeper, run on every
  /// create and every 10 minutes, removes it with its bytes).
  std::int64_t upload_session_ttl_s = 24 * 3600;
  /// Unexpired sessions one API key may hold at once (one more: 429).
  int max_upload_sessions_per_key = 4;
  /// Bytes the unexpired sessions of one API key may declare in all (one more: 429).
  /// Default: four packages of the largest size.
  std::uint64_t max_upload_session_bytes_per_key = 2ull << 30;
  /// Largest chunk one PATCH may carry (its Content-Length; 413 beyond, before the body).
  std::uint64_t max_upload_chunk_bytes = 64ull << 20;
  /// Uploads received and validated at the same time (POST /v1/drives and PATCH
  /// /v1/uploads/{id} alike); one more is answered 503 with Retry-After before its body is
  /// read (each holds a worker, disk and CPU).
  int max_concurrent_uploads = 4;
  /// Map builds waiting behind the running one; one more is answered 503 with Retry-After
  /// (each queued build holds a map version row and will read every drive).
  int max_queued_builds = 4;
  /// Exports (GET /v1/export) written at the same time; one more is answered 503 with
  /// Retry-After (each reads a whole map version and writes a file).
  int max_concurrent_exports = 1;
  /// Largest accepted JSON request body (POST /v1/maps).
  std::uint64_t max_json_bytes = 1ull << 20;
  /// Largest accepted localization run report (POST /v1/runs; 413 before the body beyond).
  /// 4 MiB holds a report of about 20,000 samples: over an hour of driving at 5 Hz.
  std::uint64_t max_run_report_bytes = 4ull << 20;
  /// Samples one run report may carry (413 beyond, before they are converted).
  std::size_t max_run_samples = 100'000;
  /// Run reports kept: storing one more deletes the oldest (reports are operational data
  /// about vehicles: keep a bounded history).
  std::int64_t max_localization_runs = 10'000;
  /// Directory for in-flight uploads (removed after each request); empty = system temp dir.
  std::filesystem::path upload_dir;
  /// Drives ingested longer ago than this are deleted (at start, then every 10 minutes);
  /// 0 keeps them forever. Drive data is personal data: keep it only as long as needed.
  double drive_retention_days = 0.0;
  /// At start, our upload and export leftovers in upload_dir that nobody touched for this
  /// long are removed (what a killed process left behind).
  double upload_leftover_age_s = 600.0;
  /// Worker threads. cpp-httplib keeps a worker per open keep-alive connection,
  /// so this bounds the number of concurrently served connections.
  int threads = 32;
  /// Requests served on one keep-alive connection before it is closed.
  int keep_alive_max_requests = 1000;
  /// Idle keep-alive connections are closed after this many seconds.
  int keep_alive_timeout_s = 5;
  /// Cache-Control max-age of tiles of the *current* version (no ?version=):
  /// clients revalidate with If-None-Match after this (304 if unchanged).
  int current_tile_max_age_s = 60;
  /// In-memory cache of tile payloads (localization, MVT, PNG) in bytes.
  std::size_t tile_cache_bytes = 64ull << 20;
  /// Base URL written into TileJSON (e.g. "https://maps.example.com"); empty =
  /// "http://" (with TLS "https://") + the request's Host header. Behind a reverse proxy
  /// set it to the proxy's public URL.
  std::string public_url;
  /// Access-Control-Allow-Origin value: empty (default) sends no CORS headers, so
  /// browsers on other origins cannot read responses; "*" any origin; or one origin.
  std::string cors_allow_origin;
  /// Requests with more header fields, or more header bytes in all, are refused with
  /// 431 before routing (cpp-httplib has already read them by then, each line capped at
  /// 8 KiB; the nginx front of docs/ bounds them before they reach us).
  std::size_t max_header_count = 64;
  std::size_t max_header_bytes = 32u << 10;
  /// TLS of the embedded server (docs/deployment.md): a PEM certificate chain (the
  /// server's certificate first, then intermediates) and its unencrypted PEM private key.
  /// Both empty (default): plain HTTP. Both set: HTTPS only, TLS 1.2 or newer. The
  /// Server constructor throws IoError when a file cannot be read, ValidationError when
  /// only one is set, a file does not parse or the key does not belong to the certificate.
  std::filesystem::path tls_cert_file;
  std::filesystem::path tls_key_file;
  /// MVT zoom range served and announced in TileJSON.
  int mvt_min_zoom = 12;
  int mvt_max_zoom = 22;
  /// On start, versions left in status Building (a previous process died during a
  /// build) are marked Failed, except partitioned builds with jobs left (build workers
  /// finish them). Turn off when several servers share one store (polmap serve does for
  /// PostgreSQL, whose store fails only builds whose process is gone).
  bool fail_stale_builds_on_start = true;
  /// Every this many seconds the build thread asks the store for builds whose process is
  /// gone (MapStore::fail_abandoned_builds: a replica killed while building or with builds
  /// queued) and fails them, so they do not wait for the next open. 0: never.
  double abandoned_build_check_s = 15.0;
  /// > 0: map builds are partitioned into regions of this zoom (MapBuildRequest::partition,
  /// schema/build_jobs.md), with this halo; 0: one-process builds (incremental).
  int build_partition_zoom = 0;
  double build_partition_halo_m = 120.0;
  /// Partitioned builds: the server's build thread works on the jobs too (with any
  /// `polmap build-worker` processes); false: it leaves them to build workers.
  bool run_build_jobs = true;
  /// One line per request (method, path, status, bytes, ms) and server events.
  bool log_requests = true;
  /// Log sink; default writes the line plus '\n' to stderr.
  std::function<void(std::string_view line)> log_sink;
};

/// Reads an API key file: one key per line, `ROLE KEY [VEHICLE_ID]` with ROLE one of
/// vehicle, viewer, operator, or a bare `KEY` (an operator key); blank lines and lines
/// starting with '#' are ignored; surrounding whitespace is trimmed. Throws IoError if
/// the file cannot be read, ValidationError (naming the line) if a line is malformed or
/// the file holds no key.
[[nodiscard]] std::vector<ApiKey> read_api_key_file(const std::filesystem::path& path);

class Server {
 public:
  /// The store must outlive the server. Throws IoError / ValidationError for a TLS
  /// certificate or key that cannot be used (ServerConfig::tls_cert_file).
  Server(MapStore& store, ServerConfig config);
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  /// Binds host:port (port 0 = any free port, see bound_port()) and serves until
  /// stop(). Throws IoError if the address cannot be bound.
  void listen(const std::string& host, int port);
  /// Stops accepting, lets requests in flight finish, waits for a running map
  /// build to finish (queued builds are marked failed), and makes listen() return.
  /// Idempotent; safe from any thread.
  void stop();
  /// The bound port once listen() has bound (0 before).
  [[nodiscard]] int bound_port() const;
  /// Blocks until listen() has bound and is accepting, or the timeout passes.
  bool wait_until_listening(std::chrono::milliseconds timeout) const;

  /// Blocks until no map build is queued or running (tests, CLI).
  void wait_for_builds() const;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace polmap::mapping
