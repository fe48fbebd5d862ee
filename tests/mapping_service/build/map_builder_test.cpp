// MapBuilder against a real SqliteMapStore: consensus over synthetic drives,
// landmarks and localization tiles, incremental tile reuse, leave-one-out,
// region builds, cancellation; fleet gridmap accumulation and PNG tiles.
#include "polmap/mapping_service/map_builder.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <random>
#include <set>

#include "builder_fixtures.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {
namespace fs = std::filesystem;
using namespace builder_fixtures;  // NOLINT: test fixtures

void put(SqliteMapStore& store, const fs::path& dir, const DrivePackage& pkg) {
  // A package-shaped archive with placeholder members (the store does not validate).
  const fs::path tar = dir / (pkg.manifest.drive_id + ".tar");
  std::ofstream(tar, std::ios::binary)
      << write_ustar({{kManifestFileName, "fake package " + pkg.manifest.drive_id},
                      {kGridmapFileName, ""},
                      {kCandidatesFileName, ""}});
  (void)store.put_drive(pkg, tar, content_etag("fake package " + pkg.manifest.drive_id));
}

/// Puts drives "d0", "d1", ... (seeds first_seed, first_seed + 1, ...) that each observe
/// the box [lo, hi] of w with `temporaries` single-drive objects.
void put_drives(SqliteMapStore& store, const fs::path& dir, const World& w, int drives,
                unsigned first_seed, const Eigen::Vector2d& lo, const Eigen::Vector2d& hi,
                int temporaries = 20) {
  for (int d = 0; d < drives; ++d) {
    std::string id = "d";  // not "d" + to_string(d): GCC 12 -O3 warns falsely (-Wrestrict)
    id += std::to_string(d);
    put(store, dir, observe(w, id, first_seed + static_cast<unsigned>(d), lo, hi, temporaries));
  }
}

MapBuildRequest no_gridmap() {
  MapBuildRequest r;
  r.build_gridmap = false;  // the fake packages have no gridmap.tif
  return r;
}

constexpr double kExtent = 600.0;  // spans several z16 tiles

TEST(MapBuilder, BuildsLandmarksAndTilesFromAllDrives) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const World w = make_world(1, 400, kExtent);
  put_drives(store, tmp.path(), w, 3, 10, {-kExtent, -kExtent}, {kExtent, kExtent});

  std::vector<std::string> stages;
  BuildControl ctl;
  ctl.progress = [&](std::string_view s, double) {
    if (stages.empty() || stages.back() != s) stages.emplace_back(s);
  };
  const MapBuildResult r = MapBuilder{}.build(store, no_gridmap(), ctl);
  ASSERT_EQ(r.status, MapBuildResult::Status::Published) << r.error;
  EXPECT_EQ(store.current_map_version(), r.version);
  EXPECT_EQ(r.stats.drives_used, 3);
  EXPECT_EQ(r.stats.point_landmarks, 400);  // temporaries (one drive each) rejected
  EXPECT_EQ(r.stats.line_landmarks, static_cast<std::int64_t>(w.walls.size()));
  EXPECT_EQ(stages.front(), "load");
  EXPECT_EQ(stages.back(), "publish");

  const tiles::LocalFrame world(kWorldOrigin);
  const auto lm = store.landmarks_in(r.version, std::nullopt);
  ASSERT_EQ(lm.points.size(), 400U);
  std::set<std::int64_t> keys;
  for (const auto& p : lm.points) {
    keys.insert(p.key);
    EXPECT_EQ(p.support_drives, 3U);
    EXPECT_EQ(p.support.size(), 3U);
    const Eigen::Vector2d xy = world.to_local(p.position);
    double best = 1e9;
    for (const auto& o : w.objects) best = std::min(best, (o - xy).norm());
    EXPECT_LT(best, 0.1);  // mean of three 3 cm observations
  }
  EXPECT_EQ(keys.size(), 400U);

  // Tiles: every point landmark in exactly one tile, at its geodetic position.
  const auto infos = store.list_tiles(r.version, TileLayer::Localization);
  EXPECT_EQ(static_cast<std::int64_t>(infos.size()), r.stats.tiles_total);
  EXPECT_GT(infos.size(), 2U);
  EXPECT_EQ(r.stats.tiles_written, r.stats.tiles_total);
  std::map<std::int64_t, GeoPoint> by_key;
  for (const auto& p : lm.points) by_key[p.key] = p.position;
  std::size_t tile_points = 0;
  std::set<std::int64_t> tile_line_ids;
  for (const auto& info : infos) {
    const auto t = store.get_tile(r.version, TileLayer::Localization, info.key);
    ASSERT_TRUE(t);
    const auto decoded = tiles::decode_localization_tile(t->payload);
    EXPECT_EQ(decoded.map_version, static_cast<std::uint64_t>(r.version));
    const tiles::LocalFrame tf(tiles::tile_center(info.key));
    for (const auto& p : decoded.points) {
      ++tile_points;
      ASSERT_TRUE(by_key.contains(p.id));
      EXPECT_EQ(tiles::tile_at(by_key[p.id].lat_deg, by_key[p.id].lon_deg, info.key.z), info.key);
      EXPECT_LT((tf.to_local(by_key[p.id]) - p.position_m).norm(), 0.004);
    }
    for (const auto& l : decoded.lines) tile_line_ids.insert(l.id);
  }
  EXPECT_EQ(tile_points, 400U);
  EXPECT_EQ(tile_line_ids.size(), w.walls.size());
  const auto info = store.get_map_version(r.version);
  EXPECT_EQ(info->statistics.at("point_landmarks"), 400);
  EXPECT_EQ(info->parameters.at("tile_zoom"), tiles::kLocalizationZoom);
}

