// parse_store_migrations (store_migrations.hpp): the section cutter of the store schema
// files, shared by the SQLite and PostgreSQL backends.
#include "polmap/mapping_service/store_migrations.hpp"

#include <algorithm>
#include <charconv>
#include <string>

#include "polmap/schema/errors.hpp"
#include "polmap/util/text.hpp"

namespace polmap::mapping {

std::vector<StoreMigration> parse_store_migrations(std::string_view sql, std::string_view source) {
  const std::string src(source);
  std::vector<StoreMigration> out;
  std::size_t body = std::string_view::npos;
  auto close = [&](std::size_t end) {
    if (out.empty()) return;
    std::string_view s = sql.substr(body, end - body);
    while (!s.empty() && util::is_ascii_space(s.back())) s.remove_suffix(1);
    while (!s.empty() && util::is_ascii_space(s.front())) s.remove_prefix(1);
    if (s.empty()) {
      throw FormatError(src + ": section '" + std::string(out.back().name) + "' is empty");
    }
    out.back().sql = s;
  };
  std::size_t pos = 0;
  while (pos < sql.size()) {
    const std::size_t eol = std::min(sql.find('\n', pos), sql.size());
    const std::string_view line = sql.substr(pos, eol - pos);
    const bool bootstrap = line.starts_with("-- bootstrap");
    const bool migration = line.starts_with("-- migration ");
    if (bootstrap || migration) {
      close(pos);
      StoreMigration m{0, "bootstrap", {}};
      if (migration) {
        const std::string_view rest = line.substr(13);
        const std::size_t colon = rest.find(':');
        int v = 0;
        const auto [p, ec] = std::from_chars(rest.data(), rest.data() + rest.size(), v);
        if (ec != std::errc{} || colon == std::string_view::npos || p != rest.data() + colon) {
          throw FormatError(src + ": malformed section header '" + std::string(line) + "'");
        }
        m.version = v;
        m.name = util::trim(rest.substr(colon + 1));
      }
      const int expected = out.empty() ? 0 : out.back().version + 1;
      if (m.version != expected || (out.empty() != bootstrap)) {
        throw FormatError(src +
                          ": sections must be the bootstrap, then migrations 1, 2, ... in "
                          "order; found '" +
                          std::string(line) + "'");
      }
      out.push_back(m);
      body = eol;
    }
    pos = eol + 1;
  }
  close(sql.size());
  if (out.empty()) throw FormatError(src + ": no bootstrap section");
  return out;
}

}  // namespace polmap::mapping
