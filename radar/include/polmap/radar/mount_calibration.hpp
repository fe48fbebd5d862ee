#pragma once
/// @file mount_calibration.hpp
/// Online calibration of each radar's mount yaw and time offset from the Doppler
/// residuals of static detections while driving (issue 15 item 2).
///
/// Model. A static target seen by sensor s at measured azimuth φ (stamp t) has, with the
/// true mount yaw ψ_s + δψ_s and the true measurement time t + δt_s,
///     v_r = h(θ)·m(t + δt_s),  θ = φ + ψ_s + δψ_s,
///     h(θ) = (−cos θ, y_s·cos θ − x_s·sin θ),  m = (v, ω)  (EgoMotionEstimator's model),
/// and to first order around the nominal mount and the stamp
///     v_r ≈ h·m(t) + δψ_s·(g·m(t)) + δt_s·(h·ṁ),   g = ∂h/∂θ = (sin θ, −y_s·sin θ − x_s·cos θ).
/// (mount_doppler_jacobian() gives these partials; the test checks them numerically.)
///
/// Estimator. Frames are grouped into blocks of one trigger cycle (`block_window_s`, one
/// frame per sensor). Within a block the motion is m(t) = m̂(t) + Δm with m̂, ṁ from a line
/// fit of the ego-motion estimates over ±`motion_fit_half_window_s` (so the calibrator lags
/// the newest frame by that much) and Δm = (Δv, Δω[, v_y]) a per-block nuisance: the
/// estimator's own bias (it used the wrong mounts) never enters the calibration. The nuisance
/// is eliminated per block by the Schur complement, and the reduced normal equations of the
/// 2·S parameters (δψ_1..S, δt_1..S) are accumulated over the whole drive (batch least
/// squares, exact for the linear model; the information matrix Λ is kept, its inverse times
/// the residual variance factor is the reported covariance). Detections are gated on their
/// residual under the current calibration (not on the ego-motion estimator's inlier mask,
/// which was selected with the wrong mounts and would bias δψ towards zero).
///
/// Observability (radar alone):
///  - A COMMON yaw of all mounts rotates every sensor's velocity by the same angle: a lateral
///    velocity −v·δψ̄ at every sensor, identical to a side-slip angle β = −δψ̄ of the rear axle
///    (in any manoeuvre, straight driving included). With `side_slip_nuisance` (default) each
///    block in a curve (|a_y| ≥ side_slip_min_lateral_accel_mps2) has a free lateral
///    velocity, so slip in curves never leaks into the mounts, and only RELATIVE yaws are
///    reported and applied: δψ_s − mean over the sensors. Internally the common yaw is a
///    constant parameter seen by the straight blocks, which assume zero slip (there the yaw
///    rate also shows in the longitudinal velocity difference across the sensors' track, so
///    a common lateral velocity is not all yaw rate); it absorbs any constant slip angle too,
///    is reported as common_yaw_rad, and is applied only with estimate_common_yaw (or with
///    side_slip_nuisance = false, no lateral nuisance at all). Not applied, it stays in the
///    ego-motion as a yaw-rate bias ≈ v·δψ̄/x_sensor, which needs a heading reference
///    outside radar (INS, map matching) or the zero-slip assumption.
///  - A COMMON time offset of all sensors shifts the whole motion in time: unobservable from
///    radar alone; the gauge fixes the mean of δt to zero (relative offsets).
///  - δψ_s needs speed (its column is v·sin θ-like: zero at standstill; blocks slower than
///    `min_speed_mps` are skipped) and a spread of azimuths.
///  - δt_s needs a changing motion: its column is h·ṁ, zero at constant v and ω. Braking,
///    accelerating and entering or leaving curves observe it; a drive at constant speed on a
///    straight road never does (status stays NotObservableYet).
/// Convergence is gated on the marginal 1-σ of each parameter from the information matrix.
/// That σ assumes white detection noise; multipath, slip and the ego-motion's own time
/// alignment are not white, and measured errors are up to ~3-4x the σ (tools/sim/README.md
/// "Online mount calibration"), hence convergence limits well above the typical σ.
#include <Eigen/Core>
#include <cstdint>
#include <deque>
#include <numbers>
#include <vector>

