// transfer_store (store_transfer.hpp) on real SQLite and a real PostgreSQL (the test
// process's throw-away cluster, store_backends.hpp): a store with drives, two builds
// (landmarks, changes, tiles, merged gridmap sums), an upload session and a deleted drive
// goes SQLite -> PostgreSQL -> SQLite and comes back equal; a map built afterwards on each
// copy equals one built on the source; non-empty destinations, other schema versions,
// unknown tables, running builds and failures midway are refused or leave nothing behind.
#include "polmap/mapping_service/store_transfer.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <map>
#include <set>

#include "mapping_service/build/builder_fixtures.hpp"
#include "mapping_service/store/exec_sql.hpp"
#include "mapping_service/store/store_backends.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/mapping_service/open_store.hpp"
#include "polmap/util/file.hpp"

namespace polmap::mapping {
namespace {
namespace fs = std::filesystem;
using namespace builder_fixtures;  // NOLINT: test fixtures
using testing::PostgresCluster;

PackageWriteOptions v2() {
  PackageWriteOptions o;
  o.format_version = 2;
  return o;
}

/// A real package (format 2, gridmap strip) of drive d of world w, validated, put.
void put_package(MapStore& store, const fs::path& tmp, const World& w, int d,
                 const std::string& name, std::optional<Eigen::Vector2d> origin_m = std::nullopt,
                 double start_time_s = 0.0) {
  put_real_package(store, tmp, w, d, name, v2(), origin_m, start_time_s);
}

/// Every table's rows, compared through the interface (what a server reads).
void expect_same_store(const MapStore& a, const MapStore& b, const std::string& what) {
  SCOPED_TRACE(what);
  const auto da = a.list_drives(), db = b.list_drives();
  ASSERT_EQ(da.size(), db.size());
  for (std::size_t i = 0; i < da.size(); ++i) {
    EXPECT_EQ(da[i].row, db[i].row);
    EXPECT_EQ(da[i].drive_id, db[i].drive_id);
    EXPECT_EQ(da[i].content_hash, db[i].content_hash);
    EXPECT_EQ(da[i].vehicle_id, db[i].vehicle_id);
    EXPECT_EQ(da[i].start_time_s, db[i].start_time_s);
    EXPECT_EQ(da[i].bbox.min_lat_deg, db[i].bbox.min_lat_deg);
    EXPECT_EQ(da[i].bbox.max_lon_deg, db[i].bbox.max_lon_deg);
    EXPECT_EQ(da[i].pol_level, db[i].pol_level);
    EXPECT_EQ(da[i].distance_m, db[i].distance_m);
    EXPECT_EQ(da[i].num_points, db[i].num_points);
    EXPECT_EQ(da[i].num_lines, db[i].num_lines);
    EXPECT_EQ(da[i].manifest, db[i].manifest);
    EXPECT_EQ(da[i].ingested_at, db[i].ingested_at);
    EXPECT_NE(da[i].package_path, db[i].package_path);  // each store's own directory
    for (const char* f : {kManifestFileName, kGridmapFileName, kCandidatesBinFileName}) {
      EXPECT_EQ(util::read_file_bytes(da[i].package_path / f),
                util::read_file_bytes(db[i].package_path / f))
          << da[i].drive_id << "/" << f;
    }
    const auto ta = a.drive_trajectory(da[i].drive_id), tb = b.drive_trajectory(db[i].drive_id);
    ASSERT_EQ(ta.size(), tb.size());
    for (std::size_t k = 0; k < ta.size(); ++k) {
      EXPECT_EQ(ta[k].time_s, tb[k].time_s);
      EXPECT_EQ(ta[k].lat_deg, tb[k].lat_deg);
    }
    const auto pa = a.drive_path(da[i].drive_id), pb = b.drive_path(db[i].drive_id);
    ASSERT_EQ(pa.size(), pb.size());
    for (std::size_t k = 0; k < pa.size(); ++k) EXPECT_EQ(pa[k].lon_deg, pb[k].lon_deg);
  }
  // Region queries go through the R*Tree / GiST index the transfer wrote.
  for (const auto& region :
       {std::optional<GeoBox>{}, std::optional<GeoBox>{GeoBox{-90.0, -180.0, 90.0, 180.0}}}) {
    const CandidateSet ca = a.candidates_in(region), cb = b.candidates_in(region);
    ASSERT_EQ(ca.points.size(), cb.points.size());
    ASSERT_EQ(ca.lines.size(), cb.lines.size());
    for (std::size_t k = 0; k < ca.points.size(); ++k) {
      EXPECT_EQ(ca.points[k].id, cb.points[k].id);
      EXPECT_EQ(ca.points[k].drive, cb.points[k].drive);
      EXPECT_EQ(ca.points[k].position.lat_deg, cb.points[k].position.lat_deg);
      EXPECT_EQ(ca.points[k].candidate.position_m, cb.points[k].candidate.position_m);
      EXPECT_EQ(ca.points[k].candidate.power_db, cb.points[k].candidate.power_db);
    }
    for (std::size_t k = 0; k < ca.lines.size(); ++k) {
      EXPECT_EQ(ca.lines[k].id, cb.lines[k].id);
      EXPECT_EQ(ca.lines[k].end.lon_deg, cb.lines[k].end.lon_deg);
    }
  }
  EXPECT_EQ(a.drives_in(GeoBox{-90.0, -180.0, 90.0, 180.0}).size(), da.size());
  EXPECT_EQ(b.drives_in(GeoBox{-90.0, -180.0, 90.0, 180.0}).size(), db.size());

  EXPECT_EQ(a.current_map_version(), b.current_map_version());
  const auto va = a.list_map_versions(), vb = b.list_map_versions();
  ASSERT_EQ(va.size(), vb.size());
  for (std::size_t i = 0; i < va.size(); ++i) {
    EXPECT_EQ(va[i].version, vb[i].version);
    EXPECT_EQ(va[i].status, vb[i].status);
    EXPECT_EQ(va[i].created_at, vb[i].created_at);
    EXPECT_EQ(va[i].published_at, vb[i].published_at);
    EXPECT_EQ(va[i].parameters, vb[i].parameters);
    EXPECT_EQ(va[i].statistics, vb[i].statistics);
    EXPECT_EQ(va[i].error, vb[i].error);
    EXPECT_EQ(va[i].current, vb[i].current);
    if (va[i].status != MapVersionStatus::Published) continue;
    const std::int64_t v = va[i].version;
    for (const auto& box :
         {std::optional<GeoBox>{}, std::optional<GeoBox>{GeoBox{-90.0, -180.0, 90.0, 180.0}}}) {
      const LandmarkSet la = a.landmarks_in(v, box), lb = b.landmarks_in(v, box);
      ASSERT_EQ(la.points.size(), lb.points.size());
      ASSERT_EQ(la.lines.size(), lb.lines.size());
      for (std::size_t k = 0; k < la.points.size(); ++k) {
        EXPECT_EQ(la.points[k].id, lb.points[k].id);
        EXPECT_EQ(la.points[k].key, lb.points[k].key);
        EXPECT_EQ(la.points[k].position.lat_deg, lb.points[k].position.lat_deg);
        EXPECT_EQ(la.points[k].scattering, lb.points[k].scattering);
        EXPECT_EQ(la.points[k].support, lb.points[k].support);
        EXPECT_EQ(la.points[k].spread_m, lb.points[k].spread_m);
      }
      for (std::size_t k = 0; k < la.lines.size(); ++k) {
        EXPECT_EQ(la.lines[k].id, lb.lines[k].id);
        EXPECT_EQ(la.lines[k].support, lb.lines[k].support);
        ASSERT_EQ(la.lines[k].polyline.size(), lb.lines[k].polyline.size());
        for (std::size_t j = 0; j < la.lines[k].polyline.size(); ++j) {
          EXPECT_EQ(la.lines[k].polyline[j].lat_deg, lb.lines[k].polyline[j].lat_deg);
        }
      }
    }
    const auto ha = a.list_hdmap_comparisons(v), hb = b.list_hdmap_comparisons(v);
    ASSERT_EQ(ha.size(), hb.size());
    for (std::size_t k = 0; k < ha.size(); ++k) {
      EXPECT_EQ(ha[k].name, hb[k].name);
      EXPECT_EQ(ha[k].created_at, hb[k].created_at);
      EXPECT_EQ(ha[k].summary, hb[k].summary);
      EXPECT_EQ(a.get_hdmap_comparison(v, ha[k].name)->features,
                b.get_hdmap_comparison(v, ha[k].name)->features);
    }
    const auto ca = a.landmark_changes(v), cb = b.landmark_changes(v);
    ASSERT_EQ(ca.size(), cb.size());
    for (std::size_t k = 0; k < ca.size(); ++k) {
      EXPECT_EQ(ca[k].change, cb[k].change);
      EXPECT_EQ(ca[k].key, cb[k].key);
      EXPECT_EQ(ca[k].previous_key, cb[k].previous_key);
      EXPECT_EQ(ca[k].distance_m, cb[k].distance_m);
      EXPECT_EQ(ca[k].reason, cb[k].reason);
      EXPECT_EQ(ca[k].geometry.size(), cb[k].geometry.size());
    }
    for (const TileLayer layer :
         {TileLayer::Localization, TileLayer::Gridmap, TileLayer::GridmapMechanism}) {
      const auto ta = a.list_tiles(v, layer), tb = b.list_tiles(v, layer);
      ASSERT_EQ(ta.size(), tb.size());
      for (std::size_t k = 0; k < ta.size(); ++k) {
        EXPECT_EQ(ta[k].key, tb[k].key);
        EXPECT_EQ(ta[k].etag, tb[k].etag);
        EXPECT_EQ(ta[k].num_points, tb[k].num_points);
        const auto pa = a.get_tile(v, layer, ta[k].key), pb = b.get_tile(v, layer, tb[k].key);
        ASSERT_TRUE(pa && pb);
        EXPECT_EQ(pa->payload, pb->payload);  // byte-identical
        EXPECT_EQ(content_etag(pb->payload), pb->etag);
      }
    }
  }
  const auto ia = a.gridmap_sum_inputs(), ib = b.gridmap_sum_inputs();
  ASSERT_EQ(ia.size(), ib.size());
  for (std::size_t k = 0; k < ia.size(); ++k) {
    EXPECT_EQ(ia[k].content_hash, ib[k].content_hash);
    EXPECT_EQ(ia[k].tiles, ib[k].tiles);
    EXPECT_EQ(a.gridmap_sum_cover(ia[k].content_hash), b.gridmap_sum_cover(ib[k].content_hash));
  }
  const auto sa = a.gridmap_sums_in(0, 0, 1 << 20, 1 << 20);
  const auto sb = b.gridmap_sums_in(0, 0, 1 << 20, 1 << 20);
  ASSERT_EQ(sa.size(), sb.size());
  for (std::size_t k = 0; k < sa.size(); ++k) {
    EXPECT_EQ(sa[k].level, sb[k].level);
    EXPECT_EQ(sa[k].x, sb[k].x);
    EXPECT_EQ(sa[k].data, sb[k].data);
    EXPECT_EQ(sa[k].updated_by, sb[k].updated_by);
  }
  const StoreStats ta = a.stats(), tb = b.stats();
  EXPECT_EQ(ta.tile_blobs, tb.tile_blobs);
  EXPECT_EQ(ta.tile_blob_bytes, tb.tile_blob_bytes);
}

/// Landmarks (id, key, position) and tile ETags of a version.
std::pair<std::vector<std::tuple<std::int64_t, std::int64_t, double, double>>,
          std::map<std::pair<int, tiles::TileKey>, std::string>>
map_of(const MapStore& s, std::int64_t v) {
  std::vector<std::tuple<std::int64_t, std::int64_t, double, double>> lm;
  const LandmarkSet set = s.landmarks_in(v, std::nullopt);
  for (const auto& p : set.points) {
    lm.emplace_back(p.id, p.key, p.position.lat_deg, p.position.lon_deg);
  }
  for (const auto& l : set.lines) {
    lm.emplace_back(l.id, l.key, l.polyline.front().lat_deg, l.polyline.back().lon_deg);
  }
  std::map<std::pair<int, tiles::TileKey>, std::string> tiles;
  for (const TileLayer layer :
       {TileLayer::Localization, TileLayer::Gridmap, TileLayer::GridmapMechanism}) {
    for (const auto& t : s.list_tiles(v, layer)) tiles[{static_cast<int>(layer), t.key}] = t.etag;
  }
  return {lm, tiles};
}

class PostgresStoreTransfer : public ::testing::Test {
 protected:
  struct Dir : polmap::test::TestDir {
    Dir() : TestDir("store_transfer") {}
  };
  Dir tmp;
  const World w = make_world(4, 50, 50.0);

