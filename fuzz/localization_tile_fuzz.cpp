// Fuzzer: the localization tile decoder (bytes from a server, or from the client's disk
// cache). Whatever decodes must have finite coordinates within the codec's bound, and
// re-encoding it must decode to the same tile (decode -> encode -> decode).
#include <cmath>
#include <cstdint>
#include <cstdlib>

#include "fuzz_seeds.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/tiles/localization_tile.hpp"

using namespace polmap;

namespace {

bool bounded(const Eigen::Vector2d& p) {
  return std::isfinite(p.x()) && std::isfinite(p.y()) &&
         std::abs(p.x()) <= tiles::kMaxTileCoordinateM + 1.0 &&
         std::abs(p.y()) <= tiles::kMaxTileCoordinateM + 1.0;
}

bool same(const tiles::LocalizationTile& a, const tiles::LocalizationTile& b) {
  if (!(a.key == b.key) || a.map_version != b.map_version || a.points.size() != b.points.size() ||
      a.lines.size() != b.lines.size()) {
    return false;
  }
  for (std::size_t i = 0; i < a.points.size(); ++i) {
    if (a.points[i].id != b.points[i].id ||
        (a.points[i].position_m - b.points[i].position_m).norm() > 1e-9) {
      return false;
    }
  }
  for (std::size_t i = 0; i < a.lines.size(); ++i) {
    if (a.lines[i].id != b.lines[i].id ||
        a.lines[i].polyline_m.size() != b.lines[i].polyline_m.size()) {
      return false;
    }
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    tiles::LocalizationTile t;
    t.key = {16, 34567, 22222};
    t.map_version = 7;
    for (int i = 0; i < 20; ++i) {
      PointLandmark p;
      p.id = 1000 + i;
      p.position_m = {3.0 * i - 30.0, 1.5 * i};
      p.support_drives = 3;
      p.spread_m = 0.05;
      t.points.push_back(p);
    }
    LineLandmark l;
    l.id = 5;
    l.polyline_m = {{0.0, 0.0}, {20.0, 1.0}, {40.0, 3.0}};
    t.lines.push_back(l);
    fuzz::write_seed(dir, "tile.bin", tiles::encode_localization_tile(t));
    t.points.clear();
    t.lines.clear();
    fuzz::write_seed(dir, "empty.bin", tiles::encode_localization_tile(t));
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  tiles::LocalizationTile t;
  try {
    t = tiles::decode_localization_tile(std::string_view(reinterpret_cast<const char*>(data), size),
                                        "fuzz");
  } catch (const FormatError&) {
    return 0;
  }
  for (const auto& p : t.points) {
    if (!bounded(p.position_m)) std::abort();
  }
  for (const auto& l : t.lines) {
    if (l.polyline_m.size() < 2) std::abort();
    for (const auto& v : l.polyline_m) {
      if (!bounded(v)) std::abort();
    }
  }
  std::string again;
  try {
    again = tiles::encode_localization_tile(t);
  } catch (const ValidationError&) {
    return 0;  // e.g. a key the encoder refuses; the decoder accepted it, which is allowed
  }
  if (!same(tiles::decode_localization_tile(again, "re-encoded"), t)) std::abort();
  return 0;
}
