#pragma once
/// @file tile_cache_file.hpp
/// The tile fetcher's disk cache file, <cache_dir>/<z>/<x>/<y>.pmtc: one answer of the
/// server for one tile (tile_fetcher.hpp). A text header, an empty line, the payload:
///
///     PMTC1
///     status 200               200 (payload: an encoded tile), 204 or 404 (no payload)
///     etag "v7-1f3a"           the server's ETag as sent ("" for 204/404)
///     version 7                X-Polmap-Map-Version of the answer (0: none)
///     fetched 1712345678.25    unix time the server last confirmed it (round-trip decimal)
///     key 16/34567/22222       the tile the answer is for
///     size 1234                payload bytes
///     <empty line>
///     <payload>
///
/// `key` and `size` are optional on reading (files written before they existed: the
/// payload is then the rest of the file); every other line is required, each at most
/// once. Unknown lines are ignored, so a newer writer's files stay readable.
///
/// The file may be anything (a torn write after a power loss, a full disk, another
/// program): decoding never trusts a value read from it. The header is searched only in
/// its first kMaxTileCacheHeaderBytes, `size` is compared with the bytes actually
/// present before anything is taken from it, numbers must be plain decimals in range,
/// a 200 payload must decode as a tile of the requested key, and 204/404 carry none.
/// A file that fails any check is not used (the fetcher asks the server again).
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "polmap/tiles/localization_tile.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::loc {

/// First line of every cache file.
inline constexpr std::string_view kTileCacheFileTag = "PMTC1";
/// Longest header (tag line to the empty line, inclusive) a decoder looks at.
inline constexpr std::size_t kMaxTileCacheHeaderBytes = 1024;
/// Longest ETag stored (the fetcher refuses answers with longer ones).
inline constexpr std::size_t kMaxTileCacheEtagBytes = 256;

/// One answer of the server as stored on disk.
struct TileCacheRecord {
  int http_status = 200;             ///< 200, 204 (covered, no landmarks) or 404 (outside)
  std::string etag;                  ///< as sent by the server, quotes included
  std::uint64_t header_version = 0;  ///< X-Polmap-Map-Version of the answer (0: none)
  double fetched_unix_s = 0.0;       ///< last time the server confirmed the answer
  std::string payload;               ///< the encoded tile (200 only; empty for 204/404)
};

/// Outcome of decode_tile_cache_file.
enum class TileCacheStatus {
  Ok,
  TooLarge,           ///< payload larger than the caller's limit
  NotACacheFile,      ///< first line is not kTileCacheFileTag
  Truncated,          ///< ends inside the header, or fewer payload bytes than `size`
  Malformed,          ///< bad header line or value, missing/duplicate line, trailing bytes
  UnsupportedStatus,  ///< an HTTP status other than 200, 204, 404
  BadPayload,         ///< 200 payload that does not decode, or a 204/404 with a payload
  WrongKey,           ///< `key` line or the decoded tile's key is not the requested key
};

/// Name of a status ("ok", "too_large", ...), for logs.
[[nodiscard]] std::string_view to_string(TileCacheStatus status);

/// What decode_tile_cache_file found.
struct TileCacheDecodeResult {
  TileCacheStatus status = TileCacheStatus::Malformed;
  std::string message;     ///< what is wrong, with the byte offset where known (empty if ok)
  TileCacheRecord record;  ///< the stored answer (valid only if ok())
  /// The tile: the decoded payload (200), or a tile of the requested key without
  /// landmarks and map_version = record.header_version (204/404). Valid only if ok().
  tiles::LocalizationTile tile;
  [[nodiscard]] bool ok() const { return status == TileCacheStatus::Ok; }
};

/// The file's bytes for `record` as the answer for `key` (with `key` and `size` lines).
/// Throws ValidationError for a record the format cannot hold or a reader would refuse:
/// a status other than 200/204/404, an ETag longer than kMaxTileCacheEtagBytes or with
/// control characters, a non-finite or negative fetch time, a payload on 204/404, an
/// invalid key.
[[nodiscard]] std::string encode_tile_cache_file(const TileCacheRecord& record,
                                                 const tiles::TileKey& key);

/// Decodes a cache file read for `key`. Never throws for bad bytes (the status says what
/// is wrong); a payload over `max_payload_bytes` is TooLarge. Decoding an encoded record
/// gives it back exactly (fetched_unix_s included).
[[nodiscard]] TileCacheDecodeResult decode_tile_cache_file(std::string_view bytes,
                                                           const tiles::TileKey& key,
                                                           std::size_t max_payload_bytes = 4u
                                                                                           << 20);

}  // namespace polmap::loc
