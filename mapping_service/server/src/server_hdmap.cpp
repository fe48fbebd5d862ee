// GET /v1/maps/{v}/hdmap-comparison (the stored HD-map comparisons of a version),
// GET /v1/maps/{v}/hdmap-comparison/{name}?format=geojson|json (one, with its features) and
// GET /v1/maps/{v}/landmarks/{key} (a landmark's attributes, supporting drives and version
// history). Read-only and keyless like the diff; exact drive times and drive ids only with a
// key that may read drive data, days otherwise (docs/security.md).
#include <ctime>

#include "polmap/util/gzip.hpp"
#include "server_impl.hpp"

namespace polmap::mapping {
namespace {

/// Drive clocks at or after 2000-01-01 are taken as UNIX time (vehicles with a GNSS-disciplined
/// clock); earlier values are a recording's own clock (the simulator starts at 0).
constexpr double kEpochPlausibleS = 946684800.0;

/// ISO 8601 UTC of a drive time, or its day only ("2024-05-01"); null unless UNIX time.
nlohmann::json iso_or_null(double t_s, bool day_only) {
  if (!(t_s >= kEpochPlausibleS) || t_s > 32503680000.0) return nullptr;  // until year 3000
  const std::time_t t = static_cast<std::time_t>(t_s);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof(buf), day_only ? "%Y-%m-%d" : "%Y-%m-%dT%H:%M:%SZ", &tm);
  return std::string(buf);
}

nlohmann::json geometry_json(const std::vector<GeoPoint>& g, bool is_line) {
  if (!is_line && !g.empty()) {
    return {{"type", "Point"}, {"coordinates", {g.front().lon_deg, g.front().lat_deg}}};
  }
  nlohmann::json c = nlohmann::json::array();
  for (const auto& p : g) c.push_back({p.lon_deg, p.lat_deg});
  return {{"type", "LineString"}, {"coordinates", c}};
}

}  // namespace

