// GIS export: files open with GDAL/OGR with the right layers, counts, attributes and CRS.
#include "polmap/mapping_service/export.hpp"

#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>

#include "mapping_service/package_fixture.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/fleet_gridmap.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {

namespace fs = std::filesystem;

class ExportTest : public ::testing::Test {
 protected:
  void SetUp() override {
    GDALAllRegister();
    root_ = polmap::test::unique_test_dir("export");
    const tiles::LocalFrame frame({35.2240, 138.8045, 0.0});
    for (int i = 0; i < 7; ++i) {
      StoredPointLandmark p;
      p.id = 100 + i;
      p.key = 1'000'000'000'000LL + i;
      p.position = frame.to_geo(Eigen::Vector2d(3.0 * i, -2.0 * i));
      p.scattering = static_cast<ScatteringClass>(i % 4);
      p.support_drives = static_cast<std::uint32_t>(2 + i);
      p.spread_m = 0.01 * i;
      p.support = {1, 2, 3};
      lm_.points.push_back(p);
    }
    for (int i = 0; i < 3; ++i) {
      StoredLineLandmark l;
      l.id = 200 + i;
      l.key = 2'000'000'000'000LL + i;
      for (int v = 0; v < 2 + i; ++v) {
        l.polyline.push_back(frame.to_geo(Eigen::Vector2d(10.0 * v, 5.0 * i)));
      }
      l.support_drives = static_cast<std::uint32_t>(3 + i);
      l.spread_m = 0.05;
      lm_.lines.push_back(l);
    }
  }
  void TearDown() override { fs::remove_all(root_); }

  static GDALDatasetUniquePtr open_vector(const std::string& path) {
    return GDALDatasetUniquePtr(GDALDataset::FromHandle(
        GDALOpenEx(path.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY, nullptr, nullptr, nullptr)));
  }
  static bool is_wgs84(OGRLayer* l) {
    OGRSpatialReference wgs84;
    wgs84.importFromEPSG(4326);
    const char* const opts[] = {"IGNORE_DATA_AXIS_TO_SRS_AXIS_MAPPING=YES", nullptr};
    return l->GetSpatialRef() != nullptr && l->GetSpatialRef()->IsSame(&wgs84, opts);
  }
  /// Checks the points/lines layers of a dataset (GeoPackage, Shapefile).
  void check_two_layers(GDALDataset& ds) {
    OGRLayer* pts = ds.GetLayerByName("points");
    OGRLayer* lines = ds.GetLayerByName("lines");
    ASSERT_NE(pts, nullptr);
    ASSERT_NE(lines, nullptr);
    EXPECT_EQ(pts->GetFeatureCount(), 7);
    EXPECT_EQ(lines->GetFeatureCount(), 3);
    EXPECT_TRUE(is_wgs84(pts));
    EXPECT_TRUE(is_wgs84(lines));
    pts->ResetReading();
    int i = 0;
    for (auto& f : *pts) {
      EXPECT_EQ(f->GetFieldAsInteger64("id"), lm_.points[i].id);
      EXPECT_EQ(f->GetFieldAsInteger64("key"), lm_.points[i].key);
      EXPECT_EQ(f->GetFieldAsInteger("support"), static_cast<int>(lm_.points[i].support_drives));
      EXPECT_EQ(f->GetFieldAsInteger("members"), 3);
      EXPECT_EQ(f->GetFieldAsInteger64("version"), 4);
      EXPECT_STREQ(f->GetFieldAsString("scattering"),
                   std::string(to_string(lm_.points[i].scattering)).c_str());
      const auto* p = f->GetGeometryRef()->toPoint();
      EXPECT_NEAR(p->getX(), lm_.points[i].position.lon_deg, 1e-9);  // x = lon
      EXPECT_NEAR(p->getY(), lm_.points[i].position.lat_deg, 1e-9);
      ++i;
    }
    lines->ResetReading();
    i = 0;
    for (auto& f : *lines) {
      EXPECT_EQ(f->GetFieldAsInteger("vertices"), 2 + i);
      EXPECT_NEAR(f->GetFieldAsDouble("length_m"), 10.0 * (1 + i), 1e-3);
      EXPECT_EQ(f->GetGeometryRef()->toLineString()->getNumPoints(), 2 + i);
      ++i;
    }
  }

  fs::path root_;
  LandmarkSet lm_;
};

