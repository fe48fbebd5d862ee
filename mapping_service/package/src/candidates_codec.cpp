// candidates.bin codec (package format 2): see candidates_codec.hpp and
// schema/drive_package.md. Layout: a 32-byte header, then one zlib stream of the body;
// the body is columns of LEB128 varints (signed values zigzag-coded), each column the
// deltas (trajectory: second differences) of a quantized field.
#include "polmap/mapping_service/candidates_codec.hpp"

#include <zlib.h>

#include <array>
#include <cmath>
#include <cstring>
#include <limits>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping {

namespace {

constexpr const char* kFile = "candidates.bin";
constexpr std::array<char, 4> kMagic{'P', 'M', 'C', 'B'};
/// Quanta that differ by version. Version 2 coarsened what nothing needs (trajectory time
/// 100 µs is 3 mm at 30 m/s; 10 µrad is 0.0006°).
/// Candidate strength and power are kept for display and export only (consensus and
/// alignment use positions), so version 2 stores them at 2 % and 0.25 dB.
struct Quanta {
  double time_s, yaw_rad, yaw_rate_rps, std_yaw_rad, strength_scale, power_db;
};
Quanta quanta(std::uint32_t version) {
  return version == 1 ? Quanta{1e-6, 1e-6, 1e-6, 1e-6, 200.0, 0.05}
                      : Quanta{1e-4, 1e-5, 1e-5, 1e-5, 50.0, 0.25};
}
constexpr std::size_t kHeaderBytes = 32;
// Columns per element (each costs at least one byte of body): the inflated size is at
// least counts x columns, checked before anything is reserved.
constexpr std::uint64_t kPointColumns = 6, kLineColumns = 5, kTrajectoryColumns = 10;
// Bounds of decoded quantized values (|x| ≤ 4e6 km in mm, lat/lon in 1e-8°, UNIX times in
// µs until the year 2112; 2^50 rejected times after 2005-09 and was raised, a relaxation that
// every earlier file still meets). Exact in a double, far from int64 overflow in the deltas.
constexpr std::int64_t kMaxAbs = std::int64_t{1} << 52;
constexpr double kMaxLogStrength = 50.0;  // strength ≤ e^50

[[noreturn]] void bad(const std::string& field, const std::string& msg) {
  throw PackageFormatError(kFile, field, msg);
}

/// Strength (a Wishart distance or ridgeness, 0 .. ~1e7) to a relative step:
/// round(scale·ln(1+s)) (scale 200: 0.5 %; 50: 2 %).
std::uint64_t strength_code(double v, double scale) {
  POLMAP_EXPECT(std::isfinite(v));
  return static_cast<std::uint64_t>(std::llround(scale * std::log1p(std::max(0.0, v))));
}
double strength_value(std::uint64_t k, double scale) { return std::expm1(double(k) / scale); }

std::int64_t q(double v, double unit) {
  POLMAP_EXPECT(std::isfinite(v) && std::abs(v / unit) < double(kMaxAbs));
  return std::llround(v / unit);
}

// ------------------------------------------------------------------ writer
struct Writer {
  std::string out;
  void u(std::uint64_t v) {
    while (v >= 0x80) {
      out.push_back(static_cast<char>((v & 0x7f) | 0x80));
      v >>= 7;
    }
    out.push_back(static_cast<char>(v));
  }
  void s(std::int64_t v) {
    u((static_cast<std::uint64_t>(v) << 1) ^ static_cast<std::uint64_t>(v >> 63));
  }
};

/// Column of deltas (order 1) or second differences (order 2).
template <typename F>
void column(Writer& w, std::size_t n, int order, F value) {
  std::int64_t prev = 0, prev_delta = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::int64_t v = value(i);
    const std::int64_t d = v - prev;
    w.s(order == 1 ? d : d - prev_delta);
    prev = v;
    prev_delta = d;
  }
}

void put_u32(std::string& s, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) s.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}
std::uint32_t get_u32(std::string_view s, std::size_t at) {
  std::uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= std::uint32_t(static_cast<unsigned char>(s[at + i])) << (8 * i);
  return v;
}

