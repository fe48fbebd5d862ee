// Drive package validation: every corruption gives an error naming the file and the field.
#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>
#include <sqlite3.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <nlohmann/json.hpp>

#include "mapping_service/package_fixture.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::make_synthetic_drive;

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}
void spit(const fs::path& p, const std::string& s) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << s;
}

class PackageValidationTest : public ::testing::Test {
 protected:
  void SetUp() override {
    GDALAllRegister();
    root_ = polmap::test::unique_test_dir("val");
    drive_ = make_synthetic_drive();
    dir_ = root_ / "pkg";
    // One written package per suite; each test corrupts its own copy.
    if (template_dir().empty()) {
      template_dir() = polmap::test::unique_test_dir("val-template") / "pkg";
      write_drive_package(drive_.pkg, drive_.raster, template_dir());
    }
    fs::copy(template_dir(), dir_);
  }
  void TearDown() override { fs::remove_all(root_); }
  static void TearDownTestSuite() {
    if (!template_dir().empty()) fs::remove_all(template_dir().parent_path());
    template_dir().clear();
  }
  static fs::path& template_dir() {
    static fs::path dir;
    return dir;
  }

  void edit_manifest(const std::function<void(json&)>& fn) {
    json j = json::parse(slurp(dir_ / "manifest.json"));
    fn(j);
    spit(dir_ / "manifest.json", j.dump(2));
  }
  /// Re-hashes the data files so only the injected defect remains.
  void refresh_manifest() {
    edit_manifest([&](json& j) {
      for (auto& f : j["files"]) {
        const std::string data = slurp(dir_ / f["name"].get<std::string>());
        f["size_bytes"] = data.size();
        f["sha256"] = sha256_hex(data);
      }
    });
  }
  /// Validation must fail with exception type E, naming `file` and `field`.
  template <typename E>
  PackageError expect_error(const std::string& file, const std::string& field,
                            const std::string& fragment, int status) {
    try {
      (void)read_and_validate_package(dir_);
      ADD_FAILURE() << "no error for " << file << " " << field;
    } catch (const E& e) {
      const PackageError& err = e.error();
      EXPECT_EQ(err.file, file) << e.what();
      EXPECT_EQ(err.field, field) << e.what();
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
      EXPECT_EQ(err.http_status, status);
      EXPECT_EQ(err.what(), std::string(e.what()));
      // The non-throwing variant reports the same.
      const auto r = try_read_and_validate_package(dir_);
      EXPECT_FALSE(r.has_value());
      if (!r.has_value()) {
        EXPECT_EQ(r.error().file, file);
        EXPECT_EQ(r.error().field, field);
        EXPECT_EQ(r.error().http_status, status);
      }
      return err;
    } catch (const std::exception& e) {
      ADD_FAILURE() << "unexpected exception type: " << e.what();
    }
    return {};
  }

  fs::path root_;
  fs::path dir_;
  testing::SyntheticDrive drive_;
};

TEST_F(PackageValidationTest, ValidPackagePasses) {
  EXPECT_NO_THROW((void)read_and_validate_package(dir_));
  EXPECT_TRUE(try_read_and_validate_package(dir_).has_value());
}

TEST_F(PackageValidationTest, MissingManifestField) {
  edit_manifest([](json& j) { j.erase("pol_level"); });
  expect_error<PackageValidationError>("manifest.json", "pol_level", "missing required field", 422);
}

TEST_F(PackageValidationTest, MissingNestedField) {
  edit_manifest([](json& j) { j["origin"].erase("lat_deg"); });
  expect_error<PackageValidationError>("manifest.json", "origin.lat_deg", "missing", 422);
}

TEST_F(PackageValidationTest, WrongFieldType) {
  edit_manifest([](json& j) { j["cell_size_m"] = "0.1"; });
  expect_error<PackageFormatError>("manifest.json", "cell_size_m", "expected number, got string",
                                   400);
}

TEST_F(PackageValidationTest, WrongTypeInsideSensor) {
  edit_manifest([](json& j) { j["sensors"][1]["spec"]["bandwidth_hz"] = true; });
  expect_error<PackageFormatError>("manifest.json", "sensors[1].spec.bandwidth_hz", "expected",
                                   400);
}

TEST_F(PackageValidationTest, UnknownPolLevel) {
  edit_manifest([](json& j) { j["pol_level"] = "xx"; });
  const auto err =
      expect_error<PackageValidationError>("manifest.json", "pol_level", "unknown level 'xx'", 422);
  EXPECT_EQ(err.what().rfind("manifest.json: field 'pol_level': unknown level 'xx'", 0), 0U);
}

