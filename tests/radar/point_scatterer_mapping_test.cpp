// A point scatterer's polar response lands at the right map-frame position for a
// rotated and translated sensor pose (sensor azimuth positive to the left).
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "polmap/radar/covariance_gridmap.hpp"

namespace polmap::radar {
namespace {

/// Spectrum of one point at (range, azimuth): separable Gaussian point-spread over
/// range bins (σ = 0.6 bins) and beams (σ = 0.6 beams), odd-bounce (LR = RL).
PolSpectrum point_spectrum(double range_m, double azimuth_rad) {
  PolSpectrum s;
  s.range_bin_m = 0.075;
  s.num_range_bins = 1067;
  for (int k = 0; k < 81; ++k) {
    s.azimuth_bins_rad.push_back(static_cast<float>((-60.0 + 1.5 * k) * std::numbers::pi / 180.0));
  }
  const double fr = range_m / s.range_bin_m;
  const double fa = (azimuth_rad * 180.0 / std::numbers::pi + 60.0) / 1.5;
  for (int k = static_cast<int>(fa) - 2; k <= static_cast<int>(fa) + 3; ++k) {
    for (int i = static_cast<int>(fr) - 3; i <= static_cast<int>(fr) + 4; ++i) {
      const double w = std::exp(-0.5 * ((i - fr) * (i - fr) + (k - fa) * (k - fa)) / 0.36);
      if (w < 1e-3) continue;
      SpectrumCell c;
      c.range_bin = static_cast<std::uint16_t>(i);
      c.azimuth_bin = static_cast<std::uint16_t>(k);
      c.s[1] = c.s[2] = cfloat(0.0F, static_cast<float>(10.0 * w));
      s.cells.push_back(c);
    }
  }
  return s;
}

struct Case {
  Pose2 pose;
  double range_m;
  double azimuth_deg;
};

TEST(PointScattererMapping, LandsInTheRightCellForRotatedTranslatedPoses) {
  const Case cases[] = {
      {{0.0, 0.0, 0.0}, 10.0, 0.0},
      {{12.3, -4.1, 0.7}, 7.5, 25.0},
      {{-200.0, 350.0, -2.4}, 15.2, -38.0},
      {{55.5, 55.5, std::numbers::pi / 2}, 4.0, 50.0},
  };
  for (const Case& c : cases) {
    CovarianceGridmap map;
    const double az = c.azimuth_deg * std::numbers::pi / 180.0;
    map.add(point_spectrum(c.range_m, az), c.pose, 0.0);
    const Eigen::Vector2d truth =
        c.pose * Eigen::Vector2d(c.range_m * std::cos(az), c.range_m * std::sin(az));
    // Brightest cell and power-weighted centroid.
    const auto t = map.cell_of(truth);
    double best = -1.0, wsum = 0.0;
    Eigen::Vector2d centroid = Eigen::Vector2d::Zero(), best_xy = Eigen::Vector2d::Zero();
    for (int iy = t[1] - 30; iy <= t[1] + 30; ++iy) {
      for (int ix = t[0] - 30; ix <= t[0] + 30; ++ix) {
        const double p = map.power(ix, iy);
        if (p > best) {
          best = p;
          best_xy = map.cell_center(ix, iy);
        }
        wsum += p;
        centroid += p * map.cell_center(ix, iy);
      }
    }
    centroid /= wsum;
    // Nearest-neighbour quantization: the brightest cell lies within half a beam
    // (arc), half a range bin and half a cell diagonal of the point.
    const double tol = 0.5 * 1.5 * std::numbers::pi / 180.0 * c.range_m + 0.0375 + 0.071;
    EXPECT_LT((best_xy - truth).norm(), tol) << "range " << c.range_m;
    EXPECT_LT((centroid - truth).norm(), 0.1) << "range " << c.range_m;
    // Peak = |LR|² + |RL|² of the strongest bin = 2·(10·w_max)².
    double w_max = 0.0;
    for (const auto& cell : point_spectrum(c.range_m, az).cells)
      w_max = std::max(w_max, cell.s[1].imag() / 10.0);
    EXPECT_NEAR(best, 200.0 * w_max * w_max, 1e-3 * best);
  }
}

}  // namespace
}  // namespace polmap::radar