TEST_F(ExportTest, FormatNames) {
  for (auto f : {ExportFormat::GeoPackage, ExportFormat::GeoJson, ExportFormat::Shapefile,
                 ExportFormat::GeoTiff}) {
    EXPECT_EQ(parse_export_format(to_string(f)), f);
  }
  EXPECT_FALSE(parse_export_format("kml").has_value());
  EXPECT_EQ(export_content_type(ExportFormat::Shapefile), "application/zip");
}

TEST_F(ExportTest, GeoPackageHasPointAndLineLayers) {
  const auto s = export_landmarks(lm_, ExportFormat::GeoPackage, root_ / "map.gpkg", {4});
  EXPECT_EQ(s.points, 7U);
  EXPECT_EQ(s.lines, 3U);
  EXPECT_GT(s.bytes, 0U);
  auto ds = open_vector((root_ / "map.gpkg").string());
  ASSERT_TRUE(ds);
  EXPECT_STREQ(ds->GetDriver()->GetDescription(), "GPKG");
  check_two_layers(*ds);
  // Re-export replaces the file.
  LandmarkSet fewer = lm_;
  fewer.points.resize(2);
  export_landmarks(fewer, ExportFormat::GeoPackage, root_ / "map.gpkg", {4});
  ds = open_vector((root_ / "map.gpkg").string());
  EXPECT_EQ(ds->GetLayerByName("points")->GetFeatureCount(), 2);
}

TEST_F(ExportTest, GeoJsonIsOneRfc7946FeatureCollection) {
  export_landmarks(lm_, ExportFormat::GeoJson, root_ / "map.geojson", {4});
  auto ds = open_vector((root_ / "map.geojson").string());
  ASSERT_TRUE(ds);
  ASSERT_EQ(ds->GetLayerCount(), 1);
  EXPECT_EQ(ds->GetLayer(0)->GetFeatureCount(), 10);
  std::ifstream in(root_ / "map.geojson");
  const auto j = nlohmann::json::parse(in);
  EXPECT_EQ(j["type"], "FeatureCollection");
  ASSERT_EQ(j["features"].size(), 10U);
  int points = 0, lines = 0;
  for (const auto& f : j["features"]) {
    const std::string type = f["geometry"]["type"];
    if (type == "Point") {
      ++points;
      EXPECT_EQ(f["properties"]["layer"], "points");
      // RFC 7946: [lon, lat].
      EXPECT_NEAR(f["geometry"]["coordinates"][0].get<double>(), 138.8045, 0.01);
      EXPECT_NEAR(f["geometry"]["coordinates"][1].get<double>(), 35.224, 0.01);
    } else if (type == "LineString") {
      ++lines;
      EXPECT_EQ(f["properties"]["layer"], "lines");
    }
  }
  EXPECT_EQ(points, 7);
  EXPECT_EQ(lines, 3);
  // Coordinates kept to ~1 mm.
  const double lon = j["features"][3]["geometry"]["coordinates"][0];
  EXPECT_NEAR(lon, lm_.points[3].position.lon_deg, 1e-8);
}

TEST_F(ExportTest, ShapefileDirectoryAndZip) {
  const auto s = export_landmarks(lm_, ExportFormat::Shapefile, root_ / "shp", {4});
  for (const char* f : {"points.shp", "points.shx", "points.dbf", "points.prj", "lines.shp",
                        "lines.dbf", "lines.prj"}) {
    EXPECT_TRUE(fs::exists(root_ / "shp" / f)) << f;
  }
  EXPECT_GE(s.files.size(), 8U);
  auto ds = open_vector((root_ / "shp").string());
  ASSERT_TRUE(ds);
  check_two_layers(*ds);

  const auto z = export_landmarks(lm_, ExportFormat::Shapefile, root_ / "map.zip", {4});
  ASSERT_EQ(z.files.size(), 1U);
  EXPECT_TRUE(fs::exists(root_ / "map.zip"));
  auto dz = open_vector("/vsizip/" + (root_ / "map.zip").string());
  ASSERT_TRUE(dz);
  check_two_layers(*dz);
}

TEST_F(ExportTest, RejectsBrokenLandmarks) {
  LandmarkSet bad = lm_;
  bad.points[2].position.lat_deg = std::nan("");
  EXPECT_THROW(export_landmarks(bad, ExportFormat::GeoPackage, root_ / "x.gpkg"), ValidationError);
  bad = lm_;
  bad.lines[0].polyline.resize(1);
  EXPECT_THROW(export_landmarks(bad, ExportFormat::GeoJson, root_ / "x.geojson"), ValidationError);
  EXPECT_THROW(export_landmarks(lm_, ExportFormat::GeoTiff, root_ / "x.tif"), ValidationError);
}

