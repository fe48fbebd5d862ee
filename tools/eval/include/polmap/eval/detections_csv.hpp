#pragma once
/// @file detections_csv.hpp
/// Plain-text detections of any Doppler radar (CSV) and the sensor mounts
/// (JSON), so recordings from other radars can feed the ego-motion estimator.
/// Both formats are specified in schema/detections_csv.md.
///
/// Every parse error throws polmap::FormatError whose message names the file,
/// the line and the column (CSV: "FILE: line L, column C (NAME): reason";
/// JSON: "FILE: line L, column C: reason" for syntax errors and
/// "FILE: [i].field: reason" for missing or invalid fields).
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <istream>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::eval {

/// The column names of the detections CSV header (any order; further columns
/// are ignored).
inline constexpr std::string_view kDetectionsCsvColumns[] = {
    "timestamp_s", "sensor_id", "range_m", "azimuth_rad", "radial_velocity_mps", "amplitude_db"};

/// Streams sensor frames out of a detections CSV: consecutive rows with the
/// same (timestamp_s, sensor_id) form one frame. amplitude_db goes into
/// Detection::snr_db; cycle_index counts the frames of each sensor from 0; the
/// frames carry no spectrum.
class DetectionsCsvReader {
 public:
  /// Opens a file (throws IoError if it cannot be opened).
  explicit DetectionsCsvReader(const std::filesystem::path& path);
  /// Reads from a stream; `source_name` is used in error messages.
  DetectionsCsvReader(std::unique_ptr<std::istream> in, std::string source_name);
  ~DetectionsCsvReader();
  DetectionsCsvReader(const DetectionsCsvReader&) = delete;
  DetectionsCsvReader& operator=(const DetectionsCsvReader&) = delete;

  /// Next frame, or std::nullopt at the end. Throws FormatError.
  std::optional<SensorFrame> next();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Parses a whole detections CSV held in memory.
std::vector<SensorFrame> parse_detections_csv(std::string_view text,
                                              const std::string& source_name = "<memory>");
/// Reads a whole detections CSV file.
std::vector<SensorFrame> read_detections_csv(const std::filesystem::path& path);

/// Formats frames as a detections CSV (header + one row per detection, values
/// with round-trip precision for the float fields). Frames without detections
/// cannot be represented and are skipped.
std::string format_detections_csv(const std::vector<SensorFrame>& frames);
/// Writes format_detections_csv(frames) to path (throws IoError).
void write_detections_csv(const std::filesystem::path& path,
                          const std::vector<SensorFrame>& frames);

/// Parses the sensor mounts JSON (an array of flat objects, see
/// schema/detections_csv.md).
std::vector<SensorMount> parse_sensor_mounts_json(std::string_view text,
                                                  const std::string& source_name = "<memory>");
std::vector<SensorMount> read_sensor_mounts_json(const std::filesystem::path& path);
/// Formats mounts in the same flat JSON (pretty-printed).
std::string format_sensor_mounts_json(const std::vector<SensorMount>& mounts);

}  // namespace polmap::eval
