#pragma once
/// @file doppler_residuals.hpp
/// Statistics of detection lists against the Doppler a static world gives at a known
/// vehicle motion (v, yaw rate; zero side slip), as measured on real corner radars
/// (tools/sim/README.md "Realism"): the robust sigma of the static core and the share of detections
/// with |residual| > 0.5 m/s (moving objects, multipath, artefacts). Used to calibrate the
/// realistic preset against real recordings (tools/sim/README.md "Realism").
#include <cstddef>
#include <cstdint>
#include <map>
#include <vector>

#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::sim {

/// Residual v_meas - v_static of one detection for a vehicle moving with (v, yaw rate), the
/// sensor at `mount`: v_static = -v_s . (cos phi, sin phi), v_s = (v - w y_m, w x_m) rotated
/// into the sensor frame. Wrapped into [-v_ua, v_ua) when v_ua > 0 (aliased sensors).
double static_doppler_residual_mps(const Detection& d, const SensorMount& mount, double v_mps,
                                   double yaw_rate_rps, double v_unambiguous_mps);

/// Robust statistics of a set of residuals.
struct DopplerResidualStats {
  std::size_t detections = 0;
  std::size_t frames = 0;
  double median_mps = 0.0;
  /// 1.4826 * median absolute deviation: the sigma of the static core, blind to outliers.
  double robust_sigma_mps = 0.0;
  /// Share of detections with |residual| > outlier_threshold_mps.
  double outlier_share = 0.0;
  double detections_per_frame = 0.0;
};

/// Collects residuals per sensor; frames at speeds below min_speed_mps are skipped (at rest
/// the residual says nothing about the motion).
class DopplerResidualAccumulator {
 public:
  explicit DopplerResidualAccumulator(double outlier_threshold_mps = 0.5,
                                      double min_speed_mps = 1.0)
      : threshold_(outlier_threshold_mps), min_speed_(min_speed_mps) {}
  void add(const SensorFrame& frame, const SensorMount& mount, double v_mps, double yaw_rate_rps);
  /// All sensors together.
  [[nodiscard]] DopplerResidualStats total() const;
  /// Per sensor id.
  [[nodiscard]] std::map<std::uint8_t, DopplerResidualStats> per_sensor() const;

 private:
  [[nodiscard]] DopplerResidualStats stats(std::vector<float> r, std::size_t frames) const;
  double threshold_, min_speed_;
  std::map<std::uint8_t, std::vector<float>> residuals_;
  std::map<std::uint8_t, std::size_t> frames_;
};

}  // namespace polmap::sim