TEST_F(ExportTest, MercatorGridmapGeoTiffBlocksAreXyzTiles) {
  const tiles::TileKey a = tiles::tile_at(35.2240, 138.8045, 18);
  const tiles::TileKey b{18, a.x + 2, a.y + 1};  // leaves empty tiles in between
  const std::vector<tiles::TileKey> keys{b, a};
  const auto s = export_mercator_gridmap_geotiff(
      18, keys,
      [&](const tiles::TileKey& k) {
        std::vector<float> db(256 * 256, std::nanf(""));
        for (int i = 0; i < 256; ++i) db[i * 256 + i] = static_cast<float>(k.x - a.x) + 0.5F;
        return db;
      },
      root_ / "grid.tif");
  EXPECT_EQ(s.gridmap_tiles, 2U);
  GDALDatasetUniquePtr ds(GDALDataset::Open((root_ / "grid.tif").c_str(), GDAL_OF_RASTER));
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetRasterXSize(), 3 * 256);
  EXPECT_EQ(ds->GetRasterYSize(), 2 * 256);
  OGRSpatialReference merc;
  merc.importFromEPSG(3857);
  ASSERT_NE(ds->GetSpatialRef(), nullptr);
  EXPECT_TRUE(ds->GetSpatialRef()->IsSame(&merc));
  // The raster's NW corner is tile a's NW corner.
  double gt[6];
  ds->GetGeoTransform(gt);
  OGRSpatialReference wgs84;
  wgs84.importFromEPSG(4326);
  wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> ct(OGRCreateCoordinateTransformation(&merc, &wgs84));
  double x = gt[0], y = gt[3];
  ASSERT_TRUE(ct->Transform(1, &x, &y));
  const tiles::GeoBox box = tiles::tile_bounds(a);
  EXPECT_NEAR(x, box.min_lon_deg, 1e-9);
  EXPECT_NEAR(y, box.max_lat_deg, 1e-9);
  // Values: diagonal of tile a = 0.5, of tile b = 2.5; elsewhere NaN (nodata).
  std::vector<float> v(3 * 256 * 2 * 256);
  ASSERT_EQ(ds->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, 768, 512, v.data(), 768, 512, GDT_Float32,
                                           0, 0),
            CE_None);
  EXPECT_FLOAT_EQ(v[10 * 768 + 10], 0.5F);
  EXPECT_FLOAT_EQ(v[(256 + 10) * 768 + 512 + 10], 2.5F);
  EXPECT_TRUE(std::isnan(v[10 * 768 + 11]));
  EXPECT_TRUE(std::isnan(v[10 * 768 + 300]));  // never-written tile
  int has_nodata = 0;
  EXPECT_TRUE(std::isnan(ds->GetRasterBand(1)->GetNoDataValue(&has_nodata)));
  EXPECT_TRUE(has_nodata);
}

TEST_F(ExportTest, CovarianceGeoTiffHasPackageBandLayout) {
  const auto d = testing::make_synthetic_drive();
  const std::string proj = tiles::LocalFrame(d.pkg.manifest.origin).proj_string();
  export_covariance_geotiff(d.raster, PolLevel::Full, proj, root_ / "cov.tif");
  const GridmapRaster back = read_gridmap((root_ / "cov.tif").string());
  EXPECT_EQ(back.count, d.raster.count);
  GDALDatasetUniquePtr ds(GDALDataset::Open((root_ / "cov.tif").c_str(), GDAL_OF_RASTER));
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetRasterCount(), 10);
  EXPECT_STREQ(ds->GetRasterBand(3)->GetDescription(), "C_LL_LR.re");
}

