// mapping::Server: setup, listen/stop, logging, auth, metrics, health, CORS,
// version resolution and the shared reply helpers. Endpoint groups live in
// server_drives.cpp, server_maps.cpp, server_tiles.cpp, server_gis.cpp.
#include "polmap/mapping_service/server.hpp"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <fstream>

#include "polmap/schema/errors.hpp"
#include "polmap/util/text.hpp"
#include "server_impl.hpp"

namespace polmap::mapping {
namespace {

using Clock = std::chrono::steady_clock;

thread_local const char* t_route = nullptr;
thread_local Clock::time_point t_start{};

std::string status_of(const MapVersionInfo& v) { return std::string(to_string(v.status)); }

}  // namespace

void set_route(const char* route) { t_route = route; }

std::string_view to_string(KeyRole role) {
  switch (role) {
    case KeyRole::Vehicle:
      return "vehicle";
    case KeyRole::Viewer:
      return "viewer";
    default:
      return "operator";
  }
}

std::vector<ApiKey> read_api_key_file(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw IoError("cannot read API key file " + path.string());
  std::vector<ApiKey> keys;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    const std::string_view t = util::trim(line);
    if (t.empty() || t.front() == '#') continue;
    std::vector<std::string_view> words;
    for (std::size_t pos = 0; pos < t.size();) {
      while (pos < t.size() && util::is_ascii_space(t[pos])) ++pos;
      const std::size_t end = std::find_if(t.begin() + static_cast<std::ptrdiff_t>(pos), t.end(),
                                           util::is_ascii_space) -
                              t.begin();
      if (end > pos) words.push_back(t.substr(pos, end - pos));
      pos = end;
    }
    const auto where = path.string() + ":" + std::to_string(number);
    if (words.size() == 1) {
      keys.emplace_back(std::string(words[0]));
      continue;
    }
    std::optional<KeyRole> role;
    for (const KeyRole r : {KeyRole::Vehicle, KeyRole::Viewer, KeyRole::Operator}) {
      if (words[0] == to_string(r)) role = r;
    }
    if (!role || words.size() > 3 || (words.size() == 3 && *role != KeyRole::Vehicle)) {
      throw ValidationError(where +
                            ": expected 'KEY' or 'vehicle|viewer|operator KEY' (vehicle keys may "
                            "add a VEHICLE_ID)");
    }
    keys.emplace_back(std::string(words[1]), *role,
                      words.size() == 3 ? std::string(words[2]) : std::string());
  }
  if (keys.empty()) throw ValidationError("API key file " + path.string() + " holds no key");
  return keys;
}

nlohmann::json geobox_to_json(const tiles::GeoBox& b) {
  return {{"min_lat_deg", b.min_lat_deg},
          {"min_lon_deg", b.min_lon_deg},
          {"max_lat_deg", b.max_lat_deg},
          {"max_lon_deg", b.max_lon_deg}};
}

nlohmann::json version_to_json(const MapVersionInfo& v) {
  nlohmann::json j{{"version", v.version},       {"status", status_of(v)},
                   {"created_at", v.created_at}, {"current", v.current},
                   {"parameters", v.parameters}, {"statistics", v.statistics}};
  j["published_at"] =
      v.published_at.empty() ? nlohmann::json(nullptr) : nlohmann::json(v.published_at);
  if (!v.error.empty()) j["error"] = v.error;
  j["href"] = "/v1/maps/" + std::to_string(v.version);
  return j;
}

// ---- Impl -----------------------------------------------------------------------------------

