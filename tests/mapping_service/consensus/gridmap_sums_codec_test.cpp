// The stored bytes of a merged-gridmap sum tile: bit-exact round trips (the sums are
// added to again and again), and every malformed input refused with a FormatError that
// names the source.
#include "polmap/mapping_service/gridmap_sums_codec.hpp"

#include <gtest/gtest.h>

#include <cstring>
#include <limits>
#include <random>

#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {

GridmapSumTile sample_tile(PolLevel level, std::uint32_t seed) {
  GridmapSumTile t(level);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 50.0);
  std::vector<double> v(static_cast<std::size_t>(t.planes()));
  for (int i = 0; i < 3000; ++i) {
    // Cells in chunks 0, 5 and 15 only: the mask has gaps.
    const int chunk = i % 3 == 0 ? 0 : (i % 3 == 1 ? 5 : 15);
    const int x = (chunk % 4) * 64 + static_cast<int>(u(rng)) % 64;
    const int y = (chunk / 4) * 64 + static_cast<int>(u(rng)) % 64;
    for (auto& e : v) e = u(rng) - 10.0;
    v[0] = u(rng);  // N >= 0
    v[1] = u(rng);  // hits >= 0
    t.add(x, y, 1.0, v.data());
  }
  return t;
}

void expect_equal(const GridmapSumTile& a, const GridmapSumTile& b) {
  ASSERT_EQ(a.level(), b.level());
  for (int c = 0; c < 16; ++c) {
    ASSERT_EQ(a.has_chunk(c), b.has_chunk(c)) << c;
    if (!a.has_chunk(c)) continue;
    EXPECT_EQ(std::memcmp(a.chunk(c), b.chunk(c), sizeof(float) * a.planes() * 4096), 0) << c;
  }
}

TEST(GridmapSumsCodec, RoundTripsBitExactlyAtEveryLevel) {
  for (PolLevel level : {PolLevel::Full, PolLevel::DualHHVV, PolLevel::SingleLR}) {
    const GridmapSumTile t = sample_tile(level, 4);
    const std::string bytes = encode_gridmap_sum_tile(t);
    expect_equal(decode_gridmap_sum_tile(bytes), t);
    // Smaller than the raw floats of its three chunks (shuffle + zstd).
    EXPECT_LT(bytes.size(), 3U * t.planes() * 4096 * 4);
  }
}

TEST(GridmapSumsCodec, EmptyTileIsItsHeader) {
  const GridmapSumTile t(PolLevel::Full);
  const std::string bytes = encode_gridmap_sum_tile(t);
  EXPECT_EQ(bytes.size(), 8U);
  EXPECT_TRUE(decode_gridmap_sum_tile(bytes).empty());
}

void expect_refused(const std::string& bytes, const std::string& what) {
  try {
    (void)decode_gridmap_sum_tile(bytes, "tile 20/1/2");
    ADD_FAILURE() << "accepted: " << what;
  } catch (const FormatError& e) {
    EXPECT_NE(std::string(e.what()).find("tile 20/1/2"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
  }
}

TEST(GridmapSumsCodec, RefusesMalformedBytesNamingTheSource) {
  const std::string good = encode_gridmap_sum_tile(sample_tile(PolLevel::Full, 9));
  expect_refused(good.substr(0, 5), "header");
  std::string b = good;
  b[0] = 'X';
  expect_refused(b, "magic");
  b = good;
  b[4] = 2;
  expect_refused(b, "version");
  b = good;
  b[5] = 42;
  expect_refused(b, "level");
  b = good;
  b[6] = static_cast<char>(b[6] | 0x02);  // announces one chunk more than the stream holds
  expect_refused(b, "mask announces");
  b = good;
  b[6] = 0x01;  // announces fewer chunks than the stream holds
  b[7] = 0x00;
  expect_refused(b, "mask announces");
  expect_refused(good.substr(0, good.size() - 10), "truncated");
  expect_refused(good + "zz", "followed by other bytes");
  b = good;
  b[good.size() / 2] = static_cast<char>(b[good.size() / 2] ^ 0x55);
  expect_refused(b, "zstd");
  std::string empty_with_data = encode_gridmap_sum_tile(GridmapSumTile(PolLevel::Full)) + "x";
  expect_refused(empty_with_data, "after the header");
}

TEST(GridmapSumsCodec, RefusesNonFiniteValuesAndNegativeCounts) {
  GridmapSumTile nan_tile(PolLevel::SingleRR);
  std::vector<double> v{1.0, 1.0, std::numeric_limits<double>::quiet_NaN(), 1.0};
  nan_tile.add(3, 3, 1.0, v.data());
  expect_refused(encode_gridmap_sum_tile(nan_tile), "non-finite");
  GridmapSumTile neg(PolLevel::SingleRR);
  v = {-1.0, 0.0, 0.0, 1.0};
  neg.add(3, 3, 1.0, v.data());
  expect_refused(encode_gridmap_sum_tile(neg), "negative");
}

}  // namespace
}  // namespace polmap::mapping
