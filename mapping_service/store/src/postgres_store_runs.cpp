// PostgresMapStore: localization run reports (localization_runs) and their quality cells
// (localization_run_cells), store_postgres.sql migration 3.
#include "postgres_store_impl.hpp"
#include "store_common.hpp"

namespace polmap::mapping {

namespace {

constexpr const char* kRunColumns =
    "id, received_at, vehicle_id, map_version, label, samples, min_lat_deg, min_lon_deg, "
    "max_lat_deg, max_lon_deg, summary_json::text";

LocalizationRunRecord run_from_row(const Result& s, int i) {
  LocalizationRunRecord r;
  r.id = s.i64(i, 0);
  r.received_at = s.text(i, 1);
  r.vehicle_id = s.text(i, 2);
  r.map_version = s.i64(i, 3);
  r.label = s.text(i, 4);
  r.samples = s.i64(i, 5);
  r.bounds = GeoBox{s.f64(i, 6), s.f64(i, 7), s.f64(i, 8), s.f64(i, 9)};
  r.summary = nlohmann::json::parse(s.text(i, 10));
  return r;
}

}  // namespace

std::int64_t PostgresMapStore::put_localization_run(const LocalizationRunRecord& record,
                                                    std::string_view canonical_body,
                                                    std::span<const LocalizationRunCell> cells,
                                                    std::size_t keep_newest) {
  check_localization_run(record, cells, keep_newest);
  const std::string received = record.received_at.empty() ? now_iso() : record.received_at;
  return impl_->write([&](Connection& c) {
    const std::int64_t id = Impl::next_id(c, "localization_runs", "id");
    c.run(
        "INSERT INTO localization_runs(id, received_at, vehicle_id, map_version, label, samples, "
        "min_lat_deg, min_lon_deg, max_lat_deg, max_lon_deg, summary_json, body) VALUES ($1, "
        "$2, $3, $4, $5, $6, $7, $8, $9, $10, $11::jsonb, $12)",
        id, received, record.vehicle_id, record.map_version, record.label, record.samples,
        record.bounds.min_lat_deg, record.bounds.min_lon_deg, record.bounds.max_lat_deg,
        record.bounds.max_lon_deg, record.summary.dump(), pg::Bytea{canonical_body});
    for (const LocalizationRunCell& cell : cells) {
      c.run(
          "INSERT INTO localization_run_cells(run, z, x, y, samples, degraded, evaluated, "
          "sum_sigma_lat_m, sum_err_lat2_m2, max_abs_err_lat_m) VALUES ($1, $2, $3, $4, $5, $6, "
          "$7, $8, $9, $10)",
          id, cell.z, cell.x, cell.y, cell.samples, cell.degraded, cell.evaluated,
          cell.sum_sigma_lat_m, cell.sum_err_lat2_m2, cell.max_abs_err_lat_m);
    }
    // Keep the newest: ids grow, so everything up to the keep_newest-th id from the top goes.
    c.run(
        "DELETE FROM localization_runs WHERE id <= (SELECT id FROM localization_runs ORDER BY "
        "id DESC LIMIT 1 OFFSET $1)",
        static_cast<std::int64_t>(keep_newest));
    return id;
  });
}

std::vector<LocalizationRunRecord> PostgresMapStore::list_localization_runs(
    std::size_t limit, std::string_view vehicle_id) const {
  return impl_->read([&](Connection& c) {
    std::vector<LocalizationRunRecord> out;
    const Result r =
        c.run(std::string("SELECT ") + kRunColumns +
                  " FROM localization_runs WHERE ($1 = '' OR vehicle_id = $1) "
                  "ORDER BY id DESC LIMIT $2",
              vehicle_id, static_cast<std::int64_t>(std::min<std::size_t>(limit, 1u << 30)));
    for (int i = 0; i < r.rows(); ++i) out.push_back(run_from_row(r, i));
    return out;
  });
}

std::optional<LocalizationRunRecord> PostgresMapStore::get_localization_run(std::int64_t id) const {
  return impl_->read([&](Connection& c) -> std::optional<LocalizationRunRecord> {
    const Result r =
        c.run(std::string("SELECT ") + kRunColumns + " FROM localization_runs WHERE id = $1", id);
    if (r.empty()) return std::nullopt;
    return run_from_row(r, 0);
  });
}

std::optional<std::string> PostgresMapStore::localization_run_body(std::int64_t id) const {
  return impl_->read([&](Connection& c) -> std::optional<std::string> {
    const Result r = c.run("SELECT body FROM localization_runs WHERE id = $1", id);
    if (r.empty()) return std::nullopt;
    return r.bytes(0, 0);
  });
}

bool PostgresMapStore::delete_localization_run(std::int64_t id) {
  return impl_->write([&](Connection& c) {
    return c.run("DELETE FROM localization_runs WHERE id = $1", id).affected() == 1;
  });
}

std::vector<LocalizationRunCell> PostgresMapStore::localization_run_cells(int z, int x0, int y0,
                                                                          int x1, int y1,
                                                                          std::size_t limit,
                                                                          RunCellRuns which) const {
  return impl_->read([&](Connection& c) {
    std::vector<LocalizationRunCell> out;
    const Result r = c.run(
        "SELECT c.x, c.y, SUM(c.samples)::bigint, SUM(c.degraded)::bigint, "
        "SUM(c.evaluated)::bigint, SUM(c.sum_sigma_lat_m), SUM(c.sum_err_lat2_m2), "
        "MAX(c.max_abs_err_lat_m), COUNT(*), MAX(r.map_version) FROM localization_run_cells c "
        "JOIN localization_runs r ON r.id = c.run WHERE c.z = $1 AND c.x BETWEEN $2 AND $3 AND "
        "c.y BETWEEN $4 AND $5 AND ($7 = 0 OR r.map_version = (SELECT MAX(r2.map_version) FROM "
        "localization_run_cells c2 JOIN localization_runs r2 ON r2.id = c2.run WHERE c2.z = c.z "
        "AND c2.x = c.x AND c2.y = c.y)) GROUP BY c.x, c.y ORDER BY c.x, c.y LIMIT $6",
        z, x0, x1, y0, y1, static_cast<std::int64_t>(std::min<std::size_t>(limit, 1u << 30)),
        which == RunCellRuns::All ? 0 : 1);
    for (int i = 0; i < r.rows(); ++i) {
      LocalizationRunCell cell;
      cell.z = z;
      cell.x = static_cast<int>(r.i64(i, 0));
      cell.y = static_cast<int>(r.i64(i, 1));
      cell.samples = r.i64(i, 2);
      cell.degraded = r.i64(i, 3);
      cell.evaluated = r.i64(i, 4);
      cell.sum_sigma_lat_m = r.f64(i, 5);
      cell.sum_err_lat2_m2 = r.f64(i, 6);
      cell.max_abs_err_lat_m = r.f64(i, 7);
      cell.runs = r.i64(i, 8);  // one row per (run, cell)
      cell.map_version = r.i64(i, 9);
      out.push_back(cell);
    }
    return out;
  });
}

}  // namespace polmap::mapping
