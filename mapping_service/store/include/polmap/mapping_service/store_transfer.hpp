#pragma once
/// @file store_transfer.hpp
/// Copies a whole map store into an EMPTY store of either backend (`polmap migrate`):
/// SQLite -> PostgreSQL, PostgreSQL -> SQLite, or the same backend. Nothing is lost: every
/// row keeps its ids (drive rows, candidate, landmark and tile blob ids, version numbers),
/// JSON and blob columns keep their values (tile payloads byte for byte, so ETags stay),
/// and the package files (and upload session files) are hard-linked or copied into the
/// destination's package directory and checked against their manifest's sha256.
///
///   transfer_store("map.db", "postgresql://polmap@db/polmap", {.package_dir = "/srv/pkg"});
///   const StoreVerifyReport v = verify_store_transfer("map.db", "postgresql://...");
///
/// How (docs/operations.md):
///  - The source is read in one snapshot (a SQLite read transaction; PostgreSQL REPEATABLE
///    READ READ ONLY), so writers may keep running but what they write after the start is
///    not copied. It is opened raw, never migrated: its schema version must equal this
///    build's, or the transfer is refused (ValidationError).
///  - The destination is opened once as a store (that creates its schema and, for
///    PostgreSQL, records its package directory), then written table by table in
///    dependency order inside ONE transaction that holds the store's write lock; geometry is
///    written as each backend writes it (SQLite: the R*Tree side tables; PostgreSQL: the
///    PostGIS columns from the same WKB / envelope). Package files are placed before the
///    commit; any failure rolls the transaction back and removes the files placed, so the
///    destination stays empty (a kill -9 midway leaves only package directories without a
///    row, which the destination's owner sweeps at its next open).
///  - Refused (ValidationError, naming the table or version): a destination with any row
///    (or any row in a `build_job*` table), a source table or column the transfer does not
///    know (a future migration must teach it here rather than be silently dropped), and a
///    source with a map version in status building.
///  - Tables whose name starts with `build_job` are transient (the queue of a running
///    partitioned build): not copied. Since no version may be building, none is running.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

namespace polmap::mapping {

/// Progress of a transfer: a table's rows (or "package files") done of total.
struct StoreTransferProgress {
  std::string table;
  std::int64_t done = 0;
  std::int64_t total = 0;
};

struct StoreTransferOptions {
  /// PostgreSQL destination: its package directory (required when the database has none
  /// recorded yet). Must be empty for a SQLite destination (<db>.drives is used).
  std::filesystem::path package_dir;
  /// Hard-link package files when source and destination share a file system (packages are
  /// immutable, named by content hash); copies otherwise or when false. Upload session
  /// files (still appended to) are always copied.
  bool hard_link_packages = true;
  /// Called after every batch of rows and after each package; may be empty.
  std::function<void(const StoreTransferProgress&)> progress;
  /// Test hook: called with "table:<name>" after each table's rows are written, "files"
  /// after the package files are placed and "commit" just before the commit; throwing
  /// from it simulates a failure at that point. Empty in production.
  std::function<void(std::string_view stage)> fault_hook;
};

/// Rows of one table.
struct StoreTableCount {
  std::string table;
  std::int64_t rows = 0;
};

struct StoreTransferReport {
  int schema_version = 0;                     ///< of source and destination (they are equal)
  std::vector<StoreTableCount> tables;        ///< rows copied per table, in copy order
  std::vector<std::string> transient_tables;  ///< `build_job*` tables of the source, skipped
  std::int64_t packages = 0;                  ///< package directories placed
  std::int64_t package_files = 0;             ///< files in them (manifest.json included)
  std::int64_t package_bytes = 0;
  std::int64_t linked_files = 0;  ///< of package_files, hard links (the rest are copies)
  std::int64_t upload_files = 0;  ///< upload session files copied
};

/// Copies store `from` into the empty store `to` (each a SQLite file path or a PostgreSQL
/// connection string, as open_map_store takes). Throws ValidationError for the refusals
/// above, IoError for database and file failures (naming the table, file or field); the
/// destination is left without rows either way.
StoreTransferReport transfer_store(const std::string& from, const std::string& to,
                                   const StoreTransferOptions& options = {});

/// Rows of one table in both stores.
struct StoreTableComparison {
  std::string table;
  std::int64_t source_rows = 0;
  std::int64_t destination_rows = 0;
};

/// What verify_store_transfer compared; mismatches empty = equal.
struct StoreVerifyReport {
  std::vector<StoreTableComparison> tables;
  std::int64_t tile_blobs_checked = 0;  ///< destination blobs whose ETag was re-hashed
  std::int64_t versions_compared = 0;   ///< published versions whose landmarks were compared
  std::int64_t landmarks_compared = 0;
  std::vector<std::string> mismatches;  ///< one line each, naming table / version / id
  [[nodiscard]] bool ok() const { return mismatches.empty(); }
};

/// Compares two stores after a transfer: row counts per table equal, every destination
/// tile blob's ETag equal to the SHA-256 of its payload, and, per published version, the
/// landmark set (ids, keys, geometry, support) and the tile listings (keys and ETags) equal,
/// read through each backend's region queries (so its geometry index is exercised), as are
/// the drives and candidates in a world-wide box.
StoreVerifyReport verify_store_transfer(const std::string& from, const std::string& to);

}  // namespace polmap::mapping
