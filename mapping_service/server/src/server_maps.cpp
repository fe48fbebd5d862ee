// Map version endpoints: POST /v1/maps (build in the background), GET /v1/maps[/{version}],
// GET /v1/maps/{version}/diff?from=U (landmark changes between two versions).
#include <algorithm>
#include <cmath>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <map>

#include "polmap/mapping_service/landmark_diff.hpp"
#include "polmap/schema/errors.hpp"
#include "server_build.hpp"
#include "server_impl.hpp"

namespace polmap::mapping {
namespace {

// Parses and checks the POST /v1/maps body. Throws JsonRequestError naming the field.
struct JsonRequestError {
  std::string field;
  std::string message;
};

std::optional<tiles::GeoBox> parse_region(const nlohmann::json& r) {
  if (r.is_null()) return std::nullopt;
  tiles::GeoBox b;
  if (r.is_array()) {
    if (r.size() != 4 ||
        !std::all_of(r.begin(), r.end(), [](const auto& v) { return v.is_number(); })) {
      throw JsonRequestError{"region", "must be [min_lon, min_lat, max_lon, max_lat] (degrees)"};
    }
    b = {r[1].get<double>(), r[0].get<double>(), r[3].get<double>(), r[2].get<double>()};
  } else if (r.is_object()) {
    for (const char* k : {"min_lat_deg", "min_lon_deg", "max_lat_deg", "max_lon_deg"}) {
      if (!r.contains(k) || !r[k].is_number()) {
        throw JsonRequestError{std::string("region.") + k, "required number (degrees)"};
      }
    }
    b = {r["min_lat_deg"].get<double>(), r["min_lon_deg"].get<double>(),
         r["max_lat_deg"].get<double>(), r["max_lon_deg"].get<double>()};
  } else {
    throw JsonRequestError{"region", "must be an object or a 4-element array"};
  }
  const bool ok = std::isfinite(b.min_lat_deg) && std::isfinite(b.max_lat_deg) &&
                  std::isfinite(b.min_lon_deg) && std::isfinite(b.max_lon_deg) &&
                  b.min_lat_deg >= -90 && b.max_lat_deg <= 90 && b.min_lat_deg < b.max_lat_deg &&
                  b.min_lon_deg >= -180 && b.max_lon_deg <= 180 && b.min_lon_deg < b.max_lon_deg;
  if (!ok) {
    throw JsonRequestError{
        "region",
        "needs -90 <= min_lat < max_lat <= 90 and -180 <= min_lon < max_lon <= 180 "
        "(antimeridian-crossing regions: build two maps)"};
  }
  return b;
}

nlohmann::json geo_json_array(const std::vector<GeoPoint>& g) {
  nlohmann::json a = nlohmann::json::array();
  for (const auto& p : g) a.push_back({{"lat_deg", p.lat_deg}, {"lon_deg", p.lon_deg}});
  return a;
}

nlohmann::json geojson_geometry(const std::vector<GeoPoint>& g, bool is_line) {
  nlohmann::json coords = nlohmann::json::array();
  for (const auto& p : g) coords.push_back({p.lon_deg, p.lat_deg});
  if (!is_line && !g.empty()) return {{"type", "Point"}, {"coordinates", coords[0]}};
  return {{"type", "LineString"}, {"coordinates", coords}};
}

/// One change as JSON (keys as decimal strings: they are 63-bit and JavaScript numbers
/// hold 53).
nlohmann::json change_json(const LandmarkChange& c, std::optional<std::int64_t> reason_version) {
  nlohmann::json j{
      {"change", std::string(to_string(c.change))},
      {"kind", c.is_line ? "line" : "point"},
      {"key", std::to_string(c.key)},
      {"geometry", geo_json_array(c.geometry)},
      {"reason", c.reason},
      {"reason_version", reason_version ? nlohmann::json(*reason_version) : nlohmann::json()}};
  if (c.change == LandmarkChangeKind::Moved) {
    j["previous_key"] = std::to_string(c.previous_key);
    j["previous_geometry"] = geo_json_array(c.previous_geometry);
    j["distance_m"] = c.distance_m;
  }
  return j;
}

}  // namespace

std::int64_t Server::Impl::submit_build(const nlohmann::json& request) {
  const std::int64_t version = begin_build(store, request);
  {
    std::lock_guard lock(build_mutex);
    build_queue.push_back({version, request});
  }
  build_cv.notify_all();
  return version;
}

void Server::Impl::build_loop() {
  auto last_retention = std::chrono::steady_clock::now();
  auto last_abandoned_check = std::chrono::steady_clock::now();
  const auto abandoned_every = std::chrono::duration<double>(cfg.abandoned_build_check_s);
  for (;;) {
    BuildJob job;
    {
      std::unique_lock lock(build_mutex);
      // Wakes every 10 minutes without work, for the retention period and the sweep of
      // expired upload sessions; every abandoned_build_check_s for builds whose process is
      // gone; every second while a failed build waits to be marked failed.
      std::chrono::duration<double> wait = std::chrono::seconds(600);
      if (cfg.abandoned_build_check_s > 0) wait = std::min(wait, abandoned_every);
      if (!builds_to_fail.empty()) wait = std::min(wait, std::chrono::duration<double>(1.0));
      if (!build_cv.wait_for(lock, wait,
                             [this] { return build_shutdown || !build_queue.empty(); })) {
        lock.unlock();
        retry_failing_builds();
        const auto now = std::chrono::steady_clock::now();
        if (cfg.abandoned_build_check_s > 0 && now - last_abandoned_check >= abandoned_every) {
          last_abandoned_check = now;
          fail_abandoned_builds();
        }
        if (now - last_retention >= std::chrono::minutes(10)) {
          last_retention = now;
          (void)apply_retention();
          (void)sweep_upload_sessions();
        }
        continue;
      }
      if (build_queue.empty()) return;  // shutdown with nothing left
      job = std::move(build_queue.front());
      build_queue.pop_front();
      build_running = true;
    }
    retry_failing_builds();
    run_build(job);
    {
      std::lock_guard lock(build_mutex);
      build_running = false;
      progress_version = 0;
    }
    build_cv.notify_all();
  }
}

void Server::Impl::fail_abandoned_builds() {
  try {
    const std::vector<std::int64_t> failed = store.fail_abandoned_builds();
    if (failed.empty()) return;
    std::string list;
    for (const std::int64_t v : failed) list += (list.empty() ? "" : ", ") + std::to_string(v);
    log("warn", "map build(s) " + list + " failed: the process building them is gone");
    for (std::size_t i = 0; i < failed.size(); ++i) metrics.build_finished("abandoned");
  } catch (const std::exception& e) {
    log("error", std::string("abandoned build check: ") + e.what());
  }
}

void Server::Impl::run_build(const BuildJob& job) {
  const auto t0 = std::chrono::steady_clock::now();
  log("info", "map build " + std::to_string(job.version) + " started");
  try {
    const nlohmann::json stats =
        execute_build(store, job.version, job.request, stopping, cfg.run_build_jobs,
                      [this, v = job.version](std::string_view stage, double fraction) {
                        std::lock_guard lock(build_mutex);
                        progress_version = v;
                        progress_stage = std::string(stage);
                        progress_fraction = fraction;
                      });
    invalidate_current_version();
    cache.clear();  // current-version entries may now be stale (versioned keys stay valid)
    metrics.build_finished("published");
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    log("info", "map build " + std::to_string(job.version) + " published in " + std::to_string(s) +
                    " s: " + stats.dump());
  } catch (const std::exception& e) {
    metrics.build_finished(stopping ? "cancelled" : "failed");
    log(stopping ? "warn" : "error",
        "map build " + std::to_string(job.version) + " failed: " + e.what());
    try {
      const auto info = store.get_map_version(job.version);
      if (info && info->status == MapVersionStatus::Building) {
        store.fail_map_version(job.version, e.what());
      }
    } catch (const std::exception& e2) {
      // Typically the same full disk that failed the build: try again later, so the
      // version does not stay "building" once space returns.
      log("error", "cannot mark map build " + std::to_string(job.version) +
                       " failed (retried every second): " + e2.what());
      std::lock_guard lock(build_mutex);
      builds_to_fail[job.version] = e.what();
    }
  }
}

void Server::Impl::retry_failing_builds() {
  std::map<std::int64_t, std::string> pending;
  {
    std::lock_guard lock(build_mutex);
    pending = builds_to_fail;
  }
  for (const auto& [version, error] : pending) {
    try {
      const auto info = store.get_map_version(version);
      if (info && info->status == MapVersionStatus::Building) {
        store.fail_map_version(version, error);
        log("info", "map build " + std::to_string(version) + " marked failed");
      }
      std::lock_guard lock(build_mutex);
      builds_to_fail.erase(version);
    } catch (const std::exception&) {  // still no space: the next second
    }
  }
#if defined(__GLIBC__)
  // A build allocates hundreds of MB on this thread and frees them; glibc keeps freed
  // pages in its arenas (the soak saw 49 MB in use, 760 MB resident). Give them back.
  malloc_trim(0);
#endif
}

void Server::Impl::register_map_routes() {
  http.Post("/v1/maps", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("maps_build");
    if (!require(req, res, Access::Operate)) return;
    if (req.body.size() > cfg.max_json_bytes) {
      return reply_error(res, 413,
                         "request body exceeds " + std::to_string(cfg.max_json_bytes) + " bytes",
                         "body");
    }
    nlohmann::json body = nlohmann::json::object();
    if (!req.body.empty()) {
      try {
        body = nlohmann::json::parse(req.body);
      } catch (const nlohmann::json::exception& e) {  // parse_error, or out_of_range (1e400)
        return reply_error(res, 400, std::string("body is not JSON: ") + e.what(), "body");
      }
      if (!body.is_object()) return reply_error(res, 400, "body must be a JSON object", "body");
    }
    nlohmann::json request = nlohmann::json::object();
    try {
      for (const auto& [k, v] : body.items()) {
        if (k != "region" && k != "exclude_drives" && k != "notes") {
          // The key is hostile and echoed back: never empty, at most 64 bytes.
          throw JsonRequestError{k.empty() ? std::string("\"\"") : k.substr(0, 64),
                                 "unknown field (known: region, exclude_drives, notes)"};
        }
      }
      if (auto region = parse_region(body.value("region", nlohmann::json(nullptr)))) {
        request["region"] = geobox_to_json(*region);
      }
      std::vector<std::string> excluded;
      if (body.contains("exclude_drives")) {
        const auto& ex = body["exclude_drives"];
        if (!ex.is_array())
          throw JsonRequestError{"exclude_drives", "must be an array of drive ids"};
        for (std::size_t i = 0; i < ex.size(); ++i) {
          if (!ex[i].is_string()) {
            throw JsonRequestError{"exclude_drives[" + std::to_string(i) + "]", "must be a string"};
          }
          const std::string id = ex[i].get<std::string>();
          if (!store.get_drive(id)) {
            throw JsonRequestError{"exclude_drives[" + std::to_string(i) + "]",
                                   "drive '" + id + "' does not exist"};
          }
          excluded.push_back(id);
        }
      }
      request["exclude_drives"] = excluded;
      if (body.contains("notes")) {
        if (!body["notes"].is_string()) throw JsonRequestError{"notes", "must be a string"};
        request["notes"] = body["notes"];
      }
    } catch (const JsonRequestError& e) {
      return reply_error(res, 422, e.message, e.field);
    }
    if (cfg.build_partition_zoom > 0) {
      request["partition"] = {{"zoom", cfg.build_partition_zoom},
                              {"halo_m", cfg.build_partition_halo_m}};
    }
    if (stopping) return reply_error(res, 503, "the server is stopping");
    {
      std::lock_guard lock(build_mutex);
      if (build_queue.size() >= static_cast<std::size_t>(std::max(cfg.max_queued_builds, 0))) {
        res.set_header("Retry-After", "60");
        return reply_error(
            res, 503,
            std::to_string(build_queue.size()) + " map builds are already queued; retry later");
      }
    }
    const std::int64_t version = submit_build(request);
    log("info", "map build " + std::to_string(version) + " queued: " + request.dump());
    res.set_header("Location", "/v1/maps/" + std::to_string(version));
    reply_json(res, 202,
               {{"version", version},
                {"status", "building"},
                {"href", "/v1/maps/" + std::to_string(version)},
                {"request", request}});
  });

