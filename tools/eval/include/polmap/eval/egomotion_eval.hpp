#pragma once
/// @file egomotion_eval.hpp
/// Evaluation of radar ego-motion and odometry against ground truth (used by
/// `polmap egomotion` and bench_egomotion).
///
/// Metrics (EgoMotionMetrics):
///  - velocity / yaw-rate errors of every Ok estimate against the truth
///    interpolated (linearly) at the estimate time: RMSE, max |e|, median |e|,
///    mean e (bias);
///  - odometry drift, two figures:
///    drift_segment_pct = mean over all 100 m sub-paths (starts every 10 m of
///      true path length, KITTI-style) of |Δp_odom − Δp_true| / 100 m, where Δp
///      is the displacement expressed in the vehicle frame at the sub-path start
///      (so each segment is aligned at its start: heading errors before it do
///      not count);
///    drift_endpoint_pct = the same for the single sub-path from the first to
///      the last Ok estimate, divided by its true length.
///    drift_pct is drift_segment_pct when the drive has at least one 100 m
///    sub-path, else drift_endpoint_pct.
#include <Eigen/Core>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "polmap/radar/egomotion.hpp"
#include "polmap/radar/mount_calibration.hpp"
#include "polmap/radar/odometry.hpp"
#include "polmap/schema/pose2.hpp"
#include "polmap/schema/recording.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::eval {

/// One ground-truth motion sample. The pose is in a metric frame (drive frame
/// for georeferenced truth, the truth's own integrated frame otherwise).
struct MotionTruthSample {
  double time_s = 0.0;
  double v_mps = 0.0;
  double yaw_rate_rps = 0.0;
  Pose2 T_frame_vehicle;
};

/// Time-sorted ground truth with interpolation.
class MotionTruth {
 public:
  MotionTruth() = default;
  /// samples: strictly increasing time. If `have_poses` is false the poses are
  /// computed by integrating (v, ω) with the exact arc model (trapezoid rule),
  /// which is exact for the piecewise-linear truth the samples describe.
  MotionTruth(std::vector<MotionTruthSample> samples, bool have_poses);

  /// Linear interpolation (yaw by shortest arc); std::nullopt outside the time range.
  [[nodiscard]] std::optional<MotionTruthSample> at(double time_s) const;
  [[nodiscard]] const std::vector<MotionTruthSample>& samples() const { return samples_; }
  [[nodiscard]] bool poses_integrated() const { return poses_integrated_; }
  [[nodiscard]] bool empty() const { return samples_.empty(); }

 private:
  std::vector<MotionTruthSample> samples_;
  bool poses_integrated_ = false;
};

/// Truth from a recording's georeferenced trajectory (speed_mps, yaw_rate_rps,
/// positions projected into `frame`, yaw converted with the meridian convergence).
MotionTruth truth_from_trajectory(const std::vector<TrajectorySample>& samples,
                                  const tiles::LocalFrame& frame);

/// Reads a truth CSV (header row, time-ordered rows), either
///   time_s,v_mps,yaw_rate_rps                       (poses integrated), or
///   time_s,lat_deg,lon_deg,yaw_enu_rad,v_mps,yaw_rate_rps  (simulator truth,
///     DIR/truth/drive_<k>_trajectory.csv; projected into LocalFrame(origin),
///     origin = the first sample when not given).
/// Columns may come in any order; extra columns are ignored. Throws
/// FormatError naming file, line and column.
MotionTruth read_truth_csv(const std::filesystem::path& path,
                           std::optional<GeoPoint> origin = std::nullopt);

/// One processed frame.
struct EgoMotionRecord {
  std::uint8_t sensor_id = 0;
  radar::MotionEstimate estimate;
  /// Odometry pose at estimate.time_s (std::nullopt before the first Ok
  /// estimate or beyond the hold time).
  std::optional<Pose2> T_odom_vehicle;
  double compute_s = 0.0;  ///< CPU time (calling thread) of EgoMotionEstimator::process
};

