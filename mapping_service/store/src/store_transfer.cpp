// transfer_store / verify_store_transfer (store_transfer.hpp): a raw, table-by-table copy
// between the two backends. Raw rather than through MapStore because the interface assigns
// ids itself and has no call that writes a published version, a drive row or a tile blob
// as it is; the geometry is written with the same helpers the backends' own writes use.
#include "polmap/mapping_service/store_transfer.hpp"

#include <algorithm>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "pg_db.hpp"
#include "polmap/mapping_service/open_store.hpp"
#include "polmap/mapping_service/postgres_store.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/sha256.hpp"
#include "sqlite_db.hpp"

namespace polmap::mapping {

// The backends' own geometry writers (their internal headers cannot share one translation
// unit: each brings its backend's names into this namespace), declared as defined in
// sqlite_store.cpp and postgres_store.cpp.
namespace sqlite_store_detail {
void insert_rtree(sqlite::Connection& c, const char* table, std::int64_t id, double min_lat,
                  double max_lat, double min_lon, double max_lon);
}  // namespace sqlite_store_detail
namespace pg_store_detail {
std::string wkb_point(double lat_deg, double lon_deg);
std::string wkb_line(const std::vector<GeoPoint>& vertices);
}  // namespace pg_store_detail

namespace {
// The PostgreSQL store's write lock (postgres_store_impl.hpp: kLockClass, kWriteLock).
constexpr int kPgLockClass = 0x706d6170;  // "pmap"
constexpr int kPgWriteLock = 1;
namespace fs = std::filesystem;

// ------------------------------------------------------------------ what is copied

enum class Col { Int, Real, Text, Json, Blob };
struct ColumnSpec {
  const char* name;
  Col type;
};
/// Geometry derived from a row's columns: SQLite's R*Tree row, PostgreSQL's geometry column.
enum class Geometry { None, DriveBox, Candidate, Landmark };
struct TableSpec {
  const char* name;
  std::vector<ColumnSpec> columns;
  std::vector<const char*> key;  ///< primary key (the copy's order and its pagination)
  Geometry geometry = Geometry::None;
};

constexpr Col I = Col::Int, R = Col::Real, T = Col::Text, J = Col::Json, B = Col::Blob;

std::vector<ColumnSpec> tile_columns() {
  return {{"version", I}, {"z", I},          {"x", I},        {"y", I},
          {"blob", I},    {"num_points", I}, {"num_lines", I}};
}

/// Every table of store.sql migration 10 / store_postgres.sql migration 4, parents first.
/// A new table or column in a later migration must be added here (the transfer refuses a
/// source with one it does not know).
const std::vector<TableSpec>& table_specs() {
  static const std::vector<TableSpec> specs = {
      {"drives",
       {{"id", I},
        {"drive_id", T},
        {"content_hash", T},
        {"vehicle_id", T},
        {"start_time_s", R},
        {"end_time_s", R},
        {"min_lat_deg", R},
        {"min_lon_deg", R},
        {"max_lat_deg", R},
        {"max_lon_deg", R},
        {"pol_level", T},
        {"distance_m", R},
        {"num_points", I},
        {"num_lines", I},
        {"manifest_json", J},
        {"package_path", T},
        {"package_bytes", I},
        {"ingested_at", T}},
       {"id"},
       Geometry::DriveBox},
      {"drive_trajectories",
       {{"drive", I}, {"min_spacing_m", R}, {"samples_json", J}, {"path_blob", B}},
       {"drive"}},
      {"candidates",
       {{"id", I},
        {"drive", I},
        {"kind", I},
        {"lat_deg", R},
        {"lon_deg", R},
        {"x_m", R},
        {"y_m", R},
        {"end_lat_deg", R},
        {"end_lon_deg", R},
        {"end_x_m", R},
        {"end_y_m", R},
        {"strength", R},
        {"power_db", R},
        {"scattering", I},
        {"num_cells", I}},
       {"id"},
       Geometry::Candidate},
      {"map_versions",
       {{"version", I},
        {"status", T},
        {"created_at", T},
        {"published_at", T},
        {"parameters_json", J},
        {"statistics_json", J},
        {"error", T}},
       {"version"}},
      {"current_map", {{"id", I}, {"version", I}}, {"id"}},
      {"landmarks",
       {{"id", I},
        {"version", I},
        {"key", I},
        {"kind", I},
        {"lat_deg", R},
        {"lon_deg", R},
        {"polyline_json", J},
        {"scattering", I},
        {"support_drives", I},
        {"spread_m", R},
        {"support_of", I}},
       {"id"},
       Geometry::Landmark},
      {"landmark_support", {{"landmark", I}, {"candidate", I}}, {"landmark", "candidate"}},
      {"landmark_changes",
       {{"version", I},
        {"seq", I},
        {"change", T},
        {"kind", I},
        {"key", I},
        {"previous_key", I},
        {"distance_m", R},
        {"geometry_json", J},
        {"previous_geometry_json", J},
        {"reason_json", J}},
       {"version", "seq"}},
      {"hdmap_comparisons",
       {{"version", I},
        {"name", T},
        {"hdmap_file", T},
        {"created_at", T},
        {"summary_json", J},
        {"features_json", J}},
       {"version", "name"}},
      {"tile_blobs", {{"id", I}, {"etag", T}, {"payload", B}, {"byte_size", I}}, {"id"}},
      {"tiles", tile_columns(), {"version", "z", "x", "y"}},
      {"gridmap_tiles", tile_columns(), {"version", "z", "x", "y"}},
      {"gridmap_mechanism_tiles", tile_columns(), {"version", "z", "x", "y"}},
      {"upload_sessions",
       {{"id", T},
        {"owner", T},
        {"length_bytes", I},
        {"offset_bytes", I},
        {"sha256", T},
        {"created_at", T},
        {"expires_at", T},
        {"file_path", T},
        {"outcome_status", I},
        {"outcome_location", T},
        {"outcome_body", T}},
       {"id"}},
      {"gridmap_sum_inputs",
       {{"content_hash", T}, {"tiles", I}, {"added_at", T}, {"placement", T}},
       {"content_hash"}},
      {"gridmap_sum_cover",
       {{"content_hash", T}, {"level", I}, {"x", I}, {"y", I}},
       {"content_hash", "level", "x", "y"}},
      {"gridmap_sums",
       {{"level", I}, {"x", I}, {"y", I}, {"data", B}, {"updated_by", I}},
       {"level", "x", "y"}},
      {"localization_runs",
       {{"id", I},
        {"received_at", T},
        {"vehicle_id", T},
        {"map_version", I},
        {"label", T},
        {"samples", I},
        {"min_lat_deg", R},
        {"min_lon_deg", R},
        {"max_lat_deg", R},
        {"max_lon_deg", R},
        {"summary_json", J},
        {"body", B}},
       {"id"}},
      {"localization_run_cells",
       {{"run", I},
        {"z", I},
        {"x", I},
        {"y", I},
        {"samples", I},
        {"degraded", I},
        {"evaluated", I},
        {"sum_sigma_lat_m", R},
        {"sum_err_lat2_m2", R},
        {"max_abs_err_lat_m", R}},
       {"run", "z", "x", "y"}},
  };
  return specs;
}

bool is_transient(std::string_view table) { return table.starts_with("build_job"); }

/// Tables of a backend that are not store content: bookkeeping, index side tables.
bool is_backend_table(bool postgres, std::string_view t) {
  if (t == "schema_migrations") return true;
  if (postgres) return t == "store_settings";  // the destination records its own package_dir
  if (t.starts_with("sqlite_")) return true;
  for (const char* suffix : {"_rtree", "_rtree_node", "_rtree_parent", "_rtree_rowid"}) {
    if (t.ends_with(suffix)) return true;
  }
  return false;
}

/// Columns PostgreSQL derives from the others (written from them here as well).
bool is_derived_column(bool postgres, std::string_view table, std::string_view column) {
  if (!postgres) return false;
  return (table == "drives" && column == "bbox") ||
         ((table == "candidates" || table == "landmarks") && column == "geom");
}

struct Value {
  bool null = true;
  std::int64_t i = 0;
  double d = 0.0;
  std::string s;  ///< text, JSON or blob bytes
};
using Row = std::vector<Value>;

int column_index(const TableSpec& t, std::string_view name) {
  for (std::size_t k = 0; k < t.columns.size(); ++k) {
    if (name == t.columns[k].name) return static_cast<int>(k);
  }
  throw ContractViolation(std::string("store_transfer: no column ") + std::string(name));
}

std::string column_list(const TableSpec& t) {
  std::string out;
  for (const auto& c : t.columns) out += (out.empty() ? "" : ", ") + std::string(c.name);
  return out;
}

std::string key_list(const TableSpec& t) {
  std::string out;
  for (const char* k : t.key) out += (out.empty() ? "" : ", ") + std::string(k);
  return out;
}

/// The drive row's box, or the candidate's / landmark's vertices (lat, lon).
std::vector<GeoPoint> row_vertices(const TableSpec& t, const Row& r) {
  auto at = [&](const char* c) { return r[static_cast<std::size_t>(column_index(t, c))]; };
  if (t.geometry == Geometry::Candidate) {
    std::vector<GeoPoint> v{{at("lat_deg").d, at("lon_deg").d, 0.0}};
    if (at("kind").i == 1) v.push_back({at("end_lat_deg").d, at("end_lon_deg").d, 0.0});
    return v;
  }
  if (t.geometry == Geometry::Landmark) {
    if (at("kind").i == 0) return {{at("lat_deg").d, at("lon_deg").d, 0.0}};
    const auto pl = nlohmann::json::parse(at("polyline_json").s, nullptr, false);
    std::vector<GeoPoint> v;
    if (pl.is_array()) {
      for (const auto& p : pl) {
        if (p.is_array() && p.size() == 2 && p[0].is_number() && p[1].is_number()) {
          v.push_back({p[0].get<double>(), p[1].get<double>(), 0.0});
        }
      }
    }
    if (v.size() < 2) {
      throw FormatError("table landmarks, id " + std::to_string(at("id").i) +
                        ": field polyline_json is not a polyline of >= 2 [lat, lon] vertices");
    }
    return v;
  }
  return {{at("min_lat_deg").d, at("min_lon_deg").d, 0.0},
          {at("max_lat_deg").d, at("max_lon_deg").d, 0.0}};
}

/// Rethrows the current exception with the table named, keeping its class.
[[noreturn]] void rethrow_in(const std::string& where) {
  try {
    throw;
  } catch (const ConflictError& e) {
    throw ConflictError(where + ": " + e.what());
  } catch (const ValidationError& e) {
    throw ValidationError(where + ": " + e.what());
  } catch (const StorageFullError& e) {
    throw StorageFullError(where + ": " + e.what());
  } catch (const FormatError& e) {
    throw FormatError(where + ": " + e.what());
  } catch (const std::exception& e) {
    throw IoError(where + ": " + e.what());
  }
}

// ------------------------------------------------------------------ reading a store

/// A store opened raw for reading, in one snapshot (begun by the constructor).
class RawReader {
 public:
  virtual ~RawReader() = default;
  [[nodiscard]] virtual bool postgres() const = 0;
  [[nodiscard]] virtual std::vector<std::string> tables() = 0;
  [[nodiscard]] virtual std::vector<std::string> columns(const std::string& table) = 0;
  [[nodiscard]] virtual std::int64_t count(const std::string& table) = 0;
  [[nodiscard]] virtual int schema_version() = 0;
  /// Rows of a spec table in key order, batch by batch.
  virtual void scan(const TableSpec& t, const std::function<void(std::vector<Row>&)>& fn) = 0;
  [[nodiscard]] virtual fs::path package_dir() = 0;
  [[nodiscard]] virtual fs::path uploads_dir() = 0;
  [[nodiscard]] virtual std::string name() const = 0;

