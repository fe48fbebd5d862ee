#include "polmap/tiles/localization_tile.hpp"

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>

#include "polmap/schema/errors.hpp"

namespace polmap::tiles {
namespace {

constexpr char kMagic[4] = {'P', 'M', 'L', 'T'};
constexpr std::size_t kHeaderBytes = 16;
constexpr std::size_t kTrailerBytes = 4;
constexpr std::uint8_t kStored = 0;
constexpr std::uint8_t kRawDeflate = 1;
// Decoder refuses bodies that would inflate beyond this (a z16 tile holds a few kB).
constexpr std::uint32_t kMaxBodyBytes = 64u << 20;

// ---- byte helpers ---------------------------------------------------------------------------

void put_u16(std::string& s, std::uint16_t v) {
  s.push_back(static_cast<char>(v & 0xFF));
  s.push_back(static_cast<char>(v >> 8));
}
void put_u32(std::string& s, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) s.push_back(static_cast<char>((v >> (8 * i)) & 0xFF));
}
std::uint32_t get_u32(std::string_view s, std::size_t at) {
  std::uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= std::uint32_t{static_cast<unsigned char>(s[at + i])} << (8 * i);
  return v;
}
std::uint16_t get_u16(std::string_view s, std::size_t at) {
  return static_cast<std::uint16_t>(static_cast<unsigned char>(s[at]) |
                                    (static_cast<unsigned char>(s[at + 1]) << 8));
}

void put_varint(std::string& s, std::uint64_t v) {
  while (v >= 0x80) {
    s.push_back(static_cast<char>((v & 0x7F) | 0x80));
    v >>= 7;
  }
  s.push_back(static_cast<char>(v));
}
std::uint64_t zigzag(std::int64_t v) {
  return (static_cast<std::uint64_t>(v) << 1) ^ static_cast<std::uint64_t>(v >> 63);
}
std::int64_t unzigzag(std::uint64_t v) {
  return static_cast<std::int64_t>(v >> 1) ^ -static_cast<std::int64_t>(v & 1);
}
void put_svarint(std::string& s, std::int64_t v) { put_varint(s, zigzag(v)); }

std::uint32_t crc32_of(std::string_view bytes) {
  return static_cast<std::uint32_t>(
      ::crc32(0L, reinterpret_cast<const Bytef*>(bytes.data()), static_cast<uInt>(bytes.size())));
}

// ---- encoder --------------------------------------------------------------------------------

std::int64_t quantize(double v_m, double quantum_m, const char* what) {
  if (!std::isfinite(v_m) || std::abs(v_m) > kMaxTileCoordinateM) {
    throw ValidationError(std::string("localization tile: ") + what + " = " + std::to_string(v_m) +
                          " m is not finite or beyond ±100 km of the tile centre");
  }
  return std::llround(v_m / quantum_m);
}

std::uint64_t quantize_spread(double spread_m, double quantum_m) {
  if (!std::isfinite(spread_m) || spread_m < 0.0 || spread_m > kMaxTileCoordinateM) {
    throw ValidationError("localization tile: spread_m = " + std::to_string(spread_m) +
                          " is negative, not finite or beyond 100 km");
  }
  return static_cast<std::uint64_t>(std::llround(spread_m / quantum_m));
}

std::string raw_deflate(std::string_view in, int level) {
  z_stream zs{};
  if (deflateInit2(&zs, level, Z_DEFLATED, -15, 9, Z_DEFAULT_STRATEGY) != Z_OK) {
    throw Error("localization tile: deflateInit2 failed");
  }
  std::string out(deflateBound(&zs, static_cast<uLong>(in.size())), '\0');
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(in.data()));
  zs.avail_in = static_cast<uInt>(in.size());
  zs.next_out = reinterpret_cast<Bytef*>(out.data());
  zs.avail_out = static_cast<uInt>(out.size());
  const int rc = deflate(&zs, Z_FINISH);
  out.resize(zs.total_out);
  deflateEnd(&zs);
  if (rc != Z_STREAM_END) throw Error("localization tile: deflate failed");
  return out;
}

// ---- decoder --------------------------------------------------------------------------------

class BodyReader {
 public:
  BodyReader(std::string_view body, const std::string& source) : body_(body), source_(source) {}

