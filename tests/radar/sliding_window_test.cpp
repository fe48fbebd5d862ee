// Localization mode: frames older than the window leave the gridmap exactly
// (counts) and to rounding (covariances); an emptied map frees its tiles.
#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <numbers>
#include <random>

#include "polmap/radar/covariance_gridmap.hpp"

namespace polmap::radar {
namespace {

PolSpectrum spectrum_with_points(std::mt19937& rng, int num_points) {
  PolSpectrum s;
  s.range_bin_m = 0.075;
  s.num_range_bins = 400;  // 30 m
  s.noise_sigma = 0.5F;
  for (int k = 0; k < 61; ++k) {
    s.azimuth_bins_rad.push_back(static_cast<float>((-60.0 + 2.0 * k) * std::numbers::pi / 180.0));
  }
  std::uniform_int_distribution<int> rb(10, 390), az(0, 60);
  std::normal_distribution<float> n(0.0F, 3.0F);
  for (int p = 0; p < num_points; ++p) {
    const int r0 = rb(rng), a0 = az(rng);
    for (int dr = -1; dr <= 1; ++dr) {
      SpectrumCell c;
      c.range_bin = static_cast<std::uint16_t>(r0 + dr);
      c.azimuth_bin = static_cast<std::uint16_t>(a0);
      for (auto& v : c.s) v = cfloat(n(rng), n(rng));
      s.cells.push_back(c);
    }
  }
  std::sort(s.cells.begin(), s.cells.end(), [](const auto& a, const auto& b) {
    return a.azimuth_bin != b.azimuth_bin ? a.azimuth_bin < b.azimuth_bin
                                          : a.range_bin < b.range_bin;
  });
  s.cells.erase(std::unique(s.cells.begin(), s.cells.end(),
                            [](const auto& a, const auto& b) {
                              return a.azimuth_bin == b.azimuth_bin && a.range_bin == b.range_bin;
                            }),
                s.cells.end());
  return s;
}

struct Frame {
  double t;
  Pose2 pose;
  PolSpectrum s;
};

std::vector<Frame> drive(int n) {
  std::mt19937 rng(5);
  std::vector<Frame> frames;
  for (int i = 0; i < n; ++i) {
    const double t = 0.1 * i;
    frames.push_back({t, {2.0 * i, 0.3 * i, 0.05 * i}, spectrum_with_points(rng, 80)});
  }
  return frames;
}

TEST(SlidingWindow, EqualsMapOfFramesInsideTheWindow) {
  const auto frames = drive(20);
  GridmapConfig wcfg;
  wcfg.window_s = 0.45;  // keeps 5 frames (t ≥ t_now − 0.45)
  CovarianceGridmap window(wcfg);
  for (const auto& f : frames) window.add(f.s, f.pose, f.t);
  EXPECT_EQ(window.num_frames(), 5U);

  GridmapConfig dcfg;
  dcfg.window_s = 1e6;  // same storage, nothing expires
  CovarianceGridmap direct(dcfg);
  for (std::size_t i = frames.size() - 5; i < frames.size(); ++i) {
    direct.add(frames[i].s, frames[i].pose, frames[i].t);
  }
  // Every frame, for the rounding bound: the window subtracts in float what it added, so
  // a cell's sums differ from the direct map's by a few float steps of the largest sum
  // the cell held, at most the sum of all its contributions.
  GridmapConfig acfg;
  acfg.window_s = 1e6;
  CovarianceGridmap all(acfg);
  for (const auto& f : frames) all.add(f.s, f.pose, f.t);
  EXPECT_EQ(window.num_tiles(), direct.num_tiles());
  const CellBox b = direct.bounds();
  const CellBox wb = window.bounds();
  EXPECT_EQ(b.min_ix, wb.min_ix);
  EXPECT_EQ(b.max_iy, wb.max_iy);
  int data_cells = 0;
  for (int iy = b.min_iy; iy < b.max_iy; iy += 2) {
    for (int ix = b.min_ix; ix < b.max_ix; ix += 2) {
      ASSERT_EQ(window.count(ix, iy), direct.count(ix, iy)) << ix << "," << iy;
      ASSERT_EQ(window.hits(ix, iy), direct.hits(ix, iy)) << ix << "," << iy;
      const Eigen::MatrixXcd a = window.covariance(ix, iy), d = direct.covariance(ix, iy);
      const double held = all.covariance(ix, iy).norm() * all.count(ix, iy);
      const double n = std::max(1U, window.count(ix, iy));
      ASSERT_LE((a - d).norm(), 1e-12 + 8.0 * std::numeric_limits<float>::epsilon() * held / n)
          << ix << "," << iy;
      data_cells += d.norm() > 0;
    }
  }
  EXPECT_GT(data_cells, 100);
  EXPECT_NEAR(window.noise_power(), 0.25, 1e-9);
}

TEST(SlidingWindow, ForgetsOldFramesAndFreesTiles) {
  const auto frames = drive(6);
  GridmapConfig cfg;
  cfg.window_s = 0.25;
  CovarianceGridmap map(cfg);
  map.add(frames[0].s, frames[0].pose, 0.0);
  // A cell only the first frame saw: 20 m ahead of the first pose.
  const auto c0 = map.cell_of(frames[0].pose * Eigen::Vector2d(5.0, 0.0));
  EXPECT_GT(map.count(c0[0], c0[1]), 0U);
  map.add(frames[5].s, frames[5].pose, 1.0);  // far away, 1 s later
  EXPECT_EQ(map.num_frames(), 1U);
  EXPECT_EQ(map.count(c0[0], c0[1]), 0U);
  EXPECT_EQ(map.power(c0[0], c0[1]), 0.0);
  map.expire_before(2.0);
  EXPECT_EQ(map.num_frames(), 0U);
  EXPECT_EQ(map.num_tiles(), 0U);
  EXPECT_TRUE(map.bounds().empty());
}

TEST(SlidingWindow, MappingModeKeepsEverything) {
  const auto frames = drive(6);
  CovarianceGridmap map;  // window_s = 0
  for (const auto& f : frames) map.add(f.s, f.pose, f.t * 100.0);
  map.expire_before(1e9);
  EXPECT_EQ(map.num_frames(), 6U);
  const auto c0 = map.cell_of(frames[0].pose * Eigen::Vector2d(5.0, 0.0));
  EXPECT_GT(map.count(c0[0], c0[1]), 0U);
}

}  // namespace
}  // namespace polmap::radar
