// The store contract, drives and candidates, on every backend (store_backends.hpp): ingest
// round trip (idempotent, all or nothing, concurrent), deletes, region queries against brute
// force, drive paths, and the owner's sweep of crash leftovers.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <fstream>
#include <random>
#include <set>
#include <thread>

#include "mapping_service/store/contract_packages.hpp"
#include "mapping_service/store/store_backends.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping::testing {
namespace {
namespace fs = std::filesystem;

using StoreDrives = StoreContract;

TEST_P(StoreDrives, PutDriveRoundTripsRowsCandidatesAndFiles) {
  MapStore& s = store();
  const auto pkg = make_package("drive_a", 50, 20, 1);
  const auto [tar, hash] = write_archive(tmp(), "a", "package bytes A");
  const auto r = s.put_drive(pkg, tar, hash);
  EXPECT_EQ(r.status, PutDriveResult::Status::Inserted);
  EXPECT_EQ(r.drive.row, 1);
  EXPECT_EQ(r.drive.drive_id, "drive_a");
  EXPECT_EQ(r.drive.content_hash, hash);
  EXPECT_EQ(r.drive.vehicle_id, "veh-1");
  EXPECT_EQ(r.drive.pol_level, PolLevel::DualLLLR);
  EXPECT_DOUBLE_EQ(r.drive.start_time_s, 10.0);
  EXPECT_DOUBLE_EQ(r.drive.end_time_s, 70.0);
  EXPECT_EQ(r.drive.num_points, 50);
  EXPECT_EQ(r.drive.num_lines, 20);
  EXPECT_EQ(r.drive.manifest.at("drive_id"), "drive_a");
  EXPECT_EQ(r.drive.manifest.at("pol_level"), "ll-lr");
  // An archive is stored as its members (what our ustar reader sees), never as an archive.
  EXPECT_EQ(r.drive.package_path, drive_dir() / hash);
  EXPECT_EQ(entries(r.drive.package_path), 3U);
  std::ifstream manifest(r.drive.package_path / kManifestFileName);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(manifest), {}), "package bytes A");
  EXPECT_EQ(r.drive.ingested_at.size(), 20U);

  const auto c = s.candidates_in(std::nullopt);
  ASSERT_EQ(c.points.size(), 50U);
  ASSERT_EQ(c.lines.size(), 20U);
  EXPECT_EQ(c.points.front().id, 1);  // points first, then lines, ids from 1
  EXPECT_EQ(c.lines.front().id, 51);
  const tiles::LocalFrame frame(kOrigin);
  for (std::size_t i = 0; i < c.points.size(); ++i) {
    EXPECT_EQ(c.points[i].drive, r.drive.row);
    EXPECT_EQ(c.points[i].candidate.position_m, pkg.points[i].position_m);
    EXPECT_EQ(c.points[i].candidate.scattering, pkg.points[i].scattering);
    EXPECT_DOUBLE_EQ(c.points[i].candidate.strength, pkg.points[i].strength);
    EXPECT_EQ(c.points[i].candidate.num_cells, pkg.points[i].num_cells);
    const Eigen::Vector2d back = frame.to_local(c.points[i].position);
    EXPECT_LT((back - pkg.points[i].position_m).norm(), 1e-6);
    EXPECT_TRUE(r.drive.bbox.contains(c.points[i].position.lat_deg, c.points[i].position.lon_deg));
  }
  for (std::size_t i = 0; i < c.lines.size(); ++i) {
    EXPECT_EQ(c.lines[i].candidate.start_m, pkg.lines[i].start_m);
    EXPECT_EQ(c.lines[i].candidate.end_m, pkg.lines[i].end_m);
    EXPECT_LT((frame.to_local(c.lines[i].end) - pkg.lines[i].end_m).norm(), 1e-6);
  }
  EXPECT_EQ(s.list_drives().size(), 1U);
  EXPECT_TRUE(s.find_drive_by_hash(hash).has_value());
  EXPECT_EQ(s.get_drive("drive_a")->manifest, r.drive.manifest);
  const auto traj = s.drive_trajectory("drive_a");
  ASSERT_EQ(traj.size(), 10U);  // 10 m apart: all kept
  EXPECT_DOUBLE_EQ(traj[3].time_s, 13.0);
  EXPECT_DOUBLE_EQ(traj[3].lat_deg, pkg.trajectory[3].lat_deg);
  // What map builds read as the vehicle's odometry (drive alignment): heading, speed and
  // yaw rate, as validated.
  for (std::size_t k = 0; k < traj.size(); ++k) {
    EXPECT_DOUBLE_EQ(traj[k].yaw_enu_rad, pkg.trajectory[k].yaw_enu_rad);
    EXPECT_DOUBLE_EQ(traj[k].speed_mps, pkg.trajectory[k].speed_mps);
    EXPECT_DOUBLE_EQ(traj[k].yaw_rate_rps, pkg.trajectory[k].yaw_rate_rps);
  }
  EXPECT_THROW((void)s.drive_trajectory("nope"), NotFoundError);
  const auto st = s.stats();
  EXPECT_EQ(st.drives, 1);
  EXPECT_EQ(st.point_candidates, 50);
  EXPECT_EQ(st.line_candidates, 20);
  EXPECT_GT(st.database_bytes, 0);
  EXPECT_GT(st.drive_store_bytes, 0);
}

