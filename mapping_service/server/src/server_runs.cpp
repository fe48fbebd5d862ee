// mapping::Server: localization run reports (schema/localization_run.md). A vehicle posts a
// run summary after localizing against the map; operators list runs, draw one (GeoJSON
// segments coloured by status or error) and the fleet-wide quality cells (where
// localization degraded: the places the map is weak).
//
//   POST   /v1/runs                 vehicle or operator key; body ≤ max_run_report_bytes
//   GET    /v1/runs[?limit=N&vehicle=ID]            viewer or operator key
//   GET    /v1/runs/quality[?bbox=...&runs=newest_map|all] viewer or operator key (GeoJSON)
//   GET    /v1/runs/{id}[?format=json|geojson]      viewer or operator key
//   DELETE /v1/runs/{id}                            operator key
#include "polmap/mapping_service/localization_runs.hpp"
#include "polmap/schema/localization_run.hpp"
#include "server_impl.hpp"

namespace polmap::mapping {

namespace {

constexpr std::size_t kDefaultListLimit = 100;
constexpr std::size_t kMaxListLimit = 1000;
/// Quality cells returned at most (a box of 64 km² at z20, far more than a screen shows).
constexpr std::size_t kMaxQualityCells = 100'000;

std::optional<std::int64_t> run_id(const std::string& s) {
  const auto id = http::parse_int(s);
  if (!id || *id <= 0) return std::nullopt;
  return id;
}

}  // namespace

void Server::Impl::register_run_routes() {
  http.Post("/v1/runs", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("runs_report");
    const auto key = require(req, res, Access::Upload);
    if (!key) return;
    LocalizationRunLimits limits;
    limits.max_bytes = cfg.max_run_report_bytes;
    limits.max_samples = cfg.max_run_samples;
    const auto run = parse_localization_run(req.body, limits);
    if (!run) {
      return reply_error(res, run.error().http_status, run.error().message, run.error().field);
    }
    // The one canonical copy: the validated run, encoded again; what is served later.
    const std::string canonical = encode_localization_run(*run);
    LocalizationRunRecord record = run_record(*run, key->vehicle_id);
    const auto cells = run_cells(*run);
    record.id = store.put_localization_run(record, canonical, cells,
                                           static_cast<std::size_t>(cfg.max_localization_runs));
    record = store.get_localization_run(record.id).value_or(record);
    log("info", "run " + std::to_string(record.id) + " from vehicle '" + record.vehicle_id +
                    "': " + std::to_string(record.samples) + " samples, " +
                    std::to_string(cells.size()) + " cells");
    res.set_header("Location", "/v1/runs/" + std::to_string(record.id));
    reply_json(res, 201, run_record_json(record));
  });

  http.Get("/v1/runs", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("runs_list");
    if (!require(req, res, Access::ReadDrives)) return;
    std::size_t limit = kDefaultListLimit;
    if (req.has_param("limit")) {
      const auto n = http::parse_int(req.get_param_value("limit"));
      if (!n || *n < 1 || *n > static_cast<std::int64_t>(kMaxListLimit)) {
        return reply_error(
            res, 400, "limit must be an integer in 1.." + std::to_string(kMaxListLimit), "limit");
      }
      limit = static_cast<std::size_t>(*n);
    }
    const std::string vehicle = req.get_param_value("vehicle");
    if (vehicle.size() > 256) return reply_error(res, 400, "vehicle is too long", "vehicle");
    nlohmann::json list = nlohmann::json::array();
    for (const auto& r : store.list_localization_runs(limit, vehicle)) {
      list.push_back(run_record_json(r));
    }
    reply_json(res, 200, {{"runs", list}, {"count", list.size()}});
  });

  http.Get("/v1/runs/quality", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("runs_quality");
    if (!require(req, res, Access::ReadDrives)) return;
    const int z = kRunCellZoom;
    const std::int64_t last = tiles::tiles_per_side(z) - 1;
    std::int64_t x0 = 0, y0 = 0, x1 = last, y1 = last;
    if (req.has_param("bbox")) {
      const auto box = http::parse_bbox(req.get_param_value("bbox"));
      if (!box) {
        return reply_error(res, 400, "bbox must be min_lon,min_lat,max_lon,max_lat in degrees",
                           "bbox");
      }
      // Rows grow southwards: the north edge gives the first row.
      const tiles::TileKey nw = tiles::tile_at(box->max_lat_deg, box->min_lon_deg, z);
      const tiles::TileKey se = tiles::tile_at(box->min_lat_deg, box->max_lon_deg, z);
      x0 = nw.x;
      y0 = nw.y;
      x1 = se.x;
      y1 = se.y;
    }
    // By default a cell shows the runs against the newest map version that has runs there:
    // a place a later map fixed is judged by how it localizes now.
    const std::string which = req.has_param("runs") ? req.get_param_value("runs") : "newest_map";
    if (which != "newest_map" && which != "all") {
      return reply_error(res, 400, "runs must be newest_map or all", "runs");
    }
    const auto cells = store.localization_run_cells(
        z, static_cast<int>(x0), static_cast<int>(y0), static_cast<int>(x1), static_cast<int>(y1),
        kMaxQualityCells, which == "all" ? RunCellRuns::All : RunCellRuns::NewestMapVersion);
    nlohmann::json j = run_cells_geojson(cells);
    j["properties"]["truncated"] = cells.size() >= kMaxQualityCells;
    j["properties"]["runs"] = which;
    reply_json(res, 200, j);
  });

  http.Get(R"(/v1/runs/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("runs_get");
    if (!require(req, res, Access::ReadDrives)) return;
    const auto id = run_id(req.matches[1]);
    if (!id) return reply_error(res, 400, "a run id is a positive integer", "run_id");
    const std::string format = req.has_param("format") ? req.get_param_value("format") : "json";
    if (format != "json" && format != "geojson") {
      return reply_error(res, 400, "format must be json or geojson", "format");
    }
    const auto record = store.get_localization_run(*id);
    const auto body = store.localization_run_body(*id);
    if (!record || !body) {
      return reply_error(res, 404, "run " + std::to_string(*id) + " does not exist", "run_id");
    }
    // The stored copy was validated on the way in; parsed again with the same parser.
    const auto run = parse_localization_run(
        *body,
        LocalizationRunLimits{.max_bytes = body->size(), .max_samples = cfg.max_run_samples});
    if (!run)
      throw IoError("stored run " + std::to_string(*id) + " does not parse: " + run.error().what());
    if (format == "geojson") return reply_json(res, 200, run_geojson(*run, *record));
    nlohmann::json j = run_record_json(*record);
    j["report"] = nlohmann::json::parse(*body);
    reply_json(res, 200, j);
  });

  http.Delete(R"(/v1/runs/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("runs_delete");
    if (!require(req, res, Access::Operate)) return;
    const auto id = run_id(req.matches[1]);
    if (!id) return reply_error(res, 400, "a run id is a positive integer", "run_id");
    if (!store.delete_localization_run(*id)) {
      return reply_error(res, 404, "run " + std::to_string(*id) + " does not exist", "run_id");
    }
    log("info", "run " + std::to_string(*id) + " deleted");
    res.status = 204;
  });
}

}  // namespace polmap::mapping
