// Recording format: round trips within the documented quantization,
// determinism, and that every truncation / corruption is a FormatError.
#include "polmap/schema/recording_io.hpp"

#include <gtest/gtest.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "polmap/schema/errors.hpp"
#include "polmap/schema/json.hpp"
#include "test_dir.hpp"

namespace polmap {
namespace {

namespace fs = std::filesystem;

class TempDir {
 public:
  TempDir() { path_ = polmap::test::unique_test_dir("recording"); }
  ~TempDir() { fs::remove_all(path_); }
  [[nodiscard]] fs::path operator/(const std::string& name) const { return path_ / name; }

 private:
  fs::path path_;
};

std::vector<char> read_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}
void write_bytes(const fs::path& p, const std::vector<char>& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

RecordingHeader make_header(bool has_cube = false) {
  RecordingHeader h;
  h.drive_id = "drive_0";
  h.vehicle_id = "test-vehicle";
  h.world = "unit-test";
  h.origin = {48.7665, 11.4258, 374.5};
  h.sensors = default_front_mounts();
  h.start_time_s = 1000.0;
  h.has_cube = has_cube;
  h.producer = "recording_io_test";
  return h;
}

TrajectorySample make_sample(std::mt19937& rng, double t) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  TrajectorySample s;
  s.time_s = t;
  s.lat_deg = 48.7665 + 1e-4 * u(rng);
  s.lon_deg = 11.4258 + 1e-4 * u(rng);
  s.yaw_enu_rad = 3.0 * u(rng);
  s.speed_mps = 10.0 + 5.0 * u(rng);
  s.yaw_rate_rps = 0.1 * u(rng);
  s.std_east_m = 0.014F;
  s.std_north_m = 0.014F;
  s.std_yaw_rad = 0.001F;
  s.solution = static_cast<GnssSolution>(rng() % 3);
  return s;
}

/// A frame with realistic value ranges: amplitudes log-uniform from below the
/// noise to 80 dB above it, some channels exactly zero, sorted sparse cells.
SensorFrame make_frame(std::mt19937& rng, std::uint32_t cycle, std::uint8_t sensor, int num_cells,
                       int num_dets, bool cube = false) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  SensorFrame f;
  f.cycle_index = cycle;
  f.sensor_id = sensor;
  f.time_s = 1000.0 + 0.1 * cycle + 0.033 * sensor;
  for (int i = 0; i < num_dets; ++i) {
    Detection d;
    d.range_m = static_cast<float>(80.0 * u(rng));
    d.azimuth_rad = static_cast<float>((u(rng) - 0.5) * 2.0 * 1.0472);
    d.radial_velocity_mps = static_cast<float>((u(rng) - 0.5) * 10.0);
    d.snr_db = static_cast<float>(12.0 + 60.0 * u(rng));
    f.detections.push_back(d);
  }
  PolSpectrum& sp = f.spectrum;
  sp.range_bin_m = 0.075;
  sp.num_range_bins = 1067;
  for (int a = 0; a < 81; ++a)
    sp.azimuth_bins_rad.push_back(static_cast<float>(-1.0472 + a * 0.02618));
  sp.noise_sigma = 0.37F;
  // Choose distinct (az, r) cells, then sort.
  std::vector<std::uint32_t> keys;
  while (static_cast<int>(keys.size()) < num_cells) {
    keys.push_back(static_cast<std::uint32_t>((rng() % 81) << 16 | (rng() % 1067)));
    if (static_cast<int>(keys.size()) == num_cells) {
      std::sort(keys.begin(), keys.end());
      keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    }
  }
  for (std::uint32_t k : keys) {
    SpectrumCell c;
    c.azimuth_bin = static_cast<std::uint16_t>(k >> 16);
    c.range_bin = static_cast<std::uint16_t>(k & 0xFFFF);
    for (int ch = 0; ch < 4; ++ch) {
      if (u(rng) < 0.1) continue;  // exactly zero channel
      const double amp = sp.noise_sigma * std::pow(10.0, (-10.0 + 90.0 * u(rng)) / 20.0);
      const double ph = 2.0 * 3.14159265358979 * u(rng);
      c.s[ch] =
          cfloat(static_cast<float>(amp * std::cos(ph)), static_cast<float>(amp * std::sin(ph)));
    }
    sp.cells.push_back(c);
  }
  if (cube) {
    DataCube dc;
    dc.num_range_bins = 64;
    dc.num_chirps = 8;
    dc.num_virtual_channels = 4;
    dc.range_bin_m = 0.075;
    dc.chirp_interval_s = 5e-5;
    std::normal_distribution<float> n(0.0F, 1.0F);
    dc.data.resize(4u * 4 * 8 * 64);
    for (auto& v : dc.data) v = cfloat(n(rng) * 1e3F, n(rng) * 1e-2F);
    dc.data[5] = {};
    f.cube = std::move(dc);
  }
  return f;
}

