// candidates.gpkg pre-screen with SQLite itself (see gpkg_screen.hpp): nothing GDAL would
// run or believe (views, triggers, extra tables, metadata rows) reaches GDAL unless it is
// exactly what our own GeoPackage writer produces.
#include "gpkg_screen.hpp"

#include <sqlite3.h>

#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <new>
#include <string>
#include <vector>

#include "candidates_schema.hpp"
#include "package_internal.hpp"

namespace polmap::mapping::detail {

namespace {

constexpr const char* kFile = "candidates.gpkg";
/// Metadata tables of our writer hold a handful of rows; more is not ours.
constexpr std::size_t kMaxMetadataRows = 64;

using Row = std::vector<std::string>;

struct SchemaEntry {
  std::string type;      ///< table, index, trigger, view
  std::string tbl_name;  ///< the table it belongs to
  std::string sql;       ///< CREATE statement as stored (empty for automatic indexes)
};

/// What a GeoPackage looks like to the screen: header values, schema, metadata rows.
struct GpkgShape {
  std::string application_id;
  std::string user_version;
  std::map<std::string, SchemaEntry> schema;         ///< by name
  std::map<std::string, std::vector<Row>> metadata;  ///< by query label
};

/// The metadata queries compared row for row (columns that legitimately differ between
/// packages, such as bounds, timestamps and feature counts, are left out).
constexpr std::pair<const char*, const char*> kMetadataQueries[] = {
    {"gpkg_contents",
     "SELECT table_name, data_type, identifier, description, srs_id FROM gpkg_contents "
     "ORDER BY table_name"},
    {"gpkg_geometry_columns", "SELECT * FROM gpkg_geometry_columns ORDER BY table_name"},
    {"gpkg_extensions",
     "SELECT * FROM gpkg_extensions ORDER BY table_name, column_name, extension_name"},
    {"gpkg_spatial_ref_sys", "SELECT * FROM gpkg_spatial_ref_sys ORDER BY srs_id"},
    {"gpkg_ogr_contents", "SELECT table_name FROM gpkg_ogr_contents ORDER BY table_name"},
    {"gpkg_tile_matrix_set", "SELECT * FROM gpkg_tile_matrix_set"},
    {"gpkg_tile_matrix", "SELECT * FROM gpkg_tile_matrix"},
};

struct DbClose {
  void operator()(sqlite3* db) const { sqlite3_close_v2(db); }
};
struct StmtFinalize {
  void operator()(sqlite3_stmt* s) const { sqlite3_finalize(s); }
};

std::string quoted(const std::string& identifier) {
  std::string q = "\"";
  for (char c : identifier) {
    q += c;
    if (c == '"') q += '"';
  }
  q += '"';
  return q;
}

[[noreturn]] void bad_value(const std::string& field, const std::string& message) {
  throw PackageValidationError(kFile, field, message);
}

std::string shorten(const std::string& s) { return s.size() <= 160 ? s : s.substr(0, 157) + "..."; }

/// A hardened, read-only connection to a private copy of the bytes.
class Screen {
 public:
  Screen(std::string_view bytes, const util::Deadline& deadline) : deadline_(deadline) {
    if (bytes.size() < 100 || std::memcmp(bytes.data(), "SQLite format 3", 16) != 0) {
      throw PackageFormatError(kFile, "", "not a SQLite 3 database (no SQLite header)");
    }
    // File format read/write versions: 1 = rollback journal, 2 = WAL.
    if (bytes[18] != 1 || bytes[19] != 1) {
      throw PackageValidationError(kFile, "journal_mode",
                                   "the database is in WAL mode (a package carries no -wal file; "
                                   "GDAL's writer leaves rollback-journal databases)");
    }
    sqlite3* raw = nullptr;
    const int rc =
        sqlite3_open_v2(":memory:", &raw, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr);
    db_.reset(raw);
    if (rc != SQLITE_OK)
      throw IoError("GeoPackage screen: cannot open an in-memory SQLite database");
    sqlite3_db_config(raw, SQLITE_DBCONFIG_DEFENSIVE, 1, nullptr);
    sqlite3_db_config(raw, SQLITE_DBCONFIG_TRUSTED_SCHEMA, 0, nullptr);
    sqlite3_db_config(raw, SQLITE_DBCONFIG_ENABLE_TRIGGER, 0, nullptr);
    sqlite3_db_config(raw, SQLITE_DBCONFIG_ENABLE_VIEW, 0, nullptr);
    sqlite3_db_config(raw, SQLITE_DBCONFIG_ENABLE_LOAD_EXTENSION, 0, nullptr);
    sqlite3_limit(raw, SQLITE_LIMIT_ATTACHED, 0);
    sqlite3_progress_handler(raw, 1000, &Screen::progress, this);
    auto* buf = static_cast<unsigned char*>(sqlite3_malloc64(bytes.size()));
    if (buf == nullptr) throw std::bad_alloc();
    std::memcpy(buf, bytes.data(), bytes.size());
    // FREEONCLOSE: SQLite owns the copy, also when deserialize fails.
    const auto n = static_cast<sqlite3_int64>(bytes.size());
    if (sqlite3_deserialize(raw, "main", buf, n, n,
                            SQLITE_DESERIALIZE_FREEONCLOSE | SQLITE_DESERIALIZE_READONLY) !=
        SQLITE_OK) {
      throw PackageFormatError(
          kFile, "", std::string("not a readable SQLite database (") + sqlite3_errmsg(raw) + ")");
    }
  }