  /// The map versions in status building.
  std::vector<std::int64_t> building_versions() {
    std::vector<std::int64_t> out;
    TableSpec t{"map_versions", {{"version", I}, {"status", T}}, {"version"}};
    scan(t, [&](std::vector<Row>& rows) {
      for (const auto& r : rows) {
        if (r[1].s == "building") out.push_back(r[0].i);
      }
    });
    return out;
  }
};

class SqliteReader final : public RawReader {
 public:
  explicit SqliteReader(const fs::path& path) : path_(path) {
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) {
      throw IoError("SQLite store " + path.string() + ": no such file");
    }
    c_ = std::make_unique<sqlite::Connection>(path, 10000);
    c_->exec("BEGIN");
    // The snapshot starts at the first read; take it now.
    (void)schema_version();
  }
  ~SqliteReader() override {
    try {
      c_->exec("ROLLBACK");
    } catch (...) {  // nothing to roll back
    }
  }
  [[nodiscard]] bool postgres() const override { return false; }
  std::vector<std::string> tables() override {
    std::vector<std::string> out;
    auto s = c_->stmt("SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name");
    while (s.step()) out.push_back(s.text(0));
    return out;
  }
  std::vector<std::string> columns(const std::string& table) override {
    std::vector<std::string> out;
    auto s = c_->stmt("SELECT name FROM pragma_table_info(?1)");
    s.bind(1, table);
    while (s.step()) out.push_back(s.text(0));
    return out;
  }
  std::int64_t count(const std::string& table) override {
    auto s = c_->stmt("SELECT COUNT(*) FROM \"" + table + "\"");
    s.step();
    return s.i64(0);
  }
  int schema_version() override {
    auto s = c_->stmt(
        "SELECT COUNT(*) FROM sqlite_master WHERE type = 'table' AND name = 'schema_migrations'");
    s.step();
    if (s.i64(0) == 0) {
      throw ValidationError(path_.string() + " is not a polmap store (no table schema_migrations)");
    }
    auto v = c_->stmt("SELECT COALESCE(MAX(version), 0) FROM schema_migrations");
    v.step();
    return static_cast<int>(v.i64(0));
  }
  void scan(const TableSpec& t, const std::function<void(std::vector<Row>&)>& fn) override {
    // One statement streams the whole table: SQLite reads it in-process, page by page.
    auto s = c_->stmt("SELECT " + column_list(t) + " FROM " + t.name + " ORDER BY " + key_list(t));
    std::vector<Row> batch;
    std::size_t bytes = 0;
    while (s.step()) {
      Row r(t.columns.size());
      for (std::size_t k = 0; k < t.columns.size(); ++k) {
        const int c = static_cast<int>(k);
        Value& v = r[k];
        v.null = s.is_null(c);
        if (v.null) continue;
        switch (t.columns[k].type) {
          case Col::Int:
            v.i = s.i64(c);
            break;
          case Col::Real:
            v.d = s.f64(c);
            break;
          case Col::Text:
          case Col::Json:
            v.s = s.text(c);
            break;
          case Col::Blob:
            v.s = s.blob(c);
            break;
        }
        bytes += v.s.size();
      }
      batch.push_back(std::move(r));
      if (batch.size() >= 2000 || bytes > (16u << 20)) {
        fn(batch);
        batch.clear();
        bytes = 0;
      }
    }
    if (!batch.empty()) fn(batch);
  }
  fs::path package_dir() override { return fs::path(path_.string() + ".drives"); }
  fs::path uploads_dir() override { return fs::path(path_.string() + ".uploads"); }
  [[nodiscard]] std::string name() const override { return path_.string(); }