TEST_P(StoreDrives, StoredManifestCarriesThePositioningOfTheValidatedTrajectory) {
  // What map builds use to tell consumer-grade drives (aligned before consensus) from
  // survey-grade ones: the medians of the trajectory's reported accuracy, not a claim.
  MapStore& s = store();
  auto pkg = make_package("drive_consumer", 10, 2, 1);
  ASSERT_GE(pkg.trajectory.size(), 3U);
  for (std::size_t i = 0; i < pkg.trajectory.size(); ++i) {
    auto& t = pkg.trajectory[i];
    const bool outlier = i == 0;  // one sample with a fix does not make the drive survey-grade
    t.std_east_m = outlier ? 0.014F : 2.0F;
    t.std_north_m = outlier ? 0.014F : 1.5F;
    t.std_yaw_rad = 0.005F;
    t.solution = outlier ? GnssSolution::CarrierPhaseFixed : GnssSolution::Standalone;
  }
  const auto [tar, hash] = write_archive(tmp(), "c", "package bytes C");
  const auto r = s.put_drive(pkg, tar, hash);
  const auto d = s.get_drive("drive_consumer");
  ASSERT_TRUE(d.has_value());
  for (const nlohmann::json& m : {r.drive.manifest, d->manifest}) {
    const nlohmann::json& p = m.at("positioning");
    EXPECT_FLOAT_EQ(p.at("median_std_m").get<float>(), 2.0F);  // max of east and north
    EXPECT_FLOAT_EQ(p.at("median_std_yaw_rad").get<float>(), 0.005F);
    EXPECT_EQ(p.at("solution"), "standalone");
  }
}