/// Runs the estimator and the odometry frame by frame and keeps every result. With a
/// MountCalibrationConfig the mount calibrator runs beside it (it always estimates; it
/// corrects the estimator only if calibrate_mounts), see mount_calibration.hpp.
class EgoMotionRunner {
 public:
  EgoMotionRunner(std::vector<SensorMount> mounts, radar::EgoMotionConfig cfg = {},
                  radar::OdometryConfig odo_cfg = {},
                  std::optional<radar::MountCalibrationConfig> calib_cfg = std::nullopt);
  const EgoMotionRecord& process(const SensorFrame& frame);
  [[nodiscard]] const std::vector<EgoMotionRecord>& records() const { return records_; }
  [[nodiscard]] const radar::Odometry& odometry() const { return odometry_; }
  /// The calibrator (nullptr without a MountCalibrationConfig).
  [[nodiscard]] const radar::MountCalibrator* calibrator() const {
    return calibrator_ ? &*calibrator_ : nullptr;
  }
  /// Driving time at which the calibration first reached Converged (nullopt: never).
  [[nodiscard]] std::optional<double> converged_at_s() const { return converged_at_s_; }
  /// Calibration snapshots every `snapshot_interval_s` (estimate time, result): how it converges.
  [[nodiscard]] const std::vector<std::pair<double, radar::MountCalibrationResult>>&
  calibration_history() const {
    return history_;
  }
  double snapshot_interval_s = 5.0;

 private:
  radar::EgoMotionEstimator estimator_;
  std::optional<radar::MountCalibrator> calibrator_;
  std::optional<double> converged_at_s_;
  std::vector<std::pair<double, radar::MountCalibrationResult>> history_;
  radar::Odometry odometry_;
  std::vector<EgoMotionRecord> records_;
};

struct EgoMotionEvalConfig {
  double segment_length_m = 100.0;  ///< sub-path length of the drift metric
  double segment_step_m = 10.0;     ///< spacing of sub-path starts
};

struct EgoMotionMetrics {
  int frames = 0;
  int estimates_ok = 0;
  int estimates_rejected = 0;
  int estimates_too_few = 0;
  int compared = 0;  ///< Ok estimates with truth at their time
  double v_rmse_mps = 0, v_max_err_mps = 0, v_median_err_mps = 0, v_bias_mps = 0;
  double yaw_rate_rmse_dps = 0, yaw_rate_max_err_dps = 0, yaw_rate_median_err_dps = 0,
         yaw_rate_bias_dps = 0;
  double distance_m = 0;           ///< true path length between first and last Ok estimate
  double odometry_distance_m = 0;  ///< integrated by the odometry
  int drift_segments = 0;
  std::optional<double> drift_segment_pct;
  std::optional<double> drift_endpoint_pct;
  std::optional<double> drift_pct;                   ///< segment figure if available, else endpoint
  std::optional<double> heading_drift_deg_per_100m;  ///< mean over segments
  /// Per-frame compute time (thread CPU time) of EgoMotionEstimator::process.
  double compute_mean_ms = 0, compute_p95_ms = 0, compute_max_ms = 0;
};

EgoMotionMetrics evaluate_egomotion(const std::vector<EgoMotionRecord>& records,
                                    const MotionTruth& truth, const EgoMotionEvalConfig& cfg = {});

/// JSON object of the metrics (keys as the field names; optional ones null).
nlohmann::json to_json(const EgoMotionMetrics& m);

/// Per-estimate CSV: time_s,sensor_id,status,v_mps,yaw_rate_rps,v_std_mps,
/// yaw_rate_std_rps,num_inliers,num_detections,num_frames,odom_x_m,odom_y_m,
/// odom_yaw_rad,truth_v_mps,truth_yaw_rate_rps,compute_ms (empty fields where
/// a value does not exist).
void write_egomotion_csv(const std::filesystem::path& path,
                         const std::vector<EgoMotionRecord>& records, const MotionTruth& truth);

}  // namespace polmap::eval