TEST(MapBuilder, ANewDriveRewritesOnlyTheTilesItTouches) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const World w = make_world(2, 600, kExtent);
  put_drives(store, tmp.path(), w, 2, 20, {-kExtent, -kExtent}, {kExtent, kExtent}, 0);
  const MapBuilder builder;
  const auto v1 = builder.build(store, no_gridmap());
  ASSERT_EQ(v1.status, MapBuildResult::Status::Published) << v1.error;

  // Unchanged input: every tile reused, nothing written.
  const auto same = builder.build(store, no_gridmap());
  ASSERT_EQ(same.status, MapBuildResult::Status::Published) << same.error;
  EXPECT_EQ(same.stats.tiles_written, 0);
  EXPECT_EQ(same.stats.tiles_reused, v1.stats.tiles_total);

  // A third drive through a 40 m square only changes the support (and spread)
  // of the landmarks there: only their tiles are rewritten.
  put(store, tmp.path(), observe(w, "d2", 22, {10, 10}, {50, 50}, 0));
  const auto v3 = builder.build(store, no_gridmap());
  ASSERT_EQ(v3.status, MapBuildResult::Status::Published) << v3.error;
  EXPECT_EQ(v3.stats.tiles_total, v1.stats.tiles_total);
  EXPECT_GE(v3.stats.tiles_written, 1);
  EXPECT_LE(v3.stats.tiles_written, 4);  // the square may straddle tile borders
  EXPECT_EQ(v3.stats.tiles_reused + v3.stats.tiles_written, v3.stats.tiles_total);
  const auto t1 = store.list_tiles(v1.version, TileLayer::Localization);
  const auto t3 = store.list_tiles(v3.version, TileLayer::Localization);
  ASSERT_EQ(t1.size(), t3.size());
  int same_etag = 0;
  for (std::size_t i = 0; i < t1.size(); ++i) {
    ASSERT_EQ(t1[i].key, t3[i].key);
    if (t1[i].etag == t3[i].etag) {
      ++same_etag;
      const auto d = tiles::decode_localization_tile(
          store.get_tile(v3.version, TileLayer::Localization, t3[i].key)->payload);
      EXPECT_EQ(d.map_version, static_cast<std::uint64_t>(v1.version));  // content stamp kept
    }
  }
  EXPECT_EQ(same_etag, v3.stats.tiles_reused);
  // The changed tiles carry the new support counts.
  const auto lm = store.landmarks_in(v3.version, std::nullopt);
  int three = 0;
  for (const auto& p : lm.points) three += p.support_drives == 3 ? 1 : 0;
  EXPECT_GT(three, 0);
}

