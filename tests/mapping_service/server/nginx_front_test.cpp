// The nginx front of deploy/nginx/ (docs/deployment.md) before a real mapping server on
// loopback: the shipped template rendered by the shipped script, run by the real nginx
// (tools/setup installs it) from a temporary prefix, as whatever user runs the test.
// Checks what the front is for: uploads and tiles pass, bodies above the caps stop at
// nginx, slow-loris sockets that stop the embedded server do not stop the front, a
// multi-range request cannot fan out, and API keys never reach the access log.
#include <csignal>
#include <nlohmann/json.hpp>

#include "mapping_service/server/net_helpers.hpp"
#include "mapping_service/server_fixture.hpp"
#include "polmap/tiles/tile_key.hpp"
// After the headers that use Eigen (httplib's <resolv.h> defines `_res`).
#include "support/nginx_process.hpp"

namespace polmap::mapping::testing {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;

/// polmap's upload cap in these tests, and the front's client_max_body_size.
constexpr int kUploadCapMiB = 4;

/// deploy/nginx/render of the front before polmap at `upstream_port` into `prefix`, plus
/// `options`.
std::function<std::vector<std::string>(int)> render_front(const std::filesystem::path& prefix,
                                                          int upstream_port,
                                                          std::vector<std::string> options = {}) {
  return [prefix, upstream_port, options](int port) {
    std::vector<std::string> render = {
        std::string(POLMAP_SOURCE_DIR) + "/deploy/nginx/render",
        "--prefix",
        prefix.string(),
        "--listen",
        "127.0.0.1:" + std::to_string(port),
        "--upstream",
        "127.0.0.1:" + std::to_string(upstream_port),
        "--max-upload-mib",
        std::to_string(kUploadCapMiB),
        "--polmap-threads",
        "8",
    };
    render.insert(render.end(), options.begin(), options.end());
    return render;
  };
}

class NginxFrontTest : public ServerFixture {
 protected:
  void SetUp() override {
    ServerConfig cfg;
    cfg.max_upload_bytes = static_cast<std::uint64_t>(kUploadCapMiB) << 20;
    start(cfg);  // 8 worker threads (ServerFixture)
    base_ = std::make_unique<polmap::test::TestDir>("nginx");
    nginx_ = std::make_unique<Nginx>(base_->path() / "prefix",
                                     render_front(base_->path() / "prefix", port_));
    ASSERT_TRUE(nginx_->running());
  }
  void TearDown() override {
    nginx_.reset();
    ServerFixture::TearDown();
    base_.reset();
  }

  /// Uploads the three scene drives with `c` and builds a map; returns the first tile's path.
  std::string upload_and_build(httplib::Client& c) {
    for (int i = 0; i < 3; ++i) {
      const std::string id = "scene_drive_" + std::to_string(i);
      auto r = c.Post("/v1/drives", auth(), scene_tar(id, 11 + i), "application/x-tar");
      EXPECT_TRUE(r);
      if (r) {
        EXPECT_EQ(r->status, 201) << r->body;
      }
    }
    auto r = c.Post("/v1/maps", auth(), "{}", "application/json");
    EXPECT_TRUE(r);
    if (r) {
      EXPECT_EQ(r->status, 202) << r->body;
    }
    server_->wait_for_builds();
    const GeoPoint g = scene_frame().to_geo(true_points()[5]);
    return "/v1/tiles/" +
           tiles::to_string(tiles::tile_at(g.lat_deg, g.lon_deg, tiles::kLocalizationZoom));
  }

  /// Lines of polmap's own log that record `needle` (method and path).
  std::size_t polmap_log_count(const std::string& needle) {
    std::size_t n = 0;
    for (const auto& l : log_lines()) n += l.find(needle) != std::string::npos;
    return n;
  }

  std::unique_ptr<polmap::test::TestDir> base_;
  std::unique_ptr<Nginx> nginx_;
};

/// GET `path` on 127.0.0.1:port with every timeout at `timeout_s`; the status (0: no
/// answer in time) and how long it took.
std::pair<int, double> timed_get(int port, const std::string& path, int timeout_s) {
  httplib::Client c("127.0.0.1", port);
  c.set_connection_timeout(timeout_s, 0);
  c.set_read_timeout(timeout_s, 0);
  c.set_write_timeout(timeout_s, 0);
  const auto t0 = Clock::now();
  auto r = c.Get(path);
  const double s = std::chrono::duration<double>(Clock::now() - t0).count();
  return {r ? r->status : 0, s};
}

TEST_F(NginxFrontTest, UploadsTilesCapsRangesAndLogsThroughTheFront) {
  auto c = nginx_->client();
  // Uploads and the build go through the front; the key is forwarded (and required).
  auto r = c.Post("/v1/drives", scene_tar("scene_drive_0", 11), "application/x-tar");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 401) << r->body;  // polmap's answer, through nginx
  const std::string tile = upload_and_build(c);

