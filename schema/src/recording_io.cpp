// Recording format v1 (byte layout: schema/recording.md). All integers and
// floats little-endian; every record is length-prefixed and carries two
// CRC32s (record header, stored payload) so the reader never interprets bytes
// it has not verified.
#include "polmap/schema/recording_io.hpp"

#include <zlib.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <set>
#include <string>
#include <vector>

#include "polmap/schema/errors.hpp"
#include "polmap/schema/json.hpp"

namespace polmap {
namespace {

constexpr std::array<std::uint8_t, 8> kMagic{0x89, 'P', 'M', 'R', 'E', 'C', '\r', '\n'};
constexpr std::size_t kPreambleBytes = 16;      // magic, u32 version, u32 reserved
constexpr std::size_t kRecordHeaderBytes = 20;  // see RecordHeader
// deflate expands at most ~1032:1 (a 258-byte match per 2 bits), zlib adds a few bytes.
constexpr std::uint32_t kDeflateMaxRatio = 1032;
constexpr std::size_t kTrajectoryPayloadBytes = 6 * 8 + 3 * 4 + 1;
constexpr std::size_t kEndPayloadBytes = 2 * 8;

enum class RecordType : std::uint8_t {
  Header = 1,
  Trajectory = 2,
  SensorFrame = 3,
  End = 15,
};
/// Record types >= this value are optional extensions: readers that do not
/// know them skip them (their framing and checksums are still verified).
constexpr std::uint8_t kFirstSkippableType = 128;

enum class Encoding : std::uint8_t { Raw = 0, Zlib = 1 };

constexpr std::uint8_t kFrameFlagCube = 0x01;

// ---------------------------------------------------------------- byte I/O

class ByteWriter {
 public:
  std::vector<std::uint8_t>& bytes() { return buf_; }
  void clear() { buf_.clear(); }
  void u8(std::uint8_t v) { buf_.push_back(v); }
  void u16(std::uint16_t v) { le(v, 2); }
  void u32(std::uint32_t v) { le(v, 4); }
  void u64(std::uint64_t v) { le(v, 8); }
  void i8(std::int8_t v) { u8(static_cast<std::uint8_t>(v)); }
  void i16(std::int16_t v) { u16(static_cast<std::uint16_t>(v)); }
  void i32(std::int32_t v) { u32(static_cast<std::uint32_t>(v)); }
  void f32(float v) { u32(std::bit_cast<std::uint32_t>(v)); }
  void f64(double v) { u64(std::bit_cast<std::uint64_t>(v)); }
  void varint(std::uint32_t v) {
    while (v >= 0x80) {
      buf_.push_back(static_cast<std::uint8_t>(v | 0x80));
      v >>= 7;
    }
    buf_.push_back(static_cast<std::uint8_t>(v));
  }
  void append(const std::uint8_t* p, std::size_t n) { buf_.insert(buf_.end(), p, p + n); }

 private:
  void le(std::uint64_t v, int n) {
    for (int i = 0; i < n; ++i) buf_.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
  }
  std::vector<std::uint8_t> buf_;
};

std::uint64_t load_le(const std::uint8_t* p, int n) {
  std::uint64_t v = 0;
  for (int i = 0; i < n; ++i) v |= static_cast<std::uint64_t>(p[i]) << (8 * i);
  return v;
}

/// Bounds-checked reader over a verified payload; failures name the record.
class ByteReader {
 public:
  ByteReader(const std::uint8_t* data, std::size_t size, const std::string& source,
             std::uint64_t record_offset, const char* what)
      : p_(data), n_(size), source_(source), record_offset_(record_offset), what_(what) {}

  [[noreturn]] void fail(const std::string& msg) const {
    throw FormatError(source_, record_offset_,
                      std::string(what_) + " record: " + msg + " (payload byte " +
                          std::to_string(pos_) + " of " + std::to_string(n_) + ")");
  }
  const std::uint8_t* take(std::size_t k) {
    if (k > n_ - pos_) fail("payload ends early, " + std::to_string(k) + " more bytes needed");
    const std::uint8_t* p = p_ + pos_;
    pos_ += k;
    return p;
  }
  std::uint8_t u8() { return *take(1); }
  std::uint16_t u16() { return static_cast<std::uint16_t>(load_le(take(2), 2)); }
  std::uint32_t u32() { return static_cast<std::uint32_t>(load_le(take(4), 4)); }
  std::uint64_t u64() { return load_le(take(8), 8); }
  std::int8_t i8() { return static_cast<std::int8_t>(u8()); }
  std::int16_t i16() { return static_cast<std::int16_t>(u16()); }
  std::int32_t i32() { return static_cast<std::int32_t>(u32()); }
  float f32() { return std::bit_cast<float>(u32()); }
  double f64() { return std::bit_cast<double>(u64()); }
  std::uint32_t varint() {
    std::uint32_t v = 0;
    for (int shift = 0; shift < 35; shift += 7) {
      const std::uint8_t b = u8();
      if (shift == 28 && (b & 0xF0) != 0) fail("varint overflows 32 bits");
      v |= static_cast<std::uint32_t>(b & 0x7F) << shift;
      if ((b & 0x80) == 0) return v;
    }
    fail("varint longer than 5 bytes");
  }
  /// Count of elements of elem_bytes each that must still fit in the payload.
  std::size_t count(std::uint64_t n, std::size_t elem_bytes, const char* field) {
    if (elem_bytes > 0 && n > (n_ - pos_) / elem_bytes) {
      fail(std::string(field) + " count " + std::to_string(n) + " exceeds the payload");
    }
    return static_cast<std::size_t>(n);
  }
  [[nodiscard]] std::size_t remaining() const { return n_ - pos_; }

