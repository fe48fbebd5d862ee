// candidates.bin (package format 2): round trip within the stated quantization,
// determinism, size per feature, and every malformed input refused with the field named.
#include "polmap/mapping_service/candidates_codec.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "polmap/mapping_service/drive_package_io.hpp"

namespace polmap::mapping {
namespace {

CandidatesContent sample_content(int points, int lines, int samples) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-400.0, 400.0);
  CandidatesContent c;
  for (int i = 0; i < points; ++i) {
    PointCandidate p;
    p.position_m = {u(rng), u(rng)};
    p.strength = 2.0 + std::abs(u(rng));
    p.power_db = u(rng) / 10.0;
    p.scattering = static_cast<ScatteringClass>(i % 4);
    p.num_cells = static_cast<std::uint32_t>(1 + i % 17);
    c.points.push_back(p);
  }
  for (int i = 0; i < lines; ++i) {
    LineCandidate l;
    l.start_m = {u(rng), u(rng)};
    l.end_m = l.start_m + Eigen::Vector2d(u(rng) / 50.0, u(rng) / 50.0);
    l.strength = 1.5 + std::abs(u(rng)) / 100.0;
    c.lines.push_back(l);
  }
  for (int i = 0; i < samples; ++i) {
    TrajectorySample s;
    s.time_s = 1000.0 + 0.02 * i;
    s.lat_deg = 48.78 + 1e-6 * i;
    s.lon_deg = 9.18 + 2e-6 * i;
    s.yaw_enu_rad = 0.3 + 1e-4 * i;
    s.speed_mps = 10.0 + 0.01 * i;
    s.yaw_rate_rps = -0.01;
    s.std_east_m = 0.014F;
    s.std_north_m = 0.015F;
    s.std_yaw_rad = 0.001F;
    s.solution = static_cast<GnssSolution>(i % 3);
    c.trajectory.push_back(s);
  }
  return c;
}

/// Round trip of one version: every value within half its quantum.
void check_round_trip(std::uint32_t version) {
  const CandidatesContent c = sample_content(300, 80, 500);
  const std::string bytes = encode_candidates(c, version);
  EXPECT_EQ(bytes, encode_candidates(c, version));  // deterministic
  EXPECT_EQ(bytes[4], static_cast<char>(version));  // u32 little-endian version
  // The trajectory quanta of the version (schema/drive_package.md, candidates.bin).
  const double time_q = version == 1 ? 1e-6 : 1e-4, yaw_q = version == 1 ? 1e-6 : 1e-5;
  // Strength: a step of 1/200 (v1) or 1/50 (v2) in ln(1 + s); power 0.05 or 0.25 dB.
  const double strength_rel = version == 1 ? 0.003 : 0.0101, power_q = version == 1 ? 0.05 : 0.25;
  const CandidatesContent d = decode_candidates(bytes);
  ASSERT_EQ(d.points.size(), c.points.size());
  ASSERT_EQ(d.lines.size(), c.lines.size());
  ASSERT_EQ(d.trajectory.size(), c.trajectory.size());
  for (std::size_t i = 0; i < c.points.size(); ++i) {
    EXPECT_LE((d.points[i].position_m - c.points[i].position_m).cwiseAbs().maxCoeff(),
              0.5e-3 + 1e-9);
    EXPECT_NEAR(d.points[i].strength, c.points[i].strength,
                strength_rel * (1.0 + c.points[i].strength));
    EXPECT_NEAR(d.points[i].power_db, c.points[i].power_db, 0.5 * power_q + 1e-9);
    EXPECT_EQ(d.points[i].scattering, c.points[i].scattering);
    EXPECT_EQ(d.points[i].num_cells, c.points[i].num_cells);
  }
  for (std::size_t i = 0; i < c.lines.size(); ++i) {
    EXPECT_LE((d.lines[i].start_m - c.lines[i].start_m).cwiseAbs().maxCoeff(), 0.5e-2 + 1e-9);
    EXPECT_LE((d.lines[i].end_m - c.lines[i].end_m).cwiseAbs().maxCoeff(), 1e-2 + 1e-9);
  }
  for (std::size_t i = 0; i < c.trajectory.size(); ++i) {
    const auto &a = c.trajectory[i], &b = d.trajectory[i];
    EXPECT_NEAR(b.time_s, a.time_s, 0.5 * time_q + 1e-9);
    EXPECT_NEAR(b.lat_deg, a.lat_deg, 0.5e-8 + 1e-12);
    EXPECT_NEAR(b.lon_deg, a.lon_deg, 0.5e-8 + 1e-12);
    EXPECT_NEAR(b.yaw_enu_rad, a.yaw_enu_rad, 0.5 * yaw_q + 1e-12);
    EXPECT_NEAR(b.yaw_rate_rps, a.yaw_rate_rps, 0.5 * yaw_q + 1e-12);
    EXPECT_NEAR(b.speed_mps, a.speed_mps, 0.5e-3 + 1e-9);
    EXPECT_NEAR(b.std_east_m, a.std_east_m, 0.5e-3 + 1e-6);
    EXPECT_NEAR(b.std_yaw_rad, a.std_yaw_rad, 0.5 * yaw_q + 1e-6);
    EXPECT_EQ(b.solution, a.solution);
  }
  // Quantizing twice changes nothing: decode(encode(x)) is a fixed point.
  EXPECT_EQ(encode_candidates(d, version), bytes);
  // Compact: a few bytes per feature (the GeoPackage costs ~400).
  EXPECT_LT(bytes.size(), 15.0 * (300 + 80 + 500));
}

