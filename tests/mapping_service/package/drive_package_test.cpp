// Drive package: write -> read round trips, determinism, GDAL/OGR readability, archive form.
#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>

#include <filesystem>
#include <fstream>

#include "mapping_service/package_fixture.hpp"
#include "polmap/mapping_service/detail/gdal.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {

namespace fs = std::filesystem;
using testing::make_synthetic_drive;

class DrivePackageTest : public ::testing::Test {
 protected:
  void SetUp() override {
    GDALAllRegister();
    root_ = polmap::test::unique_test_dir("pkg");
  }
  void TearDown() override { fs::remove_all(root_); }
  /// Writes d as the package root_/pkg and opens its `file` read-only with GDAL
  /// (kind: GDAL_OF_RASTER or GDAL_OF_VECTOR).
  [[nodiscard]] GDALDatasetUniquePtr write_and_open(const testing::SyntheticDrive& d,
                                                    const char* file, unsigned kind) const {
    write_drive_package(d.pkg, d.raster, root_ / "pkg");
    return GDALDatasetUniquePtr(
        GDALDataset::Open((root_ / "pkg" / file).c_str(), kind | GDAL_OF_READONLY));
  }
  fs::path root_;
};

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

TEST(GdalSetup, TheBlockCacheIsBoundedUnlessConfigured) {
  // GDAL's default (5 % of RAM) let a long-running server grow by a gigabyte of cached
  // gridmap blocks (found by the soak). Each test runs in its own process under ctest.
  ::unsetenv("GDAL_CACHEMAX");
  detail::ensure_gdal();
  EXPECT_EQ(GDALGetCacheMax64(), detail::kDefaultGdalCacheBytes);
}

