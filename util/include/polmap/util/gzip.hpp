#pragma once
/// @file gzip.hpp
/// gzip (RFC 1952) compression of a whole buffer (zlib, level 6): HTTP Content-Encoding and
/// MBTiles vector tiles. Throws polmap::Error if zlib fails (not an input error).
#include <string>
#include <string_view>

namespace polmap::util {

[[nodiscard]] std::string gzip_compress(std::string_view bytes);

}  // namespace polmap::util