/// Writes a small mixed recording and returns the records written.
std::vector<RecordingRecord> write_sample_recording(const fs::path& path, std::uint32_t seed,
                                                    int cycles, int cells, int dets,
                                                    bool cube = false) {
  std::mt19937 rng(seed);
  std::vector<RecordingRecord> written;
  RecordingWriter w(path, make_header(cube));
  for (int c = 0; c < cycles; ++c) {
    for (int k = 0; k < 5; ++k) {
      written.emplace_back(make_sample(rng, 1000.0 + 0.1 * c + 0.02 * k));
      w.write(std::get<TrajectorySample>(written.back()));
    }
    for (std::uint8_t s = 0; s < 3; ++s) {
      written.emplace_back(make_frame(rng, c, s, cells, dets, cube && s == 0));
      w.write(std::get<SensorFrame>(written.back()));
    }
  }
  w.close();
  return written;
}

/// Reads a whole recording; returns all records.
std::vector<RecordingRecord> read_all(const fs::path& path) {
  RecordingReader r(path);
  std::vector<RecordingRecord> out;
  while (auto rec = r.next()) out.push_back(std::move(*rec));
  EXPECT_TRUE(r.at_end());
  return out;
}

void expect_frame_close(const SensorFrame& a, const SensorFrame& b) {
  EXPECT_EQ(a.cycle_index, b.cycle_index);
  EXPECT_EQ(a.sensor_id, b.sensor_id);
  EXPECT_EQ(a.time_s, b.time_s);
  ASSERT_EQ(a.detections.size(), b.detections.size());
  for (std::size_t i = 0; i < a.detections.size(); ++i) {
    const Detection& x = a.detections[i];
    const Detection& y = b.detections[i];
    // Half a step plus float rounding of the decoded value.
    EXPECT_NEAR(x.range_m, y.range_m, kDetectionRangeStep_m / 2 + 1e-5);
    EXPECT_NEAR(x.azimuth_rad, y.azimuth_rad, kDetectionAzimuthStep_rad / 2 + 1e-7);
    EXPECT_NEAR(x.radial_velocity_mps, y.radial_velocity_mps,
                kDetectionVelocityStep_mps / 2 + 1e-6);
    EXPECT_NEAR(x.snr_db, y.snr_db, kDetectionSnrStep_db / 2 + 1e-5);
  }
  const PolSpectrum& p = a.spectrum;
  const PolSpectrum& q = b.spectrum;
  EXPECT_EQ(p.range_bin_m, q.range_bin_m);
  EXPECT_EQ(p.num_range_bins, q.num_range_bins);
  EXPECT_EQ(p.azimuth_bins_rad, q.azimuth_bins_rad);
  EXPECT_EQ(p.noise_sigma, q.noise_sigma);
  ASSERT_EQ(p.cells.size(), q.cells.size());
  for (std::size_t i = 0; i < p.cells.size(); ++i) {
    EXPECT_EQ(p.cells[i].azimuth_bin, q.cells[i].azimuth_bin);
    EXPECT_EQ(p.cells[i].range_bin, q.cells[i].range_bin);
    for (int ch = 0; ch < 4; ++ch) {
      const cfloat s = p.cells[i].s[ch];
      const cfloat t = q.cells[i].s[ch];
      const double max_comp = std::max(std::abs(s.real()), std::abs(s.imag()));
      // Documented bound: max(max(|I|,|Q|)/127, sigma/512), plus float rounding.
      const double bound =
          std::max(max_comp / 127.0, p.noise_sigma / 512.0) * (1 + 1e-6) + max_comp * 1e-7;
      ASSERT_LE(std::abs(s.real() - t.real()), bound) << "cell " << i << " ch " << ch;
      ASSERT_LE(std::abs(s.imag() - t.imag()), bound) << "cell " << i << " ch " << ch;
      if (s == cfloat{}) {
        EXPECT_EQ(t, cfloat{});
      }
    }
  }
  ASSERT_EQ(a.cube.has_value(), b.cube.has_value());
  if (a.cube) {
    const DataCube& c = *a.cube;
    const DataCube& d = *b.cube;
    EXPECT_EQ(c.num_range_bins, d.num_range_bins);
    EXPECT_EQ(c.num_chirps, d.num_chirps);
    EXPECT_EQ(c.num_virtual_channels, d.num_virtual_channels);
    EXPECT_EQ(c.range_bin_m, d.range_bin_m);
    EXPECT_EQ(c.chirp_interval_s, d.chirp_interval_s);
    EXPECT_EQ(c.element_spacing_wavelengths, d.element_spacing_wavelengths);
    ASSERT_EQ(c.data.size(), d.data.size());
    const std::size_t r = c.num_range_bins;
    for (std::size_t l = 0; l < c.data.size() / r; ++l) {
      double line_max = 0;
      for (std::size_t k = 0; k < r; ++k) {
        line_max = std::max({line_max, double{std::abs(c.data[l * r + k].real())},
                             double{std::abs(c.data[l * r + k].imag())}});
      }
      for (std::size_t k = 0; k < r; ++k) {
        const cfloat s = c.data[l * r + k];
        const cfloat t = d.data[l * r + k];
        ASSERT_LE(std::abs(s.real() - t.real()), line_max / 32767.0 * (1 + 1e-6));
        ASSERT_LE(std::abs(s.imag() - t.imag()), line_max / 32767.0 * (1 + 1e-6));
      }
    }
  }
}

