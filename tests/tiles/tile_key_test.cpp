#include "polmap/tiles/tile_key.hpp"

#include <gtest/gtest.h>

#include <GeographicLib/Geodesic.hpp>
#include <cmath>
#include <random>
#include <set>

#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/localization_tile.hpp"

namespace polmap::tiles {
namespace {

double geodesic_m(const GeoPoint& a, const GeoPoint& b) {
  double s12 = 0;
  GeographicLib::Geodesic::WGS84().Inverse(a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg, s12);
  return s12;
}

TEST(TileKey, KnownTiles) {
  // Values from the OSM slippy-map formula (independent Python implementation).
  EXPECT_EQ(tile_at(48.858093, 2.294694, 16), (TileKey{16, 33185, 22545}));     // Eiffel Tower
  EXPECT_EQ(tile_at(-33.856784, 151.215297, 16), (TileKey{16, 60295, 39325}));  // Sydney
  EXPECT_EQ(tile_at(64.1466, -21.9426, 16), (TileKey{16, 28773, 17416}));       // Reykjavik
  EXPECT_EQ(tile_at(48.4, 9.98, 16), (TileKey{16, 34584, 22672}));              // Ulm
  EXPECT_EQ(tile_at(-16.5, 179.9999, 16), (TileKey{16, 65535, 35814}));         // Fiji
  EXPECT_EQ(tile_at(0.0, 0.0, 0), (TileKey{0, 0, 0}));
  EXPECT_EQ(tile_at(0.0, 0.0, 1), (TileKey{1, 1, 1}));
  EXPECT_EQ(tile_at(1e-9, -1e-9, 1), (TileKey{1, 0, 0}));
}

TEST(TileKey, WrapsLongitudeAndClampsLatitude) {
  EXPECT_EQ(tile_at(10.0, 180.0, 16), tile_at(10.0, -180.0, 16));
  EXPECT_EQ(tile_at(10.0, 180.0, 16).x, 0);
  EXPECT_EQ(tile_at(10.0, 370.0, 10), tile_at(10.0, 10.0, 10));
  EXPECT_EQ(tile_at(10.0, -190.0, 10), tile_at(10.0, 170.0, 10));
  EXPECT_EQ(tile_at(89.9, 0.0, 16).y, 0);
  EXPECT_EQ(tile_at(-90.0, 0.0, 16).y, (1 << 16) - 1);
}

TEST(TileKey, BoundsAndCentre) {
  const GeoBox world = tile_bounds({0, 0, 0});
  EXPECT_DOUBLE_EQ(world.min_lon_deg, -180.0);
  EXPECT_DOUBLE_EQ(world.max_lon_deg, 180.0);
  EXPECT_NEAR(world.max_lat_deg, kMaxMercatorLatDeg, 1e-12);
  EXPECT_NEAR(world.min_lat_deg, -kMaxMercatorLatDeg, 1e-12);
  const TileKey k{16, 33185, 22545};
  const GeoBox b = tile_bounds(k);
  EXPECT_TRUE(b.contains(48.858093, 2.294694));
  const GeoPoint c = tile_center(k);
  EXPECT_TRUE(b.contains(c.lat_deg, c.lon_deg));
  EXPECT_EQ(tile_at(c.lat_deg, c.lon_deg, 16), k);
  EXPECT_DOUBLE_EQ(c.lon_deg, 0.5 * (b.min_lon_deg + b.max_lon_deg));
  // Mercator centre: slightly poleward of the latitude midpoint in the northern hemisphere.
  EXPECT_GT(c.lat_deg, 0.5 * (b.min_lat_deg + b.max_lat_deg));
  EXPECT_LT(c.lat_deg - 0.5 * (b.min_lat_deg + b.max_lat_deg), 1e-5);
}

TEST(TileKey, TileSizeAtLocalizationZoom) {
  EXPECT_NEAR(tile_width_m(tile_at(0.0, 0.0, kLocalizationZoom)), 611.5, 0.5);
  EXPECT_NEAR(tile_width_m(tile_at(48.5, 10.0, kLocalizationZoom)), 405.8, 1.0);
  EXPECT_NEAR(tile_width_m(tile_at(60.0, 10.0, kLocalizationZoom)), 306.3, 1.0);
  // Ground size of the z16 tile measured by geodesics agrees with tile_width_m.
  const TileKey k = tile_at(48.5, 10.0, kLocalizationZoom);
  const GeoBox b = tile_bounds(k);
  const double mid = 0.5 * (b.min_lat_deg + b.max_lat_deg);
  EXPECT_NEAR(geodesic_m({mid, b.min_lon_deg}, {mid, b.max_lon_deg}), tile_width_m(k), 0.5);
}

TEST(TileKey, NeighboursShareEdgesExactly) {
  std::mt19937_64 rng(1);
  std::uniform_int_distribution<int> xy(1, (1 << 16) - 2);
  for (int i = 0; i < 2000; ++i) {
    const TileKey k{16, xy(rng), xy(rng)};
    const GeoBox b = tile_bounds(k);
    EXPECT_EQ(b.max_lon_deg, tile_bounds({16, k.x + 1, k.y}).min_lon_deg);
    EXPECT_EQ(b.min_lon_deg, tile_bounds({16, k.x - 1, k.y}).max_lon_deg);
    EXPECT_EQ(b.min_lat_deg, tile_bounds({16, k.x, k.y + 1}).max_lat_deg);
    EXPECT_EQ(b.max_lat_deg, tile_bounds({16, k.x, k.y - 1}).min_lat_deg);
    // Parent and children edges coincide too.
    const GeoBox p = tile_bounds(parent(k));
    const auto ch = children(k);
    EXPECT_EQ(tile_bounds(ch[0]).max_lat_deg, b.max_lat_deg);
    EXPECT_EQ(tile_bounds(ch[0]).min_lon_deg, b.min_lon_deg);
    EXPECT_EQ(tile_bounds(ch[3]).min_lat_deg, b.min_lat_deg);
    EXPECT_EQ(tile_bounds(ch[3]).max_lon_deg, b.max_lon_deg);
    if (k.x % 2 == 0) {
      EXPECT_EQ(p.min_lon_deg, b.min_lon_deg);
    }
    if (k.y % 2 == 0) {
      EXPECT_EQ(p.max_lat_deg, b.max_lat_deg);
    }
    for (const TileKey& c : ch) EXPECT_EQ(parent(c), k);
  }
  // Across the antimeridian: the last column's eastern edge is +180, the first's western -180.
  EXPECT_EQ(tile_bounds({16, (1 << 16) - 1, 100}).max_lon_deg, 180.0);
  EXPECT_EQ(neighbour({16, (1 << 16) - 1, 100}, 1, 0), (TileKey{16, 0, 100}));
  EXPECT_EQ(neighbour({16, 0, 100}, -1, 0), (TileKey{16, (1 << 16) - 1, 100}));
  EXPECT_EQ(neighbour({16, 5, 0}, 0, -1), std::nullopt);
}

TEST(TileKey, RandomPointsLandInTheirTile) {
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> lat(-85.0, 85.0), lon(-180.0, 180.0);
  for (int i = 0; i < 5000; ++i) {
    const double la = lat(rng), lo = lon(rng);
    for (int z : {0, 5, 12, 16, 20, kMaxZoom}) {
      const TileKey k = tile_at(la, lo, z);
      ASSERT_TRUE(is_valid(k));
      const GeoBox b = tile_bounds(k);
      // Allow floating-point ties at edges (1e-9 deg ≈ 0.1 mm).
      EXPECT_GE(la, b.min_lat_deg - 1e-9);
      EXPECT_LE(la, b.max_lat_deg + 1e-9);
      EXPECT_GE(lo, b.min_lon_deg - 1e-9);
      EXPECT_LE(lo, b.max_lon_deg + 1e-9);
    }
  }
}

TEST(TileKey, TilesCovering) {
  const GeoBox box{48.39, 9.97, 48.41, 10.0};
  const auto tiles = tiles_covering(box, 16);
  const TileKey nw = tile_at(48.41, 9.97, 16), se = tile_at(48.39, 10.0, 16);
  ASSERT_EQ(tiles.size(), static_cast<std::size_t>((se.x - nw.x + 1) * (se.y - nw.y + 1)));
  EXPECT_EQ(tiles.front(), nw);
  EXPECT_EQ(tiles.back(), se);
  // Brute force: every tile in a generous window intersects the box iff it is listed.
  const std::set<TileKey> listed(tiles.begin(), tiles.end());
  for (int x = nw.x - 2; x <= se.x + 2; ++x) {
    for (int y = nw.y - 2; y <= se.y + 2; ++y) {
      const GeoBox b = tile_bounds({16, x, y});
      const bool strictly_intersects =
          b.min_lat_deg < box.max_lat_deg && b.max_lat_deg > box.min_lat_deg &&
          b.min_lon_deg < box.max_lon_deg && b.max_lon_deg > box.min_lon_deg;
      EXPECT_EQ(strictly_intersects, listed.count({16, x, y}) == 1) << x << "/" << y;
    }
  }
  // Antimeridian-crossing box: columns on both sides.
  const auto am = tiles_covering({-17.0, 179.99, -16.99, -179.99}, 16);
  std::set<int> cols;
  for (const auto& k : am) cols.insert(k.x);
  EXPECT_TRUE(cols.count(0) == 1 && cols.count((1 << 16) - 1) == 1);
  EXPECT_LT(cols.size(), 10u);
  // The whole world at z2.
  EXPECT_EQ(tiles_covering({-90, -180, 90, 180}, 2).size(), 16u);
}

TEST(TileKey, StringForm) {
  EXPECT_EQ(to_string(TileKey{16, 34584, 22672}), "16/34584/22672");
  EXPECT_EQ(parse_tile_key("16/34584/22672"), (TileKey{16, 34584, 22672}));
  for (const char* bad : {"", "16/1", "16/1/2/3", "a/1/2", "16/-1/2", "16/65536/0", "25/0/0",
                          "16/1/2 ", " 16/1/2", "16//2", "+1/0/0", "1/2/0"}) {
    EXPECT_EQ(parse_tile_key(bad), std::nullopt) << bad;
  }
}

TEST(TileKey, GeoBoxAntimeridian) {
  const GeoBox b{-10, 170, 10, -170};
  EXPECT_TRUE(b.contains(0, 175));
  EXPECT_TRUE(b.contains(0, -175));
  EXPECT_FALSE(b.contains(0, 0));
  EXPECT_TRUE(b.intersects({-1, -172, 1, -160}));
  EXPECT_FALSE(b.intersects({-1, -160, 1, 160}));
}

// The documented round-trip error: geodetic -> tile frame -> 5 mm codec grid -> geodetic,
// over random tiles worldwide, incl. tiles at the antimeridian and at UTM zone borders.
TEST(TileKey, RoundTripErrorThroughTileFrameAndCodec) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> lat(-85.0, 85.0), lon(-180.0, 180.0), u(0.0, 1.0);
  std::vector<double> lons;
  for (int i = 0; i < 300; ++i) lons.push_back(lon(rng));
  for (int zone = 0; zone < 60; ++zone) lons.push_back(-180.0 + 6.0 * zone + 1e-7);  // UTM borders
  lons.push_back(179.99999);
  lons.push_back(-180.0);
  double max_codec_err = 0.0, max_projection_err = 0.0;
  for (double lo : lons) {
    const TileKey k = tile_at(lat(rng), lo, kLocalizationZoom);
    const GeoBox b = tile_bounds(k);
    const LocalFrame frame(tile_center(k));
    LocalizationTile tile{k, 1, {}, {}};
    std::vector<GeoPoint> truth;
    for (int j = 0; j < 20; ++j) {
      const GeoPoint g{b.min_lat_deg + u(rng) * (b.max_lat_deg - b.min_lat_deg),
                       b.min_lon_deg + u(rng) * (b.max_lon_deg - b.min_lon_deg)};
      truth.push_back(g);
      const Eigen::Vector2d xy = frame.to_local(g);
      max_projection_err = std::max(max_projection_err, geodesic_m(frame.to_geo(xy), g));
      PointLandmark p;
      p.id = j;
      p.position_m = xy;
      tile.points.push_back(p);
    }
    const LocalizationTile back = decode_localization_tile(encode_localization_tile(tile));
    ASSERT_EQ(back.points.size(), truth.size());
    for (const PointLandmark& p : back.points) {
      max_codec_err = std::max(max_codec_err, geodesic_m(frame.to_geo(p.position_m), truth[p.id]));
    }
  }
  std::printf("round trip over %zu z16 tiles: projection only %.3g m, with 5 mm codec %.3g m\n",
              lons.size(), max_projection_err, max_codec_err);
  EXPECT_LT(max_projection_err, 1e-6);
  EXPECT_LT(max_codec_err, 0.0036);  // ≤ sqrt(2) × 2.5 mm plus scale error
}

}  // namespace
}  // namespace polmap::tiles