#include "polmap/radar/egomotion.hpp"
#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::radar {

/// Parameters of MountCalibrator. Defaults for 77 GHz corner radars on a passenger car.
struct MountCalibrationConfig {
  /// Apply converged estimates to the ego-motion estimator (corrected mount yaws and time
  /// stamps). On by default: with exact mounts the estimates are ≤ 0.003° and a few 0.1 ms
  /// after a minute, which moves the ego-motion by far less than its noise (measured),
  /// while real corner radars are off by 0.1-0.3° (residuals of a public
  /// four-radar recording) and cost heading drift.
  bool calibrate_mounts = true;
  /// Frames whose stamps lie within this window of the block's first frame form one block
  /// (one trigger cycle: one frame per sensor at 10 Hz).
  double block_window_s = 0.1;
  /// Ego-motion estimates within this much before the block and after it give the block's
  /// motion and acceleration (line fit); also the calibrator's lag behind the newest frame.
  double motion_fit_half_window_s = 0.25;
  /// At least this many Ok estimates in the fit window, else the block is skipped.
  int motion_fit_min_estimates = 5;
  /// Blocks slower than this are skipped (the yaw column is ∝ v; reversing is excluded).
  double min_speed_mps = 2.0;
  /// Per-block lateral-velocity nuisance (side slip): relative yaws only (see file comment).
  bool side_slip_nuisance = true;
  /// ... but only in blocks with |lateral acceleration| = |v·ω| at least this: below it the
  /// side slip is taken as zero (linear single-track model: β ≈ 0.23°/(m/s²)·a_y, so under
  /// 0.5 m/s² the slip is < 0.12° and averages out over straight driving). Why: with a free
  /// lateral velocity, the yaw-rate nuisance is only fixed by the small x-spread of the
  /// sensors (0.2 m on the paper's car), and the left/right antisymmetric time offset under
  /// braking looks like a yaw rate (longitudinal differential over the track): its σ grows
  /// about 5x. 0 = lateral nuisance in every block.
  double side_slip_min_lateral_accel_mps2 = 0.5;
  /// The vehicle's rear-axle side-slip gradient (EgoMotionConfig's, same sign): every block is
  /// linearized at the slip it predicts, v_y = −gradient · v² · ω, instead of zero. Why: the
  /// blocks below side_slip_min_lateral_accel_mps2 still carry up to gradient · 0.5 m/s² of
  /// slip (0.12° on a passenger car), mostly of one sign on a winding road, and a common yaw
  /// that absorbs it becomes a yaw-rate bias of v · δψ̄ / x_sensor: at 18 m/s, 0.08° of common
  /// yaw is 0.4°/s (a rural study drive with slip diverged by 3.6° in 15 s; polmap study
  /// --realism realistic --realism-sources slip). The Localizer copies its ego-motion's value.
  double side_slip_gradient_rad_per_mps2 = 0.0;
  /// Also estimate the COMMON mount yaw (absolute yaws), from the blocks below
  /// side_slip_min_lateral_accel_mps2 only, under their zero-side-slip assumption: there a
  /// common yaw shows as a lateral velocity that the yaw rate must explain, and the yaw rate
  /// is also seen in the longitudinal velocity difference across the sensors' track. Off by
  /// default: any real side slip in straight driving (road camber, crosswind, a misaligned
  /// rear axle) becomes a mount error, and the track of corner radars (1.4-1.7 m) makes it
  /// weakly observed; measured in tools/sim/README.md "Online mount calibration".
  bool estimate_common_yaw = false;
  /// With estimate_common_yaw: the common yaw is applied only when it stands out of its
  /// noise by at least this many sigmas. An estimate of zero is noise (the ideal simulator's
  /// exact mounts: applying it cost one urban drive half its lateral accuracy, 0.047 ->
  /// 0.092 m); a real common misalignment of tenths of a degree is tens of sigmas.
  double common_yaw_min_sigmas = 3.0;
  /// The common yaw is applied to every sensor as soon as it is significant, its 1-σ is at
  /// most common_yaw_early_sigma_rad and common_yaw_early_min_observed_s of driving entered,
  /// before the relative yaws converge (a sensor's own offset replaces it once converged).
  /// Why: a common yaw δψ̄ is a yaw-rate bias of v·δψ̄/x_sensor, 1.5°/s for 0.38° at 14 m/s
  /// (a realistic-preset vehicle), which lost 14 of 30 urban study drives in their first
  /// seconds while the relative yaws took 25-50 s to converge.
  /// Only a common yaw of at least common_yaw_early_min_rad applies early: smaller ones wait
  /// for the sensors' convergence (the localizer's odometry carries them as uncertainty);
  /// applied early, ideal-preset noise of 0.01-0.02° cost rural drives 0.065 -> 0.094 m
  /// lateral RMSE. The σ limit is 0.15°, not 0.05°: under realistic radar noise the σ of the
  /// first seconds stays above 0.05°, and a rural vehicle with 0.38° of common yaw lost every
  /// drive to the heading drift before it fell (polmap study --world rural --seeds 2
  /// --realism realistic: 3/3 diverged with 0.05°, lateral RMSE 0.068 m with 0.15°). Applied
  /// early, what is left of the bias is of the order of its σ instead of the whole
  /// misalignment (the localizer loosens the odometry by 3σ until convergence), and the
  /// significance test above still keeps noise out.
  double common_yaw_early_sigma_rad = 0.15 * std::numbers::pi / 180.0;
  double common_yaw_early_min_rad = 0.05 * std::numbers::pi / 180.0;
  double common_yaw_early_min_observed_s = 3.0;
  /// Noise model of one detection: σ_i² = σ_vr² + σ_φ²·(g·m)² (as EgoMotionConfig).
  double vr_sigma_mps = 0.07;
  double azimuth_sigma_rad = 0.4 * std::numbers::pi / 180.0;
  /// Gate on a detection's residual (after the block nuisance and the current calibration):
  /// max(gate_sigmas·σ_i, gate_min_mps). Rejects moving objects, multipath, gross errors.
  double gate_sigmas = 3.0;
  double gate_min_mps = 0.15;
  /// Minimum gated detections per sensor in a block; fewer: the sensor's rows are dropped.
  int min_detections_per_sensor = 10;
  /// Weak Gaussian priors around the nominal values (regularize what is not yet observed).
  double prior_yaw_sigma_rad = 2.0 * std::numbers::pi / 180.0;
  double prior_time_offset_sigma_s = 0.02;
  /// Converged when the marginal 1-σ is below these and at least min_observed_s of driving
  /// entered (the σ of correlated errors — multipath, slip — shrinks more slowly than the
  /// information matrix says; the duration guards against early optimism).
  double converged_yaw_sigma_rad = 0.02 * std::numbers::pi / 180.0;
  double converged_time_offset_sigma_s = 0.0002;
  double min_observed_s = 10.0;
};

