#pragma once
/// @file landmark_mvt.hpp
/// The landmark layers of the vector tiles (GET /v1/mvt and static publications): layer
/// "points" (Point, properties id, key, class, support_drives, spread_m, map_version) and
/// "lines" (LineString, id, key, support_drives, spread_m, map_version); feature ids are the
/// landmarks' stable keys. `key` repeats `id` as a decimal string: keys use 63 bits, and a
/// JavaScript viewer reads integers as doubles (exact to 2^53 only), so the console asks
/// GET /v1/maps/{v}/landmarks/{key} with the string.
#include <cstdint>
#include <nlohmann/json.hpp>

#include "polmap/mapping_service/store.hpp"
#include "polmap/tiles/mvt.hpp"

namespace polmap::mapping {

struct LandmarkMvtLayers {
  tiles::MvtLayer points{"points", {}};
  tiles::MvtLayer lines{"lines", {}};
};

/// The two layers for `landmarks` of map version `version`.
[[nodiscard]] LandmarkMvtLayers landmark_mvt_layers(const LandmarkSet& landmarks,
                                                    std::int64_t version);

/// TileJSON 3.0 `vector_layers` entries of the two landmark layers (ids, descriptions,
/// fields), what every TileJSON describing landmark tiles lists.
[[nodiscard]] nlohmann::json landmark_vector_layers_json();

/// A tile's bounds grown by `fraction` of its size on each side (clamped, not wrapped, at
/// the antimeridian): what to query so that geometry in the tile's buffer is drawn.
[[nodiscard]] tiles::GeoBox buffered_tile_bounds(const tiles::TileKey& key, double fraction);

}  // namespace polmap::mapping
