// Partitioned map builds (MapBuildRequest::partition, build_worker.hpp): the same drives
// give the same landmarks and tile bytes whether one process runs the jobs or several
// workers share them; a worker that dies holding a job (or stalls past its lease) loses
// nothing and commits nothing; the partitioned map agrees with the one-frame build; a
// second build reuses the unchanged tiles.
#include <gtest/gtest.h>

#include <atomic>
#include <map>
#include <thread>

#include "builder_fixtures.hpp"
#include "polmap/mapping_service/build_worker.hpp"
#include "polmap/mapping_service/map_builder.hpp"

namespace polmap::mapping {
namespace {
using namespace builder_fixtures;  // NOLINT: test fixtures

struct TempDir : polmap::test::TestDir {
  TempDir() : TestDir("partitioned_build") {}
};

constexpr double kExtentM = 1000.0;  // about 2.5 x 2.5 regions of zoom 16 (403 m at 48.8 N)

/// A lawn-mower path over the world: rows `spacing` apart.
std::vector<Eigen::Vector2d> lawnmower(double spacing, double offset) {
  std::vector<Eigen::Vector2d> p;
  const double h = kExtentM / 2;
  int k = 0;
  for (double y = -h + offset; y <= h; y += spacing, ++k) {
    p.emplace_back(k % 2 == 0 ? -h : h, y);
    p.emplace_back(k % 2 == 0 ? h : -h, y);
  }
  return p;
}

void put_drives(MapStore& store, const fs::path& tmp, const World& w, int n) {
  for (int d = 0; d < n; ++d) {
    std::string name = "d";
    name += std::to_string(d);
    put_drive_along(store, tmp, w, name, 100 + d, {-kExtentM / 2, -kExtentM / 2},
                    {kExtentM / 2, kExtentM / 2}, lawnmower(80.0, 10.0 + 7.0 * d), 30, 1000.0 * d);
  }
}

MapBuildRequest partitioned() {
  MapBuildRequest r;
  r.partition = BuildPartition{};
  r.partition->zoom = 16;
  return r;
}

/// What a version serves: landmarks by key (geometry and attributes) and tiles by key.
struct Served {
  std::map<std::int64_t, std::string> landmarks;
  std::map<std::pair<int, tiles::TileKey>, std::string> tiles;
  bool operator==(const Served&) const = default;
};

Served served(const MapStore& s, std::int64_t v) {
  Served out;
  const LandmarkSet l = s.landmarks_in(v, std::nullopt, true);
  for (const auto& p : l.points) {
    std::ostringstream o;
    o.precision(10);
    o << p.position.lat_deg << ' ' << p.position.lon_deg << ' ' << static_cast<int>(p.scattering)
      << ' ' << p.support_drives << ' ' << p.spread_m << ' ' << p.support.size();
    out.landmarks[p.key] = o.str();
  }
  for (const auto& ln : l.lines) {
    std::ostringstream o;
    o.precision(10);
    for (const auto& g : ln.polyline) o << g.lat_deg << ',' << g.lon_deg << ' ';
    o << ln.support_drives << ' ' << ln.spread_m << ' ' << ln.support.size();
    out.landmarks[ln.key] = o.str();
  }
  for (const TileLayer layer :
       {TileLayer::Localization, TileLayer::Gridmap, TileLayer::GridmapMechanism}) {
    for (const auto& t : s.list_tiles(v, layer)) {
      out.tiles[{static_cast<int>(layer), t.key}] = t.etag;
    }
  }
  return out;
}

/// Workers that loop until `version` is no longer building.
void run_workers(MapStore& store, std::int64_t version, int n, double lease_s = 30.0) {
  std::vector<std::thread> ts;
  for (int i = 0; i < n; ++i) {
    ts.emplace_back([&, i] {
      std::string id = "w";
      id += std::to_string(i);
      const BuildWorker w({.worker_id = id, .lease_s = lease_s, .renew_interval_s = lease_s / 5});
      for (;;) {
        const auto info = store.get_map_version(version);
        if (!info || info->status != MapVersionStatus::Building) return;
        if (w.run_one(store).status == BuildJobRun::Status::Idle) {
          std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
      }
    });
  }
  for (auto& t : ts) t.join();
}

/// The build of `version` with its jobs left to workers (BuildControl::run_jobs = false).
MapBuildResult enqueue_only(MapStore& store, std::int64_t version, const MapBuildRequest& r,
                            std::thread& driver) {
  MapBuildResult result;
  BuildControl c;
  c.run_jobs = false;
  c.poll_interval_s = 0.02;
  driver = std::thread(
      [&store, version, r, c, &result] { result = MapBuilder{}.run(store, version, r, c); });
  // Until the jobs are enqueued.
  while (store.build_jobs(version).empty())
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  return result;
}

/// The world, and a reference store built once by one process (MapBuilder::build runs
/// the partitioned build's jobs itself).
class PartitionedBuild : public ::testing::Test {
 protected:
  struct Reference {
    TempDir tmp;
    World world = make_world(7, 1200, kExtentM);
    std::unique_ptr<SqliteMapStore> store;
    std::int64_t version = 0;
  };
  static Reference& reference() {
    static Reference* r = [] {
      auto* x = new Reference();
      x->store = std::make_unique<SqliteMapStore>(x->tmp.path() / "reference.db");
      put_drives(*x->store, x->tmp.path(), x->world, 3);
      const MapBuildResult b = MapBuilder{}.build(*x->store, partitioned());
      if (b.status != MapBuildResult::Status::Published) {
        throw std::runtime_error("reference build: " + b.error);
      }
      x->version = b.version;
      return x;
    }();
    return *r;
  }
  void SetUp() override {
    Reference& r = reference();
    world_ = &r.world;
    reference_ = r.store.get();
    reference_version_ = r.version;
  }
  const World* world_ = nullptr;
  SqliteMapStore* reference_ = nullptr;
  std::int64_t reference_version_ = 0;
};

TEST_F(PartitionedBuild, CutsTheMapIntoRegionsWithLinesClippedAtTheirBorders) {
  const auto jobs = reference_->build_jobs(reference_version_);
  int regions = 0;
  for (const auto& j : jobs) {
    EXPECT_EQ(j.state, BuildJobState::Done) << j.kind << " " << j.error;
    if (j.kind == "region") ++regions;
  }
  EXPECT_GE(regions, 9);  // the 1 km square and its halo over zoom-16 regions
  EXPECT_EQ(jobs.back().kind, "publish");
  const LandmarkSet l = reference_->landmarks_in(reference_version_, std::nullopt, false);
  ASSERT_GT(l.points.size(), 500U);
  ASSERT_GT(l.lines.size(), 20U);
  // Every line lies in one region (closed box: a clipped end sits on the border).
  for (const auto& ln : l.lines) {
    const tiles::TileKey r = tiles::tile_at(ln.polyline[0].lat_deg, ln.polyline[0].lon_deg, 16);
    bool in_one = false;
    for (int dx = -1; dx <= 1 && !in_one; ++dx) {
      for (int dy = -1; dy <= 1 && !in_one; ++dy) {
        const auto b = tiles::tile_bounds({16, r.x + dx, r.y + dy});
        bool all = true;
        for (const auto& g : ln.polyline) {
          all = all && g.lat_deg >= b.min_lat_deg - 1e-8 && g.lat_deg <= b.max_lat_deg + 1e-8 &&
                g.lon_deg >= b.min_lon_deg - 1e-8 && g.lon_deg <= b.max_lon_deg + 1e-8;
        }
        in_one = all;
      }
    }
    EXPECT_TRUE(in_one) << "line " << ln.key << " crosses a region border";
  }
  const auto info = reference_->get_map_version(reference_version_);
  EXPECT_EQ(
      info->statistics.value("tiles_total", 0),
      static_cast<int>(reference_->list_tiles(reference_version_, TileLayer::Localization).size()));
  EXPECT_EQ(info->statistics["partition"].value("regions", 0), regions);
}

TEST_F(PartitionedBuild, ThreeWorkersGiveTheSameMapAsOneProcess) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  put_drives(store, tmp.path(), *world_, 3);
  const std::int64_t v = MapBuilder{}.begin(store, partitioned());
  std::thread driver;
  const MapBuildResult& result = enqueue_only(store, v, partitioned(), driver);
  run_workers(store, v, 3);
  driver.join();
  ASSERT_EQ(result.status, MapBuildResult::Status::Published) << result.error;
  std::set<std::string> workers;
  for (const auto& j : store.build_jobs(v)) workers.insert(j.worker);
  EXPECT_GE(workers.size(), 2U);     // the jobs were shared
  ASSERT_EQ(v, reference_version_);  // same number: tiles carry it
  EXPECT_TRUE(served(store, v) == served(*reference_, reference_version_));
}

TEST_F(PartitionedBuild, AWorkerThatDiesHoldingAJobLosesNothing) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  put_drives(store, tmp.path(), *world_, 3);
  const std::int64_t v = MapBuilder{}.begin(store, partitioned());
  std::thread driver;
  const MapBuildResult& result = enqueue_only(store, v, partitioned(), driver);
  // A worker claims a job with a short lease and dies: no renewal, no commit.
  const auto dead = store.claim_build_job("dead", 0.3, v);
  ASSERT_TRUE(dead);
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  run_workers(store, v, 2);
  driver.join();
  ASSERT_EQ(result.status, MapBuildResult::Status::Published) << result.error;
  BuildJob again;
  for (const auto& j : store.build_jobs(v)) {
    if (j.id == dead->id) again = j;
  }
  EXPECT_EQ(again.state, BuildJobState::Done);
  EXPECT_EQ(again.attempt, 2);  // claimed again once the lease had expired
  EXPECT_NE(again.worker, "dead");
  // Were it only stalled, its late commit would be refused and write nothing.
  BuildJobOutput late;
  StoredPointLandmark junk;
  junk.key = 42;
  junk.position = {48.7758, 9.1829, 0.0};
  late.points.push_back(junk);
  EXPECT_FALSE(store.complete_build_job(dead->id, dead->attempt, late));
  EXPECT_TRUE(served(store, v) == served(*reference_, reference_version_));
}

TEST_F(PartitionedBuild, AgreesWithTheOneFrameBuild) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  put_drives(store, tmp.path(), *world_, 3);
  MapBuildRequest one = partitioned();
  one.partition.reset();
  const MapBuildResult r = MapBuilder{}.build(store, one);
  ASSERT_EQ(r.status, MapBuildResult::Status::Published) << r.error;
  const LandmarkSet a = store.landmarks_in(r.version, std::nullopt, false);
  const LandmarkSet b = reference_->landmarks_in(reference_version_, std::nullopt, false);
  // Lines: cut at region borders, the same total length.
  const tiles::LocalFrame f(kWorldOrigin);
  auto length = [&](const std::vector<StoredLineLandmark>& ls) {
    double m = 0.0;
    for (const auto& l : ls) {
      for (std::size_t i = 0; i + 1 < l.polyline.size(); ++i) {
        m += (f.to_local(l.polyline[i + 1]) - f.to_local(l.polyline[i])).norm();
      }
    }
    return m;
  };
  // Points: the same landmarks (a region's halo holds every candidate and pass its
  // landmarks depend on), up to a rare flip of the 1e-8 degree quantization between frames.
  std::map<std::int64_t, const StoredPointLandmark*> by_key;
  for (const auto& p : b.points) by_key[p.key] = &p;
  std::size_t same = 0;
  for (const auto& p : a.points) {
    const auto it = by_key.find(p.key);
    if (it != by_key.end() && it->second->support_drives == p.support_drives) ++same;
  }
  std::printf("points: one frame %zu, partitioned %zu, equal %zu; lines %zu / %zu, %.1f / %.1f m\n",
              a.points.size(), b.points.size(), same, a.lines.size(), b.lines.size(),
              length(a.lines), length(b.lines));
  EXPECT_GE(static_cast<double>(same), 0.99 * static_cast<double>(a.points.size()))
      << same << " of " << a.points.size() << " point landmarks equal";
  EXPECT_NEAR(static_cast<double>(b.points.size()), static_cast<double>(a.points.size()),
              0.01 * static_cast<double>(a.points.size()));
  EXPECT_GE(b.lines.size(), a.lines.size());
  EXPECT_NEAR(length(b.lines), length(a.lines), 0.01 * length(a.lines));
}

