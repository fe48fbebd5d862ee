// The server on a full disk (docs/security.md, "Malicious-input corpus and full disk").
// The disk is made full by the ENOSPC write shim linked into this binary
// (tests/support/enospc_shim.hpp): while armed, every write of the process to a file below
// the armed paths fails with ENOSPC, so SQLite reports SQLITE_FULL, GDAL a short write and
// std::filesystem ENOSPC, as on a real full file system; no root, no mount, no skipping.
// Writes answer 507 and keep nothing; reads keep working; once space returns the same
// upload is stored and builds publish.
#include <cpl_vsi.h>
#include <fcntl.h>
#include <sqlite3.h>
#include <unistd.h>

#include <fstream>
#include <nlohmann/json.hpp>

#include "mapping_service/server/server_probe.hpp"
#include "mapping_service/server_fixture.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/tile_key.hpp"
#include "support/enospc_shim.hpp"

namespace polmap::mapping::testing {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using test::enospc::ScopedFull;

template <class Pred>
bool eventually(Pred pred, double seconds = 15.0) {
  const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < until) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return pred();
}

TEST(EnospcShim, SqliteGdalAndTheStandardLibraryAllSeeAFullDisk) {
  // The shim must really interpose, or every other test here would pass for nothing.
  const util::ScopedTempDir dir(polmap::test::unique_test_dir("enospc"));
  const fs::path full = dir.path() / "full";
  fs::create_directories(full);
  util::write_file_bytes(dir.path() / "source.bin", std::string(100000, 's'));
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open((full / "x.db").c_str(), &db), SQLITE_OK);
  ASSERT_EQ(
      sqlite3_exec(db, "PRAGMA journal_mode=WAL; CREATE TABLE t(x)", nullptr, nullptr, nullptr),
      SQLITE_OK);
  const std::uint64_t refused_before = test::enospc::refused_writes();
  {
    const ScopedFull disk_full({full});
    std::ofstream out(full / "a.txt");
    out << std::string(100000, 'y') << std::flush;
    EXPECT_FALSE(out) << "std::ofstream (libstdc++ write)";
    std::error_code ec;
    fs::copy_file(dir.path() / "source.bin", full / "copy.bin", ec);
    // sendfile stores part, then ENOSPC; libstdc++ calls that EIO (as on a full tmpfs).
    EXPECT_EQ(ec, std::errc::io_error) << "std::filesystem::copy_file (sendfile): " << ec.message();
    EXPECT_LT(fs::file_size(full / "copy.bin"), 100000u);
    EXPECT_EQ(
        sqlite3_exec(db, "INSERT INTO t VALUES (randomblob(100000))", nullptr, nullptr, nullptr),
        SQLITE_FULL)
        << "SQLite (pwrite64)";
    VSILFILE* f = VSIFOpenL((full / "g.bin").c_str(), "wb");
    ASSERT_NE(f, nullptr);
    EXPECT_EQ(VSIFWriteL("abcd", 1, 4, f), 2u) << "GDAL VSI (fwrite): a short write";
    EXPECT_EQ(VSIFWriteL("efgh", 1, 4, f), 0u) << "GDAL VSI (fwrite): then nothing";
    VSIFCloseL(f);
    // The raw calls: part of the first write, then ENOSPC.
    const int fd = ::open((full / "raw.bin").c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ASSERT_GE(fd, 0);
    EXPECT_EQ(::write(fd, "0123456789", 10), 5);
    errno = 0;
    EXPECT_EQ(::write(fd, "0123456789", 10), -1);
    EXPECT_EQ(errno, ENOSPC);
    EXPECT_EQ(::pwrite(fd, "0123456789", 10, 5), -1);
    ::close(fd);
    // Outside the armed path everything writes.
    std::ofstream elsewhere(dir.path() / "b.txt");
    elsewhere << "fine" << std::flush;
    EXPECT_TRUE(elsewhere);
  }
  EXPECT_GE(test::enospc::refused_writes(), refused_before + 4);
  // Space returned.
  EXPECT_EQ(
      sqlite3_exec(db, "INSERT INTO t VALUES (randomblob(100000))", nullptr, nullptr, nullptr),
      SQLITE_OK);
  sqlite3_close(db);
}