 private:
  const std::uint8_t* p_;
  std::size_t n_;
  std::size_t pos_ = 0;
  const std::string& source_;
  std::uint64_t record_offset_;
  const char* what_;
};

std::uint32_t crc32_of(const std::uint8_t* p, std::size_t n) {
  uLong c = crc32(0L, Z_NULL, 0);
  // zlib's crc32 takes uInt lengths; feed in chunks for records near the limit.
  while (n > 0) {
    const auto chunk = static_cast<uInt>(std::min<std::size_t>(n, 1u << 30));
    c = crc32(c, p, chunk);
    p += chunk;
    n -= chunk;
  }
  return static_cast<std::uint32_t>(c);
}

std::uint32_t zigzag(std::int32_t v) {
  return (static_cast<std::uint32_t>(v) << 1) ^ static_cast<std::uint32_t>(v >> 31);
}
std::int32_t unzigzag(std::uint32_t v) {
  return static_cast<std::int32_t>(v >> 1) ^ -static_cast<std::int32_t>(v & 1);
}

// ------------------------------------------------------------ quantization

/// Smallest e >= min_e with max_abs / 2^e <= mantissa_max (after rounding).
int block_exponent(double max_abs, int mantissa_max, int min_e) {
  if (!(max_abs > 0.0)) return min_e;
  int k = 0;
  const double f = std::frexp(max_abs / mantissa_max, &k);  // = f * 2^k, f in [0.5, 1)
  int e = (f == 0.5) ? k - 1 : k;                           // ceil(log2(max_abs / m))
  e = std::max(e, min_e);
  while (std::llround(std::ldexp(max_abs, -e)) > mantissa_max) ++e;
  return e;
}

// --------------------------------------------------------- frame encoding

struct FrameContext {
  const std::string& source;
  std::uint64_t index;
  const SensorFrame& frame;
  [[noreturn]] void fail(const std::string& field, const std::string& msg) const {
    throw ValidationError(source + ": sensor frame " + std::to_string(index) + " (sensor " +
                          std::to_string(frame.sensor_id) + ", cycle " +
                          std::to_string(frame.cycle_index) + "): " + field + ": " + msg);
  }
};

template <typename Int>
Int quantize(double value, double step, const FrameContext& ctx, const std::string& field) {
  if (!std::isfinite(value)) ctx.fail(field, "not finite");
  const double q = std::round(value / step);
  if (q < static_cast<double>(std::numeric_limits<Int>::min()) ||
      q > static_cast<double>(std::numeric_limits<Int>::max())) {
    ctx.fail(field, "value " + std::to_string(value) + " outside the representable range");
  }
  return static_cast<Int>(q);
}

void encode_frame(const SensorFrame& f, const FrameContext& ctx, ByteWriter& w) {
  w.u32(f.cycle_index);
  w.u8(f.sensor_id);
  w.u8(f.cube ? kFrameFlagCube : 0);
  w.u16(0);
  w.f64(f.time_s);

  // Detections, column by column (similar values next to each other compress better).
  const auto& dets = f.detections;
  if (dets.size() > std::numeric_limits<std::uint32_t>::max()) ctx.fail("detections", "too many");
  w.u32(static_cast<std::uint32_t>(dets.size()));
  auto name = [](const char* field, std::size_t i) {
    return "detections[" + std::to_string(i) + "]." + field;
  };
  for (std::size_t i = 0; i < dets.size(); ++i) {
    w.i32(quantize<std::int32_t>(dets[i].range_m, kDetectionRangeStep_m, ctx, name("range_m", i)));
  }
  for (std::size_t i = 0; i < dets.size(); ++i) {
    w.i16(quantize<std::int16_t>(dets[i].azimuth_rad, kDetectionAzimuthStep_rad, ctx,
                                 name("azimuth_rad", i)));
  }
  for (std::size_t i = 0; i < dets.size(); ++i) {
    w.i32(quantize<std::int32_t>(dets[i].radial_velocity_mps, kDetectionVelocityStep_mps, ctx,
                                 name("radial_velocity_mps", i)));
  }
  for (std::size_t i = 0; i < dets.size(); ++i) {
    w.i16(quantize<std::int16_t>(dets[i].snr_db, kDetectionSnrStep_db, ctx, name("snr_db", i)));
  }

  // Spectrum.
  const PolSpectrum& sp = f.spectrum;
  if (sp.azimuth_bins_rad.size() > std::numeric_limits<std::uint16_t>::max()) {
    ctx.fail("spectrum.azimuth_bins_rad", "more than 65535 bins");
  }
  if (sp.cells.size() > std::numeric_limits<std::uint32_t>::max()) {
    ctx.fail("spectrum.cells", "too many");
  }
  w.f64(sp.range_bin_m);
  w.u16(sp.num_range_bins);
  w.u16(static_cast<std::uint16_t>(sp.azimuth_bins_rad.size()));
  for (float a : sp.azimuth_bins_rad) w.f32(a);
  w.f32(sp.noise_sigma);
  w.u32(static_cast<std::uint32_t>(sp.cells.size()));
  if (!sp.cells.empty() && !(std::isfinite(sp.noise_sigma) && sp.noise_sigma > 0.0F)) {
    ctx.fail("spectrum.noise_sigma", "must be finite and > 0 when cells are present");
  }
  // Cell indices: varint zigzag azimuth delta, then the range bin as a
  // zigzag delta within the same azimuth bin or absolute on a new one.
  int prev_az = 0;
  int prev_r = 0;
  for (std::size_t i = 0; i < sp.cells.size(); ++i) {
    const SpectrumCell& c = sp.cells[i];
    const std::string field = "spectrum.cells[" + std::to_string(i) + "]";
    if (c.range_bin >= sp.num_range_bins) {
      ctx.fail(field, "range_bin " + std::to_string(c.range_bin) + " >= num_range_bins " +
                          std::to_string(sp.num_range_bins));
    }
    if (c.azimuth_bin >= sp.azimuth_bins_rad.size()) {
      ctx.fail(field, "azimuth_bin " + std::to_string(c.azimuth_bin) +
                          " >= " + std::to_string(sp.azimuth_bins_rad.size()) + " azimuth bins");
    }
    if (i > 0 && (c.azimuth_bin < prev_az || (c.azimuth_bin == prev_az && c.range_bin <= prev_r))) {
      ctx.fail(field, "cells must be sorted by (azimuth_bin, range_bin) without duplicates");
    }
    const int daz = c.azimuth_bin - prev_az;
    w.varint(zigzag(daz));
    w.varint(daz == 0 ? zigzag(c.range_bin - prev_r) : c.range_bin);
    prev_az = c.azimuth_bin;
    prev_r = c.range_bin;
  }
  // Exponents (4 per cell), then mantissas (I, Q per channel, 8 per cell).
  const double sigma = sp.noise_sigma;
  std::vector<std::int8_t> mant;
  mant.reserve(sp.cells.size() * 8);
  for (std::size_t i = 0; i < sp.cells.size(); ++i) {
    for (int ch = 0; ch < kNumPolChannels; ++ch) {
      const cfloat s = sp.cells[i].s[ch];
      if (!std::isfinite(s.real()) || !std::isfinite(s.imag())) {
        ctx.fail("spectrum.cells[" + std::to_string(i) + "].s[" + std::to_string(ch) + "]",
                 "not finite");
      }
      const double re = s.real() / sigma;
      const double im = s.imag() / sigma;
      const int e = block_exponent(std::max(std::abs(re), std::abs(im)), kSpectrumMantissaMax,
                                   kSpectrumMinExponent);
      if (e > std::numeric_limits<std::int8_t>::max()) {
        ctx.fail("spectrum.cells[" + std::to_string(i) + "]", "sample too large for noise_sigma");
      }
      w.i8(static_cast<std::int8_t>(e));
      mant.push_back(static_cast<std::int8_t>(std::llround(std::ldexp(re, -e))));
      mant.push_back(static_cast<std::int8_t>(std::llround(std::ldexp(im, -e))));
    }
  }
  for (std::int8_t m : mant) w.i8(m);

  // Optional data cube: per range line (R samples of one pol/virtual channel/
  // chirp) an i16 exponent, then i16 I/Q mantissas.
  if (f.cube) {
    const DataCube& cube = *f.cube;
    const std::uint64_t r = cube.num_range_bins;
    const std::uint64_t lines =
        std::uint64_t{kNumPolChannels} * cube.num_virtual_channels * cube.num_chirps;
    if (cube.data.size() != lines * r) {
      ctx.fail("cube.data", "size " + std::to_string(cube.data.size()) + " != 4 * " +
                                std::to_string(cube.num_virtual_channels) + " * " +
                                std::to_string(cube.num_chirps) + " * " + std::to_string(r));
    }
    if (lines * r * 4 + lines * 2 + 64 > kMaxRecordBytes) ctx.fail("cube", "too large");
    w.u16(cube.num_range_bins);
    w.u16(cube.num_chirps);
    w.u16(cube.num_virtual_channels);
    w.u16(0);
    w.f64(cube.range_bin_m);
    w.f64(cube.chirp_interval_s);
    w.f64(cube.element_spacing_wavelengths);
    std::vector<int> exps(lines);
    for (std::uint64_t l = 0; l < lines; ++l) {
      double max_abs = 0.0;
      for (std::uint64_t k = 0; k < r; ++k) {
        const cfloat s = cube.data[l * r + k];
        if (!std::isfinite(s.real()) || !std::isfinite(s.imag())) {
          ctx.fail("cube.data[" + std::to_string(l * r + k) + "]", "not finite");
        }
        max_abs = std::max({max_abs, std::abs(double{s.real()}), std::abs(double{s.imag()})});
      }
      exps[l] = block_exponent(max_abs, 32767, -200);
      w.i16(static_cast<std::int16_t>(exps[l]));
    }
    for (std::uint64_t l = 0; l < lines; ++l) {
      for (std::uint64_t k = 0; k < r; ++k) {
        const cfloat s = cube.data[l * r + k];
        w.i16(static_cast<std::int16_t>(std::llround(std::ldexp(double{s.real()}, -exps[l]))));
        w.i16(static_cast<std::int16_t>(std::llround(std::ldexp(double{s.imag()}, -exps[l]))));
      }
    }
  }
}

SensorFrame decode_frame(ByteReader& in, const std::set<std::uint8_t>& sensor_ids, bool has_cube) {
  SensorFrame f;
  f.cycle_index = in.u32();
  f.sensor_id = in.u8();
  if (!sensor_ids.contains(f.sensor_id)) {
    in.fail("sensor_id " + std::to_string(f.sensor_id) + " is not in the header");
  }
  const std::uint8_t flags = in.u8();
  if ((flags & ~kFrameFlagCube) != 0) in.fail("unknown frame flags " + std::to_string(flags));
  if ((flags & kFrameFlagCube) && !has_cube) in.fail("cube present but header.has_cube is false");
  if (in.u16() != 0) in.fail("reserved field is not zero");
  f.time_s = in.f64();

  const std::size_t nd = in.count(in.u32(), 12, "detection");
  f.detections.resize(nd);
  for (auto& d : f.detections) d.range_m = static_cast<float>(in.i32() * kDetectionRangeStep_m);
  for (auto& d : f.detections) {
    d.azimuth_rad = static_cast<float>(in.i16() * kDetectionAzimuthStep_rad);
  }
  for (auto& d : f.detections) {
    d.radial_velocity_mps = static_cast<float>(in.i32() * kDetectionVelocityStep_mps);
  }
  for (auto& d : f.detections) d.snr_db = static_cast<float>(in.i16() * kDetectionSnrStep_db);

  PolSpectrum& sp = f.spectrum;
  sp.range_bin_m = in.f64();
  sp.num_range_bins = in.u16();
  const std::size_t naz = in.count(in.u16(), 4, "azimuth bin");
  sp.azimuth_bins_rad.resize(naz);
  for (float& a : sp.azimuth_bins_rad) a = in.f32();
  sp.noise_sigma = in.f32();
  // Each cell takes at least 2 index bytes, 4 exponents and 8 mantissas.
  const std::size_t nc = in.count(in.u32(), 14, "spectrum cell");
  if (nc > 0 && !(std::isfinite(sp.noise_sigma) && sp.noise_sigma > 0.0F)) {
    in.fail("noise_sigma is not finite and positive");
  }
  sp.cells.resize(nc);
  int prev_az = 0;
  int prev_r = 0;
  for (std::size_t i = 0; i < nc; ++i) {
    const std::int64_t daz = unzigzag(in.varint());
    const std::int64_t az = prev_az + daz;
    const std::uint32_t rv = in.varint();
    const std::int64_t r = daz == 0 ? prev_r + std::int64_t{unzigzag(rv)} : std::int64_t{rv};
    if (az < 0 || az >= static_cast<std::int64_t>(naz) || r < 0 || r >= sp.num_range_bins) {
      in.fail("spectrum cell " + std::to_string(i) + " index (" + std::to_string(az) + ", " +
              std::to_string(r) + ") out of range");
    }
    if (i > 0 && !(daz > 0 || (daz == 0 && r > prev_r))) {
      in.fail("spectrum cell " + std::to_string(i) + " not sorted");
    }
    sp.cells[i].azimuth_bin = static_cast<std::uint16_t>(az);
    sp.cells[i].range_bin = static_cast<std::uint16_t>(r);
    prev_az = static_cast<int>(az);
    prev_r = static_cast<int>(r);
  }
  const std::uint8_t* exps = in.take(nc * 4);
  const std::uint8_t* mant = in.take(nc * 8);
  const double sigma = sp.noise_sigma;
  for (std::size_t i = 0; i < nc; ++i) {
    for (int ch = 0; ch < kNumPolChannels; ++ch) {
      const int e = static_cast<std::int8_t>(exps[i * 4 + ch]);
      const auto mi = static_cast<std::int8_t>(mant[i * 8 + ch * 2]);
      const auto mq = static_cast<std::int8_t>(mant[i * 8 + ch * 2 + 1]);
      if (e < kSpectrumMinExponent || mi < -kSpectrumMantissaMax || mq < -kSpectrumMantissaMax) {
        in.fail("spectrum cell " + std::to_string(i) + " sample outside the quantizer's range");
      }
      const double scale = std::ldexp(sigma, e);
      sp.cells[i].s[ch] = cfloat(static_cast<float>(mi * scale), static_cast<float>(mq * scale));
    }
  }

  if (flags & kFrameFlagCube) {
    DataCube cube;
    cube.num_range_bins = in.u16();
    cube.num_chirps = in.u16();
    cube.num_virtual_channels = in.u16();
    if (in.u16() != 0) in.fail("cube reserved field is not zero");
    cube.range_bin_m = in.f64();
    cube.chirp_interval_s = in.f64();
    cube.element_spacing_wavelengths = in.f64();
    const std::uint64_t r = cube.num_range_bins;
    const std::uint64_t lines =
        std::uint64_t{kNumPolChannels} * cube.num_virtual_channels * cube.num_chirps;
    const std::uint8_t* ex = in.take(in.count(lines, 2, "cube line") * 2);
    const std::uint8_t* m = in.take(in.count(lines * r, 4, "cube sample") * 4);
    cube.data.resize(lines * r);
    for (std::uint64_t l = 0; l < lines; ++l) {
      const auto e = static_cast<std::int16_t>(load_le(ex + 2 * l, 2));
      if (e < -200 || e > 200) in.fail("cube exponent out of range");
      const double scale = std::ldexp(1.0, e);
      for (std::uint64_t k = 0; k < r; ++k) {
        const std::uint8_t* p = m + 4 * (l * r + k);
        const auto mi = static_cast<std::int16_t>(load_le(p, 2));
        const auto mq = static_cast<std::int16_t>(load_le(p + 2, 2));
        cube.data[l * r + k] =
            cfloat(static_cast<float>(mi * scale), static_cast<float>(mq * scale));
      }
    }
    f.cube = std::move(cube);
  }
  if (in.remaining() != 0) {
    in.fail(std::to_string(in.remaining()) + " unexpected bytes after the frame");
  }
  return f;
}

void encode_trajectory(const TrajectorySample& s, ByteWriter& w) {
  w.f64(s.time_s);
  w.f64(s.lat_deg);
  w.f64(s.lon_deg);
  w.f64(s.yaw_enu_rad);
  w.f64(s.speed_mps);
  w.f64(s.yaw_rate_rps);
  w.f32(s.std_east_m);
  w.f32(s.std_north_m);
  w.f32(s.std_yaw_rad);
  w.u8(static_cast<std::uint8_t>(s.solution));
}

TrajectorySample decode_trajectory(ByteReader& in) {
  if (in.remaining() != kTrajectoryPayloadBytes) {
    in.fail("payload is " + std::to_string(in.remaining()) + " bytes, expected " +
            std::to_string(kTrajectoryPayloadBytes));
  }
  TrajectorySample s;
  s.time_s = in.f64();
  s.lat_deg = in.f64();
  s.lon_deg = in.f64();
  s.yaw_enu_rad = in.f64();
  s.speed_mps = in.f64();
  s.yaw_rate_rps = in.f64();
  s.std_east_m = in.f32();
  s.std_north_m = in.f32();
  s.std_yaw_rad = in.f32();
  const std::uint8_t sol = in.u8();
  if (sol > static_cast<std::uint8_t>(GnssSolution::Standalone)) {
    in.fail("unknown GNSS solution " + std::to_string(sol));
  }
  s.solution = static_cast<GnssSolution>(sol);
  return s;
}

}  // namespace

// ================================================================== writer

struct RecordingWriter::Impl {
  std::string source;
  std::ofstream out;
  RecordingHeader header;
  RecordingWriterOptions options;
  std::set<std::uint8_t> sensor_ids;
  std::uint64_t bytes = 0;
  std::uint64_t num_trajectory = 0;
  std::uint64_t num_frames = 0;
  bool closed = false;
  ByteWriter payload;
  std::vector<std::uint8_t> compressed;

