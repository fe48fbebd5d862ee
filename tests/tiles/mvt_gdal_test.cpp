// The MVT encoder (tiles/mvt.hpp) read back by GDAL's MVT driver: an independent decoder
// checks layer names, feature counts, attribute values and georeferenced coordinates.
#include <gdal.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>

#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/mvt.hpp"
#include "test_dir.hpp"

namespace polmap::tiles {
namespace {

class MvtGdal : public ::testing::Test {
 protected:
  void SetUp() override {
    GDALAllRegister();
    dir_ = polmap::test::unique_test_dir("mvt-gdal");
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  /// Writes the tile as DIR/z/x/y.pbf (GDAL georeferences tiles named like that) and opens it.
  GDALDatasetUniquePtr open(const TileKey& key, const std::string& bytes) {
    const auto d = dir_ / std::to_string(key.z) / std::to_string(key.x);
    std::filesystem::create_directories(d);
    const auto f = d / (std::to_string(key.y) + ".pbf");
    std::ofstream(f, std::ios::binary) << bytes;
    const char* drivers[] = {"MVT", nullptr};
    return GDALDatasetUniquePtr(
        GDALDataset::Open(f.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY, drivers, nullptr, nullptr));
  }

  std::filesystem::path dir_;
};

// Web-Mercator (EPSG:3857) metres -> WGS84 degrees, spherical formulas.
GeoPoint from_3857(double x, double y) {
  constexpr double R = 6378137.0;
  const double lon = x / R * 180.0 / M_PI;
  const double lat = (2.0 * std::atan(std::exp(y / R)) - M_PI / 2.0) * 180.0 / M_PI;
  return {lat, lon, 0.0};
}

TEST_F(MvtGdal, LayersFeaturesAttributesAndCoordinates) {
  const GeoPoint origin{48.39870, 9.99070, 0.0};
  const TileKey key = tile_at(origin.lat_deg, origin.lon_deg, 18);
  const LocalFrame frame(tile_center(key));
  // Five points on a diagonal inside the tile, one two-segment line, one trajectory.
  MvtLayer points{"points", {}}, lines{"lines", {}}, traj{"trajectories", {}};
  std::vector<GeoPoint> truth;
  for (int i = 0; i < 5; ++i) {
    const GeoPoint g = frame.to_geo(Eigen::Vector2d(-20.0 + 10.0 * i, 15.0 - 7.5 * i));
    truth.push_back(g);
    points.features.push_back({static_cast<std::uint64_t>(100 + i),
                               MvtGeometryType::Point,
                               {{g}},
                               {{"class", std::string(i % 2 ? "odd" : "even")},
                                {"support_drives", std::uint64_t(2 + i)},
                                {"spread_m", 0.01 * (i + 1)},
                                {"offset", std::int64_t(-i)}}});
  }
  lines.features.push_back(
      {7,
       MvtGeometryType::LineString,
       {{frame.to_geo({-30.0, -30.0}), frame.to_geo({0.0, -25.0}), frame.to_geo({30.0, -30.0})}},
       {{"support_drives", std::uint64_t(3)}}});
  traj.features.push_back({1,
                           MvtGeometryType::LineString,
                           {{frame.to_geo({-500.0, 0.0}), frame.to_geo({500.0, 0.0})}},
                           {{"drive_id", std::string("drive_7")}}});
  const std::string bytes = encode_mvt(key, {points, lines, traj});
  auto ds = open(key, bytes);
  ASSERT_TRUE(ds);

  ASSERT_EQ(ds->GetLayerCount(), 3);
  OGRLayer* lp = ds->GetLayerByName("points");
  OGRLayer* ll = ds->GetLayerByName("lines");
  OGRLayer* lt = ds->GetLayerByName("trajectories");
  ASSERT_TRUE(lp && ll && lt);
  EXPECT_EQ(lp->GetFeatureCount(), 5);
  EXPECT_EQ(ll->GetFeatureCount(), 1);
  EXPECT_EQ(lt->GetFeatureCount(), 1);

  // Pixel size at z18: 2πR / 2^18 / 4096 = 3.7 cm (Mercator metres); ground ≈ 2.5 cm here.
  const double pixel_m =
      2.0 * M_PI * 6378137.0 / std::pow(2.0, 18) / 4096.0 * std::cos(origin.lat_deg * M_PI / 180.0);
  int n = 0;
  for (auto& f : *lp) {
    const int i = static_cast<int>(f->GetFieldAsInteger64("mvt_id")) - 100;
    ASSERT_GE(i, 0);
    ASSERT_LT(i, 5);
    EXPECT_STREQ(f->GetFieldAsString("class"), i % 2 ? "odd" : "even");
    EXPECT_EQ(f->GetFieldAsInteger64("support_drives"), 2 + i);
    EXPECT_NEAR(f->GetFieldAsDouble("spread_m"), 0.01 * (i + 1), 1e-12);
    EXPECT_EQ(f->GetFieldAsInteger64("offset"), -i);
    const OGRPoint* p = f->GetGeometryRef()->toPoint();
    const GeoPoint g = from_3857(p->getX(), p->getY());
    const double err = (frame.to_local(g) - frame.to_local(truth[i])).norm();
    EXPECT_LT(err, pixel_m) << "point " << i;
    ++n;
  }
  EXPECT_EQ(n, 5);
  for (auto& f : *ll) {
    const OGRLineString* ls = f->GetGeometryRef()->toLineString();
    ASSERT_EQ(ls->getNumPoints(), 3);
    const GeoPoint mid = from_3857(ls->getX(1), ls->getY(1));
    EXPECT_LT((frame.to_local(mid) - Eigen::Vector2d(0.0, -25.0)).norm(), pixel_m);
    EXPECT_EQ(f->GetFieldAsInteger64("support_drives"), 3);
  }
  for (auto& f : *lt) {
    EXPECT_STREQ(f->GetFieldAsString("drive_id"), "drive_7");
    // Clipped to the tile (GDAL clips at the tile edge): within ±(tile half width + buffer).
    OGREnvelope env;
    f->GetGeometryRef()->getEnvelope(&env);
    const GeoPoint west = from_3857(env.MinX, env.MinY);
    EXPECT_GT(frame.to_local(west).x(), -0.5 * tile_width_m(key) * 1.1);
  }
}

TEST_F(MvtGdal, EmptyLayersAreSkippedAndGdalStillOpensTheTile) {
  const TileKey key{16, 34584, 22672};
  const GeoPoint c = tile_center(key);
  MvtLayer a{"points", {{1, MvtGeometryType::Point, {{c}}, {}}}};
  MvtLayer b{"lines", {}};
  auto ds = open(key, encode_mvt(key, {a, b}));
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetLayerCount(), 1);
  EXPECT_NE(ds->GetLayerByName("points"), nullptr);
}

}  // namespace
}  // namespace polmap::tiles