Server::Impl::Impl(MapStore& s, ServerConfig config)
    : store(s),
      cfg(std::move(config)),
      http_owner(make_http_server(cfg)),
      http(*http_owner),
      cache(cfg.tile_cache_bytes) {
  if (!cfg.log_sink) {
    cfg.log_sink = [](std::string_view line) {
      std::string l(line);
      l.push_back('\n');
      std::fwrite(l.data(), 1, l.size(), stderr);  // one write: lines do not interleave
    };
  }
  keys = std::make_shared<const std::vector<ApiKey>>(cfg.api_keys);
  if (!cfg.api_key_file.empty()) {
    std::error_code ec;
    keys_mtime = std::filesystem::last_write_time(cfg.api_key_file, ec);  // api_keys is its content
    keys_checked_at = std::chrono::steady_clock::now();
  }
  const int threads = std::max(1, cfg.threads);
  http.new_task_queue = [threads] { return new httplib::ThreadPool(static_cast<size_t>(threads)); };
  http.set_keep_alive_max_count(static_cast<size_t>(std::max(1, cfg.keep_alive_max_requests)));
  http.set_keep_alive_timeout(std::max(1, cfg.keep_alive_timeout_s));
  http.set_read_timeout(30, 0);
  http.set_write_timeout(30, 0);
  // Uploads are limited by our own handler (JSON error, 413); this is the hard stop.
  http.set_payload_max_length(static_cast<size_t>(
      std::max({cfg.max_upload_bytes, cfg.max_json_bytes, cfg.max_run_report_bytes}) + (1u << 20)));
  http.set_tcp_nodelay(true);
  if (!cfg.cors_allow_origin.empty()) {
    http.set_default_headers({{"Access-Control-Allow-Origin", cfg.cors_allow_origin},
                              {"Access-Control-Expose-Headers",
                               "ETag, Location, Content-Encoding, X-Polmap-Map-Version, "
                               "Upload-Offset, Upload-Length, Upload-Expires"}});
  }
  sweep_upload_dir();
  (void)apply_retention();
  (void)sweep_upload_sessions();
  register_routes();
  build_thread = std::thread([this] { build_loop(); });
  if (cfg.fail_stale_builds_on_start) {
    try {
      for (const MapVersionInfo& v : store.list_map_versions()) {
        if (v.status != MapVersionStatus::Building) continue;
        const auto jobs = store.build_jobs(v.version);
        if (std::any_of(jobs.begin(), jobs.end(), [](const mapping::BuildJob& j) {
              return j.state == BuildJobState::Pending || j.state == BuildJobState::Running;
            })) {
          continue;  // queued for build workers
        }
        {
          store.fail_map_version(v.version, "interrupted: the server stopped during the build");
          log("warn", "map version " + std::to_string(v.version) +
                          " was left building by a previous run; marked failed");
        }
      }
    } catch (const std::exception& e) {
      log("warn", std::string("could not check for stale builds: ") + e.what());
    }
  }
}

Server::Impl::~Impl() {
  {
    std::lock_guard lock(build_mutex);
    build_shutdown = true;
  }
  build_cv.notify_all();
  if (build_thread.joinable()) build_thread.join();
}

void Server::Impl::sweep_upload_dir() {
  // What a killed process left behind: upload files, unpacked members, export directories.
  // Only our own names, and only untouched for a while (the upload directory may be the
  // shared system temporary directory, and another server's upload may be in flight).
  const std::filesystem::path dir =
      cfg.upload_dir.empty() ? std::filesystem::temp_directory_path() : cfg.upload_dir;
  const auto now = std::filesystem::file_time_type::clock::now();
  std::error_code ec;
  std::size_t removed = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    if (!name.starts_with("polmap-upload-") && !name.starts_with("polmap-export-")) continue;
    const auto age = std::chrono::duration<double>(now - e.last_write_time(ec)).count();
    if (ec || age < cfg.upload_leftover_age_s) continue;
    if (std::filesystem::remove_all(e.path(), ec) > 0 && !ec) ++removed;
  }
  if (removed > 0) log("info", "removed " + std::to_string(removed) + " upload/export leftovers");
}

void Server::Impl::log(std::string_view level, std::string_view message) const {
  if (!cfg.log_requests && level == "info") return;
  std::string line = http::iso8601_now();
  line += ' ';
  line += level;
  line += ' ';
  line += http::escape_for_log(message);  // request paths, drive ids: never raw
  cfg.log_sink(line);
}