  void write_bytes(const std::uint8_t* p, std::size_t n) {
    out.write(reinterpret_cast<const char*>(p), static_cast<std::streamsize>(n));
    if (!out) {
      throw IoError(source + ": write failed at byte " + std::to_string(bytes) + ": " +
                    std::strerror(errno));
    }
    bytes += n;
  }

  void write_record(RecordType type, const std::vector<std::uint8_t>& raw, bool compress) {
    POLMAP_EXPECT(!closed);
    if (raw.size() > kMaxRecordBytes) {
      throw ValidationError(source + ": record of " + std::to_string(raw.size()) +
                            " bytes exceeds the format's limit");
    }
    const std::uint8_t* stored = raw.data();
    std::size_t stored_len = raw.size();
    Encoding enc = Encoding::Raw;
    if (compress) {
      uLongf len = compressBound(static_cast<uLong>(raw.size()));
      compressed.resize(len);
      const int rc = compress2(compressed.data(), &len, raw.data(), static_cast<uLong>(raw.size()),
                               options.compression_level);
      if (rc != Z_OK)
        throw IoError(source + ": zlib compression failed (" + std::to_string(rc) + ")");
      stored = compressed.data();
      stored_len = len;
      enc = Encoding::Zlib;
    }
    ByteWriter h;
    h.u8(static_cast<std::uint8_t>(type));
    h.u8(static_cast<std::uint8_t>(enc));
    h.u16(0);
    h.u32(static_cast<std::uint32_t>(stored_len));
    h.u32(static_cast<std::uint32_t>(raw.size()));
    h.u32(crc32_of(stored, stored_len));
    h.u32(crc32_of(h.bytes().data(), h.bytes().size()));
    write_bytes(h.bytes().data(), h.bytes().size());
    write_bytes(stored, stored_len);
  }
};

RecordingWriter::RecordingWriter(const std::filesystem::path& path, const RecordingHeader& header)
    : RecordingWriter(path, header, RecordingWriterOptions{}) {}

RecordingWriter::RecordingWriter(const std::filesystem::path& path, const RecordingHeader& header,
                                 const RecordingWriterOptions& options)
    : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  d.source = path.string();
  d.header = header;
  d.header.format_version = kRecordingFormatVersion;
  d.options = options;
  if (options.compression_level < 0 || options.compression_level > 9) {
    throw ValidationError(d.source + ": compression_level must be 0..9");
  }
  if (const auto& g = header.side_slip_gradient_rad_per_mps2; g && !side_slip_gradient_valid(*g)) {
    throw ValidationError(d.source + ": header.side_slip_gradient_rad_per_mps2 must be in [0, " +
                          std::to_string(kMaxSideSlipGradientRadPerMps2) + "]");
  }
  for (const SensorMount& m : header.sensors) {
    if (!d.sensor_ids.insert(m.sensor_id).second) {
      throw ValidationError(d.source + ": header.sensors: duplicate sensor_id " +
                            std::to_string(m.sensor_id));
    }
  }
  d.out.open(path, std::ios::binary | std::ios::trunc);
  if (!d.out) {
    throw IoError("cannot open recording for writing: " + d.source + ": " + std::strerror(errno));
  }
  ByteWriter pre;
  pre.append(kMagic.data(), kMagic.size());
  pre.u32(kRecordingFormatVersion);
  pre.u32(0);
  d.write_bytes(pre.bytes().data(), pre.bytes().size());
  const std::string text = nlohmann::json(d.header).dump();
  const std::vector<std::uint8_t> json_bytes(text.begin(), text.end());
  d.write_record(RecordType::Header, json_bytes, false);
}

