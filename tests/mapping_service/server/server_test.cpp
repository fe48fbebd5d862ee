// The mapping server end to end on loopback: real SQLite store, real packages, real HTTP.
#include <arpa/inet.h>
#include <gdal.h>
#include <netinet/in.h>
#include <ogrsf_frmts.h>
#include <sys/socket.h>
#include <zlib.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <thread>

#include "mapping_service/server_fixture.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/localization_tile.hpp"
#include "polmap/tiles/tile_key.hpp"
#include "test_dir.hpp"

namespace polmap::mapping::testing {
namespace {

using nlohmann::json;

// Sends raw bytes on a fresh connection; optionally half-closes; returns what the server sent.
std::string raw_exchange(int port, const std::string& bytes, bool read_reply = true) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    ::close(fd);
    return "connect failed";
  }
  std::size_t off = 0;
  while (off < bytes.size()) {
    const ssize_t w = ::send(fd, bytes.data() + off, bytes.size() - off, MSG_NOSIGNAL);
    if (w <= 0) break;
    off += static_cast<std::size_t>(w);
  }
  std::string reply;
  if (read_reply) {
    timeval tv{10, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    char buf[4096];
    for (;;) {
      const ssize_t r = ::recv(fd, buf, sizeof buf, 0);
      if (r <= 0) break;
      reply.append(buf, static_cast<std::size_t>(r));
      if (reply.find("\r\n\r\n") != std::string::npos) {
        // Headers complete; read the declared body and stop.
        const auto cl = reply.find("Content-Length: ");
        const auto hdr_end = reply.find("\r\n\r\n") + 4;
        if (cl != std::string::npos) {
          const std::size_t n = std::stoul(reply.substr(cl + 16));
          if (reply.size() >= hdr_end + n) break;
        }
      }
    }
  }
  ::close(fd);
  return reply;
}

template <class Pred>
bool eventually(Pred pred, double seconds = 10.0) {
  const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < until) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return pred();
}

json body_json(const httplib::Result& r) { return json::parse(r->body); }

class ServerTest : public ServerFixture {
 protected:
  /// Uploads the three scene drives and builds a map; returns the version.
  std::int64_t upload_and_build() {
    auto c = client();
    for (int i = 0; i < 3; ++i) {
      const std::string id = "scene_drive_" + std::to_string(i);
      auto r = c.Post("/v1/drives", auth(), scene_tar(id, 11 + i), "application/x-tar");
      EXPECT_TRUE(r);
      EXPECT_EQ(r->status, 201) << r->body;
    }
    auto r = c.Post("/v1/maps", auth(), "{}", "application/json");
    EXPECT_EQ(r->status, 202) << r->body;
    const std::int64_t version = body_json(r)["version"].get<std::int64_t>();
    EXPECT_EQ(r->get_header_value("Location"), "/v1/maps/" + std::to_string(version));
    server_->wait_for_builds();
    r = c.Get("/v1/maps/" + std::to_string(version));
    EXPECT_EQ(r->status, 200);
    EXPECT_EQ(body_json(r)["status"], "published") << r->body;
    return version;
  }

  /// Tiles that hold the scene's landmarks.
  static std::set<tiles::TileKey> scene_tiles() {
    std::set<tiles::TileKey> keys;
    const auto frame = scene_frame();
    for (const auto& p : true_points()) {
      const GeoPoint g = frame.to_geo(p);
      keys.insert(tiles::tile_at(g.lat_deg, g.lon_deg, tiles::kLocalizationZoom));
    }
    return keys;
  }
  static std::string tile_path(const tiles::TileKey& k) {
    return "/v1/tiles/" + tiles::to_string(k);
  }
};

TEST_F(ServerTest, HealthMetricsCorsAndUnknownRoutes) {
  auto c = client();
  auto r = c.Get("/health");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(body_json(r)["status"], "ok");
  EXPECT_TRUE(body_json(r)["current_map_version"].is_null());
  EXPECT_FALSE(r->has_header("Access-Control-Allow-Origin"));  // no CORS unless configured

  r = c.Get("/no/such/thing");
  EXPECT_EQ(r->status, 404);
  EXPECT_NE(body_json(r)["error"].get<std::string>().find("no such endpoint"), std::string::npos);

  // The server records a request after writing its response: a new connection may be
  // answered before that, so poll briefly.
  const std::string health_line =
      "polmap_http_requests_total{route=\"health\",method=\"GET\",status=\"200\"} 1";
  for (int i = 0; i < 100; ++i) {
    r = c.Get("/metrics", auth());
    if (r && r->body.find(health_line) != std::string::npos) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_EQ(r->status, 200);
  EXPECT_NE(r->body.find(health_line), std::string::npos) << r->body;
  EXPECT_NE(
      r->body.find("polmap_http_request_duration_seconds_bucket{route=\"health\",le=\"+Inf\"} 1"),
      std::string::npos);
  EXPECT_NE(r->body.find("polmap_drives 0"), std::string::npos);
  EXPECT_NE(r->body.find("polmap_current_map_version 0"), std::string::npos);
  // One log line per request with method, path, status, bytes, ms.
  bool found = false;
  for (const auto& l : log_lines()) {
    found |= l.find(" info 127.0.0.1 GET /health 200 ") != std::string::npos &&
             l.find(" ms") != std::string::npos;
  }
  EXPECT_TRUE(found);

  // CORS only for a configured origin.
  ServerConfig with_cors;
  with_cors.cors_allow_origin = "https://console.example.com";
  restart(with_cors);
  auto cc = client();
  r = cc.Get("/health");
  EXPECT_EQ(r->get_header_value("Access-Control-Allow-Origin"), "https://console.example.com");
  r = cc.Options("/v1/tiles/16/1/2");
  EXPECT_EQ(r->status, 204);
  EXPECT_NE(r->get_header_value("Access-Control-Allow-Methods").find("GET"), std::string::npos);
  EXPECT_NE(r->get_header_value("Access-Control-Allow-Headers").find("Authorization"),
            std::string::npos);
}

TEST_F(ServerTest, WritesNeedAValidKey) {
  auto c = client();
  const std::string& tar = scene_tar("scene_drive_0", 11);
  auto r = c.Post("/v1/drives", tar, "application/x-tar");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 401);
  EXPECT_EQ(body_json(r)["field"], "Authorization");
  EXPECT_EQ(r->get_header_value("WWW-Authenticate"), "Bearer realm=\"polmap\"");
  for (const std::string& bad : {std::string("wrong"), std::string(kKey) + "x",
                                 std::string(kKey).substr(0, 5), std::string()}) {
    auto c2 = client();
    r = c2.Post("/v1/drives", auth(bad), tar, "application/x-tar");
    ASSERT_TRUE(r) << bad;
    EXPECT_EQ(r->status, 401) << bad;
  }
  auto c3 = client();
  r = c3.Post("/v1/drives", {{"Authorization", "Basic " + std::string(kKey)}}, tar,
              "application/x-tar");
  EXPECT_EQ(r->status, 401);
  auto c4 = client();
  EXPECT_EQ(c4.Post("/v1/maps", "{}", "application/json")->status, 401);
  EXPECT_EQ(c4.Delete("/v1/drives/x")->status, 401);
  EXPECT_EQ(store_->list_drives().size(), 0u);
  EXPECT_EQ(store_->list_map_versions().size(), 0u);
  EXPECT_EQ(upload_leftovers(), 0u);
  // A refused small upload does not break the keep-alive connection it came on.
  auto keep = client();
  keep.set_keep_alive(true);
  EXPECT_EQ(
      keep.Post("/v1/drives", auth("nope"), std::string(1000, 'x'), "application/x-tar")->status,
      401);
  EXPECT_EQ(keep.Get("/health")->status, 200);
  EXPECT_EQ(keep.Get("/health")->status, 200);
  // The second key and the case-insensitive scheme work.
  auto c5 = client();
  r = c5.Post("/v1/drives", {{"Authorization", std::string("bearer ") + kOtherKey}}, tar,
              "application/x-tar");
  EXPECT_EQ(r->status, 201) << r->body;
}