TEST_P(StoreDrives, DecimatedTrajectoryKeepsTheOdometry) {
  // 100 Hz through slalom-like steering whose yaw rate is not linear within a metre, at
  // 1 m/s (a car manoeuvring in a car park or after a stop): the store keeps
  // about one sample per metre, and more where skipping one would change the integrated
  // yaw rate or speed (what map builds align consumer-grade drives with).
  MapStore& s = store();
  auto pkg = make_package("drive_turn", 10, 2, 1);
  const tiles::LocalFrame frame(pkg.manifest.origin);
  pkg.trajectory.clear();
  double yaw = 0.0;
  Eigen::Vector2d p = Eigen::Vector2d::Zero();
  for (int i = 0; i <= 2000; ++i) {
    TrajectorySample t;
    t.time_s = 10.0 + 0.01 * i;
    t.speed_mps = 1.0;
    t.yaw_rate_rps = 0.3 * std::sin(2.0 * 0.01 * i);
    t.yaw_enu_rad = yaw;
    const GeoPoint g = frame.to_geo(p);
    t.lat_deg = g.lat_deg;
    t.lon_deg = g.lon_deg;
    pkg.trajectory.push_back(t);
    yaw += t.yaw_rate_rps * 0.01;
    p += 0.01 * Eigen::Vector2d(std::cos(yaw), std::sin(yaw));
  }
  const auto [tar, hash] = write_archive(tmp(), "t", "package bytes T");
  (void)s.put_drive(pkg, tar, hash);
  const auto traj = s.drive_trajectory("drive_turn");
  ASSERT_LT(traj.size(), pkg.trajectory.size() / 4);
  ASSERT_GT(traj.size(), 20U);  // more than one per metre
  double full = 0.0, kept = 0.0;
  for (std::size_t i = 1; i < pkg.trajectory.size(); ++i) {
    const auto& a = pkg.trajectory[i - 1];
    const auto& b = pkg.trajectory[i];
    full += 0.5 * (a.yaw_rate_rps + b.yaw_rate_rps) * (b.time_s - a.time_s);
  }
  for (std::size_t i = 1; i < traj.size(); ++i) {
    kept += 0.5 * (traj[i - 1].yaw_rate_rps + traj[i].yaw_rate_rps) *
            (traj[i].time_s - traj[i - 1].time_s);
  }
  // Each kept interval is within 0.0005 rad of the full-rate integral.
  EXPECT_NEAR(kept, full, 0.0005 * static_cast<double>(traj.size()));
  EXPECT_NEAR(kept, full, 0.01);
}

TEST_P(StoreDrives, PutDriveCopiesPackageDirectories) {
  const fs::path dir = tmp() / "pkgdir";
  fs::create_directories(dir);
  std::ofstream(dir / "manifest.json") << "{}";
  std::ofstream(dir / "gridmap.tif") << "tif";
  const auto r = store().put_drive(make_package("d", 1, 0, 2), dir, content_etag("dir package"));
  EXPECT_TRUE(fs::is_regular_file(r.drive.package_path / "manifest.json"));
  EXPECT_TRUE(fs::is_regular_file(r.drive.package_path / "gridmap.tif"));
}

TEST_P(StoreDrives, PutIsIdempotentByContentHashAndRejectsConflictingIds) {
  MapStore& s = store();
  const auto pkg = make_package("drive_a", 10, 3, 1);
  const auto [tar, hash] = write_archive(tmp(), "a", "bytes A");
  const auto first = s.put_drive(pkg, tar, hash);
  const auto second = s.put_drive(pkg, tar, hash);
  EXPECT_EQ(second.status, PutDriveResult::Status::AlreadyPresent);
  EXPECT_EQ(second.drive.row, first.drive.row);
  EXPECT_EQ(s.list_drives().size(), 1U);
  EXPECT_EQ(s.candidates_in(std::nullopt).points.size(), 10U);

  const auto [tar2, hash2] = write_archive(tmp(), "a2", "other bytes, same drive id");
  EXPECT_THROW((void)s.put_drive(pkg, tar2, hash2), ConflictError);
  EXPECT_THROW((void)s.put_drive(pkg, tar2, "NOT-HEX"), ValidationError);
  EXPECT_THROW((void)s.put_drive(make_package("b", 1, 0, 1), tmp() / "missing.tar", hash2),
               IoError);
  EXPECT_EQ(s.list_drives().size(), 1U);
  EXPECT_EQ(entries(drive_dir()), 1U);
}

