#include "polmap/localization_client/tile_cache_file.hpp"

#include <charconv>
#include <cmath>
#include <optional>

#include "polmap/schema/errors.hpp"

namespace polmap::loc {
namespace {

bool is_control(char c) {
  const auto u = static_cast<unsigned char>(c);
  return u < 0x20 || u == 0x7f;
}

/// A plain decimal (digits only, at most 20) that fits in 64 bits.
std::optional<std::uint64_t> parse_u64(std::string_view s) {
  if (s.empty() || s.size() > 20) return std::nullopt;
  for (const char c : s) {
    if (c < '0' || c > '9') return std::nullopt;
  }
  std::uint64_t v = 0;
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc{} || p != s.data() + s.size()) return std::nullopt;
  return v;
}

/// A finite, non-negative decimal number (no "inf", "nan", hex or trailing text).
std::optional<double> parse_time(std::string_view s) {
  if (s.empty() || s.size() > 64) return std::nullopt;
  double v = 0.0;
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc{} || p != s.data() + s.size() || !std::isfinite(v) || v < 0.0) {
    return std::nullopt;
  }
  return v;
}

TileCacheDecodeResult failure(TileCacheStatus status, std::string message) {
  TileCacheDecodeResult r;
  r.status = status;
  r.message = std::move(message);
  return r;
}

std::string at(std::size_t offset, std::string_view what) {
  std::string s = "at byte ";
  s += std::to_string(offset);
  s += ": ";
  s += what;
  return s;
}

enum Line : unsigned { kStatus = 1, kEtag = 2, kVersion = 4, kFetched = 8, kKey = 16, kSize = 32 };
constexpr unsigned kRequired = kStatus | kEtag | kVersion | kFetched;

}  // namespace

std::string_view to_string(TileCacheStatus status) {
  switch (status) {
    case TileCacheStatus::Ok:
      return "ok";
    case TileCacheStatus::TooLarge:
      return "too_large";
    case TileCacheStatus::NotACacheFile:
      return "not_a_cache_file";
    case TileCacheStatus::Truncated:
      return "truncated";
    case TileCacheStatus::Malformed:
      return "malformed";
    case TileCacheStatus::UnsupportedStatus:
      return "unsupported_status";
    case TileCacheStatus::BadPayload:
      return "bad_payload";
    case TileCacheStatus::WrongKey:
      return "wrong_key";
  }
  return "unknown";
}

std::string encode_tile_cache_file(const TileCacheRecord& record, const tiles::TileKey& key) {
  const int st = record.http_status;
  if (st != 200 && st != 204 && st != 404) {
    throw ValidationError("tile cache file: HTTP status " + std::to_string(st) +
                          " is not stored (200, 204, 404)");
  }
  if (!tiles::is_valid(key)) throw ValidationError("tile cache file: invalid tile key");
  if (record.etag.size() > kMaxTileCacheEtagBytes) {
    throw ValidationError("tile cache file: ETag longer than " +
                          std::to_string(kMaxTileCacheEtagBytes) + " bytes");
  }
  for (const char c : record.etag) {
    if (is_control(c)) throw ValidationError("tile cache file: control character in the ETag");
  }
  if (!std::isfinite(record.fetched_unix_s) || record.fetched_unix_s < 0.0) {
    throw ValidationError("tile cache file: fetch time is not a finite, non-negative number");
  }
  if (st != 200 && !record.payload.empty()) {
    throw ValidationError("tile cache file: a " + std::to_string(st) + " answer has no payload");
  }
  char fetched[64];
  const auto [end, ec] = std::to_chars(fetched, fetched + sizeof(fetched), record.fetched_unix_s);
  if (ec != std::errc{}) throw ValidationError("tile cache file: fetch time not representable");
  std::string out(kTileCacheFileTag);
  out += "\nstatus ";
  out += std::to_string(st);
  out += "\netag ";
  out += record.etag;
  out += "\nversion ";
  out += std::to_string(record.header_version);
  out += "\nfetched ";
  out.append(fetched, end);
  out += "\nkey ";
  out += tiles::to_string(key);
  out += "\nsize ";
  out += std::to_string(record.payload.size());
  out += "\n\n";
  out += record.payload;
  return out;
}

