#pragma once
/// @file radar_spec.hpp
/// Radar sensor parameters (paper Table III) and mount poses.
#include <cstdint>
#include <numbers>
#include <string>
#include <vector>

#include "polmap/schema/pose2.hpp"

namespace polmap {

/// Parameters of one polarimetric radar sensor. Defaults: paper Table III.
struct RadarSpec {
  double center_frequency_hz = 78e9;
  double bandwidth_hz = 2e9;
  double range_resolution_m = 0.075;
  double max_range_m = 80.0;
  double fov_half_rad = 60.0 * std::numbers::pi / 180.0;  ///< ±60° azimuth
  double azimuth_resolution_rad = 3.0 * std::numbers::pi / 180.0;
  int virtual_elements = 31;
  double frame_rate_hz = 10.0;
  double v_unambiguous_mps = 5.0;  ///< radial velocities alias into [-v, v)
  double velocity_resolution_mps = 0.15;
  std::string polarization_basis = "LR";
  std::string mimo_scheme = "TDM";

  [[nodiscard]] double wavelength_m() const { return 299792458.0 / center_frequency_hz; }
};

/// Mount of one sensor in the vehicle frame (origin rear-axle centre, x forward,
/// y left). trigger_offset_s: trigger time within each frame cycle.
struct SensorMount {
  std::uint8_t sensor_id = 0;
  std::string name;
  Pose2 T_vehicle_sensor;
  double trigger_offset_s = 0.0;
  RadarSpec spec;
};

/// The three front sensors of the paper's vehicle (tools/sim/README.md "Frames and time").
inline std::vector<SensorMount> default_front_mounts() {
  constexpr double deg = std::numbers::pi / 180.0;
  return {
      {0, "front_center", {3.7, 0.0, 0.0}, 0.000, {}},
      {1, "front_left", {3.5, 0.75, 40.0 * deg}, 0.033, {}},
      {2, "front_right", {3.5, -0.75, -40.0 * deg}, 0.066, {}},
  };
}

}  // namespace polmap