  /// Runs a query; every value as "<storage class letter>:<text>" so that 1, 1.0 and '1'
  /// differ. At most `max_rows` rows (more is a violation named `label`).
  std::vector<Row> rows(const std::string& sql, const std::string& label,
                        std::size_t max_rows = kMaxMetadataRows) {
    sqlite3_stmt* raw = nullptr;
    const int rc = sqlite3_prepare_v2(db_.get(), sql.c_str(), -1, &raw, nullptr);
    const std::unique_ptr<sqlite3_stmt, StmtFinalize> st(raw);
    if (rc != SQLITE_OK) fail(rc, label);
    std::vector<Row> out;
    int step = 0;
    while ((step = sqlite3_step(raw)) == SQLITE_ROW) {
      if (out.size() == max_rows) {
        throw PackageValidationError(
            kFile, label,
            "more than " + std::to_string(max_rows) + " rows (GDAL's writer leaves a handful)");
      }
      Row r;
      for (int i = 0; i < sqlite3_column_count(raw); ++i) r.push_back(value(raw, i));
      out.push_back(std::move(r));
    }
    if (step != SQLITE_DONE) fail(step, label);
    return out;
  }

  /// Header values, schema and metadata rows.
  GpkgShape shape() {
    GpkgShape s;
    s.application_id = rows("PRAGMA application_id", "application_id").at(0).at(0);
    s.user_version = rows("PRAGMA user_version", "user_version").at(0).at(0);
    // Schemas of ours have ~60 entries; a few hundred bound the memory of a hostile one.
    for (auto& r : rows("SELECT type, name, tbl_name, sql FROM sqlite_schema", "schema", 1000)) {
      auto text = [](const std::string& v) { return v.starts_with("t:") ? v.substr(2) : ""; };
      s.schema[text(r[1])] = {text(r[0]), text(r[2]), text(r[3])};
    }
    return s;
  }

  /// After the schema is known to be ours (so no hostile expression is evaluated).
  void check_integrity() {
    const auto check = rows("PRAGMA integrity_check(1)", "integrity_check");
    if (check.size() != 1 || check[0][0] != "t:ok") {
      throw PackageFormatError(
          kFile, "integrity_check",
          "SQLite's integrity check fails: " + shorten(check.empty() ? "" : check[0][0].substr(2)));
    }
  }

  void read_metadata(GpkgShape& s) {
    for (const auto& [label, sql] : kMetadataQueries) s.metadata[label] = rows(sql, label);
  }

  /// Every value of the feature tables has its column's storage class (or is NULL):
  /// GDAL would read a text in a REAL column as 0 without complaint.
  void check_storage_classes() {
    for (const GpkgLayerSchema* layer : {&kPointsLayer, &kLinesLayer, &kTrajectoryLayer}) {
      check_column(layer->name, "geom", "'blob'");
      for (const auto& f : layer->fields) {
        const char* allowed = f.type == OFTString ? "'text'"
                              : f.type == OFTReal ? "'real', 'integer'"
                                                  : "'integer'";
        check_column(layer->name, f.name, allowed);
      }
    }
  }

 private:
  void check_column(const std::string& table, const std::string& column, const char* allowed) {
    const std::string sql = "SELECT fid, typeof(" + quoted(column) + ") FROM " + quoted(table) +
                            " WHERE typeof(" + quoted(column) + ") NOT IN ('null', " + allowed +
                            ") LIMIT 1";
    const auto bad = rows(sql, table + "." + column, 1);
    if (!bad.empty()) {
      throw PackageValidationError(kFile, table + "." + column,
                                   "feature fid " + bad[0][0].substr(2) + " holds a " +
                                       bad[0][1].substr(2) + " value (expected " + allowed + ")");
    }
  }