RecordingWriter::~RecordingWriter() {
  try {
    close();
  } catch (...) {  // NOLINT(bugprone-empty-catch): destructors must not throw; call close() to see
                   // errors
  }
}

void RecordingWriter::write(const TrajectorySample& sample) {
  Impl& d = *impl_;
  d.payload.clear();
  encode_trajectory(sample, d.payload);
  d.write_record(RecordType::Trajectory, d.payload.bytes(), false);
  ++d.num_trajectory;
}

void RecordingWriter::write(const SensorFrame& frame) {
  Impl& d = *impl_;
  const FrameContext ctx{d.source, d.num_frames, frame};
  if (!d.sensor_ids.contains(frame.sensor_id)) {
    ctx.fail("sensor_id", "not listed in header.sensors");
  }
  if (frame.cube && !d.header.has_cube) ctx.fail("cube", "present but header.has_cube is false");
  d.payload.clear();
  encode_frame(frame, ctx, d.payload);
  d.write_record(RecordType::SensorFrame, d.payload.bytes(), true);
  ++d.num_frames;
}

void RecordingWriter::write(const RecordingRecord& record) {
  std::visit([this](const auto& r) { write(r); }, record);
}

void RecordingWriter::close() {
  Impl& d = *impl_;
  if (d.closed) return;
  d.payload.clear();
  d.payload.u64(d.num_trajectory);
  d.payload.u64(d.num_frames);
  d.write_record(RecordType::End, d.payload.bytes(), false);
  d.closed = true;
  d.out.flush();
  d.out.close();
  if (d.out.fail()) throw IoError(d.source + ": closing the recording failed");
}