// ------------------------------------------------------------------ reader
struct Reader {
  std::string_view in;
  std::size_t pos = 0;
  std::uint64_t u(const char* field) {
    std::uint64_t v = 0;
    for (int shift = 0; shift < 64; shift += 7) {
      if (pos >= in.size()) bad(field, "truncated column");
      const auto b = static_cast<unsigned char>(in[pos++]);
      v |= std::uint64_t(b & 0x7f) << shift;
      if ((b & 0x80) == 0) return v;
    }
    bad(field, "varint longer than 64 bits");
  }
  std::int64_t s(const char* field) {
    const std::uint64_t z = u(field);
    return static_cast<std::int64_t>(z >> 1) ^ -static_cast<std::int64_t>(z & 1);
  }
};

/// Reads a delta column into out[i] (checked against ±kMaxAbs at every step).
void read_column(Reader& r, std::size_t n, int order, const char* field,
                 std::vector<std::int64_t>& out) {
  out.resize(n);
  std::int64_t prev = 0, prev_delta = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::int64_t x = r.s(field);
    if (x > kMaxAbs || x < -kMaxAbs)
      bad(field, "value out of range at element " + std::to_string(i));
    const std::int64_t d = order == 1 ? x : prev_delta + x;
    const std::int64_t v = prev + d;
    if (d > kMaxAbs || d < -kMaxAbs || v > kMaxAbs || v < -kMaxAbs) {
      bad(field, "value out of range at element " + std::to_string(i));
    }
    out[i] = v;
    prev = v;
    prev_delta = d;
  }
}

std::vector<std::uint64_t> read_unsigned(Reader& r, std::size_t n, const char* field,
                                         std::uint64_t max) {
  std::vector<std::uint64_t> out(n);
  for (std::size_t i = 0; i < n; ++i) {
    out[i] = r.u(field);
    if (out[i] > max)
      bad(field,
          "value " + std::to_string(out[i]) + " out of range at element " + std::to_string(i));
  }
  return out;
}

}  // namespace

std::string encode_candidates(const CandidatesContent& c, std::uint32_t version) {
  POLMAP_EXPECT(version == 1 || version == 2);
  const Quanta tq = quanta(version);
  Writer w;
  const auto& P = c.points;
  const auto& L = c.lines;
  const auto& T = c.trajectory;
  column(w, P.size(), 1, [&](std::size_t i) { return q(P[i].position_m.x(), 1e-3); });
  column(w, P.size(), 1, [&](std::size_t i) { return q(P[i].position_m.y(), 1e-3); });
  for (const auto& p : P) w.u(strength_code(p.strength, tq.strength_scale));
  for (const auto& p : P) w.s(q(p.power_db, tq.power_db));
  for (const auto& p : P) w.u(static_cast<std::uint64_t>(p.scattering));
  for (const auto& p : P) w.u(p.num_cells);
  column(w, L.size(), 1, [&](std::size_t i) { return q(L[i].start_m.x(), 1e-2); });
  column(w, L.size(), 1, [&](std::size_t i) { return q(L[i].start_m.y(), 1e-2); });
  for (const auto& l : L) w.s(q(l.end_m.x(), 1e-2) - q(l.start_m.x(), 1e-2));
  for (const auto& l : L) w.s(q(l.end_m.y(), 1e-2) - q(l.start_m.y(), 1e-2));
  for (const auto& l : L) w.u(strength_code(l.strength, tq.strength_scale));
  column(w, T.size(), 2, [&](std::size_t i) { return q(T[i].time_s, tq.time_s); });
  column(w, T.size(), 2, [&](std::size_t i) { return q(T[i].lat_deg, 1e-8); });
  column(w, T.size(), 2, [&](std::size_t i) { return q(T[i].lon_deg, 1e-8); });
  column(w, T.size(), 1, [&](std::size_t i) { return q(T[i].yaw_enu_rad, tq.yaw_rad); });
  column(w, T.size(), 1, [&](std::size_t i) { return q(T[i].speed_mps, 1e-3); });
  column(w, T.size(), 1, [&](std::size_t i) { return q(T[i].yaw_rate_rps, tq.yaw_rate_rps); });
  for (const auto& t : T)
    w.u(static_cast<std::uint64_t>(std::max<std::int64_t>(0, q(t.std_east_m, 1e-3))));
  for (const auto& t : T)
    w.u(static_cast<std::uint64_t>(std::max<std::int64_t>(0, q(t.std_north_m, 1e-3))));
  for (const auto& t : T)
    w.u(static_cast<std::uint64_t>(std::max<std::int64_t>(0, q(t.std_yaw_rad, tq.std_yaw_rad))));
  for (const auto& t : T) w.u(static_cast<std::uint64_t>(t.solution));

  uLongf packed_len = compressBound(static_cast<uLong>(w.out.size()));
  std::string packed(packed_len, '\0');
  const int rc =
      compress2(reinterpret_cast<Bytef*>(packed.data()), &packed_len,
                reinterpret_cast<const Bytef*>(w.out.data()), static_cast<uLong>(w.out.size()), 9);
  if (rc != Z_OK) throw IoError("candidates.bin: zlib compress failed");
  packed.resize(packed_len);

  std::string out(kMagic.begin(), kMagic.end());
  put_u32(out, version);
  put_u32(out, static_cast<std::uint32_t>(w.out.size()));
  put_u32(out, static_cast<std::uint32_t>(P.size()));
  put_u32(out, static_cast<std::uint32_t>(L.size()));
  put_u32(out, static_cast<std::uint32_t>(T.size()));
  put_u32(out, static_cast<std::uint32_t>(crc32(0L, reinterpret_cast<const Bytef*>(w.out.data()),
                                                static_cast<uInt>(w.out.size()))));
  put_u32(out, 0);
  return out + packed;
}