 private:
  fs::path path_;
  std::unique_ptr<sqlite::Connection> c_;
};

void add_value(pg::Params& p, Col type, const Value& v) {
  if (v.null) {
    const Oid oid = type == Col::Int    ? pg::kInt8Oid
                    : type == Col::Real ? pg::kFloat8Oid
                    : type == Col::Blob ? pg::kByteaOid
                                        : pg::kTextOid;
    p.add(pg::Null{oid});
    return;
  }
  switch (type) {
    case Col::Int:
      p.add(v.i);
      break;
    case Col::Real:
      p.add(v.d);
      break;
    case Col::Text:
    case Col::Json:
      p.add(std::string_view(v.s));
      break;
    case Col::Blob:
      p.add(pg::Bytea{v.s});
      break;
  }
}

class PostgresReader final : public RawReader {
 public:
  explicit PostgresReader(const std::string& conninfo)
      : description_(pg::describe_conninfo(conninfo)),
        c_(std::make_unique<pg::Connection>(conninfo, description_)) {
    c_->exec("BEGIN ISOLATION LEVEL REPEATABLE READ READ ONLY");
    (void)schema_version();  // takes the snapshot
  }
  ~PostgresReader() override {
    try {
      c_->exec("ROLLBACK");
    } catch (...) {  // a broken connection rolls back by itself
    }
  }
  [[nodiscard]] bool postgres() const override { return true; }
  std::vector<std::string> tables() override {
    // Tables of the store's schema, without those of extensions (PostGIS' spatial_ref_sys).
    const pg::Result r = c_->run(
        "SELECT c.relname::text FROM pg_class c JOIN pg_namespace n ON n.oid = c.relnamespace "
        "WHERE n.nspname = current_schema() AND c.relkind IN ('r', 'p') AND NOT EXISTS (SELECT 1 "
        "FROM pg_depend d WHERE d.classid = 'pg_class'::regclass AND d.objid = c.oid AND "
        "d.deptype = 'e') ORDER BY 1");
    std::vector<std::string> out;
    for (int i = 0; i < r.rows(); ++i) out.push_back(r.text(i, 0));
    return out;
  }
  std::vector<std::string> columns(const std::string& table) override {
    const pg::Result r = c_->run(
        "SELECT column_name::text FROM information_schema.columns WHERE table_schema = "
        "current_schema() AND table_name = $1",
        table);
    std::vector<std::string> out;
    for (int i = 0; i < r.rows(); ++i) out.push_back(r.text(i, 0));
    return out;
  }
  std::int64_t count(const std::string& table) override {
    return c_->run("SELECT COUNT(*) FROM \"" + table + "\"").i64(0, 0);
  }
  int schema_version() override {
    if (c_->run("SELECT to_regclass('schema_migrations') IS NOT NULL").i64(0, 0) == 0) {
      throw ValidationError(description_ + " is not a polmap store (no table schema_migrations)");
    }
    return static_cast<int>(
        c_->run("SELECT COALESCE(MAX(version), 0)::bigint FROM schema_migrations").i64(0, 0));
  }
  void scan(const TableSpec& t, const std::function<void(std::vector<Row>&)>& fn) override {
    // Keyset pagination in the snapshot: each batch is one query, memory stays bounded.
    const bool big =
        std::string_view(t.name) == "tile_blobs" || std::string_view(t.name) == "gridmap_sums";
    const int limit = big ? 256 : 5000;
    const std::string base = "SELECT " + column_list(t) + " FROM " + t.name;
    const std::string order = " ORDER BY " + key_list(t) + " LIMIT " + std::to_string(limit);
    std::string after = " WHERE (" + key_list(t) + ") > (";
    for (std::size_t k = 0; k < t.key.size(); ++k) {
      after += (k ? ", $" : "$") + std::to_string(k + 1);
    }
    after += ")";
    std::optional<Row> last;
    while (true) {
      pg::Params p;
      if (last) {
        for (const char* k : t.key) {
          const int c = column_index(t, k);
          add_value(p, t.columns[static_cast<std::size_t>(c)].type,
                    (*last)[static_cast<std::size_t>(c)]);
        }
      }
      const pg::Result r = c_->query(base + (last ? after : "") + order, p);
      std::vector<Row> batch;
      for (int i = 0; i < r.rows(); ++i) {
        Row row(t.columns.size());
        for (std::size_t k = 0; k < t.columns.size(); ++k) {
          const int c = static_cast<int>(k);
          Value& v = row[k];
          v.null = r.is_null(i, c);
          if (v.null) continue;
          switch (t.columns[k].type) {
            case Col::Int:
              v.i = r.i64(i, c);
              break;
            case Col::Real:
              v.d = r.f64(i, c);
              break;
            case Col::Text:
            case Col::Json:
              v.s = r.text(i, c);
              break;
            case Col::Blob:
              v.s = r.bytes(i, c);
              break;
          }
        }
        batch.push_back(std::move(row));
      }
      if (batch.empty()) return;
      last = batch.back();
      fn(batch);
      if (static_cast<int>(r.rows()) < limit) return;
    }
  }
  fs::path package_dir() override {
    const pg::Result r = c_->run("SELECT value FROM store_settings WHERE key = 'package_dir'");
    if (r.empty()) throw ValidationError(description_ + ": no package_dir in store_settings");
    return r.text(0, 0);
  }
  fs::path uploads_dir() override { return package_dir() / "uploads"; }
  [[nodiscard]] std::string name() const override { return description_; }