void expect_records_close(const std::vector<RecordingRecord>& a,
                          const std::vector<RecordingRecord>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].index(), b[i].index()) << "record " << i;
    if (const auto* s = std::get_if<TrajectorySample>(&a[i])) {
      const auto& t = std::get<TrajectorySample>(b[i]);
      // Trajectory samples are lossless.
      EXPECT_EQ(nlohmann::json(*s), nlohmann::json(t));
    } else {
      expect_frame_close(std::get<SensorFrame>(a[i]), std::get<SensorFrame>(b[i]));
    }
  }
}

/// The bytes of write_sample_recording(dir / "good.pmrec", seed, cycles, cells, dets).
std::vector<char> sample_recording_bytes(const TempDir& dir, std::uint32_t seed, int cycles,
                                         int cells, int dets) {
  const auto good = dir / "good.pmrec";
  write_sample_recording(good, seed, cycles, cells, dets);
  return read_bytes(good);
}

/// Runs a complete read and returns the FormatError message, or "" if the file read cleanly.
std::string read_error(const fs::path& path) {
  try {
    RecordingReader r(path);
    while (r.next()) {
    }
  } catch (const FormatError& e) {
    return e.what();
  }
  return "";
}

TEST(RecordingIo, RoundTripWithinDocumentedQuantization) {
  TempDir dir;
  const auto path = dir / "drive.pmrec";
  const auto written = write_sample_recording(path, 1, 6, 500, 60);
  RecordingReader r(path);
  const RecordingHeader h = make_header();
  EXPECT_EQ(nlohmann::json(r.header()), nlohmann::json(h));
  EXPECT_EQ(r.file_format_version(), kRecordingFormatVersion);
  EXPECT_EQ(r.file_size(), fs::file_size(path));
  expect_records_close(written, read_all(path));
}

TEST(RecordingIo, RoundTripWithDataCube) {
  TempDir dir;
  const auto path = dir / "cube.pmrec";
  const auto written = write_sample_recording(path, 2, 2, 100, 10, /*cube=*/true);
  const auto read = read_all(path);
  ASSERT_TRUE(std::get<SensorFrame>(read[5]).cube.has_value());
  expect_records_close(written, read);
}