TEST_F(ServerTest, UploadIsIdempotentAndConflictsAreRejected) {
  auto c = client();
  const std::string& tar = scene_tar("scene_drive_0", 11);
  auto r = c.Post("/v1/drives", auth(), tar, "application/x-tar");
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 201) << r->body;
  json j = body_json(r);
  EXPECT_EQ(j["drive_id"], "scene_drive_0");
  EXPECT_EQ(j["status"], "inserted");
  EXPECT_EQ(j["num_points"], 13);
  EXPECT_EQ(j["num_lines"], 3);
  EXPECT_EQ(r->get_header_value("Location"), "/v1/drives/scene_drive_0");
  const std::string hash = j["content_hash"];
  EXPECT_EQ(hash.size(), 64u);

  r = c.Post("/v1/drives", auth(), tar, "application/x-tar");
  EXPECT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(body_json(r)["status"], "already_present");
  EXPECT_EQ(body_json(r)["content_hash"], hash);

  // Same drive id, different content: 409, nothing changes.
  const std::size_t entries = drive_store_entries();
  // Re-use drive 1's files under drive 0's id: a different archive with the same drive_id.
  r = c.Post("/v1/drives", auth(),
             with_manifest_field(scene_tar("scene_drive_1", 12), "drive_id", "scene_drive_0"),
             "application/x-tar");
  EXPECT_EQ(r->status, 409) << r->body;
  EXPECT_EQ(body_json(r)["field"], "drive_id");
  EXPECT_EQ(store_->list_drives().size(), 1u);
  EXPECT_EQ(drive_store_entries(), entries);

  r = c.Get("/v1/drives", auth());
  EXPECT_EQ(body_json(r)["count"], 1);
  r = c.Get("/v1/drives/scene_drive_0", auth());
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(body_json(r)["manifest"]["drive_id"], "scene_drive_0");
  EXPECT_EQ(c.Get("/v1/drives/nope", auth())->status, 404);

  EXPECT_EQ(c.Delete("/v1/drives/scene_drive_0", auth())->status, 204);
  EXPECT_EQ(c.Get("/v1/drives/scene_drive_0", auth())->status, 404);
  EXPECT_EQ(c.Delete("/v1/drives/scene_drive_0", auth())->status, 404);
  EXPECT_EQ(upload_leftovers(), 0u);
}

TEST_F(ServerTest, StoredPackagesAreTheValidatedMembersNotTheUpload) {
  auto c = client();
  auto r = c.Post("/v1/drives", auth(), scene_tar("scene_drive_0", 11), "application/x-tar");
  ASSERT_EQ(r->status, 201) << r->body;
  // The store holds the members the validator read (no archive for GDAL's /vsitar/ to read
  // differently), byte for byte as in the upload.
  const auto d = store_->get_drive("scene_drive_0");
  ASSERT_TRUE(d);
  ASSERT_TRUE(std::filesystem::is_directory(d->package_path)) << d->package_path;
  std::set<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(d->package_path)) {
    EXPECT_TRUE(e.is_regular_file()) << e.path();
    names.insert(e.path().filename().string());
  }
  EXPECT_EQ(names, (std::set<std::string>{"manifest.json", "gridmap.tif", "candidates.gpkg"}));
  for (const auto& m : read_ustar(scene_tar("scene_drive_0", 11))) {
    EXPECT_EQ(util::read_file_bytes(d->package_path / m.name), m.data) << m.name;
  }
  EXPECT_EQ(upload_leftovers(), 0u);
}