std::optional<ApiKey> Server::Impl::authenticate(const httplib::Request& req) const {
  const std::string auth = req.get_header_value("Authorization");
  std::string_view token;
  constexpr std::string_view kBearer = "Bearer ";
  if (auth.size() > kBearer.size() &&
      std::equal(kBearer.begin(), kBearer.end(), auth.begin(), [](char a, char b) {
        return std::tolower(static_cast<unsigned char>(a)) ==
               std::tolower(static_cast<unsigned char>(b));
      })) {
    token = util::trim(std::string_view(auth).substr(kBearer.size()));
  }
  if (token.empty()) return std::nullopt;
  const auto keys = current_keys();
  // Compare against every key without early exit: timing does not depend on which
  // key matched, and secrets_equal compares digests in constant time.
  std::optional<ApiKey> match;
  for (const ApiKey& k : *keys) {
    if (http::secrets_equal(token, k.key) && !match) match = k;
  }
  return match;
}

std::optional<ApiKey> Server::Impl::require(const httplib::Request& req, httplib::Response& res,
                                            Access access) const {
  auto key = authenticate(req);
  if (!key) {
    res.set_header("WWW-Authenticate", "Bearer realm=\"polmap\"");
    reply_error(res, 401,
                req.has_header("Authorization")
                    ? "invalid API key"
                    : "missing API key: send 'Authorization: Bearer KEY'",
                "Authorization");
    return std::nullopt;
  }
  if (!allows(*key, access)) {
    reply_error(res, 403,
                "a " + std::string(to_string(key->role)) + " key may not " +
                    std::string(access == Access::Upload       ? "upload drives"
                                : access == Access::ReadDrives ? "read drive data"
                                                               : "run builds, deletes or exports"),
                "Authorization");
    return std::nullopt;
  }
  return key;
}

bool Server::Impl::allows(const ApiKey& key, Access access) {
  if (access == Access::AnyKey) return true;
  switch (key.role) {
    case KeyRole::Operator:
      return true;
    case KeyRole::Viewer:
      return access == Access::ReadDrives;
    case KeyRole::Vehicle:
      return access == Access::Upload;
  }
  return false;
}

std::shared_ptr<const std::vector<ApiKey>> Server::Impl::current_keys() const {
  std::lock_guard lock(keys_mutex);
  if (!cfg.api_key_file.empty()) {
    const auto now = std::chrono::steady_clock::now();
    if (now - keys_checked_at >= std::chrono::seconds(1)) {
      keys_checked_at = now;
      std::error_code ec;
      const auto mtime = std::filesystem::last_write_time(cfg.api_key_file, ec);
      if (!ec && mtime != keys_mtime) {
        try {
          keys = std::make_shared<const std::vector<ApiKey>>(read_api_key_file(cfg.api_key_file));
          keys_mtime = mtime;
          log("info", "API keys reloaded from " + cfg.api_key_file.string() + " (" +
                          std::to_string(keys->size()) + " keys)");
        } catch (const std::exception& e) {
          keys_mtime = mtime;  // do not retry a broken file every second; its next change will
          log("error",
              std::string("API key file not reloaded, keeping the previous keys: ") + e.what());
        }
      }
    }
  }
  return keys;
}

void Server::Impl::reply_json(httplib::Response& res, int status, const nlohmann::json& body) {
  res.status = status;
  res.set_content(body.dump(), kJson);
  res.set_header("Cache-Control", "no-store");
}

void Server::Impl::reply_error(httplib::Response& res, int status, std::string_view message,
                               std::string_view field, const nlohmann::json& extra) {
  res.status = status;
  res.set_content(http::json_error(message, field, extra), kJson);
  res.set_header("Cache-Control", "no-store");
}

