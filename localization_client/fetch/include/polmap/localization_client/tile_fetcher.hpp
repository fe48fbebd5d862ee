#pragma once
/// @file tile_fetcher.hpp
/// HTTP client of the tile API (GET /v1/tiles/{z}/{x}/{y}, schema/openapi.yaml)
/// with an on-disk cache, implementing the non-blocking TileSource.
///
/// Behaviour:
///  - tile() answers from memory only. A miss (or a stale entry) queues the key
///    for the background worker and returns what memory has (nullopt on a
///    miss). The per-frame loop therefore never waits for disk or network.
///  - The worker thread serves the queue in priority order (missing tiles
///    first, then prefetch, then revalidation): it loads the disk cache, and
///    asks the server when the copy is missing or older than
///    revalidate_after_s, with If-None-Match: <etag> so an unchanged tile costs
///    a 304 without payload.
///  - Answers: 200 -> decoded (a payload that does not decode is an error, not
///    cached); 304 -> cached copy confirmed; 204 -> covered, no landmarks (empty
///    tile); 404 -> outside the map's coverage (empty tile, revalidated like
///    others since a map can grow); 5xx / transport errors -> retried with
///    exponential backoff (backoff_initial_s doubling to backoff_max_s).
///  - Offline: after a transport error the server counts as unreachable and is
///    not contacted again before the backoff expires; meanwhile every tile
///    with a disk copy is served from the cache regardless of its age.
///  - New map versions: every response carries X-Polmap-Map-Version. When it
///    is newer than the version of the cached copies, all cached tiles are
///    marked stale and revalidated as they are used, so a vehicle picks up a
///    published map within one revalidation round, without a restart. Tiles in
///    use are also revalidated every revalidate_after_s (the server's
///    Cache-Control max-age of current tiles is 60 s).
///  - Disk cache: <cache_dir>/<z>/<x>/<y>.pmtc, one file per tile holding a
///    small text header (format tag, HTTP status, ETag, map version from the
///    header, fetch time, key, payload size) followed by the tile payload
///    (format: tile_cache_file.hpp). Written to a temporary file in the same
///    directory and renamed, so a crash never leaves a torn file; files that do
///    not decode (torn, corrupt, for another key, over max_tile_bytes) are
///    ignored (refetched).
///  - Signed static publication (publication_public_key set; `polmap publish`): server_url
///    is the publication root on any static host or CDN (e.g. "https://cdn.example.com/
///    polmap"; a path is allowed). The worker reads latest.json, then that directory's
///    manifest.json and manifest.sig, and adopts the manifest only if the signature
///    verifies with the configured key and its map version is not older than the one in
///    use (no rollback by a stale mirror). A tile absent from the manifest is outside the
///    map (empty); a listed tile is fetched from its content-named directory and accepted
///    only if its SHA-256 is the manifest's, which is also its ETag: a cached copy with the
///    same hash is confirmed without a request. The pointer is re-read every
///    revalidate_after_s. Anything that fails a check is a server error, retried later;
///    what was accepted before stays in use.
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "polmap/localization_client/tile_source.hpp"
#include "polmap/schema/geo.hpp"

