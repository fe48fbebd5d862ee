// SqliteMapStore against a real SQLite file in a temp dir: schema/migrations,
// WAL + foreign keys, drive ingest (idempotent, all-or-nothing), deletes,
// R*Tree region queries vs brute force, map version atomicity, tile blobs.
#include "polmap/mapping_service/sqlite_store.hpp"

#include <gtest/gtest.h>
#include <sqlite3.h>

#include <atomic>
#include <fstream>
#include <random>
#include <set>
#include <thread>

#include "mapping_service/package_fixture.hpp"
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

const GeoPoint kOrigin{48.7758, 9.1829, 250.0};  // Stuttgart

/// A synthetic validated package: n points and m lines scattered in a
/// `extent_m` square around the drive origin, plus a short trajectory.
DrivePackage make_package(const std::string& drive_id, int n_points, int n_lines, unsigned seed,
                          double extent_m = 200.0, GeoPoint origin = kOrigin) {
  DrivePackage p;
  p.manifest.drive_id = drive_id;
  p.manifest.vehicle_id = "veh-1";
  p.manifest.start_time_s = 10.0;
  p.manifest.end_time_s = 70.0;
  p.manifest.origin = origin;
  p.manifest.pol_level = PolLevel::DualLLLR;
  p.manifest.distance_m = 500.0;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-extent_m / 2, extent_m / 2);
  for (int i = 0; i < n_points; ++i) {
    PointCandidate c;
    c.position_m = {u(rng), u(rng)};
    c.strength = 3.0 + i;
    c.power_db = -10.0;
    c.scattering = static_cast<ScatteringClass>(i % 4);
    c.num_cells = 5;
    p.points.push_back(c);
  }
  for (int i = 0; i < n_lines; ++i) {
    LineCandidate l;
    l.start_m = {u(rng), u(rng)};
    l.end_m = l.start_m + Eigen::Vector2d(u(rng) / 10, u(rng) / 10);
    l.strength = 0.5;
    p.lines.push_back(l);
  }
  const tiles::LocalFrame frame(origin);
  for (int i = 0; i < 10; ++i) {
    const GeoPoint g = frame.to_geo(Eigen::Vector2d(10.0 * i, 0.0));
    TrajectorySample t;
    t.time_s = 10.0 + i;
    t.lat_deg = g.lat_deg;
    t.lon_deg = g.lon_deg;
    p.trajectory.push_back(t);
  }
  return p;
}

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
           "DROP TABLE gridmap_sum_cover; DROP TABLE gridmap_sum_inputs; DROP TABLE gridmap_sums; "
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

TEST(SqliteStore, PutDriveRoundTripsRowsCandidatesAndFiles) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const auto pkg = make_package("drive_a", 50, 20, 1);
  const auto [tar, hash] = write_archive(tmp.path(), "a", "package bytes A");
  const auto r = store.put_drive(pkg, tar, hash);
  EXPECT_EQ(r.status, PutDriveResult::Status::Inserted);
  EXPECT_EQ(r.drive.drive_id, "drive_a");
  EXPECT_EQ(r.drive.content_hash, hash);
  EXPECT_EQ(r.drive.vehicle_id, "veh-1");
  EXPECT_EQ(r.drive.pol_level, PolLevel::DualLLLR);
  EXPECT_DOUBLE_EQ(r.drive.start_time_s, 10.0);
  EXPECT_DOUBLE_EQ(r.drive.end_time_s, 70.0);
  EXPECT_EQ(r.drive.num_points, 50);
  EXPECT_EQ(r.drive.num_lines, 20);
  EXPECT_EQ(r.drive.manifest.at("drive_id"), "drive_a");
  EXPECT_EQ(r.drive.manifest.at("pol_level"), "ll-lr");
  // An archive is stored as its members (what our ustar reader sees), never as an archive.
  EXPECT_EQ(r.drive.package_path, store.drive_store_dir() / hash);
  EXPECT_EQ(entries(r.drive.package_path), 3U);
  std::ifstream manifest(r.drive.package_path / kManifestFileName);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(manifest), {}), "package bytes A");
  EXPECT_EQ(r.drive.ingested_at.size(), 20U);

  const auto c = store.candidates_in(std::nullopt);
  ASSERT_EQ(c.points.size(), 50U);
  ASSERT_EQ(c.lines.size(), 20U);
  const tiles::LocalFrame frame(kOrigin);
  for (std::size_t i = 0; i < c.points.size(); ++i) {
    EXPECT_EQ(c.points[i].drive, r.drive.row);
    EXPECT_EQ(c.points[i].candidate.position_m, pkg.points[i].position_m);
    EXPECT_EQ(c.points[i].candidate.scattering, pkg.points[i].scattering);
    EXPECT_DOUBLE_EQ(c.points[i].candidate.strength, pkg.points[i].strength);
    const Eigen::Vector2d back = frame.to_local(c.points[i].position);
    EXPECT_LT((back - pkg.points[i].position_m).norm(), 1e-6);
    EXPECT_TRUE(r.drive.bbox.contains(c.points[i].position.lat_deg, c.points[i].position.lon_deg));
  }
  for (std::size_t i = 0; i < c.lines.size(); ++i) {
    EXPECT_EQ(c.lines[i].candidate.start_m, pkg.lines[i].start_m);
    EXPECT_EQ(c.lines[i].candidate.end_m, pkg.lines[i].end_m);
    EXPECT_LT((frame.to_local(c.lines[i].end) - pkg.lines[i].end_m).norm(), 1e-6);
  }
  EXPECT_EQ(store.list_drives().size(), 1U);
  EXPECT_TRUE(store.find_drive_by_hash(hash).has_value());
  const auto st = store.stats();
  EXPECT_EQ(st.drives, 1);
  EXPECT_EQ(st.point_candidates, 50);
  EXPECT_EQ(st.line_candidates, 20);
}