TileCacheDecodeResult decode_tile_cache_file(std::string_view bytes, const tiles::TileKey& key,
                                             std::size_t max_payload_bytes) {
  using S = TileCacheStatus;
  // Tag line first: a file that is not ours is named as such, even when short.
  const std::string tag_line = std::string(kTileCacheFileTag) + "\n";
  if (bytes.substr(0, tag_line.size()) != tag_line) {
    if (bytes.size() < tag_line.size() && tag_line.starts_with(bytes)) {
      return failure(S::Truncated, at(bytes.size(), "ends inside the tag line"));
    }
    return failure(S::NotACacheFile, at(0, "no PMTC1 tag"));
  }
  // The header ends at the first empty line, searched only in the first bytes.
  const std::string_view window = bytes.substr(0, kMaxTileCacheHeaderBytes);
  const std::size_t blank = window.find("\n\n");
  if (blank == std::string_view::npos) {
    if (bytes.size() < kMaxTileCacheHeaderBytes) {
      return failure(S::Truncated, at(bytes.size(), "ends inside the header"));
    }
    return failure(S::Malformed, at(0, "no end of header in the first " +
                                           std::to_string(kMaxTileCacheHeaderBytes) + " bytes"));
  }
  const std::size_t header_bytes = blank + 2;
  const std::string_view payload_rest = bytes.substr(header_bytes);

  TileCacheDecodeResult r;
  unsigned seen = 0;
  std::optional<std::uint64_t> size;
  std::size_t pos = tag_line.size();
  while (pos < blank + 1) {
    const std::size_t nl = bytes.find('\n', pos);  // exists: blank + 1 is a '\n'
    const std::string_view line = bytes.substr(pos, nl - pos);
    const std::size_t line_at = pos;
    pos = nl + 1;
    for (std::size_t i = 0; i < line.size(); ++i) {
      if (is_control(line[i])) return failure(S::Malformed, at(line_at + i, "control character"));
    }
    const std::size_t sp = line.find(' ');
    const std::string_view name = line.substr(0, sp);
    const std::string_view value = sp == std::string_view::npos ? "" : line.substr(sp + 1);
    unsigned bit = 0;
    if (name == "status") {
      bit = kStatus;
    } else if (name == "etag") {
      bit = kEtag;
    } else if (name == "version") {
      bit = kVersion;
    } else if (name == "fetched") {
      bit = kFetched;
    } else if (name == "key") {
      bit = kKey;
    } else if (name == "size") {
      bit = kSize;
    } else {
      continue;  // a newer writer's line
    }
    if ((seen & bit) != 0) {
      return failure(S::Malformed, at(line_at, "duplicate '" + std::string(name) + "' line"));
    }
    seen |= bit;
    const auto bad_value = [&] {
      return failure(S::Malformed, at(line_at, "bad '" + std::string(name) + "' value"));
    };
    switch (bit) {
      case kStatus: {
        const auto v = parse_u64(value);
        if (!v) return bad_value();
        if (*v != 200 && *v != 204 && *v != 404) {
          return failure(S::UnsupportedStatus,
                         at(line_at, "HTTP status " + std::string(value) + " is never stored"));
        }
        r.record.http_status = static_cast<int>(*v);
        break;
      }
      case kEtag:
        if (value.size() > kMaxTileCacheEtagBytes) return bad_value();
        r.record.etag = std::string(value);
        break;
      case kVersion: {
        const auto v = parse_u64(value);
        if (!v) return bad_value();
        r.record.header_version = *v;
        break;
      }
      case kFetched: {
        const auto v = parse_time(value);
        if (!v) return bad_value();
        r.record.fetched_unix_s = *v;
        break;
      }
      case kKey: {
        const auto k = tiles::parse_tile_key(value);
        if (!k) return bad_value();
        if (!(*k == key)) {
          return failure(S::WrongKey, at(line_at, "file is for tile " + std::string(value) +
                                                      ", not " + tiles::to_string(key)));
        }
        break;
      }
      case kSize:
        size = parse_u64(value);
        if (!size) return bad_value();
        break;
      default:
        break;
    }
  }
  if ((seen & kRequired) != kRequired) {
    return failure(S::Malformed, at(header_bytes, "header lacks status, etag, version or fetched"));
  }
  // `size` is only compared with what is present; nothing is read or allocated from it.
  if (size) {
    if (*size > payload_rest.size()) {
      return failure(S::Truncated,
                     at(bytes.size(), "payload of " + std::to_string(*size) + " bytes announced, " +
                                          std::to_string(payload_rest.size()) + " present"));
    }
    if (*size < payload_rest.size()) {
      return failure(S::Malformed, at(header_bytes + *size, "trailing bytes after the payload"));
    }
  }
  if (payload_rest.size() > max_payload_bytes) {
    return failure(S::TooLarge,
                   at(header_bytes, "payload of " + std::to_string(payload_rest.size()) +
                                        " bytes exceeds the limit"));
  }
  if (r.record.http_status == 200) {
    try {
      r.tile = tiles::decode_localization_tile(payload_rest, "tile cache file");
    } catch (const Error& e) {
      return failure(S::BadPayload, e.what());
    }
    if (!(r.tile.key == key)) {
      return failure(S::WrongKey, "payload is tile " + tiles::to_string(r.tile.key) + ", not " +
                                      tiles::to_string(key));
    }
    r.record.payload = std::string(payload_rest);
  } else {
    if (!payload_rest.empty()) {
      return failure(S::BadPayload, at(header_bytes, "a 204/404 answer carries no payload"));
    }
    r.tile.key = key;
    r.tile.map_version = r.record.header_version;
  }
  r.status = S::Ok;
  return r;
}

}  // namespace polmap::loc