TEST(RecordingIo, QuantizationErrorIsSmallComparedToSignalAndNoise) {
  // Speckle-like cells 10 dB above the noise dominate real spectra. Documented
  // (recording.md): signal-to-quantization-noise ratio ~45 dB for such complex
  // Gaussian samples, so their quantization noise is ~35 dB below thermal noise.
  TempDir dir;
  const auto path = dir / "noise.pmrec";
  std::mt19937 rng(7);
  std::normal_distribution<float> n(0.0F, 1.0F);
  SensorFrame f = make_frame(rng, 0, 0, 3000, 0);
  const float sigma = f.spectrum.noise_sigma;
  const float rms = std::sqrt(10.0F) * sigma;  // 10 dB above noise
  for (auto& c : f.spectrum.cells) {
    for (auto& s : c.s) s = cfloat(n(rng), n(rng)) * (rms / std::sqrt(2.0F));
  }
  {
    RecordingWriter w(path, make_header());
    w.write(f);
  }
  const auto read = read_all(path);
  const auto& g = std::get<SensorFrame>(read.at(0));
  double err2 = 0;
  double sig2 = 0;
  for (std::size_t i = 0; i < f.spectrum.cells.size(); ++i) {
    for (int ch = 0; ch < 4; ++ch) {
      err2 += std::norm(g.spectrum.cells[i].s[ch] - f.spectrum.cells[i].s[ch]);
      sig2 += std::norm(f.spectrum.cells[i].s[ch]);
    }
  }
  const double n_samples = 4.0 * f.spectrum.cells.size();
  const double sqnr_db = 10.0 * std::log10(sig2 / err2);
  const double below_noise_db = 10.0 * std::log10(err2 / n_samples / (sigma * sigma));
  EXPECT_GT(sqnr_db, 42.0);
  EXPECT_LT(below_noise_db, -32.0);
  std::printf("spectrum SQNR %.1f dB, quantization noise %.1f dB re thermal noise\n", sqnr_db,
              below_noise_db);
}

TEST(RecordingIo, IdenticalInputGivesIdenticalBytes) {
  TempDir dir;
  write_sample_recording(dir / "a.pmrec", 3, 4, 300, 30);
  write_sample_recording(dir / "b.pmrec", 3, 4, 300, 30);
  EXPECT_EQ(read_bytes(dir / "a.pmrec"), read_bytes(dir / "b.pmrec"));
}

TEST(RecordingIo, WriteRecordVariantMatchesTypedWrites) {
  TempDir dir;
  std::mt19937 rng(4);
  const RecordingRecord a = make_sample(rng, 1.0);
  const RecordingRecord b = make_frame(rng, 0, 1, 20, 3);
  {
    RecordingWriter w(dir / "v.pmrec", make_header());
    w.write(a);
    w.write(b);
  }
  {
    RecordingWriter w(dir / "t.pmrec", make_header());
    w.write(std::get<TrajectorySample>(a));
    w.write(std::get<SensorFrame>(b));
    w.close();
    EXPECT_EQ(w.bytes_written(), fs::file_size(dir / "t.pmrec"));
  }
  EXPECT_EQ(read_bytes(dir / "v.pmrec"), read_bytes(dir / "t.pmrec"));
}

TEST(RecordingIo, EmptyStreamIsValid) {
  TempDir dir;
  const auto path = dir / "empty.pmrec";
  { RecordingWriter w(path, make_header()); }
  RecordingReader r(path);
  EXPECT_EQ(r.header().drive_id, "drive_0");
  EXPECT_EQ(r.header().sensors.size(), 3u);
  EXPECT_FALSE(r.next().has_value());
  EXPECT_TRUE(r.at_end());
  EXPECT_FALSE(r.next().has_value());
  EXPECT_EQ(r.offset(), r.file_size());
}

TEST(RecordingIo, FrameWithoutCellsOrDetections) {
  TempDir dir;
  const auto path = dir / "bare.pmrec";
  SensorFrame f;
  f.sensor_id = 2;
  f.time_s = 3.5;
  f.spectrum.noise_sigma = 0.0F;  // allowed without cells
  {
    RecordingWriter w(path, make_header());
    w.write(f);
  }
  const auto read = read_all(path);
  ASSERT_EQ(read.size(), 1u);
  expect_frame_close(f, std::get<SensorFrame>(read[0]));
}