TEST_F(ServerTest, LimitsApplyBeforeAnyBodyByteIsRead) {
  auto status_of = [](const std::string& reply) {
    return reply.size() > 12 ? std::atoi(reply.substr(9, 3).c_str()) : 0;
  };
  // An unauthenticated write announcing 100 MB, body never sent: refused at once.
  std::string reply = raw_exchange(port_,
                                   "POST /v1/maps HTTP/1.1\r\nHost: x\r\nContent-Type: "
                                   "application/json\r\nContent-Length: 100000000\r\n\r\n");
  EXPECT_EQ(status_of(reply), 401) << reply;
  reply = raw_exchange(port_,
                       "POST /v1/drives HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n");
  EXPECT_EQ(status_of(reply), 401) << reply;
  const std::string key = "Authorization: Bearer " + std::string(kKey) + "\r\n";
  // With a key: JSON bodies must declare a bounded length and must not be encoded.
  reply = raw_exchange(
      port_, "POST /v1/maps HTTP/1.1\r\nHost: x\r\n" + key + "Transfer-Encoding: chunked\r\n\r\n");
  EXPECT_EQ(status_of(reply), 411) << reply;
  reply = raw_exchange(
      port_, "POST /v1/maps HTTP/1.1\r\nHost: x\r\n" + key + "Content-Length: 2000000\r\n\r\n");
  EXPECT_EQ(status_of(reply), 413) << reply;
  reply = raw_exchange(port_, "POST /v1/maps HTTP/1.1\r\nHost: x\r\n" + key +
                                  "Content-Encoding: gzip\r\nContent-Length: 10\r\n\r\n");
  EXPECT_EQ(status_of(reply), 415) << reply;
  // Many ranges, many headers.
  reply = raw_exchange(port_, "GET /health HTTP/1.1\r\nHost: x\r\nRange: bytes=0-1,2-3\r\n\r\n");
  EXPECT_EQ(status_of(reply), 416) << reply;
  std::string many = "GET /health HTTP/1.1\r\nHost: x\r\n";
  for (int i = 0; i < 100; ++i) many += "X-Filler-" + std::to_string(i) + ": y\r\n";
  reply = raw_exchange(port_, many + "\r\n");
  EXPECT_EQ(status_of(reply), 431) << reply;
  // And the server is still there for ordinary requests.
  auto c = client();
  auto r = c.Get("/health");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
}

TEST_F(ServerTest, StartRemovesOldUploadLeftoversOnly) {
  const auto uploads = dir_ / "uploads";
  std::ofstream(uploads / "polmap-upload-old.tar") << "x";
  std::filesystem::create_directories(uploads / "polmap-upload-members-old" / "sub");
  std::ofstream(uploads / "polmap-upload-fresh.tar") << "y";
  std::ofstream(uploads / "someone-elses.tar") << "z";
  const auto old = std::filesystem::file_time_type::clock::now() - std::chrono::hours(2);
  std::filesystem::last_write_time(uploads / "polmap-upload-old.tar", old);
  std::filesystem::last_write_time(uploads / "polmap-upload-members-old", old);
  std::filesystem::last_write_time(uploads / "someone-elses.tar", old);
  // Same directory, new server process (stop() would remove dir_: restart by hand).
  server_->stop();
  if (thread_.joinable()) thread_.join();
  ServerConfig cfg;
  cfg.upload_dir = uploads;
  cfg.log_sink = [](std::string_view) {};
  Server again(*store_, cfg);
  EXPECT_FALSE(std::filesystem::exists(uploads / "polmap-upload-old.tar"));
  EXPECT_FALSE(std::filesystem::exists(uploads / "polmap-upload-members-old"));
  EXPECT_TRUE(std::filesystem::exists(uploads / "polmap-upload-fresh.tar"));  // maybe in flight
  EXPECT_TRUE(std::filesystem::exists(uploads / "someone-elses.tar"));        // not ours
}

TEST_F(ServerTest, KeyRolesLimitWhatAKeyMayDo) {
  // The fixture's keys are operators; scoped ones come from a key file.
  const util::ScopedTempDir keys_dir(polmap::test::unique_test_dir("keys"));
  const auto key_file = keys_dir.path() / "keys";
  std::ofstream(key_file) << "operator " << kKey << "\nvehicle veh-key veh_01\n"
                          << "vehicle other-veh-key someone-else\nviewer view-key\n";
  ServerConfig cfg;
  cfg.api_key_file = key_file;
  cfg.api_keys = read_api_key_file(key_file);
  const std::string& tar = scene_tar("scene_drive_0", 11);  // of vehicle veh_01
  restart(cfg);
  auto as = [](const std::string& k) { return httplib::Headers{{"Authorization", "Bearer " + k}}; };
  auto cl = client();
  // Public: tiles and map versions; not drive data.
  EXPECT_EQ(cl.Get("/v1/drives")->status, 401);
  EXPECT_EQ(cl.Get("/metrics")->status, 401);
  // A vehicle key uploads its own vehicle's drives only, and reads nothing.
  EXPECT_EQ(cl.Post("/v1/drives", as("other-veh-key"), tar, "application/x-tar")->status, 403);
  auto r = cl.Post("/v1/drives", as("veh-key"), tar, "application/x-tar");
  ASSERT_EQ(r->status, 201) << r->body;
  EXPECT_EQ(cl.Get("/v1/drives", as("veh-key"))->status, 403);
  EXPECT_EQ(cl.Delete("/v1/drives/scene_drive_0", as("veh-key"))->status, 403);
  EXPECT_EQ(cl.Post("/v1/maps", as("veh-key"), "{}", "application/json")->status, 403);
  // A viewer reads drives and metrics, and may not write.
  EXPECT_EQ(cl.Get("/v1/drives", as("view-key"))->status, 200);
  EXPECT_EQ(cl.Get("/v1/drives/scene_drive_0", as("view-key"))->status, 200);
  EXPECT_EQ(cl.Get("/metrics", as("view-key"))->status, 200);
  EXPECT_EQ(cl.Delete("/v1/drives/scene_drive_0", as("view-key"))->status, 403);
  EXPECT_EQ(cl.Get("/v1/export?format=geojson", as("view-key"))->status, 403);
  EXPECT_EQ(cl.Post("/v1/drives", as("view-key"), tar, "application/x-tar")->status, 403);
  // Keys are revoked by editing the file, without a restart.
  std::ofstream(key_file) << "operator " << kKey << "\n";
  std::filesystem::last_write_time(
      key_file, std::filesystem::file_time_type::clock::now() + std::chrono::seconds(5));
  std::this_thread::sleep_for(std::chrono::milliseconds(1100));
  EXPECT_EQ(cl.Get("/v1/drives", as("view-key"))->status, 401);
  EXPECT_EQ(cl.Get("/v1/drives", as(kKey))->status, 200);
  // The operator may delete.
  EXPECT_EQ(cl.Delete("/v1/drives/scene_drive_0", as(kKey))->status, 204);
}