TEST_F(DrivePackageTest, WrittenPackageReadsBackIdentical) {
  const auto d = make_synthetic_drive();
  const fs::path dir = root_ / "pkg";
  const DriveManifest written = write_drive_package(d.pkg, d.raster, dir);
  EXPECT_TRUE(fs::exists(dir / "manifest.json"));
  EXPECT_TRUE(fs::exists(dir / "gridmap.tif"));
  EXPECT_TRUE(fs::exists(dir / "candidates.gpkg"));
  // No side files (.aux.xml, journals) in the package directory.
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator{}), 3);

  const DrivePackage back = read_and_validate_package(dir);
  const DriveManifest& m = back.manifest;
  EXPECT_EQ(m.drive_id, "drive_0001");
  EXPECT_EQ(m.vehicle_id, "veh_01");
  EXPECT_EQ(m.world, "synthetic");
  EXPECT_EQ(m.pol_level, PolLevel::Full);
  EXPECT_DOUBLE_EQ(m.cell_size_m, 0.1);
  EXPECT_DOUBLE_EQ(m.start_time_s, d.pkg.manifest.start_time_s);
  EXPECT_DOUBLE_EQ(m.end_time_s, d.pkg.manifest.end_time_s);
  EXPECT_DOUBLE_EQ(m.distance_m, d.pkg.manifest.distance_m);
  EXPECT_DOUBLE_EQ(m.origin.lat_deg, 35.2240);
  EXPECT_DOUBLE_EQ(m.origin.lon_deg, 138.8045);
  EXPECT_EQ(m.crs_proj, tiles::LocalFrame(m.origin).proj_string());
  ASSERT_EQ(m.sensors.size(), 3U);
  EXPECT_EQ(m.sensors[1].name, "front_left");
  EXPECT_DOUBLE_EQ(m.sensors[1].T_vehicle_sensor.yaw_rad,
                   d.pkg.manifest.sensors[1].T_vehicle_sensor.yaw_rad);
  EXPECT_DOUBLE_EQ(m.sensors[2].trigger_offset_s, 0.066);
  EXPECT_EQ(m.gridmap.width, 300);
  EXPECT_EQ(m.gridmap.height, 280);
  EXPECT_EQ(m.gridmap.num_bands, 10);
  EXPECT_EQ(m.counts.points, 25U);
  EXPECT_EQ(m.counts.lines, 6U);
  EXPECT_EQ(m.counts.trajectory_samples, 120U);
  ASSERT_EQ(m.files.size(), 2U);
  EXPECT_EQ(m.files[0].name, "gridmap.tif");
  EXPECT_EQ(m.files[0].sha256, written.files[0].sha256);
  EXPECT_EQ(m.files[0].size_bytes, fs::file_size(dir / "gridmap.tif"));
  EXPECT_EQ(back.location, dir);

  // Candidates and trajectory: doubles stored as doubles, exact.
  ASSERT_EQ(back.points.size(), d.pkg.points.size());
  for (std::size_t i = 0; i < back.points.size(); ++i) {
    EXPECT_EQ(back.points[i].position_m, d.pkg.points[i].position_m);
    EXPECT_EQ(back.points[i].strength, d.pkg.points[i].strength);
    EXPECT_EQ(back.points[i].power_db, d.pkg.points[i].power_db);
    EXPECT_EQ(back.points[i].scattering, d.pkg.points[i].scattering);
    EXPECT_EQ(back.points[i].num_cells, d.pkg.points[i].num_cells);
  }
  ASSERT_EQ(back.lines.size(), d.pkg.lines.size());
  for (std::size_t i = 0; i < back.lines.size(); ++i) {
    EXPECT_EQ(back.lines[i].start_m, d.pkg.lines[i].start_m);
    EXPECT_EQ(back.lines[i].end_m, d.pkg.lines[i].end_m);
    EXPECT_EQ(back.lines[i].strength, d.pkg.lines[i].strength);
  }
  ASSERT_EQ(back.trajectory.size(), d.pkg.trajectory.size());
  for (std::size_t i = 0; i < back.trajectory.size(); ++i) {
    const auto& a = back.trajectory[i];
    const auto& b = d.pkg.trajectory[i];
    EXPECT_EQ(a.time_s, b.time_s);
    EXPECT_EQ(a.lat_deg, b.lat_deg);
    EXPECT_EQ(a.lon_deg, b.lon_deg);
    EXPECT_EQ(a.yaw_enu_rad, b.yaw_enu_rad);
    EXPECT_EQ(a.speed_mps, b.speed_mps);
    EXPECT_EQ(a.yaw_rate_rps, b.yaw_rate_rps);
    EXPECT_EQ(a.std_east_m, b.std_east_m);
    EXPECT_EQ(a.std_north_m, b.std_north_m);
    EXPECT_EQ(a.std_yaw_rad, b.std_yaw_rad);
    EXPECT_EQ(a.solution, b.solution);
  }

  // Gridmap: counts exact, covariance within Float32 precision.
  const GridmapRaster g = read_gridmap(back);
  ASSERT_EQ(g.width, d.raster.width);
  ASSERT_EQ(g.height, d.raster.height);
  ASSERT_EQ(g.q, 3);
  EXPECT_DOUBLE_EQ(g.origin_x_m, d.raster.origin_x_m);
  EXPECT_DOUBLE_EQ(g.origin_y_m, d.raster.origin_y_m);
  EXPECT_DOUBLE_EQ(g.cell_size_m, 0.1);
  EXPECT_EQ(g.count, d.raster.count);
  ASSERT_EQ(g.layers.size(), 6U);
  std::size_t compared = 0;
  for (std::size_t l = 0; l < 6; ++l) {
    for (std::size_t k = 0; k < g.count.size(); ++k) {
      const cdouble want = d.raster.layers[l][k];
      const cdouble got = g.layers[l][k];
      const double scale = std::max(std::abs(want), 1e-30);
      ASSERT_LE(std::abs(got - want), 1e-6 * scale + 1e-38) << "layer " << l << " cell " << k;
      ++compared;
    }
  }
  EXPECT_EQ(compared, 6U * 300U * 280U);
}

TEST_F(DrivePackageTest, SameInputGivesSameBytes) {
  const auto d = make_synthetic_drive();
  write_drive_package(d.pkg, d.raster, root_ / "a");
  write_drive_package(d.pkg, d.raster, root_ / "b");
  for (const char* f : {"manifest.json", "gridmap.tif", "candidates.gpkg"}) {
    EXPECT_EQ(slurp(root_ / "a" / f), slurp(root_ / "b" / f)) << f;
  }
  const std::string ta = pack_drive_package(root_ / "a");
  const std::string tb = pack_drive_package(root_ / "b");
  EXPECT_EQ(ta, tb);
  EXPECT_EQ(ta.size() % 512, 0U);
  // Content hash is the SHA-256 of the archive, for directory and archive inputs alike.
  write_drive_package_archive(root_ / "a", root_ / "a.tar");
  EXPECT_EQ(slurp(root_ / "a.tar"), ta);
  const auto from_dir = read_and_validate_package(root_ / "a");
  const auto from_tar = read_and_validate_package(root_ / "a.tar");
  EXPECT_EQ(from_dir.content_sha256, package_content_hash(ta));
  EXPECT_EQ(from_tar.content_sha256, package_content_hash(ta));
  EXPECT_EQ(from_tar.location, root_ / "a.tar");
  // A different drive gives a different hash.
  const auto other = make_synthetic_drive("drive_0002");
  write_drive_package(other.pkg, other.raster, root_ / "c");
  EXPECT_NE(package_content_hash(pack_drive_package(root_ / "c")), from_dir.content_sha256);
}