int Server::Impl::reply_blob(const httplib::Request& req, httplib::Response& res,
                             const http::CachedBlob& blob, const std::string& cache_control) const {
  const bool gzip =
      !blob.gzip_body.empty() && http::accepts_gzip(req.get_header_value("Accept-Encoding"));
  // Each representation has its own strong validator (RFC 9110 §8.8.3).
  const std::string etag = gzip ? blob.etag.substr(0, blob.etag.size() - 1) + "-gz\"" : blob.etag;
  res.set_header("ETag", etag);
  res.set_header("Cache-Control", cache_control);
  if (!blob.gzip_body.empty()) res.set_header("Vary", "Accept-Encoding");
  const std::string inm = req.get_header_value("If-None-Match");
  if (!inm.empty() && http::if_none_match_matches(inm, etag)) {
    res.status = 304;
    return 304;
  }
  res.status = 200;
  if (gzip) {
    res.set_header("Content-Encoding", "gzip");
    res.set_content(blob.gzip_body, blob.content_type.c_str());
  } else {
    res.set_content(blob.body, blob.content_type.c_str());
  }
  return 200;
}

std::optional<std::int64_t> Server::Impl::current_version() {
  const auto now = Clock::now();
  {
    std::lock_guard lock(version_mutex);
    // Half a second: a version published through another replica of the same store is
    // served here within a second.
    if (now - current_cached_at < std::chrono::milliseconds(500)) return current_cached;
  }
  const std::optional<std::int64_t> v = store.current_map_version();
  std::lock_guard lock(version_mutex);
  current_cached = v;
  current_cached_at = now;
  return v;
}

void Server::Impl::invalidate_current_version() {
  std::lock_guard lock(version_mutex);
  current_cached_at = {};
}

std::shared_ptr<const VersionIndex> Server::Impl::version_index(std::int64_t version) {
  {
    std::lock_guard lock(version_mutex);
    if (const auto it = indexes.find(version); it != indexes.end()) return it->second;
  }
  const std::optional<MapVersionInfo> info = store.get_map_version(version);
  if (!info || info->status != MapVersionStatus::Published) return nullptr;
  auto idx = std::make_shared<VersionIndex>();
  idx->version = version;
  idx->parameters = info->parameters;
  for (const TileInfo& t : store.list_tiles(version, TileLayer::Localization)) {
    idx->localization.emplace(t.key, t);
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        if (auto n = tiles::neighbour(t.key, dx, dy)) idx->covered.insert(*n);
      }
    }
    const tiles::GeoBox b = tiles::tile_bounds(t.key);
    if (!idx->bounds) {
      idx->bounds = b;
    } else {
      idx->bounds->min_lat_deg = std::min(idx->bounds->min_lat_deg, b.min_lat_deg);
      idx->bounds->min_lon_deg = std::min(idx->bounds->min_lon_deg, b.min_lon_deg);
      idx->bounds->max_lat_deg = std::max(idx->bounds->max_lat_deg, b.max_lat_deg);
      idx->bounds->max_lon_deg = std::max(idx->bounds->max_lon_deg, b.max_lon_deg);
    }
  }
  for (const TileInfo& t : store.list_tiles(version, TileLayer::Gridmap)) {
    idx->gridmap.emplace(t.key, t);
    idx->gridmap_max_zoom = std::max(idx->gridmap_max_zoom, t.key.z);
  }
  for (const TileInfo& t : store.list_tiles(version, TileLayer::GridmapMechanism)) {
    idx->gridmap_mechanism.emplace(t.key, t);
  }
  std::lock_guard lock(version_mutex);
  return indexes.try_emplace(version, std::move(idx)).first->second;
}

