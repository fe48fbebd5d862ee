// What is SQLite's own in SqliteMapStore, against a real SQLite file in a temp dir: schema
// and migrations of older files, WAL + foreign keys, the R*Tree side tables, the migration of
// archive-stored packages. The behaviour of the MapStore interface is tested on every
// backend by store_contract_*_test.cpp.
#include "polmap/mapping_service/sqlite_store.hpp"

#include <gtest/gtest.h>
#include <sqlite3.h>

#include <atomic>
#include <fstream>
#include <random>
#include <set>
#include <thread>

#include "mapping_service/package_fixture.hpp"
#include "mapping_service/store/contract_packages.hpp"
#include "mapping_service/store/exec_sql.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {
using testing::exec_sql;
namespace fs = std::filesystem;

struct TempDir : polmap::test::TestDir {
  TempDir() : TestDir("store") {}
};

using testing::kOrigin;
using testing::make_package;

/// Writes a package-shaped ustar archive (the three members; `content` as manifest.json,
/// the store does not validate) and returns (path, content hash).
std::pair<fs::path, std::string> write_archive(const fs::path& dir, const std::string& name,
                                               const std::string& content) {
  const fs::path p = dir / (name + ".tar");
  std::ofstream(p, std::ios::binary) << write_ustar({{kManifestFileName, content},
                                                     {kGridmapFileName, "tif " + name},
                                                     {kCandidatesFileName, "gpkg " + name}});
  return {p, content_etag(content)};
}

/// Puts pkg with a fake archive (write_archive(dir, name, content)).
PutDriveResult put_with_archive(SqliteMapStore& store, const fs::path& dir, const DrivePackage& pkg,
                                const std::string& name, const std::string& content) {
  const auto [tar, hash] = write_archive(dir, name, content);
  return store.put_drive(pkg, tar, hash);
}

