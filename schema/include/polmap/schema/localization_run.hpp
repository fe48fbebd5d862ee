#pragma once
/// @file localization_run.hpp
/// A localization run report (schema/localization_run.md): the summary a vehicle sends to
/// the mapping service after localizing against its map (`polmap localize --report URL`,
/// POST /v1/runs): the trajectory with the localizer's status and covariance and, when a
/// reference was available after the run (studies), the errors against it.
///
/// One parser (parse_localization_run) for every reader, one encoder whose output is the
/// canonical copy the server stores: a parsed run encodes to bytes that parse to the same
/// run. Limits apply before work: the byte cap before parsing, the sample cap before any
/// sample is converted.
#include <cstdint>
#include <expected>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace polmap {

/// The localizer's status at a sample (loc::LocalizationOutput::Status).
enum class RunStatus : std::uint8_t { Initializing, Tracking, Degraded, Lost };
inline constexpr int kRunStatusCount = 4;

[[nodiscard]] std::string_view to_string(RunStatus s);
/// "initializing" | "tracking" | "degraded" | "lost"; nullopt otherwise.
[[nodiscard]] std::optional<RunStatus> parse_run_status(std::string_view s);

/// Errors of a sample against the reference, in the reference's frame (paper §IV-C).
struct RunSampleError {
  double long_m = 0.0;   ///< along the reference heading
  double lat_m = 0.0;    ///< across it (left positive)
  double rot_deg = 0.0;  ///< heading error
};

/// One pose of the run.
struct LocalizationRunSample {
  double t_s = 0.0;  ///< sensor frame time (the recording's time base)
  double lat_deg = 0.0;
  double lon_deg = 0.0;
  double yaw_enu_deg = 0.0;  ///< heading, counter-clockwise from east, in (-180, 180]
  RunStatus status = RunStatus::Initializing;
  /// Position covariance in the local east/north plane (m²) and yaw variance (rad²).
  double cov_xx_m2 = 0.0;
  double cov_xy_m2 = 0.0;
  double cov_yy_m2 = 0.0;
  double cov_yaw_rad2 = 0.0;
  std::optional<RunSampleError> error;  ///< set when the sample was evaluated
};

/// Where a run's errors come from.
enum class RunReference : std::uint8_t { None, SimulatorTruth, GnssIns };
[[nodiscard]] std::string_view to_string(RunReference r);
[[nodiscard]] std::optional<RunReference> parse_run_reference(std::string_view s);

/// A whole run report.
struct LocalizationRun {
  std::string label;  ///< free text from the vehicle (e.g. the recording's name), ≤ 128 bytes
  std::int64_t map_version = 0;  ///< newest map version among the tiles used (0: none)
  std::string pol = "full";      ///< polarimetric level (polarimetry.hpp names)
  RunReference reference = RunReference::None;
  /// Processing speed of the run (drive time / wall time); nullopt when unknown.
  std::optional<double> realtime_factor;
  std::vector<LocalizationRunSample> samples;  ///< strictly increasing t_s
};

/// Caps of the parser (checked before the work they bound).
struct LocalizationRunLimits {
  std::size_t max_bytes = 8u << 20;    ///< the whole report
  std::size_t max_samples = 100'000;   ///< ≈ 5 h at 5 Hz
  double max_span_deg = 2.0;           ///< latitude and longitude extent of the run
  static constexpr int kMaxDepth = 4;  ///< JSON nesting (object > array > object > value)
  static constexpr std::size_t kMaxLabelBytes = 128;
};

/// Why a report was refused: the field (JSON path such as "samples[12].lat_deg", or
/// "body") and what is wrong; http_status 413 (too large), 400 (not JSON) or 422 (invalid).
struct LocalizationRunError {
  std::string field;
  std::string message;
  int http_status = 422;
  /// "field 'FIELD': MESSAGE".
  [[nodiscard]] std::string what() const;
};

/// The one parser of run reports. Never throws on any input.
[[nodiscard]] std::expected<LocalizationRun, LocalizationRunError> parse_localization_run(
    std::string_view bytes, const LocalizationRunLimits& limits = {});

/// The canonical encoding (compact JSON). Contract: `run` is valid (as parsed).
[[nodiscard]] std::string encode_localization_run(const LocalizationRun& run);

}  // namespace polmap