 private:
  std::string description_;
  std::unique_ptr<pg::Connection> c_;
};

std::unique_ptr<RawReader> open_reader(const std::string& db) {
  if (is_postgres_conninfo(db)) return std::make_unique<PostgresReader>(db);
  return std::make_unique<SqliteReader>(db);
}

int build_schema_version(bool postgres) {
  const auto& m = postgres ? postgres_store_migrations() : sqlite_store_migrations();
  return m.empty() ? 0 : m.back().version;
}

/// Refuses tables and columns this transfer does not know; returns the transient tables.
std::vector<std::string> check_known_schema(RawReader& src) {
  std::set<std::string> known;
  for (const auto& t : table_specs()) known.insert(t.name);
  std::vector<std::string> transient;
  for (const auto& t : src.tables()) {
    if (is_transient(t)) {
      transient.push_back(t);
      continue;
    }
    if (is_backend_table(src.postgres(), t)) continue;
    if (!known.contains(t)) {
      throw ValidationError("source " + src.name() + " has table '" + t +
                            "', which the store transfer does not know: it would be lost "
                            "(teach store_transfer.cpp's table_specs() about it)");
    }
  }
  for (const auto& t : table_specs()) {
    const auto cols = src.columns(t.name);
    if (cols.empty()) {
      throw ValidationError("source " + src.name() + " has no table '" + std::string(t.name) + "'");
    }
    std::set<std::string> want;
    for (const auto& c : t.columns) want.insert(c.name);
    for (const auto& c : cols) {
      if (!want.erase(c) && !is_derived_column(src.postgres(), t.name, c)) {
        throw ValidationError("source " + src.name() + ": column '" + std::string(t.name) + "." +
                              c + "' is unknown to the store transfer: it would be lost");
      }
    }
    if (!want.empty()) {
      throw ValidationError("source " + src.name() + ": table '" + std::string(t.name) +
                            "' has no column '" + *want.begin() + "'");
    }
  }
  return transient;
}

// ------------------------------------------------------------------ writing a store

class RawWriter {
 public:
  virtual ~RawWriter() = default;
  /// Rows of a table of the destination (in its transaction).
  virtual std::int64_t count(const std::string& table) = 0;
  virtual std::vector<std::string> tables() = 0;
  virtual int schema_version() = 0;
  virtual void insert(const TableSpec& t, const std::vector<Row>& rows) = 0;
  /// After all tables: whatever the backend derives from the rows (sequences).
  virtual void finish() = 0;
  virtual void commit() = 0;
};

class SqliteWriter final : public RawWriter {
 public:
  explicit SqliteWriter(const fs::path& path) : c_(path, 10000) {
    c_.exec("BEGIN IMMEDIATE");  // the store's write lock, held until commit
  }
  ~SqliteWriter() override {
    if (done_) return;
    try {
      c_.exec("ROLLBACK");
    } catch (...) {  // nothing to roll back
    }
  }
  std::int64_t count(const std::string& table) override {
    auto s = c_.stmt("SELECT COUNT(*) FROM \"" + table + "\"");
    s.step();
    return s.i64(0);
  }
  std::vector<std::string> tables() override {
    std::vector<std::string> out;
    auto s = c_.stmt("SELECT name FROM sqlite_master WHERE type = 'table'");
    while (s.step()) out.push_back(s.text(0));
    return out;
  }
  int schema_version() override {
    auto s = c_.stmt("SELECT COALESCE(MAX(version), 0) FROM schema_migrations");
    s.step();
    return static_cast<int>(s.i64(0));
  }
  void insert(const TableSpec& t, const std::vector<Row>& rows) override {
    std::string sql = "INSERT INTO " + std::string(t.name) + "(" + column_list(t) + ") VALUES (";
    for (std::size_t k = 0; k < t.columns.size(); ++k) {
      sql += (k ? ", ?" : "?") + std::to_string(k + 1);
    }
    sql += ")";
    const char* rtree = t.geometry == Geometry::DriveBox    ? "drives_rtree"
                        : t.geometry == Geometry::Candidate ? "candidates_rtree"
                        : t.geometry == Geometry::Landmark  ? "landmarks_rtree"
                                                            : nullptr;
    for (const Row& r : rows) {
      auto s = c_.stmt(sql);
      for (std::size_t k = 0; k < t.columns.size(); ++k) {
        const int i = static_cast<int>(k + 1);
        const Value& v = r[k];
        if (v.null) {
          s.bind_null(i);
          continue;
        }
        switch (t.columns[k].type) {
          case Col::Int:
            s.bind(i, v.i);
            break;
          case Col::Real:
            s.bind(i, v.d);
            break;
          case Col::Text:
          case Col::Json:
            s.bind(i, std::string_view(v.s));
            break;
          case Col::Blob:
            s.bind_blob(i, v.s);
            break;
        }
      }
      s.run();
      if (rtree != nullptr) {
        // The backend's R*Tree row: the box of the row's vertices (rounded outward by SQLite).
        const auto v = row_vertices(t, r);
        double lat0 = 90, lat1 = -90, lon0 = 180, lon1 = -180;
        for (const auto& g : v) {
          lat0 = std::min(lat0, g.lat_deg);
          lat1 = std::max(lat1, g.lat_deg);
          lon0 = std::min(lon0, g.lon_deg);
          lon1 = std::max(lon1, g.lon_deg);
        }
        sqlite_store_detail::insert_rtree(c_, rtree, r[0].i, lat0, lat1, lon0, lon1);
      }
    }
  }
  void finish() override {}
  void commit() override {
    c_.exec("COMMIT");
    done_ = true;
  }