TEST(MapBuilder, LeaveOneOutRegionAndCancellation) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const World w = make_world(3, 300, 300.0);
  put_drives(store, tmp.path(), w, 3, 30, {-200, -200}, {200, 200});
  const MapBuilder builder;
  const auto full = builder.build(store, no_gridmap());
  ASSERT_EQ(full.status, MapBuildResult::Status::Published);

  // Leave-one-out: the map without d0 is built from d1, d2 only and is not current.
  MapBuildRequest loo = no_gridmap();
  loo.excluded_drive_ids = {"d0"};
  loo.make_current = false;
  const auto r = builder.build(store, loo);
  ASSERT_EQ(r.status, MapBuildResult::Status::Published) << r.error;
  EXPECT_EQ(store.current_map_version(), full.version);
  EXPECT_EQ(r.stats.drives_used, 2);
  std::set<std::int64_t> d0_candidates;
  const auto d0 = store.get_drive("d0")->row;
  for (const auto& p : store.candidates_in(std::nullopt).points) {
    if (p.drive == d0) d0_candidates.insert(p.id);
  }
  const auto lm = store.landmarks_in(r.version, std::nullopt);
  EXPECT_EQ(lm.points.size(), 300U);
  for (const auto& p : lm.points) {
    EXPECT_EQ(p.support_drives, 2U);
    for (auto c : p.support) EXPECT_FALSE(d0_candidates.contains(c));
  }
  MapBuildRequest bad = no_gridmap();
  bad.excluded_drive_ids = {"nope"};
  EXPECT_THROW((void)builder.build(store, bad), NotFoundError);

  // Region: only landmarks inside it.
  const tiles::LocalFrame world(kWorldOrigin);
  const GeoPoint a = world.to_geo(Eigen::Vector2d(-50, -50)),
                 b = world.to_geo(Eigen::Vector2d(50, 50));
  MapBuildRequest region = no_gridmap();
  region.region = tiles::GeoBox{a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg};
  region.make_current = false;
  const auto rr = builder.build(store, region);
  ASSERT_EQ(rr.status, MapBuildResult::Status::Published) << rr.error;
  std::size_t expect = 0;
  for (const auto& o : w.objects)
    expect += (std::abs(o.x()) < 49.9 && std::abs(o.y()) < 49.9) ? 1 : 0;
  const auto rl = store.landmarks_in(rr.version, std::nullopt);
  EXPECT_NEAR(static_cast<double>(rl.points.size()), static_cast<double>(expect), 2.0);
  for (const auto& p : rl.points)
    EXPECT_TRUE(region.region->contains(p.position.lat_deg, p.position.lon_deg));

  // Cancellation: the version fails, current is untouched.
  std::atomic<bool> cancel{true};
  BuildControl ctl;
  ctl.cancel = &cancel;
  const auto c = builder.build(store, no_gridmap(), ctl);
  EXPECT_EQ(c.status, MapBuildResult::Status::Cancelled);
  EXPECT_EQ(store.get_map_version(c.version)->status, MapVersionStatus::Failed);
  EXPECT_EQ(store.current_map_version(), full.version);

  // Fake packages have no gridmap: the build still publishes and reports why.
  MapBuildRequest with_grid;
  with_grid.make_current = false;
  const auto g = builder.build(store, with_grid);
  ASSERT_EQ(g.status, MapBuildResult::Status::Published) << g.error;
  EXPECT_EQ(g.stats.gridmap_drives, 0);
  EXPECT_EQ(store.get_map_version(g.version)->statistics.at("gridmap").at("errors").size(), 3U);
}

TEST(MapBuilder, RealPackagesBuildTheFleetGridmap) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const World w = make_world(4, 50, 50.0);
  for (int d = 0; d < 2; ++d)
    put_real_package(store, tmp.path(), w, d, "real" + std::to_string(d), {});
  const auto r = MapBuilder{}.build(store, {});
  ASSERT_EQ(r.status, MapBuildResult::Status::Published) << r.error;
  EXPECT_EQ(r.stats.gridmap_drives, 2);
  EXPECT_GT(r.stats.gridmap_tiles, 5);
  EXPECT_EQ(r.stats.point_landmarks, 50);
  const auto grid = store.list_tiles(r.version, TileLayer::Gridmap);
  ASSERT_EQ(static_cast<std::int64_t>(grid.size()), r.stats.gridmap_tiles);
  const FleetGridmapConfig cfg;
  int observed = 0;
  for (const auto& t : grid) {
    if (t.key.z != cfg.base_zoom) continue;
    const auto png = store.get_tile(r.version, TileLayer::Gridmap, t.key);
    ASSERT_TRUE(png);
    for (float db : decode_gridmap_png_db(png->payload, cfg)) {
      if (std::isnan(db)) continue;
      ++observed;
      EXPECT_NEAR(db, 30.0, 0.11);
    }
  }
  // Observed: the union of both drives' 100 m x 20 m strips at ~0.39 m pixels.
  EXPECT_GT(observed, 137 * 20 / (0.39 * 0.39) * 0.9);
  EXPECT_LT(observed, 137 * 20 / (0.39 * 0.39) * 1.1);
  // Same drives again: gridmap tiles reused byte for byte (same ETags).
  const auto again = MapBuilder{}.build(store, {});
  ASSERT_EQ(again.status, MapBuildResult::Status::Published) << again.error;
  const auto grid2 = store.list_tiles(again.version, TileLayer::Gridmap);
  ASSERT_EQ(grid2.size(), grid.size());
  for (std::size_t i = 0; i < grid.size(); ++i) EXPECT_EQ(grid2[i].etag, grid[i].etag);
}

