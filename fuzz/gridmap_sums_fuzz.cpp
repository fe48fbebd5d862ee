// Fuzzer: the merged gridmap's sum-tile decoder (gridmap_sums_codec.hpp; the bytes are the
// store's own, but a store file can be damaged or planted). Any input either throws
// FormatError naming the source or decodes to a tile with finite values and N >= 0 that
// re-encodes and decodes to the same bytes.
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "fuzz_seeds.hpp"
#include "polmap/mapping_service/gridmap_sums_codec.hpp"
#include "polmap/schema/errors.hpp"

using namespace polmap;
using namespace polmap::mapping;

#define FUZZ_CHECK(cond)                                                        \
  do {                                                                          \
    if (!(cond)) {                                                              \
      std::fprintf(stderr, "fuzz_gridmap_sums: invariant failed: %s\n", #cond); \
      std::abort();                                                             \
    }                                                                           \
  } while (0)

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    for (PolLevel level : {PolLevel::Full, PolLevel::DualHHVV, PolLevel::SingleRR}) {
      GridmapSumTile t(level);
      std::vector<double> v(static_cast<std::size_t>(t.planes()), 1.5);
      for (int i = 0; i < 200; ++i) t.add((i * 37) % 256, (i * 11) % 256, 1.0 + i, v.data());
      fuzz::write_seed(dir, "level" + std::to_string(static_cast<int>(level)) + ".bin",
                       encode_gridmap_sum_tile(t));
    }
    fuzz::write_seed(dir, "empty.bin", encode_gridmap_sum_tile(GridmapSumTile(PolLevel::Full)));
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  std::string again;
  try {
    const GridmapSumTile t = decode_gridmap_sum_tile(bytes, "fuzz tile");
    for (int c = 0; c < kSumChunksPerSide * kSumChunksPerSide; ++c) {
      const float* ch = t.chunk(c);
      if (ch == nullptr) continue;
      for (int i = 0; i < t.planes() * kSumChunkCells * kSumChunkCells; ++i) {
        FUZZ_CHECK(std::isfinite(ch[i]));
      }
      for (int i = 0; i < kSumChunkCells * kSumChunkCells; ++i) FUZZ_CHECK(ch[i] >= 0.0F);
    }
    again = encode_gridmap_sum_tile(t);
  } catch (const FormatError& e) {
    FUZZ_CHECK(std::string_view(e.what()).find("fuzz tile") != std::string_view::npos);
    return 0;
  }
  FUZZ_CHECK(encode_gridmap_sum_tile(decode_gridmap_sum_tile(again)) == again);
  return 0;
}
