// manifest.json of a drive package: writer and strict reader; package error types.
#include <cmath>

#include "package_internal.hpp"
#include "polmap/schema/json.hpp"

namespace polmap::mapping {

namespace fs = std::filesystem;
using nlohmann::json;

// ------------------------------------------------------------------------ errors

namespace {
std::string format_error_message(const std::string& file, const std::string& field,
                                 const std::string& message) {
  if (field.empty()) return file + ": " + message;
  return file + ": field '" + field + "': " + message;
}
}  // namespace

std::string PackageError::what() const { return format_error_message(file, field, message); }

PackageFormatError::PackageFormatError(std::string file, std::string field, std::string message)
    : FormatError(format_error_message(file, field, message)),
      error_{std::move(file), std::move(field), std::move(message), 400} {}

PackageValidationError::PackageValidationError(std::string file, std::string field,
                                               std::string message, int http_status)
    : ValidationError(format_error_message(file, field, message)),
      error_{std::move(file), std::move(field), std::move(message), http_status} {}

std::string sha256_hex(std::string_view bytes) { return util::sha256_hex(bytes); }

namespace detail {

// ------------------------------------------------------------------------ manifest JSON

json manifest_to_json(const DriveManifest& m) {
  json files = json::array();
  for (const auto& f : m.files) {
    files.push_back({{"name", f.name}, {"size_bytes", f.size_bytes}, {"sha256", f.sha256}});
  }
  const int q = pol_dimension(m.pol_level);
  json j{{"format", "polmap.drive_package"},
         {"format_version", m.format_version},
         {"drive_id", m.drive_id},
         {"vehicle_id", m.vehicle_id},
         {"world", m.world},
         {"producer", m.producer},
         {"start_time_s", m.start_time_s},
         {"end_time_s", m.end_time_s},
         {"distance_m", m.distance_m},
         {"origin", m.origin},
         {"crs_proj", m.crs_proj},
         {"sensors", m.sensors},
         {"pol_level", std::string(to_string(m.pol_level))},
         {"q", q},
         {"cell_size_m", m.cell_size_m},
         {"counts",
          {{"points", m.counts.points},
           {"lines", m.counts.lines},
           {"trajectory_samples", m.counts.trajectory_samples}}},
         {"files", files}};
  if (m.has_gridmap) {
    json g{{"file", kGridmapFileName},           {"width", m.gridmap.width},
           {"height", m.gridmap.height},         {"origin_x_m", m.gridmap.origin_x_m},
           {"origin_y_m", m.gridmap.origin_y_m}, {"num_bands", m.gridmap.num_bands},
           {"block_size", m.gridmap.block_size}};
    if (m.gridmap.compact) {
      const GridmapCodecConfig& c = m.gridmap.codec;
      g["encoding"] = "compact";
      g["noise_power"] = m.gridmap.noise_power;
      g["codec"] = {
          {"relative_step", c.relative_step}, {"zero_step_noise", c.zero_step_noise},
          {"power_step", c.power_step},       {"offdiag_min_snr_db", c.offdiag_min_snr_db},
          {"floor_snr_db", c.floor_snr_db},   {"empty_count_bits", c.empty_count_bits}};
      g["bands"] = compact_gridmap_band_names(m.pol_level);
    } else {
      g["mantissa_bits"] = m.gridmap.mantissa_bits;
      g["bands"] = gridmap_band_names(m.pol_level);
    }
    j["gridmap"] = std::move(g);
  }
  return j;
}

namespace {

constexpr const char* kManifest = "manifest.json";

/// Strict field access for manifest.json: missing required fields are schema violations
/// (422), wrong JSON types are format errors (400); `prefix` builds the dotted field path.
class Fields {
 public:
  Fields(const json& j, std::string prefix) : j_(j), prefix_(std::move(prefix)) {}

