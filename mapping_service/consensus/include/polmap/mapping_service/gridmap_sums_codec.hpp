#pragma once
/// @file gridmap_sums_codec.hpp
/// Bytes of a stored sum tile of the merged gridmap (gridmap_sums.hpp), as the store
/// keeps them (table gridmap_sums). Lossless: the sums are added to again and again, so
/// a lossy code would drift.
///
/// Layout (little endian):
///   "PMGS" | version u8 (= 1) | level u8 (PolLevel) | chunk mask u16 (bit c: chunk c,
///   row-major 4 × 4, present) | one zstd frame (level 3, content size
///   and checksum)
/// The frame decompresses to exactly popcount(mask) × planes × 4096 × 4 bytes: for each
/// present chunk in ascending order, its planes × 4096 float32 values (plane-major, as
/// GridmapSumTile::chunk) byte-shuffled (all first bytes, then all second bytes, ...),
/// which lets the compressor see the slowly varying exponents. zstd rather than zlib: a
/// map build rewrites every tile a drive touches, and zlib's deflate/adler32 took a third
/// of a merged-gridmap build.
///
/// The decoder checks everything before use: magic, version, level, the frame's declared
/// size against the mask (the output buffer is that size, so a frame cannot decompress
/// beyond it), that the frame is the whole rest with a matching checksum, and that
/// every value is finite with N >= 0 and hits >= 0. Errors are FormatError naming `source`.
#include <string>
#include <string_view>

#include "polmap/mapping_service/gridmap_sums.hpp"

namespace polmap::mapping {

/// Encodes a sum tile (an empty tile encodes to the 8-byte header with mask 0 and no
/// frame).
[[nodiscard]] std::string encode_gridmap_sum_tile(const GridmapSumTile& tile);

/// Decodes bytes written by encode_gridmap_sum_tile. Throws FormatError (with `source`
/// in the message) on anything else.
[[nodiscard]] GridmapSumTile decode_gridmap_sum_tile(std::string_view bytes,
                                                     std::string_view source = "gridmap sum tile");

}  // namespace polmap::mapping