  auto direct = client();
  auto d = direct.Get(tile);
  ASSERT_TRUE(d);
  ASSERT_EQ(d->status, 200) << d->body;
  r = c.Get(tile);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->body, d->body);
  EXPECT_EQ(r->get_header_value("ETag"), d->get_header_value("ETag"));
  r = c.Get(tile, {{"If-None-Match", d->get_header_value("ETag")}});
  EXPECT_EQ(r->status, 304);

  // MVT: polmap's gzip passes through unchanged (nginx neither inflates nor recompresses).
  const GeoPoint g = scene_frame().to_geo(true_points()[5]);
  const std::string mvt =
      "/v1/mvt/" + tiles::to_string(tiles::tile_at(g.lat_deg, g.lon_deg, 18)) + ".mvt";
  direct.set_decompress(false);
  c.set_decompress(false);
  d = direct.Get(mvt, {{"Accept-Encoding", "gzip"}});
  r = c.Get(mvt, {{"Accept-Encoding", "gzip"}});
  ASSERT_TRUE(d && r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("Content-Encoding"), "gzip");
  EXPECT_EQ(r->get_header_value("Vary"), "Accept-Encoding");
  EXPECT_EQ(r->body, d->body);
  c.set_decompress(true);

  // One range is served; hundreds in one request get the whole body once, not hundreds
  // of parts (max_ranges 1).
  const std::string full = direct.Get(tile)->body;
  ASSERT_GT(full.size(), 4u);
  r = c.Get(tile, {{"Range", "bytes=1-3"}});
  EXPECT_EQ(r->status, 206);
  EXPECT_EQ(r->body, full.substr(1, 3));
  // Disjoint one-byte ranges (overlapping ones, or more bytes than the body, nginx
  // refuses on its own): two, and as many as the body allows (up to 400).
  std::string ranges = "bytes=0-0,2-2";
  r = c.Get(tile, {{"Range", ranges}});
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->body, full);
  for (std::size_t i = 2; i < std::min<std::size_t>(400, full.size() / 2); ++i) {
    ranges += ",";
    ranges += std::to_string(2 * i);
    ranges += "-";
    ranges += std::to_string(2 * i);
  }
  r = c.Get(tile, {{"Range", ranges}});
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(r->body, full);
  EXPECT_EQ(r->get_header_value("Content-Type").find("multipart"), std::string::npos);

  // A body below the upload cap reaches polmap (which refuses it as no package) ...
  std::size_t uploads_seen = polmap_log_count("POST /v1/drives");
  r = c.Post("/v1/drives", auth(), std::string((kUploadCapMiB - 1) << 20, 'x'),
             "application/x-tar");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 400) << r->body;
  EXPECT_EQ(json::parse(r->body)["file"], "archive") << r->body;  // polmap's JSON error
  // (polmap logs a request after its response has gone out)
  for (int i = 0; i < 500 && polmap_log_count("POST /v1/drives") == uploads_seen; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_EQ(polmap_log_count("POST /v1/drives"), uploads_seen + 1);
  // ... bodies above the caps are refused by nginx; polmap never sees those requests.
  uploads_seen = polmap_log_count("POST /v1/drives");
  const std::size_t builds_seen = polmap_log_count("POST /v1/maps");
  r = c.Post("/v1/drives", auth(), std::string((kUploadCapMiB << 20) + 1, 'x'),
             "application/x-tar");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 413);
  {  // chunked, with a first chunk beyond the cap: refused on its size line
    const std::string head =
        "POST /v1/drives HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer " +
        std::string(kKey) +
        "\r\nTransfer-Encoding: chunked\r\nContent-Type: application/x-tar"
        "\r\n\r\n500001\r\nustar";
    const int fd = connect_loopback(nginx_->port());
    ASSERT_GE(fd, 0);
    ASSERT_EQ(::send(fd, head.data(), head.size(), MSG_NOSIGNAL),
              static_cast<ssize_t>(head.size()));
    timeval tv{10, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    char buf[512] = {};
    const ssize_t n = ::recv(fd, buf, sizeof buf - 1, 0);
    ::close(fd);
    ASSERT_GT(n, 0);
    EXPECT_EQ(std::string(buf).rfind("HTTP/1.1 413", 0), 0u) << buf;
  }
  r = c.Post("/v1/maps", auth(), std::string((1u << 20) + 1, ' '), "application/json");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 413);
  EXPECT_EQ(polmap_log_count("POST /v1/drives"), uploads_seen);
  EXPECT_EQ(polmap_log_count("POST /v1/maps"), builds_seen);

  // The access log records the requests but never a key.
  r = c.Get("/v1/drives", auth());
  EXPECT_EQ(r->status, 200);
  // nginx writes a request's line after the response has gone out: wait for the last one.
  std::string access;
  const auto until = Clock::now() + std::chrono::seconds(10);
  do {
    access = nginx_->access_log();
    if (access.find("\"GET /v1/drives HTTP/1.1\" 200") != std::string::npos) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  } while (Clock::now() < until);
  EXPECT_NE(access.find("\"POST /v1/drives HTTP/1.1\" 201"), std::string::npos) << access;
  EXPECT_NE(access.find("\"GET /v1/drives HTTP/1.1\" 200"), std::string::npos) << access;
  EXPECT_NE(access.find("\"POST /v1/drives HTTP/1.1\" 413"), std::string::npos) << access;
  EXPECT_EQ(access.find(kKey), std::string::npos);
  EXPECT_EQ(access.find("Bearer"), std::string::npos);
  EXPECT_EQ(read_text(nginx_->error_log()).find(kKey), std::string::npos);
}

