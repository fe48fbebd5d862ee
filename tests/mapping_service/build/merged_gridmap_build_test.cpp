// The map build's merged gridmap: drives go into the store's sum tiles once, a new drive
// re-renders only the min-zoom regions it touches (the rest is copied, same ETags) and the
// result equals a build from scratch; a deleted drive is taken out of the sums; a
// leave-one-out build renders without the drive and leaves the sums alone.
#include <gtest/gtest.h>

#include "builder_fixtures.hpp"
#include "polmap/mapping_service/map_builder.hpp"

namespace polmap::mapping {
namespace {
using namespace builder_fixtures;  // NOLINT: test fixtures

struct TempDir : polmap::test::TestDir {
  TempDir() : TestDir("merged_gridmap") {}
};

// 5 km east: another z14 region (1.6 km wide at 48.8° N).
const Eigen::Vector2d kFar{5000.0, 0.0};

std::map<std::pair<int, tiles::TileKey>, std::string> etags(const MapStore& s, std::int64_t v) {
  std::map<std::pair<int, tiles::TileKey>, std::string> out;
  for (const TileLayer layer : {TileLayer::Gridmap, TileLayer::GridmapMechanism}) {
    for (const auto& t : s.list_tiles(v, layer)) out[{static_cast<int>(layer), t.key}] = t.etag;
  }
  return out;
}

PackageWriteOptions v2() { return package_format(2); }

TEST(MergedGridmapBuild, ANewDriveRerendersOnlyItsRegionAndEqualsABuildFromScratch) {
  TempDir tmp;
  const World w = make_world(4, 50, 50.0);
  SqliteMapStore store(tmp.path() / "map.db");
  put_real_package(store, tmp.path(), w, 0, "a", v2());
  put_real_package(store, tmp.path(), w, 1, "b", v2(), kFar);
  const auto v1 = MapBuilder{}.build(store, {});
  ASSERT_EQ(v1.status, MapBuildResult::Status::Published) << v1.error;
  EXPECT_EQ(v1.stats.gridmap_drives_added, 2);
  EXPECT_GE(v1.stats.gridmap_regions_rendered, 2);  // (a's strip may straddle a border)
  EXPECT_EQ(v1.stats.gridmap_tiles_copied, 0);
  EXPECT_EQ(store.gridmap_sum_inputs().size(), 2U);

  put_real_package(store, tmp.path(), w, 0, "c", v2(), Eigen::Vector2d(8.0, 3.0), 10.0);
  const auto v2b = MapBuilder{}.build(store, {});
  ASSERT_EQ(v2b.status, MapBuildResult::Status::Published) << v2b.error;
  EXPECT_EQ(v2b.stats.gridmap_drives_added, 1);
  // The far region is copied.
  EXPECT_LT(v2b.stats.gridmap_regions_rendered, v1.stats.gridmap_regions_rendered);
  EXPECT_GT(v2b.stats.gridmap_tiles_copied, 0);
  const auto e1 = etags(store, v1.version), e2 = etags(store, v2b.version);
  int same = 0, changed = 0;
  for (const auto& [k, etag] : e2) {
    const auto it = e1.find(k);
    (it != e1.end() && it->second == etag ? same : changed) += 1;
  }
  EXPECT_GT(same, 0);
  EXPECT_GT(changed, 0);  // the tiles drive c covers

  // The same three drives into an empty store, built once: identical tiles.
  TempDir tmp2;
  SqliteMapStore fresh(tmp2.path() / "map.db");
  put_real_package(fresh, tmp2.path(), w, 0, "a", v2());
  put_real_package(fresh, tmp2.path(), w, 1, "b", v2(), kFar);
  put_real_package(fresh, tmp2.path(), w, 0, "c", v2(), Eigen::Vector2d(8.0, 3.0), 10.0);
  const auto f = MapBuilder{}.build(fresh, {});
  ASSERT_EQ(f.status, MapBuildResult::Status::Published) << f.error;
  EXPECT_EQ(etags(fresh, f.version), e2);
}

TEST(MergedGridmapBuild, ADeletedDriveIsTakenOutOfTheSums) {
  TempDir tmp;
  const World w = make_world(4, 50, 50.0);
  SqliteMapStore store(tmp.path() / "map.db");
  put_real_package(store, tmp.path(), w, 0, "a", v2());
  const auto v1 = MapBuilder{}.build(store, {});
  ASSERT_EQ(v1.status, MapBuildResult::Status::Published) << v1.error;
  put_real_package(store, tmp.path(), w, 1, "b", v2(), Eigen::Vector2d(30.0, 5.0), 10.0);
  const auto v2b = MapBuilder{}.build(store, {});
  ASSERT_EQ(v2b.status, MapBuildResult::Status::Published) << v2b.error;
  ASSERT_NE(etags(store, v2b.version), etags(store, v1.version));
  const std::string hash_b = store.get_drive("b")->content_hash;
  EXPECT_FALSE(store.gridmap_sum_cover(hash_b).empty());

  ASSERT_TRUE(store.delete_drive("b"));
  const auto v3 = MapBuilder{}.build(store, {});
  ASSERT_EQ(v3.status, MapBuildResult::Status::Published) << v3.error;
  EXPECT_EQ(v3.stats.gridmap_drives_removed, 1);
  EXPECT_EQ(store.gridmap_sum_inputs().size(), 1U);
  EXPECT_TRUE(store.gridmap_sum_cover(hash_b).empty());
  // Back to what drive a alone gave (tiles only b covered are gone).
  EXPECT_EQ(etags(store, v3.version), etags(store, v1.version));
}

TEST(MergedGridmapBuild, LeaveOneOutRendersWithoutTheDriveAndKeepsTheSums) {
  TempDir tmp;
  const World w = make_world(4, 50, 50.0);
  SqliteMapStore store(tmp.path() / "map.db");
  put_real_package(store, tmp.path(), w, 0, "a", v2());
  const auto only_a = MapBuilder{}.build(store, {});
  ASSERT_EQ(only_a.status, MapBuildResult::Status::Published) << only_a.error;
  put_real_package(store, tmp.path(), w, 1, "b", v2(), Eigen::Vector2d(30.0, 5.0), 10.0);
  MapBuildRequest loo;
  loo.excluded_drive_ids = {"b"};
  loo.make_current = false;
  const auto r = MapBuilder{}.build(store, loo);
  ASSERT_EQ(r.status, MapBuildResult::Status::Published) << r.error;
  EXPECT_EQ(etags(store, r.version), etags(store, only_a.version));
  // b went into the sums (they are the store's, not the version's) and stays there.
  EXPECT_EQ(store.gridmap_sum_inputs().size(), 2U);
  const auto all = MapBuilder{}.build(store, {});
  ASSERT_EQ(all.status, MapBuildResult::Status::Published) << all.error;
  EXPECT_EQ(all.stats.gridmap_drives_added, 0);
  EXPECT_NE(etags(store, all.version), etags(store, only_a.version));
}

}  // namespace
}  // namespace polmap::mapping
