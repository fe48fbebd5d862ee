// Map builds over drives with consumer-grade GNSS: each drive's candidates and trajectory
// are shifted by its own metre-level error and report a 2 m accuracy. The build aligns
// them (statistics "alignment") and the consensus finds the objects once each, consistent
// to centimetres up to one common offset; without the alignment it cannot.
#include <gtest/gtest.h>

#include <random>

#include "builder_fixtures.hpp"
#include "polmap/mapping_service/drive_placement.hpp"
#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping {
namespace {
using namespace builder_fixtures;  // NOLINT: test fixtures

World road_world() {
  World w;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (double x = -140.0; x < 140.0; x += 4.0 + 6.0 * u(rng)) {
    w.objects.emplace_back(x, (u(rng) < 0.5 ? -1.0 : 1.0) * (5.0 + 15.0 * u(rng)));
  }
  return w;
}

struct Result {
  MapBuildResult build;
  std::vector<Eigen::Vector2d> landmarks;  // world frame
};

// Each drive's positioning error (drive "consumer_<d>").
const std::vector<Eigen::Vector2d> kErrors{{1.8, -1.2},  {-1.5, 0.9}, {0.4, 2.1},
                                           {-2.2, -0.6}, {1.1, 1.4},  {-0.3, -1.9}};

void put_consumer_fleet(MapStore& store, const fs::path& dir, const World& w) {
  std::vector<Eigen::Vector2d> path;
  for (double x = -160.0; x <= 160.0; x += 5.0) path.emplace_back(x, 0.0);
  for (std::size_t d = 0; d < kErrors.size(); ++d) {
    put_drive_along(store, dir, w, "consumer_" + std::to_string(d), 300 + d, {-150, -30}, {150, 30},
                    path, 0, 100.0 * d, kErrors[d], 2.0F);
  }
}

Result build_consumer_fleet(const fs::path& dir, bool align) {
  const World w = road_world();
  SqliteMapStore store(dir / "map.db");
  put_consumer_fleet(store, dir, w);
  MapBuilderConfig cfg;
  cfg.align_drives = align;
  Result r;
  r.build = MapBuilder(cfg).build(store, MapBuildRequest{});
  const tiles::LocalFrame world(kWorldOrigin);
  for (const auto& p : store.landmarks_in(r.build.version, std::nullopt, false).points) {
    r.landmarks.push_back(world.to_local(p.position));
  }
  return r;
}

/// Objects with a landmark within 0.15 m after removing the mean landmark - object offset
/// of the nearest pairs (the map's common offset), and the RMS of those pairs.
std::pair<int, double> matched(const World& w, const std::vector<Eigen::Vector2d>& lm) {
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> pairs;
  for (const auto& o : w.objects) {
    const Eigen::Vector2d* best = nullptr;
    double bd = 9.0;  // 3 m
    for (const auto& l : lm) {
      if ((l - o).squaredNorm() < bd) bd = (l - o).squaredNorm(), best = &l;
    }
    if (best) pairs.emplace_back(o, *best);
  }
  Eigen::Vector2d off = Eigen::Vector2d::Zero();
  for (const auto& [o, l] : pairs) off += l - o;
  if (!pairs.empty()) off /= static_cast<double>(pairs.size());
  int n = 0;
  double s2 = 0;
  for (const auto& [o, l] : pairs) {
    const double d = (l - o - off).norm();
    if (d < 0.15) ++n, s2 += d * d;
  }
  return {n, n ? std::sqrt(s2 / n) : 0.0};
}

TEST(DriveAlignmentBuild, ConsumerDrivesAreAlignedBeforeConsensus) {
  polmap::test::TestDir tmp("alignment_build");
  const World w = road_world();
  const Result r = build_consumer_fleet(tmp.path(), true);
  ASSERT_EQ(r.build.status, MapBuildResult::Status::Published) << r.build.error;
  EXPECT_EQ(r.build.stats.alignment_status, "aligned");
  EXPECT_EQ(r.build.stats.aligned_drives, 6);
  EXPECT_GT(r.build.stats.alignment_mean_correction_m, 0.5);
  const auto [n, rms] = matched(w, r.landmarks);
  EXPECT_GE(n, static_cast<int>(0.9 * w.objects.size()));
  EXPECT_LT(rms, 0.06);
  EXPECT_LE(r.landmarks.size(), w.objects.size() + 3);  // each object once
}

TEST(DriveAlignmentBuild, AlignedDrivesGoIntoTheMergedGridmapWhereTheAlignmentPutsThem) {
  polmap::test::TestDir tmp("alignment_build_gridmap");
  const World w = road_world();
  SqliteMapStore store(tmp.path() / "map.db");
  put_consumer_fleet(store, tmp.path(), w);
  const MapBuildResult first = MapBuilder{}.build(store, MapBuildRequest{});
  ASSERT_EQ(first.status, MapBuildResult::Status::Published) << first.error;
  EXPECT_EQ(first.stats.gridmap_drives_added, 6);
  // Each drive's placement undoes its own error, up to the map's one common offset.
  const tiles::LocalFrame world(kWorldOrigin);
  std::vector<Eigen::Vector2d> undone;
  for (std::size_t d = 0; d < kErrors.size(); ++d) {
    const std::string hash = store.get_drive("consumer_" + std::to_string(d))->content_hash;
    std::string text;
    for (const auto& in : store.gridmap_sum_inputs()) {
      if (in.content_hash == hash) text = in.placement;
    }
    ASSERT_FALSE(text.empty()) << d;
    const DrivePlacement p = decode_drive_placement(text, "test");
    const Eigen::Vector2d seen(20.0, 10.0);  // a point of the drive's gridmap strip
    const Eigen::Vector2d moved = world.to_local(placed(p, world.to_geo(seen + kErrors[d])));
    undone.push_back(moved - seen);
  }
  Eigen::Vector2d common = Eigen::Vector2d::Zero();
  for (const auto& u : undone) common += u / static_cast<double>(undone.size());
  for (std::size_t d = 0; d < undone.size(); ++d) {
    EXPECT_LT((undone[d] - common).norm(), 0.1) << d;
  }
  // The same drives again: the alignment puts them where it did, nothing is re-placed.
  const MapBuildResult again = MapBuilder{}.build(store, MapBuildRequest{});
  ASSERT_EQ(again.status, MapBuildResult::Status::Published) << again.error;
  EXPECT_EQ(again.stats.gridmap_drives_added, 0);
  EXPECT_EQ(again.stats.gridmap_drives_replaced, 0);
}

TEST(DriveAlignmentBuild, WithoutAlignmentTheSameDrivesGiveNoConsistentMap) {
  polmap::test::TestDir tmp("alignment_build_off");
  const World w = road_world();
  const Result r = build_consumer_fleet(tmp.path(), false);
  ASSERT_EQ(r.build.status, MapBuildResult::Status::Published) << r.build.error;
  EXPECT_EQ(r.build.stats.alignment_status, "off");
  EXPECT_LT(matched(w, r.landmarks).first, static_cast<int>(0.5 * w.objects.size()));
}

}  // namespace
}  // namespace polmap::mapping
