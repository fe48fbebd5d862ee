#pragma once
/// @file reference_mount_calibration.hpp
/// Calibration of each radar's mount yaw and time offset against the drive's georeferenced
/// trajectory (mapping mode, issue 15): the mapping vehicle's own mount errors otherwise go
/// into the map. A mount yaw error δψ rotates a sensor's whole view about the sensor; a
/// landmark 20 m ahead moves 0.13 m sideways per 0.38° (a simulated vehicle's common mount
/// error on the realistic preset), and the map then disagrees with a localizer that
/// calibrated its own mounts.
///
/// Model. With the trajectory the vehicle's motion is known (velocity from the positions, so
/// side slip included; yaw rate), hence every static detection's radial velocity:
///     v_r = −v_s(t + δt_s)·u(ψ_s + δψ_s + φ),   v_s = (v_x − ω·y_s, v_y + ω·x_s),
/// v in the vehicle frame of the trajectory's heading. Linearized at δψ = δt = 0, each
/// sensor has two parameters and no nuisance: unlike the localizer's calibration
/// (mount_calibration.hpp), the yaw COMMON to all sensors is observable here, and so is each
/// time offset against the trajectory's clock. What is estimated is the sensor's orientation
/// against the velocity the positions give, so a heading (boresight) error of the trajectory
/// is absorbed too: the mapped sensor's world orientation is then right either way.
///
/// Core computation: values in, values out (the drive processor computes the motion and
/// feeds frames; this class does no I/O).
#include <Eigen/Core>
#include <cstdint>
#include <numbers>
#include <vector>

#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::radar {

/// Parameters of ReferenceMountCalibrator; defaults for 77 GHz corner radars.
struct ReferenceMountCalibrationConfig {
  /// Calibrate at all (process_drive: hold the first frames until converged, then map every
  /// frame with the calibrated mounts and stamps).
  bool enabled = true;
  /// Frames slower than this are skipped (the yaw column is ∝ v).
  double min_speed_mps = 2.0;
  /// Noise of one detection: σ² = σ_vr² + σ_φ²·(∂v_r/∂φ)² (the trajectory's velocity noise
  /// is common to a frame and averages over frames).
  double vr_sigma_mps = 0.07;
  double azimuth_sigma_rad = 0.4 * std::numbers::pi / 180.0;
  /// Detections are used when their residual is within max(gate_sigmas·σ, gate_min_mps)
  /// under the current estimate (moving objects, multipath, gross errors are not); the first
  /// frames of a sensor use first_gate_mps around the nominal mount.
  double gate_sigmas = 3.0;
  double gate_min_mps = 0.15;
  double first_gate_mps = 1.0;
  /// Frames with fewer gated detections are skipped (too little to tell targets from clutter).
  int min_detections_per_frame = 8;
  /// Gaussian priors around the nominal mount (regularize what is not observed yet).
  double prior_yaw_sigma_rad = 2.0 * std::numbers::pi / 180.0;
  double prior_time_offset_sigma_s = 0.02;
  /// Converged when every sensor's yaw 1-σ (residual variance factor included, times
  /// sigma_inflation for the noise that is not white: the trajectory's velocity, multipath)
  /// is below converged_yaw_sigma_rad after min_observed_s of driving. Time offsets are
  /// applied as estimated, with their prior: they need changes of the motion to be observed.
  double converged_yaw_sigma_rad = 0.01 * std::numbers::pi / 180.0;
  double sigma_inflation = 3.0;
  double min_observed_s = 15.0;
};

/// The vehicle's motion at a frame's time, in the vehicle frame of the trajectory's heading.
struct ReferenceMotion {
  double v_x_mps = 0.0;         ///< forward velocity of the trajectory's reference point
  double v_y_mps = 0.0;         ///< lateral velocity (side slip)
  double yaw_rate_rps = 0.0;    ///< ω
  double a_x_mps2 = 0.0;        ///< d v_x / dt (vehicle-frame components)
  double a_y_mps2 = 0.0;        ///< d v_y / dt
  double yaw_accel_rps2 = 0.0;  ///< d ω / dt
};

/// Per-sensor estimate: true − nominal.
struct ReferenceMountCalibration {
  enum class Status { NotObservableYet, Converged };
  struct Sensor {
    std::uint8_t sensor_id = 0;
    double yaw_offset_rad = 0.0;
    double yaw_sigma_rad = 0.0;  ///< inflated (see config)
    double time_offset_s = 0.0;  ///< true measurement time − stamp
    double time_sigma_s = 0.0;
    long long detections = 0;  ///< gated detections used
    int frames = 0;            ///< frames that entered
  };
  Status status = Status::NotObservableYet;
  std::vector<Sensor> sensors;  ///< in the order of the mounts
  double observed_s = 0.0;      ///< time span of the frames that entered
};

const char* to_string(ReferenceMountCalibration::Status s);

/// Accumulates the per-sensor normal equations frame by frame (iteratively re-gated around
/// the current estimate). Not thread-safe.
class ReferenceMountCalibrator {
 public:
  explicit ReferenceMountCalibrator(std::vector<SensorMount> mounts,
                                    ReferenceMountCalibrationConfig cfg = {});
  /// One frame with the motion at its stamp. Unknown sensors and slow frames are ignored.
  void add_frame(const SensorFrame& frame, const ReferenceMotion& motion);
  [[nodiscard]] ReferenceMountCalibration result() const;
  /// The nominal mounts with the estimated yaws applied.
  [[nodiscard]] std::vector<SensorMount> calibrated_mounts() const;
  [[nodiscard]] const ReferenceMountCalibrationConfig& config() const { return cfg_; }

 private:
  struct Accumulator {
    Eigen::Matrix2d info = Eigen::Matrix2d::Zero();
    Eigen::Vector2d rhs = Eigen::Vector2d::Zero();
    double rwr = 0.0;
    long long n = 0;
    int frames = 0;
  };
  /// Accumulated information of sensor s plus the priors, and the estimate it gives.
  [[nodiscard]] Eigen::Matrix2d information(std::size_t s) const;
  [[nodiscard]] Eigen::Vector2d solve(std::size_t s) const;
  std::vector<SensorMount> mounts_;
  ReferenceMountCalibrationConfig cfg_;
  std::vector<Accumulator> acc_;
  double first_time_s_ = 0.0, last_time_s_ = 0.0;
  bool any_ = false;
};

}  // namespace polmap::radar