/// The store, forwarding everything, with a callback before each map-content write: the
/// test fills the disk in the middle of a build.
class WriteTriggerStore final : public MapStore {
 public:
  explicit WriteTriggerStore(MapStore& inner) : s_(inner) {}
  std::function<void(std::string_view write)> before_write;

  PutDriveResult put_drive(const DrivePackage& p, const fs::path& l,
                           const std::string& h) override {
    return s_.put_drive(p, l, h);
  }
  std::vector<DriveRecord> list_drives() const override { return s_.list_drives(); }
  std::optional<DriveRecord> get_drive(std::string_view id) const override {
    return s_.get_drive(id);
  }
  std::optional<DriveRecord> find_drive_by_hash(std::string_view h) const override {
    return s_.find_drive_by_hash(h);
  }
  std::vector<GeoPoint> drive_path(std::string_view id) const override { return s_.drive_path(id); }
  std::vector<TrajectorySample> drive_trajectory(std::string_view id) const override {
    return s_.drive_trajectory(id);
  }
  std::vector<DriveRecord> drives_in(const GeoBox& b) const override { return s_.drives_in(b); }
  bool delete_drive(std::string_view id) override { return s_.delete_drive(id); }
  CandidateSet candidates_in(const std::optional<GeoBox>& r,
                             std::span<const std::string> ex) const override {
    return s_.candidates_in(r, ex);
  }
  std::int64_t begin_map_version(const json& p) override { return s_.begin_map_version(p); }
  void put_landmarks(std::int64_t v, std::span<const StoredPointLandmark> p,
                     std::span<const StoredLineLandmark> l) override {
    if (before_write) before_write("put_landmarks");
    s_.put_landmarks(v, p, l);
  }
  std::int64_t copy_landmarks(std::int64_t f, std::int64_t t,
                              std::span<const std::int64_t> ex) override {
    if (before_write) before_write("copy_landmarks");
    return s_.copy_landmarks(f, t, ex);
  }
  std::int64_t copy_tiles(std::int64_t f, std::int64_t t, TileLayer l,
                          std::span<const tiles::TileKey> ex) override {
    if (before_write) before_write("copy_tiles");
    return s_.copy_tiles(f, t, l, ex);
  }
  void put_landmark_changes(std::int64_t v, std::span<const LandmarkChange> ch) override {
    if (before_write) before_write("put_landmark_changes");
    s_.put_landmark_changes(v, ch);
  }
  std::vector<LandmarkChange> landmark_changes(std::int64_t v) const override {
    return s_.landmark_changes(v);
  }
  void put_tiles(std::int64_t v, TileLayer layer, std::span<const TileWrite> t) override {
    if (before_write) before_write("put_tiles");
    s_.put_tiles(v, layer, t);
  }
  void publish_map_version(std::int64_t v, const json& st, bool make_current) override {
    if (before_write) before_write("publish");
    s_.publish_map_version(v, st, make_current);
  }
  void fail_map_version(std::int64_t v, std::string_view e) override { s_.fail_map_version(v, e); }
  std::vector<std::int64_t> fail_abandoned_builds() override { return s_.fail_abandoned_builds(); }
  void set_current_map_version(std::int64_t v) override { s_.set_current_map_version(v); }
  bool delete_map_version(std::int64_t v) override { return s_.delete_map_version(v); }
  std::optional<std::int64_t> current_map_version() const override {
    return s_.current_map_version();
  }
  std::optional<MapVersionInfo> get_map_version(std::int64_t v) const override {
    return s_.get_map_version(v);
  }
  std::vector<MapVersionInfo> list_map_versions() const override { return s_.list_map_versions(); }
  LandmarkSet landmarks_in(std::int64_t v, const std::optional<GeoBox>& b,
                           bool with_support) const override {
    return s_.landmarks_in(v, b, with_support);
  }
  std::optional<StoredTile> get_tile(std::int64_t v, TileLayer l,
                                     const tiles::TileKey& k) const override {
    return s_.get_tile(v, l, k);
  }
  std::optional<std::string> get_tile_etag(std::int64_t v, TileLayer l,
                                           const tiles::TileKey& k) const override {
    return s_.get_tile_etag(v, l, k);
  }
  std::vector<TileInfo> list_tiles(std::int64_t v, TileLayer l) const override {
    return s_.list_tiles(v, l);
  }
  CreateUploadSessionResult create_upload_session(const UploadSessionRequest& r) override {
    return s_.create_upload_session(r);
  }
  std::optional<UploadSession> get_upload_session(std::string_view id) const override {
    return s_.get_upload_session(id);
  }
  bool advance_upload_offset(std::string_view id, std::uint64_t from, std::uint64_t to) override {
    return s_.advance_upload_offset(id, from, to);
  }
  bool delete_upload_session(std::string_view id) override { return s_.delete_upload_session(id); }
  bool complete_upload_session(std::string_view id, const UploadOutcome& o) override {
    return s_.complete_upload_session(id, o);
  }
  std::size_t sweep_expired_upload_sessions(std::chrono::system_clock::time_point now) override {
    return s_.sweep_expired_upload_sessions(now);
  }
  std::int64_t put_localization_run(const LocalizationRunRecord& r, std::string_view body,
                                    std::span<const LocalizationRunCell> cells,
                                    std::size_t keep) override {
    if (before_write) before_write("put_localization_run");
    return s_.put_localization_run(r, body, cells, keep);
  }
  std::vector<LocalizationRunRecord> list_localization_runs(std::size_t limit,
                                                            std::string_view v) const override {
    return s_.list_localization_runs(limit, v);
  }
  std::optional<LocalizationRunRecord> get_localization_run(std::int64_t id) const override {
    return s_.get_localization_run(id);
  }
  std::optional<std::string> localization_run_body(std::int64_t id) const override {
    return s_.localization_run_body(id);
  }
  bool delete_localization_run(std::int64_t id) override { return s_.delete_localization_run(id); }
  std::vector<LocalizationRunCell> localization_run_cells(int z, int x0, int y0, int x1, int y1,
                                                          std::size_t limit,
                                                          RunCellRuns which) const override {
    return s_.localization_run_cells(z, x0, y0, x1, y1, limit, which);
  }
  std::vector<GridmapSumInput> gridmap_sum_inputs() const override {
    return s_.gridmap_sum_inputs();
  }
  std::vector<GridmapSumRow> gridmap_sums_in(int x0, int y0, int x1, int y1) const override {
    return s_.gridmap_sums_in(x0, y0, x1, y1);
  }
  std::vector<GridmapSumRow> gridmap_sum_keys(std::optional<std::int64_t> after) const override {
    return s_.gridmap_sum_keys(after);
  }
  std::vector<std::array<int, 3>> gridmap_sum_cover(std::string_view hash) const override {
    return s_.gridmap_sum_cover(hash);
  }
  std::vector<std::string> gridmap_sum_contributors(int level, int x, int y) const override {
    return s_.gridmap_sum_contributors(level, x, y);
  }
  void commit_gridmap_sums(std::int64_t version, std::span<const GridmapSumRow> tiles,
                           const GridmapSumInputChange& change) override {
    s_.commit_gridmap_sums(version, tiles, change);
  }
  void enqueue_build_jobs(std::int64_t v, std::span<const BuildJobSpec> jobs) override {
    s_.enqueue_build_jobs(v, jobs);
  }
  std::optional<BuildJob> claim_build_job(std::string_view w, double lease_s,
                                          std::optional<std::int64_t> v) override {
    return s_.claim_build_job(w, lease_s, v);
  }
  bool renew_build_job(std::int64_t j, int a, double lease_s) override {
    return s_.renew_build_job(j, a, lease_s);
  }
  bool complete_build_job(std::int64_t j, int a, const BuildJobOutput& out) override {
    if (before_write) before_write("complete_build_job");
    return s_.complete_build_job(j, a, out);
  }
  bool fail_build_job(std::int64_t j, int a, std::string_view e) override {
    return s_.fail_build_job(j, a, e);
  }
  std::vector<BuildJob> build_jobs(std::int64_t v) const override { return s_.build_jobs(v); }
  void put_hdmap_comparison(const HdMapComparisonRecord& r) override { s_.put_hdmap_comparison(r); }
  std::vector<HdMapComparisonRecord> list_hdmap_comparisons(std::int64_t v) const override {
    return s_.list_hdmap_comparisons(v);
  }
  std::optional<HdMapComparisonRecord> get_hdmap_comparison(std::int64_t v,
                                                            std::string_view n) const override {
    return s_.get_hdmap_comparison(v, n);
  }
  std::optional<LandmarkDetail> landmark_detail(std::int64_t v, std::int64_t k) const override {
    return s_.landmark_detail(v, k);
  }
  StoreStats stats() const override { return s_.stats(); }