std::uint64_t RecordingWriter::bytes_written() const { return impl_->bytes; }

// ================================================================== reader

struct RecordingReader::Impl {
  std::string source;
  std::ifstream in;
  std::uint64_t size = 0;
  std::uint64_t offset = 0;
  std::uint32_t version = 0;
  RecordingHeader header;
  std::set<std::uint8_t> sensor_ids;
  std::uint64_t num_trajectory = 0;
  std::uint64_t num_frames = 0;
  bool done = false;
  std::optional<FormatError> error;  // a failed reader keeps failing, never resyncs silently
  std::vector<std::uint8_t> stored;  // the one record held in memory
  std::vector<std::uint8_t> raw;

  [[noreturn]] void fail(std::uint64_t at, const std::string& msg) const {
    throw FormatError(source, at, msg);
  }

  /// The file must still hold n bytes for `what` (checked before anything is reserved).
  void require_left(std::size_t n, const char* what) const {
    if (n > size - offset) {
      fail(offset, std::string("file truncated: ") + what + " needs " + std::to_string(n) +
                       " bytes, only " + std::to_string(size - offset) + " left");
    }
  }

  void read_exact(std::uint8_t* p, std::size_t n, const char* what) {
    require_left(n, what);
    in.read(reinterpret_cast<char*>(p), static_cast<std::streamsize>(n));
    if (static_cast<std::size_t>(in.gcount()) != n) {
      fail(offset, std::string("read error or file shrank while reading ") + what);
    }
    offset += n;
  }

