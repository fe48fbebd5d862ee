// The polar -> Cartesian nearest-neighbour mapping and the coverage count N of the
// covariance gridmap against a brute-force reference: for each Cartesian cell, the
// nearest polar bin (nearest range bin, nearest beam centre) of each frame.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "polmap/radar/covariance_gridmap.hpp"

namespace polmap::radar {
namespace {

struct Frame {
  PolSpectrum spectrum;
  Pose2 pose;
};

/// Non-uniform beams over about ±60°, random sparse bins with distinct powers.
PolSpectrum random_spectrum(std::mt19937& rng, int num_range_bins, int num_beams, double fill) {
  PolSpectrum s;
  s.range_bin_m = 0.075;
  s.num_range_bins = static_cast<std::uint16_t>(num_range_bins);
  std::uniform_real_distribution<double> jitter(-0.3, 0.3);
  const double step = 120.0 / (num_beams - 1) * std::numbers::pi / 180.0;
  for (int k = 0; k < num_beams; ++k) {
    s.azimuth_bins_rad.push_back(
        static_cast<float>(-60.0 * std::numbers::pi / 180.0 +
                           (k + jitter(rng) * (k > 0 && k < num_beams - 1)) * step));
  }
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int k = 0; k < num_beams; ++k) {
    for (int i = 0; i < num_range_bins; ++i) {
      if (u(rng) >= fill) continue;
      SpectrumCell c;
      c.azimuth_bin = static_cast<std::uint16_t>(k);
      c.range_bin = static_cast<std::uint16_t>(i);
      // RR carries a value identifying the bin: |s|² = 1 + k + 1000 i (exact in float).
      c.s[3] = cfloat(static_cast<float>(std::sqrt(1.0 + k + 1000.0 * i)), 0.0F);
      s.cells.push_back(c);
    }
  }
  return s;
}

/// Brute force: nearest bin of a cell centre, or nothing outside the footprint.
bool nearest_bin(const PolSpectrum& s, const Pose2& pose, const Eigen::Vector2d& c, int& range_bin,
                 int& beam) {
  const Eigen::Vector2d v = pose.inverse() * c;
  const double r = v.norm();
  const double phi = std::atan2(v.y(), v.x());
  const auto& az = s.azimuth_bins_rad;
  const int m = static_cast<int>(az.size());
  const double lo = az[0] - 0.5 * (az[1] - az[0]);
  const double hi = az[m - 1] + 0.5 * (az[m - 1] - az[m - 2]);
  if (phi < lo || phi >= hi) return false;
  range_bin = static_cast<int>(std::lround(r / s.range_bin_m));
  if (range_bin >= s.num_range_bins) return false;
  beam = 0;
  for (int k = 1; k < m; ++k) {
    if (std::abs(phi - az[k]) < std::abs(phi - az[beam])) beam = k;
  }
  return true;
}

double bin_power(const PolSpectrum& s, int range_bin, int beam) {
  for (const auto& c : s.cells) {
    if (c.range_bin == range_bin && c.azimuth_bin == beam) return std::norm(c.s[3]);
  }
  return 0.0;
}

void check_against_brute_force(const std::vector<Frame>& frames, const CovarianceGridmap& map,
                               int stride) {
  const CellBox b = map.bounds();
  ASSERT_FALSE(b.empty());
  int checked = 0, observed = 0;
  for (int iy = b.min_iy - 3; iy < b.max_iy + 3; iy += stride) {
    for (int ix = b.min_ix - 3; ix < b.max_ix + 3; ix += stride) {
      const Eigen::Vector2d c = map.cell_center(ix, iy);
      std::uint32_t n = 0;
      double sum = 0.0;
      for (const Frame& f : frames) {
        int rb = 0, beam = 0;
        if (!nearest_bin(f.spectrum, f.pose, c, rb, beam)) continue;
        ++n;
        sum += bin_power(f.spectrum, rb, beam);
      }
      ASSERT_EQ(map.count(ix, iy), n) << "cell " << ix << "," << iy;
      const double expect = n > 0 ? sum / n : 0.0;
      ASSERT_NEAR(map.power(ix, iy), expect, 1e-5 * (1.0 + expect)) << "cell " << ix << "," << iy;
      ++checked;
      observed += n > 0;
    }
  }
  EXPECT_GT(observed, checked / 10);
}

/// Maps `frames` (0.1 s apart) into a gridmap with cfg and checks it against brute force.
void check_mapping_against_brute_force(const GridmapConfig& cfg, const std::vector<Frame>& frames,
                                       int stride) {
  CovarianceGridmap map(cfg);
  for (std::size_t f = 0; f < frames.size(); ++f) {
    map.add(frames[f].spectrum, frames[f].pose, static_cast<double>(f) * 0.1);
  }
  check_against_brute_force(frames, map, stride);
}

TEST(NearestNeighbourMapping, MatchesBruteForceForRandomPosesAndBeams) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> pos(-3.0, 3.0), yaw(-std::numbers::pi, std::numbers::pi);
  std::vector<Frame> frames;
  for (int f = 0; f < 4; ++f) {
    frames.push_back(
        {random_spectrum(rng, 160, 25, 0.15), {pos(rng) + 100.0, pos(rng) - 50.0, yaw(rng)}});
  }
  GridmapConfig cfg;
  cfg.level = PolLevel::SingleRR;
  cfg.cell_size_m = 0.1;
  check_mapping_against_brute_force(cfg, frames, 1);
}

TEST(NearestNeighbourMapping, FullRangeFootprintCountsMatchBruteForce) {
  // 80 m footprint: tile- and block-level coverage must agree with the per-cell rule.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> yaw(-std::numbers::pi, std::numbers::pi);
  std::vector<Frame> frames;
  for (int f = 0; f < 2; ++f) {
    frames.push_back(
        {random_spectrum(rng, 1067, 81, 0.003), {f * 7.3 - 20.0, f * 3.1 + 5.0, yaw(rng)}});
  }
  GridmapConfig cfg;
  cfg.level = PolLevel::SingleRR;
  check_mapping_against_brute_force(cfg, frames, 7);
}

TEST(NearestNeighbourMapping, MaxRangeLimitsFootprint) {
  std::mt19937 rng(3);
  GridmapConfig cfg;
  cfg.level = PolLevel::SingleRR;
  cfg.max_range_m = 5.0;
  CovarianceGridmap map(cfg);
  const PolSpectrum s = random_spectrum(rng, 400, 41, 0.2);
  map.add(s, {0.0, 0.0, 0.0}, 0.0);
  EXPECT_GT(map.count(map.cell_of({4.9, 0.0})[0], 0), 0U);
  EXPECT_EQ(map.count(map.cell_of({5.2, 0.0})[0], 0), 0U);
  EXPECT_EQ(map.power(map.cell_of({20.0, 0.0})[0], 0), 0.0);
}

}  // namespace
}  // namespace polmap::radar
