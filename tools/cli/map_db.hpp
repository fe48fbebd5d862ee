#pragma once
/// @file map_db.hpp
/// The `--db FILE|URL` / `--version V` arguments of the commands that read a map store: a
/// SQLite file, or a PostgreSQL database (postgresql://..., open_store.hpp).
#include <cstdint>
#include <filesystem>
#include <string>

#include "polmap/mapping_service/open_store.hpp"
#include "polmap/mapping_service/store.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::cli {

/// Throws IoError unless the --db file exists (opening a SQLite store would create an empty
/// one). A PostgreSQL connection string is not checked here: opening it tells.
inline void require_map_db(const std::string& db) {
  if (mapping::is_postgres_conninfo(db)) return;
  if (!std::filesystem::is_regular_file(db)) {
    throw IoError("--db " + db + ": no such map database");
  }
}

/// The --version argument, or the store's current published version where it is 0
/// (NotFoundError naming the --db file when there is none).
inline std::int64_t map_version_or_current(const mapping::MapStore& store, const std::string& db,
                                           std::int64_t version) {
  if (version != 0) return version;
  const auto current = store.current_map_version();
  if (!current) throw NotFoundError(db + ": no published map version (run build-map first)");
  return *current;
}

}  // namespace polmap::cli