TEST_F(ServerTest, AVehiclesDrivesAreErasedOnRequestAndAfterTheRetentionPeriod) {
  auto c = client();
  ASSERT_EQ(
      c.Post("/v1/drives", auth(), scene_tar("scene_drive_0", 11), "application/x-tar")->status,
      201);
  ASSERT_EQ(
      c.Post("/v1/drives", auth(), scene_tar("scene_drive_1", 12), "application/x-tar")->status,
      201);
  EXPECT_EQ(c.Delete("/v1/vehicles/veh_01/drives")->status, 401);
  auto r = c.Delete("/v1/vehicles/nobody/drives", auth());
  ASSERT_EQ(r->status, 200);
  EXPECT_EQ(body_json(r)["deleted"], 0);
  r = c.Delete("/v1/vehicles/veh_01/drives", auth());
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(body_json(r)["deleted"], 2);
  EXPECT_TRUE(store_->list_drives().empty());
  EXPECT_EQ(drive_store_entries(), 0U);  // the package files are gone too

  // Retention: a drive older than the period is deleted when the server starts.
  ASSERT_EQ(
      c.Post("/v1/drives", auth(), scene_tar("scene_drive_0", 11), "application/x-tar")->status,
      201);
  std::this_thread::sleep_for(std::chrono::milliseconds(2100));  // ingested_at has 1 s steps
  server_->stop();
  if (thread_.joinable()) thread_.join();
  ServerConfig keep;
  keep.drive_retention_days = 30.0;
  keep.log_sink = [](std::string_view) {};
  { Server s(*store_, keep); }
  EXPECT_EQ(store_->list_drives().size(), 1U);  // younger than 30 days
  ServerConfig expire;
  expire.drive_retention_days = 1.0 / 86400.0;  // one second
  expire.log_sink = [](std::string_view) {};
  { Server s(*store_, expire); }
  EXPECT_TRUE(store_->list_drives().empty());
}

TEST_F(ServerTest, ConcurrentUploadsAreCappedBeforeTheirBodyIsRead) {
  ServerConfig cfg;
  cfg.max_concurrent_uploads = 1;
  restart(cfg);
  // One upload that has sent its headers and a first byte and then waits (a slow vehicle).
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port_));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ASSERT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  const std::string head = "POST /v1/drives HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " +
                           std::string(kKey) +
                           "\r\nContent-Type: application/x-tar\r\nContent-Length: 100000\r\n\r\nx";
  ASSERT_EQ(::send(fd, head.data(), head.size(), MSG_NOSIGNAL), static_cast<ssize_t>(head.size()));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  auto c = client();
  auto r = c.Post("/v1/drives", auth(), scene_tar("scene_drive_0", 11), "application/x-tar");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 503) << r->body;
  EXPECT_EQ(r->get_header_value("Retry-After"), "5");
  ::close(fd);  // the slow upload goes away: its slot is free again
  bool inserted = false;
  for (int i = 0; i < 50 && !inserted; ++i) {
    auto c2 = client();
    r = c2.Post("/v1/drives", auth(), scene_tar("scene_drive_0", 11), "application/x-tar");
    inserted = r && r->status == 201;
    if (!inserted) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_TRUE(inserted);
  EXPECT_EQ(upload_leftovers(), 0u);
}

TEST_F(ServerTest, InternalErrorsAreLoggedNotShownAndLogsAreEscaped) {
  store_options_.fault_hook = [](std::string_view stage) {
    if (stage == "rows_inserted") throw std::runtime_error("disk detail /srv/secret/path");
  };
  restart(ServerConfig{});
  auto c = client();
  auto r = c.Post("/v1/drives", auth(), scene_tar("scene_drive_0", 11), "application/x-tar");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 500);
  EXPECT_EQ(r->body.find("secret"), std::string::npos) << r->body;
  EXPECT_NE(body_json(r)["error"].get<std::string>().find("internal error (logged as #"),
            std::string::npos)
      << r->body;
  EXPECT_FALSE(store_->get_drive("scene_drive_0"));  // nothing half-stored
  bool logged = false;
  for (const auto& l : log_lines())
    logged = logged || l.find("/srv/secret/path") != std::string::npos;
  EXPECT_TRUE(logged);

  // A path with a line break and an escape sequence is logged as one escaped line.
  r = c.Get("/v1/no%0Asuch%1B[31m");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 404);
  for (const auto& l : log_lines()) {
    for (const char ch : l) EXPECT_TRUE(ch >= 0x20 && ch < 0x7f) << l;
  }
  // Unknown methods do not mint metric label values.
  for (int i = 0; i < 20; ++i) {
    httplib::Request req;
    req.method = "XMETHOD";
    req.method.push_back(static_cast<char>('A' + i));
    req.path = "/v1/health";
    httplib::Response res;
    httplib::Error err;
    c.send(req, res, err);
  }
  r = c.Get("/metrics", auth());
  ASSERT_EQ(r->status, 200);
  EXPECT_EQ(r->body.find("method=\"XMETHOD"), std::string::npos) << r->body;
  EXPECT_NE(r->body.find("method=\"other\""), std::string::npos) << r->body;
}

