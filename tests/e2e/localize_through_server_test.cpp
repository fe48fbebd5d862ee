// End to end (issue 5): a short simulated drive set -> mapping-mode processing ->
// drive packages -> a real mapping Server on loopback over a real SQLite file ->
// upload over HTTP with an API key -> map build (POST /v1/maps, poll) ->
// loc::TileFetcher + loc::Localizer on the held-out drive -> accuracy within
// bounds against the exact simulated trajectory. Second test: the client keeps
// localizing from its tile cache when the server stops halfway through the drive.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "e2e/e2e_drive_set.hpp"
#include "polmap/eval/study.hpp"
#include "polmap/localization_client/tile_fetcher.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/server.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/world.hpp"
#include "test_dir.hpp"

// Last: httplib pulls in <resolv.h>, whose `_res` macro breaks Eigen templates.
#include <httplib.h>

namespace polmap {
namespace {

using nlohmann::json;

constexpr const char* kApiKey = "e2e-test-key-7f3a";
using namespace e2e;  // NOLINT: the shared drive set and bounds

/// A real server on loopback over a store, in its own thread.
class LoopbackServer {
 public:
  explicit LoopbackServer(mapping::MapStore& store) {
    mapping::ServerConfig sc;
    sc.api_keys = {kApiKey};
    sc.log_requests = false;
    sc.threads = 4;
    server_ = std::make_unique<mapping::Server>(store, sc);
    thread_ = std::thread([this] { server_->listen("127.0.0.1", 0); });
    ok_ = server_->wait_until_listening(std::chrono::seconds(10));
  }
  ~LoopbackServer() { stop(); }
  void stop() {
    if (server_) server_->stop();
    if (thread_.joinable()) thread_.join();
  }
  [[nodiscard]] bool ok() const { return ok_; }
  [[nodiscard]] int port() const { return server_->bound_port(); }
  [[nodiscard]] std::string url() const { return "http://127.0.0.1:" + std::to_string(port()); }

 private:
  std::unique_ptr<mapping::Server> server_;
  std::thread thread_;
  bool ok_ = false;
};

class LocalizeThroughServer : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = polmap::test::unique_test_dir("e2e-localize");
    sim_cfg_.seed = kSeed;
    world_ = sim::load_world("urban", kRouteLength_m, kSeed, sim_cfg_);
    store_ = std::make_unique<mapping::SqliteMapStore>(dir_ / "map.sqlite");
    server_ = std::make_unique<LoopbackServer>(*store_);
    ASSERT_TRUE(server_->ok());

    httplib::Client c("127.0.0.1", server_->port());
    c.set_read_timeout(120, 0);
    c.set_write_timeout(120, 0);
    const httplib::Headers auth{{"Authorization", std::string("Bearer ") + kApiKey}};
    // Every drive but the held-out one: simulate, process, package, upload.
    for (int k = 0; k < kDrives; ++k) {
      if (k == kHeldOut) continue;
      const auto pkg = eval::simulate_and_package(world_, sim_cfg_, k, PolLevel::Full, study_cfg_,
                                                  dir_ / ("pkg_" + std::to_string(k)));
      const std::string tar = mapping::pack_drive_package(pkg.dir);
      const auto r = c.Post("/v1/drives", auth, tar, "application/x-tar");
      ASSERT_TRUE(r);
      ASSERT_EQ(r->status, 201) << r->body;
    }
    auto r = c.Post("/v1/maps", auth, "{}", "application/json");
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 202) << r->body;
    version_ = json::parse(r->body)["version"].get<std::int64_t>();
    // Poll until published (or failed).
    std::string status;
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (std::chrono::steady_clock::now() < until) {
      r = c.Get("/v1/maps/" + std::to_string(version_));
      ASSERT_TRUE(r);
      ASSERT_EQ(r->status, 200) << r->body;
      status = json::parse(r->body)["status"].get<std::string>();
      if (status != "building") break;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    ASSERT_EQ(status, "published") << r->body;
    map_stats_ = json::parse(r->body)["statistics"];
  }