 private:
  sqlite::Connection c_;
  bool done_ = false;
};

class PostgresWriter final : public RawWriter {
 public:
  explicit PostgresWriter(const std::string& conninfo)
      : c_(conninfo, pg::describe_conninfo(conninfo)) {
    c_.exec("BEGIN");
    // The store's write lock: no replica writes until this transaction ends.
    c_.run("SELECT pg_advisory_xact_lock($1, $2)", kPgLockClass, kPgWriteLock);
  }
  ~PostgresWriter() override {
    if (done_) return;
    try {
      c_.exec("ROLLBACK");
    } catch (...) {  // a broken connection: the server rolls back
    }
  }
  std::int64_t count(const std::string& table) override {
    return c_.run("SELECT COUNT(*) FROM \"" + table + "\"").i64(0, 0);
  }
  std::vector<std::string> tables() override {
    const pg::Result r = c_.run(
        "SELECT c.relname::text FROM pg_class c JOIN pg_namespace n ON n.oid = c.relnamespace "
        "WHERE n.nspname = current_schema() AND c.relkind IN ('r', 'p')");
    std::vector<std::string> out;
    for (int i = 0; i < r.rows(); ++i) out.push_back(r.text(i, 0));
    return out;
  }
  int schema_version() override {
    return static_cast<int>(
        c_.run("SELECT COALESCE(MAX(version), 0)::bigint FROM schema_migrations").i64(0, 0));
  }
  void insert(const TableSpec& t, const std::vector<Row>& rows) override {
    // Multi-row INSERTs: one round trip per batch instead of per row.
    const std::size_t per_row = t.columns.size() + (t.geometry == Geometry::None ? 0 : 1);
    const std::size_t max_rows =
        std::max<std::size_t>(1, std::min<std::size_t>(500, 30000 / per_row));
    for (std::size_t first = 0; first < rows.size();) {
      std::size_t n = 0, bytes = 0;
      while (first + n < rows.size() && n < max_rows && bytes < (16u << 20)) {
        for (const auto& v : rows[first + n]) bytes += v.s.size();
        ++n;
      }
      std::string sql = "INSERT INTO " + std::string(t.name) + "(" + column_list(t) +
                        (t.geometry == Geometry::DriveBox ? ", bbox"
                         : t.geometry == Geometry::None   ? ""
                                                          : ", geom") +
                        ") VALUES ";
      pg::Params p;
      int arg = 0;
      for (std::size_t j = 0; j < n; ++j) {
        const Row& r = rows[first + j];
        const int row_first = arg + 1;
        sql += j ? ", (" : "(";
        for (std::size_t k = 0; k < t.columns.size(); ++k) {
          add_value(p, t.columns[k].type, r[k]);
          sql += (k ? ", $" : "$") + std::to_string(++arg);
          if (t.columns[k].type == Col::Json) sql += "::jsonb";
        }
        if (t.geometry == Geometry::DriveBox) {
          // As put_drive writes it: the envelope of the row's own min/max columns.
          auto col = [&](const char* c) {
            return "$" + std::to_string(row_first + column_index(t, c));
          };
          sql += ", ST_MakeEnvelope(" + col("min_lon_deg") + ", " + col("min_lat_deg") + ", " +
                 col("max_lon_deg") + ", " + col("max_lat_deg") + ", 4326)";
        } else if (t.geometry != Geometry::None) {
          const auto v = row_vertices(t, r);
          const bool point = r[static_cast<std::size_t>(column_index(t, "kind"))].i == 0;
          p.add(pg::Bytea{point ? pg_store_detail::wkb_point(v[0].lat_deg, v[0].lon_deg)
                                : pg_store_detail::wkb_line(v)});
          sql += ", ST_GeomFromWKB($" + std::to_string(++arg) + ", 4326)";
        }
        sql += ")";
      }
      c_.query(sql, p);
      first += n;
    }
  }
  void finish() override {
    // tile_blobs.id is an identity column: its sequence must continue after the copied ids.
    c_.run(
        "SELECT setval(pg_get_serial_sequence('tile_blobs', 'id'), COALESCE(MAX(id), 0) + 1, "
        "false) FROM tile_blobs");
  }
  void commit() override {
    const std::string status = c_.exec("COMMIT");
    done_ = true;
    if (status != "COMMIT") throw IoError("postgresql: the transfer's transaction was rolled back");
    try {
      c_.exec("ANALYZE");              // planner statistics for the freshly filled tables
    } catch (const std::exception&) {  // only statistics: the data is committed
    }
  }

