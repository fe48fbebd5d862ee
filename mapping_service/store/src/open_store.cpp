// open_map_store (open_store.hpp): the backend from the form of the --db string.
#include "polmap/mapping_service/open_store.hpp"

#include "polmap/mapping_service/postgres_store.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"

namespace polmap::mapping {

bool is_postgres_conninfo(std::string_view db) {
  return db.starts_with("postgresql://") || db.starts_with("postgres://") ||
         db.starts_with("host=") || db.starts_with("dbname=");
}

std::unique_ptr<MapStore> open_map_store(const std::string& db, const OpenStoreOptions& options) {
  if (is_postgres_conninfo(db)) {
    PostgresStoreOptions o;
    o.conninfo = db;
    o.package_dir = options.package_dir;
    return std::make_unique<PostgresMapStore>(std::move(o));
  }
  if (!options.package_dir.empty()) {
    throw ValidationError("a package directory (" + options.package_dir.string() +
                          ") applies to PostgreSQL stores only: the SQLite store " + db +
                          " keeps its packages in " + db + ".drives");
  }
  if (db.empty()) throw ValidationError("no map store given (--db FILE or a postgresql:// URL)");
  return std::make_unique<SqliteMapStore>(db);
}

}  // namespace polmap::mapping
