// Study building blocks that run fast: StoreTileSource against a real SQLite
// store, pooled error summaries against a brute-force computation, tables,
// JSON and CCDF figures of a synthetic result, config validation.
#include "polmap/eval/study.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "polmap/eval/store_tile_source.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/tiles/localization_tile.hpp"
#include "test_dir.hpp"

namespace polmap::eval {
namespace {

std::filesystem::path temp_dir(const std::string& name) {
  return polmap::test::unique_test_dir("study-" + name);
}

TEST(StoreTileSource, ReadsPublishedTilesAndEmptyWhereNone) {
  const auto dir = temp_dir("tiles");
  {
    mapping::SqliteMapStore store(dir / "map.sqlite");
    const tiles::TileKey key = tiles::tile_at(50.11, 8.68, tiles::kLocalizationZoom);
    tiles::LocalizationTile t{key, 0, {}, {}};
    t.map_version = 1;
    PointLandmark p;
    p.id = 42;
    p.position_m = {12.345, -7.5};
    p.scattering = ScatteringClass::Odd;
    p.support_drives = 3;
    t.points.push_back(p);
    LineLandmark l;
    l.id = 7;
    l.polyline_m = {{-20.0, 3.0}, {15.0, 3.5}};
    l.support_drives = 2;
    t.lines.push_back(l);
    const std::string bytes = tiles::encode_localization_tile(t);

    const std::int64_t v = store.begin_map_version({{"notes", "test"}});
    // Not published yet: refused.
    EXPECT_THROW(StoreTileSource(store, v), NotFoundError);
    mapping::TileWrite w;
    w.key = key;
    w.payload = bytes;
    w.etag = mapping::content_etag(bytes);
    w.num_points = 1;
    w.num_lines = 1;
    store.put_tiles(v, mapping::TileLayer::Localization, std::span(&w, 1));
    store.publish_map_version(v, nlohmann::json::object(), false);

    StoreTileSource src(store, v);
    const auto got = src.tile(key);
    ASSERT_TRUE(got.has_value());
    ASSERT_EQ(got->points.size(), 1u);
    EXPECT_EQ(got->points[0].id, 42);
    EXPECT_NEAR(got->points[0].position_m.x(), 12.345, 0.0025);
    EXPECT_NEAR(got->points[0].position_m.y(), -7.5, 0.0025);
    ASSERT_EQ(got->lines.size(), 1u);
    EXPECT_EQ(got->lines[0].polyline_m.size(), 2u);
    // A second request is served from memory: the store is read once.
    (void)src.tile(key);
    const tiles::TileKey other{key.z, key.x + 3, key.y};
    const auto empty = src.tile(other);
    ASSERT_TRUE(empty.has_value());  // never nullopt
    EXPECT_TRUE(empty->points.empty());
    EXPECT_TRUE(empty->lines.empty());
    const auto st = src.stats();
    EXPECT_EQ(st.requests, 3u);
    EXPECT_EQ(st.store_reads, 2u);
    EXPECT_EQ(st.empty_tiles, 1u);
    EXPECT_EQ(st.bytes_read, bytes.size());
    EXPECT_EQ(st.point_landmarks, 1u);
    EXPECT_EQ(st.line_landmarks, 1u);
    EXPECT_THROW(StoreTileSource(store, v + 100), NotFoundError);
  }
  std::filesystem::remove_all(dir);
}

StudyDriveResult synthetic_drive(std::uint64_t seed, PolLevel level, int drive, double scale,
                                 int n) {
  std::mt19937 rng(static_cast<unsigned>(seed * 31 + drive));
  std::normal_distribution<double> g(0.0, 1.0);
  StudyDriveResult d;
  d.seed = seed;
  d.level = level;
  d.drive = drive;
  d.drive_id = "drive_" + std::to_string(drive);
  d.duration_s = 60.0 + drive;
  d.distance_m = 500.0;
  d.reliable_gnss_share = 0.85;
  d.converged = true;
  d.frames = 1800;
  d.localizer_cpu_s = 6.0;
  d.realtime_factor = 10.0;
  d.graph_updates = 300;
  d.graph_update_mean_ms = 4.0;
  d.tile_bytes = 5000;
  d.tile_bytes_per_km = 10000;
  double sl = 0, sa = 0, sr = 0;
  for (int i = 0; i < n; ++i) {
    const double el = scale * g(rng), ea = 0.5 * scale * g(rng), er = 3 * scale * std::abs(g(rng));
    d.sample_time_s.push_back(0.1 * i);
    d.abs_long_m.push_back(std::abs(el));
    d.abs_lat_m.push_back(std::abs(ea));
    d.rot_deg.push_back(er);
    sl += el * el;
    sa += ea * ea;
    sr += er * er;
    d.errors.long_max_m = std::max(d.errors.long_max_m, std::abs(el));
    d.errors.lat_max_m = std::max(d.errors.lat_max_m, std::abs(ea));
    d.errors.rot_max_deg = std::max(d.errors.rot_max_deg, er);
  }
  d.errors.samples = n;
  d.errors.long_rmse_m = std::sqrt(sl / n);
  d.errors.lat_rmse_m = std::sqrt(sa / n);
  d.errors.rot_rmse_deg = std::sqrt(sr / n);
  return d;
}

TEST(SummarizeErrors, PoolsSamplesNotDriveRmses) {
  const auto a = synthetic_drive(1, PolLevel::Full, 0, 0.05, 100);
  const auto b = synthetic_drive(1, PolLevel::Full, 1, 0.20, 900);
  const ErrorSummary s = summarize_errors({&a, &b});
  EXPECT_EQ(s.samples, 1000);
  // Brute force: RMSE over the union of samples.
  double sq = 0;
  for (double x : a.abs_lat_m) sq += x * x;
  for (double x : b.abs_lat_m) sq += x * x;
  EXPECT_NEAR(s.lat_rmse_m, std::sqrt(sq / 1000.0), 1e-12);
  EXPECT_DOUBLE_EQ(s.long_max_m, std::max(a.errors.long_max_m, b.errors.long_max_m));
  // Sample-weighted: closer to the bigger drive's RMSE than the plain mean of the two.
  EXPECT_GT(s.long_rmse_m, 0.5 * (a.errors.long_rmse_m + b.errors.long_rmse_m));
  EXPECT_EQ(summarize_errors({}).samples, 0);
}

TEST(PoolErrorSummaries, AgreesWithPoolingTheSamples) {
  const auto a = synthetic_drive(1, PolLevel::Full, 0, 0.05, 100);
  const auto b = synthetic_drive(1, PolLevel::Full, 1, 0.20, 900);
  const ErrorSummary by_samples = summarize_errors({&a, &b});
  const ErrorSummary pooled = pool_error_summaries({a.errors, b.errors});
  EXPECT_EQ(pooled.samples, by_samples.samples);
  EXPECT_NEAR(pooled.long_rmse_m, by_samples.long_rmse_m, 1e-12);
  EXPECT_NEAR(pooled.lat_rmse_m, by_samples.lat_rmse_m, 1e-12);
  EXPECT_NEAR(pooled.rot_rmse_deg, by_samples.rot_rmse_deg, 1e-12);
  EXPECT_DOUBLE_EQ(pooled.lat_max_m, by_samples.lat_max_m);
  // Shares weigh by their own sample counts.
  ErrorSummary x, y;
  x.nees_samples = 100;
  x.nees_within_q95_share = 1.0;
  x.nees_mean = 2.0;
  y.nees_samples = 300;
  y.nees_within_q95_share = 0.8;
  y.nees_mean = 4.0;
  const ErrorSummary n = pool_error_summaries({x, y});
  EXPECT_EQ(n.nees_samples, 400);
  EXPECT_NEAR(n.nees_within_q95_share, 0.85, 1e-12);
  EXPECT_NEAR(n.nees_mean, 3.5, 1e-12);
  EXPECT_EQ(pool_error_summaries({}).samples, 0);
}

TEST(StudyOutput, TablesJsonAndFigures) {
  StudyResult r;
  r.world = "urban";
  r.length_m = 600;
  r.drives = 3;
  r.seeds = {1};
  for (PolLevel l : {PolLevel::Full, PolLevel::SingleRR}) {
    for (int k = 0; k < 3; ++k) {
      r.results.push_back(synthetic_drive(1, l, k, l == PolLevel::Full ? 0.05 : 0.15, 300));
    }
    StudyLevelSummary s;
    s.level = l;
    std::vector<const StudyDriveResult*> ds;
    for (const auto& d : r.results) {
      if (d.level == l) ds.push_back(&d);
    }
    s.errors = summarize_errors(ds);
    s.drives = 3;
    s.converged = 3;
    r.levels.push_back(s);
  }
  r.results[4].diverged = true;
  r.results[4].converged = false;

  const std::string t = format_accuracy_table(r, PolLevel::Full);
  EXPECT_NE(t.find("level full"), std::string::npos) << t;
  EXPECT_NE(t.find("#1"), std::string::npos);
  EXPECT_NE(t.find("#3"), std::string::npos);
  EXPECT_NE(t.find("total"), std::string::npos);
  EXPECT_EQ(t.find("YES"), std::string::npos);
  const std::string trr = format_accuracy_table(r, PolLevel::SingleRR);
  EXPECT_NE(trr.find("YES"), std::string::npos) << trr;
  EXPECT_NE(trr.find("never"), std::string::npos) << trr;
  const std::string lv = format_level_table(r);
  EXPECT_NE(lv.find("full"), std::string::npos);
  EXPECT_NE(lv.find("rr"), std::string::npos);
  r.results[1].realtime_factor = 12.5;
  r.results[1].realtime_factor_wall = 10.25;
  r.results[1].tile_bytes_per_km = 4321.0;
  const std::string sp = format_speed_table(r);
  EXPECT_NE(sp.find("read from the store"), std::string::npos) << sp;
  EXPECT_EQ(std::count(sp.begin(), sp.end(), '\n'), 2 + 6) << sp;  // title, header, one per drive
  const std::size_t row = sp.find("#2");
  ASSERT_NE(row, std::string::npos) << sp;
  const std::string line = sp.substr(row, sp.find('\n', row) - row);
  EXPECT_NE(line.find("12.5 ( 10.2)"), std::string::npos) << line;
  EXPECT_NE(line.find("4321"), std::string::npos) << line;

  const nlohmann::json j = to_json(r);
  ASSERT_EQ(j["results"].size(), 6u);
  EXPECT_EQ(j["levels"][1]["level"], "rr");
  EXPECT_NEAR(j["levels"][0]["errors"]["lat_rmse_m"].get<double>(), r.levels[0].errors.lat_rmse_m,
              1e-12);
  EXPECT_FALSE(j["results"][0].contains("abs_lat_m"));  // per-sample data stays out

  const auto dir = temp_dir("figs");
  const auto figs = write_ccdf_figures(r, dir);
  ASSERT_EQ(figs.size(), 3u);
  for (const auto& f : figs) {
    ASSERT_TRUE(std::filesystem::exists(f)) << f;
    std::ifstream in(f);
    std::stringstream ss;
    ss << in.rdbuf();
    const std::string svg = ss.str();
    EXPECT_NE(svg.find(">full</text>"), std::string::npos) << f;
    // The diverged RR drive is left out of the curve and counted in its label.
    EXPECT_NE(svg.find(">rr (1 of 3 drives diverged, not shown)</text>"), std::string::npos) << f;
  }
  std::filesystem::remove_all(dir);
}

TEST(RunStudy, RejectsBadConfigs) {
  StudyConfig c;
  c.out_dir = temp_dir("bad");
  c.drives = 2;
  EXPECT_THROW(run_study(c), ValidationError);
  c.drives = 3;
  c.seeds.clear();
  EXPECT_THROW(run_study(c), ValidationError);
  c.seeds = {1};
  c.levels.clear();
  EXPECT_THROW(run_study(c), ValidationError);
  c.levels = {PolLevel::Full};
  c.held_out_drives = 4;  // more than there are drives
  EXPECT_THROW(run_study(c), ValidationError);
  c.held_out_drives = -1;
  EXPECT_THROW(run_study(c), ValidationError);
  c.held_out_drives = 0;
  c.out_dir.clear();
  EXPECT_THROW(run_study(c), ValidationError);
}

}  // namespace
}  // namespace polmap::eval
