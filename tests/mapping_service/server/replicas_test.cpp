// Stateless replicas: two mapping servers, each with its own PostgresMapStore on one
// PostgreSQL database (as two processes would be), answer every request alike. The same
// drive uploaded through both at once is one drive; a map built through one is served by
// the other within a second; localization tiles, vector tiles and TileJSON have the same
// bytes and ETags on both.
#include "mapping_service/store/store_backends.hpp"
// After the store headers: server_fixture.hpp ends with httplib.
#include "mapping_service/server_fixture.hpp"
#include "polmap/mapping_service/build_worker.hpp"

namespace polmap::mapping::testing {
namespace {

using Clock = std::chrono::steady_clock;

/// One replica: a store object on the shared database and a server over it.
class Replica {
 public:
  /// partition_zoom > 0: this replica partitions its builds and leaves the jobs to workers.
  Replica(const std::string& url, const std::filesystem::path& packages,
          const std::filesystem::path& uploads, int partition_zoom = 0,
          double abandoned_build_check_s = ServerConfig{}.abandoned_build_check_s) {
    PostgresStoreOptions o;
    o.conninfo = url;
    o.package_dir = packages;
    store_ = std::make_unique<PostgresMapStore>(std::move(o));
    std::filesystem::create_directories(uploads);
    ServerConfig cfg;
    cfg.api_keys = {kKey};
    cfg.upload_dir = uploads;
    cfg.threads = 4;
    cfg.log_requests = false;
    cfg.fail_stale_builds_on_start = false;  // as polmap serve on PostgreSQL
    cfg.abandoned_build_check_s = abandoned_build_check_s;
    if (partition_zoom > 0) {
      cfg.build_partition_zoom = partition_zoom;
      cfg.run_build_jobs = false;
    }
    server_ = std::make_unique<Server>(*store_, cfg);
    thread_ = std::thread([this] { server_->listen("127.0.0.1", 0); });
    ok_ = server_->wait_until_listening(std::chrono::seconds(10));
  }
  ~Replica() {
    server_->stop();
    if (thread_.joinable()) thread_.join();
  }
  Replica(const Replica&) = delete;
  Replica& operator=(const Replica&) = delete;
  [[nodiscard]] bool ok() const { return ok_; }
  [[nodiscard]] httplib::Client client() const {
    httplib::Client c("127.0.0.1", server_->bound_port());
    c.set_read_timeout(120, 0);
    c.set_write_timeout(120, 0);
    return c;
  }
  Server& server() { return *server_; }
  MapStore& store() { return *store_; }

