#pragma once
/// @file recording.hpp
/// Value types of a recording: one drive's raw sensor data as a vehicle logs
/// it (format documented in schema/recording.md). Frames: vehicle frame at the
/// rear-axle centre; sensor frame at the antenna, azimuth positive to the left.
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "polmap/schema/geo.hpp"
#include "polmap/schema/polarimetry.hpp"
#include "polmap/schema/radar_spec.hpp"

namespace polmap {

/// Version of the recording format written by this build.
inline constexpr std::uint32_t kRecordingFormatVersion = 1;

/// GNSS solution quality of a trajectory sample.
enum class GnssSolution : std::uint8_t {
  CarrierPhaseFixed = 0,  ///< RTK fixed, σ ≈ 14 mm (paper §IV-A)
  CarrierPhaseFloat = 1,  ///< no carrier-phase fix, σ ≈ 86 mm
  Standalone = 2,
};

/// One GNSS/IMU trajectory sample (≥ 50 Hz), georeferenced.
struct TrajectorySample {
  double time_s = 0.0;
  double lat_deg = 0.0;
  double lon_deg = 0.0;
  double yaw_enu_rad = 0.0;  ///< vehicle x axis, counter-clockwise from east
  double speed_mps = 0.0;
  double yaw_rate_rps = 0.0;
  float std_east_m = 0.0F;
  float std_north_m = 0.0F;
  float std_yaw_rad = 0.0F;
  GnssSolution solution = GnssSolution::CarrierPhaseFixed;
};

/// One CFAR detection of one sensor, in the sensor frame.
struct Detection {
  float range_m = 0.0F;
  float azimuth_rad = 0.0F;
  float radial_velocity_mps = 0.0F;  ///< aliased into [-v_unamb, v_unamb)
  float snr_db = 0.0F;
};

/// One resolution cell of the static-reduced PreCFAR spectrum: complex
/// amplitudes of the four LR-basis channels (LL, LR, RL, RR).
struct SpectrumCell {
  std::uint16_t range_bin = 0;
  std::uint16_t azimuth_bin = 0;
  std::array<cfloat, 4> s{};
};

/// Static-reduced PreCFAR spectrum of one sensor frame (polar range × azimuth
/// image per polarization channel). Sparse: cells below the recorder's
/// noise-relative floor are omitted and read as zero.
struct PolSpectrum {
  double range_bin_m = 0.075;  ///< range of bin i is i * range_bin_m
  std::uint16_t num_range_bins = 0;
  std::vector<float> azimuth_bins_rad;  ///< beam centres, ascending
  float noise_sigma = 1.0F;             ///< complex noise std per cell and channel
  std::vector<SpectrumCell> cells;      ///< sorted by (azimuth_bin, range_bin)
};

/// Optional full data cube of one sensor frame (short sequences only):
/// range-compressed slow-time samples, data[((pol * V + v) * C + c) * R + r]
/// for pol in LL,LR,RL,RR, virtual channel v, chirp c, range bin r. The
/// Doppler dimension is the FFT over chirps (chirp_interval_s apart).
struct DataCube {
  std::uint16_t num_range_bins = 0;
  std::uint16_t num_chirps = 0;
  std::uint16_t num_virtual_channels = 0;
  double range_bin_m = 0.075;
  double chirp_interval_s = 0.0;
  double element_spacing_wavelengths = 0.5;
  std::vector<cfloat> data;
};

/// Everything one sensor delivered for one trigger.
struct SensorFrame {
  std::uint32_t cycle_index = 0;  ///< 10 Hz cycle counter
  std::uint8_t sensor_id = 0;
  double time_s = 0.0;  ///< trigger time
  std::vector<Detection> detections;
  PolSpectrum spectrum;
  std::optional<DataCube> cube;
};

/// Metadata at the start of a recording.
struct RecordingHeader {
  std::uint32_t format_version = kRecordingFormatVersion;
  std::string drive_id;
  std::string vehicle_id;
  std::string world;  ///< scenario / map name the drive was recorded in
  GeoPoint origin;    ///< geodetic origin of the drive's local frames
  std::vector<SensorMount> sensors;
  double start_time_s = 0.0;
  bool has_cube = false;
  std::string producer;  ///< e.g. "polmap simulate 0.1.0 seed=1"
  /// The vehicle's rear-axle side-slip gradient (rad per m/s² of lateral acceleration; ISO
  /// 8855 linear single-track model, β = −gradient · a_y), a vehicle parameter like the
  /// mounts: the ego-motion's EgoMotionConfig::side_slip_gradient_rad_per_mps2. nullopt:
  /// not recorded (consumers then use the kinematic model unless told otherwise). Range
  /// checked by the reader: [0, kMaxSideSlipGradientRadPerMps2].
  std::optional<double> side_slip_gradient_rad_per_mps2;
};

/// Largest side-slip gradient a recording may declare (0.05 rad per m/s², 2.9°: ten times a
/// passenger car's).
inline constexpr double kMaxSideSlipGradientRadPerMps2 = 0.05;

/// The one range check of a declared side-slip gradient (reader and writer).
inline bool side_slip_gradient_valid(double g) {
  return std::isfinite(g) && g >= 0.0 && g <= kMaxSideSlipGradientRadPerMps2;
}

/// A record of the stream after the header.
using RecordingRecord = std::variant<TrajectorySample, SensorFrame>;

/// Pull interface over a time-ordered record stream: a file reader or a
/// simulator streaming straight into processing.
class RecordSource {
 public:
  virtual ~RecordSource() = default;
  [[nodiscard]] virtual const RecordingHeader& header() const = 0;
  /// Next record, or std::nullopt at the end. Throws FormatError on corrupt input.
  virtual std::optional<RecordingRecord> next() = 0;
};

}  // namespace polmap
