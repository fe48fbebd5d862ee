#include "polmap/tiles/localization_tile.hpp"

#include <gtest/gtest.h>
#include <zlib.h>

#include <algorithm>
#include <random>

#include "polmap/schema/errors.hpp"

namespace polmap::tiles {
namespace {

// A synthetic urban z16 tile: a 400 m street with poles/posts every ~8 m on both sides
// (≈ 100 points) and curb/wall/guardrail segments (≈ 40 lines), ids from a global sequence.
LocalizationTile urban_tile(std::uint64_t seed, double street_length_m = 400.0) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> jitter(0.0, 0.3);
  std::uniform_int_distribution<int> cls(0, 3), support(2, 12);
  std::uniform_real_distribution<double> spread(0.01, 0.12);
  LocalizationTile t;
  t.key = {16, 34584, 22672};
  t.map_version = 42;
  std::int64_t id = 1'000'000;
  for (double s = -street_length_m / 2; s < street_length_m / 2; s += 8.0) {
    for (double side : {-7.5, 7.5}) {
      PointLandmark p;
      p.id = id += 1 + (rng() % 3);
      p.position_m = {s + jitter(rng), side + jitter(rng)};
      p.scattering = static_cast<ScatteringClass>(cls(rng));
      p.support_drives = static_cast<std::uint32_t>(support(rng));
      p.spread_m = spread(rng);
      t.points.push_back(p);
    }
  }
  for (double s = -street_length_m / 2; s < street_length_m / 2; s += 20.0) {
    for (double side : {-6.0, 6.0}) {
      LineLandmark l;
      l.id = id += 1 + (rng() % 5);
      l.polyline_m = {{s + 1.0, side + jitter(rng)}, {s + 18.0, side + jitter(rng)}};
      if (rng() % 4 == 0) l.polyline_m.push_back({s + 19.5, side + 1.0 + jitter(rng)});
      l.support_drives = static_cast<std::uint32_t>(support(rng));
      l.spread_m = spread(rng);
      t.lines.push_back(l);
    }
  }
  return t;
}

void expect_equal_within_quantum(const LocalizationTile& a, const LocalizationTile& b,
                                 double quantum_m) {
  EXPECT_EQ(a.key, b.key);
  EXPECT_EQ(a.map_version, b.map_version);
  ASSERT_EQ(a.points.size(), b.points.size());
  ASSERT_EQ(a.lines.size(), b.lines.size());
  auto pa = a.points, pb = b.points;
  auto by_id = [](const auto& x, const auto& y) { return x.id < y.id; };
  std::sort(pa.begin(), pa.end(), by_id);
  std::sort(pb.begin(), pb.end(), by_id);
  for (std::size_t i = 0; i < pa.size(); ++i) {
    EXPECT_EQ(pa[i].id, pb[i].id);
    EXPECT_LE((pa[i].position_m - pb[i].position_m).cwiseAbs().maxCoeff(), quantum_m / 2 + 1e-9);
    EXPECT_EQ(pa[i].scattering, pb[i].scattering);
    EXPECT_EQ(pa[i].support_drives, pb[i].support_drives);
    EXPECT_NEAR(pa[i].spread_m, pb[i].spread_m, 0.0005 + 1e-12);
  }
  auto la = a.lines, lb = b.lines;
  std::sort(la.begin(), la.end(), by_id);
  std::sort(lb.begin(), lb.end(), by_id);
  for (std::size_t i = 0; i < la.size(); ++i) {
    EXPECT_EQ(la[i].id, lb[i].id);
    ASSERT_EQ(la[i].polyline_m.size(), lb[i].polyline_m.size());
    for (std::size_t j = 0; j < la[i].polyline_m.size(); ++j) {
      EXPECT_LE((la[i].polyline_m[j] - lb[i].polyline_m[j]).cwiseAbs().maxCoeff(),
                quantum_m / 2 + 1e-9);
    }
    EXPECT_EQ(la[i].support_drives, lb[i].support_drives);
    EXPECT_NEAR(la[i].spread_m, lb[i].spread_m, 0.0005 + 1e-12);
  }
}

TEST(LocalizationTile, RoundTripWithinQuantization) {
  const LocalizationTile t = urban_tile(1);
  const std::string bytes = encode_localization_tile(t);
  const LocalizationTile back = decode_localization_tile(bytes);
  expect_equal_within_quantum(t, back, 0.005);
  // Output is sorted by id.
  EXPECT_TRUE(std::is_sorted(back.points.begin(), back.points.end(),
                             [](const auto& a, const auto& b) { return a.id < b.id; }));
}

TEST(LocalizationTile, OtherQuantumAndExtremeValues) {
  LocalizationTile t;
  t.key = {kMaxZoom, (1 << kMaxZoom) - 1, 0};
  t.map_version = ~std::uint64_t{0};
  PointLandmark a;
  a.id = std::numeric_limits<std::int64_t>::min();
  a.position_m = {-kMaxTileCoordinateM, kMaxTileCoordinateM};
  a.support_drives = 0xFFFFFFFFu;
  a.scattering = ScatteringClass::Mixed;
  PointLandmark b;
  b.id = std::numeric_limits<std::int64_t>::max();
  b.position_m = {kMaxTileCoordinateM, -kMaxTileCoordinateM};
  t.points = {b, a};
  LineLandmark l;
  l.id = -5;
  l.polyline_m = {{0.0, 0.0}, {0.0, 0.0}};  // degenerate but legal
  t.lines = {l};
  TileEncodeOptions opt;
  opt.quantum_m = 0.01;
  const LocalizationTile back = decode_localization_tile(encode_localization_tile(t, opt));
  expect_equal_within_quantum(t, back, 0.01);
  EXPECT_EQ(back.points.front().id, std::numeric_limits<std::int64_t>::min());
}

TEST(LocalizationTile, EmptyTileAndDeterminism) {
  LocalizationTile empty;
  empty.key = {16, 1, 2};
  const std::string e = encode_localization_tile(empty);
  EXPECT_LE(e.size(), 32u);
  const LocalizationTile back = decode_localization_tile(e);
  EXPECT_TRUE(back.points.empty() && back.lines.empty());
  EXPECT_EQ(back.key, empty.key);

  LocalizationTile t = urban_tile(2);
  const std::string a = encode_localization_tile(t);
  std::shuffle(t.points.begin(), t.points.end(), std::mt19937_64(9));
  std::reverse(t.lines.begin(), t.lines.end());
  EXPECT_EQ(a, encode_localization_tile(t)) << "encoding must not depend on input order";
}

TEST(LocalizationTile, SizePerLandmarkAndPerKilometre) {
  // 1 km of urban street: 250 points and 100 lines.
  const LocalizationTile t = urban_tile(3, 1000.0);
  const std::string bytes = encode_localization_tile(t);
  TileEncodeOptions stored;
  stored.compression_level = 0;
  const std::size_t raw = encode_localization_tile(t, stored).size();
  LocalizationTile only_points = t;
  only_points.lines.clear();
  LocalizationTile no_points = t;
  no_points.points.clear();
  const double per_point = (raw - encode_localization_tile(no_points, stored).size()) /
                           static_cast<double>(t.points.size());
  const double per_line = (raw - encode_localization_tile(only_points, stored).size()) /
                          static_cast<double>(t.lines.size());
  std::printf(
      "1 km urban: %zu points, %zu lines -> %zu bytes (uncompressed %zu); "
      "%.1f B/point, %.1f B/line uncompressed\n",
      t.points.size(), t.lines.size(), bytes.size(), raw, per_point, per_line);
  EXPECT_LE(bytes.size(), 4096u);
  EXPECT_LE(per_point, 11.0);
  EXPECT_LE(per_line, 18.0);
}

TEST(LocalizationTile, RejectsBadInput) {
  LocalizationTile t = urban_tile(4);
  t.points[3].position_m.x() = std::nan("");
  EXPECT_THROW((void)encode_localization_tile(t), ValidationError);
  t = urban_tile(4);
  t.points[0].position_m.y() = 2 * kMaxTileCoordinateM;
  EXPECT_THROW((void)encode_localization_tile(t), ValidationError);
  t = urban_tile(4);
  t.lines[0].polyline_m.resize(1);
  EXPECT_THROW((void)encode_localization_tile(t), ValidationError);
  t = urban_tile(4);
  t.key = {16, 70000, 0};
  EXPECT_THROW((void)encode_localization_tile(t), ValidationError);
}

std::string error_of(std::string_view bytes) {
  try {
    (void)decode_localization_tile(bytes, "test.pmlt");
  } catch (const FormatError& e) {
    return e.what();
  }
  return "no error";
}

TEST(LocalizationTile, CorruptionIsAFormatErrorSayingWhat) {
  const std::string good = encode_localization_tile(urban_tile(5));
  EXPECT_NE(error_of("GIF89a....").find("bad magic"), std::string::npos);
  EXPECT_NE(error_of("PM").find("truncated"), std::string::npos);
  EXPECT_NE(error_of("").find("truncated"), std::string::npos);
  EXPECT_NE(error_of(good.substr(0, good.size() - 1)).find("truncated"), std::string::npos);
  EXPECT_NE(error_of(good.substr(0, 17)).find("truncated"), std::string::npos);
  EXPECT_NE(error_of(good + "x").find("trailing"), std::string::npos);
  std::string v = good;
  v[4] = 7;
  EXPECT_NE(error_of(v).find("unknown format version 7"), std::string::npos);
  EXPECT_NE(error_of(v).find("test.pmlt"), std::string::npos);
  // Every single-byte flip anywhere after the version field is caught (CRC or header checks).
  for (std::size_t i = 6; i < good.size(); ++i) {
    std::string c = good;
    c[i] = static_cast<char>(c[i] ^ 0x5A);
    EXPECT_THROW((void)decode_localization_tile(c), FormatError) << "byte " << i;
  }
  std::string c = good;
  c[good.size() / 2] ^= 1;
  EXPECT_NE(error_of(c).find("CRC-32 mismatch"), std::string::npos);
  // Every truncation is caught.
  for (std::size_t n = 0; n < good.size(); ++n) {
    EXPECT_THROW((void)decode_localization_tile(good.substr(0, n)), FormatError) << n;
  }
}

// A stored (uncompressed) tile with a valid CRC around an arbitrary body.
std::string frame_body(const std::string& body) {
  std::string out = "PMLT";
  out += std::string("\x01\x00\x00\x00", 4);
  for (std::uint32_t v :
       {static_cast<std::uint32_t>(body.size()), static_cast<std::uint32_t>(body.size())}) {
    for (int i = 0; i < 4; ++i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xFF));
  }
  out += body;
  const auto crc = static_cast<std::uint32_t>(
      crc32(0L, reinterpret_cast<const Bytef*>(out.data()), static_cast<uInt>(out.size())));
  for (int i = 0; i < 4; ++i) out.push_back(static_cast<char>((crc >> (8 * i)) & 0xFF));
  return out;
}