  struct Record {
    std::uint8_t type;
    std::uint64_t offset;
  };

  /// Reads and verifies the next record; its payload is left in `raw`.
  Record read_record() {
    const std::uint64_t start = offset;
    std::array<std::uint8_t, kRecordHeaderBytes> h{};
    if (offset == size) fail(offset, "file truncated: end-of-stream record missing");
    read_exact(h.data(), h.size(), "record header");
    const auto header_crc = static_cast<std::uint32_t>(load_le(h.data() + 16, 4));
    if (crc32_of(h.data(), 16) != header_crc) fail(start, "record header checksum mismatch");
    const std::uint8_t type = h[0];
    const std::uint8_t enc = h[1];
    const auto stored_len = static_cast<std::uint32_t>(load_le(h.data() + 4, 4));
    const auto raw_len = static_cast<std::uint32_t>(load_le(h.data() + 8, 4));
    const auto payload_crc = static_cast<std::uint32_t>(load_le(h.data() + 12, 4));
    if (load_le(h.data() + 2, 2) != 0) fail(start, "record header reserved field is not zero");
    if (enc > static_cast<std::uint8_t>(Encoding::Zlib)) {
      fail(start, "unknown payload encoding " + std::to_string(enc));
    }
    if (raw_len > kMaxRecordBytes || stored_len > kMaxRecordBytes) {
      fail(start, "record length exceeds the format's limit");
    }
    if (enc == static_cast<std::uint8_t>(Encoding::Raw) && stored_len != raw_len) {
      fail(start, "raw record with stored length != payload length");
    }
    // Limits before memory: a header may claim up to kMaxRecordBytes, so the payload must
    // be in the file and its decompressed length within deflate's expansion bound
    // (< 1032:1) before anything is reserved for them.
    require_left(stored_len, "record payload");
    if (enc == static_cast<std::uint8_t>(Encoding::Zlib) &&
        raw_len > std::uint64_t{kDeflateMaxRatio} * stored_len + 64) {
      fail(start, "zlib payload of " + std::to_string(stored_len) + " bytes cannot expand to " +
                      std::to_string(raw_len) + " bytes");
    }
    stored.resize(stored_len);
    read_exact(stored.data(), stored_len, "record payload");
    if (crc32_of(stored.data(), stored_len) != payload_crc) {
      fail(start, "record payload checksum mismatch");
    }
    if (enc == static_cast<std::uint8_t>(Encoding::Zlib)) {
      raw.resize(raw_len);
      uLongf len = raw_len;
      const int rc = uncompress(raw.data(), &len, stored.data(), stored_len);
      if (rc != Z_OK || len != raw_len) {
        fail(start, "zlib payload does not decompress to its recorded length (zlib code " +
                        std::to_string(rc) + ")");
      }
    } else {
      raw.swap(stored);
    }
    return {type, start};
  }
};

