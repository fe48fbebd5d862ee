#include "polmap/mapping_service/ustar.hpp"

#include <algorithm>
#include <array>
#include <cstring>
#include <set>
#include <tuple>

#include "polmap/schema/errors.hpp"

namespace polmap::mapping {
namespace {

constexpr std::size_t kBlock = 512;

// Header field offsets/lengths (POSIX ustar).
constexpr std::size_t kNameOff = 0, kNameLen = 100;
constexpr std::size_t kModeOff = 100, kUidOff = 108, kGidOff = 116;
constexpr std::size_t kSizeOff = 124, kSizeLen = 12;
constexpr std::size_t kMtimeOff = 136;
constexpr std::size_t kChksumOff = 148, kChksumLen = 8;
constexpr std::size_t kTypeOff = 156;
constexpr std::size_t kMagicOff = 257;
constexpr std::size_t kVersionOff = 263;
constexpr std::size_t kPrefixOff = 345, kPrefixLen = 155;

void put_octal(char* field, std::size_t len, std::uint64_t value) {
  // len-1 zero-padded octal digits followed by NUL.
  for (std::size_t i = len - 1; i-- > 0;) {
    field[i] = static_cast<char>('0' + (value & 7U));
    value >>= 3U;
  }
  field[len - 1] = '\0';
}

std::uint32_t header_checksum(const unsigned char* h) {
  std::uint32_t sum = 0;
  for (std::size_t i = 0; i < kBlock; ++i) {
    sum += (i >= kChksumOff && i < kChksumOff + kChksumLen) ? ' ' : h[i];
  }
  return sum;
}

void check_name(const std::string& name) {
  if (name.empty() || name.size() > kNameLen || name.find('/') != std::string::npos ||
      name == "." || name == ".." || name.find('\0') != std::string::npos) {
    throw ContractViolation("ustar: invalid member name '" + name + "'");
  }
}

/// Parses an octal numeric field (NUL/space terminated, leading spaces allowed).
bool parse_octal(const char* field, std::size_t len, std::uint64_t& out) {
  // POSIX terminates every numeric field with a space or NUL inside the field; a field of
  // digits to its last byte is read by some readers and refused by others (GDAL's /vsitar/
  // stops listing there), so two readers would see two archives.
  if (len == 0 || (field[len - 1] != '\0' && field[len - 1] != ' ')) return false;
  std::size_t i = 0;
  while (i < len && field[i] == ' ') ++i;
  if (i < len && (static_cast<unsigned char>(field[i]) & 0x80U)) return false;  // base-256
  std::uint64_t v = 0;
  bool any = false;
  for (; i < len; ++i) {
    const char c = field[i];
    if (c == '\0' || c == ' ') break;
    if (c < '0' || c > '7') return false;
    if (v > (UINT64_MAX >> 3U)) return false;
    v = (v << 3U) | static_cast<std::uint64_t>(c - '0');
    any = true;
  }
  // Digits only: after the terminator nothing but NUL and space ("12 x" is not 10).
  for (; i < len; ++i) {
    if (field[i] != '\0' && field[i] != ' ') return false;
  }
  out = v;
  return any;
}

std::string c_string(const char* field, std::size_t len) { return {field, strnlen(field, len)}; }

}  // namespace

std::string ustar_header(const std::string& name, std::uint64_t size) {
  check_name(name);
  if (size >= (std::uint64_t{1} << 33U)) {
    throw ContractViolation("ustar: member " + name + " exceeds 8 GiB");
  }
  std::string h(kBlock, '\0');
  std::memcpy(h.data() + kNameOff, name.data(), name.size());
  put_octal(h.data() + kModeOff, 8, 0644);
  put_octal(h.data() + kUidOff, 8, 0);
  put_octal(h.data() + kGidOff, 8, 0);
  put_octal(h.data() + kSizeOff, kSizeLen, size);
  put_octal(h.data() + kMtimeOff, 12, 0);
  h[kTypeOff] = '0';
  std::memcpy(h.data() + kMagicOff, "ustar", 6);  // "ustar\0"
  std::memcpy(h.data() + kVersionOff, "00", 2);
  const std::uint32_t sum = header_checksum(reinterpret_cast<const unsigned char*>(h.data()));
  put_octal(h.data() + kChksumOff, 7, sum);  // 6 digits + NUL
  h[kChksumOff + 7] = ' ';
  return h;
}

std::string write_ustar(const std::vector<TarMember>& members) {
  std::size_t total = kUstarEndBytes;
  for (const auto& m : members) total += kBlock + m.data.size() + ustar_padding(m.data.size());
  std::string out;
  out.reserve(total);
  std::set<std::string> seen;
  for (const auto& m : members) {
    if (!seen.insert(m.name).second) throw ContractViolation("ustar: duplicate member " + m.name);
    out += ustar_header(m.name, m.data.size());
    out.append(m.data);
    out.append(ustar_padding(m.data.size()), '\0');
  }
  out.append(kUstarEndBytes, '\0');
  return out;
}

std::vector<TarMember> read_ustar(std::string_view bytes, const std::string& source) {
  std::vector<TarMember> members;
  for (auto& v : read_ustar_views(bytes, source)) {
    members.push_back({std::move(v.name), std::string(v.data)});
  }
  return members;
}

std::vector<TarMemberView> read_ustar_views(std::string_view bytes, const std::string& source) {
  std::vector<TarMemberView> members;
  std::set<std::string> seen;
  std::size_t off = 0;
  const auto fail = [&](std::size_t at, const std::string& what) -> FormatError {
    return FormatError(source, at, what);
  };
  while (true) {
    if (off + kBlock > bytes.size()) {
      throw fail(off, bytes.size() == off ? "truncated archive: missing end-of-archive marker"
                                          : "truncated archive: incomplete header block");
    }
    const auto* h = reinterpret_cast<const unsigned char*>(bytes.data() + off);
    if (std::all_of(h, h + kBlock, [](unsigned char c) { return c == 0; })) {
      // End of archive: two zero blocks (tolerate a lone one at the very end, as GNU tar does).
      // Only zeros may follow (tar pads to its record size); anything else is data another
      // reader might still take for members.
      const auto rest = bytes.substr(off);
      const auto bad = std::find_if(rest.begin(), rest.end(), [](char c) { return c != '\0'; });
      if (bad != rest.end()) {
        throw fail(off + static_cast<std::size_t>(bad - rest.begin()),
                   "data after the end-of-archive marker");
      }
      break;
    }
    const char* hc = bytes.data() + off;
    std::uint64_t stored_sum = 0;
    if (!parse_octal(hc + kChksumOff, kChksumLen, stored_sum)) {
      throw fail(off + kChksumOff, "not a tar header (unreadable checksum field)");
    }
    if (stored_sum != header_checksum(h)) {
      throw fail(off + kChksumOff, "tar header checksum mismatch");
    }
    if (std::memcmp(hc + kMagicOff, "ustar", 5) != 0) {
      throw fail(off + kMagicOff, "not a ustar header (magic)");
    }
    const char type = hc[kTypeOff];
    std::string name = c_string(hc + kNameOff, kNameLen);
    const std::string prefix = c_string(hc + kPrefixOff, kPrefixLen);
    if (!prefix.empty()) name = prefix + "/" + name;
    if (type != '0' && type != '\0') {
      throw fail(off + kTypeOff, std::string("member '") + name +
                                     "': unsupported tar entry type '" +
                                     (type >= 32 && type < 127 ? std::string(1, type) : "?") +
                                     "' (only regular files)");
    }
    const bool printable = std::all_of(name.begin(), name.end(), [](char c) {
      return static_cast<unsigned char>(c) >= 0x20 && static_cast<unsigned char>(c) < 0x7f;
    });
    if (name.empty() || !printable || name.find('/') != std::string::npos || name == "." ||
        name == "..") {
      throw fail(off + kNameOff, "member name is not a flat, printable file name");
    }
    // Every numeric field octal digits only (other readers reject the header otherwise and
    // would see another archive than we do).
    for (const auto& [field_off, field_len, what] :
         {std::tuple{kModeOff, std::size_t{8}, "mode"}, std::tuple{kUidOff, std::size_t{8}, "uid"},
          std::tuple{kGidOff, std::size_t{8}, "gid"},
          std::tuple{kMtimeOff, std::size_t{12}, "mtime"}}) {
      std::uint64_t ignored = 0;
      if (!parse_octal(hc + field_off, field_len, ignored)) {
        throw fail(off + field_off, "member '" + name + "': unreadable " + what + " field");
      }
    }
    std::uint64_t size = 0;
    if (!parse_octal(hc + kSizeOff, kSizeLen, size)) {
      throw fail(off + kSizeOff, "member '" + name + "': unreadable size field");
    }
    const std::size_t data_off = off + kBlock;
    if (size > bytes.size() - data_off) {
      throw fail(data_off, "truncated archive: member '" + name + "' declares " +
                               std::to_string(size) + " bytes, " +
                               std::to_string(bytes.size() - data_off) + " present");
    }
    if (!seen.insert(name).second) throw fail(off, "duplicate member '" + name + "'");
    members.push_back({name, bytes.substr(data_off, size)});
    const std::uint64_t padded = (size + kBlock - 1) / kBlock * kBlock;
    if (padded > bytes.size() - data_off) {
      throw fail(bytes.size(), "truncated archive: padding of member '" + name + "' missing");
    }
    off = data_off + padded;
  }
  return members;
}

}  // namespace polmap::mapping