TEST_F(NginxFrontTest, SlowLorisSocketsStopTheEmbeddedServerButNotTheFront) {
  auto direct = client();
  const std::string tile = upload_and_build(direct);
  ASSERT_EQ(timed_get(port_, tile, 2).first, 200);
  constexpr int kSlow = 64;  // 8 times the server's worker threads
  {
    // Control: the attack works. The embedded server gives every connection a worker
    // thread; slow sockets hold all 8 and a tile request gets no answer (docs/deployment.md).
    SlowLoris slow(port_, kSlow);
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    EXPECT_EQ(timed_get(port_, tile, 2).first, 0) << "the embedded server held off 64 slow "
                                                     "sockets: update docs/deployment.md";
  }
  // Closed again: the workers are free.
  EXPECT_EQ(timed_get(port_, tile, 5).first, 200);

  // Through the front, for longer than its client_header_timeout (10 s): every tile
  // request is answered in under 2 s while nginx drops and the attacker reopens sockets.
  SlowLoris slow(nginx_->port(), kSlow);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  EXPECT_EQ(slow.open(), kSlow);
  const auto until = Clock::now() + std::chrono::seconds(13);
  int probes = 0;
  double slowest_s = 0.0;
  while (Clock::now() < until) {
    const auto [status, seconds] = timed_get(nginx_->port(), tile, 2);
    ++probes;
    EXPECT_EQ(status, 200) << "probe " << probes;
    EXPECT_LT(seconds, 2.0);
    slowest_s = std::max(slowest_s, seconds);
    std::this_thread::sleep_for(std::chrono::milliseconds(250));
  }
  // nginx cut the slow headers off (408 after client_header_timeout) and they came back.
  EXPECT_GE(slow.reopened(), kSlow);
  std::printf("front: %d probes under %d slow sockets, slowest %.3f s, %d sockets reopened\n",
              probes, kSlow, slowest_s, slow.reopened());
}

TEST_F(NginxFrontTest, TerminatesTls) {
  const SelfSignedCert cert =
      make_self_signed_cert(base_->path(), "localhost", "DNS:localhost,IP:127.0.0.1");
  Nginx tls(base_->path() / "tls-prefix",
            render_front(base_->path() / "tls-prefix", port_,
                         {"--tls-cert", cert.cert.string(), "--tls-key", cert.key.string()}));
  ASSERT_TRUE(tls.running());
  httplib::SSLClient c("127.0.0.1", tls.port());
  c.set_ca_cert_path(cert.cert.string());
  c.enable_server_certificate_verification(true);
  auto r = c.Get("/health");
  ASSERT_TRUE(r) << httplib::to_string(r.error());
  EXPECT_EQ(r->status, 200);
  EXPECT_EQ(json::parse(r->body)["status"], "ok");
  EXPECT_EQ(r->get_header_value("Strict-Transport-Security"), "max-age=31536000");
  // Plain HTTP on the TLS port is not served.
  auto p = httplib::Client("127.0.0.1", tls.port()).Get("/health");
  EXPECT_TRUE(!p || p->status == 400);
}

}  // namespace
}  // namespace polmap::mapping::testing
