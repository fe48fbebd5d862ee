#include "polmap/tiles/tile_key.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <numbers>

#include "polmap/schema/errors.hpp"

namespace polmap::tiles {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

// Longitude of the western edge of column x (x may be 2^z: the eastern edge of the world).
// x / 2^z is exact in double, so equal edges of different zooms are bit-identical.
double edge_lon_deg(std::int64_t x, int z) {
  return static_cast<double>(x) / static_cast<double>(tiles_per_side(z)) * 360.0 - 180.0;
}

// Latitude of the northern edge of row y (y may be 2^z: the southern edge).
double edge_lat_deg(std::int64_t y, int z) {
  const double t = static_cast<double>(y) / static_cast<double>(tiles_per_side(z));
  return std::atan(std::sinh(std::numbers::pi * (1.0 - 2.0 * t))) / kDeg;
}

double wrap_lon_deg(double lon_deg) {
  if (lon_deg >= -180.0 && lon_deg < 180.0) return lon_deg;
  double l = std::fmod(lon_deg + 180.0, 360.0);
  if (l < 0) l += 360.0;
  return l - 180.0;
}

bool lon_in(double lon, double lo, double hi, bool crossing) {
  return crossing ? (lon >= lo || lon <= hi) : (lon >= lo && lon <= hi);
}

}  // namespace

bool GeoBox::contains(double lat_deg, double lon_deg) const {
  if (lat_deg < min_lat_deg || lat_deg > max_lat_deg) return false;
  return lon_in(lon_deg, min_lon_deg, max_lon_deg, crosses_antimeridian());
}

bool GeoBox::intersects(const GeoBox& o) const {
  if (o.max_lat_deg < min_lat_deg || o.min_lat_deg > max_lat_deg) return false;
  // Split each box into at most two non-crossing longitude intervals.
  auto intervals = [](const GeoBox& b) {
    std::vector<std::pair<double, double>> r;
    if (b.crosses_antimeridian()) {
      r.emplace_back(b.min_lon_deg, 180.0);
      r.emplace_back(-180.0, b.max_lon_deg);
    } else {
      r.emplace_back(b.min_lon_deg, b.max_lon_deg);
    }
    return r;
  };
  for (const auto& [a0, a1] : intervals(*this)) {
    for (const auto& [b0, b1] : intervals(o)) {
      if (a0 <= b1 && b0 <= a1) return true;
    }
  }
  return false;
}

bool is_valid(const TileKey& key) {
  if (key.z < 0 || key.z > kMaxZoom) return false;
  const std::int64_t n = tiles_per_side(key.z);
  return key.x >= 0 && key.x < n && key.y >= 0 && key.y < n;
}

MercatorXY to_mercator_tiles(double lat_deg, double lon_deg, int z) {
  const double n = static_cast<double>(tiles_per_side(z));
  const double lat = std::clamp(lat_deg, -kMaxMercatorLatDeg, kMaxMercatorLatDeg) * kDeg;
  const double x = (lon_deg + 180.0) / 360.0 * n;
  const double y = (1.0 - std::asinh(std::tan(lat)) / std::numbers::pi) / 2.0 * n;
  return {x, y};
}

GeoPoint from_mercator_tiles(double x, double y, int z) {
  const double n = static_cast<double>(tiles_per_side(z));
  const double lon = x / n * 360.0 - 180.0;
  const double lat = std::atan(std::sinh(std::numbers::pi * (1.0 - 2.0 * y / n))) / kDeg;
  return {lat, lon, 0.0};
}

TileKey tile_at(double lat_deg, double lon_deg, int z) {
  POLMAP_EXPECT(z >= 0 && z <= kMaxZoom);
  POLMAP_EXPECT(std::isfinite(lat_deg) && std::isfinite(lon_deg));
  const std::int64_t n = tiles_per_side(z);
  const MercatorXY m = to_mercator_tiles(lat_deg, wrap_lon_deg(lon_deg), z);
  const auto clamp_index = [n](double v) {
    return static_cast<int>(
        std::clamp<std::int64_t>(static_cast<std::int64_t>(std::floor(v)), 0, n - 1));
  };
  return {z, clamp_index(m.x), clamp_index(m.y)};
}

