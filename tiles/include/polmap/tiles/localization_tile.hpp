#pragma once
/// @file localization_tile.hpp
/// The localization tile: the consensus landmarks of one map version inside one
/// tile, as served to vehicles (GET /v1/tiles/{z}/{x}/{y}). Positions are metres
/// in LocalFrame(tile_center(key)) (x east, y north at the tile centre).
///
/// Wire format (schema/localization_tile.md): magic "PMLT", format version,
/// header, body of zigzag/LEB128 varints with coordinates quantized to a metric
/// grid (default 5 mm) and delta-coded in canonical order (points and lines
/// sorted by id), raw-deflate compressed when that is smaller, CRC-32 trailer.
/// Quantization error ≤ quantum/2 per axis (2.5 mm at the default). A typical
/// urban tile costs ≈ 8–10 bytes per point landmark and ≈ 15 bytes per
/// two-vertex line landmark.
///
/// Encoding is deterministic (independent of input order), so equal content
/// gives equal bytes and equal ETags.
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/schema/landmark.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::tiles {

/// Format version written by this build; the decoder reads exactly this version.
inline constexpr std::uint16_t kLocalizationTileFormatVersion = 1;

/// Media type of the encoded tile (HTTP Content-Type).
inline constexpr std::string_view kLocalizationTileMediaType = "application/vnd.polmap.tile";

/// Consensus landmarks of one tile of one map version.
struct LocalizationTile {
  TileKey key;
  std::uint64_t map_version = 0;
  std::vector<PointLandmark> points;  ///< metres in LocalFrame(tile_center(key))
  std::vector<LineLandmark> lines;    ///< metres in LocalFrame(tile_center(key))
};

/// Encoder settings. Defaults are what the server uses.
struct TileEncodeOptions {
  /// Grid step of positions. 5 mm keeps the quantization error (≤ 2.5 mm per
  /// axis) an order of magnitude below the map's own accuracy (landmark spread
  /// ≈ 5–10 cm, RTK 14 mm) while a coordinate delta inside a z16 tile still fits
  /// 3 varint bytes. Must be in [0.1 mm, 1 m].
  double quantum_m = 0.005;
  /// Grid step of spread_m (1 mm).
  double spread_quantum_m = 0.001;
  /// zlib compression level (0–9); raw deflate is used only when smaller.
  int compression_level = 9;
};

/// Largest |coordinate| the codec accepts: 100 km (tiles are < 1 km; a polyline
/// crossing the tile may reach further, but LocalFrame is only accurate to
/// ~10 km, so anything beyond 100 km is a caller bug).
inline constexpr double kMaxTileCoordinateM = 100000.0;

/// Encodes a tile. Throws ValidationError for non-finite or out-of-range
/// coordinates, invalid keys, lines with fewer than 2 vertices, or bad options.
[[nodiscard]] std::string encode_localization_tile(const LocalizationTile& tile,
                                                   const TileEncodeOptions& options = {});

/// Decodes a tile. Throws FormatError naming the problem (bad magic, unknown
/// version, truncated, trailing bytes, CRC mismatch, corrupt deflate stream,
/// malformed body) with the byte offset; `source` names the origin in messages
/// (e.g. a URL or file name). Points and lines come out sorted by id.
[[nodiscard]] LocalizationTile decode_localization_tile(std::string_view bytes,
                                                        const std::string& source = "tile");

}  // namespace polmap::tiles
