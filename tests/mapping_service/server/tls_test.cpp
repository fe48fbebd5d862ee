// The embedded server's TLS option (ServerConfig::tls_cert_file, `polmap serve --tls-cert`)
// with throw-away self-signed certificates made at test time: the TileFetcher fetches
// tiles over https with the CA file, refuses a server it cannot verify, and the server
// refuses to start with a certificate or key it cannot use.
#include "mapping_service/server/net_helpers.hpp"
#include "mapping_service/server_fixture.hpp"
#include "polmap/localization_client/tile_fetcher.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::mapping::testing {
namespace {

class TlsServerTest : public ServerFixture {
 protected:
  void SetUp() override {
    certs_ = std::make_unique<polmap::test::TestDir>("tls");
    cert_ = make_self_signed_cert(certs_->path(), "localhost", "DNS:localhost,IP:127.0.0.1");
    start(tls_config(cert_));
  }
  void TearDown() override {
    ServerFixture::TearDown();
    certs_.reset();
  }
  static ServerConfig tls_config(const SelfSignedCert& c) {
    ServerConfig cfg;
    cfg.tls_cert_file = c.cert;
    cfg.tls_key_file = c.key;
    return cfg;
  }
  /// An https client that trusts `ca` (and verifies the certificate and host name).
  [[nodiscard]] httplib::Client tls_client(const std::filesystem::path& ca) const {
    httplib::Client c("https://127.0.0.1:" + std::to_string(port_));
    c.set_ca_cert_path(ca.string());
    c.enable_server_certificate_verification(true);
    c.set_read_timeout(120, 0);
    c.set_write_timeout(120, 0);
    return c;
  }
  /// Uploads the scene drives over https and builds a map; returns a tile with landmarks.
  tiles::TileKey upload_and_build() {
    auto c = tls_client(cert_.cert);
    for (int i = 0; i < 3; ++i) {
      const std::string id = "scene_drive_" + std::to_string(i);
      auto r = c.Post("/v1/drives", auth(), scene_tar(id, 11 + i), "application/x-tar");
      EXPECT_TRUE(r) << httplib::to_string(r.error());
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
    return tiles::tile_at(g.lat_deg, g.lon_deg, tiles::kLocalizationZoom);
  }
  loc::TileFetcherConfig fetcher_config(const std::string& host) const {
    loc::TileFetcherConfig f;
    f.server_url = "https://" + host + ":" + std::to_string(port_);
    f.connect_timeout_s = 2.0;
    f.backoff_initial_s = 0.05;
    return f;
  }

  std::unique_ptr<polmap::test::TestDir> certs_;
  SelfSignedCert cert_;
};

TEST_F(TlsServerTest, TheTileFetcherFetchesOverHttpsWithTheCaFile) {
  const tiles::TileKey key = upload_and_build();
  const std::vector<tiles::TileKey> keys{key};
  for (const char* host : {"127.0.0.1", "localhost"}) {  // IP and DNS names of the certificate
    loc::TileFetcherConfig f = fetcher_config(host);
    f.ca_file = cert_.cert;
    loc::TileFetcher fetcher(f);
    fetcher.prefetch(keys);
    ASSERT_TRUE(fetcher.wait_for(keys, 10.0)) << host;
    const auto tile = fetcher.tile(key);
    ASSERT_TRUE(tile);
    EXPECT_FALSE(tile->points.empty());
    const loc::TileFetcherStats s = fetcher.stats();
    EXPECT_EQ(s.responses_200, 1u);
    EXPECT_EQ(s.transport_errors, 0u);
    EXPECT_GE(s.map_version, 1u);
  }
  // The server log says https.
  bool https = false;
  for (const auto& l : log_lines())
    https |= l.find("listening on https://127.0.0.1:") != std::string::npos;
  EXPECT_TRUE(https);
}

TEST_F(TlsServerTest, AServerThatCannotBeVerifiedIsRefused) {
  const tiles::TileKey key = upload_and_build();
  const std::vector<tiles::TileKey> keys{key};
  auto refused = [&](loc::TileFetcherConfig f) {
    loc::TileFetcher fetcher(f);
    fetcher.prefetch(keys);
    EXPECT_FALSE(fetcher.wait_for(keys, 1.5));
    EXPECT_FALSE(fetcher.tile(key));
    const loc::TileFetcherStats s = fetcher.stats();
    EXPECT_EQ(s.responses_200, 0u);
    EXPECT_GE(s.transport_errors, 1u);
    EXPECT_FALSE(s.server_reachable);
  };
  // No CA file: the system's CA store does not know the self-signed certificate.
  refused(fetcher_config("127.0.0.1"));
  // Another CA.
  const SelfSignedCert other = make_self_signed_cert(certs_->path(), "other", "DNS:localhost");
  loc::TileFetcherConfig f = fetcher_config("127.0.0.1");
  f.ca_file = other.cert;
  refused(f);
  // A CA file that does not exist.
  f.ca_file = certs_->path() / "missing.crt";
  refused(f);
  // Plain HTTP to the TLS port gets nothing.
  auto plain = client().Get("/health");
  EXPECT_FALSE(plain && plain->status == 200);

  // The right CA but a certificate for another host name.
  const SelfSignedCert wrong_name =
      make_self_signed_cert(certs_->path(), "elsewhere", "DNS:elsewhere.example");
  restart(tls_config(wrong_name));
  f = fetcher_config("127.0.0.1");
  f.ca_file = wrong_name.cert;
  refused(f);
  auto r = tls_client(wrong_name.cert).Get("/health");
  EXPECT_FALSE(r);
}

/// Server constructor with `cfg` on a fresh store; the error it throws (empty: none).
template <class E>
std::string start_error(const ServerConfig& cfg, const std::filesystem::path& dir) {
  SqliteMapStore store(dir / "map.db");
  try {
    Server server(store, cfg);
  } catch (const E& e) {
    return e.what();
  }
  return {};
}

TEST(ServerTls, RefusesToStartWithoutAUsableCertificateAndKey) {
  const polmap::test::TestDir dir("tls-start");
  const SelfSignedCert a = make_self_signed_cert(dir.path(), "a", "DNS:localhost");
  const SelfSignedCert b = make_self_signed_cert(dir.path(), "b", "DNS:localhost");
  ServerConfig cfg;
  cfg.log_requests = false;
  cfg.upload_dir = dir.path();

  cfg.tls_cert_file = a.cert;
  cfg.tls_key_file = a.key;
  EXPECT_EQ(start_error<Error>(cfg, dir.path()), "");  // the good pair starts

  cfg.tls_key_file = b.key;  // another certificate's key
  std::string e = start_error<ValidationError>(cfg, dir.path());
  EXPECT_NE(e.find(b.key.string()), std::string::npos) << e;
  EXPECT_NE(e.find("does not match the certificate " + a.cert.string()), std::string::npos) << e;

  cfg.tls_key_file = dir.path() / "missing.key";
  e = start_error<IoError>(cfg, dir.path());
  EXPECT_NE(e.find("cannot read TLS private key " + cfg.tls_key_file.string()), std::string::npos)
      << e;
  cfg.tls_key_file = dir.path();  // a directory
  e = start_error<IoError>(cfg, dir.path());
  EXPECT_NE(e.find("is a directory"), std::string::npos) << e;

  cfg.tls_key_file = a.key;
  cfg.tls_cert_file = dir.path() / "missing.crt";
  e = start_error<IoError>(cfg, dir.path());
  EXPECT_NE(e.find("cannot read TLS certificate"), std::string::npos) << e;

  cfg.tls_cert_file = a.key;  // a key where the certificate belongs
  e = start_error<ValidationError>(cfg, dir.path());
  EXPECT_NE(e.find("is not a PEM certificate chain"), std::string::npos) << e;

  cfg.tls_cert_file = a.cert;  // a certificate where the key belongs
  cfg.tls_key_file = b.cert;
  e = start_error<ValidationError>(cfg, dir.path());
  EXPECT_NE(e.find("TLS private key " + b.cert.string() + " is not an unencrypted PEM"),
            std::string::npos)
      << e;

  cfg.tls_key_file.clear();  // only one of the two
  e = start_error<ValidationError>(cfg, dir.path());
  EXPECT_NE(e.find("both a certificate and a private key"), std::string::npos) << e;

  // An encrypted key fails (no pass phrase prompt on the terminal).
  const auto encrypted = dir.path() / "encrypted.key";
  ASSERT_EQ(run_process({"openssl", "pkey", "-in", a.key.string(), "-aes256", "-passout",
                         "pass:secret", "-out", encrypted.string()},
                        dir.path() / "openssl.log"),
            0);
  cfg.tls_key_file = encrypted;
  e = start_error<ValidationError>(cfg, dir.path());
  EXPECT_NE(e.find("TLS private key " + encrypted.string() + " is not an unencrypted PEM"),
            std::string::npos)
      << e;
}

}  // namespace
}  // namespace polmap::mapping::testing
