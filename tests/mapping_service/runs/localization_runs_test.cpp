// What the server derives from a run report: lateral σ, distances, summary, quality cells
// and GeoJSON, checked against straightforward references.
#include "polmap/mapping_service/localization_runs.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::mapping {
namespace {

constexpr double kOriginLat = 48.4, kOriginLon = 9.99;

/// A straight run heading north-east at 1 m spacing: samples i at i metres.
LocalizationRun straight_run(int n, double heading_enu_deg = 45.0) {
  const tiles::LocalFrame f(GeoPoint{kOriginLat, kOriginLon, 0});
  const double h = heading_enu_deg * std::numbers::pi / 180.0;
  LocalizationRun r;
  r.reference = RunReference::SimulatorTruth;
  for (int i = 0; i < n; ++i) {
    LocalizationRunSample s;
    s.t_s = 0.1 * i;
    const GeoPoint p = f.to_geo(Eigen::Vector2d(std::cos(h), std::sin(h)) * i);
    s.lat_deg = p.lat_deg;
    s.lon_deg = p.lon_deg;
    s.yaw_enu_deg = heading_enu_deg;
    s.status = i < 5 ? RunStatus::Initializing
                     : (i % 10 == 0 ? RunStatus::Degraded
                                    : (i % 17 == 0 ? RunStatus::Lost : RunStatus::Tracking));
    s.cov_xx_m2 = 0.04;
    s.cov_yy_m2 = 0.01;
    s.cov_xy_m2 = 0.0;
    s.cov_yaw_rad2 = 1e-4;
    if (i >= 5 && i % 3 != 0) s.error = RunSampleError{0.01 * (i % 7), 0.02 * ((i % 5) - 2), 0.1};
    r.samples.push_back(s);
  }
  return r;
}

TEST(LocalizationRuns, LateralSigmaIsTheCovarianceAcrossTheHeading) {
  LocalizationRunSample s;
  s.cov_xx_m2 = 0.09;  // σ_east 0.3
  s.cov_yy_m2 = 0.01;  // σ_north 0.1
  s.cov_xy_m2 = 0.02;
  for (const double yaw_deg : {0.0, 30.0, 90.0, 135.0, -60.0}) {
    s.yaw_enu_deg = yaw_deg;
    // Reference: rotate the covariance into the vehicle frame (x along, y across).
    const double a = yaw_deg * std::numbers::pi / 180.0;
    Eigen::Matrix2d c;
    c << s.cov_xx_m2, s.cov_xy_m2, s.cov_xy_m2, s.cov_yy_m2;
    Eigen::Matrix2d R;
    R << std::cos(a), -std::sin(a), std::sin(a), std::cos(a);
    const Eigen::Matrix2d v = R.transpose() * c * R;
    EXPECT_NEAR(lateral_sigma_m(s), std::sqrt(v(1, 1)), 1e-12) << yaw_deg;
  }
  s.cov_xy_m2 = 0.0;
  s.yaw_enu_deg = 0.0;  // east: across is north
  EXPECT_NEAR(lateral_sigma_m(s), 0.1, 1e-12);
  s.yaw_enu_deg = 90.0;
  EXPECT_NEAR(lateral_sigma_m(s), 0.3, 1e-12);
}

TEST(LocalizationRuns, DistancesFollowTheGround) {
  const auto run = straight_run(101);
  const auto d = run_distances_m(run);
  ASSERT_EQ(d.size(), 101u);
  for (std::size_t i = 0; i < d.size(); ++i) EXPECT_NEAR(d[i], static_cast<double>(i), 1e-6);
}

TEST(LocalizationRuns, RecordSummarizesStatusAndErrorsAsABruteForceDoes) {
  const auto run = straight_run(200);
  const auto r = run_record(run, "veh-7");
  EXPECT_EQ(r.vehicle_id, "veh-7");
  EXPECT_EQ(r.samples, 200);
  std::array<int, kRunStatusCount> n{};
  double lat2 = 0, lat_max = 0;
  int evaluated = 0;
  for (const auto& s : run.samples) {
    ++n[static_cast<std::size_t>(s.status)];
    EXPECT_GE(s.lat_deg, r.bounds.min_lat_deg);
    EXPECT_LE(s.lat_deg, r.bounds.max_lat_deg);
    EXPECT_GE(s.lon_deg, r.bounds.min_lon_deg);
    EXPECT_LE(s.lon_deg, r.bounds.max_lon_deg);
    if (s.error) {
      lat2 += s.error->lat_m * s.error->lat_m;
      lat_max = std::max(lat_max, std::abs(s.error->lat_m));
      ++evaluated;
    }
  }
  const auto& j = r.summary;
  EXPECT_DOUBLE_EQ(j["status_share"]["tracking"].get<double>(), n[1] / 200.0);
  EXPECT_DOUBLE_EQ(j["status_share"]["degraded"].get<double>(), n[2] / 200.0);
  EXPECT_DOUBLE_EQ(j["status_share"]["lost"].get<double>(), n[3] / 200.0);
  EXPECT_EQ(j["evaluated"].get<int>(), evaluated);
  EXPECT_NEAR(j["lat_rmse_m"].get<double>(), std::sqrt(lat2 / evaluated), 1e-12);
  EXPECT_DOUBLE_EQ(j["lat_max_m"].get<double>(), lat_max);
  EXPECT_LE(j["lat_p95_m"].get<double>(), lat_max);
  EXPECT_NEAR(j["length_m"].get<double>(), 199.0, 1e-6);
  EXPECT_NEAR(j["duration_s"].get<double>(), 19.9, 1e-9);
  EXPECT_NEAR(j["time_to_tracking_s"].get<double>(), 0.5, 1e-9);  // sample 5 tracks first
  EXPECT_NEAR(j["mean_sigma_lat_m"].get<double>(), std::sqrt(0.5 * 0.04 + 0.5 * 0.01), 1e-9);

  LocalizationRun plain = run;
  for (auto& s : plain.samples) s.error.reset();
  const auto p = run_record(plain, "");
  EXPECT_TRUE(p.summary["lat_rmse_m"].is_null());
  EXPECT_EQ(p.summary["evaluated"].get<int>(), 0);
}

TEST(LocalizationRuns, CellsHoldEverySampleOnTheMapOnceAndAddUp) {
  const auto run = straight_run(300);
  const auto cells = run_cells(run);
  ASSERT_GT(cells.size(), 3u);  // 300 m diagonal over ≈ 25 m cells
  std::int64_t samples = 0, degraded = 0, evaluated = 0;
  double err2 = 0;
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const auto& c = cells[i];
    EXPECT_EQ(c.z, kRunCellZoom);
    EXPECT_EQ(c.runs, 1);
    if (i > 0) {
      EXPECT_TRUE(std::pair(cells[i - 1].x, cells[i - 1].y) < std::pair(c.x, c.y));
    }
    samples += c.samples;
    degraded += c.degraded;
    evaluated += c.evaluated;
    err2 += c.sum_err_lat2_m2;
  }
  std::int64_t want_samples = 0, want_degraded = 0, want_evaluated = 0;
  double want_err2 = 0;
  for (const auto& s : run.samples) {
    if (s.status == RunStatus::Initializing) continue;
    ++want_samples;
    if (s.status == RunStatus::Degraded || s.status == RunStatus::Lost) ++want_degraded;
    if (s.error) {
      ++want_evaluated;
      want_err2 += s.error->lat_m * s.error->lat_m;
    }
    // The sample lies in its cell.
    const auto k = tiles::tile_at(s.lat_deg, s.lon_deg, kRunCellZoom);
    EXPECT_TRUE(std::any_of(cells.begin(), cells.end(), [&](const LocalizationRunCell& c) {
      return c.x == k.x && c.y == k.y;
    }));
  }
  EXPECT_EQ(samples, want_samples);
  EXPECT_EQ(degraded, want_degraded);
  EXPECT_EQ(evaluated, want_evaluated);
  EXPECT_NEAR(err2, want_err2, 1e-12);
}