  static int progress(void* self) {
    auto* s = static_cast<Screen*>(self);
    if (s->deadline_.expired()) {
      s->timed_out_ = true;
      return 1;
    }
    return 0;
  }

  [[noreturn]] void fail(int rc, const std::string& label) {
    if (timed_out_) budget_exceeded(kFile, deadline_.budget_s());
    const std::string msg = sqlite3_errmsg(db_.get());
    if ((rc & 0xff) == SQLITE_NOMEM) throw std::bad_alloc();
    throw PackageFormatError(kFile, label, "SQLite cannot read it (" + shorten(msg) + ")");
  }

  static std::string value(sqlite3_stmt* st, int i) {
    switch (sqlite3_column_type(st, i)) {
      case SQLITE_INTEGER:
        return "i:" + std::to_string(sqlite3_column_int64(st, i));
      case SQLITE_FLOAT: {
        char buf[40];
        std::snprintf(buf, sizeof buf, "r:%.17g", sqlite3_column_double(st, i));
        return buf;
      }
      case SQLITE_TEXT: {
        const auto* t = reinterpret_cast<const char*>(sqlite3_column_text(st, i));
        std::string v = "t:";
        v.append(t, static_cast<std::size_t>(sqlite3_column_bytes(st, i)));
        return v;
      }
      case SQLITE_BLOB:
        return "b:" + std::to_string(sqlite3_column_bytes(st, i)) + " bytes";
      default:
        return "n:";
    }
  }

  std::unique_ptr<sqlite3, DbClose> db_;
  const util::Deadline& deadline_;
  bool timed_out_ = false;
};

/// The shape GDAL's GeoPackage writer gives our layers, learnt once per process from an
/// empty candidates.gpkg written by our own writer (so the allow-list cannot drift from
/// the writer, nor from the GDAL and SQLite versions the server runs).
const GpkgShape& reference_shape() {
  static const GpkgShape ref = [] {
    const util::ScopedTempDir dir = util::ScopedTempDir::create("polmap_gpkg_reference");
    const std::string path = (dir.path() / kFile).string();
    write_candidates_gpkg(path, tiles::LocalFrame(GeoPoint{}), {}, {}, {});
    const std::string bytes = read_file_bytes(path);
    const util::Deadline never = util::Deadline::never();
    Screen s(bytes, never);
    GpkgShape shape = s.shape();
    s.read_metadata(shape);
    return shape;
  }();
  return ref;
}

void compare_schema(const GpkgShape& got, const GpkgShape& want) {
  for (const GpkgLayerSchema* layer : {&kPointsLayer, &kLinesLayer, &kTrajectoryLayer}) {
    if (!got.schema.contains(layer->name)) {
      bad_value(layer->name, std::string("layer missing (no table '") + layer->name + "')");
    }
  }
  if (got.application_id != want.application_id) {
    bad_value("application_id", "is " + got.application_id.substr(2) + ", GeoPackages have " +
                                    want.application_id.substr(2) + " ('GPKG')");
  }
  if (got.user_version != want.user_version) {
    bad_value("user_version", "is " + got.user_version.substr(2) + ", GDAL's writer gives " +
                                  want.user_version.substr(2));
  }
  for (const auto& [name, e] : got.schema) {
    const auto it = want.schema.find(name);
    if (it == want.schema.end()) {
      bad_value("schema", "unexpected " + e.type + " '" + shorten(name) +
                              "' (only the tables, indexes and triggers GDAL's GeoPackage writer "
                              "creates for the points, lines and trajectory layers are allowed)");
    }
    if (e.type != it->second.type || e.tbl_name != it->second.tbl_name || e.sql != it->second.sql) {
      bad_value("schema", e.type + " '" + name +
                              "' differs from what GDAL's writer creates: " + shorten(e.sql));
    }
  }
  for (const auto& [name, e] : want.schema) {
    if (!got.schema.contains(name)) bad_value("schema", e.type + " '" + name + "' missing");
  }
}

}  // namespace

void screen_candidates_gpkg(std::string_view bytes, const util::Deadline& deadline) {
  const GpkgShape& want = reference_shape();
  Screen screen(bytes, deadline);
  GpkgShape got = screen.shape();
  compare_schema(got, want);
  screen.check_integrity();
  screen.read_metadata(got);
  for (const auto& [label, sql] : kMetadataQueries) {
    (void)sql;
    if (got.metadata[label] != want.metadata.at(label)) {
      bad_value(label, "rows differ from what GDAL's writer records for our three layers");
    }
  }
  screen.check_storage_classes();
}

}  // namespace polmap::mapping::detail
