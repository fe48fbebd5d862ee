#pragma once
/// @file open_store.hpp
/// One way for programs to open the store named by a `--db` argument: a PostgreSQL
/// connection string opens PostgresMapStore (postgres_store.hpp), anything else is the path
/// of a SQLite database file (SqliteMapStore, sqlite_store.hpp; the default).
///
///   auto store = open_map_store("/var/lib/polmap/map.db");
///   auto store = open_map_store("postgresql://polmap@db:5432/polmap", {.package_dir =
///   "/srv/pkg"});
#include <filesystem>
#include <memory>
#include <string>
#include <string_view>

#include "polmap/mapping_service/store.hpp"

namespace polmap::mapping {

struct OpenStoreOptions {
  /// PostgreSQL only: the shared package directory (required when the database is opened
  /// for the first time, see PostgresStoreOptions). A SQLite store keeps its packages beside
  /// its file (<db>.drives): naming a directory for it is a ValidationError.
  std::filesystem::path package_dir;
};

/// True if `db` is a PostgreSQL connection string: a "postgresql://" or "postgres://" URL,
/// or libpq key=value pairs starting with "host=" or "dbname=".
[[nodiscard]] bool is_postgres_conninfo(std::string_view db);

/// Opens (creating if needed) the store `db` names. Throws as the backend's constructor
/// (IoError, ValidationError).
[[nodiscard]] std::unique_ptr<MapStore> open_map_store(const std::string& db,
                                                       const OpenStoreOptions& options = {});

}  // namespace polmap::mapping
