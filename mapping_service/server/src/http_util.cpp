#include "http_util.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <ctime>

#include "polmap/schema/errors.hpp"
#include "polmap/util/text.hpp"

namespace polmap::mapping::http {
namespace {

using util::trim;

std::string_view strip_weak(std::string_view tag) {
  if (tag.size() >= 2 && (tag.substr(0, 2) == "W/" || tag.substr(0, 2) == "w/")) {
    tag.remove_prefix(2);
  }
  return tag;
}

bool iequals(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return std::tolower(static_cast<unsigned char>(x)) ==
                  std::tolower(static_cast<unsigned char>(y));
         });
}

}  // namespace

namespace {

/// At most kMaxErrorText bytes of `s` (cut at a UTF-8 character boundary, "..." added): an
/// error message may quote the request (a 10 MB drive id), the reply does not echo it all.
constexpr std::size_t kMaxErrorText = 1024;
std::string capped(std::string_view s) {
  if (s.size() <= kMaxErrorText) return std::string(s);
  std::size_t n = kMaxErrorText;
  while (n > 0 && (static_cast<unsigned char>(s[n]) & 0xC0U) == 0x80U) --n;
  return std::string(s.substr(0, n)) + "...";
}

}  // namespace

std::string json_error(std::string_view message, std::string_view field,
                       const nlohmann::json& extra) {
  nlohmann::json j = nlohmann::json::object();
  j["error"] = capped(message);
  if (!field.empty()) j["field"] = capped(field);
  if (extra.is_object()) {
    for (const auto& [k, v] : extra.items()) {
      j[k] = v.is_string() ? nlohmann::json(capped(v.get<std::string>())) : v;
    }
  }
  // Invalid UTF-8 (it cannot come from a parsed JSON request, but a message may quote other
  // bytes) is replaced, never thrown about while an error is being answered.
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

bool if_none_match_matches(std::string_view header, std::string_view etag_quoted) {
  const std::string_view want = strip_weak(etag_quoted);
  std::size_t pos = 0;
  while (pos <= header.size()) {
    const std::size_t comma = header.find(',', pos);
    const std::string_view item =
        trim(header.substr(pos, comma == std::string_view::npos ? header.npos : comma - pos));
    if (item == "*") return true;
    if (!item.empty() && strip_weak(item) == want) return true;
    if (comma == std::string_view::npos) break;
    pos = comma + 1;
  }
  return false;
}

bool accepts_gzip(std::string_view accept_encoding) {
  bool star = false, gzip = false, gzip_listed = false;
  std::size_t pos = 0;
  while (pos <= accept_encoding.size()) {
    const std::size_t comma = accept_encoding.find(',', pos);
    std::string_view item = trim(accept_encoding.substr(
        pos, comma == std::string_view::npos ? accept_encoding.npos : comma - pos));
    double q = 1.0;
    if (const std::size_t semi = item.find(';'); semi != std::string_view::npos) {
      std::string_view param = trim(item.substr(semi + 1));
      item = trim(item.substr(0, semi));
      if (param.size() > 2 && (param[0] == 'q' || param[0] == 'Q') && param[1] == '=') {
        q = std::strtod(std::string(param.substr(2)).c_str(), nullptr);
      }
    }
    if (iequals(item, "gzip") || iequals(item, "x-gzip")) {
      gzip_listed = true;
      gzip = q > 0.0;
    } else if (item == "*") {
      star = q > 0.0;
    }
    if (comma == std::string_view::npos) break;
    pos = comma + 1;
  }
  return gzip_listed ? gzip : star;
}

std::string iso8601_now() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[96];
  std::snprintf(buf, sizeof buf, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", tm.tm_year + 1900,
                tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, static_cast<int>(ms));
  return buf;
}

std::string_view metric_method(std::string_view method) {
  for (std::string_view m : {"GET", "HEAD", "POST", "PUT", "DELETE", "OPTIONS", "PATCH"}) {
    if (method == m) return m;
  }
  return "other";
}

