#include "polmap/schema/json.hpp"

#include <cmath>
#include <limits>
#include <type_traits>

namespace polmap {
namespace {

using nlohmann::json;

std::string type_reason(const char* expected, const json& value) {
  return std::string("expected ") + expected + ", got " + value.type_name();
}

/// Converts one value; wrong types throw JsonFieldError with path `path`,
/// errors of nested conversions get `path` prefixed to their own path.
template <typename T>
void convert(const json& value, T& out, const std::string& path) {
  if constexpr (std::is_same_v<T, bool>) {
    if (!value.is_boolean()) throw JsonFieldError(path, type_reason("boolean", value));
    out = value.get<bool>();
  } else if constexpr (std::is_integral_v<T>) {
    if (!value.is_number_integer()) throw JsonFieldError(path, type_reason("integer", value));
    // Range check through the widest type that holds the JSON value.
    if (value.is_number_unsigned()) {
      const auto u = value.get<std::uint64_t>();
      if (u > static_cast<std::uint64_t>(std::numeric_limits<T>::max())) {
        throw JsonFieldError(path, "integer " + std::to_string(u) + " out of range");
      }
      out = static_cast<T>(u);
    } else {
      const auto i = value.get<std::int64_t>();
      if (i < static_cast<std::int64_t>(std::numeric_limits<T>::min()) ||
          (i > 0 && static_cast<std::uint64_t>(i) >
                        static_cast<std::uint64_t>(std::numeric_limits<T>::max()))) {
        throw JsonFieldError(path, "integer " + std::to_string(i) + " out of range");
      }
      out = static_cast<T>(i);
    }
  } else if constexpr (std::is_floating_point_v<T>) {
    // null stands for NaN (nlohmann writes non-finite numbers as null).
    if (value.is_null()) {
      out = std::numeric_limits<T>::quiet_NaN();
    } else if (value.is_number()) {
      out = value.get<T>();
    } else {
      throw JsonFieldError(path, type_reason("number", value));
    }
  } else if constexpr (std::is_same_v<T, std::string>) {
    if (!value.is_string()) throw JsonFieldError(path, type_reason("string", value));
    out = value.get<std::string>();
  } else {
    try {
      from_json(value, out);
    } catch (const JsonFieldError& e) {
      const std::string& inner = e.path();
      throw JsonFieldError(
          inner.empty() ? path : path + (inner.starts_with('[') ? "" : ".") + inner, e.reason());
    }
  }
}

/// Reads j[key] into out if present (missing keys keep the default).
template <typename T>
void field(const json& j, const char* key, T& out) {
  if (!j.is_object()) throw JsonFieldError(key, type_reason("object around it", j));
  const auto it = j.find(key);
  if (it == j.end()) return;
  convert(*it, out, key);
}

template <typename T>
void array_field(const json& j, const char* key, std::vector<T>& out) {
  if (!j.is_object()) throw JsonFieldError(key, type_reason("object around it", j));
  const auto it = j.find(key);
  if (it == j.end()) return;
  if (!it->is_array()) throw JsonFieldError(key, type_reason("array", *it));
  out.clear();
  out.resize(it->size());
  for (std::size_t i = 0; i < it->size(); ++i) {
    convert((*it)[i], out[i], std::string(key) + "[" + std::to_string(i) + "]");
  }
}

void require_object(const json& j, const char* what) {
  if (!j.is_object())
    throw JsonFieldError("", std::string("expected ") + what + " object, got " + j.type_name());
}

}  // namespace

std::string_view to_string(GnssSolution s) {
  switch (s) {
    case GnssSolution::CarrierPhaseFixed:
      return "carrier_phase_fixed";
    case GnssSolution::CarrierPhaseFloat:
      return "carrier_phase_float";
    case GnssSolution::Standalone:
      return "standalone";
  }
  return "standalone";
}

void to_json(json& j, const GeoPoint& v) {
  j = json{{"lat_deg", v.lat_deg}, {"lon_deg", v.lon_deg}, {"alt_m", v.alt_m}};
}
void from_json(const json& j, GeoPoint& v) {
  require_object(j, "GeoPoint");
  field(j, "lat_deg", v.lat_deg);
  field(j, "lon_deg", v.lon_deg);
  field(j, "alt_m", v.alt_m);
}

void to_json(json& j, const GeoPose& v) {
  j = json{{"position", v.position}, {"yaw_enu_rad", v.yaw_enu_rad}};
}
void from_json(const json& j, GeoPose& v) {
  require_object(j, "GeoPose");
  field(j, "position", v.position);
  field(j, "yaw_enu_rad", v.yaw_enu_rad);
}

void to_json(json& j, const Pose2& v) {
  j = json{{"x_m", v.x_m}, {"y_m", v.y_m}, {"yaw_rad", v.yaw_rad}};
}
void from_json(const json& j, Pose2& v) {
  require_object(j, "Pose2");
  field(j, "x_m", v.x_m);
  field(j, "y_m", v.y_m);
  field(j, "yaw_rad", v.yaw_rad);
}

void to_json(json& j, const RadarSpec& v) {
  j = json{{"center_frequency_hz", v.center_frequency_hz},
           {"bandwidth_hz", v.bandwidth_hz},
           {"range_resolution_m", v.range_resolution_m},
           {"max_range_m", v.max_range_m},
           {"fov_half_rad", v.fov_half_rad},
           {"azimuth_resolution_rad", v.azimuth_resolution_rad},
           {"virtual_elements", v.virtual_elements},
           {"frame_rate_hz", v.frame_rate_hz},
           {"v_unambiguous_mps", v.v_unambiguous_mps},
           {"velocity_resolution_mps", v.velocity_resolution_mps},
           {"polarization_basis", v.polarization_basis},
           {"mimo_scheme", v.mimo_scheme}};
}
void from_json(const json& j, RadarSpec& v) {
  require_object(j, "RadarSpec");
  field(j, "center_frequency_hz", v.center_frequency_hz);
  field(j, "bandwidth_hz", v.bandwidth_hz);
  field(j, "range_resolution_m", v.range_resolution_m);
  field(j, "max_range_m", v.max_range_m);
  field(j, "fov_half_rad", v.fov_half_rad);
  field(j, "azimuth_resolution_rad", v.azimuth_resolution_rad);
  field(j, "virtual_elements", v.virtual_elements);
  field(j, "frame_rate_hz", v.frame_rate_hz);
  field(j, "v_unambiguous_mps", v.v_unambiguous_mps);
  field(j, "velocity_resolution_mps", v.velocity_resolution_mps);
  field(j, "polarization_basis", v.polarization_basis);
  field(j, "mimo_scheme", v.mimo_scheme);
}

void to_json(json& j, const SensorMount& v) {
  j = json{{"sensor_id", v.sensor_id},
           {"name", v.name},
           {"T_vehicle_sensor", v.T_vehicle_sensor},
           {"trigger_offset_s", v.trigger_offset_s},
           {"spec", v.spec}};
}
void from_json(const json& j, SensorMount& v) {
  require_object(j, "SensorMount");
  field(j, "sensor_id", v.sensor_id);
  field(j, "name", v.name);
  field(j, "T_vehicle_sensor", v.T_vehicle_sensor);
  field(j, "trigger_offset_s", v.trigger_offset_s);
  field(j, "spec", v.spec);
}

void to_json(json& j, GnssSolution v) { j = std::string(to_string(v)); }
void from_json(const json& j, GnssSolution& v) {
  if (!j.is_string()) throw JsonFieldError("", type_reason("string", j));
  const auto s = j.get<std::string>();
  for (GnssSolution c : {GnssSolution::CarrierPhaseFixed, GnssSolution::CarrierPhaseFloat,
                         GnssSolution::Standalone}) {
    if (to_string(c) == s) {
      v = c;
      return;
    }
  }
  throw JsonFieldError("", "unknown GNSS solution '" + s +
                               "' (expected carrier_phase_fixed, carrier_phase_float, standalone)");
}

void to_json(json& j, const TrajectorySample& v) {
  j = json{{"time_s", v.time_s},           {"lat_deg", v.lat_deg},
           {"lon_deg", v.lon_deg},         {"yaw_enu_rad", v.yaw_enu_rad},
           {"speed_mps", v.speed_mps},     {"yaw_rate_rps", v.yaw_rate_rps},
           {"std_east_m", v.std_east_m},   {"std_north_m", v.std_north_m},
           {"std_yaw_rad", v.std_yaw_rad}, {"solution", v.solution}};
}
void from_json(const json& j, TrajectorySample& v) {
  require_object(j, "TrajectorySample");
  field(j, "time_s", v.time_s);
  field(j, "lat_deg", v.lat_deg);
  field(j, "lon_deg", v.lon_deg);
  field(j, "yaw_enu_rad", v.yaw_enu_rad);
  field(j, "speed_mps", v.speed_mps);
  field(j, "yaw_rate_rps", v.yaw_rate_rps);
  field(j, "std_east_m", v.std_east_m);
  field(j, "std_north_m", v.std_north_m);
  field(j, "std_yaw_rad", v.std_yaw_rad);
  field(j, "solution", v.solution);
}

void to_json(json& j, const Detection& v) {
  j = json{{"range_m", v.range_m},
           {"azimuth_rad", v.azimuth_rad},
           {"radial_velocity_mps", v.radial_velocity_mps},
           {"snr_db", v.snr_db}};
}
void from_json(const json& j, Detection& v) {
  require_object(j, "Detection");
  field(j, "range_m", v.range_m);
  field(j, "azimuth_rad", v.azimuth_rad);
  field(j, "radial_velocity_mps", v.radial_velocity_mps);
  field(j, "snr_db", v.snr_db);
}

void to_json(json& j, const RecordingHeader& v) {
  j = json{{"format_version", v.format_version},
           {"drive_id", v.drive_id},
           {"vehicle_id", v.vehicle_id},
           {"world", v.world},
           {"origin", v.origin},
           {"sensors", v.sensors},
           {"start_time_s", v.start_time_s},
           {"has_cube", v.has_cube},
           {"producer", v.producer}};
  // Written only when known, so recordings without it stay byte for byte as before.
  if (v.side_slip_gradient_rad_per_mps2) {
    j["side_slip_gradient_rad_per_mps2"] = *v.side_slip_gradient_rad_per_mps2;
  }
}
void from_json(const json& j, RecordingHeader& v) {
  require_object(j, "RecordingHeader");
  field(j, "format_version", v.format_version);
  field(j, "drive_id", v.drive_id);
  field(j, "vehicle_id", v.vehicle_id);
  field(j, "world", v.world);
  field(j, "origin", v.origin);
  array_field(j, "sensors", v.sensors);
  field(j, "start_time_s", v.start_time_s);
  field(j, "has_cube", v.has_cube);
  field(j, "producer", v.producer);
  if (j.contains("side_slip_gradient_rad_per_mps2")) {
    double g = 0.0;
    field(j, "side_slip_gradient_rad_per_mps2", g);
    if (!side_slip_gradient_valid(g)) {
      throw JsonFieldError(
          "side_slip_gradient_rad_per_mps2",
          "must be in [0, " + std::to_string(kMaxSideSlipGradientRadPerMps2) + "] rad per m/s^2");
    }
    v.side_slip_gradient_rad_per_mps2 = g;
  }
}

}  // namespace polmap
