// The tile fetcher against a tiny tile server in the test (real loopback HTTP):
// cache hit, 304 revalidation, 204/404, retries after 5xx, offline operation from
// the disk cache when the server stops, pickup of a new map version, and tile()
// never blocking while the server is slow, cache files that do not decode ignored.
#include "polmap/localization_client/tile_fetcher.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <random>
#include <set>
#include <thread>

#include "polmap/localization_client/tile_cache_file.hpp"
#include "test_dir.hpp"
// After Eigen: <resolv.h> (pulled in by httplib) defines a macro _res that
// collides with Eigen's parameter names.
#include <httplib.h>

namespace polmap::loc {
namespace {

using tiles::TileKey;

tiles::LocalizationTile make_tile(const TileKey& key, std::uint64_t version, int n_points) {
  tiles::LocalizationTile t;
  t.key = key;
  t.map_version = version;
  for (int i = 0; i < n_points; ++i) {
    PointLandmark p;
    p.id = 100 * static_cast<std::int64_t>(version) + i;
    p.position_m = {1.5 * i, -2.0 * i};
    t.points.push_back(p);
  }
  LineLandmark l;
  l.id = 7;
  l.polyline_m = {{0.0, 0.0}, {10.0, 5.0}};
  t.lines.push_back(l);
  return t;
}

/// A minimal tile server with the semantics of mapping_service's
/// GET /v1/tiles/{z}/{x}/{y}: strong ETag, If-None-Match -> 304, 204 for covered
/// tiles without landmarks, 404 outside, X-Polmap-Map-Version on every answer.
class FakeTileServer {
 public:
  FakeTileServer() {
    server_.Get(R"(/v1/tiles/(\d+)/(\d+)/(\d+))",
                [this](const httplib::Request& req, httplib::Response& res) {
                  const TileKey key{std::stoi(req.matches[1]), std::stoi(req.matches[2]),
                                    std::stoi(req.matches[3])};
                  std::unique_lock lock(mutex_);
                  ++requests_;
                  if (delay_ms_ > 0) {
                    const int d = delay_ms_;
                    lock.unlock();
                    std::this_thread::sleep_for(std::chrono::milliseconds(d));
                    lock.lock();
                  }
                  if (fail_next_ > 0) {
                    --fail_next_;
                    res.status = 503;
                    return;
                  }
                  res.set_header("X-Polmap-Map-Version", std::to_string(version_));
                  if (hostile_ != Hostile::None) return serve_hostile(key, res);
                  const auto it = tiles_.find(key);
                  if (it == tiles_.end()) {
                    res.status = covered_.contains(key) ? 204 : 404;
                    if (res.status == 404) res.set_header("X-Polmap-Coverage", "outside");
                    return;
                  }
                  // (Built with += : GCC 12 warns falsely (-Wrestrict) on "\"" + s + "\"".)
                  std::string etag = std::to_string(std::hash<std::string>{}(it->second));
                  etag.insert(etag.begin(), '"');
                  etag.push_back('"');
                  if (req.get_header_value("If-None-Match") == etag) {
                    ++not_modified_;
                    res.status = 304;
                    res.set_header("ETag", etag);
                    return;
                  }
                  res.status = 200;
                  res.set_header("ETag", etag);
                  res.set_content(it->second, std::string(tiles::kLocalizationTileMediaType));
                });
    // stop() waits for open keep-alive connections to time out.
    server_.set_keep_alive_timeout(1);
    port_ = server_.bind_to_any_port("127.0.0.1");
    thread_ = std::thread([this] { server_.listen_after_bind(); });
    while (!server_.is_running()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  ~FakeTileServer() { stop(); }

  void stop() {
    server_.stop();
    if (thread_.joinable()) thread_.join();
  }
  void publish(std::uint64_t version, const std::vector<tiles::LocalizationTile>& ts) {
    std::lock_guard lock(mutex_);
    version_ = version;
    tiles_.clear();
    for (const auto& t : ts) tiles_[t.key] = tiles::encode_localization_tile(t);
  }
  void cover(const TileKey& k) {
    std::lock_guard lock(mutex_);
    covered_.insert(k);
  }
  void fail_next(int n) {
    std::lock_guard lock(mutex_);
    fail_next_ = n;
  }
  void set_delay_ms(int ms) {
    std::lock_guard lock(mutex_);
    delay_ms_ = ms;
  }
  int requests() {
    std::lock_guard lock(mutex_);
    return requests_;
  }
  int not_modified() {
    std::lock_guard lock(mutex_);
    return not_modified_;
  }
  [[nodiscard]] std::string url() const { return "http://127.0.0.1:" + std::to_string(port_); }

  /// Misbehaviours of a hostile (or broken) server.
  enum class Hostile { None, Oversized, Drip, WrongKey, Bare404 };
  void set_hostile(Hostile h) {
    std::lock_guard lock(mutex_);
    hostile_ = h;
  }

 private:
  void serve_hostile(const TileKey& key, httplib::Response& res) {
    switch (hostile_) {
      case Hostile::Oversized:  // 8 MB "tile"
        res.set_content(std::string(8u << 20, 'x'), "application/octet-stream");
        return;
      case Hostile::Drip:  // one byte every 50 ms, for 20 s
        res.set_chunked_content_provider(
            "application/octet-stream", [](std::size_t offset, httplib::DataSink& sink) {
              if (offset > 400) return false;
              std::this_thread::sleep_for(std::chrono::milliseconds(50));
              return sink.write("x", 1);
            });
        return;
      case Hostile::WrongKey:  // a valid tile, but of another place
        res.set_content(tiles::encode_localization_tile(
                            make_tile(TileKey{key.z, key.x + 1, key.y}, version_, 4)),
                        std::string(tiles::kLocalizationTileMediaType));
        return;
      case Hostile::Bare404:  // a proxy's error page
        res.status = 404;
        res.set_content("<html>not found</html>", "text/html");
        return;
      case Hostile::None:
        return;
    }
  }

  Hostile hostile_ = Hostile::None;
  httplib::Server server_;
  std::thread thread_;
  int port_ = 0;
  std::mutex mutex_;
  std::uint64_t version_ = 1;
  std::map<TileKey, std::string> tiles_;
  std::set<TileKey> covered_;
  int requests_ = 0, not_modified_ = 0, fail_next_ = 0, delay_ms_ = 0;
};

class TileFetcherTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = polmap::test::unique_test_dir("tile-fetcher"); }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  TileFetcherConfig config(const std::string& url) const {
    TileFetcherConfig c;
    c.server_url = url;
    c.cache_dir = dir_;
    c.connect_timeout_s = 0.5;
    c.read_timeout_s = 2.0;
    c.backoff_initial_s = 0.05;
    c.backoff_max_s = 0.2;
    return c;
  }