TEST(SqliteStore, PutDriveCopiesPackageDirectories) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const fs::path dir = tmp.path() / "pkgdir";
  fs::create_directories(dir);
  std::ofstream(dir / "manifest.json") << "{}";
  std::ofstream(dir / "gridmap.tif") << "tif";
  const auto r = store.put_drive(make_package("d", 1, 0, 2), dir, content_etag("dir package"));
  EXPECT_TRUE(fs::is_regular_file(r.drive.package_path / "manifest.json"));
  EXPECT_TRUE(fs::is_regular_file(r.drive.package_path / "gridmap.tif"));
}

TEST(SqliteStore, PutIsIdempotentByContentHashAndRejectsConflictingIds) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const auto pkg = make_package("drive_a", 10, 3, 1);
  const auto [tar, hash] = write_archive(tmp.path(), "a", "bytes A");
  const auto first = store.put_drive(pkg, tar, hash);
  const auto second = store.put_drive(pkg, tar, hash);
  EXPECT_EQ(second.status, PutDriveResult::Status::AlreadyPresent);
  EXPECT_EQ(second.drive.row, first.drive.row);
  EXPECT_EQ(store.list_drives().size(), 1U);
  EXPECT_EQ(store.candidates_in(std::nullopt).points.size(), 10U);

  const auto [tar2, hash2] = write_archive(tmp.path(), "a2", "other bytes, same drive id");
  EXPECT_THROW((void)store.put_drive(pkg, tar2, hash2), ConflictError);
  EXPECT_THROW((void)store.put_drive(pkg, tar2, "NOT-HEX"), ValidationError);
  EXPECT_EQ(store.list_drives().size(), 1U);
  EXPECT_EQ(entries(store.drive_store_dir()), 1U);
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

TEST(SqliteStore, InterruptedPutLeavesTheStoreUnchanged) {
  for (const std::string stage : {"files_copied", "rows_inserted", "files_renamed"}) {
    TempDir tmp;
    const fs::path db = tmp.path() / "map.db";
    SqliteStoreOptions opt;
    opt.fault_hook = [&](std::string_view s) {
      if (s == stage) throw std::runtime_error("simulated crash at " + stage);
    };
    SqliteMapStore store(db, opt);
    EXPECT_THROW((void)put_with_archive(store, tmp.path(), make_package("a", 40, 6, 1), "a", "A"),
                 std::runtime_error)
        << stage;
    EXPECT_TRUE(store.list_drives().empty()) << stage;
    EXPECT_EQ(count_rows(db, "SELECT COUNT(*) FROM candidates"), 0) << stage;
    EXPECT_EQ(count_rows(db, "SELECT COUNT(*) FROM candidates_rtree"), 0) << stage;
    EXPECT_EQ(count_rows(db, "SELECT COUNT(*) FROM drives_rtree"), 0) << stage;
    EXPECT_EQ(entries(store.drive_store_dir()), 0U) << stage;
  }
}

