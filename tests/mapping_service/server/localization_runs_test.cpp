// Localization run reports over HTTP on loopback (POST/GET/DELETE /v1/runs,
// /v1/runs/quality): roles, limits before the body, refusals naming the field, the
// canonical copy served back, GeoJSON for the console, fleet cells summed over runs, and
// erasure with the vehicle's drives.
#include <nlohmann/json.hpp>

#include "mapping_service/server_fixture.hpp"
#include "polmap/schema/localization_run.hpp"

namespace polmap::mapping::testing {
namespace {

using nlohmann::json;

constexpr const char* kVehicleKey = "vehicle-key-7";
constexpr const char* kViewerKey = "viewer-key-3";

/// n samples 1 m apart heading east from the scene's origin; every 10th degraded.
LocalizationRun run_along(int n, double lat_error_m) {
  const tiles::LocalFrame f = scene_frame();
  LocalizationRun r;
  r.label = "drive_9";
  r.map_version = 2;
  r.reference = RunReference::SimulatorTruth;
  for (int i = 0; i < n; ++i) {
    LocalizationRunSample s;
    s.t_s = 10.0 + 0.2 * i;
    const GeoPoint p = f.to_geo(Eigen::Vector2d(i, 0.0));
    s.lat_deg = p.lat_deg;
    s.lon_deg = p.lon_deg;
    s.yaw_enu_deg = 0.0;
    s.status = i == 0 ? RunStatus::Initializing
                      : (i % 10 == 0 ? RunStatus::Degraded : RunStatus::Tracking);
    s.cov_xx_m2 = s.cov_yy_m2 = 0.0025;
    s.cov_yaw_rad2 = 1e-5;
    if (i > 0) s.error = RunSampleError{0.01, lat_error_m, 0.1};
    r.samples.push_back(s);
  }
  return r;
}

class RunsServer : public ServerFixture {
 protected:
  void SetUp() override {
    ServerConfig cfg;
    cfg.api_keys = {ApiKey(kKey), ApiKey(kVehicleKey, KeyRole::Vehicle, "veh-7"),
                    ApiKey(kViewerKey, KeyRole::Viewer)};
    cfg.max_run_report_bytes = 256 << 10;
    start(cfg);
  }
  httplib::Result post(const std::string& body, const std::string& key = kVehicleKey) {
    return client().Post("/v1/runs", auth(key), body, "application/json");
  }
  std::int64_t post_ok(const LocalizationRun& r) {
    const auto res = post(encode_localization_run(r));
    EXPECT_TRUE(res);
    if (!res) return 0;
    EXPECT_EQ(res->status, 201) << res->body;
    return json::parse(res->body).value("id", std::int64_t{0});
  }
};

TEST_F(RunsServer, AVehicleReportsARunThatOperatorsReadBack) {
  const LocalizationRun r = run_along(60, 0.04);
  const auto res = post(encode_localization_run(r));
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 201) << res->body;
  const json created = json::parse(res->body);
  const std::int64_t id = created["id"];
  EXPECT_EQ(res->get_header_value("Location"), "/v1/runs/" + std::to_string(id));
  // The vehicle comes from the key, the figures from the server's own summary.
  EXPECT_EQ(created["vehicle_id"], "veh-7");
  EXPECT_EQ(created["samples"], 60);
  EXPECT_NEAR(created["summary"]["lat_rmse_m"].get<double>(), 0.04, 1e-12);
  EXPECT_NEAR(created["summary"]["length_m"].get<double>(), 59.0, 1e-3);
  EXPECT_NEAR(created["summary"]["status_share"]["degraded"].get<double>(), 5.0 / 60, 1e-12);

  // Listing needs a key that may read fleet data.
  EXPECT_EQ(client().Get("/v1/runs")->status, 401);
  EXPECT_EQ(client().Get("/v1/runs", auth(kVehicleKey))->status, 403);
  const auto list = client().Get("/v1/runs", auth(kViewerKey));
  ASSERT_EQ(list->status, 200);
  const json l = json::parse(list->body);
  ASSERT_EQ(l["count"], 1);
  EXPECT_EQ(l["runs"][0]["id"], id);
  EXPECT_EQ(l["runs"][0]["label"], "drive_9");
  EXPECT_EQ(json::parse(client().Get("/v1/runs?vehicle=other", auth(kKey))->body)["count"], 0);

  // The canonical copy comes back, and it is the run that was sent.
  const auto one = client().Get("/v1/runs/" + std::to_string(id), auth(kViewerKey));
  ASSERT_EQ(one->status, 200);
  const json report = json::parse(one->body)["report"];
  EXPECT_EQ(report.dump(), encode_localization_run(r));

  const auto geo = client().Get("/v1/runs/" + std::to_string(id) + "?format=geojson", auth(kKey));
  ASSERT_EQ(geo->status, 200);
  const json g = json::parse(geo->body);
  EXPECT_EQ(g["type"], "FeatureCollection");
  ASSERT_EQ(g["features"].size(), 59u);
  EXPECT_EQ(g["features"][9]["properties"]["status"], "degraded");
  EXPECT_NEAR(g["features"][58]["properties"]["distance_m"].get<double>(), 59.0, 1e-3);

