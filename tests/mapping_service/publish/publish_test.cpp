// Static publication of a map version: the directory form has the documented layout, its
// manifest verifies with the publisher's key and lists every file with its SHA-256, the
// pointer moves only once the new directory is complete, an earlier publication stays;
// the MBTiles form opens in GDAL with the landmarks as vector features.
#include "polmap/mapping_service/publish.hpp"

#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogrsf_frmts.h>

#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/publication_manifest.hpp"
#include "polmap/util/ed25519.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/sha256.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {
namespace fs = std::filesystem;

const GeoPoint kOrigin{48.7758, 9.1829, 0.0};

/// Publishes a version with `n` point landmarks on a 5 m grid east of kOrigin, two lines,
/// a localization tile and a gridmap tile.
std::int64_t make_version(SqliteMapStore& store, int n) {
  const std::int64_t v = store.begin_map_version({});
  const tiles::LocalFrame f(kOrigin);
  std::vector<StoredPointLandmark> pts;
  for (int i = 0; i < n; ++i) {
    StoredPointLandmark p;
    p.key = 1000 + i;
    p.position = f.to_geo(Eigen::Vector2d(5.0 * i, 3.0));
    p.support_drives = 3;
    pts.push_back(p);
  }
  std::vector<StoredLineLandmark> lines(2);
  for (int i = 0; i < 2; ++i) {
    lines[i].key = 5000 + i;
    lines[i].polyline = {f.to_geo(Eigen::Vector2d(0, -4.0 - i)),
                         f.to_geo(Eigen::Vector2d(40, -4.0 - i))};
    lines[i].support_drives = 2;
  }
  store.put_landmarks(v, pts, lines);
  const tiles::TileKey lk =
      tiles::tile_at(kOrigin.lat_deg, kOrigin.lon_deg, tiles::kLocalizationZoom);
  const std::string loc = "localization tile of version " + std::to_string(v);
  store.put_tiles(v, TileLayer::Localization,
                  std::vector<TileWrite>{{lk, content_etag(loc), loc, false, n, 2}});
  const tiles::TileKey gk = tiles::tile_at(kOrigin.lat_deg, kOrigin.lon_deg, 18);
  store.put_tiles(v, TileLayer::Gridmap,
                  std::vector<TileWrite>{{gk, content_etag("png"), "png", false, 0, 0}});
  store.put_tiles(v, TileLayer::GridmapMechanism,
                  std::vector<TileWrite>{{gk, content_etag("mech"), "mech", false, 0, 0}});
  store.publish_map_version(v, {});
  return v;
}