TEST_F(PackageValidationTest, UnsupportedFormatVersion) {
  edit_manifest([](json& j) { j["format_version"] = 3; });
  expect_error<PackageValidationError>("manifest.json", "format_version", "unsupported version 3",
                                       422);
}

TEST_F(PackageValidationTest, CrsNotTheDriveFrame) {
  edit_manifest([](json& j) { j["origin"]["lat_deg"] = 35.3; });
  expect_error<PackageValidationError>("manifest.json", "crs_proj", "LocalFrame", 422);
}

TEST_F(PackageValidationTest, BadDriveId) {
  edit_manifest([](json& j) { j["drive_id"] = "../etc/passwd"; });
  expect_error<PackageValidationError>("manifest.json", "drive_id", "[A-Za-z0-9._-]", 422);
}

TEST_F(PackageValidationTest, AnOversizedManifestIsRefusedBeforeParsing) {
  edit_manifest([](json& j) { j["notes"] = std::string(2u << 20, 'x'); });
  expect_error<PackageValidationError>("manifest.json", "", "larger than 1048576 bytes", 422);
}

TEST_F(PackageValidationTest, ANumberOverflowInTheManifestIsAFormatError) {
  std::string text = slurp(dir_ / "manifest.json");
  const auto at = text.find("\"distance_m\"");
  ASSERT_NE(at, std::string::npos);
  const auto colon = text.find(':', at), end = text.find_first_of(",}", colon);
  text.replace(colon + 1, end - colon - 1, " 1e400");
  spit(dir_ / "manifest.json", text);
  expect_error<PackageFormatError>("manifest.json", "", "not valid JSON", 400);
}

TEST_F(PackageValidationTest, ManifestNotJson) {
  spit(dir_ / "manifest.json", "{\"drive_id\": ");
  expect_error<PackageFormatError>("manifest.json", "", "not valid JSON", 400);
}

TEST_F(PackageValidationTest, BadSha256) {
  std::string gpkg = slurp(dir_ / "candidates.gpkg");
  gpkg[gpkg.size() / 2] ^= 0x01;
  spit(dir_ / "candidates.gpkg", gpkg);
  expect_error<PackageValidationError>("candidates.gpkg", "sha256",
                                       "does not match manifest.json files[1].sha256", 422);
}

TEST_F(PackageValidationTest, SizeMismatch) {
  spit(dir_ / "gridmap.tif", slurp(dir_ / "gridmap.tif") + "x");
  expect_error<PackageValidationError>("gridmap.tif", "size_bytes", "manifest.json files[0]", 422);
}

TEST_F(PackageValidationTest, MissingFile) {
  fs::remove(dir_ / "candidates.gpkg");
  expect_error<PackageValidationError>("candidates.gpkg", "", "missing", 422);
}

TEST_F(PackageValidationTest, TruncatedArchive) {
  const std::string tar = pack_drive_package(dir_);
  for (std::size_t cut : {tar.size() / 2, tar.size() - 1024, std::size_t{300}}) {
    const std::string_view truncated = std::string_view(tar).substr(0, cut);
    try {
      (void)validate_package_bytes(truncated);
      ADD_FAILURE() << "cut " << cut;
    } catch (const PackageFormatError& e) {
      EXPECT_EQ(e.error().file, "archive");
      EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("byte"), std::string::npos) << e.what();
    }
    const auto r = try_validate_package_bytes(truncated);
    ASSERT_FALSE(r.has_value());
    EXPECT_EQ(r.error().http_status, 400);
    EXPECT_EQ(r.error().file, "archive");
  }
  // Same through a file on disk.
  spit(root_ / "t.tar", tar.substr(0, tar.size() / 3));
  EXPECT_THROW((void)read_and_validate_package(root_ / "t.tar"), PackageFormatError);
}

TEST_F(PackageValidationTest, ArchiveMemberSet) {
  std::vector<TarMember> members{{"manifest.json", slurp(dir_ / "manifest.json")},
                                 {"gridmap.tif", slurp(dir_ / "gridmap.tif")}};
  auto r = try_validate_package_bytes(write_ustar(members));
  ASSERT_FALSE(r.has_value());
  EXPECT_EQ(r.error().file, "candidates.gpkg");
  EXPECT_EQ(r.error().http_status, 422);
  members.push_back({"candidates.gpkg", slurp(dir_ / "candidates.gpkg")});
  EXPECT_TRUE(try_validate_package_bytes(write_ustar(members)).has_value());
  members.push_back({"evil.sh", "rm -rf /"});
  r = try_validate_package_bytes(write_ustar(members));
  ASSERT_FALSE(r.has_value());
  EXPECT_EQ(r.error().file, "archive");
  EXPECT_NE(r.error().message.find("evil.sh"), std::string::npos);
}