TEST(RecordingIo, TruncationAtEveryOffsetIsFormatErrorNamingFileAndOffset) {
  TempDir dir;
  const auto bytes = sample_recording_bytes(dir, 5, 2, 40, 8);
  ASSERT_GT(bytes.size(), 1000u);
  const auto cut = dir / "cut.pmrec";
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    write_bytes(cut, std::vector<char>(bytes.begin(), bytes.begin() + static_cast<long>(n)));
    try {
      RecordingReader r(cut);
      while (r.next()) {
      }
      FAIL() << "truncation at " << n << " of " << bytes.size() << " bytes was not detected";
    } catch (const FormatError& e) {
      const std::string msg = e.what();
      ASSERT_NE(msg.find(cut.string()), std::string::npos) << msg;
      ASSERT_NE(msg.find(" at byte "), std::string::npos) << msg;
      ASSERT_LE(e.offset(), n) << msg;
    }
  }
}

TEST(RecordingIo, EveryCorruptedByteIsDetected) {
  TempDir dir;
  const auto bytes = sample_recording_bytes(dir, 6, 2, 40, 8);
  const auto bad = dir / "bad.pmrec";
  std::mt19937 rng(11);
  // Every position once with a random non-zero XOR mask: the format has no
  // unchecked bytes (preamble fields are validated, everything else is under a CRC).
  for (std::size_t pos = 0; pos < bytes.size(); ++pos) {
    auto copy = bytes;
    copy[pos] = static_cast<char>(copy[pos] ^ static_cast<char>(1 + rng() % 255));
    write_bytes(bad, copy);
    const std::string msg = read_error(bad);
    ASSERT_FALSE(msg.empty()) << "corruption at byte " << pos << " not detected";
    ASSERT_NE(msg.find(bad.string()), std::string::npos) << msg;
  }
}

TEST(RecordingIo, RandomMultiByteCorruptionNeverCrashes) {
  TempDir dir;
  const auto bytes = sample_recording_bytes(dir, 8, 3, 200, 20);
  const auto bad = dir / "bad.pmrec";
  std::mt19937 rng(12);
  for (int trial = 0; trial < 300; ++trial) {
    auto copy = bytes;
    const int flips = 1 + static_cast<int>(rng() % 8);
    for (int k = 0; k < flips; ++k) copy[rng() % copy.size()] ^= static_cast<char>(1 + rng() % 255);
    if (rng() % 3 == 0) copy.resize(rng() % copy.size());
    write_bytes(bad, copy);
    EXPECT_FALSE(read_error(bad).empty()) << "trial " << trial;
  }
}

TEST(RecordingIo, ChecksumMismatchIsReported) {
  TempDir dir;
  const auto path = dir / "crc.pmrec";
  write_sample_recording(path, 9, 1, 100, 10);
  auto bytes = read_bytes(path);
  bytes[bytes.size() - 40] ^= 0x01;  // inside the last frame's compressed payload
  write_bytes(path, bytes);
  const std::string msg = read_error(path);
  EXPECT_NE(msg.find("checksum mismatch"), std::string::npos) << msg;
}

TEST(RecordingIo, WrongMagicAndFutureVersionAreClearErrors) {
  TempDir dir;
  const auto path = dir / "v.pmrec";
  { RecordingWriter w(path, make_header()); }
  const auto bytes = read_bytes(path);

  auto not_ours = bytes;
  not_ours[1] = 'X';
  write_bytes(path, not_ours);
  EXPECT_NE(read_error(path).find("not a polmap recording"), std::string::npos);

  auto future = bytes;
  future[8] = static_cast<char>(kRecordingFormatVersion + 1);
  write_bytes(path, future);
  const std::string msg = read_error(path);
  EXPECT_NE(msg.find("unsupported recording format version " +
                     std::to_string(kRecordingFormatVersion + 1)),
            std::string::npos)
      << msg;
  EXPECT_NE(msg.find("newer"), std::string::npos) << msg;
  EXPECT_NE(msg.find("at byte 8"), std::string::npos) << msg;

  write_bytes(path, std::vector<char>{'h', 'e', 'l', 'l', 'o', ' ', 'w', 'o', 'r', 'l', 'd',
                                      '!', '!', '!', '!', '!', '!', '!', '!', '!', '!'});
  EXPECT_NE(read_error(path).find("bad magic"), std::string::npos);
}