std::int64_t count_rows(const fs::path& db, const std::string& sql) {
  sqlite3* h = nullptr;
  EXPECT_EQ(sqlite3_open_v2(db.c_str(), &h, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* s = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(h, sql.c_str(), -1, &s, nullptr), SQLITE_OK) << sql;
  std::int64_t n = -1;
  if (sqlite3_step(s) == SQLITE_ROW) n = sqlite3_column_int64(s, 0);
  sqlite3_finalize(s);
  sqlite3_close(h);
  return n;
}

std::size_t entries(const fs::path& dir) {
  return static_cast<std::size_t>(
      std::distance(fs::directory_iterator(dir), fs::directory_iterator{}));
}

TEST(SqliteStore, OpensWithWalForeignKeysAndMigrationsOnce) {
  TempDir tmp;
  const fs::path db = tmp.path() / "map.db";
  {
    SqliteMapStore store(db);
    EXPECT_EQ(store.pragma("journal_mode"), "wal");
    EXPECT_EQ(store.pragma("foreign_keys"), "1");
    EXPECT_EQ(store.schema_version(), sqlite_store_migrations().back().version);
  }
  {
    SqliteMapStore again(db);  // reopen: nothing re-applied, nothing fails
    EXPECT_EQ(again.schema_version(), sqlite_store_migrations().back().version);
  }
  EXPECT_EQ(count_rows(db, "SELECT COUNT(*) FROM schema_migrations"),
            static_cast<std::int64_t>(sqlite_store_migrations().size() - 1));
  EXPECT_EQ(count_rows(db, "SELECT COUNT(*) FROM sqlite_master WHERE name = 'candidates_rtree'"),
            1);
}

TEST(SqliteStore, UpgradesAnOlderDatabaseByApplyingOnlyMissingMigrations) {
  TempDir tmp;
  const fs::path db = tmp.path() / "map.db";
  {
    SqliteMapStore store(db);
    (void)put_with_archive(store, tmp.path(), make_package("a", 3, 1, 1), "a", "A");
    EXPECT_EQ(store.drive_trajectory("a").size(), 10U);  // 10 m apart: all kept
  }
  // Turn it into a schema-1 database (as written by an older build).
  exec_sql(db,
           "DROP TABLE hdmap_comparisons; DROP INDEX landmarks_key; "
           "DROP TABLE localization_run_cells; DROP TABLE localization_runs; "
           "DROP TABLE build_jobs; DROP TABLE gridmap_sum_cover; DROP TABLE gridmap_sum_inputs; "
           "DROP TABLE gridmap_sums; "
           "DROP TABLE gridmap_mechanism_tiles; "
           "DROP TABLE upload_sessions; DROP TABLE drive_trajectories; "
           "DROP TABLE landmark_changes; DROP INDEX landmarks_support_of; "
           "ALTER TABLE landmarks DROP COLUMN support_of; "
           "DELETE FROM schema_migrations WHERE version >= 2;");
  SqliteMapStore store(db);
  const int latest = sqlite_store_migrations().back().version;
  EXPECT_EQ(store.schema_version(), latest);
  EXPECT_EQ(count_rows(db, "SELECT COUNT(*) FROM sqlite_master WHERE name = 'landmark_changes'"),
            1);
  EXPECT_EQ(store.get_drive("a")->num_points, 3);    // data kept
  EXPECT_TRUE(store.drive_trajectory("a").empty());  // ingested before migration 2
  (void)put_with_archive(store, tmp.path(), make_package("b", 3, 1, 2), "b", "B");
  const auto traj = store.drive_trajectory("b");
  ASSERT_EQ(traj.size(), 10U);
  EXPECT_DOUBLE_EQ(traj[3].time_s, 13.0);
  EXPECT_THROW((void)store.drive_trajectory("nope"), NotFoundError);
  EXPECT_EQ(count_rows(db, "SELECT COUNT(*) FROM schema_migrations"), latest);
}

TEST(SqliteStore, MigrationsAreTheSectionsOfStoreSql) {
  // schema/store.sql is embedded at build time: the migrations are its sections, in order.
  std::ifstream f(std::string(POLMAP_SOURCE_DIR) + "/schema/store.sql");
  ASSERT_TRUE(f) << "schema/store.sql missing";
  const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const auto& m = sqlite_store_migrations();
  ASSERT_GE(m.size(), 3U);
  for (std::size_t i = 0; i < m.size(); ++i) {
    EXPECT_EQ(m[i].version, static_cast<int>(i));
    EXPECT_NE(text.find(std::string(m[i].sql)), std::string::npos) << "migration " << i;
  }
  EXPECT_EQ(m[0].name, "bootstrap");
  EXPECT_EQ(m[1].name, "initial schema");
  EXPECT_TRUE(m[0].sql.starts_with("CREATE TABLE IF NOT EXISTS schema_migrations"));
  EXPECT_TRUE(m[2].sql.starts_with("CREATE TABLE drive_trajectories"));
}

TEST(SqliteStore, StoreSqlParserRejectsMalformedSections) {
  const auto ok =
      parse_store_migrations("-- bootstrap\nSELECT 1;\n-- migration 1: one\nSELECT 2;\n");
  ASSERT_EQ(ok.size(), 2U);
  EXPECT_EQ(ok[1].name, "one");
  EXPECT_EQ(ok[1].sql, "SELECT 2;");
  EXPECT_THROW((void)parse_store_migrations("SELECT 1;"), FormatError);
  EXPECT_THROW((void)parse_store_migrations("-- migration 1: a\nSELECT 1;"), FormatError);
  EXPECT_THROW(
      (void)parse_store_migrations("-- bootstrap\nSELECT 1;\n-- migration 2: skip\nSELECT 2;"),
      FormatError);
  EXPECT_THROW((void)parse_store_migrations("-- bootstrap\nSELECT 1;\n-- migration 1: empty\n  \n"),
               FormatError);
  EXPECT_THROW(
      (void)parse_store_migrations("-- bootstrap\nSELECT 1;\n-- migration x: bad\nSELECT 2;"),
      FormatError);
}

TEST(SqliteStore, DeleteDriveRemovesRowsIndexEntriesAndFiles) {
  TempDir tmp;
  const fs::path db = tmp.path() / "map.db";
  SqliteMapStore store(db);
  const auto a = put_with_archive(store, tmp.path(), make_package("a", 30, 5, 1), "a", "A");
  const auto b = put_with_archive(store, tmp.path(), make_package("b", 20, 4, 2), "b", "B");
  EXPECT_TRUE(store.delete_drive("a"));
  EXPECT_FALSE(store.delete_drive("a"));
  EXPECT_FALSE(store.get_drive("a").has_value());
  EXPECT_FALSE(fs::exists(a.drive.package_path));
  EXPECT_TRUE(fs::exists(b.drive.package_path));
  const auto c = store.candidates_in(std::nullopt);
  EXPECT_EQ(c.points.size(), 20U);
  EXPECT_EQ(c.lines.size(), 4U);
  EXPECT_EQ(count_rows(db, "SELECT COUNT(*) FROM candidates_rtree"), 24);
  EXPECT_EQ(count_rows(db, "SELECT COUNT(*) FROM drives_rtree"), 1);
  EXPECT_EQ(count_rows(
                db, "SELECT COUNT(*) FROM candidates WHERE drive = " + std::to_string(a.drive.row)),
            0);
}

// Stores of older versions kept the upload archive itself and GDAL read it through
// /vsitar/ (whose reading of headers differs from the validator's): the owner's open
// replaces each archive by its members and re-validates; what no longer validates leaves.
class ArchivedPackageMigration : public ::testing::Test {
 protected:
  void SetUp() override {
    drive_ = polmap::mapping::testing::make_synthetic_drive();
    write_drive_package(drive_.pkg, drive_.raster, tmp_.path() / "pkg");
    db_ = tmp_.path() / "map.db";
  }
  /// Stores the package, then rewrites the store as an older version left it: the
  /// archive `tar_bytes` in <hash>/drive.tar, the row naming it.
  std::string put_as_archive(const std::string& tar_bytes) {
    SqliteMapStore store(db_);
    const auto pkg = read_and_validate_package(tmp_.path() / "pkg");
    const auto r = store.put_drive(pkg, tmp_.path() / "pkg", pkg.content_sha256);
    fs::remove_all(r.drive.package_path);
    fs::create_directories(r.drive.package_path);
    std::ofstream(r.drive.package_path / "drive.tar", std::ios::binary) << tar_bytes;
    sqlite3* h = nullptr;
    EXPECT_EQ(sqlite3_open(db_.c_str(), &h), SQLITE_OK);
    EXPECT_EQ(sqlite3_exec(h, "UPDATE drives SET package_path = content_hash || '/drive.tar'",
                           nullptr, nullptr, nullptr),
              SQLITE_OK);
    sqlite3_close(h);
    return r.drive.content_hash;
  }
  TempDir tmp_;
  polmap::mapping::testing::SyntheticDrive drive_;
  fs::path db_;
};

TEST_F(ArchivedPackageMigration, ArchivesBecomeTheirValidatedMembers) {
  const std::string hash = put_as_archive(pack_drive_package(tmp_.path() / "pkg"));
  SqliteMapStore store(db_);
  EXPECT_EQ(store.archive_migration().migrated, 1U);
  EXPECT_TRUE(store.archive_migration().quarantined.empty());
  const auto d = store.get_drive(drive_.pkg.manifest.drive_id);
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->package_path, store.drive_store_dir() / hash);
  EXPECT_FALSE(fs::exists(d->package_path / "drive.tar"));
  EXPECT_EQ(entries(d->package_path), 3U);
  const auto pkg = read_and_validate_package(d->package_path);
  EXPECT_EQ(pkg.points.size(), drive_.pkg.points.size());
  EXPECT_EQ(store.candidates_in(std::nullopt).points.size(), drive_.pkg.points.size());
}