TEST(Publish, DirectoryIsSignedContentNamedAndCompleteBeforeThePointerMoves) {
  polmap::test::TestDir tmp("publish");
  SqliteMapStore store(tmp.path() / "map.db");
  const std::int64_t v1 = make_version(store, 6);
  const util::Ed25519KeyPair key = util::ed25519_generate();
  PublishOptions o;
  o.out = tmp.path() / "pub";
  o.private_key_pem = key.private_pem;
  const PublishResult r = publish_map_version(store, v1, o);
  EXPECT_EQ(r.dir, "v" + std::to_string(v1) + "-" + r.manifest_sha256.substr(0, 16));
  EXPECT_EQ(r.tiles.at("localization"), 1U);
  EXPECT_EQ(r.tiles.at("gridmap"), 1U);
  EXPECT_GE(r.tiles.at("mvt"), 5U);  // one tile per zoom 14..18 at least

  const fs::path dir = o.out / r.dir;
  const std::string manifest = util::read_file_bytes(dir / "manifest.json");
  EXPECT_EQ(util::sha256_hex(manifest), r.manifest_sha256);
  std::string sig = util::read_file_bytes(dir / "manifest.sig");
  sig.erase(sig.find_last_not_of('\n') + 1);
  EXPECT_TRUE(util::ed25519_verify_hex(key.public_pem, manifest, sig));
  const tiles::PublicationManifest m = tiles::parse_publication_manifest(manifest);
  EXPECT_EQ(m.map_version, v1);
  EXPECT_EQ(m.key_id, util::ed25519_key_id(key.public_pem));
  // Every listed file exists with the listed hash and size; the localization tile's bytes
  // are the store's.
  std::size_t files = 0;
  for (const auto& layer : m.layers) {
    for (const auto& t : layer.tiles) {
      const std::string bytes =
          util::read_file_bytes(dir / tiles::published_tile_path(layer, t.key));
      EXPECT_EQ(util::sha256_hex(bytes), t.sha256) << layer.name;
      EXPECT_EQ(bytes.size(), t.bytes);
      ++files;
    }
  }
  EXPECT_EQ(files, r.tiles.at("localization") + r.tiles.at("mvt") + 2 * r.tiles.at("gridmap"));
  const auto* loc = m.layer("localization");
  ASSERT_NE(loc, nullptr);
  EXPECT_EQ(util::read_file_bytes(dir / tiles::published_tile_path(*loc, loc->tiles[0].key)),
            "localization tile of version " + std::to_string(v1));
  const tiles::PublicationPointer p =
      tiles::parse_publication_pointer(util::read_file_bytes(o.out / "latest.json"));
  EXPECT_EQ(p.dir, r.dir);
  EXPECT_EQ(p.map_version, v1);

  // A second version: a new directory, the pointer moves, the first publication stays.
  const std::int64_t v2 = make_version(store, 7);
  const PublishResult r2 = publish_map_version(store, v2, o);
  EXPECT_NE(r2.dir, r.dir);
  EXPECT_TRUE(fs::exists(dir / "manifest.json"));
  EXPECT_EQ(tiles::parse_publication_pointer(util::read_file_bytes(o.out / "latest.json")).dir,
            r2.dir);
  // No staging directory is left behind.
  for (const auto& e : fs::directory_iterator(o.out)) {
    EXPECT_FALSE(e.path().filename().string().starts_with(".publishing")) << e.path();
  }
}

TEST(Publish, RefusesUnpublishedVersionsAndMissingKeys) {
  polmap::test::TestDir tmp("publish");
  SqliteMapStore store(tmp.path() / "map.db");
  const std::int64_t v = make_version(store, 2);
  PublishOptions o;
  o.out = tmp.path() / "pub";
  EXPECT_THROW((void)publish_map_version(store, v, o), ValidationError);  // no key
  o.private_key_pem = "garbage";
  EXPECT_THROW((void)publish_map_version(store, v, o), ValidationError);
  o.private_key_pem = util::ed25519_generate().private_pem;
  EXPECT_THROW((void)publish_map_version(store, v + 7, o), NotFoundError);
  EXPECT_FALSE(fs::exists(o.out / "latest.json"));
}

TEST(Publish, MBTilesOpensInGdalWithTheLandmarks) {
  GDALAllRegister();
  polmap::test::TestDir tmp("publish");
  SqliteMapStore store(tmp.path() / "map.db");
  const std::int64_t v = make_version(store, 6);
  PublishOptions o;
  o.format = PublishFormat::MBTiles;
  o.out = tmp.path() / "map.mbtiles";
  o.mvt_min_zoom = o.mvt_max_zoom = 16;
  const PublishResult r = publish_map_version(store, v, o);
  EXPECT_GE(r.tiles.at("mvt"), 1U);
  GDALDatasetUniquePtr ds(GDALDataset::Open(o.out.c_str(), GDAL_OF_VECTOR));
  ASSERT_TRUE(ds) << "GDAL cannot open the MBTiles";
  OGRLayer* points = ds->GetLayerByName("points");
  OGRLayer* lines = ds->GetLayerByName("lines");
  ASSERT_NE(points, nullptr);
  ASSERT_NE(lines, nullptr);
  // Features are per tile (a landmark in the buffer of two tiles appears twice): at least
  // the landmarks, with their ids.
  std::set<std::int64_t> ids;
  for (auto& f : *points) ids.insert(f->GetFieldAsInteger64("id"));
  EXPECT_EQ(ids.size(), 6U);
  EXPECT_TRUE(ids.contains(1000));
  EXPECT_GE(lines->GetFeatureCount(), 2);
  EXPECT_STREQ(ds->GetMetadataItem("polmap_map_version"), std::to_string(v).c_str());
}

}  // namespace
}  // namespace polmap::mapping