  http.Get("/v1/maps", [this](const httplib::Request&, httplib::Response& res) {
    set_route("maps_list");
    nlohmann::json list = nlohmann::json::array();
    for (const MapVersionInfo& v : store.list_map_versions()) list.push_back(version_to_json(v));
    const auto cur = store.current_map_version();
    reply_json(
        res, 200,
        {{"versions", list}, {"current", cur ? nlohmann::json(*cur) : nlohmann::json(nullptr)}});
  });

  // "current" or a positive integer; replies 400/404 naming `field` and returns nullopt.
  auto version_param = [this](const std::string& s, httplib::Response& res,
                              const char* field) -> std::optional<std::int64_t> {
    if (s == "current") {
      const auto v = store.current_map_version();
      if (!v) reply_error(res, 404, "no map version has been published yet", field);
      return v;
    }
    const auto v = http::parse_int(s);
    if (!v || *v <= 0) {
      reply_error(res, 400, std::string(field) + " must be a positive integer or 'current'", field);
      return std::nullopt;
    }
    return v;
  };

  http.Get(R"(/v1/maps/([^/]+)/diff)", [this, version_param](const httplib::Request& req,
                                                             httplib::Response& res) {
    set_route("maps_diff");
    const auto to = version_param(req.matches[1], res, "version");
    if (!to) return;
    if (!req.has_param("from")) {
      return reply_error(res, 400, "from (the version to compare with) is required", "from");
    }
    const auto from = version_param(req.get_param_value("from"), res, "from");
    if (!from) return;
    const std::string format = req.has_param("format") ? req.get_param_value("format") : "json";
    if (format != "json" && format != "geojson") {
      return reply_error(res, 400, "format must be json or geojson", "format");
    }
    std::optional<GeoBox> bbox;
    if (req.has_param("bbox")) {
      bbox = http::parse_bbox(req.get_param_value("bbox"));
      if (!bbox || bbox->crosses_antimeridian()) {
        return reply_error(res, 400, "bbox must be minlon,minlat,maxlon,maxlat in degrees", "bbox");
      }
    }
    for (const auto& [v, field] : {std::pair{*from, "from"}, std::pair{*to, "version"}}) {
      const auto info = store.get_map_version(v);
      if (!info || info->status != MapVersionStatus::Published) {
        return reply_error(res, 404, "map version " + std::to_string(v) + " is not published",
                           field);
      }
    }
    // Two whole maps are read and compared: bounded like exports.
    const ConcurrencySlot slot(exports_in_flight, cfg.max_concurrent_exports);
    if (!slot.acquired()) {
      res.set_header("Retry-After", "30");
      return reply_error(res, 503, "too many exports and diffs in progress; retry later");
    }
    LandmarkDiff diff = diff_landmarks(store.landmarks_in(*from, bbox, false),
                                       store.landmarks_in(*to, bbox, false));
    // Reasons: what the versions after `from` up to `to` recorded when they made the
    // change (the latest record of a key wins).
    std::map<std::pair<int, std::int64_t>, std::pair<nlohmann::json, std::int64_t>> reasons;
    if (*from < *to) {
      for (const MapVersionInfo& v : store.list_map_versions()) {
        if (v.version <= *from || v.version > *to || v.status != MapVersionStatus::Published) {
          continue;
        }
        for (const LandmarkChange& c : store.landmark_changes(v.version)) {
          reasons[{static_cast<int>(c.change), c.key}] = {c.reason, v.version};
        }
      }
    }
    std::map<std::string, std::int64_t> counts{{"added", 0}, {"moved", 0}, {"retired", 0}};
    nlohmann::json changes = nlohmann::json::array();
    nlohmann::json features = nlohmann::json::array();
    for (LandmarkChange& c : diff.changes) {
      ++counts[std::string(to_string(c.change))];
      std::optional<std::int64_t> rv;
      if (auto it = reasons.find({static_cast<int>(c.change), c.key}); it != reasons.end()) {
        c.reason = it->second.first;
        rv = it->second.second;
      }
      nlohmann::json j = change_json(c, rv);
      if (format == "geojson") {
        nlohmann::json props = j;
        props.erase("geometry");
        props.erase("previous_geometry");
        features.push_back({{"type", "Feature"},
                            {"geometry", geojson_geometry(c.geometry, c.is_line)},
                            {"properties", props}});
      } else {
        changes.push_back(std::move(j));
      }
    }
    nlohmann::json summary{{"added", counts["added"]},
                           {"moved", counts["moved"]},
                           {"retired", counts["retired"]},
                           {"unchanged", diff.unchanged},
                           {"refined", diff.refined}};
    const nlohmann::json body =
        format == "geojson"
            ? nlohmann::json{{"type", "FeatureCollection"},
                             {"features", features},
                             {"properties", {{"from", *from}, {"to", *to}, {"counts", summary}}}}
            : nlohmann::json{
                  {"from", *from}, {"to", *to}, {"counts", summary}, {"changes", changes}};
    res.status = 200;
    res.set_content(body.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace),
                    format == "geojson" ? "application/geo+json" : "application/json");
    res.set_header("Cache-Control", "public, max-age=3600");  // published versions are immutable
  });

  http.Get(R"(/v1/maps/([^/]+))", [this, version_param](const httplib::Request& req,
                                                        httplib::Response& res) {
    set_route("maps_get");
    const auto v = version_param(req.matches[1], res, "version");
    if (!v) return;
    const auto info = store.get_map_version(*v);
    if (!info) {
      return reply_error(res, 404, "map version " + std::to_string(*v) + " does not exist",
                         "version");
    }
    nlohmann::json j = version_to_json(*info);
    if (info->status == MapVersionStatus::Building) {
      // Live progress: this replica's build thread, or the jobs of a partitioned
      // build that workers (on any host) run.
      std::lock_guard lock(build_mutex);
      if (progress_version == *v) {
        j["progress"] = {{"stage", progress_stage}, {"fraction", progress_fraction}};
      }
    }
    if (info->status == MapVersionStatus::Building && !j.contains("progress")) {
      const auto jobs = store.build_jobs(*v);
      if (!jobs.empty()) {
        const auto done = std::count_if(jobs.begin(), jobs.end(), [](const mapping::BuildJob& b) {
          return b.state == BuildJobState::Done;
        });
        j["progress"] = {{"stage", "jobs"},
                         {"fraction", static_cast<double>(done) / jobs.size()},
                         {"jobs_done", done},
                         {"jobs", jobs.size()}};
      }
    }
    reply_json(res, 200, j);
  });
}

}  // namespace polmap::mapping
