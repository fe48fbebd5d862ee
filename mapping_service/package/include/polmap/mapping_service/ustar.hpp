#pragma once
/// @file ustar.hpp
/// A small, deterministic POSIX ustar (IEEE Std 1003.1-1988 "ustar") writer and a
/// strict reader, for drive packages on the wire. Regular files only, flat names.
///
/// Determinism: members are written in the given order with mode 0644, uid/gid 0,
/// empty user/group names, mtime 0 and no extended headers, so the same member list
/// always gives the same bytes. The archive ends with two zero blocks (no padding to a
/// 10240-byte record; GNU tar, bsdtar and GDAL /vsitar/ read it).
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace polmap::mapping {

/// One archive member: a regular file.
struct TarMember {
  std::string name;  ///< flat file name, 1..100 bytes, no '/', not "." or ".."
  std::string data;
};

/// A member of a parsed archive, viewing the archive's bytes (valid while they are).
struct TarMemberView {
  std::string name;
  std::string_view data;
};

/// The 512-byte header write_ustar emits for a member (for streaming writers/hashers:
/// an archive is, per member, header + data + zero padding to 512, then 1024 zero bytes).
[[nodiscard]] std::string ustar_header(const std::string& name, std::uint64_t size);
/// Zero bytes that pad `size` bytes of member data to a 512-byte boundary.
[[nodiscard]] inline std::size_t ustar_padding(std::uint64_t size) {
  return static_cast<std::size_t>((512 - size % 512) % 512);
}
/// Bytes of the end-of-archive marker (two zero blocks).
inline constexpr std::size_t kUstarEndBytes = 1024;

/// Writes the members into one ustar archive. Throws ContractViolation on an invalid name.
[[nodiscard]] std::string write_ustar(const std::vector<TarMember>& members);

/// Parses an archive written by write_ustar (or any ustar/GNU tar of flat regular files).
/// Throws FormatError naming `source` and the byte offset on: truncation, a header
/// checksum mismatch, a non-ustar header, a member type other than a regular file,
/// a name with a directory part, duplicate names, or a missing end-of-archive marker.
[[nodiscard]] std::vector<TarMember> read_ustar(std::string_view bytes,
                                                const std::string& source = "archive");
/// Same checks as read_ustar, without copying member data.
[[nodiscard]] std::vector<TarMemberView> read_ustar_views(std::string_view bytes,
                                                          const std::string& source = "archive");

}  // namespace polmap::mapping
