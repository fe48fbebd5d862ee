// Compact gridmap codes (package format 2): error bounds against the exact covariance,
// positive semi-definiteness of what is decoded, the noise-floor mask, count limits and
// the consistency check of stored codes.
#include "polmap/mapping_service/gridmap_codec.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <vector>

namespace polmap::mapping {
namespace {

constexpr int kQ = 3;
constexpr int kL = 6;

int layer_of(int i, int j) { return i * kQ - i * (i - 1) / 2 + (j - i); }

/// C = 1/n Σ k kᴴ of n random vectors with per-component amplitudes `amp`.
std::vector<std::complex<float>> random_covariance(std::mt19937& rng, int n,
                                                   const std::array<double, 3>& amp) {
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::Matrix3cd c = Eigen::Matrix3cd::Zero();
  for (int s = 0; s < n; ++s) {
    Eigen::Vector3cd k;
    for (int i = 0; i < kQ; ++i) k[i] = cdouble(g(rng), g(rng)) * amp[i];
    c += k * k.adjoint() / double(n);
  }
  std::vector<std::complex<float>> out(kL);
  for (int i = 0; i < kQ; ++i)
    for (int j = i; j < kQ; ++j) out[layer_of(i, j)] = std::complex<float>(c(i, j));
  return out;
}

Eigen::Matrix3cd matrix(const GridmapCodec::Cell& c) {
  Eigen::Matrix3cd m;
  for (int i = 0; i < kQ; ++i) {
    for (int j = i; j < kQ; ++j) {
      m(i, j) = c.layers[layer_of(i, j)];
      m(j, i) = std::conj(m(i, j));
    }
  }
  return m;
}

TEST(GridmapCodec, StrongCellsKeepPowerComponentsAndPhases) {
  const double noise = 2.0;
  const GridmapCodecConfig cfg;
  const GridmapCodec codec(kQ, noise, cfg);
  std::mt19937 rng(3);
  std::vector<std::uint16_t> codes(codec.codes_per_cell());
  double worst_power = 0.0, worst_component_db = 0.0, worst_phase = 0.0;
  for (int trial = 0; trial < 2000; ++trial) {
    // 10..60 dB over the noise, components within 10 dB of each other, partly coherent.
    const double level = std::sqrt(noise * std::pow(10.0, (10.0 + 50.0 * trial / 2000.0) / 10.0));
    const std::array<double, 3> amp{level, level * 0.5, level * 0.3};
    const auto c = random_covariance(rng, 1 + trial % 20, amp);
    codec.encode_cell(40, 30, c, codes);
    ASSERT_TRUE(codec.valid_codes(codes));
    const GridmapCodec::Cell d = codec.decode_cell(codes);
    EXPECT_EQ(d.n, 40U);
    EXPECT_EQ(d.hits, 30U);
    double tr = 0.0, tr_d = 0.0;
    for (int i = 0; i < kQ; ++i) {
      tr += c[layer_of(i, i)].real();
      tr_d += d.layers[layer_of(i, i)].real();
    }
    worst_power = std::max(worst_power, std::abs(tr_d / tr - 1.0));
    for (int i = 0; i < kQ; ++i) {
      const double v = c[layer_of(i, i)].real();
      if (v < 9.0 * noise) continue;  // components above 3σ of the noise
      worst_component_db = std::max(
          worst_component_db, std::abs(10.0 * std::log10(d.layers[layer_of(i, i)].real() / v)));
      for (int j = i + 1; j < kQ; ++j) {
        const cdouble x(c[layer_of(i, j)]);
        const double vj = c[layer_of(j, j)].real();
        if (vj < 9.0 * noise || std::abs(x) < 0.3 * std::sqrt(v * vj)) continue;
        worst_phase =
            std::max(worst_phase, std::abs(std::arg(d.layers[layer_of(i, j)] * std::conj(x))));
      }
    }
  }
  EXPECT_LT(worst_power, cfg.power_step);      // trace coded on its own
  EXPECT_LT(worst_component_db, 0.5);          // the format's bound
  EXPECT_LT(worst_phase * 180.0 / M_PI, 5.0);  // the format's bound
  EXPECT_GT(worst_component_db, 0.0);          // it is lossy, not a copy
}

TEST(GridmapCodec, DecodedCovarianceIsPositiveSemiDefiniteEvenForRankOneCells) {
  const GridmapCodec codec(kQ, 1.0);
  std::mt19937 rng(5);
  std::vector<std::uint16_t> codes(codec.codes_per_cell());
  for (int trial = 0; trial < 500; ++trial) {
    // One look: C = k kᴴ, rank 1, 20..80 dB: quantizing C itself makes it indefinite.
    const double a = std::pow(10.0, (20.0 + 60.0 * trial / 500.0) / 20.0);
    const auto c = random_covariance(rng, 1, {a, a * 0.1, a * 0.01});
    codec.encode_cell(7, 1, c, codes);
    const Eigen::Matrix3cd m = matrix(codec.decode_cell(codes));
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3cd> es(m);
    EXPECT_GE(es.eigenvalues().minCoeff(), -1e-9 * es.eigenvalues().maxCoeff()) << trial;
  }
}

TEST(GridmapCodec, CellsBelowTheFloorAreStoredEmptyWithTheirCountRounded) {
  const GridmapCodecConfig cfg;  // floor −3 dB over q σ², 2 significant bits of N
  const GridmapCodec codec(kQ, 1.0, cfg);
  std::vector<std::uint16_t> codes(codec.codes_per_cell());
  std::vector<std::complex<float>> weak(kL);
  for (int i = 0; i < kQ; ++i) weak[layer_of(i, i)] = 0.1F;  // trace 0.3 < 0.5·3
  codec.encode_cell(1000, 12, weak, codes);
  EXPECT_TRUE(codec.valid_codes(codes));
  const GridmapCodec::Cell d = codec.decode_cell(codes);
  EXPECT_EQ(d.hits, 0U);
  EXPECT_EQ(d.n, 1024U);  // 1000 with 2 significant bits
  for (int l = 0; l < kL; ++l) EXPECT_EQ(d.layers[l], cdouble{});
  // An unobserved cell is all zeros (sparse blocks).
  codec.encode_cell(0, 0, weak, codes);
  for (auto k : codes) EXPECT_EQ(k, 0);
  EXPECT_EQ(codec.decode_cell(codes).n, 0U);
}

TEST(GridmapCodec, CountsAboveTheCodeRangeKeepPersistence) {
  const GridmapCodec codec(kQ, 1.0);
  std::vector<std::uint16_t> codes(codec.codes_per_cell());
  std::vector<std::complex<float>> c(kL);
  for (int i = 0; i < kQ; ++i) c[layer_of(i, i)] = 100.0F;
  codec.encode_cell(200'000, 50'000, c, codes);
  const GridmapCodec::Cell d = codec.decode_cell(codes);
  EXPECT_EQ(d.n, kCompactMaxCount);
  EXPECT_NEAR(double(d.hits) / d.n, 0.25, 1e-4);
}

TEST(GridmapCodec, InconsistentCodesAreRejected) {
  const GridmapCodec codec(kQ, 1.0);
  std::vector<std::uint16_t> codes(codec.codes_per_cell(), 0);
  EXPECT_TRUE(codec.valid_codes(codes));
  codes[3] = 5;  // data where N = 0
  EXPECT_FALSE(codec.valid_codes(codes));
  codes.assign(codes.size(), 0);
  codes[0] = 3;
  codes[1] = 4;  // hits > N
  EXPECT_FALSE(codec.valid_codes(codes));
  codes[1] = 2;  // hits but no power code
  EXPECT_FALSE(codec.valid_codes(codes));
  codes[2] = 10;
  codes[3] = static_cast<std::uint16_t>(codec.max_magnitude_code() + 1);  // beyond the range
  EXPECT_FALSE(codec.valid_codes(codes));
  codes[3] = codec.max_magnitude_code();
  EXPECT_TRUE(codec.valid_codes(codes));
  EXPECT_FALSE(codec.valid_codes(std::vector<std::uint16_t>(4)));  // wrong size
}

}  // namespace
}  // namespace polmap::mapping