TEST_F(DrivePackageTest, Sha256MatchesKnownVectors) {
  EXPECT_EQ(sha256_hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(sha256_hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
}

TEST_F(DrivePackageTest, GdalOpensGridmapWithCrsBandsAndTiling) {
  const auto d = make_synthetic_drive();
  const GDALDatasetUniquePtr ds = write_and_open(d, "gridmap.tif", GDAL_OF_RASTER);
  ASSERT_TRUE(ds);
  EXPECT_STREQ(ds->GetDriver()->GetDescription(), "GTiff");
  EXPECT_EQ(ds->GetRasterCount(), 10);
  EXPECT_EQ(ds->GetRasterXSize(), 300);
  EXPECT_EQ(ds->GetRasterYSize(), 280);
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  ASSERT_NE(srs, nullptr);
  OGRSpatialReference frame_srs;
  ASSERT_EQ(
      frame_srs.SetFromUserInput(tiles::LocalFrame(d.pkg.manifest.origin).proj_string().c_str()),
      OGRERR_NONE);
  EXPECT_TRUE(OSRIsSame(OGRSpatialReference::ToHandle(const_cast<OGRSpatialReference*>(srs)),
                        OGRSpatialReference::ToHandle(&frame_srs)));
  double gt[6];
  ASSERT_EQ(ds->GetGeoTransform(gt), CE_None);
  EXPECT_DOUBLE_EQ(gt[0], -10.0);
  EXPECT_DOUBLE_EQ(gt[1], 0.1);
  EXPECT_DOUBLE_EQ(gt[3], 18.0);
  EXPECT_DOUBLE_EQ(gt[5], -0.1);
  EXPECT_STREQ(ds->GetMetadataItem("COMPRESSION", "IMAGE_STRUCTURE"), "DEFLATE");
  EXPECT_STREQ(ds->GetMetadataItem("POLMAP_DRIVE_ID"), "drive_0001");
  const auto names = gridmap_band_names(PolLevel::Full);
  ASSERT_EQ(names.size(), 10U);
  EXPECT_EQ(names[1], "C_LL_LL");
  EXPECT_EQ(names[2], "C_LL_LR.re");
  EXPECT_EQ(names[3], "C_LL_LR.im");
  EXPECT_EQ(names[9], "C_RR_RR");
  for (int b = 1; b <= 10; ++b) {
    GDALRasterBand* band = ds->GetRasterBand(b);
    EXPECT_EQ(band->GetRasterDataType(), GDT_Float32);
    EXPECT_EQ(names[b - 1], band->GetDescription());
    int bx = 0, by = 0;
    band->GetBlockSize(&bx, &by);
    EXPECT_EQ(bx, 256);
    EXPECT_EQ(by, 256);
  }
  // The centre of a known cell reads back through plain GDAL too.
  float n = 0;
  const int col = 100, row = 90;
  ASSERT_EQ(ds->GetRasterBand(1)->RasterIO(GF_Read, col, row, 1, 1, &n, 1, 1, GDT_Float32, 0, 0),
            CE_None);
  EXPECT_EQ(static_cast<std::uint32_t>(n), d.raster.count[row * 300 + col]);
}

TEST_F(DrivePackageTest, EmptyBlocksTakeNoSpace) {
  // 2000 x 2000 cells (64 blocks), only a 10x10 patch observed.
  auto d = make_synthetic_drive("drive_sparse", PolLevel::SingleRR, 10, 10, 3, 2, 1, 20);
  GridmapRaster big = d.raster;
  big.width = big.height = 2000;
  big.count.assign(2000U * 2000U, 0);
  big.layers.assign(1, std::vector<cdouble>(2000U * 2000U));
  for (int r = 0; r < 10; ++r)
    for (int c = 0; c < 10; ++c) {
      big.count[r * 2000 + c] = d.raster.count[r * 10 + c];
      big.layers[0][r * 2000 + c] = d.raster.layers[0][r * 10 + c];
    }
  d.pkg.points.clear();
  d.pkg.lines.clear();
  write_drive_package(d.pkg, big, root_ / "pkg");
  // Dense Float32 would be 2 bands x 16 MB; sparse tiles keep it tiny.
  EXPECT_LT(fs::file_size(root_ / "pkg" / "gridmap.tif"), 20'000U);
  GDALDatasetUniquePtr ds(GDALDataset::Open((root_ / "pkg" / "gridmap.tif").c_str()));
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetRasterCount(), 2);
  EXPECT_EQ(ds->GetRasterBand(1)->GetDataCoverageStatus(1024, 1024, 256, 256) &
                GDAL_DATA_COVERAGE_STATUS_EMPTY,
            GDAL_DATA_COVERAGE_STATUS_EMPTY);
  const auto pkg = read_and_validate_package(root_ / "pkg");
  int blocks = 0;
  for_each_gridmap_block(pkg, [&](const GridmapRaster& b) {
    ++blocks;
    EXPECT_EQ(b.width, 256);
    EXPECT_DOUBLE_EQ(b.origin_x_m, big.origin_x_m);
    EXPECT_EQ(b.count[0], big.count[0]);
    EXPECT_EQ(b.count[9 * 256 + 9], big.count[9 * 2000 + 9]);
  });
  EXPECT_EQ(blocks, 1);
}

TEST_F(DrivePackageTest, OgrOpensCandidatesLayers) {
  const auto d = make_synthetic_drive();
  const GDALDatasetUniquePtr ds = write_and_open(d, "candidates.gpkg", GDAL_OF_VECTOR);
  ASSERT_TRUE(ds);
  EXPECT_STREQ(ds->GetDriver()->GetDescription(), "GPKG");
  OGRSpatialReference wgs84;
  wgs84.importFromEPSG(4326);
  const std::pair<const char*, GIntBig> layers[] = {
      {"points", 25}, {"lines", 6}, {"trajectory", 120}};
  for (const auto& [name, n] : layers) {
    OGRLayer* l = ds->GetLayerByName(name);
    ASSERT_NE(l, nullptr) << name;
    EXPECT_EQ(l->GetFeatureCount(), n) << name;
    ASSERT_NE(l->GetSpatialRef(), nullptr);
    const char* const ignore_axis[] = {"IGNORE_DATA_AXIS_TO_SRS_AXIS_MAPPING=YES", nullptr};
    EXPECT_TRUE(l->GetSpatialRef()->IsSame(&wgs84, ignore_axis));
  }
  OGRLayer* pts = ds->GetLayerByName("points");
  for (const char* f : {"strength", "power_db", "scattering", "num_cells", "x_m", "y_m"}) {
    EXPECT_GE(pts->GetLayerDefn()->GetFieldIndex(f), 0) << f;
  }
  // Geometry is WGS84 lon/lat of the drive-frame position.
  std::unique_ptr<OGRFeature> f(pts->GetNextFeature());
  ASSERT_TRUE(f);
  const auto* p = f->GetGeometryRef()->toPoint();
  const tiles::LocalFrame frame(d.pkg.manifest.origin);
  const Eigen::Vector2d xy = frame.to_local(p->getY(), p->getX());
  EXPECT_NEAR((xy - d.pkg.points[0].position_m).norm(), 0.0, 1e-6);
}

TEST_F(DrivePackageTest, ArchiveRoundTripThroughVsitarAndUnpack) {
  const auto d = make_synthetic_drive("drive_tar", PolLevel::DualHHVV);
  write_drive_package(d.pkg, d.raster, root_ / "pkg");
  write_drive_package_archive(root_ / "pkg", root_ / "pkg.tar");
  const DrivePackage pkg = read_and_validate_package(root_ / "pkg.tar");
  EXPECT_EQ(pkg.manifest.pol_level, PolLevel::DualHHVV);
  EXPECT_EQ(pkg.manifest.gridmap.num_bands, 5);
  // GDAL reads the gridmap straight out of the archive (/vsitar/).
  const GridmapRaster g = read_gridmap(pkg);
  EXPECT_EQ(g.q, 2);
  EXPECT_EQ(g.count, d.raster.count);
  // Members are in fixed order with zero mtimes.
  const auto members = read_ustar(slurp(root_ / "pkg.tar"));
  ASSERT_EQ(members.size(), 3U);
  EXPECT_EQ(members[0].name, "manifest.json");
  EXPECT_EQ(members[1].name, "gridmap.tif");
  EXPECT_EQ(members[2].name, "candidates.gpkg");
  // Bytes -> validation without any file, and unpack to a temp dir.
  const std::string bytes = slurp(root_ / "pkg.tar");
  const DrivePackage mem = validate_package_bytes(bytes);
  EXPECT_EQ(mem.points.size(), d.pkg.points.size());
  EXPECT_TRUE(mem.location.empty());
  const fs::path tmp = unpack_drive_package_to_temp(bytes);
  for (const char* f : {"manifest.json", "gridmap.tif", "candidates.gpkg"}) {
    EXPECT_EQ(slurp(tmp / f), slurp(root_ / "pkg" / f)) << f;
  }
  EXPECT_EQ(pack_drive_package(tmp), bytes);
  fs::remove_all(tmp);
  // The system tar lists the archive too (if present on this machine).
  if (std::system("command -v tar >/dev/null 2>&1") == 0) {
    const std::string cmd =
        "tar -tf " + (root_ / "pkg.tar").string() + " > " + (root_ / "list.txt").string();
    ASSERT_EQ(std::system(cmd.c_str()), 0);
    EXPECT_EQ(slurp(root_ / "list.txt"), "manifest.json\ngridmap.tif\ncandidates.gpkg\n");
  }
}

TEST_F(DrivePackageTest, UstarWriterAndReader) {
  const std::vector<TarMember> in{{"a.txt", "hello"},
                                  {"empty", ""},
                                  {std::string(100, 'n'), std::string(1024, 'x')},
                                  {"b.bin", std::string("\0\1\2", 3)}};
  const std::string tar = write_ustar(in);
  EXPECT_EQ(tar.size(), 512U * (2 + 1 + 1 + 1 + 1 + 2 + 1 + 1));
  const auto out = read_ustar(tar);
  ASSERT_EQ(out.size(), in.size());
  for (std::size_t i = 0; i < in.size(); ++i) {
    EXPECT_EQ(out[i].name, in[i].name);
    EXPECT_EQ(out[i].data, in[i].data);
  }
  EXPECT_EQ(write_ustar(in), tar);
  EXPECT_THROW((void)write_ustar({{"dir/x", "1"}}), ContractViolation);
  EXPECT_THROW((void)write_ustar({{std::string(101, 'n'), "1"}}), ContractViolation);
  EXPECT_THROW((void)write_ustar({{"a", "1"}, {"a", "2"}}), ContractViolation);
  // Truncations anywhere are format errors naming the byte offset.
  for (std::size_t cut :
       {std::size_t{0}, std::size_t{100}, std::size_t{512}, std::size_t{700}, tar.size() - 1024}) {
    try {
      (void)read_ustar(std::string_view(tar).substr(0, cut), "x.tar");
      ADD_FAILURE() << "cut " << cut;
    } catch (const FormatError& e) {
      EXPECT_NE(std::string(e.what()).find("x.tar at byte"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
    }
  }
  std::string bad = tar;
  bad[3] ^= 0x20;  // name byte: checksum no longer matches
  EXPECT_THROW((void)read_ustar(bad), FormatError);
}

TEST_F(DrivePackageTest, OverwriteOnlyWhenAsked) {
  const auto d = make_synthetic_drive();
  write_drive_package(d.pkg, d.raster, root_ / "pkg");
  EXPECT_THROW(write_drive_package(d.pkg, d.raster, root_ / "pkg"), IoError);
  auto d2 = make_synthetic_drive("drive_0002");
  PackageWriteOptions opts;
  opts.overwrite = true;
  opts.producer = "test-producer";
  write_drive_package(d2.pkg, d2.raster, root_ / "pkg", opts);
  const auto back = read_and_validate_package(root_ / "pkg");
  EXPECT_EQ(back.manifest.drive_id, "drive_0002");
  EXPECT_EQ(back.manifest.producer, "test-producer");
  // No temporary siblings left behind.
  int entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(root_)) ++entries;
  EXPECT_EQ(entries, 1);
}

TEST_F(DrivePackageTest, InconsistentInputsAreRejectedBeforeWriting) {
  auto d = make_synthetic_drive();
  auto bad = d;
  bad.raster.q = 2;
  EXPECT_THROW(write_drive_package(bad.pkg, bad.raster, root_ / "x"), ValidationError);
  bad = d;
  bad.raster.cell_size_m = 0.2;
  EXPECT_THROW(write_drive_package(bad.pkg, bad.raster, root_ / "x"), ValidationError);
  bad = d;
  bad.pkg.manifest.crs_proj = "EPSG:4326";
  EXPECT_THROW(write_drive_package(bad.pkg, bad.raster, root_ / "x"), ValidationError);
  bad = d;
  bad.pkg.points[3].position_m.x() = 1e9;  // caught by validate_after_write
  EXPECT_THROW(write_drive_package(bad.pkg, bad.raster, root_ / "x"), ValidationError);
  EXPECT_FALSE(fs::exists(root_ / "x"));
  int entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(root_)) ++entries;
  EXPECT_EQ(entries, 0);
}

TEST_F(DrivePackageTest, EmptyDriveStillMakesAValidPackage) {
  auto d = make_synthetic_drive("drive_empty", PolLevel::SingleLR, 1, 1, 1, 0, 0, 10);
  d.raster.width = d.raster.height = 0;
  d.raster.count.clear();
  d.raster.layers.assign(1, {});
  write_drive_package(d.pkg, d.raster, root_ / "pkg");
  const auto back = read_and_validate_package(root_ / "pkg");
  EXPECT_EQ(back.manifest.gridmap.width, 1);
  EXPECT_TRUE(back.points.empty());
  EXPECT_EQ(read_gridmap(back).count, std::vector<std::uint32_t>{0});
}

TEST_F(DrivePackageTest, GridmapReaderRechecksTypeAndBlockSizeWhereItReadsBlocks) {
  // A stored gridmap is read block by block into 256 x 256 float buffers: a file of another
  // type or tiling (one that never went through validation) is refused, not overrun.
  const struct {
    GDALDataType type;
    int block;
    const char* expected;
  } cases[] = {{GDT_Float64, 256, "data type Float64, expected Float32"},
               {GDT_Float32, 512, "block size 512x512, expected 256x256 tiles"},
               {GDT_Float32, 128, "block size 128x128, expected 256x256 tiles"}};
  for (const auto& [type, block, expected] : cases) {
    const fs::path tif = root_ / ("odd_" + std::to_string(block) + ".tif");
    const std::string bs = std::to_string(block);
    const std::string bx = "BLOCKXSIZE=" + bs, by = "BLOCKYSIZE=" + bs;
    const char* opts[] = {"TILED=YES", bx.c_str(), by.c_str(), nullptr};
    {
      GDALDatasetUniquePtr ds(GetGDALDriverManager()->GetDriverByName("GTiff")->Create(
          tif.c_str(), 600, 600, 2, type, const_cast<char**>(opts)));
      ASSERT_TRUE(ds);
      double gt[6] = {0, 0.1, 0, 60, 0, -0.1};
      ds->SetGeoTransform(gt);
    }
    try {
      (void)read_gridmap(tif.string());
      ADD_FAILURE() << "read " << tif;
    } catch (const PackageValidationError& e) {
      EXPECT_EQ(e.error().field, "band 1") << e.what();
      EXPECT_EQ(e.error().message, expected) << e.what();
    }
  }
}

}  // namespace
}  // namespace polmap::mapping