TEST_F(ServerTest, BadUploadsLeaveNoTrace) {
  auto c = client();
  // Seed one good drive so "unchanged" is not trivially "empty".
  ASSERT_EQ(
      c.Post("/v1/drives", auth(), scene_tar("scene_drive_0", 11), "application/x-tar")->status,
      201);
  const std::size_t entries = drive_store_entries();
  auto unchanged = [&] {
    EXPECT_EQ(store_->list_drives().size(), 1u);
    EXPECT_EQ(drive_store_entries(), entries);
    EXPECT_EQ(upload_leftovers(), 0u);
  };
  const std::string& good = scene_tar("scene_drive_1", 12);

  auto r = c.Post("/v1/drives", auth(), std::string(4000, 'x'), "application/x-tar");
  EXPECT_EQ(r->status, 400) << r->body;
  EXPECT_TRUE(body_json(r).contains("error"));
  unchanged();

  r = c.Post("/v1/drives", auth(), good.substr(0, good.size() / 2), "application/x-tar");
  EXPECT_EQ(r->status, 400) << r->body;
  unchanged();

  r = c.Post("/v1/drives", auth(), "", "application/x-tar");
  EXPECT_EQ(r->status, 400) << r->body;
  unchanged();

  r = c.Post("/v1/drives", auth(), good, "application/json");
  EXPECT_EQ(r->status, 415) << r->body;
  unchanged();

  // Parses, but violates the schema: 422 naming file and field.
  r = c.Post("/v1/drives", auth(), with_manifest_field(good, "pol_level", "quadruple"),
             "application/x-tar");
  EXPECT_EQ(r->status, 422) << r->body;
  const json e = body_json(r);
  EXPECT_EQ(e["field"], "pol_level") << r->body;
  EXPECT_EQ(e["file"], "manifest.json") << r->body;
  unchanged();

  // A data file that does not match its manifest hash.
  auto members = read_ustar(good);
  for (auto& m : members) {
    if (m.name == "candidates.gpkg") m.data[m.data.size() / 2] ^= 0x55;
  }
  r = c.Post("/v1/drives", auth(), write_ustar(members), "application/x-tar");
  EXPECT_TRUE(r->status == 422 || r->status == 400) << r->body;
  unchanged();
}

TEST_F(ServerTest, OversizedAndInterruptedUploads) {
  ServerConfig cfg;
  cfg.max_upload_bytes = 64 * 1024;
  restart(cfg);
  const std::string& good = scene_tar("scene_drive_1", 12);
  ASSERT_GT(good.size(), cfg.max_upload_bytes);

  // Announced too large: 413 before a byte of the body is read.
  std::string reply = raw_exchange(
      port_, "POST /v1/drives HTTP/1.1\r\nHost: t\r\nAuthorization: Bearer " + std::string(kKey) +
                 "\r\nContent-Type: application/x-tar\r\nContent-Length: 600000000\r\n\r\n");
  EXPECT_EQ(reply.substr(0, 12), "HTTP/1.1 413") << reply;
  EXPECT_NE(reply.find("upload limit"), std::string::npos);

  // Chunked (no length) beyond the limit: the server stops reading at the limit.
  {
    auto c = client();
    std::size_t sent = 0;
    auto r = c.Post(
        "/v1/drives", auth(),
        [&](std::size_t, httplib::DataSink& sink) {
          const std::size_t n = std::min<std::size_t>(16384, good.size() - sent);
          if (n == 0) {
            sink.done();
            return true;
          }
          sink.write(good.data() + sent, n);
          sent += n;
          return true;
        },
        "application/x-tar");
    if (r) {
      EXPECT_EQ(r->status, 413);  // the client may also see the connection reset
    }
  }
  EXPECT_TRUE(eventually([&] {
    for (const auto& l : log_lines()) {
      if (l.find("POST /v1/drives 413") != std::string::npos &&
          l.find("600000000") == std::string::npos) {
        return true;
      }
    }
    return false;
  }));

  // Interrupted: the client sends part of the body and disconnects.
  raw_exchange(port_,
               "POST /v1/drives HTTP/1.1\r\nHost: t\r\nAuthorization: Bearer " + std::string(kKey) +
                   "\r\nContent-Type: application/x-tar\r\nContent-Length: 60000\r\n\r\n" +
                   good.substr(0, 20000),
               false);
  EXPECT_TRUE(eventually([&] {
    for (const auto& l : log_lines()) {
      if (l.find("POST /v1/drives 400") != std::string::npos) return true;
    }
    return false;
  }));
  EXPECT_TRUE(eventually([&] { return upload_leftovers() == 0; }));
  EXPECT_EQ(store_->list_drives().size(), 0u);
  EXPECT_EQ(drive_store_entries(), 0u);
  // The server still works.
  EXPECT_EQ(client().Get("/health")->status, 200);
}

