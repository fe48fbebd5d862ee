// Fuzzer: the parsers of request parameters and headers (tile keys, bbox, If-None-Match,
// Accept-Encoding, integers). None may crash; what parses must be in range.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "fuzz_seeds.hpp"
#include "http_util.hpp"
#include "polmap/tiles/tile_key.hpp"

using namespace polmap;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    fuzz::write_seed(dir, "key", "16/34567/22222");
    fuzz::write_seed(dir, "bbox", "9.1,48.7,9.2,48.8");
    fuzz::write_seed(dir, "inm", "W/\"abc\", \"def\"");
    fuzz::write_seed(dir, "ae", "gzip;q=0.5, br, *;q=0");
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view s(reinterpret_cast<const char*>(data), size);
  if (const auto k = tiles::parse_tile_key(s)) {
    if (k->z < 0 || k->z > 24 || k->x < 0 || k->y < 0 || k->x >= (1 << k->z) ||
        k->y >= (1 << k->z)) {
      std::abort();
    }
  }
  if (const auto b = mapping::http::parse_bbox(s)) {
    if (!(std::abs(b->min_lat_deg) <= 90 && std::abs(b->max_lat_deg) <= 90 &&
          std::abs(b->min_lon_deg) <= 180 && std::abs(b->max_lon_deg) <= 180)) {
      std::abort();
    }
  }
  (void)mapping::http::if_none_match_matches(s, "\"0123456789abcdef\"");
  (void)mapping::http::accepts_gzip(s);
  (void)mapping::http::parse_int(s);
  (void)mapping::http::escape_for_log(s, 64);
  return 0;
}
