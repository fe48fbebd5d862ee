// Drive paths of SqliteMapStore files stored before migration 5 (no packed path): simplified
// from the decimated samples on read. Paths simplified at ingest are tested on every backend
// in store_contract_drives_test.cpp.
#include <gtest/gtest.h>

#include <fstream>

#include "mapping_service/store/exec_sql.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {
namespace fs = std::filesystem;

const GeoPoint kOrigin{48.7758, 9.1829, 0.0};

/// 300 m east, 200 m north, then back 100 m south (a turn back on itself), one sample
/// per metre, 3 cm of lateral wobble.
DrivePackage l_drive(const std::string& id) {
  const tiles::LocalFrame f(kOrigin);
  DrivePackage p;
  p.manifest.drive_id = id;
  p.manifest.origin = kOrigin;
  std::vector<Eigen::Vector2d> xy;
  for (int i = 0; i <= 300; ++i) xy.emplace_back(i, 0.03 * std::sin(i));
  for (int i = 1; i <= 200; ++i) xy.emplace_back(300.0 + 0.03 * std::sin(i), i);
  for (int i = 199; i >= 100; --i) xy.emplace_back(300.0, i);
  for (std::size_t k = 0; k < xy.size(); ++k) {
    const GeoPoint g = f.to_geo(xy[k]);
    TrajectorySample t;
    t.time_s = 0.1 * static_cast<double>(k);
    t.lat_deg = g.lat_deg;
    t.lon_deg = g.lon_deg;
    p.trajectory.push_back(t);
  }
  return p;
}

void put(SqliteMapStore& store, const fs::path& dir, const DrivePackage& p) {
  const std::string bytes = write_ustar({{kManifestFileName, p.manifest.drive_id}});
  const fs::path tar = dir / (p.manifest.drive_id + ".tar");
  std::ofstream(tar, std::ios::binary) << bytes;
  ASSERT_EQ(store.put_drive(p, tar, content_etag(bytes)).status, PutDriveResult::Status::Inserted);
}

void expect_l_path(const std::vector<GeoPoint>& path) {
  const tiles::LocalFrame f(kOrigin);
  ASSERT_EQ(path.size(), 4U);
  const std::vector<Eigen::Vector2d> corners{{0, 0}, {300, 0}, {300, 200}, {300, 100}};
  for (std::size_t i = 0; i < corners.size(); ++i) {
    EXPECT_LT((f.to_local(path[i]) - corners[i]).norm(), 0.05) << i;
  }
}

TEST(DrivePath, DrivesStoredBeforeThePathColumnAreSimplifiedOnRead) {
  polmap::test::TestDir tmp("drive_path");
  const fs::path db = tmp.path() / "map.db";
  {
    SqliteMapStore store(db);
    put(store, tmp.path(), l_drive("old"));
  }
  sqlite3* h = nullptr;
  ASSERT_EQ(sqlite3_open(db.c_str(), &h), SQLITE_OK);
  ASSERT_EQ(
      sqlite3_exec(h, "UPDATE drive_trajectories SET path_blob = NULL", nullptr, nullptr, nullptr),
      SQLITE_OK);
  sqlite3_close(h);
  SqliteMapStore store(db);
  expect_l_path(store.drive_path("old"));
}

}  // namespace
}  // namespace polmap::mapping
