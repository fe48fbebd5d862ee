#pragma once
/// @file gridmap_sums_codec.hpp
/// Bytes of a stored sum tile of the merged gridmap (gridmap_sums.hpp), as the store
/// keeps them (table gridmap_sums). Lossless: the sums are added to again and again, so
/// a lossy code would drift.
///
/// Layout (little endian):
///   "PMGS" | version u8 (= 1) | level u8 (PolLevel) | chunk mask u16 (bit c: chunk c,
///   row-major 4 × 4, present) | zlib stream
/// The zlib stream inflates to exactly popcount(mask) × planes × 4096 × 4 bytes: for each
/// present chunk in ascending order, its planes × 4096 float32 values (plane-major, as
/// GridmapSumTile::chunk) byte-shuffled (all first bytes, then all second bytes, ...),
/// which lets deflate see the slowly varying exponents: 3–5× smaller than plain floats.
///
/// The decoder checks everything before use: magic, version, level, the exact inflated
/// size (the output buffer is that size, so a stream cannot inflate beyond it), and that
/// every value is finite with N >= 0 and hits >= 0. Errors are FormatError naming `source`.
#include <string>
#include <string_view>

#include "polmap/mapping_service/gridmap_sums.hpp"

namespace polmap::mapping {

/// Encodes a sum tile (an empty tile encodes to the 8-byte header with mask 0 and an
/// empty zlib stream).
[[nodiscard]] std::string encode_gridmap_sum_tile(const GridmapSumTile& tile);

/// Decodes bytes written by encode_gridmap_sum_tile. Throws FormatError (with `source`
/// in the message) on anything else.
[[nodiscard]] GridmapSumTile decode_gridmap_sum_tile(std::string_view bytes,
                                                     std::string_view source = "gridmap sum tile");

}  // namespace polmap::mapping