 private:
  std::unique_ptr<PostgresMapStore> store_;
  std::unique_ptr<Server> server_;
  std::thread thread_;
  bool ok_ = false;
};

httplib::Headers auth() { return {{"Authorization", std::string("Bearer ") + kKey}}; }

const std::string& scene_tar(const std::string& drive_id, unsigned seed) {
  static std::map<std::string, std::string> cache;
  auto it = cache.find(drive_id);
  if (it == cache.end()) {
    const util::ScopedTempDir base(polmap::test::unique_test_dir("replica-pkgs"));
    it =
        cache
            .emplace(drive_id, pack_drive_package(write_scene_package(base.path(), drive_id, seed)))
            .first;
  }
  return it->second;
}

TEST(Replicas, TwoServersOnOnePostgresStoreAnswerAlike) {
  polmap::test::TestDir tmp("replicas");
  const std::string url = PostgresCluster::instance().create_database();
  Replica a(url, tmp.path() / "packages", tmp.path() / "uploads-a");
  Replica b(url, tmp.path() / "packages", tmp.path() / "uploads-b");
  ASSERT_TRUE(a.ok());
  ASSERT_TRUE(b.ok());

  // The same drive through both replicas at once: one drive.
  const std::string& d0 = scene_tar("replica_drive_0", 21);
  int status_a = 0, status_b = 0;
  std::thread ta([&] {
    auto c = a.client();
    auto r = c.Post("/v1/drives", auth(), d0, "application/x-tar");
    status_a = r ? r->status : -1;
  });
  std::thread tb([&] {
    auto c = b.client();
    auto r = c.Post("/v1/drives", auth(), d0, "application/x-tar");
    status_b = r ? r->status : -1;
  });
  ta.join();
  tb.join();
  EXPECT_TRUE((status_a == 201 && status_b == 200) || (status_a == 200 && status_b == 201))
      << status_a << " " << status_b;
  EXPECT_EQ(a.store().list_drives().size(), 1U);
  // Two more drives, one through each.
  auto ca = a.client();
  auto cb = b.client();
  ASSERT_EQ(
      ca.Post("/v1/drives", auth(), scene_tar("replica_drive_1", 22), "application/x-tar")->status,
      201);
  ASSERT_EQ(
      cb.Post("/v1/drives", auth(), scene_tar("replica_drive_2", 23), "application/x-tar")->status,
      201);
  EXPECT_EQ(b.store().list_drives().size(), 3U);

  // A map built through A: served by B within a second of its publication.
  auto r = ca.Post("/v1/maps", auth(), "{}", "application/json");
  ASSERT_EQ(r->status, 202) << r->body;
  const auto version = nlohmann::json::parse(r->body)["version"].get<std::int64_t>();
  a.server().wait_for_builds();
  ASSERT_EQ(nlohmann::json::parse(ca.Get("/v1/maps/" + std::to_string(version))->body)["status"],
            "published");
  const auto published = Clock::now();
  double seen_after_s = -1;
  while (Clock::now() - published < std::chrono::seconds(5)) {
    const auto tj = cb.Get("/v1/tilejson.json");
    if (tj && tj->status == 200) {
      const auto j = nlohmann::json::parse(tj->body);
      if (j.contains("polmap") && j["polmap"]["map_version"] == version) {
        seen_after_s = std::chrono::duration<double>(Clock::now() - published).count();
        break;
      }
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_GE(seen_after_s, 0.0) << "replica B never served the new version";
  EXPECT_LT(seen_after_s, 1.0);
  std::printf("[replicas] version %lld served by the other replica after %.3f s\n",
              static_cast<long long>(version), seen_after_s);

  // Same bytes and ETags from both: localization tiles, vector tiles, TileJSON.
  const auto tiles_listed = a.store().list_tiles(version, TileLayer::Localization);
  ASSERT_FALSE(tiles_listed.empty());
  httplib::Headers host{{"Host", "maps.example"}};
  for (const auto& t : tiles_listed) {
    for (const std::string& path :
         {"/v1/tiles/" + tiles::to_string(t.key), "/v1/mvt/" + tiles::to_string(t.key) + ".mvt"}) {
      const auto ra = ca.Get(path, host);
      const auto rb = cb.Get(path, host);
      ASSERT_TRUE(ra && rb);
      EXPECT_EQ(ra->status, rb->status) << path;
      EXPECT_EQ(ra->get_header_value("ETag"), rb->get_header_value("ETag")) << path;
      EXPECT_EQ(ra->body, rb->body) << path;
    }
  }
  EXPECT_EQ(ca.Get("/v1/tilejson.json", host)->body, cb.Get("/v1/tilejson.json", host)->body);
}

TEST(Replicas, AReplicaFailsTheBuildsOfOneThatWasKilledWithinItsCheckInterval) {
  polmap::test::TestDir tmp("replicas-abandoned");
  const std::string url = PostgresCluster::instance().create_database();
  Replica a(url, tmp.path() / "packages", tmp.path() / "uploads-a", 0, 0.2);
  ASSERT_TRUE(a.ok());
  PostgresStoreOptions o;
  o.conninfo = url;
  PostgresMapStore alive(o);  // a replica that is building
  const std::int64_t running = alive.begin_map_version({{"notes", "running"}});
  std::int64_t abandoned = 0;
  {
    PostgresMapStore killed(o);  // a replica killed with a build queued
    abandoned = killed.begin_map_version({{"notes", "queued"}});
  }
  auto ca = a.client();
  std::string status;
  const auto deadline = Clock::now() + std::chrono::seconds(10);
  while (Clock::now() < deadline) {
    auto r = ca.Get("/v1/maps/" + std::to_string(abandoned));
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200);
    status = nlohmann::json::parse(r->body).value("status", "");
    if (status != "building") break;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  EXPECT_EQ(status, "failed");
  auto r = ca.Get("/v1/maps/" + std::to_string(running));
  ASSERT_TRUE(r);
  EXPECT_EQ(nlohmann::json::parse(r->body).value("status", ""), "building");
  r = ca.Get("/metrics", auth());
  ASSERT_TRUE(r);
  EXPECT_NE(r->body.find("polmap_map_builds_total{outcome=\"abandoned\"} 1"), std::string::npos)
      << r->body;
  alive.publish_map_version(running, {});
  EXPECT_EQ(a.store().current_map_version(), running);
}

TEST(Replicas, APartitionedBuildQueuedOnOneIsRunByWorkersWithItsProgressOnTheOther) {
  polmap::test::TestDir tmp("replicas-workers");
  const std::string url = PostgresCluster::instance().create_database();
  Replica a(url, tmp.path() / "packages", tmp.path() / "uploads-a", 16);
  Replica b(url, tmp.path() / "packages", tmp.path() / "uploads-b");
  ASSERT_TRUE(a.ok());
  ASSERT_TRUE(b.ok());
  auto ca = a.client();
  auto cb = b.client();
  ASSERT_EQ(
      ca.Post("/v1/drives", auth(), scene_tar("replica_drive_1", 22), "application/x-tar")->status,
      201);
  ASSERT_EQ(
      cb.Post("/v1/drives", auth(), scene_tar("replica_drive_2", 23), "application/x-tar")->status,
      201);
  auto r = ca.Post("/v1/maps", auth(), "{}", "application/json");
  ASSERT_EQ(r->status, 202);
  const std::int64_t version = nlohmann::json::parse(r->body)["version"].get<std::int64_t>();
  const std::string path = "/v1/maps/" + std::to_string(version);
  // No worker yet: the build waits, and the other replica shows its jobs.
  nlohmann::json j;
  for (int i = 0; i < 200; ++i) {
    j = nlohmann::json::parse(cb.Get(path)->body);
    if (j.contains("progress")) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  ASSERT_EQ(j["status"], "building");
  ASSERT_TRUE(j.contains("progress")) << j.dump();
  EXPECT_EQ(j["progress"]["stage"], "jobs");
  EXPECT_EQ(j["progress"]["jobs_done"], 0);
  EXPECT_GE(j["progress"]["jobs"].get<int>(), 3);  // gridmap, regions, publish
  // Two workers with stores of their own (as two more processes) finish it.
  std::atomic<bool> stop{false};
  std::vector<std::thread> workers;
  for (int w = 0; w < 2; ++w) {
    workers.emplace_back([&, w] {
      PostgresStoreOptions o;
      o.conninfo = url;
      PostgresMapStore store(std::move(o));
      std::string id = "worker-";
      id += std::to_string(w);
      const BuildWorker worker({.worker_id = id});
      while (!stop) {
        if (worker.run_one(store).status == BuildJobRun::Status::Idle) {
          std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
      }
    });
  }
  a.server().wait_for_builds();
  stop = true;
  for (auto& t : workers) t.join();
  j = nlohmann::json::parse(cb.Get(path)->body);
  EXPECT_EQ(j["status"], "published") << j.dump();
  EXPECT_FALSE(j.contains("progress"));
  EXPECT_GT(j["statistics"]["point_landmarks"].get<int>(), 0);
  EXPECT_GE(j["statistics"]["partition"]["regions"].get<int>(), 1);
  // Served by the other replica within a second.
  bool served = false;
  for (int i = 0; i < 40 && !served; ++i) {
    const auto t = cb.Get("/v1/tilejson.json");
    served = t && nlohmann::json::parse(t->body)["polmap"]["map_version"] == version;
    if (!served) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  EXPECT_TRUE(served);
}

}  // namespace
}  // namespace polmap::mapping::testing