 private:
  pg::Connection c_;
  bool done_ = false;
};

/// The destination opened as a store: creates its schema (and records a PostgreSQL
/// package directory); kept open during the transfer, so it is the store's owner and no
/// other opener sweeps the package directories placed before the commit.
struct Destination {
  std::unique_ptr<MapStore> store;
  fs::path package_dir;
  fs::path uploads_dir;
  bool postgres = false;
};

Destination open_destination(const std::string& to, const StoreTransferOptions& o) {
  Destination d;
  d.postgres = is_postgres_conninfo(to);
  if (d.postgres) {
    PostgresStoreOptions p;
    p.conninfo = to;
    p.package_dir = o.package_dir;
    auto s = std::make_unique<PostgresMapStore>(std::move(p));
    d.package_dir = s->package_dir();
    d.uploads_dir = s->upload_session_dir();
    d.store = std::move(s);
  } else {
    if (!o.package_dir.empty()) {
      throw ValidationError(
          "--package-dir is for a PostgreSQL destination; a SQLite store keeps "
          "its packages in " +
          to + ".drives");
    }
    auto s = std::make_unique<SqliteMapStore>(to);
    d.package_dir = s->drive_store_dir();
    d.uploads_dir = s->upload_session_dir();
    d.store = std::move(s);
  }
  return d;
}

std::string file_sha256(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw IoError("cannot read " + file.string());
  util::Sha256 h;
  std::string buf(1 << 20, '\0');
  while (in) {
    in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    h.update(std::string_view(buf.data(), static_cast<std::size_t>(in.gcount())));
  }
  return h.hex();
}

/// Places one package directory (hard links or copies) and checks every file its
/// manifest.json lists against the listed size and sha256.
void place_package(const fs::path& from, const fs::path& to, const std::string& drive_id, bool link,
                   StoreTransferReport& report, std::vector<fs::path>& placed) {
  std::error_code ec;
  if (!fs::is_directory(from, ec)) {
    throw IoError("drive '" + drive_id + "': package directory " + from.string() + " is missing");
  }
  if (fs::exists(to, ec)) {
    throw ValidationError("destination package directory " + to.string() +
                          " already exists (the destination store is not empty)");
  }
  fs::create_directories(to.parent_path());
  fs::create_directory(to);
  placed.push_back(to);
  for (const auto& e : fs::directory_iterator(from)) {
    if (!e.is_regular_file()) continue;
    const fs::path dst = to / e.path().filename();
    bool linked = false;
    if (link) {
      fs::create_hard_link(e.path(), dst, ec);
      linked = !ec;
    }
    if (!linked) fs::copy_file(e.path(), dst);
    ++report.package_files;
    report.package_bytes += static_cast<std::int64_t>(fs::file_size(dst));
    if (linked) ++report.linked_files;
  }
  const fs::path manifest = to / kManifestFileName;
  if (!fs::is_regular_file(manifest, ec)) {
    throw IoError("drive '" + drive_id + "': no manifest.json in " + from.string());
  }
  const auto m = nlohmann::json::parse(util::read_file_bytes(manifest), nullptr, false);
  if (!m.is_object() || !m.contains("files") || !m["files"].is_array()) {
    throw FormatError("drive '" + drive_id + "': " + manifest.string() + ": field 'files' missing");
  }
  for (const auto& f : m["files"]) {
    const std::string name = f.value("name", "");
    const std::string want = f.value("sha256", "");
    const fs::path file = to / name;
    if (name.empty() || name.find('/') != std::string::npos || !fs::is_regular_file(file, ec)) {
      throw IoError("drive '" + drive_id + "': file '" + name + "' of its manifest is missing in " +
                    from.string());
    }
    const std::string got = file_sha256(file);
    if (got != want) {
      throw IoError("drive '" + drive_id + "': " + file.string() + " has sha256 " + got +
                    ", its manifest says " + want);
    }
  }
  util::sync_tree(to);
}

}  // namespace