TEST(RecordingIo, MissingFileIsIoError) {
  EXPECT_THROW(RecordingReader("/nonexistent/dir/none.pmrec"), IoError);
  EXPECT_THROW(RecordingWriter("/nonexistent/dir/none.pmrec", make_header()), IoError);
}

TEST(RecordingIo, TrailingBytesAreRejected) {
  TempDir dir;
  const auto path = dir / "tail.pmrec";
  write_sample_recording(path, 10, 1, 10, 2);
  auto bytes = read_bytes(path);
  bytes.push_back(0);
  write_bytes(path, bytes);
  EXPECT_NE(read_error(path).find("trailing bytes"), std::string::npos);
}

TEST(RecordingIo, ReaderKeepsFailingAfterAnError) {
  TempDir dir;
  const auto path = dir / "sticky.pmrec";
  write_sample_recording(path, 13, 2, 50, 5);
  auto bytes = read_bytes(path);
  bytes.resize(bytes.size() / 2);
  write_bytes(path, bytes);
  RecordingReader r(path);
  EXPECT_THROW(
      {
        while (r.next()) {
        }
      },
      FormatError);
  EXPECT_THROW(r.next(), FormatError);
}

// Crafted records (the layout of schema/recording.md, built here independently).
std::vector<char> record(std::uint8_t type, const std::string& payload) {
  std::vector<std::uint8_t> h(20, 0);
  h[0] = type;
  auto put32 = [&](int at, std::uint32_t v) {
    for (int i = 0; i < 4; ++i) h[at + i] = static_cast<std::uint8_t>(v >> (8 * i));
  };
  put32(4, static_cast<std::uint32_t>(payload.size()));
  put32(8, static_cast<std::uint32_t>(payload.size()));
  put32(12, static_cast<std::uint32_t>(
                crc32(0, reinterpret_cast<const Bytef*>(payload.data()), payload.size())));
  put32(16, static_cast<std::uint32_t>(crc32(0, h.data(), 16)));
  std::vector<char> out(h.begin(), h.end());
  out.insert(out.end(), payload.begin(), payload.end());
  return out;
}

std::vector<char> with_record_before_end(const std::vector<char>& file, std::uint8_t type) {
  // The end record is the last 20 + 16 bytes.
  auto out = std::vector<char>(file.begin(), file.end() - 36);
  const auto extra = record(type, "extension payload");
  out.insert(out.end(), extra.begin(), extra.end());
  out.insert(out.end(), file.end() - 36, file.end());
  return out;
}

TEST(RecordingIo, OptionalExtensionRecordsAreSkippedUnknownCoreRecordsRejected) {
  TempDir dir;
  const auto path = dir / "ext.pmrec";
  const auto written = write_sample_recording(path, 14, 1, 20, 2);
  const auto bytes = read_bytes(path);

  write_bytes(path, with_record_before_end(bytes, 200));
  expect_records_close(written, read_all(path));

  write_bytes(path, with_record_before_end(bytes, 42));
  EXPECT_NE(read_error(path).find("unknown record type 42"), std::string::npos);
}

TEST(RecordingIo, WriterRejectsWhatTheFormatCannotRepresent) {
  TempDir dir;
  std::mt19937 rng(15);
  RecordingWriter w(dir / "w.pmrec", make_header());

  SensorFrame unsorted = make_frame(rng, 0, 0, 50, 1);
  std::swap(unsorted.spectrum.cells[3], unsorted.spectrum.cells[10]);
  EXPECT_THROW(w.write(unsorted), ValidationError);

  SensorFrame out_of_range = make_frame(rng, 0, 0, 50, 1);
  out_of_range.spectrum.cells.back().range_bin = 1067;
  EXPECT_THROW(w.write(out_of_range), ValidationError);

  SensorFrame unknown_sensor = make_frame(rng, 0, 7, 5, 1);
  try {
    w.write(unknown_sensor);
    FAIL();
  } catch (const ValidationError& e) {
    EXPECT_NE(std::string(e.what()).find("sensor_id"), std::string::npos) << e.what();
  }

  SensorFrame nan_det = make_frame(rng, 0, 0, 5, 3);
  nan_det.detections[1].snr_db = std::nanf("");
  try {
    w.write(nan_det);
    FAIL();
  } catch (const ValidationError& e) {
    EXPECT_NE(std::string(e.what()).find("detections[1].snr_db"), std::string::npos) << e.what();
  }

  SensorFrame cube_without_header = make_frame(rng, 0, 0, 5, 1, true);
  EXPECT_THROW(w.write(cube_without_header), ValidationError);

  // Rejected frames leave nothing behind: the file is still a valid, empty recording.
  w.close();
  EXPECT_TRUE(read_all(dir / "w.pmrec").empty());
}