TEST_F(PackageValidationTest, NotAnArchive) {
  const auto r = try_validate_package_bytes("this is not a tar file at all");
  ASSERT_FALSE(r.has_value());
  EXPECT_EQ(r.error().file, "archive");
  EXPECT_EQ(r.error().http_status, 400);
}

/// Rewrites gridmap.tif with `bands` bands (same size, tiling, CRS, geotransform).
void rewrite_tiff(const fs::path& path, int bands, const std::string& proj) {
  GDALDatasetUniquePtr src(GDALDataset::Open(path.c_str()));
  ASSERT_TRUE(src);
  const int w = src->GetRasterXSize(), h = src->GetRasterYSize();
  double gt[6];
  src->GetGeoTransform(gt);
  std::vector<std::string> desc;
  for (int b = 1; b <= src->GetRasterCount(); ++b)
    desc.push_back(src->GetRasterBand(b)->GetDescription());
  std::vector<float> band1(static_cast<std::size_t>(w) * h);
  ASSERT_EQ(
      src->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, w, h, band1.data(), w, h, GDT_Float32, 0, 0),
      CE_None);
  src.reset();
  fs::remove(path);
  const char* opts[] = {"TILED=YES", "BLOCKXSIZE=256", "BLOCKYSIZE=256", "COMPRESS=DEFLATE",
                        nullptr};
  GDALDatasetUniquePtr dst(GetGDALDriverManager()->GetDriverByName("GTiff")->Create(
      path.c_str(), w, h, bands, GDT_Float32, const_cast<char**>(opts)));
  ASSERT_TRUE(dst);
  dst->SetGeoTransform(gt);
  OGRSpatialReference srs;
  srs.SetFromUserInput(proj.c_str());
  dst->SetSpatialRef(&srs);
  for (int b = 1; b <= bands; ++b) {
    if (b <= static_cast<int>(desc.size()))
      dst->GetRasterBand(b)->SetDescription(desc[b - 1].c_str());
  }
  ASSERT_EQ(
      dst->GetRasterBand(1)->RasterIO(GF_Write, 0, 0, w, h, band1.data(), w, h, GDT_Float32, 0, 0),
      CE_None);
}

TEST_F(PackageValidationTest, GeoTiffWithWrongBandCount) {
  rewrite_tiff(dir_ / "gridmap.tif", 7,
               tiles::LocalFrame(drive_.pkg.manifest.origin).proj_string());
  refresh_manifest();
  const auto err = expect_error<PackageValidationError>(
      "gridmap.tif", "bands", "has 7 bands, pol_level 'full' needs 10", 422);
  EXPECT_EQ(err.what(), "gridmap.tif: field 'bands': has 7 bands, pol_level 'full' needs 10");
}

TEST_F(PackageValidationTest, GeoTiffWithWrongCrs) {
  rewrite_tiff(dir_ / "gridmap.tif", 10, tiles::LocalFrame({35.3, 138.8, 0}).proj_string());
  refresh_manifest();
  expect_error<PackageValidationError>("gridmap.tif", "crs", "is not manifest.json crs_proj", 422);
}

TEST_F(PackageValidationTest, NotAGeoTiff) {
  spit(dir_ / "gridmap.tif", "II*\0garbage");
  refresh_manifest();
  expect_error<PackageFormatError>("gridmap.tif", "", "not a readable GeoTIFF", 400);
}

TEST_F(PackageValidationTest, CovarianceWhereNothingWasObserved) {
  {
    GDALDatasetUniquePtr ds(GDALDataset::Open((dir_ / "gridmap.tif").c_str(), GDAL_OF_UPDATE));
    ASSERT_TRUE(ds);
    // Cell (col 10, row 10) lies in the observed band: zero its count only.
    float zero = 0.0F;
    ASSERT_EQ(
        ds->GetRasterBand(1)->RasterIO(GF_Write, 10, 10, 1, 1, &zero, 1, 1, GDT_Float32, 0, 0),
        CE_None);
  }
  refresh_manifest();
  expect_error<PackageValidationError>("gridmap.tif", "C_LL_LL", "at column 10 row 10 where N = 0",
                                       422);
}