#include "polmap/radar/covariance_gridmap.hpp"

namespace polmap::mapping {
namespace {

TEST_F(DrivePackageTest, WritesRadarGridmapTileByTileAlignedToItsCells) {
  radar::GridmapConfig cfg;
  cfg.cell_size_m = 0.1;
  cfg.level = PolLevel::Full;
  radar::CovarianceGridmap gm(cfg);
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0.0, 1.0);
  // Three separate patches, including negative cell indices and far-apart tiles
  // (the bounding box spans many empty GeoTIFF blocks).
  struct Cell {
    int ix, iy;
  };
  std::vector<Cell> cells;
  for (int ix = -70; ix < -40; ++ix)
    for (int iy = 5; iy < 9; ++iy) cells.push_back({ix, iy});
  for (int ix = 600; ix < 603; ++ix)
    for (int iy = -300; iy < -290; ++iy) cells.push_back({ix, iy});
  cells.push_back({1000, 700});
  for (const auto& c : cells) {
    const int n = 1 + ((c.ix * 31 + c.iy * 17) % 5 + 5) % 5;
    for (int s = 0; s < n; ++s) {
      std::vector<cdouble> k(3);
      for (auto& x : k) x = {g(rng), g(rng)};
      gm.add_cell_sample(c.ix, c.iy, k);
    }
  }
  auto d = make_synthetic_drive("drive_radar");
  d.pkg.points.clear();
  d.pkg.lines.clear();
  PointCandidate p;
  p.position_m = gm.cell_center(600, -295);
  p.num_cells = 1;
  d.pkg.points.push_back(p);
  write_drive_package(d.pkg, gm, root_ / "pkg");
  const DrivePackage back = read_and_validate_package(root_ / "pkg");
  const radar::CellBox b = gm.bounds();
  EXPECT_DOUBLE_EQ(back.manifest.gridmap.origin_x_m, b.min_ix * 0.1);
  EXPECT_DOUBLE_EQ(back.manifest.gridmap.origin_y_m, b.max_iy * 0.1);
  EXPECT_EQ(back.manifest.gridmap.width, b.width());
  EXPECT_EQ(back.manifest.gridmap.height, b.height());
  const GridmapRaster r = read_gridmap(back);
  std::size_t observed = 0;
  for (int row = 0; row < r.height; ++row) {
    for (int col = 0; col < r.width; ++col) {
      const int ix = b.min_ix + col;
      const int iy = b.max_iy - 1 - row;
      const std::size_t k = static_cast<std::size_t>(row) * r.width + col;
      ASSERT_EQ(r.count[k], gm.count(ix, iy)) << ix << "," << iy;
      if (r.count[k] == 0) continue;
      ++observed;
      const Eigen::MatrixXcd c = gm.covariance(ix, iy);
      for (int i = 0; i < 3; ++i)
        for (int j = i; j < 3; ++j) {
          const cdouble got = r.layers[GridmapRaster::layer_index(3, i, j)][k];
          ASSERT_LE(std::abs(got - c(i, j)), 1e-5 * std::abs(c(0, 0) + c(1, 1) + c(2, 2)))
              << ix << "," << iy << " C" << i << j;
        }
      // The cell centre in the raster geotransform is the gridmap's cell centre.
      const Eigen::Vector2d centre{r.origin_x_m + (col + 0.5) * 0.1,
                                   r.origin_y_m - (row + 0.5) * 0.1};
      ASSERT_LT((centre - gm.cell_center(ix, iy)).norm(), 1e-9);
    }
  }
  EXPECT_EQ(observed, cells.size());
  // Sparse: ~107 x 100 m bounding box, three patches -> a few blocks only.
  EXPECT_LT(fs::file_size(root_ / "pkg" / "gridmap.tif"), 60'000U);
  // Deterministic bytes from the tile path too.
  write_drive_package(d.pkg, gm, root_ / "pkg2");
  EXPECT_EQ(pack_drive_package(root_ / "pkg"), pack_drive_package(root_ / "pkg2"));
}

}  // namespace
}  // namespace polmap::mapping

