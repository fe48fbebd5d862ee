// Same seed -> identical record streams (and files); different seeds differ.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "polmap/schema/recording_io.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/realism.hpp"
#include "polmap/sim/truth.hpp"
#include "test_dir.hpp"

namespace polmap::sim {
namespace {

/// FNV-1a over every field of every record.
struct Hasher {
  std::uint64_t h = 1469598103934665603ULL;
  void bytes(const void* p, std::size_t n) {
    const auto* b = static_cast<const unsigned char*>(p);
    for (std::size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 1099511628211ULL;
  }
  template <typename T>
  void pod(const T& v) {
    bytes(&v, sizeof v);
  }
  void record(const RecordingRecord& r) {
    if (const auto* t = std::get_if<TrajectorySample>(&r)) {
      pod(t->time_s), pod(t->lat_deg), pod(t->lon_deg), pod(t->yaw_enu_rad), pod(t->speed_mps);
      pod(t->yaw_rate_rps), pod(t->std_east_m), pod(t->solution);
    } else {
      const auto& f = std::get<SensorFrame>(r);
      pod(f.time_s), pod(f.sensor_id), pod(f.cycle_index);
      for (const auto& d : f.detections)
        pod(d.range_m), pod(d.azimuth_rad), pod(d.radial_velocity_mps), pod(d.snr_db);
      for (const auto& c : f.spectrum.cells)
        pod(c.range_bin), pod(c.azimuth_bin), bytes(c.s.data(), sizeof c.s);
      if (f.cube) bytes(f.cube->data.data(), f.cube->data.size() * sizeof(cfloat));
    }
  }
};

std::uint64_t stream_hash(const std::string& world, std::uint64_t seed, int drive, double duration,
                          bool cube = false) {
  SimConfig cfg;
  cfg.seed = seed;
  cfg.duration_s = duration;
  cfg.cube = cube;
  cfg.cube_seconds = 0.1;
  cfg.radar.cube_max_range_m = 3.0;
  auto w = load_world(world, 400.0, seed, cfg);
  DriveSimulator sim(w, cfg, drive);
  Hasher h;
  while (auto r = sim.next()) h.record(*r);
  return h.h;
}

TEST(Determinism, SameSeedSameRecords) {
  EXPECT_EQ(stream_hash("urban", 7, 0, 4.0), stream_hash("urban", 7, 0, 4.0));
  EXPECT_EQ(stream_hash("rural", 3, 1, 2.0, true), stream_hash("rural", 3, 1, 2.0, true));
}

TEST(Determinism, DifferentSeedsOrDrivesDiffer) {
  EXPECT_NE(stream_hash("urban", 7, 0, 2.0), stream_hash("urban", 8, 0, 2.0));
  EXPECT_NE(stream_hash("urban", 7, 0, 2.0), stream_hash("urban", 7, 1, 2.0));
}

TEST(Determinism, SameSeedSameWorldTruth) {
  SimConfig cfg;
  auto a = load_world("industrial", 500.0, 11, cfg);
  auto b = load_world("industrial", 500.0, 11, cfg);
  EXPECT_EQ(world_truth_json(*a, 3, 11), world_truth_json(*b, 3, 11));
}

std::string file_bytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

TEST(Determinism, SameSeedByteIdenticalRecordingFiles) {
  const util::ScopedTempDir owned(polmap::test::unique_test_dir("sim-determinism"));
  const auto dir = owned.path();
  for (int k = 0; k < 2; ++k) {
    SimConfig cfg;
    cfg.seed = 5;
    cfg.duration_s = 3.0;
    auto w = load_world("urban", 300.0, 5, cfg);
    DriveSimulator sim(w, cfg, 0);
    RecordingWriter wr(dir / (k == 0 ? "r0.pmrec" : "r1.pmrec"), sim.header());
    while (auto r = sim.next()) {
      if (const auto* t = std::get_if<TrajectorySample>(&*r)) {
        wr.write(*t);
      } else {
        wr.write(std::get<SensorFrame>(*r));
      }
    }
    wr.close();
  }
  const std::string a = file_bytes(dir / "r0.pmrec"), b = file_bytes(dir / "r1.pmrec");
  EXPECT_GT(a.size(), 1000U);
  EXPECT_EQ(a, b);
  std::filesystem::remove_all(dir);
}

TEST(Determinism, RecordedTrajectoryIsWhatTheStreamCarries) {
  // Consumer GNSS (bias, multipath, outages) under the realistic preset (INS latency): the
  // trajectory alone must be the stream's trajectory records, sample for sample.
  SimConfig cfg;
  cfg.seed = 11;
  cfg.duration_s = 3.0;
  cfg.realism = realism_preset("realistic");
  cfg.gnss.grade = GnssGrade::Consumer;
  auto w = load_world("urban", 400.0, cfg.seed, cfg);
  DriveSimulator sim(w, cfg, 2);
  const std::vector<TrajectorySample> alone = sim.recorded_trajectory();
  std::vector<TrajectorySample> streamed;
  while (auto r = sim.next()) {
    if (const auto* t = std::get_if<TrajectorySample>(&*r)) streamed.push_back(*t);
  }
  ASSERT_EQ(alone.size(), streamed.size());
  ASSERT_GT(alone.size(), 100u);
  for (std::size_t i = 0; i < alone.size(); ++i) {
    EXPECT_EQ(alone[i].time_s, streamed[i].time_s);
    EXPECT_EQ(alone[i].lat_deg, streamed[i].lat_deg) << i;
    EXPECT_EQ(alone[i].lon_deg, streamed[i].lon_deg) << i;
    EXPECT_EQ(alone[i].yaw_enu_rad, streamed[i].yaw_enu_rad) << i;
    EXPECT_EQ(alone[i].speed_mps, streamed[i].speed_mps) << i;
    EXPECT_EQ(alone[i].yaw_rate_rps, streamed[i].yaw_rate_rps) << i;
  }
  // And it carries the consumer error: metres off the exact trajectory somewhere.
  const std::vector<ExactState> exact = sim.exact_trajectory();
  double max_err_m = 0.0;
  for (std::size_t i = 0; i < alone.size(); ++i) {
    const Eigen::Vector2d p = w->frame.to_local(GeoPoint{alone[i].lat_deg, alone[i].lon_deg, 0.0});
    max_err_m = std::max(max_err_m, (p - Eigen::Vector2d(exact[i].x_m, exact[i].y_m)).norm());
  }
  EXPECT_GT(max_err_m, 0.3);
}

}  // namespace
}  // namespace polmap::sim
