// Stored sum tiles of the merged gridmap (layout in gridmap_sums_codec.hpp).
#include "polmap/mapping_service/gridmap_sums_codec.hpp"

#include <zstd.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <memory>

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
  // With the frame checksum: a damaged tile is refused, not added to.
  std::unique_ptr<ZSTD_CCtx, decltype(&ZSTD_freeCCtx)> cctx(ZSTD_createCCtx(), &ZSTD_freeCCtx);
  if (!cctx) throw Error("gridmap sum tile: zstd context allocation failed");
  ZSTD_CCtx_setParameter(cctx.get(), ZSTD_c_compressionLevel, 3);
  ZSTD_CCtx_setParameter(cctx.get(), ZSTD_c_checksumFlag, 1);
  std::string packed(ZSTD_compressBound(raw.size()), '\0');
  const std::size_t n =
      ZSTD_compress2(cctx.get(), packed.data(), packed.size(), raw.data(), raw.size());
  if (ZSTD_isError(n)) {
    throw Error(std::string("gridmap sum tile: zstd compress failed: ") + ZSTD_getErrorName(n));
  }
  out.append(packed.data(), n);
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
  // One frame whose declared size is exactly what the mask announces; the output buffer is
  // that size, so no frame can decompress beyond it.
  const unsigned long long declared = ZSTD_getFrameContentSize(packed.data(), packed.size());
  if (declared == ZSTD_CONTENTSIZE_ERROR || declared == ZSTD_CONTENTSIZE_UNKNOWN) {
    bad(source, "not a zstd frame with a declared size");
  }
  if (declared != expected) {
    bad(source, "zstd frame inflates to " + std::to_string(declared) + " bytes, mask announces " +
                    std::to_string(expected));
  }
  const std::size_t frame = ZSTD_findFrameCompressedSize(packed.data(), packed.size());
  if (ZSTD_isError(frame) || frame != packed.size()) {
    bad(source, "zstd frame truncated or followed by other bytes");
  }
  std::string raw(expected, '\0');
  const std::size_t got = ZSTD_decompress(raw.data(), raw.size(), packed.data(), packed.size());
  if (ZSTD_isError(got)) {
    bad(source, std::string("corrupt zstd frame (") + ZSTD_getErrorName(got) + ")");
  }
  if (got != expected) {
    bad(source, "zstd frame inflates to " + std::to_string(got) + " bytes, mask announces " +
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