 private:
  MapStore& s_;
};

class FullDiskTest : public ServerFixture {
 protected:
  void SetUp() override {
    ServerFixture::SetUp();
    // Serve through the trigger store (same SQLite store, same directories).
    server_->stop();
    thread_.join();
    server_.reset();
    trigger_ = std::make_unique<WriteTriggerStore>(*store_);
    ServerConfig cfg;
    cfg.api_keys = {kKey};
    cfg.upload_dir = dir_ / "uploads";
    cfg.threads = 8;
    cfg.log_sink = [this](std::string_view line) {
      std::lock_guard lock(log_mutex_);
      log_.emplace_back(line);
    };
    server_ = std::make_unique<Server>(*trigger_, cfg);
    thread_ = std::thread([this] { server_->listen("127.0.0.1", 0); });
    ASSERT_TRUE(server_->wait_until_listening(std::chrono::seconds(10)));
    port_ = server_->bound_port();

    for (int i = 0; i < 2; ++i) {
      const std::string id = "scene_drive_" + std::to_string(i);
      ASSERT_EQ(upload(scene_tar(id, 11 + i)).status, 201);
    }
    const RawReply r = post_build();
    ASSERT_EQ(r.status, 202) << r.bytes;
    server_->wait_for_builds();
    ASSERT_EQ(store_->current_map_version(), std::optional<std::int64_t>(1));
    tile_ = store_->list_tiles(1, TileLayer::Localization).at(0).key;
    const GeoPoint p = store_->landmarks_in(1, std::nullopt, false).points.at(0).position;
    mvt_tile_ = tiles::tile_at(p.lat_deg, p.lon_deg, 18);
  }
  void TearDown() override {
    test::enospc::disarm();
    ServerFixture::TearDown();
    trigger_.reset();
  }

