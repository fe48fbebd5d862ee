#pragma once
// A real mapping server on loopback (port 0) over a real SQLite file in a temp dir,
// plus drive packages with shared landmarks for the server tests.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "mapping_service/package_fixture.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/server.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

// Last: httplib pulls in <resolv.h>, whose `_res` macro breaks Eigen templates.
#include <httplib.h>

namespace polmap::mapping::testing {

inline constexpr const char* kKey = "k1-correct-horse-battery";
inline constexpr const char* kOtherKey = "k2-second-key";

/// True landmarks of the synthetic scene, in the drive frame of make_synthetic_drive.
inline std::vector<Eigen::Vector2d> true_points() {
  std::vector<Eigen::Vector2d> p;
  for (int i = 0; i < 12; ++i) p.emplace_back(-8.0 + 2.2 * i, 10.0 - 1.5 * i);
  return p;
}
/// (Clear of the drives' path, which passes (0, 11.2): a line the drives drove through is
/// an overhead structure to the line filter.)
inline std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> true_lines() {
  return {{{-8.0, -5.0}, {8.0, -5.0}}, {{0.0, 0.0}, {0.0, 10.0}}, {{10.0, -8.0}, {18.0, -8.0}}};
}

/// A package directory of drive `drive_id` that sees the true landmarks with
/// small per-drive jitter (±2 cm) plus one drive-specific clutter point.
inline std::filesystem::path write_scene_package(const std::filesystem::path& dir,
                                                 const std::string& drive_id, unsigned seed) {
  SyntheticDrive d = make_synthetic_drive(drive_id, PolLevel::Full, 300, 280, seed, 0, 0, 120);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> j(-0.02, 0.02);
  for (const auto& t : true_points()) {
    PointCandidate p;
    p.position_m = t + Eigen::Vector2d(j(rng), j(rng));
    p.strength = 12.0;
    p.power_db = -35.0;
    p.scattering = ScatteringClass::Odd;
    p.num_cells = 4;
    d.pkg.points.push_back(p);
  }
  PointCandidate clutter;
  clutter.position_m = {-5.0 + seed % 7, -9.0};
  clutter.strength = 9.0;
  d.pkg.points.push_back(clutter);
  for (const auto& [a, b] : true_lines()) {
    LineCandidate l;
    l.start_m = a + Eigen::Vector2d(j(rng), j(rng));
    l.end_m = b + Eigen::Vector2d(j(rng), j(rng));
    l.strength = 0.8;
    d.pkg.lines.push_back(l);
  }
  const auto out = dir / drive_id;
  write_drive_package(d.pkg, d.raster, out);
  return out;
}

/// The package archive `tar` with one field of its manifest.json set to `value`.
inline std::string with_manifest_field(const std::string& tar, const std::string& field,
                                       const nlohmann::json& value) {
  auto members = read_ustar(tar);
  for (auto& m : members) {
    if (m.name == "manifest.json") {
      nlohmann::json mf = nlohmann::json::parse(m.data);
      mf[field] = value;
      m.data = mf.dump(2);
    }
  }
  return write_ustar(members);
}

/// A landmarks-only drive without candidates yet: one pass along the drive frame's x axis
/// from -20 to +20 m at 10 m/s, starting at start_time_s (the world-change tests add
/// what the pass sees).
inline SyntheticDrive pass_along_x(const std::string& drive_id, const std::string& vehicle_id,
                                   double start_time_s, unsigned seed) {
  SyntheticDrive d = make_synthetic_drive(drive_id, PolLevel::Full, 2, 2, seed, 0, 0, 2);
  d.pkg.manifest.vehicle_id = vehicle_id;
  d.pkg.manifest.start_time_s = start_time_s;
  d.pkg.manifest.end_time_s = start_time_s + 4.0;
  const tiles::LocalFrame frame(d.pkg.manifest.origin);
  d.pkg.trajectory.clear();
  for (int k = 0; k <= 40; ++k) {
    const GeoPoint g = frame.to_geo(Eigen::Vector2d(-20.0 + k, 0.0));
    TrajectorySample t;
    t.time_s = start_time_s + 0.1 * k;
    t.lat_deg = g.lat_deg;
    t.lon_deg = g.lon_deg;
    t.speed_mps = 10.0;
    d.pkg.trajectory.push_back(t);
  }
  return d;
}

/// The drive frame shared by all scene packages.
inline tiles::LocalFrame scene_frame() {
  return tiles::LocalFrame(
      make_synthetic_drive("x", PolLevel::Full, 2, 2, 1, 0, 0, 2).pkg.manifest.origin);
}

class ServerFixture : public ::testing::Test {
 protected:
  void SetUp() override { start(ServerConfig{}); }