CandidatesContent decode_candidates(std::string_view bytes, const CandidatesDecodeLimits& lim) {
  if (bytes.size() < kHeaderBytes)
    bad("header", "truncated (" + std::to_string(bytes.size()) + " bytes)");
  if (std::memcmp(bytes.data(), kMagic.data(), kMagic.size()) != 0)
    bad("header", "not a candidates.bin file (magic)");
  const std::uint32_t version = get_u32(bytes, 4);
  if (version != 1 && version != 2) {
    bad("version",
        "unsupported version " + std::to_string(version) + " (this build reads 1 and 2)");
  }
  const Quanta tq = quanta(version);
  const auto max_strength = static_cast<std::uint64_t>(tq.strength_scale * kMaxLogStrength);
  const std::uint64_t body_len = get_u32(bytes, 8);
  const std::uint64_t np = get_u32(bytes, 12), nl = get_u32(bytes, 16), nt = get_u32(bytes, 20);
  const std::uint32_t crc = get_u32(bytes, 24);
  if (get_u32(bytes, 28) != 0) bad("header", "reserved field not zero");
  if (np > lim.max_points) bad("points", std::to_string(np) + " points exceed the limit");
  if (nl > lim.max_lines) bad("lines", std::to_string(nl) + " lines exceed the limit");
  if (nt > lim.max_trajectory_samples)
    bad("trajectory", std::to_string(nt) + " samples exceed the limit");
  const std::uint64_t packed_len = bytes.size() - kHeaderBytes;
  if (body_len > lim.max_body_bytes || body_len > lim.max_inflation_ratio * packed_len + 64) {
    bad("header", "inflated size " + std::to_string(body_len) + " is implausible for " +
                      std::to_string(packed_len) + " compressed bytes");
  }
  if (body_len < np * kPointColumns + nl * kLineColumns + nt * kTrajectoryColumns) {
    bad("header", "inflated size " + std::to_string(body_len) + " too small for the counts");
  }
  std::string body(body_len, '\0');
  {
    z_stream z{};
    if (inflateInit(&z) != Z_OK) throw IoError("candidates.bin: zlib init failed");
    z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(bytes.data() + kHeaderBytes));
    z.avail_in = static_cast<uInt>(packed_len);
    z.next_out = reinterpret_cast<Bytef*>(body.data());
    z.avail_out = static_cast<uInt>(body.size());
    const int rc = inflate(&z, Z_FINISH);
    const bool exact = rc == Z_STREAM_END && z.avail_out == 0 && z.avail_in == 0;
    inflateEnd(&z);
    if (!exact)
      bad("body", "zlib stream corrupt, truncated or of another size than the header says");
  }
  if (static_cast<std::uint32_t>(crc32(0L, reinterpret_cast<const Bytef*>(body.data()),
                                       static_cast<uInt>(body.size()))) != crc) {
    bad("body", "CRC-32 mismatch");
  }
  Reader r{body};
  CandidatesContent c;
  std::vector<std::int64_t> a, b;
  c.points.resize(np);
  read_column(r, np, 1, "points.x", a);
  read_column(r, np, 1, "points.y", b);
  for (std::size_t i = 0; i < np; ++i) c.points[i].position_m = {a[i] * 1e-3, b[i] * 1e-3};
  {
    const auto st = read_unsigned(r, np, "points.strength", max_strength);
    for (std::size_t i = 0; i < np; ++i)
      c.points[i].strength = strength_value(st[i], tq.strength_scale);
  }
  for (std::size_t i = 0; i < np; ++i) {
    const std::int64_t v = r.s("points.power_db");
    if (v > 100'000 || v < -100'000)
      bad("points.power_db", "out of range at element " + std::to_string(i));
    c.points[i].power_db = double(v) * tq.power_db;
  }
  {
    const auto sc = read_unsigned(r, np, "points.scattering", 3);
    for (std::size_t i = 0; i < np; ++i)
      c.points[i].scattering = static_cast<ScatteringClass>(sc[i]);
    const auto nc =
        read_unsigned(r, np, "points.num_cells", std::numeric_limits<std::uint32_t>::max());
    for (std::size_t i = 0; i < np; ++i) c.points[i].num_cells = static_cast<std::uint32_t>(nc[i]);
  }
  c.lines.resize(nl);
  read_column(r, nl, 1, "lines.x0", a);
  read_column(r, nl, 1, "lines.y0", b);
  for (std::size_t i = 0; i < nl; ++i) c.lines[i].start_m = {a[i] * 1e-2, b[i] * 1e-2};
  for (int axis = 0; axis < 2; ++axis) {
    const char* field = axis == 0 ? "lines.dx" : "lines.dy";
    for (std::size_t i = 0; i < nl; ++i) {
      const std::int64_t d = r.s(field);
      if (d > kMaxAbs || d < -kMaxAbs)
        bad(field, "value out of range at element " + std::to_string(i));
      c.lines[i].end_m[axis] = c.lines[i].start_m[axis] + double(d) * 1e-2;
    }
  }
  {
    const auto st = read_unsigned(r, nl, "lines.strength", max_strength);
    for (std::size_t i = 0; i < nl; ++i)
      c.lines[i].strength = strength_value(st[i], tq.strength_scale);
  }
  c.trajectory.resize(nt);
  auto& T = c.trajectory;
  read_column(r, nt, 2, "trajectory.time", a);
  for (std::size_t i = 0; i < nt; ++i) T[i].time_s = double(a[i]) * tq.time_s;
  read_column(r, nt, 2, "trajectory.lat", a);
  for (std::size_t i = 0; i < nt; ++i) T[i].lat_deg = a[i] * 1e-8;
  read_column(r, nt, 2, "trajectory.lon", a);
  for (std::size_t i = 0; i < nt; ++i) T[i].lon_deg = a[i] * 1e-8;
  read_column(r, nt, 1, "trajectory.yaw", a);
  for (std::size_t i = 0; i < nt; ++i) T[i].yaw_enu_rad = double(a[i]) * tq.yaw_rad;
  read_column(r, nt, 1, "trajectory.speed", a);
  for (std::size_t i = 0; i < nt; ++i) T[i].speed_mps = a[i] * 1e-3;
  read_column(r, nt, 1, "trajectory.yaw_rate", a);
  for (std::size_t i = 0; i < nt; ++i) T[i].yaw_rate_rps = double(a[i]) * tq.yaw_rate_rps;
  const std::uint64_t kMaxStd = 1'000'000'000;  // 1000 km / 1000 rad
  {
    const auto e = read_unsigned(r, nt, "trajectory.std_east", kMaxStd);
    const auto n = read_unsigned(r, nt, "trajectory.std_north", kMaxStd);
    const auto y = read_unsigned(r, nt, "trajectory.std_yaw", kMaxStd);
    const auto s = read_unsigned(r, nt, "trajectory.solution", 2);
    for (std::size_t i = 0; i < nt; ++i) {
      T[i].std_east_m = static_cast<float>(double(e[i]) * 1e-3);
      T[i].std_north_m = static_cast<float>(double(n[i]) * 1e-3);
      T[i].std_yaw_rad = static_cast<float>(double(y[i]) * tq.std_yaw_rad);
      T[i].solution = static_cast<GnssSolution>(s[i]);
    }
  }
  if (r.pos != body.size()) bad("body", std::to_string(body.size() - r.pos) + " trailing bytes");
  return c;
}

}  // namespace polmap::mapping
