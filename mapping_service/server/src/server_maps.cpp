// Map version endpoints: POST /v1/maps (build in the background), GET /v1/maps[/{version}].
#include <cmath>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

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
  for (;;) {
    BuildJob job;
    {
      std::unique_lock lock(build_mutex);
      // Wakes every 10 minutes without work, for the retention period and the sweep of
      // expired upload sessions; every second while
      // a failed build waits to be marked failed.
      const auto wait =
          builds_to_fail.empty() ? std::chrono::seconds(600) : std::chrono::seconds(1);
      if (!build_cv.wait_for(lock, wait,
                             [this] { return build_shutdown || !build_queue.empty(); })) {
        lock.unlock();
        retry_failing_builds();
        if (std::chrono::steady_clock::now() - last_retention >= std::chrono::minutes(10)) {
          last_retention = std::chrono::steady_clock::now();
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
    }
    build_cv.notify_all();
  }
}

void Server::Impl::run_build(const BuildJob& job) {
  const auto t0 = std::chrono::steady_clock::now();
  log("info", "map build " + std::to_string(job.version) + " started");
  try {
    const nlohmann::json stats = execute_build(store, job.version, job.request, stopping);
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
          throw JsonRequestError{k, "unknown field (known: region, exclude_drives, notes)"};
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

  http.Get(R"(/v1/maps/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("maps_get");
    const std::string s = req.matches[1];
    std::optional<std::int64_t> v;
    if (s == "current") {
      v = store.current_map_version();
      if (!v) return reply_error(res, 404, "no map version has been published yet", "version");
    } else {
      v = http::parse_int(s);
      if (!v || *v <= 0) {
        return reply_error(res, 400, "version must be a positive integer or 'current'", "version");
      }
    }
    const auto info = store.get_map_version(*v);
    if (!info) {
      return reply_error(res, 404, "map version " + std::to_string(*v) + " does not exist",
                         "version");
    }
    reply_json(res, 200, version_to_json(*info));
  });
}

}  // namespace polmap::mapping