GeoBox tile_bounds(const TileKey& key) {
  POLMAP_EXPECT(is_valid(key));
  return {edge_lat_deg(key.y + 1, key.z), edge_lon_deg(key.x, key.z), edge_lat_deg(key.y, key.z),
          edge_lon_deg(key.x + 1, key.z)};
}

GeoPoint tile_center(const TileKey& key) {
  POLMAP_EXPECT(is_valid(key));
  return from_mercator_tiles(key.x + 0.5, key.y + 0.5, key.z);
}

std::vector<TileKey> tiles_covering(const GeoBox& box, int z) {
  POLMAP_EXPECT(z >= 0 && z <= kMaxZoom);
  POLMAP_EXPECT(box.min_lat_deg <= box.max_lat_deg);
  const TileKey nw = tile_at(box.max_lat_deg, box.min_lon_deg, z);
  const TileKey se = tile_at(box.min_lat_deg, box.max_lon_deg, z);
  // max_lon = 180 wraps to column 0; treat it as the eastern edge of the last column.
  int x_last = se.x;
  if (!box.crosses_antimeridian() && box.max_lon_deg >= 180.0) {
    x_last = static_cast<int>(tiles_per_side(z) - 1);
  }
  std::vector<int> columns;
  if (box.crosses_antimeridian() || x_last < nw.x) {
    for (int x = nw.x; x < tiles_per_side(z); ++x) columns.push_back(x);
    for (int x = 0; x <= x_last; ++x) columns.push_back(x);
  } else {
    for (int x = nw.x; x <= x_last; ++x) columns.push_back(x);
  }
  std::vector<TileKey> out;
  out.reserve(columns.size() * static_cast<std::size_t>(se.y - nw.y + 1));
  for (int y = nw.y; y <= se.y; ++y) {
    for (int x : columns) out.push_back({z, x, y});
  }
  return out;
}

TileKey parent(const TileKey& key) {
  POLMAP_EXPECT(is_valid(key) && key.z > 0);
  return {key.z - 1, key.x / 2, key.y / 2};
}

std::array<TileKey, 4> children(const TileKey& key) {
  POLMAP_EXPECT(is_valid(key) && key.z < kMaxZoom);
  const int z = key.z + 1, x = 2 * key.x, y = 2 * key.y;
  return {TileKey{z, x, y}, TileKey{z, x + 1, y}, TileKey{z, x, y + 1}, TileKey{z, x + 1, y + 1}};
}

std::optional<TileKey> neighbour(const TileKey& key, int dx, int dy) {
  POLMAP_EXPECT(is_valid(key));
  const std::int64_t n = tiles_per_side(key.z);
  const std::int64_t y = std::int64_t{key.y} + dy;
  if (y < 0 || y >= n) return std::nullopt;
  std::int64_t x = (std::int64_t{key.x} + dx) % n;
  if (x < 0) x += n;
  return TileKey{key.z, static_cast<int>(x), static_cast<int>(y)};
}

std::string to_string(const TileKey& key) {
  return std::to_string(key.z) + "/" + std::to_string(key.x) + "/" + std::to_string(key.y);
}

std::optional<TileKey> parse_tile_key(std::string_view s) {
  TileKey k;
  int* fields[3] = {&k.z, &k.x, &k.y};
  const char* p = s.data();
  const char* end = s.data() + s.size();
  for (int i = 0; i < 3; ++i) {
    if (p == end || *p < '0' || *p > '9') return std::nullopt;
    const auto [next, ec] = std::from_chars(p, end, *fields[i]);
    if (ec != std::errc{}) return std::nullopt;
    p = next;
    if (i < 2) {
      if (p == end || *p != '/') return std::nullopt;
      ++p;
    }
  }
  if (p != end || !is_valid(k)) return std::nullopt;
  return k;
}

double tile_width_m(const TileKey& key) {
  const GeoPoint c = tile_center(key);
  constexpr double a = 6378137.0;
  constexpr double f = 1.0 / 298.257223563;
  constexpr double e2 = f * (2.0 - f);
  const double s = std::sin(c.lat_deg * kDeg);
  const double parallel_radius = a * std::cos(c.lat_deg * kDeg) / std::sqrt(1.0 - e2 * s * s);
  return parallel_radius * (360.0 / static_cast<double>(tiles_per_side(key.z))) * kDeg;
}

}  // namespace polmap::tiles