TEST(CandidatesCodec, RoundTripKeepsValuesWithinTheQuantization) { check_round_trip(2); }

TEST(CandidatesCodec, VersionOneFilesOfOlderVehiclesAreStillRead) { check_round_trip(1); }

TEST(CandidatesCodec, VersionTwoIsSmallerForTheSameContent) {
  // Realistic time stamps: 50 Hz samples with jitter, thinned as the writer's simplification
  // does; yaw and yaw rate of a gentle curve.
  CandidatesContent c;
  std::mt19937 rng(3);
  std::normal_distribution<double> jitter(0.0, 2e-4);
  double t = 1.7e9, yaw = 0.3;
  for (int i = 0; i < 500; ++i) {
    TrajectorySample s;
    t += 0.02 * (1 + i % 7) + jitter(rng);
    yaw += 0.001 * std::sin(0.01 * i);
    s.time_s = t;
    s.lat_deg = 48.78 + 1e-6 * i;
    s.lon_deg = 9.18 + 1e-6 * i;
    s.yaw_enu_rad = yaw;
    s.yaw_rate_rps = 0.05 * std::sin(0.01 * i) + jitter(rng);
    s.speed_mps = 10.0;
    c.trajectory.push_back(s);
  }
  const std::size_t v1 = encode_candidates(c, 1).size(), v2 = encode_candidates(c, 2).size();
  EXPECT_LT(static_cast<double>(v2), 0.85 * static_cast<double>(v1)) << v1 << " vs " << v2;
}

TEST(CandidatesCodec, MalformedInputNamesTheField) {
  const std::string good = encode_candidates(sample_content(20, 5, 30));
  const auto field_of = [](const std::string& bytes, CandidatesDecodeLimits lim = {}) {
    try {
      (void)decode_candidates(bytes, lim);
    } catch (const PackageFormatError& e) {
      EXPECT_EQ(e.error().file, "candidates.bin");
      return e.error().field;
    }
    return std::string("(accepted)");
  };
  EXPECT_EQ(field_of(good.substr(0, 10)), "header");
  std::string magic = good;
  magic[0] = 'X';
  EXPECT_EQ(field_of(magic), "header");
  std::string version = good;
  version[4] = 9;
  EXPECT_EQ(field_of(version), "version");
  EXPECT_EQ(field_of(good.substr(0, good.size() - 3)), "body");  // truncated stream
  EXPECT_EQ(field_of(good + "x"), "body");                       // trailing bytes
  std::string flipped = good;
  flipped.back() ^= 0x55;
  EXPECT_EQ(field_of(flipped), "body");
  // Limits apply before anything is inflated or reserved.
  CandidatesDecodeLimits lim;
  lim.max_points = 10;
  EXPECT_EQ(field_of(good, lim), "points");
  std::string bomb = good;
  bomb[8] = bomb[9] = bomb[10] = static_cast<char>(0xff);  // claims a huge body
  EXPECT_EQ(field_of(bomb), "header");
  EXPECT_EQ(field_of(good), "(accepted)");
}

}  // namespace
}  // namespace polmap::mapping