  fs::path src_path() const { return tmp.path() / "src.db"; }

  /// The source: drives a, b -> build 1 (landmarks of both); an upload session with bytes;
  /// drive x put and deleted; b deleted and c (b's objects, seen 2 m off) put -> build 2
  /// (incremental: copied tiles, landmark changes "retired", support links of b gone).
  void make_source() {
    SqliteMapStore s(src_path());
    put_package(s, tmp.path(), w, 0, "a");
    put_package(s, tmp.path(), w, 1, "b", std::nullopt, 5.0);
    const auto v1 = MapBuilder{}.build(s, {});
    ASSERT_EQ(v1.status, MapBuildResult::Status::Published);
    ASSERT_GT(s.landmarks_in(v1.version, std::nullopt).points.size(), 0u);
    UploadSessionRequest r;
    r.owner = std::string(64, 'f');
    r.length_bytes = 1000;
    const auto session = s.create_upload_session(r);
    ASSERT_EQ(session.status, CreateUploadSessionResult::Status::Created);
    {
      std::ofstream f(session.session.file, std::ios::binary | std::ios::app);
      f << std::string(100, 'u');
    }
    ASSERT_TRUE(s.advance_upload_offset(session.session.id, 0, 100));
    session_id_ = session.session.id;
    // A completed one: its answer, no file.
    const auto done = s.create_upload_session(r);
    ASSERT_TRUE(s.complete_upload_session(done.session.id, {201, "/v1/drives/a", R"({"n":1})"}));
    completed_id_ = done.session.id;
    put_package(s, tmp.path(), w, 0, "x", Eigen::Vector2d(-20.0, 0.0), 7.0);
    ASSERT_TRUE(s.delete_drive("x"));
    ASSERT_TRUE(s.delete_drive("b"));
    put_package(s, tmp.path(), w, 1, "c", Eigen::Vector2d(2.0, 0.0), 10.0);
    const auto v2 = MapBuilder{}.build(s, {});
    ASSERT_EQ(v2.status, MapBuildResult::Status::Published);
    ASSERT_GT(s.landmark_changes(v2.version).size(), 0u);
    ASSERT_GT(s.gridmap_sum_inputs().size(), 0u);
    // An HD-map comparison stored with version 1 (compare-hdmap --store), JSON both ways.
    s.put_hdmap_comparison(
        {v1.version,
         "town",
         "town.osm",
         "",
         {{"point_recall", 0.75}, {"line_coverage", nullptr}},
         {{"type", "FeatureCollection"},
          {"features",
           {{{"type", "Feature"},
             {"geometry", {{"type", "Point"}, {"coordinates", {9.1, 48.7}}}},
             {"properties", {{"role", "hd"}, {"matched", false}, {"hd_id", 12}}}}}}}});
  }

