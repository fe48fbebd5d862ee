// The fleet gridmap's scattering-mechanism layer: per-cell odd/even powers equal
// radar::mechanism_powers (the reference) for every level, and the tiles are coloured
// odd bounce green, even bounce magenta, brightness from amplitude, gray without
// mechanism information.
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <random>

#include "polmap/mapping_service/fleet_gridmap.hpp"
#include "polmap/radar/polarimetry.hpp"

namespace polmap::mapping {
namespace {

TEST(FleetGridmapMechanism, CellPowersEqualTheRadarReferenceAtEveryLevel) {
  std::mt19937 rng(8);
  std::normal_distribution<double> g(0.0, 1.0);
  for (PolLevel level : {PolLevel::Full, PolLevel::DualLLLR, PolLevel::DualHHVV, PolLevel::SingleLR,
                         PolLevel::SingleHH}) {
    const int q = pol_dimension(level);
    for (int trial = 0; trial < 50; ++trial) {
      // C = 1/n Σ w w^H: Hermitian, positive semi-definite.
      Eigen::MatrixXcd c = Eigen::MatrixXcd::Zero(q, q);
      for (int s = 0; s < 8; ++s) {
        Eigen::VectorXcd w(q);
        for (int i = 0; i < q; ++i) w(i) = {g(rng), g(rng)};
        c += w * w.adjoint() / 8.0;
      }
      std::vector<cdouble> layers;
      for (int i = 0; i < q; ++i)
        for (int j = i; j < q; ++j) layers.push_back(c(i, j));
      const double noise = 0.3;
      const auto [odd, even] = cell_mechanism_powers(layers, level, noise);
      const radar::MechanismPowers ref = radar::mechanism_powers(c, level, noise);
      EXPECT_NEAR(odd, ref.odd, 1e-12) << to_string(level);
      EXPECT_NEAR(even, ref.even, 1e-12) << to_string(level);
    }
  }
}

/// A 40 × 40 raster of `level` whose left half is odd bounce (LR power), right
/// half even bounce (LL and RR power), at 20 dB.
GridmapRaster two_mechanisms(PolLevel level) {
  GridmapRaster r;
  r.q = pol_dimension(level);
  r.width = r.height = 40;
  r.cell_size_m = 0.1;
  r.origin_x_m = -2.0;
  r.origin_y_m = 2.0;
  r.count.assign(1600, 10);
  r.layers.assign(static_cast<std::size_t>(r.num_layers()), std::vector<cdouble>(1600));
  for (int row = 0; row < 40; ++row) {
    for (int col = 0; col < 40; ++col) {
      const std::size_t i = static_cast<std::size_t>(row) * 40 + col;
      const bool odd = col < 20;
      for (int k = 0; k < r.q; ++k) {
        // Component 1 (LR) carries odd bounce, 0 and 2 (LL, RR) even bounce.
        const double p = r.q == 1 ? 100.0 : ((k == 1) == odd ? 100.0 : 1.0);
        r.layers[static_cast<std::size_t>(GridmapRaster::layer_index(r.q, k, k))][i] = p;
      }
    }
  }
  return r;
}

cv::Vec4b pixel_at(const FleetGridmapAccumulator& acc, bool mechanism, const tiles::LocalFrame& f,
                   const Eigen::Vector2d& xy) {
  const GeoPoint g = f.to_geo(xy);
  const int z = acc.config().base_zoom;
  const tiles::TileKey key = tiles::tile_at(g.lat_deg, g.lon_deg, z);
  const auto m = tiles::to_mercator_tiles(g.lat_deg, g.lon_deg, z);
  const int px = static_cast<int>((m.x - key.x) * kGridmapTilePixels);
  const int py = static_cast<int>((m.y - key.y) * kGridmapTilePixels);
  for (const auto& [k, png] :
       mechanism ? acc.encode_mechanism_png_tiles() : acc.encode_png_tiles()) {
    if (k != key) continue;
    const cv::Mat buf(1, static_cast<int>(png.size()), CV_8UC1, const_cast<char*>(png.data()));
    const cv::Mat img = cv::imdecode(buf, cv::IMREAD_UNCHANGED);
    return img.at<cv::Vec4b>(py, px);
  }
  ADD_FAILURE() << "no tile";
  return {};
}

TEST(FleetGridmapMechanism, OddIsGreenEvenMagentaBrightnessFromAmplitude) {
  const tiles::LocalFrame frame({48.7758, 9.1829, 0.0});
  FleetGridmapAccumulator acc;
  acc.add(two_mechanisms(PolLevel::Full), frame, PolLevel::Full);
  const Eigen::Vector2d odd_at(-1.0, 0.0), even_at(1.0, 0.0);
  // B, G, R, A: odd has green only, even red and blue only.
  const cv::Vec4b o = pixel_at(acc, true, frame, odd_at);
  const cv::Vec4b e = pixel_at(acc, true, frame, even_at);
  EXPECT_EQ(o[3], 255);
  EXPECT_GT(o[1], 100);
  EXPECT_LT(o[0], o[1] / 40 + 2);
  EXPECT_EQ(o[0], o[2]);
  EXPECT_GT(e[0], 100);
  EXPECT_EQ(e[0], e[2]);
  EXPECT_LT(e[1], e[0] / 40 + 2);
  // Brightness: the amplitude tile's gray splits between the mechanisms.
  const cv::Vec4b a = pixel_at(acc, false, frame, odd_at);
  EXPECT_NEAR(o[0] + o[1], a[0], 2);
}

TEST(FleetGridmapMechanism, OnePassGivesTheSameTilesAsEachLayerAlone) {
  const tiles::LocalFrame frame({48.7758, 9.1829, 0.0});
  FleetGridmapAccumulator acc;
  acc.add(two_mechanisms(PolLevel::Full), frame, PolLevel::Full);
  const auto all = acc.encode_all_png_tiles();
  EXPECT_EQ(all.amplitude, acc.encode_png_tiles());
  EXPECT_EQ(all.mechanism, acc.encode_mechanism_png_tiles());
  EXPECT_FALSE(all.mechanism.empty());
}

TEST(FleetGridmapMechanism, SinglePolarizationStaysGray) {
  const tiles::LocalFrame frame({48.7758, 9.1829, 0.0});
  FleetGridmapAccumulator acc;
  acc.add(two_mechanisms(PolLevel::SingleHH), frame, PolLevel::SingleHH);
  const cv::Vec4b m = pixel_at(acc, true, frame, {-1.0, 0.0});
  const cv::Vec4b a = pixel_at(acc, false, frame, {-1.0, 0.0});
  EXPECT_EQ(m, a);
  EXPECT_EQ(m[0], m[1]);
  EXPECT_EQ(m[1], m[2]);
}

}  // namespace
}  // namespace polmap::mapping