  static std::string key_header() { return std::string("Authorization: Bearer ") + kKey + "\r\n"; }
  RawReply upload(const std::string& tar) const {
    return raw_request(port_, "POST /v1/drives HTTP/1.1\r\nHost: t\r\n" + key_header() +
                                  "Content-Type: application/x-tar\r\nContent-Length: " +
                                  std::to_string(tar.size()) + "\r\nConnection: close\r\n\r\n" +
                                  tar);
  }
  RawReply post_build() const {
    return raw_request(port_, "POST /v1/maps HTTP/1.1\r\nHost: t\r\n" + key_header() +
                                  "Content-Type: application/json\r\nContent-Length: "
                                  "2\r\nConnection: close\r\n\r\n{}");
  }
  RawReply get(const std::string& target, bool with_key = false) const {
    return raw_request(port_, "GET " + target + " HTTP/1.1\r\nHost: t\r\n" +
                                  (with_key ? key_header() : "") + "Connection: close\r\n\r\n");
  }

  /// Every read the service offers answers as it did before the disk filled up.
  void expect_reads_work(std::int64_t version) const {
    const std::string v = std::to_string(version);
    const RawReply tile = get("/v1/tiles/" + tiles::to_string(tile_));
    EXPECT_EQ(tile.status, 200);
    EXPECT_NE(tile.bytes.find("X-Polmap-Map-Version: " + v), std::string::npos);
    EXPECT_EQ(get("/v1/tiles/" + tiles::to_string(tile_) + "?version=" + v).status, 200);
    EXPECT_EQ(get("/v1/tilejson.json").status, 200);
    EXPECT_EQ(get("/v1/mvt/" + tiles::to_string(mvt_tile_) + ".mvt", true).status, 200);
    const RawReply drives = get("/v1/drives", true);
    EXPECT_EQ(drives.status, 200);
    EXPECT_NE(drives.body().find("scene_drive_0"), std::string::npos);
    EXPECT_EQ(get("/v1/drives/scene_drive_1", true).status, 200);
    EXPECT_EQ(get("/v1/maps").status, 200);
    EXPECT_EQ(get("/v1/maps/" + v).status, 200);
    EXPECT_EQ(get("/health").status, 200);
    EXPECT_EQ(get("/metrics", true).status, 200);
  }