/// Three drives built, then a fourth over one corner only and a second build.
struct TwoBuilds {
  MapBuildResult r1, r2;
};
TwoBuilds build_then_add_a_corner_drive(MapStore& store, const fs::path& tmp, const World& w) {
  put_drives(store, tmp, w, 3);
  TwoBuilds b;
  b.r1 = MapBuilder{}.build(store, partitioned());
  const double h = kExtentM / 2;
  put_drive_along(store, tmp, w, "corner", 200, {-h, -h}, {-h + 150, -h + 150},
                  {{-h, -h + 20}, {-h + 150, -h + 20}}, 5, 9000.0);
  b.r2 = MapBuilder{}.build(store, partitioned());
  return b;
}

TEST_F(PartitionedBuild, ASecondBuildKeepsTheBlobsOfUnchangedTiles) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const auto [r1, r2] = build_then_add_a_corner_drive(store, tmp.path(), *world_);
  ASSERT_EQ(r1.status, MapBuildResult::Status::Published) << r1.error;
  ASSERT_EQ(r2.status, MapBuildResult::Status::Published) << r2.error;
  const auto t1 = served(store, r1.version).tiles, t2 = served(store, r2.version).tiles;
  int same = 0, changed = 0;
  for (const auto& [k, etag] : t2) {
    if (k.first != static_cast<int>(TileLayer::Localization)) continue;
    const auto it = t1.find(k);
    (it != t1.end() && it->second == etag ? same : changed) += 1;
  }
  EXPECT_GT(same, changed);  // far from the corner nothing changed
  EXPECT_GT(changed, 0);
  const auto info = store.get_map_version(r2.version);
  EXPECT_EQ(info->statistics.value("previous_version", 0), r1.version);
  EXPECT_GT(info->statistics.value("tiles_reused", 0), 0);
}