  std::uint64_t varint(const char* field) {
    std::uint64_t v = 0;
    const std::size_t start = pos_;
    for (int shift = 0; shift < 64; shift += 7) {
      if (pos_ >= body_.size()) fail(start, std::string("body truncated in ") + field);
      const auto b = static_cast<unsigned char>(body_[pos_++]);
      if (shift == 63 && b > 1) fail(start, std::string("varint overflow in ") + field);
      v |= std::uint64_t{b & 0x7Fu} << shift;
      if ((b & 0x80) == 0) return v;
    }
    fail(start, std::string("varint longer than 10 bytes in ") + field);
  }
  std::int64_t svarint(const char* field) { return unzigzag(varint(field)); }
  /// A count that cannot exceed the remaining bytes divided by min_bytes_each.
  std::size_t count(const char* field, std::size_t min_bytes_each) {
    const std::size_t start = pos_;
    const std::uint64_t n = varint(field);
    if (n > (body_.size() - pos_) / min_bytes_each) {
      fail(start, std::string(field) + " = " + std::to_string(n) + " exceeds the body size");
    }
    return static_cast<std::size_t>(n);
  }
  [[nodiscard]] std::size_t pos() const { return pos_; }
  [[nodiscard]] bool at_end() const { return pos_ == body_.size(); }
  [[noreturn]] void fail(std::size_t at, const std::string& what) const {
    // Body offsets are offsets into the inflated body, reported as such.
    throw FormatError(source_, at, "(inflated body) " + what);
  }

 private:
  std::string_view body_;
  const std::string& source_;
  std::size_t pos_ = 0;
};

std::string inflate_raw(std::string_view in, std::uint32_t expected, const std::string& source) {
  std::string out(expected, '\0');
  z_stream zs{};
  if (inflateInit2(&zs, -15) != Z_OK) throw Error("localization tile: inflateInit2 failed");
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(in.data()));
  zs.avail_in = static_cast<uInt>(in.size());
  zs.next_out = reinterpret_cast<Bytef*>(out.data());
  zs.avail_out = static_cast<uInt>(out.size());
  const int rc = inflate(&zs, Z_FINISH);
  const auto produced = zs.total_out;
  const auto consumed = zs.total_in;
  inflateEnd(&zs);
  if (rc != Z_STREAM_END) {
    throw FormatError(source, kHeaderBytes + consumed,
                      rc == Z_BUF_ERROR ? "deflate stream inflates beyond the announced " +
                                              std::to_string(expected) + " bytes or ends early"
                                        : "corrupt deflate stream");
  }
  if (produced != expected || consumed != in.size()) {
    throw FormatError(source, kHeaderBytes + consumed,
                      "deflate stream gives " + std::to_string(produced) + " bytes from " +
                          std::to_string(consumed) + " input bytes, header announces " +
                          std::to_string(expected) + " from " + std::to_string(in.size()));
  }
  return out;
}

}  // namespace