TEST(SqliteStore, ReopenSweepsCrashLeftovers) {
  TempDir tmp;
  const fs::path db = tmp.path() / "map.db";
  fs::path drives;
  {
    SqliteMapStore store(db);
    drives = store.drive_store_dir();
    (void)put_with_archive(store, tmp.path(), make_package("a", 3, 0, 1), "a", "A");
    (void)store.begin_map_version({{"notes", "crashed build"}});
  }
  // A hard crash between rename and commit leaves a hash-named dir without a
  // row; one during the copy leaves a .tmp- dir.
  fs::create_directories(drives / std::string(64, 'e'));
  fs::create_directories(drives / ".tmp-abc-1");
  SqliteStoreOptions opt;
  opt.orphan_grace_s = 0.0;
  SqliteMapStore store(db, opt);
  EXPECT_EQ(entries(drives), 1U);  // only drive "a"
  const auto versions = store.list_map_versions();
  ASSERT_EQ(versions.size(), 1U);
  EXPECT_EQ(versions[0].status, MapVersionStatus::Failed);
}

TEST(SqliteStore, ASecondOpenerNeverSweepsTheOwnersWork) {
  TempDir tmp;
  const fs::path db = tmp.path() / "map.db";
  SqliteStoreOptions opt;
  opt.orphan_grace_s = 0.0;
  SqliteMapStore owner(db, opt);
  EXPECT_TRUE(owner.owns_store());
  const std::int64_t v = owner.begin_map_version({{"notes", "running build"}});
  fs::create_directories(owner.drive_store_dir() / ".tmp-inflight-1");
  {
    // E.g. `polmap export --db` while the server builds: reads work, nothing is swept.
    SqliteMapStore reader(db, opt);
    EXPECT_FALSE(reader.owns_store());
    EXPECT_EQ(reader.get_map_version(v)->status, MapVersionStatus::Building);
    EXPECT_TRUE(fs::exists(owner.drive_store_dir() / ".tmp-inflight-1"));
  }
  EXPECT_EQ(owner.get_map_version(v)->status, MapVersionStatus::Building);
  owner.put_landmarks(v, {}, {});
  owner.publish_map_version(v, {}, true);  // the owner's build still publishes
  EXPECT_EQ(owner.current_map_version(), v);
}

TEST(SqliteStore, RegionQueryMatchesBruteForce) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  for (int d = 0; d < 4; ++d) {
    (void)put_with_archive(store, tmp.path(),
                           make_package("d" + std::to_string(d), 400, 100, 10 + d, 1500.0),
                           "d" + std::to_string(d), "D" + std::to_string(d));
  }
  const auto all = store.candidates_in(std::nullopt);
  ASSERT_EQ(all.points.size(), 1600U);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.008, 0.008);
  for (int q = 0; q < 40; ++q) {
    const double lat0 = kOrigin.lat_deg + u(rng), lon0 = kOrigin.lon_deg + u(rng);
    const tiles::GeoBox box{lat0, lon0, lat0 + std::abs(u(rng)) / 2, lon0 + std::abs(u(rng)) / 2};
    std::set<std::int64_t> expect, got;
    for (const auto& p : all.points) {
      if (p.position.lat_deg >= box.min_lat_deg && p.position.lat_deg <= box.max_lat_deg &&
          p.position.lon_deg >= box.min_lon_deg && p.position.lon_deg <= box.max_lon_deg) {
        expect.insert(p.id);
      }
    }
    for (const auto& l : all.lines) {
      const double la0 = std::min(l.start.lat_deg, l.end.lat_deg);
      const double la1 = std::max(l.start.lat_deg, l.end.lat_deg);
      const double lo0 = std::min(l.start.lon_deg, l.end.lon_deg);
      const double lo1 = std::max(l.start.lon_deg, l.end.lon_deg);
      if (la1 >= box.min_lat_deg && la0 <= box.max_lat_deg && lo1 >= box.min_lon_deg &&
          lo0 <= box.max_lon_deg) {
        expect.insert(l.id);
      }
    }
    const auto r = store.candidates_in(box);
    for (const auto& p : r.points) got.insert(p.id);
    for (const auto& l : r.lines) got.insert(l.id);
    EXPECT_EQ(got, expect) << "query " << q;
  }
  // Exclusion by drive id.
  const auto ex = store.candidates_in(std::nullopt, std::vector<std::string>{"d1", "d2"});
  EXPECT_EQ(ex.points.size(), 800U);
  for (const auto& p : ex.points) EXPECT_NE(p.drive, store.get_drive("d1")->row);
  EXPECT_THROW((void)store.candidates_in(std::nullopt, std::vector<std::string>{"nope"}),
               NotFoundError);
  // Drives by box.
  EXPECT_EQ(store
                .drives_in({kOrigin.lat_deg - 0.001, kOrigin.lon_deg - 0.001,
                            kOrigin.lat_deg + 0.001, kOrigin.lon_deg + 0.001})
                .size(),
            4U);
  EXPECT_TRUE(store.drives_in({0.0, 0.0, 1.0, 1.0}).empty());
}