std::optional<std::int64_t> parse_int(std::string_view s) {
  std::int64_t v = 0;
  if (s.empty()) return std::nullopt;
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc{} || p != s.data() + s.size()) return std::nullopt;
  return v;
}

std::optional<tiles::GeoBox> parse_bbox(std::string_view s) {
  double v[4];
  std::size_t pos = 0;
  for (int i = 0; i < 4; ++i) {
    const std::size_t comma = i < 3 ? s.find(',', pos) : s.size();
    if (comma == std::string_view::npos) return std::nullopt;
    const std::string_view item = trim(s.substr(pos, comma - pos));
    const auto [p, ec] = std::from_chars(item.data(), item.data() + item.size(), v[i]);
    if (ec != std::errc{} || p != item.data() + item.size() || !std::isfinite(v[i])) {
      return std::nullopt;
    }
    pos = comma + 1;
  }
  tiles::GeoBox b{v[1], v[0], v[3], v[2]};
  if (b.min_lat_deg < -90 || b.max_lat_deg > 90 || b.min_lat_deg > b.max_lat_deg ||
      b.min_lon_deg < -180 || b.min_lon_deg > 180 || b.max_lon_deg < -180 || b.max_lon_deg > 180) {
    return std::nullopt;
  }
  return b;
}

// ---- BlobCache ------------------------------------------------------------------------------

std::shared_ptr<const CachedBlob> BlobCache::get(const std::string& key) {
  std::lock_guard lock(mutex_);
  const auto it = index_.find(key);
  if (it == index_.end()) return nullptr;
  lru_.splice(lru_.begin(), lru_, it->second);
  return it->second->second;
}

void BlobCache::put(const std::string& key, std::shared_ptr<const CachedBlob> blob) {
  const std::size_t size = blob->body.size() + blob->gzip_body.size() + key.size() + 128;
  if (size > max_bytes_ / 4) return;  // never let one entry flush the cache
  std::lock_guard lock(mutex_);
  if (const auto it = index_.find(key); it != index_.end()) {
    bytes_ -=
        it->second->second->body.size() + it->second->second->gzip_body.size() + key.size() + 128;
    lru_.erase(it->second);
    index_.erase(it);
  }
  lru_.emplace_front(key, std::move(blob));
  index_[key] = lru_.begin();
  bytes_ += size;
  while (bytes_ > max_bytes_ && !lru_.empty()) {
    const Entry& last = lru_.back();
    bytes_ -= last.second->body.size() + last.second->gzip_body.size() + last.first.size() + 128;
    index_.erase(last.first);
    lru_.pop_back();
  }
}

void BlobCache::clear() {
  std::lock_guard lock(mutex_);
  lru_.clear();
  index_.clear();
  bytes_ = 0;
}

// ---- Metrics --------------------------------------------------------------------------------

std::string prom_label(std::string_view v) {
  std::string out;
  for (char c : v) {
    if (c == '\\' || c == '"') {
      out.push_back('\\');
      out.push_back(c);
    } else if (c == '\n') {
      out += "\\n";
    } else {
      out.push_back(c);
    }
  }
  return out;
}

void Metrics::observe_request(std::string_view route, std::string_view method, int status,
                              double seconds, std::uint64_t bytes) {
  std::lock_guard lock(mutex_);
  ++requests_[{std::string(route), std::string(method), status}];
  Histogram& h = latency_[std::string(route)];
  std::size_t b = 0;
  while (b < kNumBuckets && seconds > kBuckets[b]) ++b;
  ++h.counts[b];
  h.sum += seconds;
  ++h.count;
  response_bytes_[std::string(route)] += bytes;
}

void Metrics::tile_served(std::string_view kind, int status) {
  std::lock_guard lock(mutex_);
  ++tiles_[{std::string(kind), status}];
}

void Metrics::upload(std::string_view outcome, std::uint64_t bytes) {
  std::lock_guard lock(mutex_);
  ++uploads_[std::string(outcome)];
  upload_bytes_ += bytes;
}

void Metrics::build_finished(std::string_view outcome) {
  std::lock_guard lock(mutex_);
  ++builds_[std::string(outcome)];
}