TEST_F(PartitionedBuild, ANewDriveRebuildsOnlyTheRegionsItCanChange) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const auto [r1, r2] = build_then_add_a_corner_drive(store, tmp.path(), *world_);
  ASSERT_EQ(r1.status, MapBuildResult::Status::Published) << r1.error;
  ASSERT_EQ(r2.status, MapBuildResult::Status::Published) << r2.error;
  auto region_jobs = [&](std::int64_t v) {
    int n = 0;
    for (const auto& j : store.build_jobs(v)) n += j.kind == "region" ? 1 : 0;
    return n;
  };
  const auto s1 = store.get_map_version(r1.version)->statistics;
  const auto s2 = store.get_map_version(r2.version)->statistics;
  const int carried = s2["partition"].value("regions_carried", 0);
  EXPECT_GT(carried, 0);
  EXPECT_LT(region_jobs(r2.version), region_jobs(r1.version));
  EXPECT_EQ(region_jobs(r2.version) + carried, region_jobs(r1.version));
  EXPECT_EQ(s2.value("incremental_from", 0), r1.version);

  // The same drives built in full: the same landmarks, tiles and counts.
  MapBuildRequest full = partitioned();
  full.incremental = false;
  const MapBuildResult r3 = MapBuilder{}.build(store, full);
  ASSERT_EQ(r3.status, MapBuildResult::Status::Published) << r3.error;
  const auto s3 = store.get_map_version(r3.version)->statistics;
  EXPECT_EQ(s3["partition"].value("regions_carried", 0), 0);
  const Served a = served(store, r2.version), b = served(store, r3.version);
  EXPECT_EQ(a.landmarks.size(), b.landmarks.size());
  EXPECT_TRUE(a.landmarks == b.landmarks);
  std::set<std::pair<int, tiles::TileKey>> ka, kb;
  for (const auto& [k, e] : a.tiles) ka.insert(k);
  for (const auto& [k, e] : b.tiles) kb.insert(k);
  EXPECT_TRUE(ka == kb);
  for (const char* key : {"point_landmarks", "line_landmarks", "drives_used", "tiles_total"}) {
    EXPECT_EQ(s2.value(key, -1), s3.value(key, -2)) << key;
  }
  // The new drive changed its corner (support of the landmarks it saw), nothing else.
  EXPECT_FALSE(served(store, r1.version).landmarks == a.landmarks);
  EXPECT_GT(s2.value("tiles_reused", 0), s1.value("tiles_total", 0) / 2);
}

}  // namespace
}  // namespace polmap::mapping
