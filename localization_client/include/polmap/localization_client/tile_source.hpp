#pragma once
/// @file tile_source.hpp
/// Where the Localizer gets map tiles from. The Localizer runs once per radar
/// frame and must never wait for the network, so tile() is non-blocking: it
/// answers from memory and, if the tile is not there yet, asks for it in the
/// background and returns std::nullopt (ask again next frame).
#include <map>
#include <mutex>
#include <optional>
#include <span>
#include <vector>

#include "polmap/schema/geo.hpp"
#include "polmap/tiles/localization_tile.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::loc {

class TileSource {
 public:
  virtual ~TileSource() = default;
  /// Non-blocking. The tile when available; a tile without landmarks for
  /// places the map covers without landmarks (HTTP 204) and for places outside
  /// the map (HTTP 404); std::nullopt while it is not available yet (being
  /// fetched, or the server is unreachable and the cache has no copy).
  /// A new map version shows up as a tile with different content (and
  /// map_version) under the same key.
  virtual std::optional<tiles::LocalizationTile> tile(const tiles::TileKey& key) = 0;
  /// Hint: these tiles will be needed soon (e.g. ahead of the predicted path).
  /// Non-blocking; default: ignored.
  virtual void prefetch(std::span<const tiles::TileKey> keys) { (void)keys; }
};

/// Tiles of zoom z intersecting the square of half-size radius_m around p.
[[nodiscard]] std::vector<tiles::TileKey> tiles_around(const GeoPoint& p, double radius_m,
                                                       int z = tiles::kLocalizationZoom);

/// A TileSource over tiles held in memory (tests, benchmarks, offline use
/// with tiles built in-process). Thread-safe; put() replaces a tile, e.g. to
/// simulate a new map version.
class InMemoryTileSource final : public TileSource {
 public:
  void put(tiles::LocalizationTile tile) {
    std::lock_guard lock(mutex_);
    const tiles::TileKey key = tile.key;
    tiles_[key] = std::move(tile);
  }
  std::optional<tiles::LocalizationTile> tile(const tiles::TileKey& key) override {
    std::lock_guard lock(mutex_);
    const auto it = tiles_.find(key);
    if (it == tiles_.end()) return tiles::LocalizationTile{key, 0, {}, {}};  // outside: empty
    return it->second;
  }

 private:
  std::mutex mutex_;
  std::map<tiles::TileKey, tiles::LocalizationTile> tiles_;
};

}  // namespace polmap::loc