TEST(RecordingIo, TheVehiclesSideSlipGradientIsAnOptionalHeaderKey) {
  TempDir dir;
  // Declared: read back exactly.
  RecordingHeader h = make_header();
  h.side_slip_gradient_rad_per_mps2 = 0.0040142572795869575;
  { RecordingWriter w(dir / "slip.pmrec", h); }
  EXPECT_EQ(RecordingReader(dir / "slip.pmrec").header().side_slip_gradient_rad_per_mps2,
            h.side_slip_gradient_rad_per_mps2);
  // Not declared: absent from the header JSON (older recordings' bytes), read as nullopt.
  const RecordingHeader plain = make_header();
  EXPECT_FALSE(nlohmann::json(plain).contains("side_slip_gradient_rad_per_mps2"));
  { RecordingWriter w(dir / "plain.pmrec", plain); }
  EXPECT_FALSE(RecordingReader(dir / "plain.pmrec").header().side_slip_gradient_rad_per_mps2);
  // Out of range or not a number: the header is rejected, naming the key.
  for (const nlohmann::json& bad : {nlohmann::json(-0.001), nlohmann::json(0.06),
                                    nlohmann::json("0.004"), nlohmann::json(nullptr)}) {
    nlohmann::json j = plain;
    j["side_slip_gradient_rad_per_mps2"] = bad;
    try {
      (void)j.get<RecordingHeader>();
      ADD_FAILURE() << bad.dump();
    } catch (const JsonFieldError& e) {
      EXPECT_EQ(e.path(), "side_slip_gradient_rad_per_mps2") << e.what();
    }
  }
  // The writer does not write what the reader would reject.
  RecordingHeader wrong = make_header();
  wrong.side_slip_gradient_rad_per_mps2 = 0.5;
  EXPECT_THROW(RecordingWriter(dir / "wrong.pmrec", wrong), ValidationError);
  EXPECT_FALSE(fs::exists(dir / "wrong.pmrec"));
}

TEST(RecordingIo, StreamsManyRecordsOneAtATime) {
  // A long drive: the writer and reader handle it record by record (the
  // reader's state is the header plus one record; here we check the stream
  // functionally: counts, order and the offset advancing monotonically).
  TempDir dir;
  const auto path = dir / "long.pmrec";
  std::mt19937 rng(16);
  const int cycles = 1500;
  {
    RecordingWriter w(path, make_header());
    const SensorFrame proto = make_frame(rng, 0, 0, 300, 20);
    for (int c = 0; c < cycles; ++c) {
      for (int k = 0; k < 5; ++k) w.write(make_sample(rng, 0.1 * c + 0.02 * k));
      for (std::uint8_t s = 0; s < 3; ++s) {
        SensorFrame f = proto;
        f.cycle_index = static_cast<std::uint32_t>(c);
        f.sensor_id = s;
        f.time_s = 0.1 * c + 0.033 * s;
        w.write(f);
      }
    }
  }
  RecordingReader r(path);
  std::uint64_t last_offset = r.offset();
  int samples = 0;
  int frames = 0;
  while (auto rec = r.next()) {
    ASSERT_GT(r.offset(), last_offset);
    last_offset = r.offset();
    if (const auto* f = std::get_if<SensorFrame>(&*rec)) {
      ASSERT_EQ(f->cycle_index, static_cast<std::uint32_t>(frames / 3));
      ASSERT_EQ(f->spectrum.cells.size(), 300u);
      ++frames;
    } else {
      ++samples;
    }
  }
  EXPECT_EQ(samples, 5 * cycles);
  EXPECT_EQ(frames, 3 * cycles);
  EXPECT_EQ(r.offset(), fs::file_size(path));
}

}  // namespace
}  // namespace polmap