TEST_F(ServerTest, UploadBuildTileDecodeGivesBackTheLandmarks) {
  const std::int64_t version = upload_and_build();
  auto c = client();
  const auto frame = scene_frame();
  std::vector<GeoPoint> truth;
  for (const auto& p : true_points()) truth.push_back(frame.to_geo(p));

  std::vector<GeoPoint> served;
  std::size_t lines = 0;
  for (const tiles::TileKey& k : scene_tiles()) {
    auto r = c.Get(tile_path(k));
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200) << tiles::to_string(k) << " " << r->body;
    EXPECT_EQ(r->get_header_value("Content-Type"), "application/vnd.polmap.tile");
    EXPECT_EQ(r->get_header_value("X-Polmap-Map-Version"), std::to_string(version));
    EXPECT_EQ(r->get_header_value("Cache-Control"), "public, max-age=60, must-revalidate");
    const tiles::LocalizationTile t = tiles::decode_localization_tile(r->body, tile_path(k));
    EXPECT_EQ(t.key, k);
    const tiles::LocalFrame tf(tiles::tile_center(k));
    for (const auto& p : t.points) served.push_back(tf.to_geo(p.position_m));
    lines += t.lines.size();
    for (const auto& p : t.points) EXPECT_GE(p.support_drives, 2u);
  }
  // Every true landmark comes back within the drives' jitter (2 cm) + 5 mm quantization.
  ASSERT_EQ(served.size(), truth.size()) << "clutter seen by one drive must not become a landmark";
  for (const GeoPoint& g : truth) {
    double best = 1e9;
    for (const GeoPoint& s : served) {
      const Eigen::Vector2d d = frame.to_local(s) - frame.to_local(g);
      best = std::min(best, d.norm());
    }
    EXPECT_LT(best, 0.035);
  }
  EXPECT_GE(lines, 3u);

  // Explicit version: immutable caching.
  const tiles::TileKey k = *scene_tiles().begin();
  auto r = c.Get(tile_path(k) + "?version=" + std::to_string(version));
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("Cache-Control"), "public, max-age=31536000, immutable");
  const std::string etag = r->get_header_value("ETag");
  ASSERT_EQ(etag.size(), 66u) << etag;  // quoted SHA-256 hex
  EXPECT_EQ(etag.front(), '"');

  // If-None-Match -> 304 without a body; other tags -> 200.
  r = c.Get(tile_path(k), {{"If-None-Match", etag}});
  EXPECT_EQ(r->status, 304);
  EXPECT_TRUE(r->body.empty());
  EXPECT_EQ(r->get_header_value("ETag"), etag);
  r = c.Get(tile_path(k), {{"If-None-Match", "\"other\", W/" + etag}});
  EXPECT_EQ(r->status, 304);
  r = c.Get(tile_path(k), {{"If-None-Match", "\"other\""}});
  EXPECT_EQ(r->status, 200);

  // Far away: outside the map. Malformed: 400. Other zoom: 404. Unknown version: 404.
  const tiles::TileKey far = tiles::tile_at(48.0, 11.0, 16);
  r = c.Get(tile_path(far));
  EXPECT_EQ(r->status, 404);
  EXPECT_NE(body_json(r)["error"].get<std::string>().find("outside the coverage"),
            std::string::npos);
  for (const char* bad :
       {"/v1/tiles/16/abc/1", "/v1/tiles/16/70000/1", "/v1/tiles/-1/0/0", "/v1/tiles/16/1/1x"}) {
    EXPECT_EQ(c.Get(bad)->status, 400) << bad;
  }
  EXPECT_EQ(c.Get("/v1/tiles/15/0/0")->status, 404);
  EXPECT_EQ(c.Get(tile_path(k) + "?version=999")->status, 404);
  EXPECT_EQ(c.Get(tile_path(k) + "?version=abc")->status, 400);

  // A neighbour of the landmark tiles without landmarks: 204 (inside the map's coverage).
  std::optional<tiles::TileKey> empty_neighbour;
  for (int dy = -1; dy <= 1 && !empty_neighbour; ++dy) {
    for (int dx = -1; dx <= 1 && !empty_neighbour; ++dx) {
      const auto n = tiles::neighbour(k, dx, dy);
      if (n && !scene_tiles().count(*n)) {
        if (auto t = store_->get_tile(version, TileLayer::Localization, *n); !t)
          empty_neighbour = n;
      }
    }
  }
  ASSERT_TRUE(empty_neighbour);
  r = c.Get(tile_path(*empty_neighbour));
  EXPECT_EQ(r->status, 204);
  EXPECT_TRUE(r->body.empty());

  // Versions list and metrics reflect the build.
  r = c.Get("/v1/maps");
  EXPECT_EQ(body_json(r)["current"], version);
  EXPECT_EQ(c.Get("/v1/maps/current")->status, 200);
  EXPECT_EQ(c.Get("/v1/maps/77")->status, 404);
  r = c.Get("/metrics", auth());
  EXPECT_NE(r->body.find("polmap_current_map_version " + std::to_string(version)),
            std::string::npos);
  EXPECT_NE(r->body.find("polmap_tiles_served_total{kind=\"localization\",status=\"304\"} 2"),
            std::string::npos)
      << r->body;
  EXPECT_NE(r->body.find("polmap_map_builds_total{outcome=\"published\"} 1"), std::string::npos);
  EXPECT_NE(r->body.find("polmap_drives 3"), std::string::npos);
}

TEST_F(ServerTest, MapBuildRequestValidation) {
  auto c = client();
  EXPECT_EQ(c.Post("/v1/maps", auth(), "{not json", "application/json")->status, 400);
  EXPECT_EQ(c.Post("/v1/maps", auth(), "[1]", "application/json")->status, 400);
  auto r = c.Post("/v1/maps", auth(), R"({"exclude_drives": ["ghost"]})", "application/json");
  EXPECT_EQ(r->status, 422);
  EXPECT_EQ(body_json(r)["field"], "exclude_drives[0]");
  r = c.Post("/v1/maps", auth(), R"({"region": [10, 50, 9, 51]})", "application/json");
  EXPECT_EQ(r->status, 422);
  EXPECT_EQ(body_json(r)["field"], "region");
  r = c.Post("/v1/maps", auth(), R"({"regoin": {}})", "application/json");
  EXPECT_EQ(r->status, 422);
  EXPECT_EQ(body_json(r)["field"], "regoin");
  EXPECT_EQ(store_->list_map_versions().size(), 0u);
  // No map yet: tiles say so.
  r = c.Get("/v1/tiles/16/1/1");
  EXPECT_EQ(r->status, 404);
  EXPECT_NE(body_json(r)["error"].get<std::string>().find("no map version"), std::string::npos);
}

TEST_F(ServerTest, TheBuildQueueIsBounded) {
  ServerConfig cfg;
  cfg.max_queued_builds = 0;  // nothing may wait: every request is one too many
  restart(cfg);
  auto c = client();
  const auto r = c.Post("/v1/maps", auth(), "{}", "application/json");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 503);
  EXPECT_EQ(r->get_header_value("Retry-After"), "60");
  EXPECT_TRUE(store_->list_map_versions().empty());  // refused before a version row exists
  cfg.max_queued_builds = 1;
  restart(cfg);
  auto c2 = client();
  EXPECT_EQ(c2.Post("/v1/maps", auth(), "{}", "application/json")->status, 202);
}