TEST_P(StoreDrives, DeleteDriveRemovesRowsAndFilesAndIdsContinueAsSqlite) {
  MapStore& s = store();
  const auto a = put_with_archive(s, tmp(), make_package("a", 30, 5, 1), "a", "A");
  const auto b = put_with_archive(s, tmp(), make_package("b", 20, 4, 2), "b", "B");
  EXPECT_EQ(b.drive.row, 2);
  EXPECT_TRUE(s.delete_drive("a"));
  EXPECT_FALSE(s.delete_drive("a"));
  EXPECT_FALSE(s.get_drive("a").has_value());
  EXPECT_FALSE(fs::exists(a.drive.package_path));
  EXPECT_TRUE(fs::exists(b.drive.package_path));
  const auto c = s.candidates_in(std::nullopt);
  EXPECT_EQ(c.points.size(), 20U);
  EXPECT_EQ(c.lines.size(), 4U);
  for (const auto& p : c.points) EXPECT_EQ(p.drive, b.drive.row);
  EXPECT_TRUE(s.drives_in({kOrigin.lat_deg - 0.01, kOrigin.lon_deg - 0.01, kOrigin.lat_deg + 0.01,
                           kOrigin.lon_deg + 0.01})
                  .size() == 1U);
  // The next row ids follow the largest one in use (as SQLite's rowids).
  EXPECT_TRUE(s.delete_drive("b"));
  const auto d = put_with_archive(s, tmp(), make_package("d", 2, 0, 3), "d", "D");
  EXPECT_EQ(d.drive.row, 1);
  EXPECT_EQ(s.candidates_in(std::nullopt).points.front().id, 1);
}

TEST_P(StoreDrives, InterruptedPutLeavesTheStoreUnchanged) {
  int round = 0;
  for (const std::string stage : {"files_copied", "rows_inserted", "files_renamed"}) {
    ContractOpenOptions o;
    o.fault_hook = [&](std::string_view st) {
      if (st == stage) throw std::runtime_error("simulated crash at " + stage);
    };
    const auto s = open(o);
    EXPECT_THROW((void)put_with_archive(*s, tmp(), make_package("a", 40, 6, 1), "a",
                                        "A" + std::to_string(++round)),
                 std::runtime_error)
        << stage;
    EXPECT_TRUE(s->list_drives().empty()) << stage;
    EXPECT_TRUE(s->candidates_in(std::nullopt).points.empty()) << stage;
    EXPECT_TRUE(s->candidates_in(std::nullopt).lines.empty()) << stage;
    EXPECT_EQ(s->stats().drives, 0) << stage;
    EXPECT_EQ(entries(drive_dir()), 0U) << stage;
  }
}