  /// Rows of a table of the database for one map version, read past the store (a version
  /// that is not published is invisible through it).
  std::int64_t rows_of_version(const char* table, std::int64_t version) const {
    sqlite3* db = nullptr;
    EXPECT_EQ(sqlite3_open_v2((dir_ / "map.db").c_str(), &db, SQLITE_OPEN_READONLY, nullptr),
              SQLITE_OK);
    sqlite3_stmt* s = nullptr;
    const std::string sql = std::string("SELECT COUNT(*) FROM ") + table + " WHERE version = ?1";
    EXPECT_EQ(sqlite3_prepare_v2(db, sql.c_str(), -1, &s, nullptr), SQLITE_OK);
    sqlite3_bind_int64(s, 1, version);
    const std::int64_t n = sqlite3_step(s) == SQLITE_ROW ? sqlite3_column_int64(s, 0) : -1;
    sqlite3_finalize(s);
    sqlite3_close(db);
    return n;
  }

  std::unique_ptr<WriteTriggerStore> trigger_;
  tiles::TileKey tile_{};      ///< a localization tile of the map
  tiles::TileKey mvt_tile_{};  ///< a z18 vector tile with a landmark
};

TEST_F(FullDiskTest, UploadsAnswer507KeepNothingAndSucceedOnceSpaceReturns) {
  const std::string& tar = scene_tar("scene_drive_2", 13);
  const std::string before = store_digest(*store_);
  // Whichever part of the store has no space: all of it; the drive store only (the
  // package files cannot be copied); the database only (the rows cannot commit, after the
  // files were copied and renamed); the upload directory only (the body cannot be saved).
  const std::vector<std::pair<std::string, std::vector<fs::path>>> full_parts{
      {"everything", {dir_}},
      {"drive store", {store_->drive_store_dir()}},
      {"database", {dir_ / "map.db", dir_ / "map.db-wal"}},
      {"upload directory", {dir_ / "uploads"}},
  };
  for (const auto& [what, paths] : full_parts) {
    SCOPED_TRACE(what + " full");
    const std::uint64_t refused = test::enospc::refused_writes();
    {
      const ScopedFull disk_full(paths);
      const RawReply r = upload(tar);
      EXPECT_EQ(r.status, 507) << r.bytes.substr(0, 400);
      EXPECT_NE(r.body().find("storage is full"), std::string::npos) << r.body();
      EXPECT_GT(test::enospc::refused_writes(), refused) << "the shim refused nothing";
      // Nothing partial: no row, no package directory, no staging or member files.
      EXPECT_EQ(store_digest(*store_), before);
      EXPECT_EQ(directory_entries(dir_ / "uploads"), 0u);
      expect_reads_work(1);
    }
    EXPECT_EQ(store_digest(*store_), before);
  }
  // Space returned: the very same upload is stored.
  const RawReply r = upload(tar);
  ASSERT_EQ(r.status, 201) << r.bytes.substr(0, 400);
  ASSERT_TRUE(store_->get_drive("scene_drive_2"));
  EXPECT_EQ(
      util::read_file_bytes(store_->get_drive("scene_drive_2")->package_path / "manifest.json"),
      read_ustar(tar).front().data);
  std::size_t storage_full = 0;
  for (const auto& l : log_lines()) storage_full += l.find("storage full") != std::string::npos;
  EXPECT_EQ(storage_full, full_parts.size()) << "each 507 is logged (warn), with the cause";
}