TEST(LocalizationRuns, GeoJsonHasOneSegmentPerStepWithTheLaterSamplesState) {
  const auto run = straight_run(50);
  LocalizationRunRecord rec = run_record(run, "v");
  rec.id = 9;
  const auto g = run_geojson(run, rec);
  ASSERT_EQ(g["features"].size(), 49u);
  EXPECT_EQ(g["properties"]["id"].get<int>(), 9);
  double last = -1;
  for (std::size_t i = 0; i < 49; ++i) {
    const auto& f = g["features"][i];
    const auto& s = run.samples[i + 1];
    EXPECT_EQ(f["properties"]["status"].get<std::string>(), to_string(s.status));
    EXPECT_GT(f["properties"]["distance_m"].get<double>(), last);
    last = f["properties"]["distance_m"].get<double>();
    EXPECT_EQ(f["properties"]["err_lat_m"].is_null(), !s.error.has_value());
    EXPECT_DOUBLE_EQ(f["geometry"]["coordinates"][1][0].get<double>(), s.lon_deg);
    EXPECT_DOUBLE_EQ(f["geometry"]["coordinates"][1][1].get<double>(), s.lat_deg);
  }
}

TEST(LocalizationRuns, CellsBecomeWeakByEachThreshold) {
  LocalizationRunCell good{kRunCellZoom, 549000, 359000, 10, 0, 10, 10 * 0.05, 10 * 0.01, 0.1, 2};
  LocalizationRunCell degraded = good;
  degraded.degraded = 3;
  LocalizationRunCell uncertain = good;
  uncertain.sum_sigma_lat_m = 10 * 0.5;
  LocalizationRunCell wrong = good;
  wrong.sum_err_lat2_m2 = 10 * 0.09;  // RMSE 0.3 m
  const std::vector<LocalizationRunCell> cells{good, degraded, uncertain, wrong};
  const auto g = run_cells_geojson(cells);
  ASSERT_EQ(g["features"].size(), 4u);
  EXPECT_FALSE(g["features"][0]["properties"]["weak"].get<bool>());
  EXPECT_TRUE(g["features"][1]["properties"]["weak"].get<bool>());
  EXPECT_TRUE(g["features"][2]["properties"]["weak"].get<bool>());
  EXPECT_TRUE(g["features"][3]["properties"]["weak"].get<bool>());
  EXPECT_NEAR(g["features"][3]["properties"]["lat_rmse_m"].get<double>(), 0.3, 1e-12);
  EXPECT_EQ(g["features"][0]["properties"]["runs"].get<int>(), 2);
  // The polygon is the cell's tile.
  const auto b = tiles::tile_bounds(tiles::TileKey{kRunCellZoom, 549000, 359000});
  const auto& ring = g["features"][0]["geometry"]["coordinates"][0];
  EXPECT_DOUBLE_EQ(ring[0][0].get<double>(), b.min_lon_deg);
  EXPECT_DOUBLE_EQ(ring[2][1].get<double>(), b.max_lat_deg);
}

}  // namespace
}  // namespace polmap::mapping
