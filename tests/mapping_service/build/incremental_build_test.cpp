// Incremental builds: a drive added to one end of the map rebuilds only the area it can
// influence; the result equals a full build (landmarks, support, tiles), the rest is
// copied, and deleting the older version keeps the copies' support links.
#include <gtest/gtest.h>

#include <fstream>
#include <random>
#include <set>

#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {
namespace fs = std::filesystem;

const GeoPoint kOrigin{48.7758, 9.1829, 0.0};

/// Poles every 10 m, 6 m left and right of a 3 km road along x, and one wall per 100 m.
struct Road {
  std::vector<Eigen::Vector2d> poles;
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls;
};
Road road() {
  Road r;
  for (double x = 0; x <= 3000; x += 10) r.poles.emplace_back(x, (int(x) / 10) % 2 ? 6.0 : -6.0);
  for (double x = 20; x < 3000; x += 100) r.walls.push_back({{x, 9.0}, {x + 30, 9.0}});
  return r;
}

/// A drive along the road from 0 to max_x, seeing everything with ±3 cm noise.
void put_drive(SqliteMapStore& store, const fs::path& dir, int k, double max_x) {
  const tiles::LocalFrame world(kOrigin);
  DrivePackage p;
  // Names from a table (GCC 12 warns falsely about string concatenation inlined here).
  static const char* const kDrives[] = {"d0", "d1", "d2", "d3", "d4", "d5"};
  static const char* const kVehicles[] = {"v0", "v1"};
  p.manifest.drive_id = kDrives[k];
  p.manifest.vehicle_id = kVehicles[k % 2];
  p.manifest.origin = kOrigin;
  p.manifest.start_time_s = 1000.0 * (k + 1);
  for (double x = 0; x <= max_x; x += 2.0) {
    const GeoPoint g = world.to_geo(Eigen::Vector2d(x, 0.0));
    TrajectorySample t;
    t.time_s = p.manifest.start_time_s + x / 10.0;
    t.lat_deg = g.lat_deg;
    t.lon_deg = g.lon_deg;
    t.speed_mps = 10.0;
    p.trajectory.push_back(t);
  }
  p.manifest.end_time_s = p.trajectory.back().time_s;
  std::mt19937 rng(k);
  std::uniform_real_distribution<double> j(-0.03, 0.03);
  const Road r = road();
  for (const auto& pole : r.poles) {
    if (pole.x() > max_x) continue;
    PointCandidate c;
    c.position_m = pole + Eigen::Vector2d(j(rng), j(rng));
    c.scattering = ScatteringClass::Odd;
    p.points.push_back(c);
  }
  for (const auto& [a, b] : r.walls) {
    if (b.x() > max_x) continue;
    LineCandidate l;
    l.start_m = a + Eigen::Vector2d(j(rng), j(rng));
    l.end_m = b + Eigen::Vector2d(j(rng), j(rng));
    p.lines.push_back(l);
  }
  // The builder reads candidates from the store: a placeholder archive suffices.
  const std::string bytes = write_ustar({{kManifestFileName, p.manifest.drive_id}});
  const fs::path tar = dir / (p.manifest.drive_id + ".tar");
  std::ofstream(tar, std::ios::binary) << bytes;
  ASSERT_EQ(store.put_drive(p, tar, content_etag(bytes)).status, PutDriveResult::Status::Inserted);
}

MapBuildRequest request(bool incremental) {
  MapBuildRequest r;
  r.build_gridmap = false;
  r.incremental = incremental;
  return r;
}

std::map<std::int64_t, std::vector<std::int64_t>> support_by_key(const LandmarkSet& s) {
  std::map<std::int64_t, std::vector<std::int64_t>> m;
  for (const auto& p : s.points) m[p.key] = p.support;
  for (const auto& l : s.lines) m[l.key] = l.support;
  return m;
}

