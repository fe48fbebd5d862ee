// The localization run report's parser and canonical encoder (schema/localization_run.md).
#include "polmap/schema/localization_run.hpp"

#include <array>
#include <cmath>
#include <nlohmann/json.hpp>
#include <span>

namespace polmap {
namespace {

using json = nlohmann::json;

constexpr std::array<std::string_view, kRunStatusCount> kStatusNames{"initializing", "tracking",
                                                                     "degraded", "lost"};
constexpr std::array<std::string_view, 3> kReferenceNames{"none", "simulator-truth", "gnss-ins"};
constexpr std::array<std::string_view, 6> kPolNames{"full", "ll-lr", "hh-vv", "lr", "rr", "hh"};

/// Bounds of plausible values: beyond them a report is broken or hostile.
constexpr double kMaxAbsTimeS = 1e10;   // UNIX seconds until year 2286, or relative
constexpr double kMaxVarianceM2 = 1e8;  // σ 10 km: the localizer never reports more
constexpr double kMaxYawVarianceRad2 = 1e3;
constexpr double kMaxAbsErrorM = 1e5;
constexpr std::int64_t kMaxMapVersion = std::int64_t{1} << 53;

struct Refusal {
  LocalizationRunError error;
};

[[noreturn]] void refuse(std::string field, std::string message, int status = 422) {
  throw Refusal{{std::move(field), std::move(message), status}};
}

double number(const json& j, const char* key, const std::string& where) {
  const auto it = j.find(key);
  const std::string field = where + key;
  if (it == j.end()) refuse(field, "missing");
  if (!it->is_number()) refuse(field, "must be a number");
  const double v = it->get<double>();
  if (!std::isfinite(v)) refuse(field, "must be finite");
  return v;
}

std::optional<double> optional_number(const json& j, const char* key, const std::string& where) {
  if (!j.contains(key) || j.at(key).is_null()) return std::nullopt;
  return number(j, key, where);
}

// A received key as it appears in an error: the empty key as "" (an error must name a field),
// control bytes as '?', and at most 64 bytes, since the key is hostile and echoed to the client.
std::string key_for_error(std::string_view k) {
  if (k.empty()) return "\"\"";
  std::string out;
  for (const char c : k.substr(0, 64)) out += (static_cast<unsigned char>(c) < 0x20) ? '?' : c;
  if (k.size() > 64) out += "...";
  return out;
}

void known_keys(const json& j, std::initializer_list<std::string_view> keys,
                const std::string& where) {
  for (const auto& [k, v] : j.items()) {
    bool known = false;
    for (const std::string_view n : keys) known = known || k == n;
    if (!known) refuse(where + key_for_error(k), "unknown field");
  }
}

template <std::size_t N>
int name_index(const std::array<std::string_view, N>& names, std::string_view s) {
  for (std::size_t i = 0; i < N; ++i) {
    if (names[i] == s) return static_cast<int>(i);
  }
  return -1;
}

std::string names_list(std::span<const std::string_view> names) {
  std::string out;
  for (const std::string_view n : names) out += (out.empty() ? "" : ", ") + std::string(n);
  return out;
}

LocalizationRunSample parse_sample(const json& s, const std::string& where) {
  if (!s.is_object()) refuse(where.substr(0, where.size() - 1), "must be an object");
  known_keys(s,
             {"t_s", "lat_deg", "lon_deg", "yaw_enu_deg", "status", "cov_xx_m2", "cov_xy_m2",
              "cov_yy_m2", "cov_yaw_rad2", "err_long_m", "err_lat_m", "err_rot_deg"},
             where);
  LocalizationRunSample out;
  out.t_s = number(s, "t_s", where);
  if (std::abs(out.t_s) > kMaxAbsTimeS) refuse(where + "t_s", "out of range");
  out.lat_deg = number(s, "lat_deg", where);
  if (std::abs(out.lat_deg) > 85.0) refuse(where + "lat_deg", "must be within ±85°");
  out.lon_deg = number(s, "lon_deg", where);
  if (std::abs(out.lon_deg) > 180.0) refuse(where + "lon_deg", "must be within ±180°");
  out.yaw_enu_deg = number(s, "yaw_enu_deg", where);
  if (out.yaw_enu_deg <= -180.0 || out.yaw_enu_deg > 180.0) {
    refuse(where + "yaw_enu_deg", "must be within (-180, 180]");
  }
  const auto st = s.find("status");
  if (st == s.end() || !st->is_string()) refuse(where + "status", "must be a string");
  const int si = name_index(kStatusNames, st->get_ref<const std::string&>());
  if (si < 0) refuse(where + "status", "must be one of " + names_list(kStatusNames));
  out.status = static_cast<RunStatus>(si);
  out.cov_xx_m2 = number(s, "cov_xx_m2", where);
  out.cov_xy_m2 = number(s, "cov_xy_m2", where);
  out.cov_yy_m2 = number(s, "cov_yy_m2", where);
  out.cov_yaw_rad2 = number(s, "cov_yaw_rad2", where);
  if (out.cov_xx_m2 < 0 || out.cov_xx_m2 > kMaxVarianceM2)
    refuse(where + "cov_xx_m2", "out of range");
  if (out.cov_yy_m2 < 0 || out.cov_yy_m2 > kMaxVarianceM2)
    refuse(where + "cov_yy_m2", "out of range");
  if (out.cov_yaw_rad2 < 0 || out.cov_yaw_rad2 > kMaxYawVarianceRad2) {
    refuse(where + "cov_yaw_rad2", "out of range");
  }
  // Positive semi-definite (with rounding slack): a covariance, not three numbers.
  if (out.cov_xy_m2 * out.cov_xy_m2 > out.cov_xx_m2 * out.cov_yy_m2 * (1.0 + 1e-6) + 1e-18) {
    refuse(where + "cov_xy_m2", "the covariance is not positive semi-definite");
  }
  const auto el = optional_number(s, "err_long_m", where);
  const auto ea = optional_number(s, "err_lat_m", where);
  const auto er = optional_number(s, "err_rot_deg", where);
  if (el.has_value() != ea.has_value() || ea.has_value() != er.has_value()) {
    refuse(where + "err_long_m", "err_long_m, err_lat_m and err_rot_deg come together");
  }
  if (el) {
    if (std::abs(*el) > kMaxAbsErrorM) refuse(where + "err_long_m", "out of range");
    if (std::abs(*ea) > kMaxAbsErrorM) refuse(where + "err_lat_m", "out of range");
    if (std::abs(*er) > 180.0) refuse(where + "err_rot_deg", "must be within ±180°");
    out.error = RunSampleError{*el, *ea, *er};
  }
  return out;
}

LocalizationRun parse_document(std::string_view bytes, const LocalizationRunLimits& limits) {
  if (bytes.size() > limits.max_bytes) {
    refuse("body", "exceeds " + std::to_string(limits.max_bytes) + " bytes", 413);
  }
  // Nesting first, by a linear scan (strings skipped): what nests deeper is refused before
  // a DOM is built. (nlohmann's parser callback could discard it too, but costs ~25 µs per
  // value: 150,000 empty samples took 3.8 s.)
  {
    int depth = 0;
    bool in_string = false, escaped = false;
    for (const char c : bytes) {
      if (in_string) {
        if (escaped) {
          escaped = false;
        } else if (c == '\\') {
          escaped = true;
        } else if (c == '"') {
          in_string = false;
        }
        continue;
      }
      if (c == '"') {
        in_string = true;
      } else if (c == '[' || c == '{') {
        if (++depth > LocalizationRunLimits::kMaxDepth) {
          refuse("body", "nested deeper than " + std::to_string(LocalizationRunLimits::kMaxDepth),
                 400);
        }
      } else if (c == ']' || c == '}') {
        --depth;
      }
    }
  }
  json j;
  try {
    j = json::parse(bytes.begin(), bytes.end());
  } catch (const json::exception& e) {  // parse_error, or out_of_range (1e400)
    refuse("body", std::string("not JSON: ") + e.what(), 400);
  }
  if (!j.is_object()) refuse("body", "must be a JSON object", 400);
  known_keys(j,
             {"format", "version", "label", "map_version", "pol", "reference", "realtime_factor",
              "samples"},
             "");
  if (j.value("format", json()) != "polmap-localization-run") {
    refuse("format", "must be \"polmap-localization-run\"");
  }
  const auto ver = j.find("version");
  if (ver == j.end() || !ver->is_number_integer() || ver->get<std::int64_t>() != 1) {
    refuse("version", "must be 1 (the only version this server reads)");
  }
  LocalizationRun run;
  if (j.contains("label")) {
    const json& l = j.at("label");
    if (!l.is_string()) refuse("label", "must be a string");
    run.label = l.get<std::string>();
    if (run.label.size() > LocalizationRunLimits::kMaxLabelBytes) {
      refuse("label",
             "longer than " + std::to_string(LocalizationRunLimits::kMaxLabelBytes) + " bytes");
    }
    for (const unsigned char c : run.label) {
      if (c < 0x20 || c == 0x7f) refuse("label", "contains a control character");
    }
  }
  const auto mv = j.find("map_version");
  if (mv == j.end() || !mv->is_number_integer()) refuse("map_version", "must be an integer");
  run.map_version = mv->get<std::int64_t>();
  if (mv->is_number_unsigned() &&
      mv->get<std::uint64_t>() > static_cast<std::uint64_t>(kMaxMapVersion)) {
    refuse("map_version", "out of range");
  }
  if (run.map_version < 0 || run.map_version > kMaxMapVersion)
    refuse("map_version", "out of range");
  const auto pol = j.find("pol");
  if (pol == j.end() || !pol->is_string() ||
      name_index(kPolNames, pol->get_ref<const std::string&>()) < 0) {
    refuse("pol", "must be one of " + names_list(kPolNames));
  }
  run.pol = pol->get<std::string>();
  const auto ref = j.find("reference");
  if (ref == j.end() || !ref->is_string() ||
      name_index(kReferenceNames, ref->get_ref<const std::string&>()) < 0) {
    refuse("reference", "must be one of " + names_list(kReferenceNames));
  }
  run.reference =
      static_cast<RunReference>(name_index(kReferenceNames, ref->get_ref<const std::string&>()));
  if (auto rt = optional_number(j, "realtime_factor", "")) {
    if (*rt < 0 || *rt > 1e6) refuse("realtime_factor", "out of range");
    run.realtime_factor = *rt;
  }
  const auto samples = j.find("samples");
  if (samples == j.end() || !samples->is_array()) refuse("samples", "must be an array");
  if (samples->size() < 2) refuse("samples", "a run needs at least 2 samples");
  if (samples->size() > limits.max_samples) {
    refuse("samples", "more than " + std::to_string(limits.max_samples) + " samples", 413);
  }
  run.samples.reserve(samples->size());
  double min_lat = 90, max_lat = -90, min_lon = 180, max_lon = -180;
  bool any_error = false;
  for (std::size_t i = 0; i < samples->size(); ++i) {
    const std::string where = "samples[" + std::to_string(i) + "].";
    LocalizationRunSample s = parse_sample((*samples)[i], where);
    if (!run.samples.empty() && !(s.t_s > run.samples.back().t_s)) {
      refuse(where + "t_s", "times must increase strictly");
    }
    min_lat = std::min(min_lat, s.lat_deg);
    max_lat = std::max(max_lat, s.lat_deg);
    min_lon = std::min(min_lon, s.lon_deg);
    max_lon = std::max(max_lon, s.lon_deg);
    if (max_lat - min_lat > limits.max_span_deg || max_lon - min_lon > limits.max_span_deg) {
      refuse(where.substr(0, where.size() - 1), "the run spans more than " +
                                                    std::to_string(limits.max_span_deg) +
                                                    "° (one report is one drive)");
    }
    any_error = any_error || s.error.has_value();
    run.samples.push_back(s);
  }
  if (any_error && run.reference == RunReference::None) {
    refuse("reference", "samples carry errors, so the reference must be named");
  }
  return run;
}

}  // namespace

std::string_view to_string(RunStatus s) { return kStatusNames.at(static_cast<std::size_t>(s)); }

std::optional<RunStatus> parse_run_status(std::string_view s) {
  const int i = name_index(kStatusNames, s);
  if (i < 0) return std::nullopt;
  return static_cast<RunStatus>(i);
}

std::string_view to_string(RunReference r) {
  return kReferenceNames.at(static_cast<std::size_t>(r));
}

std::optional<RunReference> parse_run_reference(std::string_view s) {
  const int i = name_index(kReferenceNames, s);
  if (i < 0) return std::nullopt;
  return static_cast<RunReference>(i);
}

std::string LocalizationRunError::what() const { return "field '" + field + "': " + message; }

std::expected<LocalizationRun, LocalizationRunError> parse_localization_run(
    std::string_view bytes, const LocalizationRunLimits& limits) {
  try {
    return parse_document(bytes, limits);
  } catch (const Refusal& r) {
    return std::unexpected(r.error);
  } catch (const std::bad_alloc&) {
    return std::unexpected(LocalizationRunError{"body", "too large to hold", 413});
  }
}

std::string encode_localization_run(const LocalizationRun& run) {
  json j;
  j["format"] = "polmap-localization-run";
  j["version"] = 1;
  if (!run.label.empty()) j["label"] = run.label;
  j["map_version"] = run.map_version;
  j["pol"] = run.pol;
  j["reference"] = std::string(to_string(run.reference));
  if (run.realtime_factor) j["realtime_factor"] = *run.realtime_factor;
  json samples = json::array();
  for (const LocalizationRunSample& s : run.samples) {
    json o{{"t_s", s.t_s},
           {"lat_deg", s.lat_deg},
           {"lon_deg", s.lon_deg},
           {"yaw_enu_deg", s.yaw_enu_deg},
           {"status", std::string(to_string(s.status))},
           {"cov_xx_m2", s.cov_xx_m2},
           {"cov_xy_m2", s.cov_xy_m2},
           {"cov_yy_m2", s.cov_yy_m2},
           {"cov_yaw_rad2", s.cov_yaw_rad2}};
    if (s.error) {
      o["err_long_m"] = s.error->long_m;
      o["err_lat_m"] = s.error->lat_m;
      o["err_rot_deg"] = s.error->rot_deg;
    }
    samples.push_back(std::move(o));
  }
  j["samples"] = std::move(samples);
  // A parsed run is valid UTF-8; a label made on a vehicle from a file name may not be.
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

}  // namespace polmap
