// Landmark changes recorded with a map version (SqliteMapStore): round trip of every
// field, call order kept across batches, visible only once published, dropped with a
// failed version.
#include <gtest/gtest.h>

#include "polmap/mapping_service/sqlite_store.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {

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

TEST(LandmarkChanges, RoundTripInCallOrderOnceTheVersionIsPublished) {
  polmap::test::TestDir tmp("landmark_changes");
  SqliteMapStore store(tmp.path() / "map.db");
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
      EXPECT_DOUBLE_EQ(got[i].geometry[k].lat_deg, expect[i].geometry[k].lat_deg);
      EXPECT_DOUBLE_EQ(got[i].geometry[k].lon_deg, expect[i].geometry[k].lon_deg);
    }
    EXPECT_EQ(got[i].previous_geometry.size(), expect[i].previous_geometry.size()) << i;
  }
  // A published version takes no more changes.
  EXPECT_THROW(store.put_landmark_changes(v, b), ValidationError);
}

TEST(LandmarkChanges, AFailedVersionKeepsNone) {
  polmap::test::TestDir tmp("landmark_changes");
  const auto db = tmp.path() / "map.db";
  std::int64_t v = 0;
  {
    SqliteMapStore store(db);
    v = store.begin_map_version({});
    store.put_landmark_changes(v, std::vector{change(LandmarkChangeKind::Added, true, 1)});
    store.fail_map_version(v, "test");
    EXPECT_THROW((void)store.landmark_changes(v), NotFoundError);
  }
  SqliteMapStore again(db);
  EXPECT_EQ(again.stats().map_versions, 1);
  const std::int64_t w = again.begin_map_version({});
  again.publish_map_version(w, {});
  EXPECT_TRUE(again.landmark_changes(w).empty());
}

}  // namespace
}  // namespace polmap::mapping