RecordingReader::RecordingReader(const std::filesystem::path& path)
    : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  d.source = path.string();
  std::error_code ec;
  d.size = std::filesystem::file_size(path, ec);
  if (ec) throw IoError("cannot open recording: " + d.source + ": " + ec.message());
  d.in.open(path, std::ios::binary);
  if (!d.in) throw IoError("cannot open recording: " + d.source + ": " + std::strerror(errno));

  std::array<std::uint8_t, kPreambleBytes> pre{};
  if (d.size < kMagic.size() + 4) {
    d.fail(d.size, "file truncated: too short for the recording preamble (" +
                       std::to_string(d.size) + " bytes)");
  }
  const std::size_t head = static_cast<std::size_t>(std::min<std::uint64_t>(d.size, pre.size()));
  d.in.read(reinterpret_cast<char*>(pre.data()), static_cast<std::streamsize>(head));
  if (static_cast<std::size_t>(d.in.gcount()) != head) d.fail(0, "read error on preamble");
  if (!std::equal(kMagic.begin(), kMagic.end(), pre.begin())) {
    d.fail(0, "not a polmap recording (bad magic)");
  }
  d.version = static_cast<std::uint32_t>(load_le(pre.data() + 8, 4));
  if (d.version == 0 || d.version > kRecordingFormatVersion) {
    d.fail(8, "unsupported recording format version " + std::to_string(d.version) +
                  " (this build reads versions 1.." + std::to_string(kRecordingFormatVersion) +
                  (d.version > kRecordingFormatVersion ? "; written by a newer polmap)" : ")"));
  }
  if (head < pre.size()) d.fail(d.size, "file truncated inside the preamble");
  if (load_le(pre.data() + 12, 4) != 0) d.fail(12, "preamble reserved field is not zero");
  d.offset = kPreambleBytes;

  const auto rec = d.read_record();
  if (rec.type != static_cast<std::uint8_t>(RecordType::Header)) {
    d.fail(rec.offset, "first record is not the header (type " + std::to_string(rec.type) + ")");
  }
  try {
    const auto j = nlohmann::json::parse(d.raw.begin(), d.raw.end());
    d.header = j.get<RecordingHeader>();
  } catch (const nlohmann::json::exception& e) {
    d.fail(rec.offset, std::string("header JSON: ") + e.what());
  } catch (const JsonFieldError& e) {
    d.fail(rec.offset, std::string("header ") + e.what());
  }
  d.header.format_version = d.version;
  for (const SensorMount& m : d.header.sensors) {
    if (!d.sensor_ids.insert(m.sensor_id).second) {
      d.fail(rec.offset, "header lists sensor_id " + std::to_string(m.sensor_id) + " twice");
    }
  }
  d.raw.clear();
  d.stored.clear();
}

