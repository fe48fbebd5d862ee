#pragma once
// Internal: the state of mapping::Server shared by server*.cpp (not installed).
#include <atomic>
#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>
#include <thread>

#include "http_util.hpp"
#include "polmap/mapping_service/server.hpp"
#include "polmap/mapping_service/store.hpp"
#include "polmap/schema/recording.hpp"
#include "polmap/tiles/tile_key.hpp"

// After everything that includes Eigen: httplib pulls in <resolv.h>, whose `_res`
// macro breaks Eigen's templates.
#include <httplib.h>

namespace polmap::mapping {

/// Media types used by the server.
inline constexpr const char* kJson = "application/json";
/// The 507 reply of a write that found no space (the detail goes to the log).
inline constexpr const char* kStorageFullMessage =
    "the server's storage is full: nothing was stored; retry once space is freed";

/// Per-request context kept in thread-locals: cpp-httplib runs routing, the
/// handler, response writing and the logger on the same worker thread.
void set_route(const char* route);

/// Immutable facts about a published map version, cached per version.
struct VersionIndex {
  std::int64_t version = 0;
  std::map<tiles::TileKey, TileInfo> localization;  ///< tiles with payload
  std::set<tiles::TileKey> covered;                 ///< tiles with payload + 1-tile margin
  std::map<tiles::TileKey, TileInfo> gridmap;
  std::map<tiles::TileKey, TileInfo> gridmap_mechanism;  ///< same keys, mechanism colouring
  int gridmap_max_zoom = -1;                             ///< base zoom of the fleet gridmap
  std::optional<tiles::GeoBox> bounds;                   ///< of the localization tiles
  nlohmann::json parameters;
};

/// One of `limit` slots of a counter, held for the slot's lifetime: heavy requests
/// (uploads, exports) beyond the limit are refused with 503 instead of queueing up.
class ConcurrencySlot {
 public:
  ConcurrencySlot(std::atomic<int>& counter, int limit) : n_(counter), ok_(++counter <= limit) {}
  ~ConcurrencySlot() { --n_; }
  ConcurrencySlot(const ConcurrencySlot&) = delete;
  ConcurrencySlot& operator=(const ConcurrencySlot&) = delete;
  [[nodiscard]] bool acquired() const { return ok_; }

 private:
  std::atomic<int>& n_;
  bool ok_;
};

struct Server::Impl {
  Impl(MapStore& store, ServerConfig config);
  ~Impl();

  MapStore& store;
  ServerConfig cfg;
  /// httplib::SSLServer when cfg names a TLS certificate, else httplib::Server.
  std::unique_ptr<httplib::Server> http_owner;
  httplib::Server& http;
  http::Metrics metrics;
  http::BlobCache cache;

  // Listening state.
  std::atomic<int> port{0};
  std::atomic<bool> stopping{false};
  mutable std::mutex state_mutex;
  mutable std::condition_variable state_cv;
  bool listening = false;

  /// Uploads in flight (body being received or validated).
  std::atomic<int> uploads_in_flight{0};
  /// Exports being written (streaming a finished export does not count).
  std::atomic<int> exports_in_flight{0};
  /// Removes leftovers of a killed process from the upload directory (start-up).
  void sweep_upload_dir();
  /// Deletes drives older than cfg.drive_retention_days; returns how many.
  std::size_t apply_retention();
  /// Removes expired upload sessions (store and files); returns how many. Never throws.
  std::size_t sweep_upload_sessions();
  /// Fails the store's builds whose process is gone (logged, counted). Never throws.
  void fail_abandoned_builds();

