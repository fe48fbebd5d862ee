// The store contract, map versions and published content, on every backend
// (store_backends.hpp): atomic publish (readers see whole maps only), tile blobs shared and
// collected, rollback/delete/fail, landmark box queries, support links surviving a drive
// deleted during the build, incremental copies, and landmark changes.
#include <gtest/gtest.h>

#include <atomic>
#include <thread>

#include "mapping_service/store/contract_packages.hpp"
#include "mapping_service/store/store_backends.hpp"

namespace polmap::mapping::testing {
namespace {

using StoreMaps = StoreContract;

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

TEST_P(StoreMaps, MapVersionsPublishAtomicallyAndReadersSeeOnlyPublishedMaps) {
  MapStore& store = this->store();
  (void)put_with_archive(store, tmp(), make_package("a", 5, 0, 1), "a", "A");
  const auto cands = store.candidates_in(std::nullopt);
  const tiles::TileKey key =
      tiles::tile_at(kOrigin.lat_deg, kOrigin.lon_deg, tiles::kLocalizationZoom);

  EXPECT_FALSE(store.current_map_version().has_value());
  const auto v1 = store.begin_map_version({{"notes", "v1"}});
  EXPECT_EQ(v1, 1);
  std::vector<StoredPointLandmark> pts1{point_lm(0.0, 1, {cands.points[1].id, cands.points[0].id}),
                                        point_lm(0.0001, 2)};
  StoredLineLandmark line;
  line.key = 3;
  line.polyline = {{kOrigin.lat_deg, kOrigin.lon_deg, 0},
                   {kOrigin.lat_deg + 0.0002, kOrigin.lon_deg + 0.0002, 0}};
  line.support_drives = 3;
  line.spread_m = 0.125;
  store.put_landmarks(v1, pts1, std::vector<StoredLineLandmark>{line});
  store.put_tiles(v1, TileLayer::Localization,
                  std::vector<TileWrite>{{key, "", "tile v1", false, 2, 1}});
  EXPECT_THROW((void)store.landmarks_in(v1, std::nullopt), NotFoundError);  // still building
  EXPECT_THROW((void)store.get_tile(v1, TileLayer::Localization, key), NotFoundError);
  EXPECT_THROW(store.set_current_map_version(v1), NotFoundError);
  EXPECT_EQ(store.list_tiles(v1, TileLayer::Localization).size(), 1U);  // its builder sees it
  store.publish_map_version(v1, {{"landmarks", 3}});
  EXPECT_EQ(store.current_map_version(), v1);
  const auto l1 = store.landmarks_in(v1, std::nullopt);
  ASSERT_EQ(l1.points.size(), 2U);
  ASSERT_EQ(l1.lines.size(), 1U);
  EXPECT_EQ(l1.points[0].id, 1);
  EXPECT_EQ(l1.lines[0].id, 3);
  EXPECT_EQ(l1.points[0].support,
            (std::vector<std::int64_t>{cands.points[0].id, cands.points[1].id}));
  EXPECT_TRUE(l1.points[1].support.empty());
  EXPECT_TRUE(store.landmarks_in(v1, std::nullopt, false).points[0].support.empty());
  EXPECT_EQ(l1.lines[0].polyline.size(), 2U);
  EXPECT_DOUBLE_EQ(l1.lines[0].polyline[1].lat_deg, kOrigin.lat_deg + 0.0002);
  EXPECT_DOUBLE_EQ(l1.lines[0].spread_m, 0.125);
  EXPECT_EQ(l1.lines[0].support_drives, 3U);
  EXPECT_EQ(l1.points[0].scattering, ScatteringClass::Even);
  const auto t1 = store.get_tile(v1, TileLayer::Localization, key);
  ASSERT_TRUE(t1);
  EXPECT_EQ(t1->payload, "tile v1");
  EXPECT_EQ(t1->etag, content_etag("tile v1"));
  EXPECT_EQ(store.get_tile_etag(v1, TileLayer::Localization, key), t1->etag);
  EXPECT_FALSE(store.get_tile(v1, TileLayer::Gridmap, key).has_value());
  const auto listed = store.list_tiles(v1, TileLayer::Localization);
  ASSERT_EQ(listed.size(), 1U);
  EXPECT_EQ(listed[0].byte_size, 7);
  EXPECT_EQ(listed[0].num_points, 2);
  EXPECT_EQ(listed[0].num_lines, 1);
  EXPECT_THROW(store.publish_map_version(v1, {}), ValidationError);  // immutable now
  const auto info1 = store.get_map_version(v1);
  ASSERT_TRUE(info1);
  EXPECT_EQ(info1->published_at.size(), 20U);
  EXPECT_TRUE(info1->current);

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
  EXPECT_THROW(store.put_tiles(v2, TileLayer::Localization,
                               std::vector<TileWrite>{{key, std::string(64, 'f'), "", true, 0, 0}}),
               ValidationError);
  EXPECT_THROW(
      store.put_tiles(v2, TileLayer::Localization,
                      std::vector<TileWrite>{{key, std::string(64, 'f'), "payload", false, 0, 0}}),
      ValidationError);
  store.publish_map_version(v2, {});
  while (reads < 20) std::this_thread::yield();
  stop = true;
  reader.join();
  EXPECT_EQ(bad, 0);
  EXPECT_EQ(store.current_map_version(), v2);
  EXPECT_EQ(store.stats().tile_blobs, 1);  // shared by both versions
  EXPECT_EQ(store.stats().current_point_landmarks, 400);
  EXPECT_EQ(store.stats().current_tiles, 1);
  EXPECT_EQ(store.get_tile(v2, TileLayer::Localization, key)->payload, "tile v1");

  // Rollback, delete, failed builds.
  EXPECT_THROW((void)store.delete_map_version(v2), ConflictError);
  store.set_current_map_version(v1);
  EXPECT_FALSE(store.get_map_version(v2)->current);
  EXPECT_TRUE(store.delete_map_version(v2));
  EXPECT_FALSE(store.delete_map_version(v2));
  EXPECT_EQ(store.stats().tile_blobs, 1);  // still used by v1
  const auto v3 = store.begin_map_version({});
  EXPECT_EQ(v3, 2);  // numbers follow the largest one in use
  store.put_tiles(v3, TileLayer::Gridmap, std::vector<TileWrite>{{key, "", "grid", false, 0, 0}});
  store.fail_map_version(v3, "test failure");
  EXPECT_THROW(store.fail_map_version(v1, "no"), ValidationError);
  EXPECT_THROW(store.fail_map_version(99, "no"), NotFoundError);
  const auto info3 = store.get_map_version(v3);
  ASSERT_TRUE(info3);
  EXPECT_EQ(info3->status, MapVersionStatus::Failed);
  EXPECT_EQ(info3->error, "test failure");
  EXPECT_TRUE(info3->statistics.is_null());
  EXPECT_EQ(store.stats().tile_blobs, 1);  // failed build's blob dropped
  EXPECT_TRUE(store.get_map_version(v1)->current);
  EXPECT_EQ(store.get_map_version(v1)->statistics.at("landmarks"), 3);
  EXPECT_EQ(store.get_map_version(v1)->parameters.at("notes"), "v1");
  const auto all = store.list_map_versions();
  ASSERT_EQ(all.size(), 2U);
  EXPECT_EQ(all[0].version, v1);
  EXPECT_EQ(all[1].version, v3);
  EXPECT_EQ(store.stats().map_versions, 2);
}

TEST_P(StoreMaps, LandmarkBoxQueryAndDriveDeleteKeepsPublishedLandmarks) {
  MapStore& store = this->store();
  (void)put_with_archive(store, tmp(), make_package("a", 5, 0, 1), "a", "A");
  const auto cands = store.candidates_in(std::nullopt);
  const auto v = store.begin_map_version({});
  std::vector<StoredPointLandmark> pts;
  for (int i = 0; i < 50; ++i) pts.push_back(point_lm(1e-5 * i, i, {cands.points[0].id}));
  StoredLineLandmark line;
  line.key = 77;
  line.polyline = {{kOrigin.lat_deg + 1e-5 * 30, kOrigin.lon_deg - 1e-3, 0},
                   {kOrigin.lat_deg + 1e-5 * 30, kOrigin.lon_deg - 2e-3, 0},
                   {kOrigin.lat_deg + 1e-5 * 40, kOrigin.lon_deg - 3e-3, 0}};
  store.put_landmarks(v, pts, std::vector<StoredLineLandmark>{line});
  StoredLineLandmark bad;
  bad.polyline = {line.polyline[0]};
  EXPECT_THROW(store.put_landmarks(v, {}, std::vector<StoredLineLandmark>{bad}), ValidationError);
  store.publish_map_version(v, {});
  const tiles::GeoBox box{kOrigin.lat_deg + 1e-5 * 9.5, kOrigin.lon_deg - 1e-3,
                          kOrigin.lat_deg + 1e-5 * 20.5, kOrigin.lon_deg + 1e-3};
  EXPECT_EQ(store.landmarks_in(v, box).points.size(), 11U);
  EXPECT_TRUE(store.landmarks_in(v, box).lines.empty());
  const tiles::GeoBox line_box{kOrigin.lat_deg + 1e-5 * 35, kOrigin.lon_deg - 2.5e-3,
                               kOrigin.lat_deg + 1e-5 * 36, kOrigin.lon_deg - 2.4e-3};
  const auto in_line_box = store.landmarks_in(v, line_box);
  ASSERT_EQ(in_line_box.lines.size(), 1U);  // its bounding box intersects
  EXPECT_EQ(in_line_box.lines[0].polyline.size(), 3U);
  EXPECT_TRUE(store.delete_drive("a"));
  const auto after = store.landmarks_in(v, std::nullopt);
  EXPECT_EQ(after.points.size(), 50U);
  EXPECT_TRUE(after.points[0].support.empty());
  EXPECT_THROW((void)store.landmarks_in(v + 1, std::nullopt), NotFoundError);
}

TEST_P(StoreMaps, ADriveDeletedDuringABuildDoesNotFailIt) {
  // The build read the candidates of "a" and "b"; "a" is erased before its landmarks are
  // stored (found by the soak: the build failed on a foreign key).
  MapStore& store = this->store();
  (void)put_with_archive(store, tmp(), make_package("a", 3, 0, 1), "a", "A");
  (void)put_with_archive(store, tmp(), make_package("b", 3, 0, 2), "b", "B");
  const auto cands = store.candidates_in(std::nullopt);
  ASSERT_EQ(cands.points.size(), 6U);
  const auto v = store.begin_map_version({});
  EXPECT_TRUE(store.delete_drive("a"));
  std::vector<StoredPointLandmark> pts;
  pts.push_back(point_lm(0.0, 1, {cands.points[0].id, cands.points[3].id, cands.points[3].id}));
  store.put_landmarks(v, pts, {});
  store.publish_map_version(v, {});
  const auto lm = store.landmarks_in(v, std::nullopt);
  ASSERT_EQ(lm.points.size(), 1U);
  // Only the link to the surviving drive's candidate remains.
  EXPECT_EQ(lm.points[0].support, std::vector<std::int64_t>{cands.points[3].id});
}

TEST_P(StoreMaps, IncrementalCopiesShareSupportAndSurviveTheirSourcesDeletion) {
  MapStore& store = this->store();
  (void)put_with_archive(store, tmp(), make_package("a", 4, 0, 1), "a", "A");
  const auto cands = store.candidates_in(std::nullopt);
  const tiles::TileKey k1 = tiles::tile_at(kOrigin.lat_deg, kOrigin.lon_deg, 16);
  const tiles::TileKey k2{k1.z, k1.x + 1, k1.y};
  const auto v1 = store.begin_map_version({});
  store.put_landmarks(v1,
                      std::vector<StoredPointLandmark>{point_lm(0.0, 1, {cands.points[0].id}),
                                                       point_lm(1e-5, 2, {cands.points[1].id}),
                                                       point_lm(2e-5, 3, {cands.points[2].id})},
                      {});
  store.put_tiles(v1, TileLayer::Gridmap,
                  std::vector<TileWrite>{{k1, "", "g1", false, 0, 0}, {k2, "", "g2", false, 0, 0}});
  EXPECT_THROW((void)store.copy_landmarks(v1, v1, {}), NotFoundError);  // v1 not published
  store.publish_map_version(v1, {});
  const auto old = store.landmarks_in(v1, std::nullopt);
  const auto v2 = store.begin_map_version({});
  const std::vector<std::int64_t> except{old.points[1].id};
  EXPECT_EQ(store.copy_landmarks(v1, v2, except), 2);
  const std::vector<tiles::TileKey> except_tiles{k2};
  EXPECT_EQ(store.copy_tiles(v1, v2, TileLayer::Gridmap, except_tiles), 1);
  EXPECT_EQ(store.copy_tiles(v1, v2, TileLayer::Localization, {}), 0);
  EXPECT_THROW((void)store.copy_landmarks(v2, v1, {}), NotFoundError);
  store.publish_map_version(v2, {}, false);
  EXPECT_EQ(store.current_map_version(), v1);
  const auto copied = store.landmarks_in(v2, std::nullopt);
  ASSERT_EQ(copied.points.size(), 2U);
  EXPECT_EQ(copied.points[0].id, 4);  // new ids follow, in the order of the old ones
  EXPECT_EQ(copied.points[1].id, 5);
  EXPECT_EQ(copied.points[0].key, 1);
  EXPECT_EQ(copied.points[1].key, 3);
  EXPECT_EQ(copied.points[1].support, std::vector<std::int64_t>{cands.points[2].id});
  EXPECT_EQ(store.list_tiles(v2, TileLayer::Gridmap).size(), 1U);
  EXPECT_EQ(store.get_tile(v2, TileLayer::Gridmap, k1)->payload, "g1");
  // Deleting v1 hands its support links to the copies, and its unshared blob goes.
  store.set_current_map_version(v2);
  EXPECT_TRUE(store.delete_map_version(v1));
  const auto kept = store.landmarks_in(v2, std::nullopt);
  ASSERT_EQ(kept.points.size(), 2U);
  EXPECT_EQ(kept.points[0].support, std::vector<std::int64_t>{cands.points[0].id});
  EXPECT_EQ(kept.points[1].support, std::vector<std::int64_t>{cands.points[2].id});
  EXPECT_EQ(store.stats().tile_blobs, 1);
}

LandmarkChange change(LandmarkChangeKind k, bool line, std::int64_t key) {
  LandmarkChange c;
  c.change = k;
  c.is_line = line;
  c.key = key;
  c.geometry = {{48.1 + 1e-6 * key, 9.2, 0.0}};
  if (line) c.geometry.push_back({48.1001, 9.2003, 0.0});
  if (k == LandmarkChangeKind::Moved) {
    c.previous_key = key + 1000;
    c.previous_geometry = {{48.09, 9.19, 0.0}};
    c.distance_m = 1.25;
  }
  c.reason = {{"rule", "support"}, {"support_drives", key}};
  return c;
}

TEST_P(StoreMaps, LandmarkChangesRoundTripInCallOrderOnceTheVersionIsPublished) {
  MapStore& store = this->store();
  const std::int64_t v = store.begin_map_version({});
  const std::vector<LandmarkChange> a{change(LandmarkChangeKind::Added, false, 7),
                                      change(LandmarkChangeKind::Moved, true, 3)};
  const std::vector<LandmarkChange> b{change(LandmarkChangeKind::Retired, false, 5)};
  store.put_landmark_changes(v, a);
  store.put_landmark_changes(v, b);
  EXPECT_THROW((void)store.landmark_changes(v), NotFoundError);  // still building
  store.publish_map_version(v, {});
  const auto got = store.landmark_changes(v);
  ASSERT_EQ(got.size(), 3U);
  const std::vector<LandmarkChange> expect{a[0], a[1], b[0]};
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].change, expect[i].change) << i;
    EXPECT_EQ(got[i].is_line, expect[i].is_line) << i;
    EXPECT_EQ(got[i].key, expect[i].key) << i;
    EXPECT_EQ(got[i].previous_key, expect[i].previous_key) << i;
    EXPECT_DOUBLE_EQ(got[i].distance_m, expect[i].distance_m) << i;
    EXPECT_EQ(got[i].reason, expect[i].reason) << i;
    ASSERT_EQ(got[i].geometry.size(), expect[i].geometry.size()) << i;
    for (std::size_t k = 0; k < got[i].geometry.size(); ++k) {
      EXPECT_EQ(got[i].geometry[k].lat_deg, expect[i].geometry[k].lat_deg);  // exact
      EXPECT_EQ(got[i].geometry[k].lon_deg, expect[i].geometry[k].lon_deg);
    }
    EXPECT_EQ(got[i].previous_geometry.size(), expect[i].previous_geometry.size()) << i;
  }
  // A published version takes no more changes.
  EXPECT_THROW(store.put_landmark_changes(v, b), ValidationError);
}

TEST_P(StoreMaps, AFailedVersionKeepsNoLandmarkChanges) {
  std::int64_t v = 0;
  {
    const auto s = open();
    v = s->begin_map_version({});
    s->put_landmark_changes(v, std::vector{change(LandmarkChangeKind::Added, true, 1)});
    s->fail_map_version(v, "test");
    EXPECT_THROW((void)s->landmark_changes(v), NotFoundError);
  }
  const auto again = open();
  EXPECT_EQ(again->stats().map_versions, 1);
  const std::int64_t w = again->begin_map_version({});
  again->publish_map_version(w, {});
  EXPECT_TRUE(again->landmark_changes(w).empty());
}

POLMAP_STORE_CONTRACT_BACKENDS(StoreMaps);

}  // namespace
}  // namespace polmap::mapping::testing
