#pragma once
/// @file store_migrations.hpp
/// The schema files of the store backends (schema/store.sql for SQLite,
/// schema/store_postgres.sql for PostgreSQL) are one bootstrap section run on every open,
/// then numbered migrations, append-only; each backend embeds its file at build time and
/// cuts it into sections with parse_store_migrations.
#include <string_view>
#include <vector>

namespace polmap::mapping {

/// One migration of a store schema (version 0 is the bootstrap).
struct StoreMigration {
  int version;
  std::string_view name;
  std::string_view sql;
};

/// Cuts a schema file's text into its sections at the headers "-- bootstrap ..." and
/// "-- migration N: name" (the views point into `sql`). Throws FormatError, naming `source`,
/// for a missing bootstrap, an empty section, or versions out of order.
[[nodiscard]] std::vector<StoreMigration> parse_store_migrations(
    std::string_view sql, std::string_view source = "schema/store.sql");

}  // namespace polmap::mapping