namespace polmap::mapping {
namespace {

TEST_F(DrivePackageTest, MantissaRoundingBoundsTheRelativeError) {
  const auto d = make_synthetic_drive();
  PackageWriteOptions opts;
  opts.mantissa_bits = 10;
  write_drive_package(d.pkg, d.raster, root_ / "lossy", opts);
  write_drive_package(d.pkg, d.raster, root_ / "exact");
  const auto pkg = read_and_validate_package(root_ / "lossy");
  EXPECT_EQ(pkg.manifest.gridmap.mantissa_bits, 10);
  EXPECT_EQ(read_and_validate_package(root_ / "exact").manifest.gridmap.mantissa_bits, 23);
  const GridmapRaster g = read_gridmap(pkg);
  EXPECT_EQ(g.count, d.raster.count);  // N stays exact
  double worst = 0.0;
  for (std::size_t l = 0; l < 6; ++l) {
    for (std::size_t k = 0; k < g.count.size(); ++k) {
      const cdouble want = d.raster.layers[l][k];
      const cdouble got = g.layers[l][k];
      // Per component: float rounding (2^-24) then 10-bit rounding (2^-11).
      for (const auto& [w, v] :
           {std::pair{want.real(), got.real()}, std::pair{want.imag(), got.imag()}}) {
        if (w == 0.0) {
          ASSERT_EQ(v, 0.0);
          continue;
        }
        worst = std::max(worst, std::abs(v - w) / std::abs(w));
      }
    }
  }
  EXPECT_LE(worst, std::ldexp(1.0, -11) + std::ldexp(1.0, -23));
  EXPECT_GT(worst, std::ldexp(1.0, -14));  // it really rounded
  EXPECT_LT(fs::file_size(root_ / "lossy" / "gridmap.tif"),
            fs::file_size(root_ / "exact" / "gridmap.tif") * 7 / 10);
}

}  // namespace
}  // namespace polmap::mapping

