#include "polmap/eval/store_tile_source.hpp"

#include <string>

#include "polmap/schema/errors.hpp"

namespace polmap::eval {

StoreTileSource::StoreTileSource(const mapping::MapStore& store, std::int64_t version)
    : store_(store), version_(version) {
  const auto info = store_.get_map_version(version);
  if (!info || info->status != mapping::MapVersionStatus::Published) {
    throw NotFoundError("map version " + std::to_string(version) +
                        " is not published in the store");
  }
}

std::optional<tiles::LocalizationTile> StoreTileSource::tile(const tiles::TileKey& key) {
  std::lock_guard lock(mutex_);
  ++stats_.requests;
  if (const auto it = cache_.find(key); it != cache_.end()) return it->second;
  ++stats_.store_reads;
  tiles::LocalizationTile t{key, static_cast<std::uint64_t>(version_), {}, {}};
  if (const auto stored = store_.get_tile(version_, mapping::TileLayer::Localization, key)) {
    stats_.bytes_read += stored->payload.size();
    t = tiles::decode_localization_tile(
        stored->payload,
        "store tile " + tiles::to_string(key) + " of version " + std::to_string(version_));
    stats_.point_landmarks += t.points.size();
    stats_.line_landmarks += t.lines.size();
  } else {
    ++stats_.empty_tiles;
  }
  return cache_.emplace(key, std::move(t)).first->second;
}

StoreTileSourceStats StoreTileSource::stats() const {
  std::lock_guard lock(mutex_);
  return stats_;
}

}  // namespace polmap::eval