  EXPECT_EQ(client().Delete("/v1/runs/" + std::to_string(id), auth(kViewerKey))->status, 403);
  EXPECT_EQ(client().Delete("/v1/runs/" + std::to_string(id), auth(kKey))->status, 204);
  EXPECT_EQ(client().Get("/v1/runs/" + std::to_string(id), auth(kKey))->status, 404);
  EXPECT_EQ(client().Delete("/v1/runs/" + std::to_string(id), auth(kKey))->status, 404);
}

TEST_F(RunsServer, RefusesReportsNamingWhatIsWrongAndStoresNothing) {
  json j = json::parse(encode_localization_run(run_along(20, 0.02)));
  j["samples"][3]["status"] = "confused";
  auto res = post(j.dump());
  ASSERT_EQ(res->status, 422);
  EXPECT_EQ(json::parse(res->body)["field"], "samples[3].status");

  res = post("{\"format\": \"polmap-localization-run\", ");
  ASSERT_EQ(res->status, 400);
  EXPECT_EQ(json::parse(res->body)["field"], "body");

  // Too many bytes: refused on its Content-Length, before the body is read.
  res = post(std::string(300 << 10, ' '));
  ASSERT_EQ(res->status, 413);
  EXPECT_EQ(json::parse(res->body)["field"], "Content-Length");

  // A viewer cannot report, and is told so before its body is read (it may be large).
  res = post(encode_localization_run(run_along(20, 0.02)), kViewerKey);
  EXPECT_EQ(res->status, 403);
  res = client().Post("/v1/runs", encode_localization_run(run_along(20, 0.02)), "application/json");
  EXPECT_EQ(res->status, 401);

  EXPECT_EQ(client().Get("/v1/runs/abc", auth(kKey))->status, 400);
  EXPECT_EQ(client().Get("/v1/runs/1?format=kml", auth(kKey))->status, 400);
  EXPECT_EQ(client().Get("/v1/runs?limit=0", auth(kKey))->status, 400);
  EXPECT_EQ(client().Get("/v1/runs/quality?bbox=1,2,3", auth(kKey))->status, 400);
  EXPECT_TRUE(store_->list_localization_runs(100).empty());
}

TEST_F(RunsServer, QualityCellsSumTheFleetsRunsAndMarkWeakPlaces) {
  post_ok(run_along(80, 0.03));
  post_ok(run_along(80, 0.5));  // the same road, badly
  const auto res = client().Get("/v1/runs/quality", auth(kViewerKey));
  ASSERT_EQ(res->status, 200);
  const json g = json::parse(res->body);
  ASSERT_GE(g["features"].size(), 2u);  // 80 m over ≈ 25 m cells
  std::int64_t samples = 0;
  for (const auto& f : g["features"]) {
    const auto& p = f["properties"];
    EXPECT_EQ(p["runs"], 2);
    samples += p["samples"].get<std::int64_t>();
    // RMSE of 0.03 and 0.5 m over equal counts: above the 0.2 m threshold.
    EXPECT_NEAR(p["lat_rmse_m"].get<double>(), std::sqrt((0.03 * 0.03 + 0.25) / 2), 1e-9);
    EXPECT_TRUE(p["weak"].get<bool>());
  }
  EXPECT_EQ(samples, 2 * 79);  // initializing samples are not on the map
  // A box elsewhere holds none.
  const auto away = client().Get("/v1/runs/quality?bbox=0,0,0.01,0.01", auth(kKey));
  ASSERT_EQ(away->status, 200);
  EXPECT_TRUE(json::parse(away->body)["features"].empty());
}

TEST_F(RunsServer, APlaceALaterMapFixedIsJudgedByTheRunsAgainstThatMap) {
  post_ok(run_along(80, 0.5));  // weak against map version 2
  LocalizationRun fixed = run_along(80, 0.03);
  fixed.map_version = 3;  // the same road against the map that fixed it
  post_ok(fixed);
  auto quality = [&](const std::string& query) {
    const auto res = client().Get("/v1/runs/quality" + query, auth(kViewerKey));
    EXPECT_EQ(res->status, 200) << res->body;
    return json::parse(res->body);
  };
  const json now = quality("");
  EXPECT_EQ(now["properties"]["runs"], "newest_map");
  ASSERT_GE(now["features"].size(), 2u);
  for (const auto& f : now["features"]) {
    EXPECT_EQ(f["properties"]["runs"], 1);
    EXPECT_EQ(f["properties"]["map_version"], 3);
    EXPECT_NEAR(f["properties"]["lat_rmse_m"].get<double>(), 0.03, 1e-9);
    EXPECT_FALSE(f["properties"]["weak"].get<bool>());
  }
  const json all = quality("?runs=all");
  for (const auto& f : all["features"]) {
    EXPECT_EQ(f["properties"]["runs"], 2);
    EXPECT_TRUE(f["properties"]["weak"].get<bool>());  // the old runs still count there
  }
  EXPECT_EQ(client().Get("/v1/runs/quality?runs=some", auth(kViewerKey))->status, 400);
}

TEST_F(RunsServer, ErasingAVehicleErasesItsRuns) {
  post_ok(run_along(10, 0.01));
  post_ok(run_along(10, 0.01));
  const auto res = client().Delete("/v1/vehicles/veh-7/drives", auth(kKey));
  ASSERT_EQ(res->status, 200);
  EXPECT_EQ(json::parse(res->body)["runs_deleted"], 2);
  EXPECT_TRUE(store_->list_localization_runs(100).empty());
}

TEST_F(RunsServer, KeepsTheNewestRunsOnly) {
  ServerConfig cfg;
  cfg.api_keys = {ApiKey(kVehicleKey, KeyRole::Vehicle, "veh-7")};
  cfg.max_localization_runs = 2;
  restart(cfg);
  const auto a = post_ok(run_along(5, 0.0));
  const auto b = post_ok(run_along(5, 0.0));
  const auto c = post_ok(run_along(5, 0.0));
  const auto kept = store_->list_localization_runs(10);
  ASSERT_EQ(kept.size(), 2u);
  EXPECT_EQ(kept[0].id, c);
  EXPECT_EQ(kept[1].id, b);
  EXPECT_FALSE(store_->get_localization_run(a));
}

}  // namespace
}  // namespace polmap::mapping::testing