RecordingReader::~RecordingReader() = default;

const RecordingHeader& RecordingReader::header() const { return impl_->header; }

std::optional<RecordingRecord> RecordingReader::next() {
  Impl& d = *impl_;
  if (d.error) throw *d.error;
  try {
    return next_record();
  } catch (const FormatError& e) {
    d.error = e;
    throw;
  }
}

std::optional<RecordingRecord> RecordingReader::next_record() {
  Impl& d = *impl_;
  while (!d.done) {
    const auto rec = d.read_record();
    switch (static_cast<RecordType>(rec.type)) {
      case RecordType::Trajectory: {
        ByteReader in(d.raw.data(), d.raw.size(), d.source, rec.offset, "trajectory");
        auto s = decode_trajectory(in);
        ++d.num_trajectory;
        return s;
      }
      case RecordType::SensorFrame: {
        ByteReader in(d.raw.data(), d.raw.size(), d.source, rec.offset, "sensor-frame");
        auto f = decode_frame(in, d.sensor_ids, d.header.has_cube);
        ++d.num_frames;
        return f;
      }
      case RecordType::End: {
        ByteReader in(d.raw.data(), d.raw.size(), d.source, rec.offset, "end-of-stream");
        if (in.remaining() != kEndPayloadBytes) in.fail("unexpected payload length");
        const std::uint64_t nt = in.u64();
        const std::uint64_t nf = in.u64();
        if (nt != d.num_trajectory || nf != d.num_frames) {
          d.fail(rec.offset, "end record counts " + std::to_string(nt) +
                                 " trajectory samples and " + std::to_string(nf) +
                                 " frames, the file holds " + std::to_string(d.num_trajectory) +
                                 " and " + std::to_string(d.num_frames));
        }
        if (d.offset != d.size) {
          d.fail(d.offset,
                 std::to_string(d.size - d.offset) + " trailing bytes after the end record");
        }
        d.done = true;
        break;
      }
      case RecordType::Header:
        d.fail(rec.offset, "second header record");
      default:
        if (rec.type < kFirstSkippableType) {
          d.fail(rec.offset, "unknown record type " + std::to_string(rec.type));
        }
        break;  // optional extension record: verified and skipped
    }
  }
  d.raw.clear();
  return std::nullopt;
}

std::uint64_t RecordingReader::offset() const { return impl_->offset; }
std::uint64_t RecordingReader::file_size() const { return impl_->size; }
std::uint32_t RecordingReader::file_format_version() const { return impl_->version; }
bool RecordingReader::at_end() const { return impl_->done; }

}  // namespace polmap