std::string encode_localization_tile(const LocalizationTile& tile,
                                     const TileEncodeOptions& options) {
  if (!is_valid(tile.key)) {
    throw ValidationError("localization tile: invalid key " + to_string(tile.key));
  }
  if (!(options.quantum_m >= 1e-4 && options.quantum_m <= 1.0) ||
      !(options.spread_quantum_m >= 1e-4 && options.spread_quantum_m <= 1.0)) {
    throw ValidationError("localization tile: quantum_m and spread_quantum_m must be in [1e-4, 1]");
  }
  if (options.compression_level < 0 || options.compression_level > 9) {
    throw ValidationError("localization tile: compression_level must be in [0, 9]");
  }
  // Quanta are stored in whole micrometres, so encoder and decoder agree exactly.
  const auto quantum_um = static_cast<std::uint64_t>(std::llround(options.quantum_m * 1e6));
  const auto spread_um = static_cast<std::uint64_t>(std::llround(options.spread_quantum_m * 1e6));
  const double q = static_cast<double>(quantum_um) * 1e-6;
  const double sq = static_cast<double>(spread_um) * 1e-6;

  std::string body;
  body.reserve(16 + tile.points.size() * 10 + tile.lines.size() * 16);
  put_varint(body, static_cast<std::uint64_t>(tile.key.z));
  put_varint(body, static_cast<std::uint64_t>(tile.key.x));
  put_varint(body, static_cast<std::uint64_t>(tile.key.y));
  put_varint(body, tile.map_version);
  put_varint(body, quantum_um);
  put_varint(body, spread_um);

  // Canonical order: by id (ties by position), so the bytes do not depend on input order.
  std::vector<std::size_t> order(tile.points.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    const auto& pa = tile.points[a];
    const auto& pb = tile.points[b];
    if (pa.id != pb.id) return pa.id < pb.id;
    if (pa.position_m.x() != pb.position_m.x()) return pa.position_m.x() < pb.position_m.x();
    return pa.position_m.y() < pb.position_m.y();
  });
  std::uint64_t prev_id = 0;
  std::int64_t cx = 0, cy = 0;  // one delta cursor through all coordinates
  put_varint(body, tile.points.size());
  for (std::size_t i : order) {
    const PointLandmark& p = tile.points[i];
    const auto id = static_cast<std::uint64_t>(p.id);
    put_svarint(body, static_cast<std::int64_t>(id - prev_id));  // wrap-around safe
    prev_id = id;
    const std::int64_t qx = quantize(p.position_m.x(), q, "point x");
    const std::int64_t qy = quantize(p.position_m.y(), q, "point y");
    put_svarint(body, qx - cx);
    put_svarint(body, qy - cy);
    cx = qx;
    cy = qy;
    const auto cls = static_cast<std::uint64_t>(p.scattering);
    if (cls > 3) throw ValidationError("localization tile: point scattering class out of range");
    put_varint(body, (std::uint64_t{p.support_drives} << 2) | cls);
    put_varint(body, quantize_spread(p.spread_m, sq));
  }

  order.resize(tile.lines.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return tile.lines[a].id < tile.lines[b].id;
  });
  prev_id = 0;
  put_varint(body, tile.lines.size());
  for (std::size_t i : order) {
    const LineLandmark& l = tile.lines[i];
    if (l.polyline_m.size() < 2) {
      throw ValidationError("localization tile: line " + std::to_string(l.id) + " has " +
                            std::to_string(l.polyline_m.size()) + " vertices (needs ≥ 2)");
    }
    const auto id = static_cast<std::uint64_t>(l.id);
    put_svarint(body, static_cast<std::int64_t>(id - prev_id));
    prev_id = id;
    put_varint(body, l.support_drives);
    put_varint(body, quantize_spread(l.spread_m, sq));
    put_varint(body, l.polyline_m.size());
    for (const Eigen::Vector2d& v : l.polyline_m) {
      const std::int64_t qx = quantize(v.x(), q, "line vertex x");
      const std::int64_t qy = quantize(v.y(), q, "line vertex y");
      put_svarint(body, qx - cx);
      put_svarint(body, qy - cy);
      cx = qx;
      cy = qy;
    }
  }
  if (body.size() > kMaxBodyBytes) {
    throw ValidationError("localization tile: body of " + std::to_string(body.size()) +
                          " bytes exceeds the 64 MiB limit");
  }

  std::string packed;
  std::uint8_t compression = kStored;
  if (options.compression_level > 0) {
    packed = raw_deflate(body, options.compression_level);
    if (packed.size() < body.size()) compression = kRawDeflate;
  }
  const std::string_view stored =
      compression == kRawDeflate ? std::string_view(packed) : std::string_view(body);
  std::string out;
  out.reserve(kHeaderBytes + stored.size() + kTrailerBytes);
  out.append(kMagic, 4);
  put_u16(out, kLocalizationTileFormatVersion);
  out.push_back(static_cast<char>(compression));
  out.push_back('\0');
  put_u32(out, static_cast<std::uint32_t>(stored.size()));
  put_u32(out, static_cast<std::uint32_t>(body.size()));
  out.append(stored);
  put_u32(out, crc32_of(out));
  return out;
}