  [[nodiscard]] std::string path(const std::string& key) const {
    return prefix_.empty() ? key : prefix_ + "." + key;
  }
  [[nodiscard]] const json* find(const std::string& key) const {
    const auto it = j_.find(key);
    return it == j_.end() ? nullptr : &*it;
  }
  const json& require(const std::string& key) const {
    const json* v = find(key);
    if (v == nullptr) throw PackageValidationError(kManifest, path(key), "missing required field");
    return *v;
  }
  [[nodiscard]] std::string type_error(const std::string& expected, const json& v) const {
    return std::string("expected ") + expected + ", got " + v.type_name();
  }
  double number(const std::string& key, bool required = true, double def = 0.0) const {
    const json* v = required ? &require(key) : find(key);
    if (v == nullptr) return def;
    if (!v->is_number()) throw PackageFormatError(kManifest, path(key), type_error("number", *v));
    const double d = v->get<double>();
    if (!std::isfinite(d)) throw PackageValidationError(kManifest, path(key), "not finite");
    return d;
  }
  std::int64_t integer(const std::string& key) const {
    const json& v = require(key);
    if (!v.is_number_integer()) {
      throw PackageFormatError(kManifest, path(key), type_error("integer", v));
    }
    if (v.is_number_unsigned() && v.get<std::uint64_t>() > static_cast<std::uint64_t>(INT64_MAX)) {
      throw PackageValidationError(kManifest, path(key), "integer out of range");
    }
    return v.get<std::int64_t>();
  }
  std::uint64_t count(const std::string& key) const {
    const std::int64_t v = integer(key);
    if (v < 0) throw PackageValidationError(kManifest, path(key), "negative count");
    return static_cast<std::uint64_t>(v);
  }
  std::string string(const std::string& key, bool required = true) const {
    const json* v = required ? &require(key) : find(key);
    if (v == nullptr) return {};
    if (!v->is_string()) throw PackageFormatError(kManifest, path(key), type_error("string", *v));
    return v->get<std::string>();
  }
  const json& object(const std::string& key) const {
    const json& v = require(key);
    if (!v.is_object()) throw PackageFormatError(kManifest, path(key), type_error("object", v));
    return v;
  }
  const json& array(const std::string& key) const {
    const json& v = require(key);
    if (!v.is_array()) throw PackageFormatError(kManifest, path(key), type_error("array", v));
    return v;
  }

