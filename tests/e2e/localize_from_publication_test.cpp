// End to end (issue 13): simulated drives -> a map built in a SQLite store -> `polmap
// publish` as a signed static tile set -> the shipped nginx configuration serving it on
// loopback under a path -> loc::TileFetcher in publication mode + loc::Localizer on the
// held-out drive, within the same bounds as through the server. A CDN or mirror cannot
// alter the map: a wrong key, a replaced manifest and an altered tile are all refused.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <string>

#include "e2e/e2e_drive_set.hpp"
#include "polmap/eval/study.hpp"
#include "polmap/localization_client/tile_fetcher.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/mapping_service/publish.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/sim/world.hpp"
#include "polmap/tiles/publication_manifest.hpp"
#include "polmap/util/ed25519.hpp"
#include "polmap/util/file.hpp"
#include "test_dir.hpp"
// After the headers that use Eigen (httplib's <resolv.h> defines `_res`).
#include "support/nginx_process.hpp"

namespace polmap {
namespace {
namespace fs = std::filesystem;
using mapping::testing::Nginx;

using namespace e2e;  // NOLINT: the shared drive set and bounds

class LocalizeFromPublication : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = polmap::test::unique_test_dir("e2e-publication");
    sim_cfg_.seed = kSeed;
    world_ = sim::load_world("urban", kRouteLength_m, kSeed, sim_cfg_);
    study_cfg_.landmarks_only = true;
    mapping::SqliteMapStore store(dir_ / "map.sqlite");
    for (int k = 0; k < kDrives; ++k) {
      if (k == kHeldOut) continue;
      const auto pkg = eval::simulate_and_package(world_, sim_cfg_, k, PolLevel::Full, study_cfg_,
                                                  dir_ / ("pkg_" + std::to_string(k)));
      const mapping::DrivePackage p = mapping::read_and_validate_package(pkg.dir);
      ASSERT_EQ(store.put_drive(p, pkg.dir, p.content_sha256).status,
                mapping::PutDriveResult::Status::Inserted);
    }
    mapping::MapBuildRequest req;
    req.build_gridmap = false;
    const auto built = mapping::MapBuilder{}.build(store, req);
    ASSERT_EQ(built.status, mapping::MapBuildResult::Status::Published) << built.error;
    version_ = built.version;
    key_ = util::ed25519_generate();
    util::write_file_bytes(dir_ / "publisher.pub", key_.public_pem);
    mapping::PublishOptions po;
    po.out = dir_ / "pub";
    po.private_key_pem = key_.private_pem;
    published_ = mapping::publish_map_version(store, version_, po);
    nginx_ = std::make_unique<Nginx>(dir_ / "nginx", [](int port) {
      return std::vector<std::string>{
          std::string(POLMAP_SOURCE_DIR) + "/deploy/nginx/render-publication",
          "--prefix",
          (dir_ / "nginx").string(),
          "--listen",
          "127.0.0.1:" + std::to_string(port),
          "--root",
          (dir_ / "pub").string(),
          "--location",
          "/polmap",
          "--workers",
          "1"};
    });
    ASSERT_TRUE(nginx_->running());
  }