#include "polmap/radar/drive_processor.hpp"

namespace polmap::mapping {
namespace {

/// A short in-memory drive: 2 s straight east at 5 m/s, 50 Hz trajectory, one sensor at
/// 10 Hz seeing a bright scatterer 10 m ahead.
class TinyDrive final : public RecordSource {
 public:
  TinyDrive() {
    header_.drive_id = "tiny_drive";
    header_.vehicle_id = "veh_tiny";
    header_.world = "unit-test";
    header_.origin = {48.78, 9.18, 250.0};
    header_.sensors = {default_front_mounts().front()};
    header_.start_time_s = 100.0;
    const tiles::LocalFrame frame(header_.origin);
    for (int i = 0; i <= 100; ++i) {
      const double t = 100.0 + 0.02 * i;
      const GeoPoint g = frame.to_geo(Eigen::Vector2d(5.0 * (t - 100.0), 0.0));
      TrajectorySample s;
      s.time_s = t;
      s.lat_deg = g.lat_deg;
      s.lon_deg = g.lon_deg;
      s.yaw_enu_rad = 0.0;
      s.speed_mps = 5.0;
      records_.push_back(s);
      if (i % 5 == 2 && i < 96) {
        SensorFrame f;
        f.sensor_id = 0;
        f.time_s = t;
        f.spectrum.range_bin_m = 0.075;
        f.spectrum.num_range_bins = 400;
        for (int a = 0; a < 41; ++a) f.spectrum.azimuth_bins_rad.push_back(-1.0F + 0.05F * a);
        f.spectrum.noise_sigma = 0.01F;
        for (std::uint16_t r = 120; r < 150; ++r) {
          for (std::uint16_t a = 15; a < 26; ++a) {
            SpectrumCell c;
            c.range_bin = r;
            c.azimuth_bin = a;
            const float amp = (r == 133 && a == 20) ? 10.0F : 0.05F;
            c.s = {cfloat(amp, 0), cfloat(0.3F * amp, 0.1F), cfloat(0.3F * amp, 0.1F),
                   cfloat(-amp, 0)};
            f.spectrum.cells.push_back(c);
          }
        }
        records_.push_back(f);
      }
    }
  }
  [[nodiscard]] const RecordingHeader& header() const override { return header_; }
  std::optional<RecordingRecord> next() override {
    if (next_ >= records_.size()) return std::nullopt;
    return records_[next_++];
  }