  /// The one ingest path of an uploaded package, for POST /v1/drives and a completed
  /// upload session alike: `bytes` is the whole archive (`hash` its SHA-256 hex), already
  /// received under the upload limit. Already stored -> 200; validation (the one parser:
  /// try_validate_package_bytes) -> 400/422; the key's vehicle -> 403; the validated
  /// members, unpacked by the same reader below `scratch_dir`, are what put_drive stores ->
  /// 201, 409 (drive_id conflict) or 507. Writes the reply and the upload metric; returns
  /// the status. Other failures throw (500).
  int ingest_package(const std::string& bytes, const std::string& hash, const ApiKey& key,
                     const std::filesystem::path& scratch_dir, httplib::Response& res);
  /// The directory for in-flight upload files (cfg.upload_dir or the system temp dir).
  [[nodiscard]] std::filesystem::path upload_scratch_dir() const;

  // ---- logging
  /// One line to the log sink; the message is escaped (escape_for_log).
  void log(std::string_view level, std::string_view message) const;
  /// Internal errors so far: their number is the reference a 500 reply gives.
  std::atomic<std::uint64_t> internal_errors{0};

  // ---- helpers for handlers
  /// The limits applied once the headers are parsed and before any body byte is read
  /// (header count and size, one range, no encoded bodies, a key for every write,
  /// declared and bounded JSON bodies). False: the refusal is in `res`.
  bool admit(const httplib::Request& req, httplib::Response& res) const;
  /// What a request needs its key for.
  enum class Access { AnyKey, Upload, ReadDrives, Operate };
  /// The request's key, if it carries a valid one (Authorization: Bearer KEY).
  [[nodiscard]] std::optional<ApiKey> authenticate(const httplib::Request& req) const;
  /// The request's key if its role allows `access`; otherwise writes 401 (no valid key)
  /// or 403 (role) into `res` and returns nullopt.
  std::optional<ApiKey> require(const httplib::Request& req, httplib::Response& res,
                                Access access) const;
  [[nodiscard]] static bool allows(const ApiKey& key, Access access);
  /// The keys in force (reloaded from cfg.api_key_file when it changed).
  [[nodiscard]] std::shared_ptr<const std::vector<ApiKey>> current_keys() const;
  mutable std::mutex keys_mutex;
  mutable std::shared_ptr<const std::vector<ApiKey>> keys;
  mutable std::chrono::steady_clock::time_point keys_checked_at{};
  mutable std::filesystem::file_time_type keys_mtime{};
  static void reply_json(httplib::Response& res, int status, const nlohmann::json& body);
  static void reply_error(httplib::Response& res, int status, std::string_view message,
                          std::string_view field = {}, const nlohmann::json& extra = nullptr);
  /// Serves a cached blob with ETag / If-None-Match / gzip negotiation.
  /// Returns the status written (200 or 304).
  int reply_blob(const httplib::Request& req, httplib::Response& res, const http::CachedBlob& blob,
                 const std::string& cache_control) const;

  // ---- map versions
  /// The current version, cached for up to 1 s (invalidated by our own builds).
  std::optional<std::int64_t> current_version();
  void invalidate_current_version();
  /// Index of a published version; nullptr if unknown or not published.
  std::shared_ptr<const VersionIndex> version_index(std::int64_t version);
  /// Resolves ?version= (explicit) or the current version. On failure writes the
  /// error reply (400 malformed, 404 unknown/unpublished/none) and returns nullptr.
  std::shared_ptr<const VersionIndex> resolve_version(const httplib::Request& req,
                                                      httplib::Response& res, bool& is_explicit);

  std::mutex version_mutex;
  std::optional<std::int64_t> current_cached;
  std::chrono::steady_clock::time_point current_cached_at{};
  std::map<std::int64_t, std::shared_ptr<const VersionIndex>> indexes;

  // ---- trajectories for the MVT layer (decimated, per drive content hash)
  std::shared_ptr<const std::vector<GeoPoint>> drive_trajectory(const DriveRecord& drive);
  std::mutex trajectory_mutex;
  std::map<std::string, std::shared_ptr<const std::vector<GeoPoint>>> trajectories;