TEST_P(StoreDrives, ConcurrentPutsOfTheSameContentInsertOnce) {
  MapStore& s = store();
  const auto pkg = make_package("a", 20, 2, 1);
  const auto [tar, hash] = write_archive(tmp(), "a", "A");
  std::atomic<int> inserted{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&] {
      if (s.put_drive(pkg, tar, hash).status == PutDriveResult::Status::Inserted) ++inserted;
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(inserted, 1);
  EXPECT_EQ(s.candidates_in(std::nullopt).points.size(), 20U);
  EXPECT_EQ(entries(drive_dir()), 1U);
}

TEST_P(StoreDrives, RegionQueryMatchesBruteForce) {
  MapStore& s = store();
  for (int d = 0; d < 4; ++d) {
    (void)put_with_archive(s, tmp(),
                           make_package("d" + std::to_string(d), 400, 100, 10 + d, 1500.0),
                           "d" + std::to_string(d), "D" + std::to_string(d));
  }
  const auto all = s.candidates_in(std::nullopt);
  ASSERT_EQ(all.points.size(), 1600U);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.008, 0.008);
  for (int q = 0; q < 40; ++q) {
    const double lat0 = kOrigin.lat_deg + u(rng), lon0 = kOrigin.lon_deg + u(rng);
    const tiles::GeoBox box{lat0, lon0, lat0 + std::abs(u(rng)) / 2, lon0 + std::abs(u(rng)) / 2};
    std::set<std::int64_t> expect, got;
    for (const auto& p : all.points) {
      if (p.position.lat_deg >= box.min_lat_deg && p.position.lat_deg <= box.max_lat_deg &&
          p.position.lon_deg >= box.min_lon_deg && p.position.lon_deg <= box.max_lon_deg) {
        expect.insert(p.id);
      }
    }
    for (const auto& l : all.lines) {
      const double la0 = std::min(l.start.lat_deg, l.end.lat_deg);
      const double la1 = std::max(l.start.lat_deg, l.end.lat_deg);
      const double lo0 = std::min(l.start.lon_deg, l.end.lon_deg);
      const double lo1 = std::max(l.start.lon_deg, l.end.lon_deg);
      if (la1 >= box.min_lat_deg && la0 <= box.max_lat_deg && lo1 >= box.min_lon_deg &&
          lo0 <= box.max_lon_deg) {
        expect.insert(l.id);
      }
    }
    const auto r = s.candidates_in(box);
    for (const auto& p : r.points) got.insert(p.id);
    for (const auto& l : r.lines) got.insert(l.id);
    EXPECT_EQ(got, expect) << "query " << q;
    for (std::size_t i = 1; i < r.points.size(); ++i) EXPECT_LT(r.points[i - 1].id, r.points[i].id);
  }
  // A box whose edges pass exactly through a candidate keeps it (closed bounds).
  const auto& p0 = all.points[17].position;
  const auto edge = s.candidates_in(tiles::GeoBox{p0.lat_deg, p0.lon_deg, p0.lat_deg, p0.lon_deg});
  ASSERT_FALSE(edge.points.empty());
  EXPECT_EQ(edge.points[0].id, all.points[17].id);
  // Exclusion by drive id.
  const auto ex = s.candidates_in(std::nullopt, std::vector<std::string>{"d1", "d2"});
  EXPECT_EQ(ex.points.size(), 800U);
  for (const auto& p : ex.points) EXPECT_NE(p.drive, s.get_drive("d1")->row);
  EXPECT_THROW((void)s.candidates_in(std::nullopt, std::vector<std::string>{"nope"}),
               NotFoundError);
  // Drives by box.
  EXPECT_EQ(s.drives_in({kOrigin.lat_deg - 0.001, kOrigin.lon_deg - 0.001, kOrigin.lat_deg + 0.001,
                         kOrigin.lon_deg + 0.001})
                .size(),
            4U);
  EXPECT_TRUE(s.drives_in({0.0, 0.0, 1.0, 1.0}).empty());
}

TEST_P(StoreDrives, AntimeridianBoxesAreQueriedAsTwoHalves) {
  MapStore& s = store();
  const GeoPoint east{10.0, 179.9995, 0.0}, west{10.0, -179.9995, 0.0};
  (void)put_with_archive(s, tmp(), make_package("e", 20, 5, 1, 50.0, east), "e", "E");
  (void)put_with_archive(s, tmp(), make_package("w", 20, 5, 2, 50.0, west), "w", "W");
  (void)put_with_archive(s, tmp(), make_package("far", 20, 5, 3, 50.0, {10.0, 0.0, 0.0}), "f", "F");
  const tiles::GeoBox across{9.99, 179.99, 10.01, -179.99};
  const auto c = s.candidates_in(across);
  std::size_t expect = 0;
  for (const auto& p : s.candidates_in(std::nullopt).points) {
    if (std::abs(p.position.lon_deg) >= 179.99 && std::abs(p.position.lat_deg - 10.0) <= 0.01) {
      ++expect;
    }
  }
  EXPECT_EQ(c.points.size(), expect);
  EXPECT_GT(expect, 20U);
  for (std::size_t i = 1; i < c.points.size(); ++i) EXPECT_LT(c.points[i - 1].id, c.points[i].id);
  const auto d = s.drives_in(across);
  ASSERT_EQ(d.size(), 2U);
  EXPECT_EQ(d[0].drive_id, "e");
  EXPECT_EQ(d[1].drive_id, "w");
}