/// Calibration state. Offsets are relative (gauge: mean over the sensors = 0, see file comment).
struct MountCalibrationResult {
  enum class Status {
    NotObservableYet,  ///< marginal σ above the convergence limit (too little / unsuited driving)
    Converged,         ///< σ below the limit after min_observed_s of driving
  };
  struct Sensor {
    std::uint8_t sensor_id = 0;
    /// True mount yaw − nominal yaw, minus the mean over the sensors (radians; the mean is
    /// included when estimate_common_yaw).
    double yaw_offset_rad = 0.0;
    double yaw_sigma_rad = 0.0;
    Status yaw_status = Status::NotObservableYet;
    /// True measurement time − stamp, minus the mean over the sensors (seconds).
    double time_offset_s = 0.0;
    double time_sigma_s = 0.0;
    Status time_status = Status::NotObservableYet;
    long long detections = 0;  ///< gated detections used so far
  };
  Status status = Status::NotObservableYet;  ///< Converged when every estimate is
  std::vector<Sensor> sensors;               ///< in the order of the mounts
  double observed_s = 0.0;                   ///< driving time (blocks) that entered
  int blocks = 0;
  /// √(residual variance factor): weighted residual RMS, 1 if the noise model is right.
  double residual_sigma_factor = 1.0;
  /// Common yaw (mean of the yaw offsets over the sensors) as the zero-slip blocks see it,
  /// with 1-σ: reported always, in the yaw offsets only with estimate_common_yaw (it is
  /// indistinguishable from a constant side-slip angle, see the file comment).
  double common_yaw_rad = 0.0;
  double common_yaw_sigma_rad = 0.0;
  /// The common yaw is in the yaw offsets (estimate_common_yaw and significant).
  bool common_yaw_applied = false;
  /// ... and good enough to apply to sensors whose own yaw has not converged yet
  /// (MountCalibrationConfig::common_yaw_early_sigma_rad).
  bool common_yaw_applies_early = false;
  /// Covariance of the reported (δψ_1..S, δt_1..S), residual variance factor included.
  Eigen::MatrixXd covariance;
};