void Server::Impl::register_hdmap_routes() {
  // "current" or a positive integer, and published; replies 400/404 naming "version".
  auto published_version = [this](const std::string& s,
                                  httplib::Response& res) -> std::optional<std::int64_t> {
    std::optional<std::int64_t> v;
    if (s == "current") {
      v = current_version();
      if (!v) {
        reply_error(res, 404, "no map version has been published yet", "version");
        return std::nullopt;
      }
    } else {
      v = http::parse_int(s);
      if (!v || *v <= 0) {
        reply_error(res, 400, "version must be a positive integer or 'current'", "version");
        return std::nullopt;
      }
    }
    const auto info = store.get_map_version(*v);
    if (!info || info->status != MapVersionStatus::Published) {
      reply_error(
          res, 404,
          "map version " + std::to_string(*v) + (info ? " is not published" : " does not exist"),
          "version");
      return std::nullopt;
    }
    return v;
  };

  http.Get(R"(/v1/maps/([^/]+)/hdmap-comparison)",
           [this, published_version](const httplib::Request& req, httplib::Response& res) {
             set_route("maps_hdmap_list");
             const auto v = published_version(req.matches[1], res);
             if (!v) return;
             nlohmann::json list = nlohmann::json::array();
             for (const HdMapComparisonRecord& r : store.list_hdmap_comparisons(*v)) {
               list.push_back(
                   {{"name", r.name},
                    {"hdmap_file", r.hdmap_file},
                    {"created_at", r.created_at},
                    {"summary", r.summary},
                    {"href", "/v1/maps/" + std::to_string(*v) + "/hdmap-comparison/" + r.name}});
             }
             reply_json(res, 200, {{"version", *v}, {"comparisons", list}});
           });

  http.Get(R"(/v1/maps/([^/]+)/hdmap-comparison/([^/]+))", [this, published_version](
                                                               const httplib::Request& req,
                                                               httplib::Response& res) {
    set_route("maps_hdmap_get");
    const std::string name = req.matches[2];
    if (!is_valid_hdmap_comparison_name(name)) {
      return reply_error(res, 400,
                         "name must be 1..64 characters of [A-Za-z0-9._-], not "
                         "starting with '.'",
                         "name");
    }
    const std::string format = req.has_param("format") ? req.get_param_value("format") : "geojson";
    if (format != "json" && format != "geojson") {
      return reply_error(res, 400, "format must be geojson or json", "format");
    }
    const auto v = published_version(req.matches[1], res);
    if (!v) return;
    const auto r = store.get_hdmap_comparison(*v, name);
    if (!r) {
      return reply_error(res, 404,
                         "map version " + std::to_string(*v) + " has no HD-map comparison named '" +
                             name + "' (polmap compare-hdmap --store stores one)",
                         "name");
    }
    nlohmann::json body;
    if (format == "geojson") {
      body = r->features.is_object() ? r->features
                                     : nlohmann::json{{"type", "FeatureCollection"},
                                                      {"features", nlohmann::json::array()}};
      body["properties"]["summary"] = r->summary;
      body["properties"]["version"] = *v;
      body["properties"]["name"] = r->name;
      body["properties"]["hdmap_file"] = r->hdmap_file;
      body["properties"]["created_at"] = r->created_at;
    } else {
      body = {{"version", *v},
              {"name", r->name},
              {"hdmap_file", r->hdmap_file},
              {"created_at", r->created_at},
              {"summary", r->summary}};
    }
    http::CachedBlob blob;
    blob.body = body.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
    blob.gzip_body = util::gzip_compress(blob.body);
    blob.etag = "\"" + content_etag(blob.body).substr(0, 32) + "\"";
    blob.content_type = format == "geojson" ? "application/geo+json" : kJson;
    // Replaced when compare-hdmap stores the same name again: revalidate (304).
    reply_blob(req, res, blob, "no-cache");
  });

  http.Get(
      R"(/v1/maps/([^/]+)/landmarks/([^/]+))",
      [this, published_version](const httplib::Request& req, httplib::Response& res) {
        set_route("maps_landmark");
        const auto key = http::parse_int(req.matches[2].str());
        if (!key || *key <= 0) {
          return reply_error(res, 400,
                             "key must be a landmark's stable key (a positive integer: "
                             "the id of its vector-tile feature)",
                             "key");
        }
        const auto v = published_version(req.matches[1], res);
        if (!v) return;
        const auto d = store.landmark_detail(*v, *key);
        if (!d) {
          return reply_error(res, 404,
                             "map version " + std::to_string(*v) + " has no landmark with key " +
                                 std::to_string(*key),
                             "key");
        }
        // When a vehicle passed a place is trajectory data: without a key that may read
        // drive data, counts and UTC days only (as the diff's reasons); with one, the
        // times and the drives.
        const auto api_key = authenticate(req);
        const bool with_drives = api_key && allows(*api_key, Access::ReadDrives);
        const bool day_only = !with_drives;
        double first_s = 0.0, last_s = 0.0;
        std::string first_in, last_in;
        nlohmann::json drives = nlohmann::json::array();
        for (std::size_t i = 0; i < d->drives.size(); ++i) {
          const LandmarkDriveInfo& dr = d->drives[i];
          if (i == 0 || dr.start_time_s < first_s) first_s = dr.start_time_s;
          if (i == 0 || dr.end_time_s > last_s) last_s = dr.end_time_s;
          if (first_in.empty() || dr.ingested_at < first_in) first_in = dr.ingested_at;
          if (last_in.empty() || dr.ingested_at > last_in) last_in = dr.ingested_at;
          if (with_drives) {
            drives.push_back({{"drive_id", dr.drive_id},
                              {"vehicle_id", dr.vehicle_id},
                              {"start_time_s", dr.start_time_s},
                              {"end_time_s", dr.end_time_s},
                              {"ingested_at", dr.ingested_at},
                              {"candidates", dr.candidates}});
          }
        }
        const bool any = !d->drives.empty();
        nlohmann::json history = nlohmann::json::array();
        for (const LandmarkHistoryEntry& e : d->history) {
          nlohmann::json h{{"version", e.version},
                           {"change", std::string(to_string(e.change.change))},
                           {"key", std::to_string(e.change.key)},
                           {"published_at", e.published_at},
                           {"reason", e.change.reason},
                           {"inferred", e.inferred}};
          if (e.change.change == LandmarkChangeKind::Moved) {
            h["distance_m"] = e.change.distance_m;
            h["previous_key"] = std::to_string(e.change.previous_key);
          }
          history.push_back(std::move(h));
        }
        nlohmann::json j{
            {"version", *v},
            {"key", std::to_string(d->key)},
            {"kind", d->is_line ? "line" : "point"},
            {"geometry", geometry_json(d->geometry, d->is_line)},
            {"support_drives", d->support_drives},
            {"spread_m", d->spread_m},
            {"supporting_drives", d->drives.size()},
            {"times", day_only ? "day" : "exact"},
            {"first_seen_s", any && !day_only ? nlohmann::json(first_s) : nlohmann::json(nullptr)},
            {"last_seen_s", any && !day_only ? nlohmann::json(last_s) : nlohmann::json(nullptr)},
            {"first_seen", any ? iso_or_null(first_s, day_only) : nlohmann::json(nullptr)},
            {"last_seen", any ? iso_or_null(last_s, day_only) : nlohmann::json(nullptr)},
            {"first_ingested_at", any ? nlohmann::json(day_only ? first_in.substr(0, 10) : first_in)
                                      : nlohmann::json(nullptr)},
            {"last_ingested_at", any ? nlohmann::json(day_only ? last_in.substr(0, 10) : last_in)
                                     : nlohmann::json(nullptr)},
            {"history", history}};
        if (!d->is_line) j["class"] = std::string(to_string(d->scattering));
        if (with_drives) j["drives"] = drives;
        // Drives may be deleted later (their support goes with them): short caching.
        res.status = 200;
        res.set_content(j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace), kJson);
        res.set_header("Cache-Control", with_drives ? "private, max-age=60" : "public, max-age=60");
        res.set_header("Vary", "Authorization");
      });
}

}  // namespace polmap::mapping