std::shared_ptr<const VersionIndex> Server::Impl::resolve_version(const httplib::Request& req,
                                                                  httplib::Response& res,
                                                                  bool& is_explicit) {
  is_explicit = req.has_param("version") && req.get_param_value("version") != "current";
  std::int64_t version = 0;
  if (is_explicit) {
    const auto v = http::parse_int(req.get_param_value("version"));
    if (!v || *v <= 0) {
      reply_error(res, 400, "version must be a positive integer or 'current'", "version");
      return nullptr;
    }
    version = *v;
  } else {
    const auto cur = current_version();
    if (!cur) {
      reply_error(res, 404, "no map version has been published yet", "version");
      return nullptr;
    }
    version = *cur;
  }
  auto idx = version_index(version);
  if (!idx) {
    const auto info = store.get_map_version(version);
    reply_error(res, 404,
                info ? "map version " + std::to_string(version) + " is not published (status " +
                           status_of(*info) + ")"
                     : "map version " + std::to_string(version) + " does not exist",
                "version");
    return nullptr;
  }
  res.set_header("X-Polmap-Map-Version", std::to_string(version));
  return idx;
}

// ---- admission: limits checked after the headers, before any body byte is read ------------

bool Server::Impl::admit(const httplib::Request& req, httplib::Response& res) const {
  // A refusal leaves the body unread, so the connection cannot carry another request.
  auto refuse = [&](int status, std::string_view message, std::string_view field) {
    set_route("refused");
    reply_error(res, status, message, field);
    res.set_header("Connection", "close");
    return false;
  };
  std::size_t header_bytes = 0;
  for (const auto& [k, v] : req.headers) header_bytes += k.size() + v.size() + 4;
  if (req.headers.size() > cfg.max_header_count || header_bytes > cfg.max_header_bytes) {
    return refuse(431,
                  "request headers exceed " + std::to_string(cfg.max_header_count) + " fields or " +
                      std::to_string(cfg.max_header_bytes) + " bytes",
                  "headers");
  }
  if (req.get_header_value("Range").find(',') != std::string::npos) {
    return refuse(416, "at most one byte range per request", "Range");
  }
  const std::string encoding = req.get_header_value("Content-Encoding");
  if (!encoding.empty() && encoding != "identity") {
    return refuse(415, "request bodies are not decompressed: send them without Content-Encoding",
                  "Content-Encoding");
  }
  const bool write = req.method != "GET" && req.method != "HEAD" && req.method != "OPTIONS";
  if (!write) return true;
  // Uploads: their handler checks the key before it reads a byte, drains a small refused
  // body (the keep-alive connection survives) and streams the rest to disk, capped.
  const bool upload = (req.method == "POST" && req.path == "/v1/drives") || is_upload_chunk(req);
  if (upload) return true;
  // Other writes without a valid key: refused before the body is read unless it is tiny
  // (then the handler answers 401 on a connection that stays usable).
  const auto declared = http::parse_int(req.get_header_value("Content-Length"));
  const bool tiny = !req.has_header("Transfer-Encoding") &&
                    (!req.has_header("Content-Length") || (declared && *declared <= (64 << 10)));
  if (!tiny && !authenticate(req)) {
    (void)require(req, res, Access::AnyKey);  // writes the 401
    set_route("refused");
    res.set_header("Connection", "close");
    return false;
  }
  // Other bodies are small JSON that cpp-httplib buffers whole: they must declare their
  // length, and it must be within max_json_bytes.
  if (req.has_header("Transfer-Encoding")) {
    return refuse(411, "send a Content-Length (chunked request bodies are not accepted here)",
                  "Transfer-Encoding");
  }
  // Run reports (POST /v1/runs) have their own cap, and only keys that may send them get
  // their body read.
  const bool run_report = req.method == "POST" && req.path == "/v1/runs";
  if (run_report) {
    const auto key = authenticate(req);
    if (key && !allows(*key, Access::Upload)) {
      (void)require(req, res, Access::Upload);  // writes the 403
      set_route("refused");
      res.set_header("Connection", "close");
      return false;
    }
  }
  const std::uint64_t cap = run_report ? cfg.max_run_report_bytes : cfg.max_json_bytes;
  if (req.has_header("Content-Length")) {
    const auto len = http::parse_int(req.get_header_value("Content-Length"));
    if (!len || *len < 0 || static_cast<std::uint64_t>(*len) > cap) {
      return refuse(413, "request body exceeds " + std::to_string(cap) + " bytes",
                    "Content-Length");
    }
  }
  return true;
}