TEST(IncrementalBuild, AShortDriveRebuildsItsAreaAndEqualsAFullBuild) {
  polmap::test::TestDir tmp("incremental");
  SqliteMapStore store(tmp.path() / "map.db");
  for (int k = 0; k < 3; ++k) put_drive(store, tmp.path(), k, 3000.0);
  const MapBuilder builder;
  const auto v1 = builder.build(store, request(true));
  ASSERT_EQ(v1.status, MapBuildResult::Status::Published) << v1.error;
  EXPECT_FALSE(v1.stats.incremental_from);  // nothing to build on

  put_drive(store, tmp.path(), 3, 300.0);  // the first 300 m only
  const auto v2 = builder.build(store, request(true));
  ASSERT_EQ(v2.status, MapBuildResult::Status::Published) << v2.error;
  ASSERT_EQ(v2.stats.incremental_from, v1.version);
  EXPECT_GT(v2.stats.landmarks_copied, 250);     // of 331: all but the first ~460 m
  EXPECT_LT(v2.stats.point_candidates, 3 * 80);  // only the area's candidates were read
  EXPECT_GT(v2.stats.tiles_reused, 0);
  const auto v3 = builder.build(store, request(false));  // the same, built in full
  ASSERT_EQ(v3.status, MapBuildResult::Status::Published) << v3.error;
  EXPECT_FALSE(v3.stats.incremental_from);

  const LandmarkSet inc = store.landmarks_in(v2.version, std::nullopt, true);
  const LandmarkSet full = store.landmarks_in(v3.version, std::nullopt, true);
  EXPECT_EQ(inc.points.size(), full.points.size());
  EXPECT_EQ(inc.lines.size(), full.lines.size());
  EXPECT_EQ(v2.stats.point_landmarks, static_cast<std::int64_t>(inc.points.size()));
  EXPECT_EQ(v2.stats.line_landmarks, static_cast<std::int64_t>(inc.lines.size()));
  EXPECT_EQ(support_by_key(inc), support_by_key(full));
  int four = 0;
  for (const auto& p : inc.points) four += p.support_drives == 4 ? 1 : 0;
  EXPECT_GT(four, 20);  // the new drive's area was rebuilt with it
  // Tiles: byte-identical content wherever the two builds agree; same keys.
  const auto ti = store.list_tiles(v2.version, TileLayer::Localization);
  const auto tf = store.list_tiles(v3.version, TileLayer::Localization);
  ASSERT_EQ(ti.size(), tf.size());
  for (std::size_t i = 0; i < ti.size(); ++i) {
    EXPECT_EQ(ti[i].key, tf[i].key);
    EXPECT_EQ(ti[i].num_points, tf[i].num_points) << tiles::to_string(ti[i].key);
    EXPECT_EQ(ti[i].num_lines, tf[i].num_lines) << tiles::to_string(ti[i].key);
  }

  // Deleting v1 (whose rows v2's copies share) keeps v2's support links.
  store.delete_map_version(v1.version);
  EXPECT_EQ(support_by_key(store.landmarks_in(v2.version, std::nullopt, true)),
            support_by_key(full));
  // A further incremental build on top of v3 (full) works as well.
  put_drive(store, tmp.path(), 4, 250.0);
  const auto v4 = builder.build(store, request(true));
  ASSERT_EQ(v4.status, MapBuildResult::Status::Published) << v4.error;
  EXPECT_EQ(v4.stats.incremental_from, v3.version);
  store.delete_map_version(v2.version);
  store.delete_map_version(v3.version);
  const LandmarkSet after = store.landmarks_in(v4.version, std::nullopt, true);
  EXPECT_EQ(after.points.size(), full.points.size());
  for (const auto& p : after.points) EXPECT_EQ(p.support.size(), p.support_drives) << p.key;
}

TEST(IncrementalBuild, ChangedParametersOrRemovedDrivesBuildInFull) {
  polmap::test::TestDir tmp("incremental");
  SqliteMapStore store(tmp.path() / "map.db");
  for (int k = 0; k < 3; ++k) put_drive(store, tmp.path(), k, 3000.0);
  const MapBuilder builder;
  ASSERT_EQ(builder.build(store, request(true)).status, MapBuildResult::Status::Published);
  put_drive(store, tmp.path(), 3, 300.0);
  MapBuildRequest other = request(true);
  other.points.max_pair_distance_m = 0.25;
  const auto a = builder.build(store, other);
  EXPECT_FALSE(a.stats.incremental_from);
  ASSERT_TRUE(store.delete_drive("d1"));
  const auto b = builder.build(store, other);
  EXPECT_FALSE(b.stats.incremental_from);
}

}  // namespace
}  // namespace polmap::mapping
