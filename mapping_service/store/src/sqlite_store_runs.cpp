// SqliteMapStore: localization run reports (localization_runs) and their quality cells
// (localization_run_cells), store.sql migration 9.
#include "polmap/util/text.hpp"
#include "sqlite_store_impl.hpp"
#include "store_common.hpp"

namespace polmap::mapping {

namespace {

constexpr const char* kRunColumns =
    "id, received_at, vehicle_id, map_version, label, samples, min_lat_deg, min_lon_deg, "
    "max_lat_deg, max_lon_deg, summary_json";

LocalizationRunRecord run_from_row(Stmt& s) {
  LocalizationRunRecord r;
  r.id = s.i64(0);
  r.received_at = s.text(1);
  r.vehicle_id = s.text(2);
  r.map_version = s.i64(3);
  r.label = s.text(4);
  r.samples = s.i64(5);
  r.bounds = GeoBox{s.f64(6), s.f64(7), s.f64(8), s.f64(9)};
  r.summary = nlohmann::json::parse(s.text(10));
  return r;
}

}  // namespace

std::int64_t SqliteMapStore::put_localization_run(const LocalizationRunRecord& record,
                                                  std::string_view canonical_body,
                                                  std::span<const LocalizationRunCell> cells,
                                                  std::size_t keep_newest) {
  check_localization_run(record, cells, keep_newest);
  const std::string received = record.received_at.empty() ? now_iso() : record.received_at;
  return impl_->write([&](Connection& c) {
    c.stmt(
         "INSERT INTO localization_runs(received_at, vehicle_id, map_version, label, samples, "
         "min_lat_deg, min_lon_deg, max_lat_deg, max_lon_deg, summary_json, body) VALUES (?1, "
         "?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)")
        .bind(1, received)
        .bind(2, record.vehicle_id)
        .bind(3, record.map_version)
        .bind(4, record.label)
        .bind(5, record.samples)
        .bind(6, record.bounds.min_lat_deg)
        .bind(7, record.bounds.min_lon_deg)
        .bind(8, record.bounds.max_lat_deg)
        .bind(9, record.bounds.max_lon_deg)
        .bind(10, record.summary.dump())
        .bind_blob(11, canonical_body.empty() ? std::string_view("", 0) : canonical_body)
        .run();
    const std::int64_t id = c.last_id();
    for (const LocalizationRunCell& cell : cells) {
      // A statement per row: the cached statement is reset when it goes out of scope.
      c.stmt(
           "INSERT INTO localization_run_cells(run, z, x, y, samples, degraded, evaluated, "
           "sum_sigma_lat_m, sum_err_lat2_m2, max_abs_err_lat_m) VALUES (?1, ?2, ?3, ?4, ?5, "
           "?6, ?7, ?8, ?9, ?10)")
          .bind(1, id)
          .bind(2, cell.z)
          .bind(3, cell.x)
          .bind(4, cell.y)
          .bind(5, cell.samples)
          .bind(6, cell.degraded)
          .bind(7, cell.evaluated)
          .bind(8, cell.sum_sigma_lat_m)
          .bind(9, cell.sum_err_lat2_m2)
          .bind(10, cell.max_abs_err_lat_m)
          .run();
    }
    // Keep the newest: ids grow, so everything below the keep_newest-th id goes.
    c.stmt(
         "DELETE FROM localization_runs WHERE id <= (SELECT id FROM localization_runs ORDER BY "
         "id DESC LIMIT 1 OFFSET ?1)")
        .bind(1, static_cast<std::int64_t>(keep_newest))
        .run();
    return id;
  });
}

std::vector<LocalizationRunRecord> SqliteMapStore::list_localization_runs(
    std::size_t limit, std::string_view vehicle_id) const {
  return impl_->read([&](Connection& c) {
    std::vector<LocalizationRunRecord> out;
    auto s = c.stmt(std::string("SELECT ") + kRunColumns +
                    " FROM localization_runs WHERE (?1 = '' OR vehicle_id = ?1) ORDER BY id DESC "
                    "LIMIT ?2");
    const std::string vehicle(vehicle_id);  // never a null pointer: '' is not NULL
    s.bind(1, vehicle).bind(2, static_cast<std::int64_t>(std::min<std::size_t>(limit, 1u << 30)));
    while (s.step()) out.push_back(run_from_row(s));
    return out;
  });
}

std::optional<LocalizationRunRecord> SqliteMapStore::get_localization_run(std::int64_t id) const {
  return impl_->read([&](Connection& c) -> std::optional<LocalizationRunRecord> {
    auto s = c.stmt(std::string("SELECT ") + kRunColumns + " FROM localization_runs WHERE id = ?1");
    s.bind(1, id);
    if (!s.step()) return std::nullopt;
    return run_from_row(s);
  });
}

std::optional<std::string> SqliteMapStore::localization_run_body(std::int64_t id) const {
  return impl_->read([&](Connection& c) -> std::optional<std::string> {
    auto s = c.stmt("SELECT body FROM localization_runs WHERE id = ?1");
    s.bind(1, id);
    if (!s.step()) return std::nullopt;
    return s.blob(0);
  });
}

bool SqliteMapStore::delete_localization_run(std::int64_t id) {
  return impl_->write([&](Connection& c) {
    c.stmt("DELETE FROM localization_runs WHERE id = ?1").bind(1, id).run();
    return c.changes() == 1;
  });
}

std::vector<LocalizationRunCell> SqliteMapStore::localization_run_cells(int z, int x0, int y0,
                                                                        int x1, int y1,
                                                                        std::size_t limit,
                                                                        RunCellRuns which) const {
  return impl_->read([&](Connection& c) {
    std::vector<LocalizationRunCell> out;
    auto s = c.stmt(
        "SELECT c.x, c.y, SUM(c.samples), SUM(c.degraded), SUM(c.evaluated), "
        "SUM(c.sum_sigma_lat_m), SUM(c.sum_err_lat2_m2), MAX(c.max_abs_err_lat_m), COUNT(*), "
        "MAX(r.map_version) FROM localization_run_cells c JOIN localization_runs r ON r.id = "
        "c.run WHERE c.z = ?1 AND c.x BETWEEN ?2 AND ?3 AND c.y BETWEEN ?4 AND ?5 AND (?7 = 0 "
        "OR r.map_version = (SELECT MAX(r2.map_version) FROM localization_run_cells c2 JOIN "
        "localization_runs r2 ON r2.id = c2.run WHERE c2.z = c.z AND c2.x = c.x AND c2.y = "
        "c.y)) GROUP BY c.x, c.y ORDER BY c.x, c.y LIMIT ?6");
    s.bind(1, z).bind(2, x0).bind(3, x1).bind(4, y0).bind(5, y1);
    s.bind(6, static_cast<std::int64_t>(std::min<std::size_t>(limit, 1u << 30)));
    s.bind(7, which == RunCellRuns::All ? 0 : 1);
    while (s.step()) {
      LocalizationRunCell cell;
      cell.z = z;
      cell.x = static_cast<int>(s.i64(0));
      cell.y = static_cast<int>(s.i64(1));
      cell.samples = s.i64(2);
      cell.degraded = s.i64(3);
      cell.evaluated = s.i64(4);
      cell.sum_sigma_lat_m = s.f64(5);
      cell.sum_err_lat2_m2 = s.f64(6);
      cell.max_abs_err_lat_m = s.f64(7);
      cell.runs = s.i64(8);  // one row per (run, cell)
      cell.map_version = s.i64(9);
      out.push_back(cell);
    }
    return out;
  });
}

}  // namespace polmap::mapping