const char* to_string(MountCalibrationResult::Status s);

/// Partial derivatives of the static-target radial velocity v_r = h(φ + ψ + δψ)·m(t + δt)
/// (with a rear-axle lateral velocity v_y: v_r −= v_y·sin θ) at δψ = δt = 0.
struct MountDopplerJacobian {
  double v_r_mps = 0.0;     ///< predicted radial velocity
  double d_yaw = 0.0;       ///< ∂v_r/∂δψ  (m/s per rad)
  double d_time = 0.0;      ///< ∂v_r/∂δt  (m/s per s)
  double d_v = 0.0;         ///< ∂v_r/∂v
  double d_yaw_rate = 0.0;  ///< ∂v_r/∂ω
  double d_v_lat = 0.0;     ///< ∂v_r/∂v_y
};
MountDopplerJacobian mount_doppler_jacobian(const Pose2& T_vehicle_sensor, double azimuth_rad,
                                            double v_mps, double yaw_rate_rps, double v_lat_mps,
                                            double accel_mps2, double yaw_accel_rps2);

/// Online estimator of relative mount yaws and time offsets (see file comment). Feed every
/// frame and every ego-motion estimate in time order. Not thread-safe.
class MountCalibrator {
 public:
  /// mounts: the nominal (stored) mounts, the linearization point.
  explicit MountCalibrator(std::vector<SensorMount> mounts, MountCalibrationConfig cfg = {});

  /// Buffers a frame (stamp order; unknown sensors are ignored).
  void add_frame(const SensorFrame& frame);
  /// Buffers an estimate (Ok ones only) and processes every block whose fit window is
  /// complete. Returns true if the calibration changed.
  bool add_estimate(const MotionEstimate& estimate);

  /// Current estimate with covariance and status.
  [[nodiscard]] MountCalibrationResult result() const;
  [[nodiscard]] const MountCalibrationConfig& config() const { return cfg_; }

 private:
  struct Frame {
    std::size_t sensor = 0;
    double stamp_s = 0.0;
    std::vector<Detection> detections;
  };
  struct Motion {
    double time_s, v_mps, yaw_rate_rps;
  };
  void process_block(std::size_t n_frames);
  [[nodiscard]] Eigen::VectorXd solve(Eigen::MatrixXd* covariance) const;

  std::vector<SensorMount> mounts_;
  MountCalibrationConfig cfg_;
  std::deque<Frame> frames_;
  std::deque<Motion> motions_;
  Eigen::MatrixXd info_;     // reduced normal equations Λ (2S × 2S)
  Eigen::VectorXd rhs_;      // η
  Eigen::VectorXd theta_;    // current solution (for gating)
  double chi2_const_ = 0.0;  // Σ (rᵀWr − b_Aᵀ N_AA⁻¹ b_A)
  long long observations_ = 0;
  long long nuisance_ = 0;
  std::vector<long long> detections_;
  double observed_s_ = 0.0;
  int blocks_ = 0;
};

/// Applies a calibration to the ego-motion estimator: converged yaw offsets to the mounts (the
/// common yaw to the others when it applies early), converged time offsets to the stamps
/// (not-converged ones are left at zero).
void apply_mount_calibration(EgoMotionEstimator& estimator, const MountCalibrationResult& result);

}  // namespace polmap::radar
