#pragma once
// Internal helpers of the HTTP server (not installed): JSON errors, ETags,
// content negotiation, hashing, constant-time comparison, an LRU byte cache,
// and Prometheus metrics.
#include <chrono>
#include <cstdint>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "polmap/tiles/tile_key.hpp"
#include "polmap/util/sha256.hpp"
#include "polmap/util/text.hpp"

namespace polmap::mapping::http {

/// {"error": message, "field": field} (field omitted when empty) plus extra keys.
std::string json_error(std::string_view message, std::string_view field = {},
                       const nlohmann::json& extra = nullptr);

/// RFC 9110 If-None-Match evaluation (weak comparison): true if any listed entity
/// tag (or "*") matches `etag` (given quoted, e.g. "\"abc\"").
bool if_none_match_matches(std::string_view header, std::string_view etag_quoted);

/// True if Accept-Encoding allows gzip (q > 0 for gzip, x-gzip or "*").
bool accepts_gzip(std::string_view accept_encoding);

/// ISO 8601 UTC with milliseconds, e.g. "2024-05-01T12:00:00.123Z".
std::string iso8601_now();

using util::secrets_equal;  // constant-time comparison of keys

using util::escape_for_log;  // request paths, drive ids: never raw into a log line

/// The method as a metrics label: a standard HTTP method, or "other" (a client must not
/// be able to create label values, each of which is kept forever).
std::string_view metric_method(std::string_view method);

/// Parses "minlon,minlat,maxlon,maxlat" (degrees); nullopt if malformed or out of range.
std::optional<tiles::GeoBox> parse_bbox(std::string_view s);

/// Parses a decimal int64 (the whole string); nullopt otherwise.
std::optional<std::int64_t> parse_int(std::string_view s);

/// A cached response body.
struct CachedBlob {
  std::string body;
  std::string gzip_body;  ///< empty if not compressible / not worth it
  std::string etag;       ///< quoted strong ETag of `body`
  std::string content_type;
};

/// Thread-safe LRU cache of blobs, bounded by total bytes.
class BlobCache {
 public:
  explicit BlobCache(std::size_t max_bytes) : max_bytes_(max_bytes) {}
  std::shared_ptr<const CachedBlob> get(const std::string& key);
  void put(const std::string& key, std::shared_ptr<const CachedBlob> blob);
  void clear();

 private:
  using Entry = std::pair<std::string, std::shared_ptr<const CachedBlob>>;
  std::mutex mutex_;
  std::size_t max_bytes_;
  std::size_t bytes_ = 0;
  std::list<Entry> lru_;  // front = most recent
  std::unordered_map<std::string, std::list<Entry>::iterator> index_;
};

/// Request/tile/build counters and latency histograms, rendered as Prometheus text.
class Metrics {
 public:
  void observe_request(std::string_view route, std::string_view method, int status, double seconds,
                       std::uint64_t bytes);
  void tile_served(std::string_view kind, int status);
  void upload(std::string_view outcome, std::uint64_t bytes);
  void build_finished(std::string_view outcome);
  /// Counters and histograms; gauges are appended by the caller.
  [[nodiscard]] std::string render() const;

  static constexpr double kBuckets[] = {0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05,
                                        0.1,    0.25,  0.5,    1.0,   2.5,  5.0,   10.0};
  static constexpr std::size_t kNumBuckets = std::size(kBuckets);

 private:
  struct Histogram {
    std::uint64_t counts[kNumBuckets + 1] = {};
    double sum = 0.0;
    std::uint64_t count = 0;
  };
  mutable std::mutex mutex_;
  std::map<std::tuple<std::string, std::string, int>, std::uint64_t> requests_;
  std::map<std::string, Histogram> latency_;
  std::map<std::string, std::uint64_t> response_bytes_;
  std::map<std::pair<std::string, int>, std::uint64_t> tiles_;
  std::map<std::string, std::uint64_t> uploads_;
  std::uint64_t upload_bytes_ = 0;
  std::map<std::string, std::uint64_t> builds_;
};

/// Escapes a Prometheus label value.
std::string prom_label(std::string_view v);

}  // namespace polmap::mapping::http