TEST_F(ServerTest, ConcurrentExportsAreBounded) {
  ServerConfig cfg;
  cfg.max_concurrent_exports = 0;  // every export is one too many (one: ExportStreamsGisFiles)
  restart(cfg);
  (void)upload_and_build();
  auto c = client();
  const auto r = c.Get("/v1/export?format=geojson", auth());
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 503) << r->body;
  EXPECT_EQ(r->get_header_value("Retry-After"), "30");
}

TEST_F(ServerTest, VectorTilesTileJsonAndGridmap) {
  const std::int64_t version = upload_and_build();
  auto c = client();
  const tiles::TileKey k16 = *scene_tiles().begin();
  const tiles::TileKey k18{18, k16.x * 4 + 1, k16.y * 4 + 1};
  // The z18 tile containing the first true landmark.
  const GeoPoint g = scene_frame().to_geo(true_points()[5]);
  const tiles::TileKey k = tiles::tile_at(g.lat_deg, g.lon_deg, 18);
  (void)k18;

  // Public: landmarks only. With a key that may read drives: their trajectories too.
  auto r = c.Get("/v1/mvt/" + tiles::to_string(k) + ".mvt");
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(r->get_header_value("Cache-Control"), "public, max-age=60");
  const std::string public_mvt = r->body;
  r = c.Get("/v1/mvt/" + tiles::to_string(k) + ".mvt", auth());
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(r->get_header_value("Cache-Control"), "private, max-age=60");
  EXPECT_EQ(r->get_header_value("Content-Type"), "application/vnd.mapbox-vector-tile");
  EXPECT_EQ(r->get_header_value("Vary"), "Accept-Encoding");
  const std::string mvt = r->body;
  const std::string etag = r->get_header_value("ETag");

  r = c.Get("/v1/mvt/" + tiles::to_string(k) + ".mvt",
            {{"Accept-Encoding", "gzip"}, {"Authorization", std::string("Bearer ") + kKey}});
  // httplib's client inflates transparently only when asked; check the header and the bytes.
  EXPECT_EQ(r->get_header_value("Content-Encoding"), "gzip");
  EXPECT_NE(r->get_header_value("ETag"), etag);
  r = c.Get("/v1/mvt/" + tiles::to_string(k) + ".mvt",
            {{"If-None-Match", etag}, {"Authorization", std::string("Bearer ") + kKey}});
  EXPECT_EQ(r->status, 304);
  EXPECT_EQ(c.Get("/v1/mvt/5/1/1.mvt")->status, 404);  // below minzoom
  EXPECT_EQ(c.Get("/v1/mvt/18/1/x.mvt")->status, 400);

  // GDAL reads the served tile (written as {z}/{x}/{y}.pbf so it georeferences it).
  const auto tile_dir = dir_ / "mvt" / std::to_string(k.z) / std::to_string(k.x);
  std::filesystem::create_directories(tile_dir);
  const auto tile_file = tile_dir / (std::to_string(k.y) + ".pbf");
  std::ofstream(tile_file, std::ios::binary) << mvt;
  GDALAllRegister();
  const char* drivers[] = {"MVT", nullptr};
  GDALDatasetUniquePtr ds(
      GDALDataset::Open(tile_file.c_str(), GDAL_OF_VECTOR, drivers, nullptr, nullptr));
  ASSERT_TRUE(ds) << tile_file;
  std::set<std::string> names;
  for (int i = 0; i < ds->GetLayerCount(); ++i) names.insert(ds->GetLayer(i)->GetName());
  EXPECT_TRUE(names.count("points") && names.count("lines") && names.count("trajectories"));
  EXPECT_GE(ds->GetLayerByName("points")->GetFeatureCount(), 1);
  ds.reset();
  std::ofstream(tile_file, std::ios::binary | std::ios::trunc) << public_mvt;
  ds.reset(GDALDataset::Open(tile_file.c_str(), GDAL_OF_VECTOR, drivers, nullptr, nullptr));
  ASSERT_TRUE(ds);
  names.clear();
  for (int i = 0; i < ds->GetLayerCount(); ++i) names.insert(ds->GetLayer(i)->GetName());
  EXPECT_TRUE(names.count("points") && !names.count("trajectories"));
  ds.reset();

  // TileJSON 3.0.
  r = c.Get("/v1/tilejson.json?version=" + std::to_string(version));
  ASSERT_EQ(r->status, 200);
  const json tj = body_json(r);
  EXPECT_EQ(tj["tilejson"], "3.0.0");
  EXPECT_EQ(tj["tiles"][0], "http://127.0.0.1:" + std::to_string(port_) +
                                "/v1/mvt/{z}/{x}/{y}.mvt?version=" + std::to_string(version));
  EXPECT_EQ(tj["vector_layers"].size(), 3u);
  const auto& b = tj["bounds"];
  EXPECT_LE(b[0].get<double>(), g.lon_deg);
  EXPECT_GE(b[2].get<double>(), g.lon_deg);
  EXPECT_LE(b[1].get<double>(), g.lat_deg);
  EXPECT_GE(b[3].get<double>(), g.lat_deg);

  // Gridmap PNG at the base zoom and over-zoomed.
  const auto gridmap_tiles = store_->list_tiles(version, TileLayer::Gridmap);
  ASSERT_FALSE(gridmap_tiles.empty());
  int base_zoom = 0;
  for (const auto& t : gridmap_tiles) base_zoom = std::max(base_zoom, t.key.z);
  tiles::TileKey gk{};
  for (const auto& t : gridmap_tiles) {
    if (t.key.z == base_zoom) gk = t.key;
  }
  r = c.Get("/v1/gridmap/" + tiles::to_string(gk) + ".png");
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(r->get_header_value("Content-Type"), "image/png");
  EXPECT_EQ(r->body.substr(1, 3), "PNG");
  r = c.Get("/v1/gridmap/" + tiles::to_string(tiles::children(gk)[3]) + ".png");
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(r->body.substr(1, 3), "PNG");
  EXPECT_EQ(c.Get("/v1/gridmap/" + tiles::to_string(tiles::tile_at(-40, 100, base_zoom)) + ".png")
                ->status,
            204);
  // The scattering-mechanism layer beside it: the same tiles, its own ETags where the
  // drives carry mechanism information (the scene is fully polarimetric).
  const auto mech_tiles = store_->list_tiles(version, TileLayer::GridmapMechanism);
  ASSERT_EQ(mech_tiles.size(), gridmap_tiles.size());
  for (std::size_t i = 0; i < mech_tiles.size(); ++i)
    EXPECT_EQ(mech_tiles[i].key, gridmap_tiles[i].key);
  r = c.Get("/v1/gridmap/mechanism/" + tiles::to_string(gk) + ".png");
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(r->get_header_value("Content-Type"), "image/png");
  EXPECT_EQ(r->body.substr(1, 3), "PNG");
  EXPECT_NE(r->get_header_value("ETag"),
            c.Get("/v1/gridmap/" + tiles::to_string(gk) + ".png")->get_header_value("ETag"));
  EXPECT_EQ(
      c.Get("/v1/gridmap/mechanism/" + tiles::to_string(tiles::children(gk)[0]) + ".png")->status,
      200);
  EXPECT_EQ(c.Get("/v1/gridmap/mechanism/x/0/0.png")->status, 400);
  EXPECT_EQ(tj["polmap"]["gridmap_mechanism_tiles"],
            "http://127.0.0.1:" + std::to_string(port_) +
                "/v1/gridmap/mechanism/{z}/{x}/{y}.png?version=" + std::to_string(version));
}

