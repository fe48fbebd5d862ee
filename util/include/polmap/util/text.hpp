#pragma once
/// @file text.hpp
/// Text helpers shared by every parser of ours (key files, HTTP headers, CSV).
#include <string>
#include <string_view>
#include <vector>

namespace polmap::util {

/// True for the ASCII whitespace characters " \t\n\v\f\r" (C locale isspace, without
/// locale lookups).
[[nodiscard]] constexpr bool is_ascii_space(char c) {
  return c == ' ' || c == '\t' || c == '\n' || c == '\v' || c == '\f' || c == '\r';
}

/// `s` without leading and trailing ASCII whitespace.
[[nodiscard]] std::string_view trim(std::string_view s);

/// Splits at every `sep`, trimming each field; "" gives one empty field, "a," two.
[[nodiscard]] std::vector<std::string_view> split_trimmed(std::string_view s, char sep);

/// `s` made safe for a one-line log: printable ASCII kept, backslash and every other byte
/// (control characters, CR/LF, non-ASCII) as \xHH; cut at max_bytes with "...".
[[nodiscard]] std::string escape_for_log(std::string_view s, std::size_t max_bytes = 4096);

/// True if `s` is non-empty and consists of lower-case hex digits only.
[[nodiscard]] bool is_lower_hex(std::string_view s);

}  // namespace polmap::util