StoreTransferReport transfer_store(const std::string& from, const std::string& to,
                                   const StoreTransferOptions& o) {
  StoreTransferReport report;
  auto src = open_reader(from);
  const int want_version = build_schema_version(src->postgres());
  const int src_version = src->schema_version();
  if (src_version != want_version) {
    throw ValidationError("source " + src->name() + " has schema version " +
                          std::to_string(src_version) + ", this build's is " +
                          std::to_string(want_version) +
                          ": open it once with a polmap of this version (e.g. polmap drives "
                          "--db) to migrate it, or use the polmap it was written by");
  }
  report.schema_version = src_version;
  report.transient_tables = check_known_schema(*src);
  if (const auto building = src->building_versions(); !building.empty()) {
    throw ValidationError("source " + src->name() + ": map version " +
                          std::to_string(building.front()) +
                          " is building: wait until the build ends (an abandoned build is "
                          "failed by the next open of its server) and migrate then");
  }
  const fs::path src_packages = src->package_dir();
  const fs::path src_uploads = src->uploads_dir();

  Destination dst = open_destination(to, o);
  std::unique_ptr<RawWriter> w;
  if (dst.postgres) {
    w = std::make_unique<PostgresWriter>(to);
  } else {
    w = std::make_unique<SqliteWriter>(to);
  }
  const int dst_version = w->schema_version();
  if (dst_version != build_schema_version(dst.postgres)) {
    throw ValidationError("destination " + to + " has schema version " +
                          std::to_string(dst_version) + ", this build's is " +
                          std::to_string(build_schema_version(dst.postgres)));
  }
  for (const auto& t : w->tables()) {
    const bool content = is_transient(t) || std::any_of(table_specs().begin(), table_specs().end(),
                                                        [&](const auto& s) { return t == s.name; });
    if (!content) continue;
    if (const auto n = w->count(t); n > 0) {
      throw ValidationError("destination " + (dst.postgres ? std::string("database") : to) +
                            " is not empty: table '" + t + "' has " + std::to_string(n) +
                            " row(s); migrate into a new, empty store");
    }
  }

  std::vector<fs::path> placed;  // removed again unless the transaction commits
  struct Package {
    std::string drive_id, rel;
  };
  std::vector<Package> packages;
  std::vector<std::string> upload_files;
  bool committed = false;
  try {
    for (const TableSpec& t : table_specs()) {
      const std::int64_t total = src->count(t.name);
      std::int64_t done = 0;
      try {
        src->scan(t, [&](std::vector<Row>& rows) {
          if (std::string_view(t.name) == "drives") {
            const int id = column_index(t, "drive_id"), rel = column_index(t, "package_path");
            for (const auto& r : rows) packages.push_back({r[id].s, r[rel].s});
          } else if (std::string_view(t.name) == "upload_sessions") {
            const int f = column_index(t, "file_path"), st = column_index(t, "outcome_status");
            for (const auto& r : rows) {
              if (r[st].i == 0) upload_files.push_back(r[f].s);  // a completed one has none
            }
          }
          w->insert(t, rows);
          done += static_cast<std::int64_t>(rows.size());
          if (o.progress) o.progress({t.name, done, total});
        });
      } catch (...) {
        rethrow_in("table " + std::string(t.name));
      }
      if (done != total) {
        throw IoError("table " + std::string(t.name) + ": copied " + std::to_string(done) + " of " +
                      std::to_string(total) + " rows");
      }
      if (o.progress && total == 0) o.progress({t.name, 0, 0});
      report.tables.push_back({t.name, done});
      if (o.fault_hook) o.fault_hook("table:" + std::string(t.name));
    }
    w->finish();

    std::int64_t n = 0;
    for (const auto& p : packages) {
      const fs::path rel(p.rel);
      if (rel.empty() || rel.is_absolute() || p.rel.find("..") != std::string::npos) {
        throw ValidationError("table drives, drive '" + p.drive_id + "': field package_path '" +
                              p.rel + "' is not a relative package directory");
      }
      place_package(src_packages / rel, dst.package_dir / rel, p.drive_id, o.hard_link_packages,
                    report, placed);
      ++report.packages;
      if (o.progress)
        o.progress({"package files", ++n, static_cast<std::int64_t>(packages.size())});
    }
    for (const auto& f : upload_files) {
      const fs::path src_file = src_uploads / f;
      const fs::path dst_file = dst.uploads_dir / f;
      std::error_code ec;
      if (fs::exists(dst_file, ec)) {
        throw ValidationError("destination upload session file " + dst_file.string() +
                              " already exists");
      }
      fs::create_directories(dst.uploads_dir);
      placed.push_back(dst_file);
      // A copy, never a link: the session's bytes are still appended to.
      if (!fs::copy_file(src_file, dst_file, ec) || ec) {
        throw IoError("table upload_sessions: cannot copy session file " + src_file.string() +
                      " to " + dst_file.string() + ": " + ec.message());
      }
      util::sync_file(dst_file);
      ++report.upload_files;
    }
    if (!placed.empty()) {
      util::sync_directory(dst.package_dir);
      if (report.upload_files > 0) util::sync_directory(dst.uploads_dir);
    }
    if (o.fault_hook) o.fault_hook("files");
    if (o.fault_hook) o.fault_hook("commit");
    w->commit();
    committed = true;
  } catch (...) {
    if (!committed) {
      w.reset();  // rolls back before the files go
      for (auto it = placed.rbegin(); it != placed.rend(); ++it) {
        std::error_code ec;
        fs::remove_all(*it, ec);
      }
    }
    throw;
  }
  return report;
}

// ------------------------------------------------------------------ verification

namespace {

std::string point_text(const GeoPoint& g) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "(%.9f, %.9f)", g.lat_deg, g.lon_deg);
  return buf;
}

}  // namespace