 private:
  const json& j_;
  std::string prefix_;
};

bool valid_id(const std::string& s) {
  if (s.empty() || s.size() > 128 || s.front() == '.') return false;
  return std::all_of(s.begin(), s.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' ||
           c == '_' || c == '-';
  });
}

bool is_hex64(const std::string& s) {
  return s.size() == 64 && std::all_of(s.begin(), s.end(), [](char c) {
           return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
         });
}

}  // namespace

DriveManifest manifest_from_json(const json& j) {
  if (!j.is_object()) {
    throw PackageFormatError(kManifest, "",
                             std::string("expected a JSON object, got ") + j.type_name());
  }
  const Fields f(j, "");
  DriveManifest m;
  {
    const std::string format = f.string("format");
    if (format != "polmap.drive_package") {
      throw PackageValidationError(kManifest, "format",
                                   "expected 'polmap.drive_package', got '" + format + "'");
    }
  }
  const std::int64_t version = f.integer("format_version");
  if (version != 1 && version != 2) {
    throw PackageValidationError(
        kManifest, "format_version",
        "unsupported version " + std::to_string(version) + " (this build reads 1 and 2)");
  }
  m.format_version = static_cast<std::uint32_t>(version);
  m.drive_id = f.string("drive_id");
  if (!valid_id(m.drive_id)) {
    throw PackageValidationError(kManifest, "drive_id",
                                 "'" + m.drive_id +
                                     "' is not 1..128 characters of [A-Za-z0-9._-] "
                                     "(not starting with '.')");
  }
  m.vehicle_id = f.string("vehicle_id");
  if (!valid_id(m.vehicle_id)) {
    throw PackageValidationError(
        kManifest, "vehicle_id",
        "'" + m.vehicle_id + "' is not 1..128 characters of [A-Za-z0-9._-]");
  }
  m.world = f.string("world", false);
  m.producer = f.string("producer", false);
  m.start_time_s = f.number("start_time_s");
  m.end_time_s = f.number("end_time_s");
  if (m.end_time_s < m.start_time_s) {
    throw PackageValidationError(kManifest, "end_time_s", "before start_time_s");
  }
  m.distance_m = f.number("distance_m");
  if (m.distance_m < 0) throw PackageValidationError(kManifest, "distance_m", "negative");

  {
    const Fields o(f.object("origin"), "origin");
    m.origin.lat_deg = o.number("lat_deg");
    m.origin.lon_deg = o.number("lon_deg");
    m.origin.alt_m = o.number("alt_m", false);
    if (std::abs(m.origin.lat_deg) > 85.0) {
      throw PackageValidationError(kManifest, "origin.lat_deg", "outside [-85, 85] degrees");
    }
    if (std::abs(m.origin.lon_deg) > 180.0) {
      throw PackageValidationError(kManifest, "origin.lon_deg", "outside [-180, 180] degrees");
    }
  }
  m.crs_proj = f.string("crs_proj");
  if (!is_local_frame_proj(m.crs_proj, m.origin)) {
    throw PackageValidationError(
        kManifest, "crs_proj",
        "'" + m.crs_proj + "' is not the drive frame (LocalFrame) of 'origin'");
  }

  {
    const json& sensors = f.array("sensors");
    if (sensors.empty()) throw PackageValidationError(kManifest, "sensors", "no sensors");
    std::vector<int> ids;
    for (std::size_t i = 0; i < sensors.size(); ++i) {
      const std::string p = "sensors[" + std::to_string(i) + "]";
      if (!sensors[i].is_object()) {
        throw PackageFormatError(kManifest, p,
                                 std::string("expected object, got ") + sensors[i].type_name());
      }
      const Fields s(sensors[i], p);
      s.integer("sensor_id");
      s.object("T_vehicle_sensor");
      SensorMount mount;
      try {
        from_json(sensors[i], mount);
      } catch (const JsonFieldError& e) {
        throw PackageFormatError(kManifest, p + "." + e.path(), e.reason());
      }
      if (std::find(ids.begin(), ids.end(), mount.sensor_id) != ids.end()) {
        throw PackageValidationError(kManifest, p + ".sensor_id",
                                     "duplicate sensor id " + std::to_string(mount.sensor_id));
      }
      ids.push_back(mount.sensor_id);
      m.sensors.push_back(std::move(mount));
    }
  }

  {
    const std::string level = f.string("pol_level");
    const auto parsed = parse_pol_level(level);
    if (!parsed) {
      std::string names;
      for (const auto& n : pol_level_names()) names += (names.empty() ? "" : ", ") + n;
      throw PackageValidationError(kManifest, "pol_level",
                                   "unknown level '" + level + "' (expected one of " + names + ")");
    }
    m.pol_level = *parsed;
    const std::int64_t q = f.integer("q");
    if (q != pol_dimension(m.pol_level)) {
      throw PackageValidationError(kManifest, "q",
                                   std::to_string(q) + " does not match pol_level '" + level +
                                       "' (q = " + std::to_string(pol_dimension(m.pol_level)) +
                                       ")");
    }
  }
  m.cell_size_m = f.number("cell_size_m");
  if (!(m.cell_size_m >= 0.01 && m.cell_size_m <= 10.0)) {
    throw PackageValidationError(kManifest, "cell_size_m", "outside [0.01, 10] m");
  }

  // Format 2 may leave the gridmap out (a landmarks-only package).
  m.has_gridmap = version == 1 || f.find("gridmap") != nullptr;
  if (m.has_gridmap) {
    const Fields g(f.object("gridmap"), "gridmap");
    const bool compact = version >= 2;
    m.gridmap.compact = compact;
    if (g.string("file") != kGridmapFileName) {
      throw PackageValidationError(kManifest, "gridmap.file",
                                   std::string("expected '") + kGridmapFileName + "'");
    }
    const auto w = g.integer("width");
    const auto h = g.integer("height");
    if (w < 1 || h < 1 || w > 1'000'000 || h > 1'000'000) {
      throw PackageValidationError(kManifest,
                                   w < 1 || w > 1'000'000 ? "gridmap.width" : "gridmap.height",
                                   "outside [1, 1000000] cells");
    }
    m.gridmap.width = static_cast<int>(w);
    m.gridmap.height = static_cast<int>(h);
    m.gridmap.origin_x_m = g.number("origin_x_m");
    m.gridmap.origin_y_m = g.number("origin_y_m");
    const auto bands = g.integer("num_bands");
    const int q = pol_dimension(m.pol_level);
    const int want_bands = (compact ? 3 : 1) + q * q;
    if (bands != want_bands) {
      throw PackageValidationError(kManifest, "gridmap.num_bands",
                                   std::to_string(bands) + " bands, pol_level '" +
                                       std::string(to_string(m.pol_level)) + "' needs " +
                                       std::to_string(want_bands));
    }
    m.gridmap.num_bands = static_cast<int>(bands);
    const auto block = g.integer("block_size");
    if (block != kGridmapBlockSize) {
      throw PackageValidationError(kManifest, "gridmap.block_size",
                                   "expected " + std::to_string(kGridmapBlockSize));
    }
    m.gridmap.block_size = static_cast<int>(block);
    if (compact) {
      if (g.string("encoding") != "compact") {
        throw PackageValidationError(kManifest, "gridmap.encoding", "expected 'compact'");
      }
      m.gridmap.noise_power = g.number("noise_power");
      if (!(m.gridmap.noise_power > 0.0 && m.gridmap.noise_power < 1e30)) {
        throw PackageValidationError(kManifest, "gridmap.noise_power", "not in (0, 1e30)");
      }
      const Fields c(g.object("codec"), "gridmap.codec");
      GridmapCodecConfig& cc = m.gridmap.codec;
      const auto ranged = [&](const char* key, double lo, double hi) {
        const double v = c.number(key);
        if (!(v >= lo && v <= hi)) {
          throw PackageValidationError(
              kManifest, std::string("gridmap.codec.") + key,
              "outside [" + json(lo).dump() + ", " + json(hi).dump() + "]");
        }
        return v;
      };
      cc.relative_step = ranged("relative_step", 0.001, 0.05);
      cc.zero_step_noise = ranged("zero_step_noise", 0.001, 1.0);
      cc.power_step = ranged("power_step", 1e-4, 0.05);
      cc.offdiag_min_snr_db = ranged("offdiag_min_snr_db", -100.0, 100.0);
      cc.floor_snr_db = ranged("floor_snr_db", -100.0, 100.0);
      const auto bits = c.integer("empty_count_bits");
      if (bits < 1 || bits > 16) {
        throw PackageValidationError(kManifest, "gridmap.codec.empty_count_bits",
                                     "outside [1, 16]");
      }
      cc.empty_count_bits = static_cast<int>(bits);
    }
    // Optional (absent in packages written before it existed: lossless).
    if (!compact && g.find("mantissa_bits") != nullptr) {
      const auto bits = g.integer("mantissa_bits");
      if (bits < 1 || bits > 23) {
        throw PackageValidationError(kManifest, "gridmap.mantissa_bits", "outside [1, 23]");
      }
      m.gridmap.mantissa_bits = static_cast<int>(bits);
    }
    const json& names = g.array("bands");
    if (names !=
        json(compact ? compact_gridmap_band_names(m.pol_level) : gridmap_band_names(m.pol_level))) {
      throw PackageValidationError(
          kManifest, "gridmap.bands",
          "band names do not match pol_level '" + std::string(to_string(m.pol_level)) + "'");
    }
  }
  {
    const Fields c(f.object("counts"), "counts");
    m.counts.points = c.count("points");
    m.counts.lines = c.count("lines");
    m.counts.trajectory_samples = c.count("trajectory_samples");
  }
  {
    const json& files = f.array("files");
    std::vector<std::string> expected;
    if (m.has_gridmap) expected.push_back(kGridmapFileName);
    expected.push_back(version >= 2 ? kCandidatesBinFileName : kCandidatesFileName);
    for (std::size_t i = 0; i < files.size(); ++i) {
      const std::string p = "files[" + std::to_string(i) + "]";
      if (!files[i].is_object()) {
        throw PackageFormatError(kManifest, p,
                                 std::string("expected object, got ") + files[i].type_name());
      }
      const Fields fe(files[i], p);
      PackageFileEntry e;
      e.name = fe.string("name");
      e.size_bytes = fe.count("size_bytes");
      e.sha256 = fe.string("sha256");
      if (!is_hex64(e.sha256)) {
        throw PackageValidationError(kManifest, p + ".sha256", "not 64 lower-case hex digits");
      }
      m.files.push_back(std::move(e));
    }
    for (std::size_t i = 0; i < std::max(files.size(), expected.size()); ++i) {
      if (i >= m.files.size()) {
        throw PackageValidationError(kManifest, "files", "entry for '" + expected[i] + "' missing");
      }
      if (i >= expected.size() || m.files[i].name != expected[i]) {
        throw PackageValidationError(
            kManifest, "files[" + std::to_string(i) + "].name",
            "unexpected file '" + m.files[i].name + "' (expected " +
                (i < expected.size() ? "'" + expected[i] + "'" : std::string("no more entries")) +
                ")");
      }
    }
  }
  return m;
}

}  // namespace detail

DriveManifest parse_manifest(std::string_view json_text) {
  json j;
  try {
    j = json::parse(json_text);
  } catch (const json::exception& e) {
    throw PackageFormatError(kManifestFileName, "", std::string("not valid JSON: ") + e.what());
  }
  return detail::manifest_from_json(j);
}

}  // namespace polmap::mapping