  static void TearDownTestSuite() {
    server_.reset();
    store_.reset();
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }

  static void expect_within_bounds(const eval::ErrorSummary& e, const char* what) {
    SCOPED_TRACE(what);
    EXPECT_GT(e.samples, 100);
    EXPECT_LT(e.lat_rmse_m, kMaxLatRmse_m);
    EXPECT_LT(e.long_rmse_m, kMaxLongRmse_m);
    EXPECT_LT(e.rot_rmse_deg, kMaxRotRmse_deg);
    EXPECT_LT(e.lat_max_m, kMaxLat_m);
  }

  static inline std::filesystem::path dir_;
  static inline sim::SimConfig sim_cfg_;
  static inline eval::StudyConfig study_cfg_;
  static inline std::shared_ptr<const sim::World> world_;
  static inline std::unique_ptr<mapping::SqliteMapStore> store_;
  static inline std::unique_ptr<LoopbackServer> server_;
  static inline std::int64_t version_ = 0;
  static inline json map_stats_;
};

TEST_F(LocalizeThroughServer, DiagnosisSeesOdometryAndCandidatesAgreeWithTheMap) {
  // `polmap study --diagnose` on the held-out drive: truth-posed candidates
  // coincide with the consensus landmarks (no bias the graph could not
  // remove) and the radar odometry stays within decimetres over a graph window.
  ASSERT_GT(version_, 0);
  const eval::DriveDiagnosis d = eval::diagnose_drive(world_, sim_cfg_, kHeldOut, PolLevel::Full,
                                                      study_cfg_, *store_, version_);
  std::printf("[e2e] diagnosis: %s\n", eval::to_json(d).dump().c_str());
  EXPECT_GT(d.map_points, 20);
  EXPECT_GT(d.extractions, 20);
  EXPECT_GT(d.egomotion_ok, d.egomotion_frames * 9 / 10);
  EXPECT_GT(d.matched_share, 0.1);  // most candidates are clutter; measured 0.20
  EXPECT_GT(d.pairs_per_extraction, 3.0);
  EXPECT_LT(std::abs(d.offset_long_mean_m), 0.05);
  EXPECT_LT(std::abs(d.offset_lat_mean_m), 0.05);
  EXPECT_LT(d.offset_rms_m, 0.2);
  EXPECT_LT(d.odo_window_pos_rms_m, 0.3);
  EXPECT_LT(d.odo_window_yaw_rms_deg, 1.0);
}

TEST_F(LocalizeThroughServer, HeldOutDriveLocalizesWithinBounds) {
  ASSERT_GT(version_, 0);
  EXPECT_GT(map_stats_.value("point_landmarks", 0), 20) << map_stats_.dump();
  // The held-out drive is not in the store.
  EXPECT_EQ(store_->list_drives().size(), static_cast<std::size_t>(kDrives - 1));
  EXPECT_FALSE(store_->get_drive("drive_" + std::to_string(kHeldOut)).has_value());

  loc::TileFetcherConfig fc;
  fc.server_url = server_->url();
  fc.cache_dir = dir_ / "cache-a";
  loc::TileFetcher fetcher(fc);
  eval::LocalizeOptions opt;
  opt.fetcher = &fetcher;
  opt.csv_path = dir_ / "loc_a.csv";
  const eval::StudyDriveResult r = eval::localize_simulated_drive(
      world_, sim_cfg_, kHeldOut, PolLevel::Full, study_cfg_, fetcher, opt);

  const auto st = fetcher.stats();
  EXPECT_GT(st.responses_200, 0u);
  EXPECT_GT(st.bytes_downloaded, 0u);
  EXPECT_EQ(st.map_version, static_cast<std::uint64_t>(version_));
  ASSERT_TRUE(r.converged) << "never reached Tracking";
  EXPECT_LT(r.converge_time_s, 10.0);
  EXPECT_FALSE(r.diverged);
  EXPECT_EQ(r.lost_events, 0);
  expect_within_bounds(r.errors, "whole drive");
  std::printf(
      "[e2e] held-out drive: %lld samples, long RMSE %.3f max %.3f m, lat RMSE %.3f max "
      "%.3f m, rot RMSE %.2f max %.2f deg, converged after %.1f s, %.1fx real time, "
      "%llu tile bytes\n",
      static_cast<long long>(r.errors.samples), r.errors.long_rmse_m, r.errors.long_max_m,
      r.errors.lat_rmse_m, r.errors.lat_max_m, r.errors.rot_rmse_deg, r.errors.rot_max_deg,
      r.converge_time_s, r.realtime_factor, static_cast<unsigned long long>(st.bytes_downloaded));
}