TEST_F(ArchivedPackageMigration, AnArchiveThatNoLongerValidatesIsQuarantined) {
  // Validated once by older rules; today's GeoPackage screen rejects a view.
  const fs::path bad = tmp_.path() / "bad";
  fs::copy(tmp_.path() / "pkg", bad);
  sqlite3* h = nullptr;
  ASSERT_EQ(sqlite3_open((bad / kCandidatesFileName).c_str(), &h), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(h, "CREATE VIEW v AS SELECT 1", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(h);
  {  // re-hash, so that only the GeoPackage's content is wrong
    std::ifstream in(bad / kManifestFileName);
    auto j = nlohmann::json::parse(in);
    std::ifstream g(bad / kCandidatesFileName, std::ios::binary);
    const std::string gpkg(std::istreambuf_iterator<char>(g), {});
    for (auto& f : j["files"]) {
      if (f["name"] == kCandidatesFileName) {
        f["size_bytes"] = gpkg.size();
        f["sha256"] = sha256_hex(gpkg);
      }
    }
    std::ofstream(bad / kManifestFileName, std::ios::trunc) << j.dump(2);
  }
  std::vector<TarMember> members;
  for (const char* name : {kManifestFileName, kGridmapFileName, kCandidatesFileName}) {
    std::ifstream in(bad / name, std::ios::binary);
    members.push_back({name, std::string(std::istreambuf_iterator<char>(in), {})});
  }
  const std::string hash = put_as_archive(write_ustar(members));
  SqliteMapStore store(db_);
  EXPECT_EQ(store.archive_migration().migrated, 0U);
  ASSERT_EQ(store.archive_migration().quarantined.size(), 1U);
  EXPECT_NE(store.archive_migration().quarantined[0].find("unexpected view 'v'"), std::string::npos)
      << store.archive_migration().quarantined[0];
  EXPECT_FALSE(store.get_drive(drive_.pkg.manifest.drive_id).has_value());
  EXPECT_TRUE(store.candidates_in(std::nullopt).points.empty());
  EXPECT_TRUE(fs::is_regular_file(store.drive_store_dir() / "quarantine" / (hash + ".tar")));
  EXPECT_FALSE(fs::exists(store.drive_store_dir() / hash));
}

TEST_F(ArchivedPackageMigration, OnlyTheOwnerMigratesAndOnlyOnce) {
  (void)put_as_archive(pack_drive_package(tmp_.path() / "pkg"));
  {
    SqliteMapStore owner(db_);
    SqliteMapStore second(db_);  // another process's open: no migration, no sweep
    EXPECT_EQ(owner.archive_migration().migrated, 1U);
    EXPECT_EQ(second.archive_migration().migrated, 0U);
  }
  SqliteMapStore again(db_);
  EXPECT_EQ(again.archive_migration().migrated, 0U);
  EXPECT_TRUE(again.get_drive(drive_.pkg.manifest.drive_id).has_value());
}

}  // namespace
}  // namespace polmap::mapping