  static void TearDownTestSuite() {
    nginx_.reset();
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  static loc::TileFetcherConfig fetcher_config(const std::string& cache) {
    loc::TileFetcherConfig fc;
    fc.server_url = "http://127.0.0.1:" + std::to_string(nginx_->port()) + "/polmap";
    fc.publication_public_key = dir_ / "publisher.pub";
    fc.cache_dir = dir_ / cache;
    fc.backoff_initial_s = 0.05;
    fc.backoff_max_s = 0.2;
    return fc;
  }

  /// The localization tiles the manifest lists.
  static std::vector<tiles::TileKey> listed_keys() {
    const auto m = tiles::parse_publication_manifest(
        util::read_file_bytes(dir_ / "pub" / published_.dir / "manifest.json"));
    std::vector<tiles::TileKey> keys;
    for (const auto& t : m.layer("localization")->tiles) keys.push_back(t.key);
    return keys;
  }

  static inline fs::path dir_;
  static inline sim::SimConfig sim_cfg_;
  static inline eval::StudyConfig study_cfg_;
  static inline std::shared_ptr<const sim::World> world_;
  static inline std::int64_t version_ = 0;
  static inline util::Ed25519KeyPair key_;
  static inline mapping::PublishResult published_;
  static inline std::unique_ptr<Nginx> nginx_;
};

TEST_F(LocalizeFromPublication, NginxServesThePublicationWithCacheHeadersByLayout) {
  auto c = nginx_->client();
  const auto latest = c.Get("/polmap/latest.json");
  ASSERT_TRUE(latest);
  EXPECT_EQ(latest->status, 200);
  EXPECT_EQ(latest->get_header_value("Cache-Control"), "public, max-age=10");
  EXPECT_EQ(tiles::parse_publication_pointer(latest->body).dir, published_.dir);
  const auto manifest = c.Get("/polmap/" + published_.dir + "/manifest.json");
  ASSERT_TRUE(manifest);
  EXPECT_EQ(manifest->status, 200);
  EXPECT_EQ(manifest->get_header_value("Cache-Control"), "public, max-age=31536000, immutable");
  // Nothing outside the publication, no directory listings, no path tricks.
  EXPECT_EQ(c.Get("/polmap/")->status, 404);
  EXPECT_EQ(c.Get("/polmap/" + published_.dir + "/../../nginx/nginx.conf")->status, 404);
  EXPECT_EQ(c.Get("/polmap/" + published_.dir + "/%2e%2e/%2e%2e/map.sqlite")->status, 404);
  EXPECT_EQ(c.Get("/nginx.conf")->status, 404);
}

TEST_F(LocalizeFromPublication, HeldOutDriveLocalizesFromTheSignedStaticPublication) {
  loc::TileFetcher fetcher(fetcher_config("cache-a"));
  eval::LocalizeOptions opt;
  opt.fetcher = &fetcher;
  const eval::StudyDriveResult r = eval::localize_simulated_drive(
      world_, sim_cfg_, kHeldOut, PolLevel::Full, study_cfg_, fetcher, opt);
  const auto st = fetcher.stats();
  EXPECT_EQ(st.manifests_adopted, 1U);
  EXPECT_EQ(st.manifest_rejections, 0U);
  EXPECT_EQ(st.hash_mismatches, 0U);
  EXPECT_GT(st.responses_200, 0U);
  EXPECT_EQ(st.map_version, static_cast<std::uint64_t>(version_));
  ASSERT_TRUE(r.converged) << "never reached Tracking";
  EXPECT_FALSE(r.diverged);
  EXPECT_GT(r.errors.samples, 100);
  EXPECT_LT(r.errors.lat_rmse_m, kMaxLatRmse_m);
  EXPECT_LT(r.errors.long_rmse_m, kMaxLongRmse_m);
  EXPECT_LT(r.errors.rot_rmse_deg, kMaxRotRmse_deg);
  EXPECT_LT(r.errors.lat_max_m, kMaxLat_m);
  std::printf(
      "[e2e] from the publication: %lld samples, lat RMSE %.3f m, long RMSE %.3f m, rot "
      "RMSE %.2f deg, %llu tile bytes\n",
      static_cast<long long>(r.errors.samples), r.errors.lat_rmse_m, r.errors.long_rmse_m,
      r.errors.rot_rmse_deg, static_cast<unsigned long long>(st.bytes_downloaded));
}

TEST_F(LocalizeFromPublication, AWrongKeyAReplacedManifestAndAnAlteredTileAreRefused) {
  const std::vector<tiles::TileKey> keys = listed_keys();
  ASSERT_FALSE(keys.empty());
  {
    // Another publisher's key: the manifest is never adopted, no tile is accepted.
    util::write_file_bytes(dir_ / "stranger.pub", util::ed25519_generate().public_pem);
    auto fc = fetcher_config("cache-wrong-key");
    fc.publication_public_key = dir_ / "stranger.pub";
    loc::TileFetcher f(fc);
    EXPECT_FALSE(f.wait_for(keys, 1.0));
    EXPECT_GT(f.stats().manifest_rejections, 0U);
    EXPECT_EQ(f.stats().manifests_adopted, 0U);
  }
  const fs::path pub_dir = dir_ / "pub" / published_.dir;
  {
    // A manifest replaced by one that lists other hashes (the signature no longer matches).
    const std::string original = util::read_file_bytes(pub_dir / "manifest.json");
    std::string forged = original;
    const auto at = forged.find("\"tiles\":[[");
    ASSERT_NE(at, std::string::npos);
    const auto hash_at =
        forged.find('"', forged.find(',', forged.find(',', forged.find(',', at + 10) + 1) + 1)) + 1;
    forged[hash_at] = forged[hash_at] == 'a' ? 'b' : 'a';
    util::write_file_bytes(pub_dir / "manifest.json", forged);
    loc::TileFetcher f(fetcher_config("cache-forged"));
    EXPECT_FALSE(f.wait_for(keys, 1.0));
    EXPECT_GT(f.stats().manifest_rejections, 0U);
    util::write_file_bytes(pub_dir / "manifest.json", original);
  }
  {
    // One tile's bytes altered on the host: that tile is refused, the others are accepted.
    const auto m =
        tiles::parse_publication_manifest(util::read_file_bytes(pub_dir / "manifest.json"));
    const auto& layer = *m.layer("localization");
    const fs::path victim = pub_dir / tiles::published_tile_path(layer, keys.front());
    const std::string original = util::read_file_bytes(victim);
    std::string altered = original;
    altered[altered.size() / 2] = static_cast<char>(altered[altered.size() / 2] ^ 0x01);
    util::write_file_bytes(victim, altered);
    loc::TileFetcher f(fetcher_config("cache-altered"));
    const std::vector<tiles::TileKey> first{keys.front()};
    EXPECT_FALSE(f.wait_for(first, 1.5));
    EXPECT_GT(f.stats().hash_mismatches, 0U);
    if (keys.size() > 1) {
      const std::vector<tiles::TileKey> second{keys[1]};
      EXPECT_TRUE(f.wait_for(second, 5.0));
    }
    util::write_file_bytes(victim, original);
  }
}

}  // namespace
}  // namespace polmap