std::string Metrics::render() const {
  std::lock_guard lock(mutex_);
  std::string out;
  char buf[512];
  out += "# HELP polmap_http_requests_total HTTP requests by route, method and status.\n";
  out += "# TYPE polmap_http_requests_total counter\n";
  for (const auto& [k, n] : requests_) {
    const auto& [route, method, status] = k;
    std::snprintf(buf, sizeof buf,
                  "polmap_http_requests_total{route=\"%s\",method=\"%s\",status=\"%d\"} %llu\n",
                  prom_label(route).c_str(), prom_label(method).c_str(), status,
                  static_cast<unsigned long long>(n));
    out += buf;
  }
  out +=
      "# HELP polmap_http_request_duration_seconds Request latency (routing to response "
      "written).\n";
  out += "# TYPE polmap_http_request_duration_seconds histogram\n";
  for (const auto& [route, h] : latency_) {
    std::uint64_t cumulative = 0;
    const std::string r = prom_label(route);
    for (std::size_t b = 0; b < kNumBuckets; ++b) {
      cumulative += h.counts[b];
      std::snprintf(buf, sizeof buf,
                    "polmap_http_request_duration_seconds_bucket{route=\"%s\",le=\"%g\"} %llu\n",
                    r.c_str(), kBuckets[b], static_cast<unsigned long long>(cumulative));
      out += buf;
    }
    std::snprintf(buf, sizeof buf,
                  "polmap_http_request_duration_seconds_bucket{route=\"%s\",le=\"+Inf\"} %llu\n"
                  "polmap_http_request_duration_seconds_sum{route=\"%s\"} %.6f\n"
                  "polmap_http_request_duration_seconds_count{route=\"%s\"} %llu\n",
                  r.c_str(), static_cast<unsigned long long>(h.count), r.c_str(), h.sum, r.c_str(),
                  static_cast<unsigned long long>(h.count));
    out += buf;
  }
  out += "# HELP polmap_http_response_bytes_total Response body bytes by route.\n";
  out += "# TYPE polmap_http_response_bytes_total counter\n";
  for (const auto& [route, n] : response_bytes_) {
    std::snprintf(buf, sizeof buf, "polmap_http_response_bytes_total{route=\"%s\"} %llu\n",
                  prom_label(route).c_str(), static_cast<unsigned long long>(n));
    out += buf;
  }
  out +=
      "# HELP polmap_tiles_served_total Tiles answered, by kind and status (200, 204, 304, 404).\n";
  out += "# TYPE polmap_tiles_served_total counter\n";
  for (const auto& [k, n] : tiles_) {
    std::snprintf(buf, sizeof buf, "polmap_tiles_served_total{kind=\"%s\",status=\"%d\"} %llu\n",
                  prom_label(k.first).c_str(), k.second, static_cast<unsigned long long>(n));
    out += buf;
  }
  out += "# HELP polmap_uploads_total Drive package uploads by outcome.\n";
  out += "# TYPE polmap_uploads_total counter\n";
  for (const auto& [k, n] : uploads_) {
    std::snprintf(buf, sizeof buf, "polmap_uploads_total{outcome=\"%s\"} %llu\n",
                  prom_label(k).c_str(), static_cast<unsigned long long>(n));
    out += buf;
  }
  out += "# HELP polmap_upload_bytes_total Bytes received in drive package uploads.\n";
  out += "# TYPE polmap_upload_bytes_total counter\n";
  std::snprintf(buf, sizeof buf, "polmap_upload_bytes_total %llu\n",
                static_cast<unsigned long long>(upload_bytes_));
  out += buf;
  out += "# HELP polmap_map_builds_total Map builds finished, by outcome.\n";
  out += "# TYPE polmap_map_builds_total counter\n";
  for (const auto& [k, n] : builds_) {
    std::snprintf(buf, sizeof buf, "polmap_map_builds_total{outcome=\"%s\"} %llu\n",
                  prom_label(k).c_str(), static_cast<unsigned long long>(n));
    out += buf;
  }
  return out;
}

}  // namespace polmap::mapping::http