TEST_F(LocalizeThroughServer, KeepsLocalizingFromCacheWhenServerStops) {
  ASSERT_GT(version_, 0);
  // A second server over the same store, which this test stops halfway.
  LoopbackServer server(*store_);
  ASSERT_TRUE(server.ok());
  const double half_s = sim::DriveSimulator(world_, sim_cfg_, kHeldOut).duration_s() / 2.0;

  loc::TileFetcherConfig fc;
  fc.server_url = server.url();
  fc.cache_dir = dir_ / "cache-b";
  // Revalidate often, so the fetcher does contact the (stopped) server in the
  // second half and must fall back to its cache.
  fc.revalidate_after_s = 1.0;
  fc.connect_timeout_s = 0.5;
  fc.backoff_initial_s = 0.1;
  fc.backoff_max_s = 1.0;
  loc::TileFetcher fetcher(fc);
  bool stopped = false;
  std::uint64_t ok_before_stop = 0;
  eval::LocalizeOptions opt;
  opt.fetcher = &fetcher;
  opt.before_frame = [&](double t) {
    if (!stopped && t >= half_s) {
      ok_before_stop = fetcher.stats().responses_200 + fetcher.stats().responses_304;
      server.stop();
      stopped = true;
    }
  };
  const eval::StudyDriveResult r = eval::localize_simulated_drive(
      world_, sim_cfg_, kHeldOut, PolLevel::Full, study_cfg_, fetcher, opt);
  ASSERT_TRUE(stopped);
  EXPECT_GT(ok_before_stop, 0u);
  const auto st = fetcher.stats();
  EXPECT_GT(st.transport_errors, 0u) << "the fetcher never noticed the server was gone";
  EXPECT_FALSE(st.server_reachable);

  ASSERT_TRUE(r.converged);
  EXPECT_FALSE(r.diverged);
  // Errors of the second half only (after the server stopped).
  eval::StudyDriveResult second;
  for (std::size_t i = 0; i < r.sample_time_s.size(); ++i) {
    if (r.sample_time_s[i] < half_s) continue;
    second.abs_long_m.push_back(r.abs_long_m[i]);
    second.abs_lat_m.push_back(r.abs_lat_m[i]);
    second.rot_deg.push_back(r.rot_deg[i]);
    second.errors.long_max_m = std::max(second.errors.long_max_m, r.abs_long_m[i]);
    second.errors.lat_max_m = std::max(second.errors.lat_max_m, r.abs_lat_m[i]);
    second.errors.rot_max_deg = std::max(second.errors.rot_max_deg, r.rot_deg[i]);
  }
  const eval::ErrorSummary e2 = eval::summarize_errors({&second});
  expect_within_bounds(e2, "second half, server stopped");
  std::printf(
      "[e2e] second half without server: %lld samples, lat RMSE %.3f m (max %.3f), "
      "long RMSE %.3f m, rot RMSE %.2f deg; %llu transport errors\n",
      static_cast<long long>(e2.samples), e2.lat_rmse_m, e2.lat_max_m, e2.long_rmse_m,
      e2.rot_rmse_deg, static_cast<unsigned long long>(st.transport_errors));
}

}  // namespace
}  // namespace polmap