/// 300 m east, 200 m north, then back 100 m south (a turn back on itself), one sample
/// per metre, 3 cm of lateral wobble.
DrivePackage l_drive(const std::string& id) {
  const GeoPoint origin{48.7758, 9.1829, 0.0};
  const tiles::LocalFrame f(origin);
  DrivePackage p;
  p.manifest.drive_id = id;
  p.manifest.origin = origin;
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

TEST_P(StoreDrives, DrivePathIsSimplifiedAtIngestKeepingCornersAndTheTurnBack) {
  MapStore& s = store();
  const DrivePackage p = l_drive("a");
  const std::string bytes = write_ustar({{kManifestFileName, p.manifest.drive_id}});
  const fs::path tar = tmp() / "a.tar";
  std::ofstream(tar, std::ios::binary) << bytes;
  ASSERT_EQ(s.put_drive(p, tar, content_etag(bytes)).status, PutDriveResult::Status::Inserted);
  const auto path = s.drive_path("a");
  const tiles::LocalFrame f(p.manifest.origin);
  ASSERT_EQ(path.size(), 4U);
  const std::vector<Eigen::Vector2d> corners{{0, 0}, {300, 0}, {300, 200}, {300, 100}};
  for (std::size_t i = 0; i < corners.size(); ++i) {
    EXPECT_LT((f.to_local(path[i]) - corners[i]).norm(), 0.05) << i;
  }
  EXPECT_THROW((void)s.drive_path("nope"), NotFoundError);
}

TEST_P(StoreDrives, ReopenSweepsCrashLeftovers) {
  {
    const auto s = open();
    (void)put_with_archive(*s, tmp(), make_package("a", 3, 0, 1), "a", "A");
    (void)s->begin_map_version({{"notes", "crashed build"}});
  }
  // A hard crash between rename and commit leaves a hash-named dir without a
  // row; one during the copy leaves a .tmp- dir.
  fs::create_directories(drive_dir() / std::string(64, 'e'));
  fs::create_directories(drive_dir() / ".tmp-abc-1");
  ContractOpenOptions o;
  o.orphan_grace_s = 0.0;
  const auto s = open(o);
  EXPECT_TRUE(owns(*s));
  EXPECT_EQ(entries(drive_dir()), 1U);  // only drive "a"
  const auto versions = s->list_map_versions();
  ASSERT_EQ(versions.size(), 1U);
  EXPECT_EQ(versions[0].status, MapVersionStatus::Failed);
  EXPECT_EQ(versions[0].error, "interrupted (found building on open)");
}

TEST_P(StoreDrives, ASecondOpenerNeverSweepsTheOwnersWork) {
  ContractOpenOptions o;
  o.orphan_grace_s = 0.0;
  const auto owner = open(o);
  EXPECT_TRUE(owns(*owner));
  const std::int64_t v = owner->begin_map_version({{"notes", "running build"}});
  fs::create_directories(drive_dir() / ".tmp-inflight-1");
  {
    // E.g. `polmap export --db` while the server builds: reads work, nothing is swept.
    const auto reader = open(o);
    EXPECT_FALSE(owns(*reader));
    EXPECT_EQ(reader->get_map_version(v)->status, MapVersionStatus::Building);
    EXPECT_TRUE(fs::exists(drive_dir() / ".tmp-inflight-1"));
  }
  EXPECT_EQ(owner->get_map_version(v)->status, MapVersionStatus::Building);
  owner->put_landmarks(v, {}, {});
  owner->publish_map_version(v, {}, true);  // the owner's build still publishes
  EXPECT_EQ(owner->current_map_version(), v);
}

POLMAP_STORE_CONTRACT_BACKENDS(StoreDrives);

}  // namespace
}  // namespace polmap::mapping::testing
