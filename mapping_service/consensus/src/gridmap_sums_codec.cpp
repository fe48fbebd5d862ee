// Stored sum tiles of the merged gridmap (layout in gridmap_sums_codec.hpp).
#include "polmap/mapping_service/gridmap_sums_codec.hpp"

#include <zlib.h>

#include <bit>
#include <cmath>
#include <cstring>

#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {
constexpr char kMagic[4] = {'P', 'M', 'G', 'S'};
constexpr std::uint8_t kVersion = 1;
constexpr std::size_t kHeader = 8;
constexpr int kChunks = kSumChunksPerSide * kSumChunksPerSide;
constexpr std::size_t kChunkArea = static_cast<std::size_t>(kSumChunkCells) * kSumChunkCells;

[[noreturn]] void bad(std::string_view source, const std::string& what) {
  throw FormatError(std::string(source) + ": " + what);
}
}  // namespace

std::string encode_gridmap_sum_tile(const GridmapSumTile& tile) {
  const std::size_t floats = static_cast<std::size_t>(tile.planes()) * kChunkArea;
  std::uint16_t mask = 0;
  std::string raw;
  for (int c = 0; c < kChunks; ++c) {
    const float* ch = tile.chunk(c);
    if (ch == nullptr) continue;
    mask = static_cast<std::uint16_t>(mask | (1U << c));
    const std::size_t base = raw.size();
    raw.resize(base + floats * 4);
    const auto* bytes = reinterpret_cast<const unsigned char*>(ch);
    for (std::size_t i = 0; i < floats; ++i) {
      for (std::size_t b = 0; b < 4; ++b) {
        raw[base + b * floats + i] = static_cast<char>(bytes[i * 4 + b]);
      }
    }
  }
  std::string out(kMagic, 4);
  out.push_back(static_cast<char>(kVersion));
  out.push_back(static_cast<char>(tile.level()));
  out.push_back(static_cast<char>(mask & 0xFF));
  out.push_back(static_cast<char>(mask >> 8));
  if (raw.empty()) return out;
  uLongf packed_len = compressBound(static_cast<uLong>(raw.size()));
  std::string packed(packed_len, '\0');
  if (compress2(reinterpret_cast<Bytef*>(packed.data()), &packed_len,
                reinterpret_cast<const Bytef*>(raw.data()), static_cast<uLong>(raw.size()),
                6) != Z_OK) {
    throw Error("gridmap sum tile: zlib compress failed");
  }
  out.append(packed.data(), packed_len);
  return out;
}

GridmapSumTile decode_gridmap_sum_tile(std::string_view in, std::string_view source) {
  if (in.size() < kHeader) bad(source, "shorter than its 8-byte header");
  if (std::memcmp(in.data(), kMagic, 4) != 0) bad(source, "not a sum tile (magic)");
  if (static_cast<std::uint8_t>(in[4]) != kVersion) {
    bad(source, "unsupported version " + std::to_string(static_cast<std::uint8_t>(in[4])));
  }
  const auto level_code = static_cast<std::uint8_t>(in[5]);
  if (level_code > static_cast<std::uint8_t>(PolLevel::SingleHH)) {
    bad(source, "unknown polarimetric level " + std::to_string(level_code));
  }
  const auto level = static_cast<PolLevel>(level_code);
  const auto mask = static_cast<std::uint16_t>(static_cast<std::uint8_t>(in[6]) |
                                               (static_cast<std::uint8_t>(in[7]) << 8));
  GridmapSumTile tile(level);
  const std::size_t floats = static_cast<std::size_t>(tile.planes()) * kChunkArea;
  const std::size_t expected = static_cast<std::size_t>(std::popcount(mask)) * floats * 4;
  const std::string_view packed = in.substr(kHeader);
  if (expected == 0) {
    if (!packed.empty()) bad(source, "data after the header of an empty tile");
    return tile;
  }
  std::string raw(expected, '\0');
  uLongf raw_len = static_cast<uLongf>(expected);
  const int rc =
      uncompress(reinterpret_cast<Bytef*>(raw.data()), &raw_len,
                 reinterpret_cast<const Bytef*>(packed.data()), static_cast<uLong>(packed.size()));
  if (rc == Z_BUF_ERROR && raw_len == expected) {
    bad(source, "zlib stream inflates beyond the " + std::to_string(expected) +
                    " bytes its chunk mask announces, or is truncated");
  }
  if (rc != Z_OK) bad(source, "corrupt zlib stream (" + std::string(zError(rc)) + ")");
  if (raw_len != expected) {
    bad(source, "zlib stream inflates to " + std::to_string(raw_len) + " bytes, mask announces " +
                    std::to_string(expected));
  }
  std::size_t base = 0;
  for (int c = 0; c < kChunks; ++c) {
    if ((mask & (1U << c)) == 0) continue;
    float* ch = tile.chunk(c);
    auto* bytes = reinterpret_cast<unsigned char*>(ch);
    for (std::size_t i = 0; i < floats; ++i) {
      for (std::size_t b = 0; b < 4; ++b) {
        bytes[i * 4 + b] = static_cast<unsigned char>(raw[base + b * floats + i]);
      }
    }
    for (std::size_t i = 0; i < floats; ++i) {
      if (!std::isfinite(ch[i])) bad(source, "non-finite value in chunk " + std::to_string(c));
    }
    for (std::size_t i = 0; i < kChunkArea; ++i) {
      if (ch[i] < 0.0F || ch[kChunkArea + i] < 0.0F) {
        bad(source, "negative observation or hit count in chunk " + std::to_string(c));
      }
    }
    base += floats * 4;
  }
  return tile;
}

}  // namespace polmap::mapping
