#pragma once
// Internal: line and field helpers shared by the CSV readers of polmap_eval.
#include <charconv>
#include <optional>
#include <string_view>
#include <system_error>
#include <vector>

#include "polmap/util/text.hpp"

namespace polmap::eval::detail {

/// The comma-separated fields of a line, each trimmed of ASCII whitespace.
inline std::vector<std::string_view> split_commas(std::string_view line) {
  return util::split_trimmed(line, ',');
}

/// True for an empty or all-whitespace line and for a '#' comment line.
inline bool blank_or_comment(std::string_view line) {
  const std::string_view t = util::trim(line);
  return t.empty() || t.front() == '#';
}

/// `s` as a double if all of it is one number (std::from_chars), else nothing. "inf" and
/// "nan" parse: callers that need a finite value check it.
inline std::optional<double> parse_double(std::string_view s) {
  double v = 0.0;
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (s.empty() || ec != std::errc{} || p != s.data() + s.size()) return std::nullopt;
  return v;
}

}  // namespace polmap::eval::detail
