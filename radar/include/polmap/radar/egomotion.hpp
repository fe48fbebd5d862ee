#pragma once
/// @file egomotion.hpp
/// Instantaneous radar ego-motion (paper §III-A, Kellner et al.): forward
/// velocity v and yaw rate ω at the rear-axle centre (zero side slip) from the
/// Doppler detections of all sensors together.
///
/// Model. Sensor s has mount (x_m, y_m, yaw_m). A detection at sensor azimuth φ
/// looks along u = (cos θ, sin θ), θ = φ + yaw_m, in the vehicle frame. The
/// sensor moves with v_s = (v − ω·y_m, ω·x_m), so a static target has
///     v_r = −v_s·u = h·(v, ω)ᵀ,   h = (−cos θ, y_m·cos θ − x_m·sin θ),
/// linear in (v, ω): a two-parameter least-squares problem whose minimal
/// RANSAC sample is two detections.
///
/// Aliasing (Nyquist-zone augmentation). Measured radial velocities are
/// aliased into [−v_ua, v_ua). Instead of folding the model, every detection is
/// copied to v_meas + 2k·v_ua for every zone k whose velocity is physically
/// reachable for that detection's direction (given the configured speed and
/// yaw-rate ranges). Plain RANSAC then runs on the augmented set: wrong copies
/// are just more outliers. The final least-squares refinement uses, per
/// detection, only its best-matching copy.
///
/// Sequential triggering (sensors fire 0/33/66 ms into each cycle). process()
/// combines the new frame with every stored frame at most `combine_window_s`
/// older (default 0.09 s: the most recent frame of each other sensor; a longer
/// window also adds earlier frames of the same sensors). The motion state is not constant over
/// that span, so each older detection is corrected to the new frame's time t
/// with the acceleration a and yaw acceleration α estimated from previous
/// estimates (slope of a line fit over `accel_window_s`):
///     m(t_s) = m(t) − (a, α)·(t − t_s)   ⇒   v_r + h·(a, α)ᵀ·(t − t_s) = h·m(t),
/// i.e. the measured radial velocity of a detection taken at t_s is shifted by
/// the change in radial velocity the extrapolated motion predicts, after which
/// all detections share the unknown m(t). (The target direction need not be
/// corrected: it is the direction at t_s, matching the measurement at t_s.)
/// Without a usable acceleration (start-up, after outages) no shift is applied.
/// The extrapolated acceleration lags when the driver starts braking or
/// accelerating, and a plain combination would then side with the majority of
/// (older) frames. Hence (a) older detections get an inlier threshold widened
/// by the extrapolation uncertainty σ_a·(t − t_s)·|h|, and (b) the final
/// least squares also estimates a correction (δa, δα) to the acceleration,
///     v_r,i = h_i·m(t) − (t − t_i)·h_i·(δa, δα)ᵀ,
/// with a Gaussian prior (σ_a, σ_α) on it, so frames spread over time pull the
/// acceleration to what the data show instead of biasing m(t).
///
/// Plausibility (acceleration limits). With a recent accepted estimate m₀ at
/// t₀, a new estimate must satisfy |v − v₀| ≤ a_max·(t − t₀) + slack_v and
/// |ω − ω₀| ≤ α_max·(t − t₀) + slack_ω. If the best RANSAC hypothesis violates
/// this (e.g. a large moving vehicle dominates the detections), a second
/// RANSAC restricted to hypotheses consistent with the limits looks for the
/// best consistent one; if none has enough inliers the estimate is
/// Status::Rejected. After `max_prior_age_s` without an accepted estimate the
/// prior is dropped (so a wrong prior cannot lock the estimator forever).
///
/// Noise model and weighting. A detection's radial-velocity error combines the
/// Doppler noise σ_vr and the azimuth noise σ_φ propagated through
/// ∂v_r/∂θ = g·(v, ω), g = (sin θ, −y_m·sin θ − x_m·cos θ):
///     σ_i² = σ_vr² + σ_φ²·(g·m)².
/// The inlier threshold scales with σ_i (inlier_threshold_mps at σ_i = σ_vr),
/// and the refinement is weighted least squares with weights 1/σ_i². The
/// covariance is s²·(HᵀWH)⁻¹ with s² = Σ w_i r_i² / (n − 2) (residual variance
/// factor), so it reflects the actual scatter of the inliers.
///
/// Motion prior. If enabled (prior_accel_sigma_mps2 > 0) and a recent
/// estimate exists, the final fit is a maximum-a-posteriori estimate: data
/// (weighted by the residual variance factor) plus a Gaussian prior from the
/// previous estimate (see EgoMotionConfig). Inlier selection and the
/// plausibility checks are unchanged; at least min_inliers static detections
/// and a data-only fit within max_data_*_std are still required, so the prior
/// never produces an estimate (or one of its two directions) on its own.
///
/// Determinism: RANSAC draws from a std::mt19937_64 reseeded at every
/// process() call from (config seed, call number), so a given frame sequence
/// always yields the same estimates.
#include <Eigen/Core>
#include <cstdint>
#include <deque>
#include <numbers>
#include <optional>
#include <vector>