TEST_F(ExportTest, ExportMapFromStoreAllFormatsAndBbox) {
  SqliteStoreOptions opts;
  opts.orphan_grace_s = 0;
  SqliteMapStore store(root_ / "map.db", opts);
  const auto v = store.begin_map_version({{"notes", "export test"}});
  // Support lists reference stored candidates (foreign keys); none in this store.
  LandmarkSet stored = lm_;
  for (auto& p : stored.points) p.support.clear();
  store.put_landmarks(v, stored.points, stored.lines);
  // Fleet gridmap tiles from a synthetic drive raster.
  const auto d = testing::make_synthetic_drive();
  FleetGridmapAccumulator acc;
  acc.add(d.raster, tiles::LocalFrame(d.pkg.manifest.origin), d.pkg.manifest.pol_level);
  std::vector<TileWrite> tw;
  int base_tiles = 0;
  for (auto& [key, png] : acc.encode_png_tiles()) {
    base_tiles += key.z == acc.config().base_zoom;
    tw.push_back({key, content_etag(png), png, false, 0, 0});
  }
  store.put_tiles(v, TileLayer::Gridmap, tw);
  store.publish_map_version(v, {{"gridmap", {{"db_min", -10.0}, {"db_max", 40.0}}}});

  const auto g = export_map(store, v, ExportFormat::GeoPackage, std::nullopt, root_ / "a.gpkg");
  EXPECT_EQ(g.points, 7U);
  EXPECT_EQ(g.lines, 3U);
  auto ds = open_vector((root_ / "a.gpkg").string());
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetLayerByName("points")->GetFeatureCount(), 7);
  const std::unique_ptr<OGRFeature> first(ds->GetLayerByName("points")->GetFeature(1));
  ASSERT_TRUE(first);
  EXPECT_EQ(first->GetFieldAsInteger64("version"), v);

  // A box around the first three points (3 m steps east/south of the origin).
  const tiles::LocalFrame frame({35.2240, 138.8045, 0.0});
  const GeoPoint sw = frame.to_geo(Eigen::Vector2d(-1.0, -5.0));
  const GeoPoint ne = frame.to_geo(Eigen::Vector2d(7.0, 1.0));
  const GeoBox box{sw.lat_deg, sw.lon_deg, ne.lat_deg, ne.lon_deg};
  const auto b = export_map(store, v, ExportFormat::GeoJson, box, root_ / "b.geojson");
  EXPECT_EQ(b.points, 3U);
  ds = open_vector((root_ / "b.geojson").string());
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetLayer(0)->GetFeatureCount(), static_cast<GIntBig>(b.points + b.lines));

  const auto z = export_map(store, v, ExportFormat::Shapefile, std::nullopt, root_ / "c.zip");
  ds = open_vector("/vsizip/" + (root_ / "c.zip").string());
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetLayerByName("lines")->GetFeatureCount(), 3);

  const auto t = export_map(store, v, ExportFormat::GeoTiff, std::nullopt, root_ / "d.tif");
  EXPECT_EQ(t.gridmap_tiles, static_cast<std::uint64_t>(base_tiles));
  GDALDatasetUniquePtr r(GDALDataset::Open((root_ / "d.tif").c_str(), GDAL_OF_RASTER));
  ASSERT_TRUE(r);
  // Observed pixels read back the accumulator's mean power within the 0.2 dB PNG steps.
  std::vector<float> px(static_cast<std::size_t>(r->GetRasterXSize()) * r->GetRasterYSize());
  ASSERT_EQ(r->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, r->GetRasterXSize(), r->GetRasterYSize(),
                                          px.data(), r->GetRasterXSize(), r->GetRasterYSize(),
                                          GDT_Float32, 0, 0),
            CE_None);
  double gt[6];
  r->GetGeoTransform(gt);
  const int zoom = acc.config().base_zoom;
  const double tile_m = 2.0 * M_PI * 6378137.0 / std::pow(2.0, zoom);
  const int x0 = static_cast<int>(std::lround((gt[0] + M_PI * 6378137.0) / tile_m));
  const int y0 = static_cast<int>(std::lround((M_PI * 6378137.0 - gt[3]) / tile_m));
  int observed = 0;
  for (int row = 0; row < r->GetRasterYSize(); ++row) {
    for (int col = 0; col < r->GetRasterXSize(); ++col) {
      const float v_db = px[static_cast<std::size_t>(row) * r->GetRasterXSize() + col];
      const tiles::TileKey key{zoom, x0 + col / 256, y0 + row / 256};
      const auto p = acc.mean_power(key, col % 256, row % 256);
      ASSERT_EQ(p.has_value(), !std::isnan(v_db)) << row << "," << col;
      if (!p) continue;
      ++observed;
      const double want = std::clamp(10.0 * std::log10(*p), -10.0, 40.0);
      ASSERT_NEAR(v_db, want, 0.11) << row << "," << col;
    }
  }
  EXPECT_GT(observed, 100);

  EXPECT_THROW(export_map(store, v + 1, ExportFormat::GeoPackage, std::nullopt, root_ / "e.gpkg"),
               NotFoundError);
}

}  // namespace
}  // namespace polmap::mapping