StoreVerifyReport verify_store_transfer(const std::string& from, const std::string& to) {
  StoreVerifyReport out;
  {
    auto a = open_reader(from);
    auto b = open_reader(to);
    for (const auto& t : table_specs()) {
      const std::int64_t na = a->count(t.name), nb = b->count(t.name);
      out.tables.push_back({t.name, na, nb});
      if (na != nb) {
        out.mismatches.push_back("table " + std::string(t.name) + ": " + std::to_string(na) +
                                 " rows in the source, " + std::to_string(nb) +
                                 " in the destination");
      }
    }
    TableSpec blobs{"tile_blobs", {{"id", I}, {"etag", T}, {"payload", B}}, {"id"}};
    b->scan(blobs, [&](std::vector<Row>& rows) {
      for (const auto& r : rows) {
        ++out.tile_blobs_checked;
        if (content_etag(r[2].s) != r[1].s) {
          out.mismatches.push_back("table tile_blobs, id " + std::to_string(r[0].i) + ": ETag " +
                                   r[1].s + " is not the SHA-256 of its payload");
        }
      }
    });
  }
  const auto sa = open_map_store(from);
  const auto sb = open_map_store(to);
  const GeoBox world{-90.0, -180.0, 90.0, 180.0};
  auto mismatch = [&](std::string s) { out.mismatches.push_back(std::move(s)); };

  const auto da = sa->drives_in(world), db = sb->drives_in(world);
  if (da.size() != db.size()) {
    mismatch("drives in a world-wide box: " + std::to_string(da.size()) + " vs " +
             std::to_string(db.size()));
  }
  for (std::size_t i = 0; i < std::min(da.size(), db.size()); ++i) {
    if (da[i].row != db[i].row || da[i].drive_id != db[i].drive_id ||
        da[i].content_hash != db[i].content_hash || da[i].manifest != db[i].manifest) {
      mismatch("drive row " + std::to_string(da[i].row) + " ('" + da[i].drive_id + "') differs");
    }
  }
  const auto ca = sa->candidates_in(world), cb = sb->candidates_in(world);
  if (ca.points.size() != cb.points.size() || ca.lines.size() != cb.lines.size()) {
    mismatch("candidates in a world-wide box differ in number");
  } else {
    for (std::size_t i = 0; i < ca.points.size(); ++i) {
      if (ca.points[i].id != cb.points[i].id ||
          ca.points[i].position.lat_deg != cb.points[i].position.lat_deg ||
          ca.points[i].position.lon_deg != cb.points[i].position.lon_deg) {
        mismatch("point candidate " + std::to_string(ca.points[i].id) + " differs");
      }
    }
    for (std::size_t i = 0; i < ca.lines.size(); ++i) {
      if (ca.lines[i].id != cb.lines[i].id) {
        mismatch("line candidate " + std::to_string(ca.lines[i].id) + " differs");
      }
    }
  }
  if (sa->current_map_version() != sb->current_map_version())
    mismatch("current map version differs");
  for (const auto& v : sa->list_map_versions()) {
    if (v.status != MapVersionStatus::Published) continue;
    ++out.versions_compared;
    const std::string vs = "version " + std::to_string(v.version);
    const auto w = sb->get_map_version(v.version);
    if (!w || w->status != v.status || w->parameters != v.parameters ||
        w->statistics != v.statistics || w->published_at != v.published_at) {
      mismatch(vs + ": status, parameters, statistics or published_at differ");
      continue;
    }
    const LandmarkSet la = sa->landmarks_in(v.version, world, true);
    const LandmarkSet lb = sb->landmarks_in(v.version, world, true);
    out.landmarks_compared += static_cast<std::int64_t>(la.points.size() + la.lines.size());
    if (la.points.size() != lb.points.size() || la.lines.size() != lb.lines.size()) {
      mismatch(vs + ": " + std::to_string(la.points.size()) + "+" +
               std::to_string(la.lines.size()) + " landmarks in the source, " +
               std::to_string(lb.points.size()) + "+" + std::to_string(lb.lines.size()) +
               " in the destination");
    } else {
      for (std::size_t i = 0; i < la.points.size(); ++i) {
        const auto &p = la.points[i], &q = lb.points[i];
        if (p.id != q.id || p.key != q.key || p.position.lat_deg != q.position.lat_deg ||
            p.position.lon_deg != q.position.lon_deg || p.support != q.support ||
            p.support_drives != q.support_drives || p.spread_m != q.spread_m ||
            p.scattering != q.scattering) {
          mismatch(vs + ": point landmark id " + std::to_string(p.id) + " at " +
                   point_text(p.position) + " differs");
        }
      }
      for (std::size_t i = 0; i < la.lines.size(); ++i) {
        const auto &p = la.lines[i], &q = lb.lines[i];
        bool same = p.id == q.id && p.key == q.key && p.support == q.support &&
                    p.polyline.size() == q.polyline.size();
        for (std::size_t k = 0; same && k < p.polyline.size(); ++k) {
          same = p.polyline[k].lat_deg == q.polyline[k].lat_deg &&
                 p.polyline[k].lon_deg == q.polyline[k].lon_deg;
        }
        if (!same) mismatch(vs + ": line landmark id " + std::to_string(p.id) + " differs");
      }
    }
    for (const TileLayer layer :
         {TileLayer::Localization, TileLayer::Gridmap, TileLayer::GridmapMechanism}) {
      const auto ta = sa->list_tiles(v.version, layer), tb = sb->list_tiles(v.version, layer);
      bool same = ta.size() == tb.size();
      for (std::size_t i = 0; same && i < ta.size(); ++i) {
        same = ta[i].key == tb[i].key && ta[i].etag == tb[i].etag;
      }
      if (!same)
        mismatch(vs + ": tile listing (layer " + std::to_string(static_cast<int>(layer)) +
                 ") differs");
    }
  }
  return out;
}

}  // namespace polmap::mapping