TEST(MapBuilder, CompactAndLandmarksOnlyPackagesContributeWhatTheyContain) {
  TempDir tmp;
  SqliteMapStore store(tmp.path() / "map.db");
  const World w = make_world(4, 50, 50.0);
  for (int d = 0; d < 2; ++d) {
    // Drive 0: compact gridmap (format 2); drive 1: landmarks only.
    PackageWriteOptions o;
    o.format_version = 2;
    o.landmarks_only = d == 1;
    put_real_package(store, tmp.path(), w, d, "v2_" + std::to_string(d), o);
  }
  const auto r = MapBuilder{}.build(store, {});
  ASSERT_EQ(r.status, MapBuildResult::Status::Published) << r.error;
  EXPECT_EQ(r.stats.point_landmarks, 50);  // both drives' candidates agree
  EXPECT_EQ(r.stats.gridmap_drives, 1) << store.get_map_version(r.version)->statistics.dump();
  const FleetGridmapConfig cfg;
  int observed = 0;
  for (const auto& t : store.list_tiles(r.version, TileLayer::Gridmap)) {
    if (t.key.z != cfg.base_zoom) continue;
    const auto png = store.get_tile(r.version, TileLayer::Gridmap, t.key);
    ASSERT_TRUE(png);
    for (float db : decode_gridmap_png_db(png->payload, cfg)) {
      if (std::isnan(db)) continue;
      ++observed;
      EXPECT_NEAR(db, 30.0, 0.11);  // the decoded power (±0.002 dB) at the PNG's 0.2 dB steps
    }
  }
  // One drive's 100 m x 20 m strip at ~0.39 m pixels.
  EXPECT_GT(observed, 100 * 20 / (0.39 * 0.39) * 0.9);
  EXPECT_LT(observed, 100 * 20 / (0.39 * 0.39) * 1.1);
}

TEST(FleetGridmap, AccumulatesPowerAndCountsIntoWebMercatorPixels) {
  const tiles::LocalFrame frame(kWorldOrigin);
  GridmapRaster r = unobserved_raster(2, 300, 200, -15.0, 10.0);
  double n_total = 0;
  for (int row = 0; row < r.height; ++row) {
    for (int col = 0; col < r.width; ++col) {
      if ((row / 20 + col / 20) % 2) continue;  // a checkerboard of observed blocks
      const std::size_t i = static_cast<std::size_t>(row) * r.width + col;
      r.count[i] = 4;
      r.layers[0][i] = 30.0;               // C_00
      r.layers[1][i] = cdouble(1.0, 2.0);  // C_01 (off-diagonal: not in the trace)
      r.layers[2][i] = 70.0;               // C_11
      n_total += 4;
    }
  }
  FleetGridmapConfig cfg;
  FleetGridmapAccumulator acc(cfg);
  acc.add(r, frame, PolLevel::DualLLLR);
  acc.add(r, frame,
          PolLevel::DualLLLR);  // a second drive on the same cells doubles N, keeps the mean
  ASSERT_GT(acc.num_base_tiles(), 0U);
  const auto png_tiles = acc.encode_png_tiles();
  double counted = 0;
  std::set<int> zooms;
  for (const auto& [key, png] : png_tiles) {
    zooms.insert(key.z);
    if (key.z != cfg.base_zoom) continue;
    const auto db = decode_gridmap_png_db(png, cfg);
    for (int py = 0; py < kGridmapTilePixels; ++py) {
      for (int px = 0; px < kGridmapTilePixels; ++px) {
        const auto p = acc.mean_power(key, px, py);
        counted += acc.count(key, px, py);
        const float v = db[static_cast<std::size_t>(py) * kGridmapTilePixels + px];
        if (!p) {
          EXPECT_TRUE(std::isnan(v));
          continue;
        }
        EXPECT_NEAR(*p, 100.0, 1e-3);  // tr(C) = 30 + 70
        EXPECT_NEAR(v, 20.0, 0.11);    // 10 log10(100), gray step 0.2 dB
      }
    }
  }
  EXPECT_DOUBLE_EQ(counted, 2 * n_total);
  EXPECT_EQ(zooms, (std::set<int>{14, 15, 16, 17, 18}));
  // The observed area is where the raster is: centre of the first observed block.
  const GeoPoint g = frame.to_geo(Eigen::Vector2d(-15.0 + 1.0, 10.0 - 1.0));
  const auto m = tiles::to_mercator_tiles(g.lat_deg, g.lon_deg, cfg.base_zoom);
  const tiles::TileKey key{cfg.base_zoom, static_cast<int>(m.x), static_cast<int>(m.y)};
  const int px = static_cast<int>((m.x - key.x) * kGridmapTilePixels);
  const int py = static_cast<int>((m.y - key.y) * kGridmapTilePixels);
  EXPECT_TRUE(acc.mean_power(key, px, py).has_value());
  EXPECT_THROW((void)decode_gridmap_png_db("not a png", cfg), FormatError);
}

}  // namespace
}  // namespace polmap::mapping
