// Fuzzer: the tile cache-file decoder (bytes from the client's own disk, which may be torn,
// corrupt or written by anything). Rejections carry a message; whatever decodes is a
// record the encoder accepts, for the requested key, and re-encoding it must decode to
// the same record and tile and give the same bytes again (decode -> encode -> decode).
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "fuzz_seeds.hpp"
#include "polmap/localization_client/tile_cache_file.hpp"
#include "polmap/schema/errors.hpp"

using namespace polmap;
using loc::TileCacheDecodeResult;
using loc::TileCacheRecord;

namespace {

const tiles::TileKey kKey{16, 34567, 22222};
/// Small, so that TooLarge is reachable by the fuzzer.
constexpr std::size_t kMaxPayload = 4096;

#define FUZZ_CHECK(cond)                                                      \
  do {                                                                        \
    if (!(cond)) {                                                            \
      std::fprintf(stderr, "fuzz_tile_cache: invariant failed: %s\n", #cond); \
      std::abort();                                                           \
    }                                                                         \
  } while (0)

bool same(const TileCacheDecodeResult& a, const TileCacheDecodeResult& b) {
  const TileCacheRecord& x = a.record;
  const TileCacheRecord& y = b.record;
  if (x.http_status != y.http_status || x.etag != y.etag || x.header_version != y.header_version ||
      x.payload != y.payload) {
    return false;
  }
  // Bitwise: the encoder writes the shortest round-trip decimal.
  if (std::signbit(x.fetched_unix_s) != std::signbit(y.fetched_unix_s) ||
      x.fetched_unix_s != y.fetched_unix_s) {
    return false;
  }
  const tiles::LocalizationTile& s = a.tile;
  const tiles::LocalizationTile& t = b.tile;
  if (!(s.key == t.key) || s.map_version != t.map_version || s.points.size() != t.points.size() ||
      s.lines.size() != t.lines.size()) {
    return false;
  }
  for (std::size_t i = 0; i < s.points.size(); ++i) {
    if (s.points[i].id != t.points[i].id || s.points[i].position_m != t.points[i].position_m) {
      return false;
    }
  }
  for (std::size_t i = 0; i < s.lines.size(); ++i) {
    if (s.lines[i].id != t.lines[i].id || s.lines[i].polyline_m != t.lines[i].polyline_m) {
      return false;
    }
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    tiles::LocalizationTile t;
    t.key = kKey;
    t.map_version = 7;
    for (int i = 0; i < 12; ++i) {
      PointLandmark p;
      p.id = 1000 + i;
      p.position_m = {3.0 * i - 30.0, 1.5 * i};
      t.points.push_back(p);
    }
    LineLandmark l;
    l.id = 5;
    l.polyline_m = {{0.0, 0.0}, {20.0, 1.0}, {40.0, 3.0}};
    t.lines.push_back(l);
    TileCacheRecord r;
    r.http_status = 200;
    r.etag = "\"v7-1f3a\"";
    r.header_version = 7;
    r.fetched_unix_s = 1712345678.125;
    r.payload = tiles::encode_localization_tile(t);
    fuzz::write_seed(dir, "tile_200.pmtc", loc::encode_tile_cache_file(r, kKey));
    r.http_status = 204;
    r.etag.clear();
    r.payload.clear();
    fuzz::write_seed(dir, "tile_204.pmtc", loc::encode_tile_cache_file(r, kKey));
    r.http_status = 404;
    r.header_version = 0;
    fuzz::write_seed(dir, "tile_404.pmtc", loc::encode_tile_cache_file(r, kKey));
    // The previous writer's layout: no key and size lines, six-decimal fetch time.
    fuzz::write_seed(dir, "legacy_200.pmtc",
                     "PMTC1\nstatus 200\netag \"v7\"\nversion 7\nfetched 1712345678.250000\n\n" +
                         tiles::encode_localization_tile(t));
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  const TileCacheDecodeResult r = loc::decode_tile_cache_file(bytes, kKey, kMaxPayload);
  if (!r.ok()) {
    FUZZ_CHECK(!r.message.empty());
    return 0;
  }
  const TileCacheRecord& rec = r.record;
  FUZZ_CHECK(r.message.empty());
  FUZZ_CHECK(rec.http_status == 200 || rec.http_status == 204 || rec.http_status == 404);
  FUZZ_CHECK(rec.etag.size() <= loc::kMaxTileCacheEtagBytes);
  FUZZ_CHECK(std::isfinite(rec.fetched_unix_s) && rec.fetched_unix_s >= 0.0);
  FUZZ_CHECK(rec.payload.size() <= kMaxPayload);
  FUZZ_CHECK(r.tile.key == kKey);
  if (rec.http_status == 200) {
    FUZZ_CHECK(!rec.payload.empty());
  } else {
    FUZZ_CHECK(rec.payload.empty() && r.tile.points.empty() && r.tile.lines.empty());
    FUZZ_CHECK(r.tile.map_version == rec.header_version);
  }
  std::string again;
  try {
    again = loc::encode_tile_cache_file(rec, kKey);
  } catch (const ValidationError& e) {
    std::fprintf(stderr, "fuzz_tile_cache: decoded record not encodable: %s\n", e.what());
    std::abort();
  }
  const TileCacheDecodeResult r2 = loc::decode_tile_cache_file(again, kKey, kMaxPayload);
  FUZZ_CHECK(r2.ok());
  FUZZ_CHECK(same(r, r2));
  FUZZ_CHECK(loc::encode_tile_cache_file(r2.record, kKey) == again);
  return 0;
}
