// An aligned drive's gridmap in the merged gridmap sums: it goes in where its placement puts
// it, and when a later build moves its alignment beyond the threshold it is taken out the
// way it went in and added again, so the sums equal those of a store that only ever saw the
// new placement; a smaller move leaves the sums alone, and taking out another drive
// recomputes shared tiles with the stored placement.
#include <gtest/gtest.h>

#include <cmath>

#include "builder_fixtures.hpp"
#include "gridmap_build.hpp"
#include "polmap/mapping_service/drive_placement.hpp"
#include "polmap/mapping_service/gridmap_sums_codec.hpp"

namespace polmap::mapping {
namespace {
using namespace builder_fixtures;  // NOLINT: test fixtures

struct TempDir : polmap::test::TestDir {
  TempDir() : TestDir("gridmap_placement") {}
};

PackageWriteOptions v2() {
  PackageWriteOptions o;
  o.format_version = 2;
  return o;
}

// Drive `id` corrected by (dx, dy) everywhere, in the frame of kWorldOrigin.
DrivePlacement shifted(const MapStore& store, const std::string& id, double dx, double dy) {
  const tiles::LocalFrame frame(kWorldOrigin);
  DriveCorrection c;
  double s = 0.0;
  for (const TrajectorySample& t : store.drive_trajectory(id)) {
    const Eigen::Vector2d p = frame.to_local(t.lat_deg, t.lon_deg);
    if (!c.path_m.empty()) s += (p - c.path_m.back()).norm();
    c.path_m.push_back(p);
    c.path_s_m.push_back(s);
    c.node_s_m.push_back(s);
    c.node_position_m.push_back(p);
    c.node_correction.emplace_back(dx, dy, 0.0);
  }
  return drive_placement(frame, c);
}

std::map<GridmapSumKey, std::string> sums(const MapStore& store) {
  std::map<GridmapSumKey, std::string> out;
  for (const auto& r : store.gridmap_sums_in(0, 0, 1 << 20, 1 << 20)) {
    out[{static_cast<PolLevel>(r.level), r.x, r.y}] = r.data;
  }
  return out;
}

// N-weighted centroid of all sums, in metres east and north of the first tile's corner.
Eigen::Vector2d centroid_m(const MapStore& store) {
  double n = 0.0;
  Eigen::Vector2d acc = Eigen::Vector2d::Zero();
  const double cell_m =
      40075016.686 * std::cos(kWorldOrigin.lat_deg * M_PI / 180.0) / (1 << 20) / kSumTileCells;
  for (const auto& r : store.gridmap_sums_in(0, 0, 1 << 20, 1 << 20)) {
    const GridmapSumTile t = decode_gridmap_sum_tile(r.data, "test");
    for (int y = 0; y < kSumTileCells; ++y) {
      for (int x = 0; x < kSumTileCells; ++x) {
        const double w = t.at(0, x, y);
        if (w <= 0.0) continue;
        n += w;
        acc += w * Eigen::Vector2d((r.x * kSumTileCells + x) * cell_m,
                                   -(r.y * kSumTileCells + y) * cell_m);
      }
    }
  }
  return acc / n;
}

// Largest difference between two stores' sums, relative to the value (recomputing a tile
// sums a drive's blocks in another order than adding it did: float rounding).
double sums_difference(const std::map<GridmapSumKey, std::string>& a,
                       const std::map<GridmapSumKey, std::string>& b) {
  double worst = 0.0;
  std::set<GridmapSumKey> keys;
  for (const auto& [k, v] : a) keys.insert(k);
  for (const auto& [k, v] : b) keys.insert(k);
  for (const auto& k : keys) {
    const GridmapSumTile ta =
        a.contains(k) ? decode_gridmap_sum_tile(a.at(k), "a") : GridmapSumTile(k.level);
    const GridmapSumTile tb =
        b.contains(k) ? decode_gridmap_sum_tile(b.at(k), "b") : GridmapSumTile(k.level);
    for (int p = 0; p < ta.planes(); ++p) {
      for (int y = 0; y < kSumTileCells; ++y) {
        for (int x = 0; x < kSumTileCells; ++x) {
          const double va = ta.at(p, x, y), vb = tb.at(p, x, y);
          worst = std::max(worst, std::abs(va - vb) / std::max(1.0, std::abs(va)));
        }
      }
    }
  }
  return worst;
}

std::set<std::string> hashes(const MapStore& store) {
  std::set<std::string> out;
  for (const auto& d : store.list_drives()) out.insert(d.content_hash);
  return out;
}

TEST(GridmapPlacement, AMovedAlignmentIsTakenOutAndAddedWhereItNowBelongs) {
  TempDir tmp;
  const World w = make_world(4, 50, 50.0);
  SqliteMapStore store(tmp.path() / "map.db");
  put_real_package(store, tmp.path(), w, 0, "a", v2());
  put_real_package(store, tmp.path(), w, 1, "b", v2(), Eigen::Vector2d(20.0, 5.0), 10.0);
  const std::string hash_a = store.get_drive("a")->content_hash;

  // Build 1: drive a aligned 0.3 m east.
  detail::GridmapPlacements first;
  first.by_hash.emplace(hash_a, shifted(store, "a", 0.3, 0.0));
  auto up = detail::update_gridmap_sums(store, 1, store.list_drives(), hashes(store), {}, first);
  EXPECT_EQ(up.drives_added, 2);
  EXPECT_EQ(up.drives_replaced, 0);
  EXPECT_TRUE(up.errors.empty());
  const Eigen::Vector2d c1 = centroid_m(store);

  // Build 2: moved by 1 cm: below the threshold, nothing is rewritten.
  detail::GridmapPlacements small;
  small.by_hash.emplace(hash_a, shifted(store, "a", 0.31, 0.0));
  up = detail::update_gridmap_sums(store, 2, store.list_drives(), hashes(store), {}, small);
  EXPECT_EQ(up.drives_added + up.drives_replaced + up.tiles_written, 0);

  // Build 3: now 0.6 m north instead: re-placed.
  detail::GridmapPlacements moved;
  moved.by_hash.emplace(hash_a, shifted(store, "a", 0.0, 0.6));
  up = detail::update_gridmap_sums(store, 3, store.list_drives(), hashes(store), {}, moved);
  EXPECT_EQ(up.drives_replaced, 1);
  EXPECT_EQ(up.drives_added, 0);
  EXPECT_TRUE(up.errors.empty());
  // Half of the N is drive a's (both drives are the same strip): the centroid moves by half
  // of a's move, (-0.3, +0.6) / 2.
  const Eigen::Vector2d c3 = centroid_m(store);
  EXPECT_NEAR(c3.x() - c1.x(), -0.15, 0.03);
  EXPECT_NEAR(c3.y() - c1.y(), 0.30, 0.03);
  const auto inputs = store.gridmap_sum_inputs();
  ASSERT_EQ(inputs.size(), 2U);
  for (const auto& in : inputs) {
    EXPECT_EQ(in.placement.empty(), in.content_hash != hash_a);
    if (in.content_hash == hash_a) {
      EXPECT_LT(placement_difference_m(decode_drive_placement(in.placement, "test"),
                                       shifted(store, "a", 0.0, 0.6)),
                0.002);
    }
  }

  // A store that only ever saw the new placement holds the same sums.
  TempDir tmp2;
  SqliteMapStore fresh(tmp2.path() / "map.db");
  put_real_package(fresh, tmp2.path(), w, 0, "a", v2());
  put_real_package(fresh, tmp2.path(), w, 1, "b", v2(), Eigen::Vector2d(20.0, 5.0), 10.0);
  detail::GridmapPlacements direct;
  direct.by_hash.emplace(fresh.get_drive("a")->content_hash, shifted(fresh, "a", 0.0, 0.6));
  (void)detail::update_gridmap_sums(fresh, 1, fresh.list_drives(), hashes(fresh), {}, direct);
  const auto before_delete = sums(store);
  EXPECT_LT(sums_difference(before_delete, sums(fresh)), 1e-5);
  // ... and not those of the first placement (the test can tell them apart).
  TempDir tmp4;
  SqliteMapStore first_only(tmp4.path() / "map.db");
  put_real_package(first_only, tmp4.path(), w, 0, "a", v2());
  put_real_package(first_only, tmp4.path(), w, 1, "b", v2(), Eigen::Vector2d(20.0, 5.0), 10.0);
  detail::GridmapPlacements old;
  old.by_hash.emplace(first_only.get_drive("a")->content_hash, shifted(first_only, "a", 0.3, 0.0));
  (void)detail::update_gridmap_sums(first_only, 1, first_only.list_drives(), hashes(first_only), {},
                                    old);
  EXPECT_GT(sums_difference(before_delete, sums(first_only)), 0.1);

  // Both re-placed in one update: b's tiles are recomputed with a where a now is.
  detail::GridmapPlacements both;
  both.by_hash.emplace(hash_a, shifted(store, "a", 0.0, -0.4));
  both.by_hash.emplace(store.get_drive("b")->content_hash, shifted(store, "b", 0.5, 0.0));
  up = detail::update_gridmap_sums(store, 4, store.list_drives(), hashes(store), {}, both);
  EXPECT_EQ(up.drives_replaced, 2);
  TempDir tmp5;
  SqliteMapStore both_fresh(tmp5.path() / "map.db");
  put_real_package(both_fresh, tmp5.path(), w, 0, "a", v2());
  put_real_package(both_fresh, tmp5.path(), w, 1, "b", v2(), Eigen::Vector2d(20.0, 5.0), 10.0);
  detail::GridmapPlacements both_direct;
  both_direct.by_hash.emplace(both_fresh.get_drive("a")->content_hash,
                              shifted(both_fresh, "a", 0.0, -0.4));
  both_direct.by_hash.emplace(both_fresh.get_drive("b")->content_hash,
                              shifted(both_fresh, "b", 0.5, 0.0));
  (void)detail::update_gridmap_sums(both_fresh, 1, both_fresh.list_drives(), hashes(both_fresh), {},
                                    both_direct);
  EXPECT_LT(sums_difference(sums(store), sums(both_fresh)), 1e-5);

  // Drive b deleted: its tiles are recomputed with a where its stored placement puts it.
  ASSERT_TRUE(store.delete_drive("b"));
  up = detail::update_gridmap_sums(store, 5, store.list_drives(), hashes(store), {}, {});
  EXPECT_EQ(up.drives_removed, 1);
  TempDir tmp3;
  SqliteMapStore only_a(tmp3.path() / "map.db");
  put_real_package(only_a, tmp3.path(), w, 0, "a", v2());
  detail::GridmapPlacements a_only;
  a_only.by_hash.emplace(only_a.get_drive("a")->content_hash, shifted(only_a, "a", 0.0, -0.4));
  (void)detail::update_gridmap_sums(only_a, 1, only_a.list_drives(), hashes(only_a), {}, a_only);
  // Tiles only b touched stay as (empty) tiles; the rest is a's alone, where it was placed.
  EXPECT_LT(sums_difference(sums(store), sums(only_a)), 1e-5);
}

}  // namespace
}  // namespace polmap::mapping