#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::radar {

/// Parameters of EgoMotionEstimator. Defaults suit the paper's sensors (Table III,
/// σ_vr = 0.05 m/s, σ_φ = 0.5°) on passenger cars.
struct EgoMotionConfig {
  /// The vehicle's rear-axle side-slip gradient (linear single-track model, ISO 8855 sign):
  /// β = −gradient · a_y, so the rear axle moves sideways at v_y = −gradient · v² · ω. A
  /// vehicle parameter, like the mounts (Rajamani's passenger car: 0.0040 rad per m/s²).
  /// 0 = the kinematic model (no lateral velocity at the rear axle). Unmodelled, slip
  /// reads as yaw rate: the front sensors see v_y + ω·x as if it were all ω, a yaw-rate
  /// error of v_y / x (1.6°/s at 10 m/s and 3 m/s² with the sensors 3.6 m ahead). The
  /// estimator predicts v_y from the previous speed, which keeps the model linear in (v, ω).
  double side_slip_gradient_rad_per_mps2 = 0.0;
  // --- plausible motion range (bounds the Nyquist zones and RANSAC hypotheses) ---
  /// Highest forward speed considered. Determines how many Nyquist zones are
  /// augmented (25 m/s with v_ua = 5 m/s: up to 4 copies per detection).
  double max_speed_mps = 25.0;
  /// Lowest speed considered (negative = reversing).
  double min_speed_mps = -5.0;
  /// Largest |yaw rate| considered (1 rad/s: tight manoeuvring at walking speed).
  double max_yaw_rate_rps = 1.0;

  // --- noise model and RANSAC ---
  /// Doppler noise σ_vr of one detection.
  double vr_sigma_mps = 0.05;
  /// Azimuth noise σ_φ of one detection; 0 disables the azimuth term.
  double azimuth_sigma_rad = 0.5 * std::numbers::pi / 180.0;
  /// Inlier threshold on |v_r − h·m| for a detection with σ_i = σ_vr (2σ);
  /// scaled by σ_i/σ_vr for detections with larger azimuth sensitivity.
  double inlier_threshold_mps = 0.1;
  /// RANSAC stops when this confidence of having drawn an all-inlier sample is
  /// reached (adaptive), after at least min_iterations and at most max_iterations.
  double ransac_confidence = 0.999;
  int min_iterations = 50;
  int max_iterations = 600;
  /// Fewer static inliers than this -> Status::TooFewDetections.
  int min_inliers = 10;
  /// The same when the motion prior is active (the prior constrains what few
  /// detections leave open; sparse scenes would otherwise lose most estimates),
  /// but only if the inliers are at least this fraction of all combined
  /// detections (else min_inliers applies): a few coincidental fits among many
  /// moving detections must not pass.
  int min_inliers_with_prior = 6;
  double min_inlier_fraction_with_prior = 0.25;
  /// An estimate whose standard deviations exceed these is not reported (its
  /// inliers do not constrain the motion, e.g. all near one azimuth, where an
  /// aliasing zone can be explained by a wrong speed): TooFewDetections, or
  /// Rejected for the limit-consistent fallback.
  double max_v_std_mps = 0.3;
  double max_yaw_rate_std_rps = 0.05;
  /// The same limits for the fit of the detections alone (without the motion
  /// prior): the prior may sharpen an estimate but never supply a direction the
  /// detections leave open (e.g. only points broadside of a truck).
  double max_data_v_std_mps = 0.5;
  double max_data_yaw_rate_std_rps = 0.1;
  /// Refinement rounds (re-select best copies/inliers, re-solve weighted LS).
  int refinement_rounds = 3;
  /// Seed of the RANSAC random generator.
  std::uint64_t seed = 1;