// ---- routes: health, metrics, CORS preflight, errors ----------------------------------------

void Server::Impl::register_routes() {
  http.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    t_start = Clock::now();
    t_route = nullptr;
    return admit(req, res) ? httplib::Server::HandlerResponse::Unhandled
                           : httplib::Server::HandlerResponse::Handled;
  });
  // "Expect: 100-continue": the client waits for our go before it sends the body. Only
  // requests that pass admission and carry a key that may make them get it; the others are
  // answered at once (401, 403, 413, ...), and their body never comes.
  http.set_expect_100_continue_handler([this](const httplib::Request& req, httplib::Response& res) {
    t_start = Clock::now();
    t_route = nullptr;
    if (!admit(req, res)) return res.status;
    const bool chunk = is_upload_chunk(req);
    const bool upload = (req.method == "POST" && req.path == "/v1/drives") || chunk;
    if (req.method == "GET" || req.method == "HEAD" || req.method == "OPTIONS") return 100;
    if (!require(req, res, upload ? Access::Upload : Access::AnyKey)) {
      set_route(chunk ? "uploads_patch" : upload ? "drives_upload" : "refused");
      res.set_header("Connection", "close");
      return res.status;
    }
    const auto len = http::parse_int(req.get_header_value("Content-Length"));
    if (chunk && len && *len > 0 && static_cast<std::uint64_t>(*len) > cfg.max_upload_chunk_bytes) {
      set_route("uploads_patch");
      reply_error(res, 413,
                  "chunk of " + std::to_string(*len) + " bytes exceeds the chunk limit of " +
                      std::to_string(cfg.max_upload_chunk_bytes) + " bytes",
                  "Content-Length", {{"limit_bytes", cfg.max_upload_chunk_bytes}});
      res.set_header("Connection", "close");
      return 413;
    }
    if (upload && len && *len > 0 && static_cast<std::uint64_t>(*len) > cfg.max_upload_bytes) {
      set_route("drives_upload");
      reply_error(res, 413,
                  "package of " + std::to_string(*len) + " bytes exceeds the upload limit of " +
                      std::to_string(cfg.max_upload_bytes) + " bytes",
                  "Content-Length", {{"limit_bytes", cfg.max_upload_bytes}});
      res.set_header("Connection", "close");
      return 413;
    }
    return 100;
  });
  http.set_logger([this](const httplib::Request& req, const httplib::Response& res) {
    const double seconds = t_start == Clock::time_point{}
                               ? 0.0
                               : std::chrono::duration<double>(Clock::now() - t_start).count();
    t_start = {};
    const char* route = t_route != nullptr ? t_route : "unmatched";
    std::uint64_t bytes = res.body.size();
    if (bytes == 0 && res.has_header("Content-Length")) {
      bytes = std::strtoull(res.get_header_value("Content-Length").c_str(), nullptr, 10);
    }
    metrics.observe_request(route, http::metric_method(req.method), res.status, seconds, bytes);
    if (cfg.log_requests) {
      char buf[96];
      std::snprintf(buf, sizeof buf, " %d %llu B %.2f ms", res.status,
                    static_cast<unsigned long long>(bytes), seconds * 1e3);
      log("info", req.remote_addr + " " + req.method + " " + req.path + buf);
    }
  });
  http.set_error_handler([](const httplib::Request& req, httplib::Response& res) {
    if (!res.body.empty()) return;
    if (res.status == 404) {
      reply_error(res, 404,
                  "no such endpoint: " + http::escape_for_log(req.method, 16) + " " +
                      http::escape_for_log(req.path, 256));
    } else if (res.status == 413) {
      reply_error(res, 413, "request body too large");
    } else if (res.status >= 400) {
      reply_error(res, res.status, "request failed with HTTP status " + std::to_string(res.status));
    }
  });
  http.set_exception_handler(
      [this](const httplib::Request& req, httplib::Response& res, std::exception_ptr ep) {
        try {
          std::rethrow_exception(ep);
        } catch (const StorageFullError& e) {
          // Nothing of the write was kept (the store rolls back); reads keep working.
          log("warn", "storage full in " + req.method + " " + req.path + ": " + e.what());
          reply_error(res, 507, kStorageFullMessage);
        } catch (const NotFoundError& e) {
          reply_error(res, 404, e.what());
        } catch (const ConflictError& e) {
          reply_error(res, 409, e.what());
        } catch (const ValidationError& e) {
          reply_error(res, 422, e.what());
        } catch (const FormatError& e) {
          reply_error(res, 400, e.what());
        } catch (const std::exception& e) {
          // The detail goes to the log only: a client learns that it failed, not why.
          const std::uint64_t id = ++internal_errors;
          log("error", "internal error #" + std::to_string(id) + " in " + req.method + " " +
                           req.path + ": " + e.what());
          reply_error(res, 500, "internal error (logged as #" + std::to_string(id) + ")");
        } catch (...) {
          const std::uint64_t id = ++internal_errors;
          log("error", "internal error #" + std::to_string(id) + " in " + req.method + " " +
                           req.path + ": unknown exception");
          reply_error(res, 500, "internal error (logged as #" + std::to_string(id) + ")");
        }
      });

  // cpp-httplib tries the patterns (std::regex) in registration order: the hot tile
  // routes go first.
  register_tile_routes();

  http.Options(R"(/.*)", [](const httplib::Request&, httplib::Response& res) {
    set_route("preflight");
    res.status = 204;
    res.set_header("Access-Control-Allow-Methods", "GET, HEAD, POST, PATCH, DELETE, OPTIONS");
    res.set_header("Access-Control-Allow-Headers",
                   "Authorization, Content-Type, If-None-Match, Accept-Encoding, Upload-Offset, "
                   "Upload-Length, Upload-Sha256");
    res.set_header("Access-Control-Max-Age", "86400");
    res.set_header("Allow", "GET, HEAD, POST, PATCH, DELETE, OPTIONS");
  });

  http.Get("/health", [this](const httplib::Request&, httplib::Response& res) {
    set_route("health");
    nlohmann::json j{{"status", "ok"}, {"service", "polmap"}, {"version", "0.1.0"}};
    try {
      const auto v = store.current_map_version();
      j["current_map_version"] = v ? nlohmann::json(*v) : nlohmann::json(nullptr);
    } catch (const std::exception& e) {
      reply_json(res, 503, {{"status", "unavailable"}, {"error", e.what()}});
      return;
    }
    {
      std::lock_guard lock(build_mutex);
      j["builds_queued"] = build_queue.size();
      j["build_running"] = build_running;
    }
    reply_json(res, 200, j);
  });

  http.Get("/metrics", [this](const httplib::Request& req, httplib::Response& res) {
    if (!require(req, res, Access::ReadDrives)) return;
    set_route("metrics");
    std::string out = metrics.render();
    const StoreStats s = store.stats();
    auto gauge = [&out](const char* name, const char* help, double v) {
      char buf[256];
      std::snprintf(buf, sizeof buf, "# HELP %s %s\n# TYPE %s gauge\n%s %.17g\n", name, help, name,
                    name, v);
      out += buf;
    };
    gauge("polmap_drives", "Drives in the store.", static_cast<double>(s.drives));
    gauge("polmap_point_candidates", "Point candidates in the store.",
          static_cast<double>(s.point_candidates));
    gauge("polmap_line_candidates", "Line candidates in the store.",
          static_cast<double>(s.line_candidates));
    gauge("polmap_map_versions", "Map versions (any status).", static_cast<double>(s.map_versions));
    gauge("polmap_current_map_version", "Current map version (0: none).",
          static_cast<double>(s.current_version.value_or(0)));
    gauge("polmap_current_point_landmarks", "Point landmarks of the current version.",
          static_cast<double>(s.current_point_landmarks));
    gauge("polmap_current_line_landmarks", "Line landmarks of the current version.",
          static_cast<double>(s.current_line_landmarks));
    gauge("polmap_current_tiles", "Localization tiles of the current version.",
          static_cast<double>(s.current_tiles));
    gauge("polmap_tile_blob_bytes", "Bytes of stored tile blobs.",
          static_cast<double>(s.tile_blob_bytes));
    gauge("polmap_database_bytes", "Size of the database.", static_cast<double>(s.database_bytes));
    gauge("polmap_drive_store_bytes", "Size of the stored packages.",
          static_cast<double>(s.drive_store_bytes));
    {
      std::lock_guard lock(build_mutex);
      gauge("polmap_map_builds_queued", "Map builds waiting.",
            static_cast<double>(build_queue.size()));
      gauge("polmap_map_build_running", "1 while a map build runs.", build_running ? 1.0 : 0.0);
    }
    res.set_content(out, "text/plain; version=0.0.4");
    res.set_header("Cache-Control", "no-store");
  });

  register_drive_routes();
  register_run_routes();
  register_upload_routes();
  register_map_routes();
  register_gis_routes();
  register_hdmap_routes();
  register_console_routes();
}