/// Applies fn to feature `index` (0-based) of a layer of candidates.gpkg, in place.
void edit_feature(const fs::path& gpkg, const char* layer, int index,
                  const std::function<void(OGRFeature&)>& fn) {
  GDALDatasetUniquePtr ds(GDALDataset::Open(gpkg.c_str(), GDAL_OF_VECTOR | GDAL_OF_UPDATE));
  ASSERT_TRUE(ds);
  OGRLayer* l = ds->GetLayerByName(layer);
  ASSERT_NE(l, nullptr);
  std::unique_ptr<OGRFeature> f(l->GetFeature(index + 1));  // FIDs start at 1
  ASSERT_TRUE(f);
  fn(*f);
  ASSERT_EQ(l->SetFeature(f.get()), OGRERR_NONE);
}

TEST_F(PackageValidationTest, NanCoordinateAttribute) {
  edit_feature(dir_ / "candidates.gpkg", "points", 3,
               [](OGRFeature& f) { f.SetField("x_m", std::numeric_limits<double>::quiet_NaN()); });
  refresh_manifest();
  // SQLite stores NaN as NULL; either way the field is named.
  expect_error<PackageValidationError>("candidates.gpkg", "points.x_m", "feature 3", 422);
}

TEST_F(PackageValidationTest, NanGeometry) {
  CPLPushErrorHandler(CPLQuietErrorHandler);  // GDAL complains updating the NaN extent
  edit_feature(dir_ / "candidates.gpkg", "lines", 2, [](OGRFeature& f) {
    OGRLineString ls;
    ls.addPoint(std::numeric_limits<double>::quiet_NaN(), 35.2);
    ls.addPoint(138.8, 35.2);
    f.SetGeometry(&ls);
  });
  CPLPopErrorHandler();
  refresh_manifest();
  expect_error<PackageValidationError>("candidates.gpkg", "lines.geom",
                                       "feature 2: non-finite coordinate", 422);
}

TEST_F(PackageValidationTest, GeometryInconsistentWithFrameCoordinates) {
  edit_feature(dir_ / "candidates.gpkg", "points", 0, [](OGRFeature& f) {
    OGRPoint p(138.81, 35.23);  // ~700 m away from x_m/y_m
    f.SetGeometry(&p);
  });
  refresh_manifest();
  expect_error<PackageValidationError>("candidates.gpkg", "points.x_m",
                                       "from the drive-frame position", 422);
}

TEST_F(PackageValidationTest, PointOutsideGridmap) {
  const tiles::LocalFrame frame(drive_.pkg.manifest.origin);
  edit_feature(dir_ / "candidates.gpkg", "points", 5, [&](OGRFeature& f) {
    const Eigen::Vector2d xy{500.0, 500.0};
    const GeoPoint g = frame.to_geo(xy);
    f.SetField("x_m", xy.x());
    f.SetField("y_m", xy.y());
    OGRPoint p(g.lon_deg, g.lat_deg);
    f.SetGeometry(&p);
  });
  refresh_manifest();
  expect_error<PackageValidationError>("candidates.gpkg", "points.x_m",
                                       "feature 5: (500, 500) outside the gridmap extent", 422);
}

TEST_F(PackageValidationTest, TrajectoryTimesNotMonotonic) {
  const double t4 = drive_.pkg.trajectory[4].time_s;
  edit_feature(dir_ / "candidates.gpkg", "trajectory", 5,
               [&](OGRFeature& f) { f.SetField("time_s", t4); });
  refresh_manifest();
  expect_error<PackageValidationError>("candidates.gpkg", "trajectory.time_s", "feature 5: time",
                                       422);
}

TEST_F(PackageValidationTest, UnknownScatteringClass) {
  edit_feature(dir_ / "candidates.gpkg", "points", 1,
               [](OGRFeature& f) { f.SetField("scattering", "triple"); });
  refresh_manifest();
  expect_error<PackageValidationError>("candidates.gpkg", "points.scattering",
                                       "unknown class 'triple'", 422);
}

TEST_F(PackageValidationTest, CountsDisagreeWithManifest) {
  edit_manifest([](json& j) { j["counts"]["points"] = 24; });
  expect_error<PackageValidationError>("candidates.gpkg", "points",
                                       "25 features, manifest.json counts say 24", 422);
}