  std::string session_id_;
  std::string completed_id_;
};

TEST_F(PostgresStoreTransfer, SqliteToPostgresToSqliteLosesNothingAndBuildsTheSameMap) {
  make_source();
  const std::string url = PostgresCluster::instance().create_database();
  const fs::path pg_packages = tmp.path() / "pg_packages";
  std::vector<std::string> seen;
  StoreTransferOptions o;
  o.package_dir = pg_packages;
  o.progress = [&](const StoreTransferProgress& p) {
    if (seen.empty() || seen.back() != p.table) seen.push_back(p.table);
    EXPECT_LE(p.done, p.total);
  };
  const auto to_pg = transfer_store(src_path().string(), url, o);
  EXPECT_EQ(to_pg.packages, 2);  // a, c (b and x were deleted)
  EXPECT_EQ(to_pg.upload_files, 1);
  EXPECT_GT(to_pg.linked_files, 0);  // same file system: hard links
  EXPECT_EQ(seen.front(), "drives");
  EXPECT_EQ(seen.back(), "package files");
  const auto v1 = verify_store_transfer(src_path().string(), url);
  EXPECT_TRUE(v1.ok()) << ::testing::PrintToString(v1.mismatches);
  EXPECT_GT(v1.tile_blobs_checked, 0);
  EXPECT_EQ(v1.versions_compared, 2);

  const fs::path back = tmp.path() / "back.db";
  StoreTransferOptions copy;
  copy.hard_link_packages = false;
  const auto to_sqlite = transfer_store(url, back.string(), copy);
  EXPECT_EQ(to_sqlite.linked_files, 0);
  EXPECT_EQ(to_sqlite.tables.size(), to_pg.tables.size());
  for (std::size_t i = 0; i < to_pg.tables.size(); ++i) {
    EXPECT_EQ(to_sqlite.tables[i].rows, to_pg.tables[i].rows) << to_pg.tables[i].table;
  }
  EXPECT_TRUE(verify_store_transfer(url, back.string()).ok());

  {
    SqliteMapStore src(src_path());
    PostgresStoreOptions po;
    po.conninfo = url;
    PostgresMapStore pg(po);
    SqliteMapStore dst(back);
    expect_same_store(src, pg, "source vs PostgreSQL");
    expect_same_store(src, dst, "source vs SQLite after the round trip");
    for (MapStore* s : std::initializer_list<MapStore*>{&pg, &dst}) {
      const auto u = s->get_upload_session(session_id_);
      ASSERT_TRUE(u);
      EXPECT_EQ(u->offset_bytes, 100u);
      EXPECT_EQ(u->length_bytes, 1000u);
      EXPECT_EQ(util::read_file_bytes(u->file), std::string(100, 'u'));
      const auto c = s->get_upload_session(completed_id_);
      ASSERT_TRUE(c && c->outcome);
      EXPECT_EQ(c->outcome->http_status, 201);
      EXPECT_EQ(c->outcome->location, "/v1/drives/a");
      EXPECT_EQ(c->outcome->body, R"({"n":1})");
      EXPECT_FALSE(fs::exists(c->file));
    }

    // A map built afterwards on each copy equals one built on the source: same new drive,
    // same drive row, same landmarks (ids included) and tile ETags.
    std::vector<std::int64_t> versions;
    for (MapStore* s : std::initializer_list<MapStore*>{&src, &pg, &dst}) {
      put_package(*s, tmp.path(), w, 1, "d", std::nullopt, 20.0);
      const auto r = MapBuilder{}.build(*s, {});
      ASSERT_EQ(r.status, MapBuildResult::Status::Published) << r.error;
      versions.push_back(r.version);
    }
    EXPECT_EQ(versions[0], versions[1]);
    EXPECT_EQ(versions[0], versions[2]);
    const auto want = map_of(src, versions[0]);
    EXPECT_FALSE(want.first.empty());
    EXPECT_FALSE(want.second.empty());
    EXPECT_EQ(map_of(pg, versions[1]), want);
    EXPECT_EQ(map_of(dst, versions[2]), want);
  }
}

/// Row count of a content table of a store (raw, so a failed transfer cannot hide rows).
std::int64_t rows_in(const std::string& db, const std::string& table) {
  if (is_postgres_conninfo(db)) {
    return std::stoll(PostgresCluster::instance().scalar(db, "SELECT COUNT(*) FROM " + table));
  }
  sqlite3* h = nullptr;
  EXPECT_EQ(sqlite3_open(db.c_str(), &h), SQLITE_OK);
  sqlite3_stmt* s = nullptr;
  std::int64_t n = -1;
  if (sqlite3_prepare_v2(h, ("SELECT COUNT(*) FROM " + table).c_str(), -1, &s, nullptr) ==
          SQLITE_OK &&
      sqlite3_step(s) == SQLITE_ROW) {
    n = sqlite3_column_int64(s, 0);
  }
  sqlite3_finalize(s);
  sqlite3_close(h);
  return n;
}

void expect_empty(const std::string& db, const fs::path& packages, const std::string& what) {
  SCOPED_TRACE(what);
  for (const char* t : {"drives", "candidates", "drive_trajectories", "map_versions", "current_map",
                        "landmarks", "landmark_support", "landmark_changes", "hdmap_comparisons",
                        "tile_blobs", "tiles", "gridmap_tiles", "upload_sessions", "gridmap_sums",
                        "gridmap_sum_inputs", "gridmap_sum_cover"}) {
    EXPECT_EQ(rows_in(db, t), 0) << t;
  }
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(packages, ec)) {
    const std::string name = e.path().filename().string();
    EXPECT_TRUE(name == "uploads" || name == "quarantine") << "left behind: " << e.path();
    if (name == "uploads") {
      EXPECT_TRUE(fs::is_empty(e.path())) << e.path();
    }
  }
}

template <typename E>
std::string error_of(const std::function<void()>& fn) {
  try {
    fn();
  } catch (const E& e) {
    return e.what();
  } catch (const std::exception& e) {
    return std::string("wrong exception type: ") + e.what();
  }
  return "no exception";
}

TEST_F(PostgresStoreTransfer, AFailureMidwayLeavesTheDestinationEmpty) {
  make_source();
  const std::string url = PostgresCluster::instance().create_database();
  const fs::path pg_packages = tmp.path() / "pg_packages";
  const fs::path dst = tmp.path() / "dst.db";
  for (const std::string stage :
       {"table:candidates", "table:landmarks", "table:gridmap_sums", "files", "commit"}) {
    StoreTransferOptions o;
    o.fault_hook = [&](std::string_view s) {
      if (s == stage) throw IoError("injected failure at " + stage);
    };
    o.package_dir = pg_packages;
    EXPECT_NE(error_of<IoError>([&] {
                transfer_store(src_path().string(), url, o);
              }).find("injected failure at " + stage),
              std::string::npos);
    expect_empty(url, pg_packages, "PostgreSQL, failed at " + stage);
    o.package_dir.clear();
    EXPECT_NE(error_of<IoError>([&] {
                transfer_store(src_path().string(), dst.string(), o);
              }).find("injected failure"),
              std::string::npos);
    expect_empty(dst.string(), dst.string() + ".drives", "SQLite, failed at " + stage);
  }
  // The destination database dies midway: every connection to it is terminated.
  StoreTransferOptions kill;
  kill.package_dir = pg_packages;
  kill.fault_hook = [&](std::string_view s) {
    if (s != "table:tiles") return;
    PostgresCluster::instance().exec(
        PostgresCluster::instance().url_for("polmap"),
        "SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = '" +
            url.substr(url.rfind('/') + 1) + "'");
  };
  EXPECT_NE(error_of<IoError>([&] { transfer_store(src_path().string(), url, kill); }),
            "no exception");
  expect_empty(url, pg_packages, "PostgreSQL, connections terminated");

  // Nothing was left that would make the destination non-empty: the transfer now succeeds.
  StoreTransferOptions ok;
  ok.package_dir = pg_packages;
  (void)transfer_store(src_path().string(), url, ok);
  EXPECT_TRUE(verify_store_transfer(src_path().string(), url).ok());
  (void)transfer_store(src_path().string(), dst.string(), {});
  EXPECT_TRUE(verify_store_transfer(src_path().string(), dst.string()).ok());
}

TEST_F(PostgresStoreTransfer, RefusesNonEmptyDestinationsOtherSchemasUnknownTablesAndBuilds) {
  {
    SqliteMapStore s(src_path());
    put_package(s, tmp.path(), w, 0, "a");
  }
  // Non-empty destinations: one drive in each.
  const std::string url = PostgresCluster::instance().create_database();
  const fs::path full = tmp.path() / "full.db";
  {
    PostgresStoreOptions po;
    po.conninfo = url;
    po.package_dir = tmp.path() / "pg_packages";
    PostgresMapStore pg(po);
    put_package(pg, tmp.path(), w, 1, "other", Eigen::Vector2d(30.0, 5.0));
    SqliteMapStore s(full);
    put_package(s, tmp.path(), w, 1, "other", Eigen::Vector2d(30.0, 5.0));
  }
  for (const std::string& to : {url, full.string()}) {
    const std::string e =
        error_of<ValidationError>([&] { transfer_store(src_path().string(), to, {}); });
    EXPECT_NE(e.find("is not empty: table 'drives' has 1 row(s)"), std::string::npos) << e;
    EXPECT_EQ(rows_in(to, "drives"), 1);
  }
  const fs::path dst = tmp.path() / "dst.db";

  // A source of another schema version (as if written by an older polmap).
  const fs::path old = tmp.path() / "old.db";
  fs::copy_file(src_path(), old);
  const int latest = sqlite_store_migrations().back().version;
  testing::exec_sql(old, "DELETE FROM schema_migrations WHERE version = " + std::to_string(latest));
  std::string e =
      error_of<ValidationError>([&] { transfer_store(old.string(), dst.string(), {}); });
  EXPECT_NE(e.find("has schema version " + std::to_string(latest - 1) + ", this build's is " +
                   std::to_string(latest)),
            std::string::npos)
      << e;

  // A table the transfer does not know is refused, a transient build_job* table skipped.
  const fs::path extra = tmp.path() / "extra.db";
  fs::copy_file(src_path(), extra);
  testing::exec_sql(extra, "CREATE TABLE landmark_colours (id INTEGER PRIMARY KEY)");
  e = error_of<ValidationError>([&] { transfer_store(extra.string(), dst.string(), {}); });
  EXPECT_NE(e.find("has table 'landmark_colours'"), std::string::npos) << e;
  const fs::path column = tmp.path() / "column.db";
  fs::copy_file(src_path(), column);
  testing::exec_sql(column, "ALTER TABLE drives ADD COLUMN colour TEXT");
  e = error_of<ValidationError>([&] { transfer_store(column.string(), dst.string(), {}); });
  EXPECT_NE(e.find("column 'drives.colour'"), std::string::npos) << e;
  EXPECT_FALSE(fs::exists(dst)) << "a refused source must not create the destination";

  const fs::path jobs = tmp.path() / "jobs.db";
  fs::copy_file(src_path(), jobs);
  fs::copy(src_path().string() + ".drives", jobs.string() + ".drives", fs::copy_options::recursive);
  // A finished partitioned build's job rows: transient, not copied.
  testing::exec_sql(jobs,
                    "INSERT INTO map_versions(version, status, created_at, parameters_json, "
                    "error) VALUES (99, 'failed', '2026-12-03T00:00:00Z', '{}', 'x'); INSERT "
                    "INTO build_jobs(version, kind, z, x, y, spec_json, state) VALUES (99, "
                    "'region', 16, 1, 1, '{}', 'failed')");
  const auto r = transfer_store(jobs.string(), dst.string(), {});
  EXPECT_EQ(r.transient_tables, std::vector<std::string>{"build_jobs"});
  EXPECT_EQ(rows_in(dst.string(), "drives"), 1);

  // A build running in the source.
  {
    SqliteMapStore s(src_path());
    (void)s.begin_map_version(nlohmann::json::object());
  }
  e = error_of<ValidationError>(
      [&] { transfer_store(src_path().string(), (tmp.path() / "dst2.db").string(), {}); });
  EXPECT_NE(e.find("map version 1 is building"), std::string::npos) << e;
}

}  // namespace
}  // namespace polmap::mapping