namespace polmap::loc {

/// Settings of the fetcher; defaults suit a vehicle on a cellular link.
struct TileFetcherConfig {
  /// Base URL of the mapping service, e.g. "http://127.0.0.1:8080" or
  /// "https://maps.example.com". Empty: offline mode (disk cache only).
  std::string server_url;
  /// https:// only: PEM file of the CA certificates the server's certificate must chain
  /// to (e.g. a private CA, or a self-signed server certificate itself). Empty: the
  /// system's CA store. The certificate and its host name are always verified; a server
  /// that fails the check counts as unreachable (transport error), nothing is fetched.
  std::filesystem::path ca_file;
  /// Disk cache directory (created if missing). Empty: memory only.
  std::filesystem::path cache_dir;
  /// Copies older than this are revalidated (If-None-Match) when used; 60 s
  /// matches the server's max-age of current-version tiles.
  double revalidate_after_s = 60.0;
  double connect_timeout_s = 2.0;
  /// Longest silence between two reads of a response.
  double read_timeout_s = 5.0;
  /// Longest time for a whole response body: a server dripping bytes is cut off here
  /// (read_timeout_s alone would let it hold the fetch worker forever).
  double request_deadline_s = 15.0;
  /// Largest tile body accepted (after any HTTP decompression). Localization tiles are
  /// a few kB; a larger answer is treated as a server error, not stored.
  std::size_t max_tile_bytes = 4u << 20;
  /// Retry delays after 5xx/transport errors: initial, doubled up to max.
  double backoff_initial_s = 0.25;
  double backoff_max_s = 10.0;
  /// Tiles kept in memory (least recently used beyond are dropped; the disk
  /// cache keeps them). 512 z16 tiles ≈ 100 km² of map.
  std::size_t memory_capacity_tiles = 512;
  /// Optional query string appended to tile requests, e.g. "version=7" to pin
  /// a map version (then no version pickup happens).
  std::string query;
  /// Ed25519 public key (PEM file) of the publisher: switches to a signed static
  /// publication at server_url (file comment). ValidationError at construction if it is not
  /// such a key.
  std::filesystem::path publication_public_key;
  /// Largest manifest.json accepted (a city's manifest is a few MB).
  std::size_t max_manifest_bytes = 64u << 20;
};

/// Counters for logs and tests.
struct TileFetcherStats {
  std::uint64_t memory_hits = 0;
  std::uint64_t memory_misses = 0;
  std::uint64_t disk_loads = 0;
  std::uint64_t responses_200 = 0;
  std::uint64_t responses_304 = 0;
  std::uint64_t responses_204 = 0;
  std::uint64_t responses_404 = 0;
  std::uint64_t server_errors = 0;     ///< 5xx and undecodable payloads
  std::uint64_t transport_errors = 0;  ///< connection refused, timeouts
  std::uint64_t bytes_downloaded = 0;
  std::uint64_t map_version = 0;  ///< newest X-Polmap-Map-Version seen (0: none)
  /// Static publication: manifests adopted, and checks that failed (signature, rollback,
  /// malformed manifest; tile bytes whose SHA-256 is not the manifest's).
  std::uint64_t manifests_adopted = 0;
  std::uint64_t manifest_rejections = 0;
  std::uint64_t hash_mismatches = 0;
  bool server_reachable = false;  ///< last request reached the server
  std::size_t queued = 0;
  /// CPU time of the fetch worker thread (requests, decoding, cache files), seconds:
  /// a localizer's cost includes it.
  double worker_cpu_s = 0.0;
};

class TileFetcher final : public TileSource {
 public:
  explicit TileFetcher(TileFetcherConfig cfg);
  /// Stops the worker (waits for an in-flight request, at most the timeouts).
  ~TileFetcher() override;
  TileFetcher(const TileFetcher&) = delete;
  TileFetcher& operator=(const TileFetcher&) = delete;

  std::optional<tiles::LocalizationTile> tile(const tiles::TileKey& key) override;
  void prefetch(std::span<const tiles::TileKey> keys) override;

  /// Blocking helper for start-up and tests (never call it from the frame
  /// loop): waits until every key has an answer in memory or timeout_s passes.
  /// Returns true when all are available.
  bool wait_for(std::span<const tiles::TileKey> keys, double timeout_s);
  /// Blocks until the queue is empty and the worker idle, or timeout_s passes.
  bool wait_idle(double timeout_s);
  /// Marks every cached tile stale, so its next use revalidates it.
  void invalidate_all();

  [[nodiscard]] TileFetcherStats stats() const;
  [[nodiscard]] const TileFetcherConfig& config() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace polmap::loc
