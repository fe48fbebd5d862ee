#pragma once
/// @file tile_key.hpp
/// Tile keys and grid math of the XYZ Web-Mercator tile scheme (the scheme of
/// OSM slippy maps, Mapbox Vector Tiles and TileJSON): at zoom z the world
/// between ±85.0511° latitude is a 2^z × 2^z grid, x grows east from the
/// antimeridian (lon -180°), y grows south from the northern edge.
///
/// Localization tiles use the same keys as the GIS tiles, but their payload is
/// metric: positions are metres in LocalFrame(tile_center(key)) (local_frame.hpp),
/// a transverse Mercator frame centred on the tile. Because every tile brings its
/// own frame, the grid is seamless worldwide: there are no UTM zone borders, and
/// the antimeridian is an ordinary tile edge (tile x = 2^z - 1 neighbours x = 0).
///
/// Round-trip error geodetic -> tile frame -> geodetic: the transverse Mercator
/// projection itself round-trips to < 1e-9 m within a tile; the error that matters
/// is the quantization of the tile codec (localization_tile.hpp, 5 mm grid):
/// ≤ 2.5 mm per axis, ≤ 3.6 mm in the plane, measured by
/// tests/tiles/tile_key_test.cpp over random tiles worldwide (|lat| ≤ 85°, across
/// the antimeridian and UTM zone borders).
#include <array>
#include <compare>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/schema/geo.hpp"

namespace polmap::tiles {

/// Zoom level of localization tiles. A z16 tile spans 360°/2^16 = 0.0055° of
/// longitude, i.e. 611 m × cos(lat) on a side (611 m at the equator, 405 m at
/// 48.5° N, 306 m at 60° N). Why 16: the radar sees 80 m, so a vehicle needs
/// the tile it is in plus at most its 8 neighbours (a 3×3 block of ≈ 1.2–1.8 km
/// a side) — a few kB of payload per fetch and one request per ~0.5 km of route;
/// at z15 a block would be 4× the area (4× the bytes, mostly unused), at z17
/// a vehicle at 30 m/s crosses a tile every 5–10 s and tile requests dominate.
/// Tiles this small also keep the transverse Mercator scale error of the tile
/// frame below 1e-8 (negligible against the 5 mm quantization).
inline constexpr int kLocalizationZoom = 16;

/// Largest supported zoom: 2^24 tiles a side (≈ 2.4 m tiles at the equator);
/// keeps every coordinate computation exact in double and x/y within int32.
inline constexpr int kMaxZoom = 24;

/// Northern/southern limit of the Web-Mercator square: atan(sinh(pi)) in degrees.
inline constexpr double kMaxMercatorLatDeg = 85.0511287798066;

/// A tile of the XYZ scheme. Valid when 0 ≤ z ≤ kMaxZoom and 0 ≤ x, y < 2^z.
struct TileKey {
  int z = 0;
  int x = 0;
  int y = 0;
  friend auto operator<=>(const TileKey&, const TileKey&) = default;
};

/// A geodetic box in degrees. Boxes crossing the antimeridian have
/// min_lon_deg > max_lon_deg (e.g. 179.9 .. -179.9), as in GeoJSON bboxes.
struct GeoBox {
  double min_lat_deg = 0.0;
  double min_lon_deg = 0.0;
  double max_lat_deg = 0.0;
  double max_lon_deg = 0.0;

  [[nodiscard]] bool crosses_antimeridian() const { return min_lon_deg > max_lon_deg; }
  /// True if (lat, lon) is inside or on the border (antimeridian-aware).
  [[nodiscard]] bool contains(double lat_deg, double lon_deg) const;
  /// True if the boxes share at least a point (antimeridian-aware).
  [[nodiscard]] bool intersects(const GeoBox& other) const;
};

/// Number of tiles a side at zoom z (2^z).
[[nodiscard]] constexpr std::int64_t tiles_per_side(int z) { return std::int64_t{1} << z; }

/// True if z is in [0, kMaxZoom] and x, y are in [0, 2^z).
[[nodiscard]] bool is_valid(const TileKey& key);

/// The tile containing (lat, lon) at zoom z. Longitude is wrapped into
/// [-180, 180) (so 180° is tile x = 0); latitude is clamped to the Mercator
/// square (poles map to the first/last row). Precondition: 0 ≤ z ≤ kMaxZoom.
[[nodiscard]] TileKey tile_at(double lat_deg, double lon_deg, int z);

/// Geodetic bounds of a tile. Edges are functions of the integer edge index
/// only, so neighbouring tiles share their edges bit-exactly.
[[nodiscard]] GeoBox tile_bounds(const TileKey& key);

/// Geodetic centre of a tile: the centre of the tile in Web-Mercator space
/// (pixel (0.5, 0.5) of the tile), unprojected. This point is the origin of the
/// tile's LocalFrame; server and client compute it with this same function.
[[nodiscard]] GeoPoint tile_center(const TileKey& key);

/// All tiles of zoom z that intersect the box, row by row (y, then x).
/// Antimeridian-crossing boxes (min_lon > max_lon) give tiles on both sides.
/// Latitudes beyond the Mercator square are clamped.
[[nodiscard]] std::vector<TileKey> tiles_covering(const GeoBox& box, int z);

/// The tile of zoom z-1 containing this tile. Precondition: key.z > 0.
[[nodiscard]] TileKey parent(const TileKey& key);

/// The four tiles of zoom z+1 inside this tile (NW, NE, SW, SE).
/// Precondition: key.z < kMaxZoom.
[[nodiscard]] std::array<TileKey, 4> children(const TileKey& key);

/// Neighbour at offset (dx, dy) tiles; x wraps around the antimeridian,
/// std::nullopt beyond the northern/southern edge.
[[nodiscard]] std::optional<TileKey> neighbour(const TileKey& key, int dx, int dy);

/// "z/x/y".
[[nodiscard]] std::string to_string(const TileKey& key);

/// Parses "z/x/y" (decimal, no signs, no spaces); std::nullopt if malformed
/// or not a valid key.
[[nodiscard]] std::optional<TileKey> parse_tile_key(std::string_view s);

/// Web-Mercator coordinates in units of tiles at zoom z: x in [0, 2^z) from the
/// antimeridian eastward, y in [0, 2^z) from the northern edge southward.
/// Latitude is clamped to the Mercator square; longitude is not wrapped.
struct MercatorXY {
  double x = 0.0;
  double y = 0.0;
};
[[nodiscard]] MercatorXY to_mercator_tiles(double lat_deg, double lon_deg, int z);
/// Inverse of to_mercator_tiles.
[[nodiscard]] GeoPoint from_mercator_tiles(double x, double y, int z);

/// Approximate ground size of a tile's edge along the parallel through its
/// centre, metres (WGS84 radius of the parallel). For documentation and sizing.
[[nodiscard]] double tile_width_m(const TileKey& key);

}  // namespace polmap::tiles