  std::filesystem::path dir_;
  const TileKey k1{16, 34000, 22000}, k2{16, 34001, 22000}, k_empty{16, 34002, 22000},
      k_outside{16, 1, 1};
};

TEST_F(TileFetcherTest, FetchesCachesAndRevalidatesWith304) {
  FakeTileServer server;
  server.publish(1, {make_tile(k1, 1, 5), make_tile(k2, 1, 3)});
  server.cover(k_empty);
  auto cfg = config(server.url());
  cfg.revalidate_after_s = 0.3;
  TileFetcher fetcher(cfg);

  EXPECT_FALSE(fetcher.tile(k1).has_value());  // miss: queued, not waited for
  const std::vector<TileKey> keys{k1, k2, k_empty, k_outside};
  ASSERT_TRUE(fetcher.wait_for(keys, 5.0));
  const auto t1 = fetcher.tile(k1);
  ASSERT_TRUE(t1.has_value());
  EXPECT_EQ(t1->points.size(), 5U);
  EXPECT_EQ(t1->lines.size(), 1U);
  EXPECT_TRUE(fetcher.tile(k_empty)->points.empty());    // 204: covered, no landmarks
  EXPECT_TRUE(fetcher.tile(k_outside)->points.empty());  // 404: outside the map
  const int requests_after_fetch = server.requests();
  EXPECT_EQ(requests_after_fetch, 4);

  // Fresh copies are served from memory without requests.
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(fetcher.tile(k1).has_value());
  ASSERT_TRUE(fetcher.wait_idle(2.0));
  EXPECT_EQ(server.requests(), requests_after_fetch);

  // After revalidate_after_s the copy is revalidated with If-None-Match -> 304.
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  ASSERT_TRUE(fetcher.tile(k1).has_value());  // still served while revalidating
  ASSERT_TRUE(fetcher.wait_idle(2.0));
  EXPECT_EQ(server.not_modified(), 1);
  const auto s = fetcher.stats();
  EXPECT_EQ(s.responses_200, 2U);
  EXPECT_EQ(s.responses_204, 1U);
  EXPECT_EQ(s.responses_404, 1U);
  EXPECT_EQ(s.responses_304, 1U);
  EXPECT_EQ(s.map_version, 1U);
  EXPECT_TRUE(s.server_reachable);
  EXPECT_TRUE(std::filesystem::exists(dir_ / "16" / "34000" / "22000.pmtc"));
}

TEST_F(TileFetcherTest, ServesFromDiskCacheWhenTheServerIsGone) {
  std::string url;
  {
    FakeTileServer server;
    url = server.url();
    server.publish(1, {make_tile(k1, 1, 5)});
    TileFetcher fetcher(config(url));
    const std::vector<TileKey> keys{k1};
    ASSERT_TRUE(fetcher.wait_for(keys, 5.0));
    // Same fetcher, server stops: the memory copy keeps being served even when
    // its revalidation fails.
    server.stop();
    fetcher.invalidate_all();
    ASSERT_TRUE(fetcher.tile(k1).has_value());
    ASSERT_TRUE(fetcher.wait_idle(3.0));
    EXPECT_EQ(fetcher.tile(k1)->points.size(), 5U);
    EXPECT_GE(fetcher.stats().transport_errors, 1U);
    EXPECT_FALSE(fetcher.stats().server_reachable);
  }
  // A new process (restart) with the server still down: the disk cache serves.
  TileFetcher offline(config(url));
  const std::vector<TileKey> keys{k1};
  ASSERT_TRUE(offline.wait_for(keys, 5.0));
  const auto t = offline.tile(k1);
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->points.size(), 5U);
  EXPECT_EQ(offline.stats().disk_loads, 1U);
  // A tile that was never cached stays unavailable (and is retried in the background).
  const std::vector<TileKey> missing{k2};
  EXPECT_FALSE(offline.wait_for(missing, 0.5));
  EXPECT_FALSE(offline.tile(k2).has_value());
}

TEST_F(TileFetcherTest, IgnoresCacheFilesThatDoNotDecode) {
  // Offline (no server): only the disk cache can answer.
  auto cfg = config("");
  const auto write = [&](const TileKey& key, const std::string& bytes) {
    const auto path =
        dir_ / std::to_string(key.z) / std::to_string(key.x) / (std::to_string(key.y) + ".pmtc");
    std::filesystem::create_directories(path.parent_path());
    std::ofstream(path, std::ios::binary) << bytes;
  };
  const auto record = [](const TileKey& key, int extra_points) {
    TileCacheRecord r;
    r.etag = "\"e\"";
    r.header_version = 3;
    r.fetched_unix_s = 1.0;
    r.payload = tiles::encode_localization_tile(make_tile(key, 3, 4 + extra_points));
    return r;
  };
  const TileKey k_torn{16, 34003, 22000}, k_other{16, 34004, 22000}, k_big{16, 34005, 22000};
  write(k1, encode_tile_cache_file(record(k1, 0), k1));
  const std::string torn = encode_tile_cache_file(record(k_torn, 0), k_torn);
  write(k_torn, torn.substr(0, torn.size() - 1));
  write(k_other, encode_tile_cache_file(record(k1, 0), k1));  // k1's file under k_other
  write(k_big, encode_tile_cache_file(record(k_big, 2000), k_big));
  cfg.max_tile_bytes = record(k1, 0).payload.size() + 8;  // k1 fits, k_big does not
  ASSERT_GT(record(k_big, 2000).payload.size(), cfg.max_tile_bytes);
  TileFetcher fetcher(cfg);
  const std::vector<TileKey> keys{k1};
  ASSERT_TRUE(fetcher.wait_for(keys, 5.0));
  EXPECT_EQ(fetcher.tile(k1)->points.size(), 4U);
  const std::vector<TileKey> bad{k_torn, k_other, k_big};
  EXPECT_FALSE(fetcher.wait_for(bad, 0.5));
  for (const auto& k : bad) EXPECT_FALSE(fetcher.tile(k).has_value()) << tiles::to_string(k);
  EXPECT_EQ(fetcher.stats().disk_loads, 1U);
}

TEST_F(TileFetcherTest, PicksUpANewMapVersionWithoutRestart) {
  FakeTileServer server;
  server.publish(1, {make_tile(k1, 1, 5), make_tile(k2, 1, 3)});
  auto cfg = config(server.url());
  cfg.revalidate_after_s = 3600.0;  // only the version header can trigger the pickup
  TileFetcher fetcher(cfg);
  const std::vector<TileKey> first{k1};
  ASSERT_TRUE(fetcher.wait_for(first, 5.0));
  EXPECT_EQ(fetcher.tile(k1)->map_version, 1U);

  server.publish(2, {make_tile(k1, 2, 8), make_tile(k2, 2, 3)});
  // Any answer of the new version (here: a tile not seen before) reveals it.
  const std::vector<TileKey> second{k2};
  ASSERT_TRUE(fetcher.wait_for(second, 5.0));
  EXPECT_EQ(fetcher.stats().map_version, 2U);
  // The old copy is still served at once, and revalidated in the background.
  EXPECT_EQ(fetcher.tile(k1)->map_version, 1U);
  ASSERT_TRUE(fetcher.wait_idle(3.0));
  const auto t = fetcher.tile(k1);
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->map_version, 2U);
  EXPECT_EQ(t->points.size(), 8U);

