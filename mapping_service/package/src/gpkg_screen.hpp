#pragma once
// The GeoPackage pre-screen of package validation: candidates.gpkg is checked with
// SQLite itself, on a hardened connection, before GDAL may open it. Not installed.
#include <string_view>

#include "polmap/util/deadline.hpp"

namespace polmap::mapping::detail {

/// Screens the bytes of a candidates.gpkg before GDAL opens them:
///  - a SQLite 3 database in rollback-journal mode (a WAL file would need side files a
///    package cannot carry), application_id 'GPKG', the user_version GDAL writes;
///  - `PRAGMA integrity_check` is "ok";
///  - its schema equals, statement for statement, the schema GDAL's GeoPackage writer
///    creates for our three layers (tables, indexes, R-tree and feature-count triggers;
///    learnt once per process by writing an empty candidates.gpkg) — so no views, no
///    other tables or triggers, no altered columns;
///  - the GeoPackage metadata tables hold exactly the writer's rows (feature counts in
///    gpkg_ogr_contents excepted: features are counted by reading them);
///  - every value of the feature tables has its column's storage class (or is NULL).
/// The connection is opened on a private in-memory copy, read-only, with SQLite's
/// defensive mode on, `trusted_schema` off, triggers, views and extension loading
/// disabled, and a progress handler that stops at `deadline`.
/// Throws PackageFormatError (not a usable SQLite database), PackageValidationError (422:
/// schema or rows not ours; 413: the deadline passed).
void screen_candidates_gpkg(std::string_view bytes, const util::Deadline& deadline);

}  // namespace polmap::mapping::detail