StoredPointLandmark point_lm(double dlat, std::int64_t key,
                             std::vector<std::int64_t> support = {}) {
  StoredPointLandmark p;
  p.key = key;
  p.position = {kOrigin.lat_deg + dlat, kOrigin.lon_deg, 0.0};
  p.support_drives = 2;
  p.spread_m = 0.05;
  p.scattering = ScatteringClass::Even;
  p.support = std::move(support);
  return p;
}

TEST(SqliteStore, MapVersionsPublishAtomicallyAndReadersSeeOnlyPublishedMaps) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  (void)put_with_archive(store, tmp.path(), make_package("a", 5, 0, 1), "a", "A");
  const auto cands = store.candidates_in(std::nullopt);
  const tiles::TileKey key =
      tiles::tile_at(kOrigin.lat_deg, kOrigin.lon_deg, tiles::kLocalizationZoom);

  EXPECT_FALSE(store.current_map_version().has_value());
  const auto v1 = store.begin_map_version({{"notes", "v1"}});
  std::vector<StoredPointLandmark> pts1{point_lm(0.0, 1, {cands.points[0].id, cands.points[1].id}),
                                        point_lm(0.0001, 2)};
  StoredLineLandmark line;
  line.key = 3;
  line.polyline = {{kOrigin.lat_deg, kOrigin.lon_deg, 0},
                   {kOrigin.lat_deg + 0.0002, kOrigin.lon_deg + 0.0002, 0}};
  line.support_drives = 3;
  store.put_landmarks(v1, pts1, std::vector<StoredLineLandmark>{line});
  store.put_tiles(v1, TileLayer::Localization,
                  std::vector<TileWrite>{{key, "", "tile v1", false, 2, 1}});
  EXPECT_THROW((void)store.landmarks_in(v1, std::nullopt), NotFoundError);  // still building
  EXPECT_THROW((void)store.get_tile(v1, TileLayer::Localization, key), NotFoundError);
  EXPECT_THROW(store.set_current_map_version(v1), NotFoundError);
  store.publish_map_version(v1, {{"landmarks", 3}});
  EXPECT_EQ(store.current_map_version(), v1);
  const auto l1 = store.landmarks_in(v1, std::nullopt);
  ASSERT_EQ(l1.points.size(), 2U);
  ASSERT_EQ(l1.lines.size(), 1U);
  EXPECT_EQ(l1.points[0].support,
            (std::vector<std::int64_t>{cands.points[0].id, cands.points[1].id}));
  EXPECT_EQ(l1.lines[0].polyline.size(), 2U);
  EXPECT_DOUBLE_EQ(l1.lines[0].polyline[1].lat_deg, kOrigin.lat_deg + 0.0002);
  EXPECT_EQ(l1.points[0].scattering, ScatteringClass::Even);
  const auto t1 = store.get_tile(v1, TileLayer::Localization, key);
  ASSERT_TRUE(t1);
  EXPECT_EQ(t1->payload, "tile v1");
  EXPECT_EQ(t1->etag, content_etag("tile v1"));
  EXPECT_EQ(store.get_tile_etag(v1, TileLayer::Localization, key), t1->etag);
  EXPECT_THROW(store.publish_map_version(v1, {}), ValidationError);  // immutable now

  // Build v2 while a reader thread keeps reading: it must only ever see
  // complete maps (v1 with 2 points or v2 with 400 points), never a mix.
  std::atomic<bool> stop{false};
  std::atomic<int> reads{0}, bad{0};
  std::thread reader([&] {
    while (!stop) {
      const auto v = store.current_map_version();
      const auto lm = store.landmarks_in(*v, std::nullopt);
      const std::size_t expect = *v == v1 ? 2U : 400U;
      if (lm.points.size() != expect) ++bad;
      ++reads;
    }
  });
  const auto v2 = store.begin_map_version({{"notes", "v2"}});
  for (int batch = 0; batch < 4; ++batch) {
    std::vector<StoredPointLandmark> pts;
    for (int i = 0; i < 100; ++i)
      pts.push_back(point_lm(1e-6 * (batch * 100 + i), 100 + batch * 100 + i));
    store.put_landmarks(v2, pts, {});
    EXPECT_EQ(store.current_map_version(), v1);
  }
  store.put_tiles(v2, TileLayer::Localization,
                  std::vector<TileWrite>{{key, t1->etag, "", true, 2, 1}});  // reused blob
  store.publish_map_version(v2, {});
  while (reads < 20) std::this_thread::yield();
  stop = true;
  reader.join();
  EXPECT_EQ(bad, 0);
  EXPECT_EQ(store.current_map_version(), v2);
  EXPECT_EQ(store.stats().tile_blobs, 1);  // shared by both versions
  EXPECT_EQ(store.get_tile(v2, TileLayer::Localization, key)->payload, "tile v1");

  // Rollback, delete, failed builds.
  EXPECT_THROW((void)store.delete_map_version(v2), ConflictError);
  store.set_current_map_version(v1);
  EXPECT_TRUE(store.delete_map_version(v2));
  EXPECT_EQ(store.stats().tile_blobs, 1);  // still used by v1
  const auto v3 = store.begin_map_version({});
  store.put_tiles(v3, TileLayer::Gridmap, std::vector<TileWrite>{{key, "", "grid", false, 0, 0}});
  store.fail_map_version(v3, "test failure");
  const auto info3 = store.get_map_version(v3);
  ASSERT_TRUE(info3);
  EXPECT_EQ(info3->status, MapVersionStatus::Failed);
  EXPECT_EQ(info3->error, "test failure");
  EXPECT_EQ(store.stats().tile_blobs, 1);  // failed build's blob dropped
  EXPECT_TRUE(store.get_map_version(v1)->current);
  EXPECT_EQ(store.get_map_version(v1)->statistics.at("landmarks"), 3);
  EXPECT_EQ(store.get_map_version(v1)->parameters.at("notes"), "v1");
}