  // ---- map builds (one at a time, on build_thread)
  struct BuildJob {
    std::int64_t version = 0;
    nlohmann::json request;
  };
  std::int64_t submit_build(const nlohmann::json& request);
  void build_loop();
  void run_build(const BuildJob& job);
  /// Marks failed the versions whose failed build could not be marked failed then (the
  /// store was full); those that still cannot be stay listed for the next try.
  void retry_failing_builds();
  mutable std::mutex build_mutex;
  mutable std::condition_variable build_cv;
  std::deque<BuildJob> build_queue;
  /// Failed builds still in status Building, with their error (build_mutex); retried
  /// every second and before the next build.
  std::map<std::int64_t, std::string> builds_to_fail;
  bool build_running = false;
  bool build_shutdown = false;
  /// The running build's stage and fraction (GET /v1/maps/{v} "progress"; under build_mutex).
  std::int64_t progress_version = 0;
  std::string progress_stage;
  double progress_fraction = 0.0;
  std::thread build_thread;

  // ---- routes (one function per file)
  void register_routes();
  void register_drive_routes();
  void register_upload_routes();
  void register_map_routes();
  void register_tile_routes();
  /// Localization run reports (server_runs.cpp).
  void register_run_routes();
  // tile handlers (server_tiles.cpp)
  void get_localization_tile(const httplib::Request& req, httplib::Response& res);
  void get_mvt_tile(const httplib::Request& req, httplib::Response& res);
  void get_tilejson(const httplib::Request& req, httplib::Response& res);
  /// 503 with Retry-After: max_concurrent_uploads uploads are being received already.
  void reply_uploads_busy(httplib::Response& res) const;
  void get_gridmap_tile(const httplib::Request& req, httplib::Response& res);
  void get_gridmap_mechanism_tile(const httplib::Request& req, httplib::Response& res);
  /// Either fleet gridmap raster layer (Gridmap or GridmapMechanism).
  void serve_gridmap_layer(const httplib::Request& req, httplib::Response& res, TileLayer layer);
  /// Cache-Control of a tile: immutable for an explicit ?version=, revalidated otherwise.
  [[nodiscard]] std::string tile_cache_control(bool is_explicit) const;
  /// Answers 304 (with ETag and Cache-Control) when If-None-Match matches `etag`.
  static bool reply_not_modified(const httplib::Request& req, httplib::Response& res,
                                 const std::string& etag, const std::string& cache_control);
  void register_gis_routes();
  /// GET /v1/maps/{v}/hdmap-comparison[/{name}] and /v1/maps/{v}/landmarks/{key}
  /// (server_hdmap.cpp).
  void register_hdmap_routes();
  /// The web console (GET /, /console/...; server_console.cpp).
  void register_console_routes();
};

/// The cpp-httplib server for `cfg`: plain, or TLS with cfg's certificate and key (checked
/// here; throws IoError / ValidationError naming the file). server_tls.cpp.
std::unique_ptr<httplib::Server> make_http_server(const ServerConfig& cfg);

/// The owner fingerprint of upload sessions created with `key`: SHA-256 hex of a
/// domain-separated key (the store never holds a key).
std::string upload_owner(const ApiKey& key);
/// True for "PATCH /v1/uploads/..." (bodies streamed by their handler, like POST /v1/drives).
bool is_upload_chunk(const httplib::Request& req);

/// JSON of a drive record (manifest only when with_manifest).
nlohmann::json drive_to_json(const DriveRecord& d, bool with_manifest);
/// JSON of a map version.
nlohmann::json version_to_json(const MapVersionInfo& v);
nlohmann::json geobox_to_json(const tiles::GeoBox& b);
/// PNG of a stored fleet gridmap tile payload (TileLayer::Gridmap).
std::string gridmap_png(std::string_view payload);
/// Over-zoomed gridmap tile: the part of `ancestor_png` (a 256 px tile dz zoom
/// levels up) covering `key`, scaled up with nearest-neighbour pixels.
std::string gridmap_overzoom_png(std::string_view ancestor_png, const tiles::TileKey& ancestor,
                                 const tiles::TileKey& key);

}  // namespace polmap::mapping