// ---- Server ---------------------------------------------------------------------------------

Server::Server(MapStore& store, ServerConfig config)
    : impl_(std::make_unique<Impl>(store, std::move(config))) {}

Server::~Server() { stop(); }

void Server::listen(const std::string& host, int port) {
  Impl& s = *impl_;
  int bound = -1;
  if (port == 0) {
    bound = s.http.bind_to_any_port(host);
  } else if (s.http.bind_to_port(host, port)) {
    bound = port;
  }
  if (bound <= 0) {
    throw IoError("cannot listen on " + host + ":" + std::to_string(port) + ": " +
                  std::strerror(errno));
  }
  s.port = bound;
  {
    std::lock_guard lock(s.state_mutex);
    s.listening = true;
  }
  s.state_cv.notify_all();
  s.log(
      "info",
      std::string(s.cfg.tls_cert_file.empty() ? "listening on http://" : "listening on https://") +
          host + ":" + std::to_string(bound) + " (" + std::to_string(s.cfg.threads) + " threads)");
  if (!s.stopping) s.http.listen_after_bind();
  // Requests in flight have finished (the pool joined). Now the builds.
  std::deque<Impl::BuildJob> dropped;
  {
    std::lock_guard lock(s.build_mutex);
    s.build_shutdown = true;
    dropped.swap(s.build_queue);
    if (s.build_running) s.log("info", "waiting for the running map build to finish");
  }
  s.build_cv.notify_all();
  for (const auto& job : dropped) {
    try {
      s.store.fail_map_version(job.version, "cancelled: the server stopped before the build ran");
    } catch (const std::exception& e) {
      s.log("warn", e.what());
    }
  }
  if (s.build_thread.joinable()) s.build_thread.join();
  {
    std::lock_guard lock(s.state_mutex);
    s.listening = false;
  }
  s.state_cv.notify_all();
  s.log("info", "stopped");
}

void Server::stop() {
  Impl& s = *impl_;
  s.stopping = true;
  // listen() may be between bind and accept loop; wait briefly for it to run so
  // httplib's stop() reaches the accept loop.
  for (int i = 0; i < 400; ++i) {
    {
      std::lock_guard lock(s.state_mutex);
      if (!s.listening) break;
    }
    if (s.http.is_running()) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  s.http.stop();
}

int Server::bound_port() const { return impl_->port; }

bool Server::wait_until_listening(std::chrono::milliseconds timeout) const {
  std::unique_lock lock(impl_->state_mutex);
  return impl_->state_cv.wait_for(lock, timeout, [this] { return impl_->listening; });
}

void Server::wait_for_builds() const {
  std::unique_lock lock(impl_->build_mutex);
  impl_->build_cv.wait(lock, [this] {
    return (impl_->build_queue.empty() && !impl_->build_running) || impl_->build_shutdown;
  });
}

}  // namespace polmap::mapping
