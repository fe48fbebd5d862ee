#pragma once
/// @file store_tile_source.hpp
/// A loc::TileSource that reads the localization tiles of one published map
/// version straight from a mapping::MapStore (no HTTP). For evaluation and
/// tools running next to the store (leave-one-out studies, benchmarks): the
/// localizer sees exactly the bytes the server would send for
/// GET /v1/tiles/{z}/{x}/{y}?version=V, decoded by the same codec.
///
/// The client library itself never depends on mapping_service; this adapter
/// lives in tools/eval, which may use both.
///
/// Semantics (TileSource): a store read is local and fast, so tile() answers
/// synchronously: the decoded tile; an empty tile where the version has no
/// tile (the server's 204/404); never std::nullopt. Decoded tiles are kept in
/// memory. Thread-safe.
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>

#include "polmap/localization_client/tile_source.hpp"
#include "polmap/mapping_service/store.hpp"
#include "polmap/tiles/localization_tile.hpp"

namespace polmap::eval {

/// Counters of a StoreTileSource.
struct StoreTileSourceStats {
  std::uint64_t requests = 0;         ///< tile() calls
  std::uint64_t store_reads = 0;      ///< distinct tiles read from the store
  std::uint64_t empty_tiles = 0;      ///< of those, keys without a stored tile
  std::uint64_t bytes_read = 0;       ///< encoded payload bytes of the distinct tiles read
                                      ///< (what a vehicle would download once)
  std::uint64_t point_landmarks = 0;  ///< in the distinct tiles read
  std::uint64_t line_landmarks = 0;
};

class StoreTileSource final : public loc::TileSource {
 public:
  /// `store` must outlive the source. Throws NotFoundError if `version` is not
  /// a published version of the store.
  StoreTileSource(const mapping::MapStore& store, std::int64_t version);

  std::optional<tiles::LocalizationTile> tile(const tiles::TileKey& key) override;

  [[nodiscard]] std::int64_t version() const { return version_; }
  [[nodiscard]] StoreTileSourceStats stats() const;

 private:
  const mapping::MapStore& store_;
  std::int64_t version_;
  mutable std::mutex mutex_;
  std::map<tiles::TileKey, tiles::LocalizationTile> cache_;
  StoreTileSourceStats stats_;
};

}  // namespace polmap::eval
