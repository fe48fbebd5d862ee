#pragma once
/// @file mvt.hpp
/// Mapbox Vector Tile 2.1 encoder (https://github.com/mapbox/vector-tile-spec/tree/master/2.1)
/// for GIS viewers (QGIS, MapLibre, OpenLayers). Features are given in geodetic
/// coordinates and projected into the tile's Web-Mercator pixel space (extent
/// 4096 by default, y down). Points outside the buffered tile are dropped,
/// lines are clipped segment by segment to the buffered tile (a line leaving
/// and re-entering becomes a multi-linestring), polygons are clipped
/// (Sutherland–Hodgman) and their rings oriented as the spec requires
/// (exterior clockwise in tile pixel space, interiors counter-clockwise).
/// Features near the antimeridian are shifted by ±360° to the tile's side.
#include <cstdint>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "polmap/schema/geo.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::tiles {

/// Media type of an encoded MVT (HTTP Content-Type).
inline constexpr std::string_view kMvtMediaType = "application/vnd.mapbox-vector-tile";

/// An attribute value. MVT value types: string, double, sint64 (signed
/// integers), uint64, bool.
using MvtValue = std::variant<std::string, double, std::int64_t, std::uint64_t, bool>;

enum class MvtGeometryType : std::uint8_t { Point = 1, LineString = 2, Polygon = 3 };

/// One feature. Geometry by type:
///  - Point: every vertex of every part is one point (MultiPoint if > 1);
///  - LineString: each part is one linestring (≥ 2 vertices);
///  - Polygon: parts[0] is the exterior ring, the rest are holes (rings need
///    not repeat their first vertex).
struct MvtFeature {
  std::uint64_t id = 0;
  MvtGeometryType type = MvtGeometryType::Point;
  std::vector<std::vector<GeoPoint>> parts;
  std::vector<std::pair<std::string, MvtValue>> properties;
};

struct MvtLayer {
  std::string name;
  std::vector<MvtFeature> features;
};

struct MvtOptions {
  /// Tile extent in pixel units (spec default 4096).
  std::uint32_t extent = 4096;
  /// Geometry outside the tile is kept up to this many pixel units beyond the
  /// edges, so renderers draw lines and symbols continuous across tile borders.
  std::uint32_t buffer = 64;
  /// Layers that end up without features are omitted.
  bool skip_empty_layers = true;
};

/// Encodes the layers as one vector tile. Features whose geometry falls fully
/// outside the buffered tile are dropped. Throws ValidationError for an invalid
/// key, an empty layer name, duplicate layer names, or non-finite coordinates.
[[nodiscard]] std::string encode_mvt(const TileKey& key, const std::vector<MvtLayer>& layers,
                                     const MvtOptions& options = {});

/// Projects a geodetic point into the tile's pixel space (not rounded, not
/// clipped): (0,0) is the north-west corner, (extent, extent) the south-east.
/// Longitude is shifted by a multiple of 360° to the side of the tile.
struct PixelXY {
  double x = 0.0;
  double y = 0.0;
};
[[nodiscard]] PixelXY project_to_tile_pixels(const TileKey& key, double lat_deg, double lon_deg,
                                             std::uint32_t extent = 4096);

}  // namespace polmap::tiles
