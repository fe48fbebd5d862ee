// The merged gridmap's COG export: GDAL opens it as a Cloud Optimized GeoTIFF in EPSG:3857
// with one named band per covariance component, its grid is the z20 sum grid, its pixels
// are the fleet covariance of the sums (N, noise, Σ N C / Σ N), unobserved pixels are
// nodata, and it has overviews.
#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>

#include <cmath>

#include "polmap/mapping_service/export.hpp"
#include "polmap/mapping_service/gridmap_sums_codec.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;
namespace {

const GeoPoint kOrigin{48.78, 9.18, 0.0};

/// A 60 m × 40 m full-polarimetric strip of a drive at kOrigin, cell-dependent covariances.
GridmapRaster strip() {
  GridmapRaster r;
  r.q = 3;
  r.width = 600;
  r.height = 400;
  r.origin_x_m = -30.0;
  r.origin_y_m = 20.0;
  r.noise_power = 0.5;
  r.count.assign(static_cast<std::size_t>(r.width) * r.height, 12);
  r.hits.assign(r.count.size(), 9);
  r.layers.assign(6, std::vector<cdouble>(r.count.size()));
  for (std::size_t i = 0; i < r.count.size(); ++i) {
    const double a = 1.0 + static_cast<double>(i % 600) / 60.0;  // grows eastwards
    r.layers[0][i] = a;
    r.layers[1][i] = cdouble(0.2, -0.1);
    r.layers[3][i] = 2.0 * a;
    r.layers[5][i] = 3.0;
  }
  return r;
}

TEST(MergedGridmapCog, OpensAsACogWithTheSumGridAndTheFleetCovariance) {
  GDALAllRegister();
  polmap::test::TestDir tmp("merged_cog");
  SqliteMapStore store(tmp.path() / "map.db");
  GridmapSumTiles sums;
  splat_gridmap(strip(), tiles::LocalFrame(kOrigin), PolLevel::Full, sums);
  std::vector<GridmapSumRow> rows;
  GridmapSumInputChange add;
  add.kind = GridmapSumInputChange::Kind::Add;
  add.content_hash = "h";
  for (const auto& [k, t] : sums) {
    rows.push_back({static_cast<int>(k.level), k.x, k.y, encode_gridmap_sum_tile(t), 0});
    add.cover.push_back({static_cast<int>(k.level), k.x, k.y});
  }
  store.commit_gridmap_sums(1, rows, add);

  const fs::path out = tmp.path() / "merged.tif";
  const ExportSummary s = export_merged_gridmap_cog(store, std::nullopt, std::nullopt, out);
  EXPECT_EQ(s.gridmap_tiles, sums.size());
  GDALDatasetUniquePtr ds(GDALDataset::Open(out.c_str(), GDAL_OF_RASTER));
  ASSERT_TRUE(ds);
  const char* layout = ds->GetMetadataItem("LAYOUT", "IMAGE_STRUCTURE");
  ASSERT_NE(layout, nullptr);
  EXPECT_STREQ(layout, "COG");
  OGRSpatialReference merc;
  merc.importFromEPSG(3857);
  ASSERT_NE(ds->GetSpatialRef(), nullptr);
  EXPECT_TRUE(ds->GetSpatialRef()->IsSame(&merc));
  const std::vector<std::string> names = merged_gridmap_band_names(PolLevel::Full);
  ASSERT_EQ(ds->GetRasterCount(), 12);
  ASSERT_EQ(names.size(), 12U);
  for (int b = 0; b < 12; ++b) {
    EXPECT_EQ(std::string(ds->GetRasterBand(b + 1)->GetDescription()),
              names[static_cast<std::size_t>(b)]);
  }
  EXPECT_EQ(names[0], "N");
  EXPECT_EQ(names[1], "hits");
  EXPECT_EQ(names[2], "noise_power");
  EXPECT_EQ(names[3], "C_LL_LL");
  EXPECT_EQ(names[4], "C_LL_LR.re");
  EXPECT_GT(ds->GetRasterBand(1)->GetOverviewCount(), 0);

  // The raster's origin is the NW corner of the westmost/northmost sum tile; pixel size is
  // the z20 cell.
  int x0 = 1 << 30, y0 = 1 << 30;
  for (const auto& [k, t] : sums) {
    x0 = std::min(x0, k.x);
    y0 = std::min(y0, k.y);
  }
  double gt[6];
  ds->GetGeoTransform(gt);
  const double cell = 2.0 * M_PI * 6378137.0 / (std::pow(2.0, 20) * 256.0);
  EXPECT_NEAR(gt[1], cell, 1e-9);
  EXPECT_NEAR(gt[5], -cell, 1e-9);
  EXPECT_NEAR(gt[0], -M_PI * 6378137.0 + x0 * 256 * cell, 1e-6);
  EXPECT_NEAR(gt[3], M_PI * 6378137.0 - y0 * 256 * cell, 1e-6);

  // Every pixel of one sum tile equals merged_cell of the sums; NaN where N = 0.
  const auto& [key, tile] = *sums.begin();
  std::vector<float> band(256 * 256);
  int observed = 0, empty = 0;
  for (int b : {0, 1, 2, 3, 4, 5, 11}) {
    ASSERT_EQ(
        ds->GetRasterBand(b + 1)->RasterIO(GF_Read, (key.x - x0) * 256, (key.y - y0) * 256, 256,
                                           256, band.data(), 256, 256, GDT_Float32, 0, 0),
        CE_None);
    for (int y = 0; y < 256; ++y) {
      for (int x = 0; x < 256; ++x) {
        const MergedCell m = merged_cell(tile, x, y);
        const float v = band[static_cast<std::size_t>(y) * 256 + x];
        if (m.n <= 0.0) {
          EXPECT_TRUE(std::isnan(v));
          ++empty;
          continue;
        }
        ++observed;
        double ref = m.n;
        if (b == 1) ref = m.hits;
        if (b == 2) ref = m.noise_power;
        if (b == 3) ref = m.layers[0].real();
        if (b == 4) ref = m.layers[1].real();
        if (b == 5) ref = m.layers[1].imag();
        if (b == 11) ref = m.layers[5].real();
        ASSERT_NEAR(v, ref, 1e-5 * (1.0 + std::abs(ref)))
            << "band " << b << " at " << x << "," << y;
      }
    }
  }
  EXPECT_GT(observed, 0);
  // An empty store and a level that is not there: NotFoundError.
  EXPECT_THROW((void)export_merged_gridmap_cog(store, std::nullopt, PolLevel::SingleHH, out),
               NotFoundError);
}

}  // namespace
}  // namespace polmap::mapping
