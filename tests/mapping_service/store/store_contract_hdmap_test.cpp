// The store contract, HD-map comparisons and landmark provenance, on every backend
// (store_backends.hpp): comparisons stored per published version and name, replaced by a
// new put, listed without features, deleted with their version; a landmark found by its
// stable key with its supporting drives (copies share their source's) and its history
// along moved changes back to the version that added it.
#include <gtest/gtest.h>

#include "mapping_service/store/contract_packages.hpp"
#include "mapping_service/store/store_backends.hpp"

namespace polmap::mapping::testing {
namespace {

using StoreHdMap = StoreContract;

StoredPointLandmark point_at(double dlat, std::int64_t key, std::vector<std::int64_t> support) {
  StoredPointLandmark p;
  p.key = key;
  p.position = {kOrigin.lat_deg + dlat, kOrigin.lon_deg, 0.0};
  p.support_drives = 2;
  p.spread_m = 0.05;
  p.scattering = ScatteringClass::Odd;
  p.support = std::move(support);
  return p;
}

std::int64_t publish(MapStore& store, std::span<const StoredPointLandmark> points,
                     std::span<const LandmarkChange> changes) {
  const auto v = store.begin_map_version({});
  store.put_landmarks(v, points, {});
  store.put_landmark_changes(v, changes);
  store.publish_map_version(v, {});
  return v;
}

TEST_P(StoreHdMap, ComparisonsAreKeptPerVersionAndNameAndGoWithTheirVersion) {
  MapStore& store = this->store();
  const StoredPointLandmark p = point_at(0.0, 11, {});
  const auto v1 = publish(store, std::span(&p, 1), {});
  const auto v2 = publish(store, std::span(&p, 1), {});

  const nlohmann::json features{
      {"type", "FeatureCollection"},
      {"features",
       {{{"type", "Feature"},
         {"geometry", {{"type", "Point"}, {"coordinates", {9.18, 48.77}}}},
         {"properties", {{"role", "hd"}, {"matched", true}, {"landmark_key", "11"}}}}}}};
  HdMapComparisonRecord r{v1, "town", "/maps/town.osm", "", {{"point_recall", 0.5}}, features};
  store.put_hdmap_comparison(r);
  r.name = "another-map_2.v1";
  r.summary = {{"point_recall", nullptr}, {"line_coverage", 0.25}};
  store.put_hdmap_comparison(r);

  const auto list = store.list_hdmap_comparisons(v1);
  ASSERT_EQ(list.size(), 2U);
  EXPECT_EQ(list[0].name, "another-map_2.v1");  // by name
  EXPECT_EQ(list[1].name, "town");
  EXPECT_EQ(list[1].hdmap_file, "/maps/town.osm");
  EXPECT_EQ(list[1].summary["point_recall"], 0.5);
  EXPECT_TRUE(list[1].features.is_null());    // listings leave the features out
  EXPECT_EQ(list[1].created_at.size(), 20U);  // ISO 8601 UTC
  EXPECT_TRUE(store.list_hdmap_comparisons(v2).empty());

  auto got = store.get_hdmap_comparison(v1, "town");
  ASSERT_TRUE(got);
  EXPECT_EQ(got->version, v1);
  EXPECT_EQ(got->features, features);
  EXPECT_EQ(store.get_hdmap_comparison(v1, "another-map_2.v1")->summary["line_coverage"], 0.25);
  EXPECT_FALSE(store.get_hdmap_comparison(v2, "town").has_value());
  EXPECT_FALSE(store.get_hdmap_comparison(v1, "nope").has_value());

  // The same name again replaces it.
  r.name = "town";
  r.summary = {{"point_recall", 1.0}};
  r.features = {{"type", "FeatureCollection"}, {"features", nlohmann::json::array()}};
  store.put_hdmap_comparison(r);
  EXPECT_EQ(store.list_hdmap_comparisons(v1).size(), 2U);
  got = store.get_hdmap_comparison(v1, "town");
  EXPECT_EQ(got->summary["point_recall"], 1.0);
  EXPECT_TRUE(got->features["features"].empty());

  // Bad names, unknown or unpublished versions.
  for (const char* bad : {"", ".hidden", "a/b", "white space", "ä"}) {
    r.name = bad;
    EXPECT_THROW(store.put_hdmap_comparison(r), ValidationError) << bad;
  }
  r.name = std::string(65, 'a');
  EXPECT_THROW(store.put_hdmap_comparison(r), ValidationError);
  r.name = std::string(64, 'a');
  store.put_hdmap_comparison(r);
  r.name = "town";
  r.version = 99;
  EXPECT_THROW(store.put_hdmap_comparison(r), NotFoundError);
  const auto building = store.begin_map_version({});
  r.version = building;
  EXPECT_THROW(store.put_hdmap_comparison(r), NotFoundError);
  EXPECT_THROW((void)store.list_hdmap_comparisons(building), NotFoundError);
  EXPECT_THROW((void)store.get_hdmap_comparison(99, "town"), NotFoundError);
  store.fail_map_version(building, "test");

  // Another store object (replica, reopen) sees them; deleting the version deletes them.
  const auto other = open();
  EXPECT_EQ(other->list_hdmap_comparisons(v1).size(), 3U);
  ASSERT_EQ(store.current_map_version(), v2);
  ASSERT_TRUE(store.delete_map_version(v1));
  EXPECT_THROW((void)other->list_hdmap_comparisons(v1), NotFoundError);
  // A new version does not inherit rows of a deleted one.
  const auto v3 = publish(store, std::span(&p, 1), {});
  EXPECT_TRUE(store.list_hdmap_comparisons(v3).empty());
}

TEST_P(StoreHdMap, LandmarkDetailFollowsTheKeyChainAndNamesSupportingDrives) {
  MapStore& store = this->store();
  DrivePackage a = make_package("drive-a", 3, 0, 1);
  a.manifest.start_time_s = 1.7e9;
  a.manifest.end_time_s = 1.7e9 + 60;
  DrivePackage b = make_package("drive-b", 3, 0, 2);
  b.manifest.vehicle_id = "veh-2";
  b.manifest.start_time_s = 1.6e9;
  b.manifest.end_time_s = 1.6e9 + 90;
  (void)put_with_archive(store, tmp(), a, "a", "A");
  (void)put_with_archive(store, tmp(), b, "b", "B");
  const auto cands = store.candidates_in(std::nullopt);
  ASSERT_EQ(cands.points.size(), 6U);
  const std::int64_t ca0 = cands.points[0].id, ca1 = cands.points[1].id;
  const std::int64_t cb0 = cands.points[3].id;

  // v1: landmark 100 (drives a, a, b) and 200. v2: 100 moved to key 101; 300 added.
  // v3: incremental copy of everything (no changes). v4: 101 moved to 102.
  std::vector<StoredPointLandmark> l1{point_at(0.0, 100, {ca0, ca1, cb0}),
                                      point_at(0.001, 200, {})};
  const auto v1 = publish(store, l1, {});

  std::vector<StoredPointLandmark> l2{point_at(0.00001, 101, {ca0, cb0}), point_at(0.001, 200, {}),
                                      point_at(0.002, 300, {ca1})};
  LandmarkChange moved;
  moved.change = LandmarkChangeKind::Moved;
  moved.key = 101;
  moved.previous_key = 100;
  moved.distance_m = 1.1;
  moved.geometry = {l2[0].position};
  moved.previous_geometry = {l1[0].position};
  moved.reason = {{"rule", "moved"}, {"support_drives", 2}};
  LandmarkChange added;
  added.key = 300;
  added.geometry = {l2[2].position};
  added.reason = {{"rule", "support"}};
  const auto v2 = publish(store, l2, std::vector<LandmarkChange>{moved, added});

  const auto v3 = store.begin_map_version({});
  EXPECT_EQ(store.copy_landmarks(v2, v3, {}), 3);
  store.publish_map_version(v3, {});

  std::vector<StoredPointLandmark> l4{point_at(0.00002, 102, {cb0})};
  LandmarkChange moved2 = moved;
  moved2.key = 102;
  moved2.previous_key = 101;
  moved2.distance_m = 1.2;
  const auto v4 = publish(store, l4, std::vector<LandmarkChange>{moved2});

  // In v3 (a copy), key 101: the source's support links, the history of v2 and v1.
  auto d = store.landmark_detail(v3, 101);
  ASSERT_TRUE(d);
  EXPECT_EQ(d->version, v3);
  EXPECT_EQ(d->key, 101);
  EXPECT_FALSE(d->is_line);
  ASSERT_EQ(d->geometry.size(), 1U);
  EXPECT_DOUBLE_EQ(d->geometry[0].lat_deg, kOrigin.lat_deg + 0.00001);
  EXPECT_EQ(d->scattering, ScatteringClass::Odd);
  EXPECT_EQ(d->support_drives, 2U);
  EXPECT_DOUBLE_EQ(d->spread_m, 0.05);
  ASSERT_EQ(d->drives.size(), 2U);
  EXPECT_EQ(d->drives[0].drive_id, "drive-b");  // by start time
  EXPECT_EQ(d->drives[0].vehicle_id, "veh-2");
  EXPECT_DOUBLE_EQ(d->drives[0].start_time_s, 1.6e9);
  EXPECT_DOUBLE_EQ(d->drives[0].end_time_s, 1.6e9 + 90);
  EXPECT_EQ(d->drives[0].candidates, 1);
  EXPECT_EQ(d->drives[1].drive_id, "drive-a");
  EXPECT_EQ(d->drives[1].ingested_at.size(), 20U);
  ASSERT_EQ(d->history.size(), 2U);
  EXPECT_EQ(d->history[0].version, v2);
  EXPECT_EQ(d->history[0].change.change, LandmarkChangeKind::Moved);
  EXPECT_EQ(d->history[0].change.previous_key, 100);
  EXPECT_DOUBLE_EQ(d->history[0].change.distance_m, 1.1);
  EXPECT_EQ(d->history[0].change.reason["rule"], "moved");
  EXPECT_FALSE(d->history[0].inferred);
  EXPECT_FALSE(d->history[0].published_at.empty());
  EXPECT_EQ(d->history[1].version, v1);  // the first version records no changes
  EXPECT_EQ(d->history[1].change.change, LandmarkChangeKind::Added);
  EXPECT_EQ(d->history[1].change.key, 100);
  EXPECT_TRUE(d->history[1].inferred);

  // In v4: two moves, then v1.
  d = store.landmark_detail(v4, 102);
  ASSERT_TRUE(d);
  ASSERT_EQ(d->history.size(), 3U);
  EXPECT_EQ(d->history[0].version, v4);
  EXPECT_EQ(d->history[0].change.previous_key, 101);
  EXPECT_EQ(d->history[1].version, v2);
  EXPECT_EQ(d->history[2].version, v1);
  EXPECT_EQ(d->drives.size(), 1U);

  // Added in v2 (recorded): no inferred entry before it. Unchanged since v1: inferred only.
  d = store.landmark_detail(v3, 300);
  ASSERT_TRUE(d);
  ASSERT_EQ(d->history.size(), 1U);
  EXPECT_EQ(d->history[0].version, v2);
  EXPECT_EQ(d->history[0].change.change, LandmarkChangeKind::Added);
  EXPECT_FALSE(d->history[0].inferred);
  EXPECT_EQ(d->history[0].change.reason["rule"], "support");
  d = store.landmark_detail(v3, 200);
  ASSERT_TRUE(d);
  ASSERT_EQ(d->history.size(), 1U);
  EXPECT_EQ(d->history[0].version, v1);
  EXPECT_TRUE(d->history[0].inferred);
  EXPECT_TRUE(d->drives.empty());

  // A version sees only its past: key 101 in v2 has no v4 entry; key 102 is not in v3.
  EXPECT_EQ(store.landmark_detail(v2, 101)->history.size(), 2U);
  EXPECT_FALSE(store.landmark_detail(v3, 102).has_value());
  EXPECT_FALSE(store.landmark_detail(v1, 101).has_value());
  EXPECT_THROW((void)store.landmark_detail(99, 101), NotFoundError);

  // A deleted drive takes its support with it.
  ASSERT_TRUE(store.delete_drive("drive-b"));
  d = store.landmark_detail(v3, 101);
  ASSERT_EQ(d->drives.size(), 1U);
  EXPECT_EQ(d->drives[0].drive_id, "drive-a");
  EXPECT_EQ(d->support_drives, 2U);  // as the consensus counted them
}

POLMAP_STORE_CONTRACT_BACKENDS(StoreHdMap);

}  // namespace
}  // namespace polmap::mapping::testing