LocalizationTile decode_localization_tile(std::string_view bytes, const std::string& source) {
  if (bytes.size() >= 4 && std::memcmp(bytes.data(), kMagic, 4) != 0) {
    throw FormatError(source, 0, "bad magic (not a polmap localization tile, expected \"PMLT\")");
  }
  if (bytes.size() < kHeaderBytes + kTrailerBytes) {
    throw FormatError(source, bytes.size(),
                      "truncated: " + std::to_string(bytes.size()) +
                          " bytes, shorter than the 20-byte header and trailer");
  }
  const std::uint16_t version = get_u16(bytes, 4);
  if (version != kLocalizationTileFormatVersion) {
    throw FormatError(source, 4,
                      "unknown format version " + std::to_string(version) +
                          " (this build reads version " +
                          std::to_string(kLocalizationTileFormatVersion) + ")");
  }
  const auto compression = static_cast<std::uint8_t>(bytes[6]);
  const std::uint32_t stored_len = get_u32(bytes, 8);
  const std::uint32_t body_len = get_u32(bytes, 12);
  const std::uint64_t expected_total = std::uint64_t{kHeaderBytes} + stored_len + kTrailerBytes;
  if (bytes.size() < expected_total) {
    throw FormatError(source, bytes.size(),
                      "truncated: header announces " + std::to_string(expected_total) + " bytes, " +
                          std::to_string(bytes.size()) + " present");
  }
  if (bytes.size() > expected_total) {
    throw FormatError(
        source, expected_total,
        std::to_string(bytes.size() - expected_total) + " trailing bytes after the CRC-32");
  }
  const std::uint32_t stored_crc = get_u32(bytes, kHeaderBytes + stored_len);
  const std::uint32_t actual_crc = crc32_of(bytes.substr(0, kHeaderBytes + stored_len));
  if (stored_crc != actual_crc) {
    char buf[96];
    std::snprintf(buf, sizeof(buf), "CRC-32 mismatch (stored %08x, computed %08x)", stored_crc,
                  actual_crc);
    throw FormatError(source, kHeaderBytes + stored_len, buf);
  }
  if (body_len > kMaxBodyBytes) {
    throw FormatError(source, 12,
                      "body length " + std::to_string(body_len) + " exceeds the 64 MiB limit");
  }
  const std::string_view stored = bytes.substr(kHeaderBytes, stored_len);
  std::string inflated;
  std::string_view body;
  if (compression == kStored) {
    if (stored_len != body_len) {
      throw FormatError(source, 8,
                        "stored body length " + std::to_string(stored_len) +
                            " differs from body length " + std::to_string(body_len));
    }
    body = stored;
  } else if (compression == kRawDeflate) {
    inflated = inflate_raw(stored, body_len, source);
    body = inflated;
  } else {
    throw FormatError(source, 6, "unknown compression method " + std::to_string(compression));
  }

  BodyReader r(body, source);
  LocalizationTile tile;
  const std::size_t key_at = r.pos();
  const std::uint64_t z = r.varint("key z");
  const std::uint64_t x = r.varint("key x");
  const std::uint64_t y = r.varint("key y");
  if (z > kMaxZoom || x >= static_cast<std::uint64_t>(tiles_per_side(static_cast<int>(z))) ||
      y >= static_cast<std::uint64_t>(tiles_per_side(static_cast<int>(z)))) {
    r.fail(key_at, "invalid tile key");
  }
  tile.key = {static_cast<int>(z), static_cast<int>(x), static_cast<int>(y)};
  tile.map_version = r.varint("map_version");
  const std::size_t q_at = r.pos();
  const std::uint64_t quantum_um = r.varint("quantum_um");
  const std::uint64_t spread_um = r.varint("spread_quantum_um");
  if (quantum_um < 100 || quantum_um > 1000000 || spread_um < 100 || spread_um > 1000000) {
    r.fail(q_at, "quantum out of range [100, 1e6] µm");
  }
  const double q = static_cast<double>(quantum_um) * 1e-6;
  const double sq = static_cast<double>(spread_um) * 1e-6;

  std::uint64_t id = 0;
  std::int64_t cx = 0, cy = 0;
  // Each point takes at least 5 bytes (five one-byte varints).
  tile.points.resize(r.count("num_points", 5));
  for (PointLandmark& p : tile.points) {
    id += static_cast<std::uint64_t>(r.svarint("point id"));
    p.id = static_cast<std::int64_t>(id);
    cx += r.svarint("point x");
    cy += r.svarint("point y");
    p.position_m = {static_cast<double>(cx) * q, static_cast<double>(cy) * q};
    const std::uint64_t packed = r.varint("point support/class");
    if ((packed >> 2) > 0xFFFFFFFFu) r.fail(r.pos(), "point support_drives exceeds 32 bits");
    p.scattering = static_cast<ScatteringClass>(packed & 3u);
    p.support_drives = static_cast<std::uint32_t>(packed >> 2);
    p.spread_m = static_cast<double>(r.varint("point spread")) * sq;
  }
  id = 0;
  // Each line takes at least 8 bytes (id, support, spread, count, two 2-byte vertices).
  tile.lines.resize(r.count("num_lines", 8));
  for (LineLandmark& l : tile.lines) {
    id += static_cast<std::uint64_t>(r.svarint("line id"));
    l.id = static_cast<std::int64_t>(id);
    const std::uint64_t support = r.varint("line support");
    if (support > 0xFFFFFFFFu) r.fail(r.pos(), "line support_drives exceeds 32 bits");
    l.support_drives = static_cast<std::uint32_t>(support);
    l.spread_m = static_cast<double>(r.varint("line spread")) * sq;
    const std::size_t n_at = r.pos();
    const std::size_t n = r.count("line vertex count", 2);
    if (n < 2) r.fail(n_at, "line " + std::to_string(l.id) + " has fewer than 2 vertices");
    l.polyline_m.resize(n);
    for (Eigen::Vector2d& v : l.polyline_m) {
      cx += r.svarint("line vertex x");
      cy += r.svarint("line vertex y");
      v = {static_cast<double>(cx) * q, static_cast<double>(cy) * q};
    }
  }
  if (!r.at_end()) r.fail(r.pos(), "trailing bytes after the last line");
  return tile;
}

}  // namespace polmap::tiles