TEST_F(FullDiskTest, WritesOtherThanUploadsAnswer507AndReadsKeepWorking) {
  const std::string before = store_digest(*store_);
  {
    const ScopedFull disk_full({dir_});
    RawReply r = post_build();
    EXPECT_EQ(r.status, 507) << r.bytes.substr(0, 400);
    r = raw_request(port_, "DELETE /v1/drives/scene_drive_0 HTTP/1.1\r\nHost: t\r\n" +
                               key_header() + "Connection: close\r\n\r\n");
    EXPECT_EQ(r.status, 507) << r.bytes.substr(0, 400);
    r = raw_request(port_, "DELETE /v1/vehicles/veh_01/drives HTTP/1.1\r\nHost: t\r\n" +
                               key_header() + "Connection: close\r\n\r\n");
    EXPECT_EQ(r.status, 507) << r.bytes.substr(0, 400);
    EXPECT_EQ(store_digest(*store_), before);
    expect_reads_work(1);
    // An export needs scratch space too: 507, and none of its files stay.
    for (const char* format : {"gpkg", "geojson", "shp"}) {
      r = get(std::string("/v1/export?format=") + format, true);
      EXPECT_EQ(r.status, 507) << format << ": " << r.bytes.substr(0, 400);
      EXPECT_EQ(directory_entries(dir_ / "uploads"), 0u) << format;
    }
  }
  EXPECT_EQ(get("/v1/export?format=gpkg", true).status, 200);
  const RawReply r = post_build();
  ASSERT_EQ(r.status, 202) << r.bytes;
  server_->wait_for_builds();
  EXPECT_EQ(store_->current_map_version(), std::optional<std::int64_t>(2));
  expect_reads_work(2);
}

TEST_F(FullDiskTest, ABuildThatRunsOutOfSpaceFailsWithoutPublishingAnything) {
  // The disk fills up once the build has stored its landmarks, before the tiles.
  std::atomic<bool> filled{false};
  trigger_->before_write = [&](std::string_view write) {
    if (write == "put_tiles" && !filled.exchange(true)) test::enospc::arm({dir_});
  };
  RawReply r = post_build();
  ASSERT_EQ(r.status, 202) << r.bytes;
  const std::int64_t v = json::parse(r.body())["version"].get<std::int64_t>();
  ASSERT_EQ(v, 2);
  server_->wait_for_builds();
  ASSERT_TRUE(filled);
  // Failed, and could not even be marked failed: still "building", invisible to readers,
  // the current map untouched.
  EXPECT_EQ(store_->get_map_version(v)->status, MapVersionStatus::Building);
  EXPECT_EQ(store_->current_map_version(), std::optional<std::int64_t>(1));
  EXPECT_GT(rows_of_version("landmarks", v), 0);  // committed before the disk filled up
  EXPECT_EQ(rows_of_version("tiles", v), 0);
  EXPECT_EQ(get("/v1/tiles/" + tiles::to_string(tile_) + "?version=2").status, 404);
  expect_reads_work(1);
  const RawReply again = post_build();
  EXPECT_EQ(again.status, 507) << again.bytes.substr(0, 400);  // no new version meanwhile

  test::enospc::disarm();  // space returns
  ASSERT_TRUE(eventually([&] {
    return store_->get_map_version(v)->status == MapVersionStatus::Failed;
  })) << "the server marks the build failed once it can";
  const std::string error = store_->get_map_version(v)->error;
  EXPECT_NE(error.find("full"), std::string::npos) << error;  // a clear reason
  EXPECT_EQ(rows_of_version("landmarks", v), 0);              // its content dropped with it
  r = get("/v1/maps/2");
  EXPECT_NE(r.body().find("\"status\":\"failed\""), std::string::npos) << r.body();

  // And the next build publishes.
  r = post_build();
  ASSERT_EQ(r.status, 202) << r.bytes;
  server_->wait_for_builds();
  EXPECT_EQ(store_->current_map_version(), std::optional<std::int64_t>(3));
  expect_reads_work(3);
  bool logged = false;
  for (const auto& l : log_lines()) logged |= l.find("cannot mark map build 2 failed") != l.npos;
  EXPECT_TRUE(logged);
}

}  // namespace
}  // namespace polmap::mapping::testing