TEST_F(PackageValidationTest, ALyingFeatureCountIsNotBelieved) {
  // The uploader adds 5 points and keeps gpkg_ogr_contents (and the manifest) at 25:
  // counting by reading finds 30.
  {
    GDALDatasetUniquePtr ds(
        GDALDataset::Open((dir_ / "candidates.gpkg").c_str(), GDAL_OF_VECTOR | GDAL_OF_UPDATE));
    ASSERT_TRUE(ds);
    OGRLayer* l = ds->GetLayerByName("points");
    std::unique_ptr<OGRFeature> f(l->GetFeature(1));
    for (int k = 0; k < 5; ++k) {
      f->SetFID(OGRNullFID);
      ASSERT_EQ(l->CreateFeature(f.get()), OGRERR_NONE);
    }
  }
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open((dir_ / "candidates.gpkg").c_str(), &db), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(db,
                         "UPDATE gpkg_ogr_contents SET feature_count = 25 WHERE table_name = "
                         "'points'",
                         nullptr, nullptr, nullptr),
            SQLITE_OK);
  sqlite3_close(db);
  {  // GDAL itself now believes the lie
    GDALDatasetUniquePtr ds(GDALDataset::Open((dir_ / "candidates.gpkg").c_str(), GDAL_OF_VECTOR));
    ASSERT_EQ(ds->GetLayerByName("points")->GetFeatureCount(TRUE), 25);
  }
  refresh_manifest();
  expect_error<PackageValidationError>("candidates.gpkg", "points",
                                       "30 features, manifest.json counts say 25", 422);
}

TEST_F(PackageValidationTest, MissingLayer) {
  {
    GDALDatasetUniquePtr ds(
        GDALDataset::Open((dir_ / "candidates.gpkg").c_str(), GDAL_OF_VECTOR | GDAL_OF_UPDATE));
    ASSERT_TRUE(ds);
    for (int i = 0; i < ds->GetLayerCount(); ++i) {
      if (std::string(ds->GetLayer(i)->GetName()) == "lines") {
        ASSERT_EQ(ds->DeleteLayer(i), OGRERR_NONE);
      }
    }
  }
  refresh_manifest();
  expect_error<PackageValidationError>("candidates.gpkg", "lines", "layer missing", 422);
}

// ------------------------------------------------------------ GeoPackage pre-screen
// SQLite screens candidates.gpkg before GDAL opens it: its schema must be, statement for
// statement, what GDAL's writer creates for our layers; nothing else may run or be read.

class GpkgScreenTest : public PackageValidationTest {
 protected:
  /// Runs SQL on the package's candidates.gpkg as an attacker with sqlite3 would, then
  /// re-hashes the manifest so that only the GeoPackage content is wrong.
  void edit_gpkg_sql(const std::string& sql) {
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open((dir_ / "candidates.gpkg").c_str(), &db), SQLITE_OK);
    // GDAL's R-tree triggers call SpatiaLite-style functions plain sqlite3 lacks.
    sqlite3_db_config(db, SQLITE_DBCONFIG_ENABLE_TRIGGER, 0, nullptr);
    char* err = nullptr;
    const int rc = sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &err);
    EXPECT_EQ(rc, SQLITE_OK) << sql << ": " << (err != nullptr ? err : "");
    sqlite3_free(err);
    sqlite3_close(db);
    refresh_manifest();
  }
};

TEST_F(GpkgScreenTest, AViewIsRejected) {
  edit_gpkg_sql("CREATE VIEW points_view AS SELECT * FROM points");
  expect_error<PackageValidationError>("candidates.gpkg", "schema", "unexpected view 'points_view'",
                                       422);
}

TEST_F(GpkgScreenTest, AnExtraTriggerIsRejected) {
  edit_gpkg_sql("CREATE TRIGGER wipe AFTER INSERT ON points BEGIN DELETE FROM lines; END");
  expect_error<PackageValidationError>("candidates.gpkg", "schema", "unexpected trigger 'wipe'",
                                       422);
}

TEST_F(GpkgScreenTest, AnExtraTableIsRejected) {
  edit_gpkg_sql("CREATE TABLE notes(x TEXT); INSERT INTO notes VALUES ('hello')");
  expect_error<PackageValidationError>("candidates.gpkg", "schema", "unexpected table 'notes'",
                                       422);
}

TEST_F(GpkgScreenTest, AnAlteredLayerTableIsRejected) {
  edit_gpkg_sql("ALTER TABLE points ADD COLUMN extra REAL");
  expect_error<PackageValidationError>(
      "candidates.gpkg", "schema", "table 'points' differs from what GDAL's writer creates", 422);
}