  void start(ServerConfig cfg) {
    dir_ = polmap::test::unique_test_dir("server");
    std::filesystem::create_directories(dir_ / "uploads");
    SqliteStoreOptions so = store_options_;
    so.orphan_grace_s = 0;
    store_ = std::make_unique<SqliteMapStore>(dir_ / "map.db", so);
    if (cfg.api_keys.empty()) cfg.api_keys = {kKey, kOtherKey};
    cfg.upload_dir = dir_ / "uploads";
    cfg.threads = 8;
    cfg.log_sink = [this](std::string_view line) {
      std::lock_guard lock(log_mutex_);
      log_.emplace_back(line);
    };
    server_ = std::make_unique<Server>(*store_, cfg);
    thread_ = std::thread([this] { server_->listen("127.0.0.1", 0); });
    ASSERT_TRUE(server_->wait_until_listening(std::chrono::seconds(10)));
    port_ = server_->bound_port();
    ASSERT_GT(port_, 0);
  }

  void restart(ServerConfig cfg) {
    stop();
    start(std::move(cfg));
  }

  void stop() {
    if (server_) {
      server_->stop();
      if (thread_.joinable()) thread_.join();
      server_.reset();
    }
    store_.reset();
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }

  void TearDown() override { stop(); }

  httplib::Client client() const {
    httplib::Client c("127.0.0.1", port_);
    c.set_read_timeout(120, 0);
    c.set_write_timeout(120, 0);
    return c;
  }
  static httplib::Headers auth(const std::string& key = kKey) {
    return {{"Authorization", "Bearer " + key}};
  }

  /// Files left in the upload directory (must be none after every request).
  std::size_t upload_leftovers() const {
    std::size_t n = 0;
    for ([[maybe_unused]] const auto& e : std::filesystem::directory_iterator(dir_ / "uploads"))
      ++n;
    return n;
  }
  /// Entries of the drive store directory (ingested packages).
  std::size_t drive_store_entries() const {
    std::size_t n = 0;
    for ([[maybe_unused]] const auto& e :
         std::filesystem::directory_iterator(store_->drive_store_dir())) {
      ++n;
    }
    return n;
  }
  std::vector<std::string> log_lines() {
    std::lock_guard lock(log_mutex_);
    return log_;
  }

  /// Packs a scene package (cached per drive id across the test binary: writing
  /// GeoTIFF/GeoPackage files takes a while).
  static const std::string& scene_tar(const std::string& drive_id, unsigned seed) {
    static std::mutex m;
    static std::map<std::string, std::string> cache;
    std::lock_guard lock(m);
    auto it = cache.find(drive_id);
    if (it == cache.end()) {
      const util::ScopedTempDir base(polmap::test::unique_test_dir("server-pkgs"));
      const auto dir = write_scene_package(base.path(), drive_id, seed);
      it = cache.emplace(drive_id, pack_drive_package(dir)).first;
    }
    return it->second;
  }

  std::filesystem::path dir_;
  std::unique_ptr<SqliteMapStore> store_;
  std::unique_ptr<Server> server_;
  std::thread thread_;
  int port_ = 0;
  std::mutex log_mutex_;
  std::vector<std::string> log_;
  /// Options of the store the next start() opens (tests set fault hooks here).
  SqliteStoreOptions store_options_;

 private:
  static std::atomic<int>& counter() {
    static std::atomic<int> c{0};
    return c;
  }
};

}  // namespace polmap::mapping::testing
