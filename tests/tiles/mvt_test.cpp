#include "polmap/tiles/mvt.hpp"

#include <gtest/gtest.h>

#include <map>
#include <protozero/pbf_reader.hpp>

#include "polmap/schema/errors.hpp"

namespace polmap::tiles {
namespace {

// A small independent MVT reader (spec 2.1) to check what the encoder wrote.
struct DecodedFeature {
  std::uint64_t id = 0;
  int type = 0;
  std::vector<std::pair<int, std::vector<std::pair<int, int>>>> commands;  // (cmd, points)
  std::map<std::string, MvtValue> props;
};
struct DecodedLayer {
  std::string name;
  std::uint32_t version = 0;
  std::uint32_t extent = 0;
  std::vector<DecodedFeature> features;
};

std::vector<DecodedLayer> decode(const std::string& data) {
  std::vector<DecodedLayer> out;
  protozero::pbf_reader tile(data);
  while (tile.next(3)) {
    protozero::pbf_reader layer = tile.get_message();
    DecodedLayer dl;
    std::vector<std::string> keys;
    std::vector<MvtValue> values;
    std::vector<std::pair<DecodedFeature, std::vector<std::uint32_t>>> raw;
    while (layer.next()) {
      switch (layer.tag()) {
        case 1:
          dl.name = layer.get_string();
          break;
        case 15:
          dl.version = layer.get_uint32();
          break;
        case 5:
          dl.extent = layer.get_uint32();
          break;
        case 3:
          keys.push_back(layer.get_string());
          break;
        case 4: {
          protozero::pbf_reader v = layer.get_message();
          while (v.next()) {
            switch (v.tag()) {
              case 1:
                values.emplace_back(v.get_string());
                break;
              case 3:
                values.emplace_back(v.get_double());
                break;
              case 5:
                values.emplace_back(v.get_uint64());
                break;
              case 6:
                values.emplace_back(v.get_sint64());
                break;
              case 7:
                values.emplace_back(v.get_bool());
                break;
              default:
                v.skip();
            }
          }
          break;
        }
        case 2: {
          protozero::pbf_reader f = layer.get_message();
          DecodedFeature df;
          std::vector<std::uint32_t> tags;
          std::vector<std::uint32_t> geom;
          while (f.next()) {
            switch (f.tag()) {
              case 1:
                df.id = f.get_uint64();
                break;
              case 2: {
                auto r = f.get_packed_uint32();
                tags.assign(r.begin(), r.end());
                break;
              }
              case 3:
                df.type = f.get_enum();
                break;
              case 4: {
                auto r = f.get_packed_uint32();
                geom.assign(r.begin(), r.end());
                break;
              }
              default:
                f.skip();
            }
          }
          int cx = 0, cy = 0;
          for (std::size_t i = 0; i < geom.size();) {
            const int cmd = static_cast<int>(geom[i] & 7), count = static_cast<int>(geom[i] >> 3);
            ++i;
            std::vector<std::pair<int, int>> pts;
            if (cmd != 7) {
              for (int k = 0; k < count; ++k) {
                const auto dx = static_cast<int>((geom[i] >> 1) ^ (~(geom[i] & 1) + 1));
                const auto dy = static_cast<int>((geom[i + 1] >> 1) ^ (~(geom[i + 1] & 1) + 1));
                i += 2;
                cx += dx;
                cy += dy;
                pts.emplace_back(cx, cy);
              }
            }
            df.commands.emplace_back(cmd, pts);
          }
          raw.emplace_back(df, tags);
          break;
        }
        default:
          layer.skip();
      }
    }
    for (auto& [df, tags] : raw) {
      for (std::size_t i = 0; i + 1 < tags.size(); i += 2) {
        df.props[keys.at(tags[i])] = values.at(tags[i + 1]);
      }
      dl.features.push_back(df);
    }
    out.push_back(dl);
  }
  return out;
}

TEST(Mvt, PointsLinesAndAttributes) {
  const TileKey key = tile_at(48.4, 9.98, 16);
  const GeoBox b = tile_bounds(key);
  const GeoPoint c = tile_center(key);
  MvtLayer points{"points", {}};
  points.features.push_back({7,
                             MvtGeometryType::Point,
                             {{c}},
                             {{"class", std::string("odd")},
                              {"support", std::uint64_t{5}},
                              {"spread_m", 0.04},
                              {"offset", std::int64_t{-3}},
                              {"permanent", true}}});
  points.features.push_back({8,
                             MvtGeometryType::Point,
                             {{{b.max_lat_deg, b.min_lon_deg}}},
                             {{"class", std::string("odd")}}});
  // Far away: dropped.
  points.features.push_back({9, MvtGeometryType::Point, {{{0.0, 0.0}}}, {}});
  MvtLayer lines{"lines", {}};
  // West -> east through the centre, extending well beyond the tile on both sides.
  lines.features.push_back({11,
                            MvtGeometryType::LineString,
                            {{{c.lat_deg, b.min_lon_deg - 0.01},
                              {c.lat_deg, c.lon_deg},
                              {c.lat_deg, b.max_lon_deg + 0.01}}},
                            {{"support", std::uint64_t{3}}}});
  MvtLayer empty{"trajectories", {}};
  const std::string bytes = encode_mvt(key, {points, lines, empty});
  const auto layers = decode(bytes);
  ASSERT_EQ(layers.size(), 2u);  // empty layer skipped
  EXPECT_EQ(layers[0].name, "points");
  EXPECT_EQ(layers[0].version, 2u);
  EXPECT_EQ(layers[0].extent, 4096u);
  ASSERT_EQ(layers[0].features.size(), 2u);
  const auto& f0 = layers[0].features[0];
  EXPECT_EQ(f0.id, 7u);
  EXPECT_EQ(f0.type, 1);
  ASSERT_EQ(f0.commands.size(), 1u);
  EXPECT_EQ(f0.commands[0].first, 1);
  EXPECT_EQ(f0.commands[0].second, (std::vector<std::pair<int, int>>{{2048, 2048}}));
  EXPECT_EQ(std::get<std::string>(f0.props.at("class")), "odd");
  EXPECT_EQ(std::get<std::uint64_t>(f0.props.at("support")), 5u);
  EXPECT_DOUBLE_EQ(std::get<double>(f0.props.at("spread_m")), 0.04);
  EXPECT_EQ(std::get<std::int64_t>(f0.props.at("offset")), -3);
  EXPECT_EQ(std::get<bool>(f0.props.at("permanent")), true);
  EXPECT_EQ(layers[0].features[1].commands[0].second, (std::vector<std::pair<int, int>>{{0, 0}}));
  // The line is clipped to the buffered extent [-64, 4160].
  const auto& l = layers[1].features[0];
  EXPECT_EQ(l.type, 2);
  ASSERT_EQ(l.commands.size(), 2u);
  EXPECT_EQ(l.commands[0].first, 1);
  EXPECT_EQ(l.commands[1].first, 2);
  EXPECT_EQ(l.commands[0].second.front().first, -64);
  EXPECT_EQ(l.commands[1].second.back().first, 4160);
  EXPECT_EQ(l.commands[1].second.front(), (std::pair<int, int>{2048, 2048}));
}

TEST(Mvt, LineLeavingAndReenteringBecomesTwoParts) {
  const TileKey key{16, 34584, 22672};
  auto px = [&](double x, double y) {
    // Pixel -> geodetic via Mercator tiles.
    return from_mercator_tiles(key.x + x / 4096.0, key.y + y / 4096.0, key.z);
  };
  MvtLayer lines{"lines",
                 {{1,
                   MvtGeometryType::LineString,
                   {{px(100, 100), px(100, -1000), px(300, -1000), px(300, 100)}},
                   {}}}};
  const auto layers = decode(encode_mvt(key, {lines}));
  ASSERT_EQ(layers.size(), 1u);
  const auto& cmds = layers[0].features[0].commands;
  ASSERT_EQ(cmds.size(), 4u);  // MoveTo LineTo MoveTo LineTo
  EXPECT_EQ(cmds[0].second.front(), (std::pair<int, int>{100, 100}));
  EXPECT_EQ(cmds[1].second.back(), (std::pair<int, int>{100, -64}));
  EXPECT_EQ(cmds[2].second.front(), (std::pair<int, int>{300, -64}));
  EXPECT_EQ(cmds[3].second.back(), (std::pair<int, int>{300, 100}));
}

TEST(Mvt, PolygonClippedAndOrientedClockwise) {
  const TileKey key{16, 34584, 22672};
  auto px = [&](double x, double y) {
    return from_mercator_tiles(key.x + x / 4096.0, key.y + y / 4096.0, key.z);
  };
  // Counter-clockwise on screen (y down) input square, partly outside.
  MvtLayer poly{"coverage",
                {{5,
                  MvtGeometryType::Polygon,
                  {{px(-500, -500), px(-500, 1000), px(1000, 1000), px(1000, -500)}},
                  {}}}};
  const auto layers = decode(encode_mvt(key, {poly}));
  const auto& cmds = layers.at(0).features.at(0).commands;
  ASSERT_EQ(cmds.size(), 3u);
  EXPECT_EQ(cmds[2].first, 7);
  std::vector<std::pair<int, int>> ring = cmds[0].second;
  ring.insert(ring.end(), cmds[1].second.begin(), cmds[1].second.end());
  ASSERT_EQ(ring.size(), 4u);
  long long area2 = 0;
  for (std::size_t i = 0; i < ring.size(); ++i) {
    const auto& p = ring[i];
    const auto& q = ring[(i + 1) % ring.size()];
    area2 +=
        static_cast<long long>(p.first) * q.second - static_cast<long long>(q.first) * p.second;
    EXPECT_GE(p.first, -64);
    EXPECT_GE(p.second, -64);
  }
  EXPECT_EQ(area2, 2LL * 1064 * 1064);  // positive = exterior (clockwise on screen)
}

TEST(Mvt, AntimeridianFeatureLandsOnTheRightSide) {
  const TileKey key{16, 0, 35814};  // western edge at -180
  const GeoBox b = tile_bounds(key);
  const double lat = 0.5 * (b.min_lat_deg + b.max_lat_deg);
  // A point just east of +180 ... written as 179.99999 (west of the antimeridian):
  const PixelXY p = project_to_tile_pixels(key, lat, 179.99999);
  EXPECT_LT(p.x, 0.0);
  EXPECT_GT(p.x, -64.0);
  const PixelXY q = project_to_tile_pixels(key, lat, -180.0 + 360.0 * 3);
  EXPECT_NEAR(q.x, 0.0, 1e-6);
}

TEST(Mvt, Rejects) {
  EXPECT_THROW((void)encode_mvt({16, -1, 0}, {}), ValidationError);
  EXPECT_THROW((void)encode_mvt({16, 0, 0}, {{"a", {}}, {"a", {}}}), ValidationError);
  EXPECT_THROW((void)encode_mvt({16, 0, 0}, {{"", {}}}), ValidationError);
}

}  // namespace
}  // namespace polmap::tiles