TEST(SqliteStore, LandmarkBoxQueryAndDriveDeleteKeepsPublishedLandmarks) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  (void)put_with_archive(store, tmp.path(), make_package("a", 5, 0, 1), "a", "A");
  const auto cands = store.candidates_in(std::nullopt);
  const auto v = store.begin_map_version({});
  std::vector<StoredPointLandmark> pts;
  for (int i = 0; i < 50; ++i) pts.push_back(point_lm(1e-5 * i, i, {cands.points[0].id}));
  store.put_landmarks(v, pts, {});
  store.publish_map_version(v, {});
  const tiles::GeoBox box{kOrigin.lat_deg + 1e-5 * 9.5, kOrigin.lon_deg - 1e-3,
                          kOrigin.lat_deg + 1e-5 * 20.5, kOrigin.lon_deg + 1e-3};
  EXPECT_EQ(store.landmarks_in(v, box).points.size(), 11U);
  EXPECT_TRUE(store.delete_drive("a"));
  const auto after = store.landmarks_in(v, std::nullopt);
  EXPECT_EQ(after.points.size(), 50U);
  EXPECT_TRUE(after.points[0].support.empty());
}

TEST(SqliteStore, ADriveDeletedDuringABuildDoesNotFailIt) {
  // The build read the candidates of "a" and "b"; "a" is erased before its landmarks are
  // stored (found by the soak: the build failed on a foreign key).
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  (void)put_with_archive(store, tmp.path(), make_package("a", 3, 0, 1), "a", "A");
  (void)put_with_archive(store, tmp.path(), make_package("b", 3, 0, 2), "b", "B");
  const auto cands = store.candidates_in(std::nullopt);
  ASSERT_EQ(cands.points.size(), 6U);
  const auto v = store.begin_map_version({});
  EXPECT_TRUE(store.delete_drive("a"));
  std::vector<StoredPointLandmark> pts;
  pts.push_back(point_lm(0.0, 1, {cands.points[0].id, cands.points[3].id}));
  store.put_landmarks(v, pts, {});
  store.publish_map_version(v, {});
  const auto lm = store.landmarks_in(v, std::nullopt);
  ASSERT_EQ(lm.points.size(), 1U);
  // Only the link to the surviving drive's candidate remains.
  EXPECT_EQ(lm.points[0].support, std::vector<std::int64_t>{cands.points[3].id});
}

TEST(SqliteStore, ConcurrentPutsOfTheSameContentInsertOnce) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const auto pkg = make_package("a", 20, 2, 1);
  const auto [tar, hash] = write_archive(tmp.path(), "a", "A");
  std::atomic<int> inserted{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&] {
      if (store.put_drive(pkg, tar, hash).status == PutDriveResult::Status::Inserted) ++inserted;
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(inserted, 1);
  EXPECT_EQ(store.candidates_in(std::nullopt).points.size(), 20U);
  EXPECT_EQ(entries(store.drive_store_dir()), 1U);
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