TEST(LocalizationTile, MalformedBodyWithValidCrc) {
  // key 16/1/2, version 3, quantum 5000 µm (0x88 0x27), spread 1000 µm (0xE8 0x07)
  const std::string head = std::string("\x10\x01\x02\x03\x88\x27\xE8\x07", 8);
  EXPECT_NO_THROW((void)decode_localization_tile(frame_body(head + std::string(2, '\0'))));
  EXPECT_NE(error_of(frame_body(head)).find("body truncated in num_points"), std::string::npos);
  // One point announced, its fields cut off.
  EXPECT_NE(error_of(frame_body(head + "\x03\x02\x02\x02\x02\x02")).find("exceeds"),
            std::string::npos);
  EXPECT_NE(error_of(frame_body(head + "\x7F")).find("num_points"), std::string::npos);
  // Line with 1 vertex.
  EXPECT_NE(error_of(frame_body(head + std::string("\x00\x01\x02\x02\x02\x01\x00\x00", 8) +
                                std::string(6, '\0')))
                .find("fewer than 2 vertices"),
            std::string::npos);
  // Bad key and bad quantum.
  EXPECT_NE(error_of(frame_body(std::string("\x19\x00\x00\x00\x88\x27\xE8\x07\x00\x00", 10)))
                .find("invalid tile key"),
            std::string::npos);
  EXPECT_NE(
      error_of(frame_body(std::string("\x10\x01\x02\x03\x00\xE8\x07\x00\x00", 9))).find("quantum"),
      std::string::npos);
  EXPECT_NE(error_of(frame_body(head + std::string(3, '\0'))).find("trailing"), std::string::npos);
}

}  // namespace
}  // namespace polmap::tiles