  // The new version also reached the disk cache.
  TileFetcherConfig offline_cfg = cfg;
  offline_cfg.server_url.clear();
  TileFetcher offline(offline_cfg);
  ASSERT_TRUE(offline.wait_for(first, 5.0));
  EXPECT_EQ(offline.tile(k1)->map_version, 2U);
}

TEST_F(TileFetcherTest, RetriesAfterServerErrors) {
  FakeTileServer server;
  server.publish(1, {make_tile(k1, 1, 2)});
  server.fail_next(2);
  TileFetcher fetcher(config(server.url()));
  const std::vector<TileKey> keys{k1};
  ASSERT_TRUE(fetcher.wait_for(keys, 5.0));
  EXPECT_EQ(fetcher.stats().server_errors, 2U);
  EXPECT_EQ(server.requests(), 3);
}

TEST_F(TileFetcherTest, TileNeverBlocksOnASlowServer) {
  FakeTileServer server;
  server.publish(1, {make_tile(k1, 1, 2), make_tile(k2, 1, 2)});
  server.set_delay_ms(800);
  TileFetcher fetcher(config(server.url()));
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < 100; ++i) {
    (void)fetcher.tile(k1);
    (void)fetcher.tile(k2);
  }
  const double elapsed_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // 200 calls while a request takes 0.8 s: they must not wait for it. 0.1 s is
  // far above the real cost (microseconds) and far below one request.
  EXPECT_LT(elapsed_s, 0.1);
  const std::vector<TileKey> keys{k1, k2};
  EXPECT_TRUE(fetcher.wait_for(keys, 5.0));
}

