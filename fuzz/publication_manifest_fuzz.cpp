// Fuzzer: the static publication's manifest.json and latest.json parsers (what a vehicle
// reads from a CDN or mirror; tiles/publication_manifest.hpp). Any input either throws
// FormatError naming the source or parses to keys inside their zoom's range, 64-digit
// hashes and safe paths, and re-encodes to a manifest that parses to the same encoding.
#include <cstdio>
#include <cstdlib>

#include "fuzz_seeds.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/tiles/publication_manifest.hpp"

using namespace polmap;
using namespace polmap::tiles;

#define FUZZ_CHECK(cond)                                                                \
  do {                                                                                  \
    if (!(cond)) {                                                                      \
      std::fprintf(stderr, "fuzz_publication_manifest: invariant failed: %s\n", #cond); \
      std::abort();                                                                     \
    }                                                                                   \
  } while (0)

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    PublicationManifest m;
    m.map_version = 7;
    m.created_at = "2026-12-03T12:00:00Z";
    m.key_id = "0123456789abcdef";
    m.bounds = GeoBox{48.7, 9.1, 48.8, 9.2};
    PublishedLayer l{"localization",
                     "loc/{z}/{x}/{y}.pmt",
                     "application/x-polmap-localization-tile",
                     16,
                     16,
                     {}};
    for (int i = 0; i < 3; ++i) {
      l.tiles.push_back({{16, 34000 + i, 22000},
                         std::string(64, static_cast<char>('a' + i)),
                         static_cast<std::uint64_t>(100 + i)});
    }
    m.layers.push_back(l);
    fuzz::write_seed(dir, "manifest.json", encode_publication_manifest(m));
    fuzz::write_seed(dir, "latest.json",
                     encode_publication_pointer({7, "v7-0123456789abcdef", std::string(64, 'f')}));
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  ManifestLimits lim;
  lim.max_bytes = 1U << 20;
  lim.max_tiles = 10'000;
  try {
    const PublicationManifest m = parse_publication_manifest(bytes, lim, "fuzz manifest");
    for (const auto& l : m.layers) {
      FUZZ_CHECK(l.path.find("..") == std::string::npos && !l.path.starts_with("/"));
      for (const auto& t : l.tiles) {
        FUZZ_CHECK(t.key.z >= l.min_zoom && t.key.z <= l.max_zoom);
        FUZZ_CHECK(t.key.x >= 0 && t.key.x < tiles_per_side(t.key.z));
        FUZZ_CHECK(t.key.y >= 0 && t.key.y < tiles_per_side(t.key.z));
        FUZZ_CHECK(t.sha256.size() == 64 && t.bytes >= 1);
      }
    }
    const std::string again = encode_publication_manifest(m);
    FUZZ_CHECK(encode_publication_manifest(parse_publication_manifest(again, lim)) == again);
  } catch (const FormatError& e) {
    FUZZ_CHECK(std::string_view(e.what()).find("fuzz manifest") != std::string_view::npos);
  }
  try {
    const PublicationPointer p = parse_publication_pointer(bytes, "fuzz pointer");
    FUZZ_CHECK(!p.dir.empty() && p.dir.find('/') == std::string::npos &&
               p.dir.find('.') == std::string::npos && p.manifest_sha256.size() == 64);
  } catch (const FormatError& e) {
    FUZZ_CHECK(std::string_view(e.what()).find("fuzz pointer") != std::string_view::npos);
  }
  return 0;
}
