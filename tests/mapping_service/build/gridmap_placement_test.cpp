// An aligned drive's gridmap in the merged gridmap sums: it goes in where its placement puts
// it, and when a later build moves its alignment beyond the threshold it is taken out the
// way it went in and added again, so the sums equal those of a store that only ever saw the
// new placement; a smaller move leaves the sums alone, and taking out another drive
// recomputes shared tiles with the stored placement.
#include <gtest/gtest.h>

#include <cmath>
#include <optional>

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

using Shift = std::optional<Eigen::Vector2d>;  // a drive's correction; none: as uploaded

/// Drives a and b of world w in a store (b 20 m east, 5 m north of a).
void put_drives(MapStore& store, const fs::path& dir, const World& w, bool with_b = true) {
  put_real_package(store, dir, w, 0, "a", package_format(2));
  if (with_b) {
    put_real_package(store, dir, w, 1, "b", package_format(2), Eigen::Vector2d(20.0, 5.0), 10.0);
  }
}

/// One update of `store`'s sums with drives a and b placed as given.
detail::GridmapSumsUpdate update(MapStore& store, std::int64_t version, const Shift& a,
                                 const Shift& b) {
  detail::GridmapPlacements p;
  for (const auto& [id, shift] : {std::pair{"a", a}, std::pair{"b", b}}) {
    const auto d = store.get_drive(id);
    if (d && shift) p.by_hash.emplace(d->content_hash, shifted(store, id, shift->x(), shift->y()));
  }
  return detail::update_gridmap_sums(store, version, store.list_drives(), hashes(store), {}, p);
}

/// The sums of a store that only ever saw these placements.
std::map<GridmapSumKey, std::string> sums_of_fresh_store(const World& w, const Shift& a,
                                                         const Shift& b, bool with_b = true) {
  TempDir tmp;
  SqliteMapStore fresh(tmp.path() / "map.db");
  put_drives(fresh, tmp.path(), w, with_b);
  (void)update(fresh, 1, a, b);
  return sums(fresh);
}

TEST(GridmapPlacement, AMovedAlignmentIsTakenOutAndAddedWhereItNowBelongs) {
  TempDir tmp;
  const World w = make_world(4, 50, 50.0);
  SqliteMapStore store(tmp.path() / "map.db");
  put_drives(store, tmp.path(), w);
  const std::string hash_a = store.get_drive("a")->content_hash;

  // Build 1: drive a aligned 0.3 m east, b as uploaded.
  auto up = update(store, 1, Eigen::Vector2d(0.3, 0.0), {});
  EXPECT_EQ(up.drives_added, 2);
  EXPECT_EQ(up.drives_replaced, 0);
  EXPECT_TRUE(up.errors.empty());
  const Eigen::Vector2d c1 = centroid_m(store);

  // Build 2: moved by 1 cm: below the threshold, nothing is rewritten.
  up = update(store, 2, Eigen::Vector2d(0.31, 0.0), {});
  EXPECT_EQ(up.drives_added + up.drives_replaced + up.tiles_written, 0);

  // Build 3: now 0.6 m north instead: re-placed.
  up = update(store, 3, Eigen::Vector2d(0.0, 0.6), {});
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
  // A store that only ever saw the new placement holds the same sums, and not those of the
  // first placement (the comparison can tell them apart).
  EXPECT_LT(sums_difference(sums(store), sums_of_fresh_store(w, Eigen::Vector2d(0.0, 0.6), {})),
            1e-5);
  EXPECT_GT(sums_difference(sums(store), sums_of_fresh_store(w, Eigen::Vector2d(0.3, 0.0), {})),
            0.1);

  // Both re-placed in one update: b's old contribution comes out of tiles a is in now.
  up = update(store, 4, Eigen::Vector2d(0.0, -0.4), Eigen::Vector2d(0.5, 0.0));
  EXPECT_EQ(up.drives_replaced, 2);
  EXPECT_LT(sums_difference(sums(store), sums_of_fresh_store(w, Eigen::Vector2d(0.0, -0.4),
                                                             Eigen::Vector2d(0.5, 0.0))),
            1e-5);

  // Drive b deleted: its tiles are recomputed with a where its stored placement puts it.
  ASSERT_TRUE(store.delete_drive("b"));
  up = update(store, 5, {}, {});
  EXPECT_EQ(up.drives_removed, 1);
  // Tiles only b touched stay as (empty) tiles; the rest is a's alone, where it was placed.
  EXPECT_LT(
      sums_difference(sums(store), sums_of_fresh_store(w, Eigen::Vector2d(0.0, -0.4), {}, false)),
      1e-5);
}

}  // namespace
}  // namespace polmap::mapping