TEST(TilesAround, CoversTheRadius) {
  const GeoPoint p{48.4, 9.98, 0.0};
  const auto keys = tiles_around(p, 150.0);
  ASSERT_FALSE(keys.empty());
  EXPECT_LE(keys.size(), 4U);  // 300 m box vs ~400 m tiles
  bool contains_own = false;
  const TileKey own = tiles::tile_at(p.lat_deg, p.lon_deg, tiles::kLocalizationZoom);
  for (const auto& k : keys) contains_own = contains_own || k == own;
  EXPECT_TRUE(contains_own);
}

TEST_F(TileFetcherTest, SurvivesAHostileServer) {
  // Each misbehaviour: the tile is not served, nothing is cached, the worker stays free.
  for (const auto mode : {FakeTileServer::Hostile::Oversized, FakeTileServer::Hostile::Drip,
                          FakeTileServer::Hostile::WrongKey, FakeTileServer::Hostile::Bare404}) {
    FakeTileServer server;
    server.set_hostile(mode);
    auto cfg = config(server.url());
    cfg.request_deadline_s = 1.0;
    cfg.max_tile_bytes = 1u << 20;
    const auto t0 = std::chrono::steady_clock::now();
    {
      TileFetcher fetcher(cfg);
      EXPECT_FALSE(fetcher.tile(k1).has_value());
      EXPECT_FALSE(fetcher.wait_for(std::vector<TileKey>{k1}, 2.0)) << static_cast<int>(mode);
      EXPECT_FALSE(fetcher.tile(k1).has_value());
      EXPECT_GE(fetcher.stats().server_errors, 1U) << static_cast<int>(mode);
      EXPECT_EQ(fetcher.stats().responses_200 + fetcher.stats().responses_404, 0U);
    }
    EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 10.0);
    EXPECT_FALSE(std::filesystem::exists(dir_ / "16" / "34000" / "22000.pmtc"))
        << static_cast<int>(mode);
    server.stop();
  }
}

}  // namespace
}  // namespace polmap::loc