  // --- sequential triggering ---
  /// Frames at most this much older than the new frame are combined with it
  /// (0.09 s: one frame of each of the other two sensors at 10 Hz with offsets
  /// 0/33/66 ms; 0.19 s: two frames of each sensor, √2 less noise, more reliance
  /// on the acceleration model). 0 = per-frame estimates only.
  double combine_window_s = 0.09;
  /// Previous accepted estimates within this window give the acceleration used
  /// to correct older frames to the new frame's time (line fit of v and ω).
  double accel_window_s = 0.3;
  /// At least this many estimates spanning ≥ accel_window_s/3 are needed for an
  /// acceleration; otherwise no correction is applied.
  int accel_min_estimates = 3;
  /// Uncertainty (σ) of that acceleration (it lags at the onset of braking or
  /// accelerating; jerk). Older frames get a wider inlier threshold
  /// accordingly, and the refinement estimates a correction of the
  /// acceleration with this prior σ (see file comment).
  double accel_uncertainty_mps2 = 1.0;
  double yaw_accel_uncertainty_rps2 = 0.1;

  // --- physical plausibility vs. the previous estimate ---
  double max_accel_mps2 = 6.0;        ///< |dv/dt| limit
  double max_yaw_accel_rps2 = 1.0;    ///< |dω/dt| limit
  double accel_slack_mps = 0.3;       ///< added to a_max·Δt (estimate noise)
  double yaw_accel_slack_rps = 0.05;  ///< added to α_max·Δt
  /// A prior older than this is dropped (no limit check).
  double max_prior_age_s = 1.0;

  // --- motion prior (temporal regularization) ---
  /// The previous accepted estimate, extrapolated to the new time (with the
  /// acceleration of accel_window_s), enters the final least squares as a
  /// Gaussian prior with covariance
  ///   P = n_prev · C_prev + diag((σ_a·Δt)², (σ_α·Δt)²),
  /// n_prev = frames with detections the previous estimate combined
  /// (consecutive estimates share most of their frames; inflating C_prev keeps
  /// that data from being counted n times). Where detections constrain the
  /// motion well (σ ≈ 0.01 m/s against σ_a·Δt = 0.07 m/s per 33 ms) the prior
  /// is negligible; where they are few or all at one azimuth it keeps the
  /// poorly observed direction from jumping. 0 disables the prior (purely
  /// instantaneous estimates).
  double prior_accel_sigma_mps2 = 2.0;
  double prior_yaw_accel_sigma_rps2 = 0.5;
};

