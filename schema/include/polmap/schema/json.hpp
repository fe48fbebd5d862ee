#pragma once
/// @file json.hpp
/// nlohmann::json conversions (found by ADL) for the schema value types that
/// appear in JSON documents: the recording header inside .pmrec files, drive
/// package manifests, CLI `--json` output.
///
/// Conventions: keys are the C++ field names (units in the names), angles in
/// radians, enums as lower-case strings. `from_json` is lenient about missing
/// keys (the field keeps its documented default, so older and newer documents
/// stay readable) and unknown keys (ignored), and strict about types and enum
/// spellings: a present key of the wrong type throws JsonFieldError naming the
/// full field path, e.g. `sensors[1].spec.bandwidth_hz`.
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <utility>

#include "polmap/schema/errors.hpp"
#include "polmap/schema/geo.hpp"
#include "polmap/schema/pose2.hpp"
#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap {

/// A JSON document field is missing a required value or has the wrong type.
/// what() reads "JSON field 'PATH': REASON".
class JsonFieldError : public FormatError {
 public:
  JsonFieldError(std::string path, std::string reason)
      : FormatError("JSON field '" + path + "': " + reason),
        path_(std::move(path)),
        reason_(std::move(reason)) {}
  /// Dotted path of the field from the converted object, e.g. "sensors[1].spec.bandwidth_hz".
  [[nodiscard]] const std::string& path() const { return path_; }
  [[nodiscard]] const std::string& reason() const { return reason_; }

 private:
  std::string path_;
  std::string reason_;
};

/// "carrier_phase_fixed", "carrier_phase_float", "standalone".
std::string_view to_string(GnssSolution s);

void to_json(nlohmann::json& j, const GeoPoint& v);
void from_json(const nlohmann::json& j, GeoPoint& v);

void to_json(nlohmann::json& j, const GeoPose& v);
void from_json(const nlohmann::json& j, GeoPose& v);

void to_json(nlohmann::json& j, const Pose2& v);
void from_json(const nlohmann::json& j, Pose2& v);

void to_json(nlohmann::json& j, const RadarSpec& v);
void from_json(const nlohmann::json& j, RadarSpec& v);

void to_json(nlohmann::json& j, const SensorMount& v);
void from_json(const nlohmann::json& j, SensorMount& v);

void to_json(nlohmann::json& j, GnssSolution v);
void from_json(const nlohmann::json& j, GnssSolution& v);

void to_json(nlohmann::json& j, const TrajectorySample& v);
void from_json(const nlohmann::json& j, TrajectorySample& v);

void to_json(nlohmann::json& j, const Detection& v);
void from_json(const nlohmann::json& j, Detection& v);

void to_json(nlohmann::json& j, const RecordingHeader& v);
void from_json(const nlohmann::json& j, RecordingHeader& v);

}  // namespace polmap