TEST_F(ServerTest, ExportStreamsGisFiles) {
  const std::int64_t version = upload_and_build();
  auto c = client();
  auto r = c.Get("/v1/export?format=geojson", auth());
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(r->get_header_value("Content-Type"), "application/geo+json");
  EXPECT_EQ(r->get_header_value("Content-Disposition"),
            "attachment; filename=\"polmap-map-v" + std::to_string(version) + ".geojson\"");
  const json fc = json::parse(r->body);
  EXPECT_EQ(fc["type"], "FeatureCollection");
  std::size_t points = 0;
  for (const auto& f : fc["features"]) points += f["geometry"]["type"] == "Point";
  EXPECT_EQ(points, true_points().size());

  r = c.Get("/v1/export?format=gpkg&version=" + std::to_string(version), auth());
  ASSERT_EQ(r->status, 200);
  const auto gpkg = dir_ / "export.gpkg";
  std::ofstream(gpkg, std::ios::binary) << r->body;
  GDALAllRegister();
  GDALDatasetUniquePtr ds(
      GDALDataset::Open(gpkg.c_str(), GDAL_OF_VECTOR, nullptr, nullptr, nullptr));
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetLayerByName("points")->GetFeatureCount(),
            static_cast<GIntBig>(true_points().size()));
  ds.reset();

  r = c.Get("/v1/export?format=shp", auth());
  ASSERT_EQ(r->status, 200);
  EXPECT_EQ(r->body.substr(0, 2), "PK");  // zip

  // A bbox far away: a valid, empty file. Bad arguments: 400.
  r = c.Get("/v1/export?format=geojson&bbox=10,47,10.01,47.01", auth());
  ASSERT_EQ(r->status, 200);
  EXPECT_TRUE(json::parse(r->body)["features"].empty());
  EXPECT_EQ(c.Get("/v1/export?format=pdf", auth())->status, 400);
  EXPECT_EQ(c.Get("/v1/export?format=gpkg&bbox=1,2,3", auth())->status, 400);
  EXPECT_EQ(c.Get("/v1/export?format=gpkg&version=42", auth())->status, 404);
  // Temp files are gone once the responses are done.
  EXPECT_TRUE(eventually([&] { return upload_leftovers() == 0; }));
}

TEST(ApiKeyFile, CommentsBlankLinesAndWhitespace) {
  const util::ScopedTempDir dir(polmap::test::unique_test_dir("keys"));
  const auto f = dir.path() / "keys";
  std::ofstream(f) << "# fleet keys\n\n  key-one  \n#disabled\nkey-two\r\n\t\n"
                      "vehicle  key-v   veh-7\nviewer key-w\noperator\tkey-o\n";
  const auto keys = read_api_key_file(f);
  ASSERT_EQ(keys.size(), 5U);
  EXPECT_EQ(keys[0].key, "key-one");
  EXPECT_EQ(keys[0].role, KeyRole::Operator);  // a bare key: operator, as before roles
  EXPECT_EQ(keys[1].key, "key-two");
  EXPECT_EQ(keys[2].key, "key-v");
  EXPECT_EQ(keys[2].role, KeyRole::Vehicle);
  EXPECT_EQ(keys[2].vehicle_id, "veh-7");
  EXPECT_EQ(keys[3].role, KeyRole::Viewer);
  EXPECT_EQ(keys[4].key, "key-o");
  EXPECT_EQ(keys[4].role, KeyRole::Operator);
  for (const char* bad : {"root key-x\n", "viewer key-x veh-1\n", "vehicle a b c\n"}) {
    std::ofstream(f) << bad;
    try {
      (void)read_api_key_file(f);
      ADD_FAILURE() << bad;
    } catch (const ValidationError& e) {
      EXPECT_NE(std::string(e.what()).find(":1"), std::string::npos) << e.what();  // names the line
    }
  }
  std::ofstream(f) << "# nothing here\n\n";
  EXPECT_THROW((void)read_api_key_file(f), ValidationError);
  std::filesystem::remove(f);
  EXPECT_THROW((void)read_api_key_file(f), IoError);
}

TEST_F(ServerTest, StopIsGracefulAndIdempotent) {
  auto c = client();
  EXPECT_EQ(c.Get("/health")->status, 200);
  server_->stop();
  thread_.join();
  server_->stop();
  auto r = client().Get("/health");
  EXPECT_FALSE(r);  // connection refused
  bool stopped = false;
  for (const auto& l : log_lines()) stopped |= l.find(" info stopped") != std::string::npos;
  EXPECT_TRUE(stopped);
}

}  // namespace
}  // namespace polmap::mapping::testing