TEST_F(GpkgScreenTest, AGdalTriggerWithAnotherBodyIsRejected) {
  // Same name as GDAL's feature-count trigger, different statement.
  edit_gpkg_sql(
      "DROP TRIGGER trigger_insert_feature_count_points; "
      "CREATE TRIGGER trigger_insert_feature_count_points AFTER INSERT ON points BEGIN "
      "DELETE FROM trajectory; END");
  expect_error<PackageValidationError>(
      "candidates.gpkg", "schema", "trigger 'trigger_insert_feature_count_points' differs", 422);
}

TEST_F(GpkgScreenTest, MetadataRowsMustBeTheWritersOwn) {
  edit_gpkg_sql(
      "INSERT INTO gpkg_extensions VALUES ('points', 'geom', 'gdal_evil', 'x', 'read-write')");
  expect_error<PackageValidationError>("candidates.gpkg", "gpkg_extensions", "rows differ", 422);
}

TEST_F(GpkgScreenTest, AContentsEntryForAnotherTableIsRejected) {
  // A gpkg_contents row would make GDAL expose (and read) any table as a layer.
  edit_gpkg_sql(
      "INSERT INTO gpkg_contents(table_name, data_type, identifier, srs_id) "
      "VALUES ('sqlite_sequence', 'attributes', 'seq', 0)");
  expect_error<PackageValidationError>("candidates.gpkg", "gpkg_contents", "rows differ", 422);
}

TEST_F(GpkgScreenTest, AValueOfTheWrongStorageClassIsRejected) {
  // GDAL would read the text as 0.0 without complaint.
  edit_gpkg_sql("UPDATE points SET strength = 'abc' WHERE fid = 3");
  expect_error<PackageValidationError>("candidates.gpkg", "points.strength",
                                       "feature fid 3 holds a text value", 422);
}

TEST_F(GpkgScreenTest, AStandardDeviationBeyondFloatRangeIsRejected) {
  // Finite as the stored double, +inf as the float the trajectory keeps (fuzz_package).
  edit_gpkg_sql("UPDATE trajectory SET std_east_m = 1e300 WHERE fid = 1");
  expect_error<PackageValidationError>("candidates.gpkg", "trajectory.std_east_m",
                                       "beyond the float range", 422);
}

TEST_F(GpkgScreenTest, AWalModeDatabaseIsRejected) {
  edit_gpkg_sql("PRAGMA journal_mode = WAL");
  expect_error<PackageValidationError>("candidates.gpkg", "journal_mode", "WAL mode", 422);
}

TEST_F(GpkgScreenTest, NotASqliteDatabase) {
  spit(dir_ / "candidates.gpkg", std::string(4096, 'x'));
  refresh_manifest();
  expect_error<PackageFormatError>("candidates.gpkg", "", "not a SQLite 3 database", 400);
}

TEST_F(GpkgScreenTest, CorruptPagesAreRejectedAsUnreadable) {
  std::string bytes = slurp(dir_ / "candidates.gpkg");
  ASSERT_GT(bytes.size(), 40960U);
  // Scribble over the b-tree pages after the schema page (page size 4096).
  for (std::size_t i = 8192; i < bytes.size() - 4096; i += 4096) {
    for (std::size_t k = 0; k < 64; ++k) bytes[i + k] = static_cast<char>(0xA5 ^ k);
  }
  spit(dir_ / "candidates.gpkg", bytes);
  refresh_manifest();
  const auto r = try_read_and_validate_package(dir_);
  ASSERT_FALSE(r.has_value());
  EXPECT_EQ(r.error().file, "candidates.gpkg") << r.error().what();
  EXPECT_EQ(r.error().http_status, 400) << r.error().what();
}

TEST_F(GpkgScreenTest, ValidationStopsAtItsTimeBudget) {
  PackageValidationConfig cfg;
  cfg.max_validation_s = 1e-9;  // expired before the first gridmap block is read
  const auto r = try_read_and_validate_package(dir_, cfg);
  ASSERT_FALSE(r.has_value());
  EXPECT_EQ(r.error().http_status, 413) << r.error().what();
  EXPECT_NE(r.error().message.find("time budget"), std::string::npos) << r.error().what();
  // Without a budget the same package passes.
  cfg.max_validation_s = 0.0;
  EXPECT_TRUE(try_read_and_validate_package(dir_, cfg).has_value());
}

}  // namespace
}  // namespace polmap::mapping