/// One motion estimate. Valid (v_mps, yaw_rate_rps, covariance) only when
/// status == Ok; otherwise they are NaN — never a made-up value.
struct MotionEstimate {
  enum class Status {
    Ok,                ///< estimate valid
    TooFewDetections,  ///< fewer than min_inliers static inliers, or they leave the
                       ///< motion unconstrained (std above max_v_std_mps / max_yaw_rate_std_rps)
    Rejected,          ///< best hypothesis violates the acceleration limits, no consistent one
  };
  Status status = Status::TooFewDetections;
  double time_s = 0.0;  ///< time the estimate refers to (the newest frame's trigger time)
  double v_mps = 0.0;   ///< forward velocity of the rear-axle centre
  double yaw_rate_rps = 0.0;
  /// Covariance of (v_mps, yaw_rate_rps): residual variance factor × (HᵀWH)⁻¹.
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();
  int num_inliers = 0;     ///< static detections used in the final fit
  int num_detections = 0;  ///< detections of all combined frames
  int num_frames = 0;      ///< sensor frames (with detections) combined
  /// True when the motion was searched within the acceleration limits around the
  /// previous estimates only (every estimate after the first few): a motion outside
  /// them, e.g. that of a truck filling the view, cannot be chosen.
  bool searched_within_limits = false;
  /// True when older frames were corrected with an estimated acceleration.
  bool time_corrected = false;
  /// True when the motion prior (previous estimate) entered the fit.
  bool used_motion_prior = false;
};

const char* to_string(MotionEstimate::Status s);

/// Ego-motion from sequentially triggered Doppler radars. Not thread-safe.
class EgoMotionEstimator {
 public:
  /// mounts: every sensor whose frames will be processed (sensor_id unique).
  EgoMotionEstimator(std::vector<SensorMount> mounts, EgoMotionConfig cfg = {});

  /// Processes one sensor frame (frames in non-decreasing time order, any
  /// sensor) and returns the motion estimate at frame.time_s. Throws
  /// ContractViolation for an unknown sensor_id or a frame older than the last.
  MotionEstimate process(const SensorFrame& frame);

  /// Detections of the last processed frame judged static (inliers of the
  /// final fit), same order as frame.detections; all false unless status Ok.
  [[nodiscard]] const std::vector<bool>& last_static_mask() const { return static_mask_; }

  [[nodiscard]] const EgoMotionConfig& config() const { return cfg_; }
  [[nodiscard]] const std::vector<SensorMount>& mounts() const { return mounts_; }
  /// Mount calibration (MountCalibrator): per mount (same order as mounts()), a yaw added to
  /// the nominal mount yaw and a time offset added to the frame stamps (true measurement
  /// time = stamp + offset). Empty vectors = no correction. Takes effect with the next
  /// frame; estimate times are then corrected times (kept non-decreasing).
  void set_mount_corrections(std::vector<double> yaw_offsets_rad,
                             std::vector<double> time_offsets_s);
  [[nodiscard]] const std::vector<double>& yaw_offsets_rad() const { return yaw_offsets_rad_; }
  [[nodiscard]] const std::vector<double>& time_offsets_s() const { return time_offsets_s_; }
  /// Forgets all history (stored frames, prior, acceleration).
  void reset();

 private:
  struct StoredFrame {
    std::size_t mount_index = 0;
    double time_s = 0.0;
    std::vector<Detection> detections;
  };
  struct Accepted {
    double time_s;
    double v_mps;
    double yaw_rate_rps;
    Eigen::Matrix2d covariance;
    int num_frames;
  };
  [[nodiscard]] std::optional<Eigen::Vector2d> acceleration(double time_s) const;

  std::vector<SensorMount> mounts_;
  EgoMotionConfig cfg_;
  std::deque<StoredFrame> history_;  // frames within combine_window_s, oldest first
  std::deque<Accepted> accepted_;    // recent Ok estimates
  std::vector<bool> static_mask_;
  std::uint64_t calls_ = 0;
  double last_time_s_ = -1e300;
  double last_corrected_time_s_ = -1e300;
  std::vector<double> yaw_offsets_rad_;  // empty or one per mount
  std::vector<double> time_offsets_s_;
};

}  // namespace polmap::radar