 private:
  RecordingHeader header_;
  std::vector<RecordingRecord> records_;
  std::size_t next_ = 0;
};

TEST_F(DrivePackageTest, WritesProcessedDriveFromTheRadarFrontEnd) {
  TinyDrive source;
  radar::DriveProcessingConfig cfg;
  cfg.gridmap.level = PolLevel::DualLLLR;
  const radar::DriveProcessingResult result = radar::process_drive(source, cfg);
  ASSERT_GT(result.stats.frames_mapped, 0U);
  PackageWriteOptions opts;
  opts.producer = "unit test";
  const DriveManifest m = write_drive_package(result, root_ / "pkg", opts);
  const DrivePackage back = read_and_validate_package(root_ / "pkg");
  EXPECT_EQ(back.manifest.drive_id, "tiny_drive");
  EXPECT_EQ(back.manifest.vehicle_id, "veh_tiny");
  EXPECT_EQ(back.manifest.world, "unit-test");
  EXPECT_EQ(back.manifest.producer, "unit test");
  EXPECT_EQ(back.manifest.pol_level, PolLevel::DualLLLR);
  EXPECT_EQ(back.manifest.gridmap.num_bands, 5);
  EXPECT_DOUBLE_EQ(back.manifest.start_time_s, 100.0);
  EXPECT_DOUBLE_EQ(back.manifest.end_time_s, 102.0);
  EXPECT_NEAR(back.manifest.distance_m, 10.0, 0.01);
  EXPECT_EQ(back.manifest.sensors.size(), 1U);
  EXPECT_EQ(back.trajectory.size(), 101U);
  EXPECT_EQ(back.points.size(), result.points.size());
  EXPECT_EQ(back.lines.size(), result.lines.size());
  EXPECT_EQ(m.files[0].sha256, back.manifest.files[0].sha256);
  // Every observed cell of the radar gridmap is in the GeoTIFF with its count.
  const GridmapRaster g = read_gridmap(back);
  const radar::CellBox b = result.gridmap.bounds();
  std::size_t observed = 0;
  for (int row = 0; row < g.height; ++row) {
    for (int col = 0; col < g.width; ++col) {
      const std::uint32_t n = result.gridmap.count(b.min_ix + col, b.max_iy - 1 - row);
      ASSERT_EQ(g.count[static_cast<std::size_t>(row) * g.width + col], n);
      observed += n > 0;
    }
  }
  EXPECT_GT(observed, 100U);
}

}  // namespace
}  // namespace polmap::mapping
