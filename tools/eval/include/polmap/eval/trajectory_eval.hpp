#pragma once
/// @file trajectory_eval.hpp
/// Localization trajectories (schema/trajectory_csv.md) and their evaluation
/// against a reference trajectory, as in the paper (§IV-C):
///   ε_t = (ε_long, ε_lat)ᵀ = R_gtᵀ (t̂ − t_gt)   (errors in the reference's vehicle frame)
///   ε_rot = arccos(½ tr(R_gtᵀ R̂))              (= |wrap(ŷaw − yaw_gt)| in the plane)
/// reduced to RMSE and maximum over the evaluated samples: samples where the
/// reference speed is > 0.5 m/s and the reference has a carrier-phase fixed
/// solution. Positions are compared in one transverse Mercator frame
/// (tiles::LocalFrame at the reference's first sample); yaws are ENU.
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "polmap/schema/geo.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::loc {
struct LocalizationOutput;
}

namespace polmap::eval {

/// One row of a localization trajectory CSV (schema/trajectory_csv.md).
struct TrajectoryRow {
  double time_s = 0.0;
  std::string status;  ///< initializing | tracking | degraded | lost
  double lat_deg = 0.0;
  double lon_deg = 0.0;
  double yaw_enu_rad = 0.0;
  double cov_xx_m2 = 0.0;  ///< covariance in the local ENU plane (x east, y north)
  double cov_xy_m2 = 0.0;
  double cov_yy_m2 = 0.0;
  double cov_yaw_rad2 = 0.0;
  int matched_points = 0;
  int matched_lines = 0;
  std::uint64_t map_version = 0;
  double graph_ms = 0.0;  ///< graph solve time of this frame, 0 if no solve
  double pl_lat_m = 0.0;  ///< lateral protection level (0: not reported)
};

/// The row of one localizer output (which must have a pose).
[[nodiscard]] TrajectoryRow to_trajectory_row(const loc::LocalizationOutput& out);

/// The CSV header line (without newline) written by TrajectoryCsvWriter.
[[nodiscard]] const std::string& trajectory_csv_header();

/// Streams rows to a CSV file. Throws IoError naming the file.
class TrajectoryCsvWriter {
 public:
  explicit TrajectoryCsvWriter(const std::filesystem::path& path);
  void write(const TrajectoryRow& row);
  void close();

 private:
  std::filesystem::path path_;
  std::ofstream out_;
};

/// Reads a trajectory CSV. Throws IoError (cannot open) or FormatError
/// naming the file, line and column.
[[nodiscard]] std::vector<TrajectoryRow> read_trajectory_csv(const std::filesystem::path& path);

/// A reference pose (ground truth) with the flags the evaluation needs.
struct ReferenceSample {
  double time_s = 0.0;
  double lat_deg = 0.0;
  double lon_deg = 0.0;
  double yaw_enu_rad = 0.0;
  double speed_mps = 0.0;
  bool carrier_phase = true;  ///< GNSS solution was carrier-phase fixed
};

/// Reference from a recording's GNSS/IMU samples (time order).
[[nodiscard]] std::vector<ReferenceSample> reference_from_samples(
    const std::vector<TrajectorySample>& samples);

/// Reference from the simulator's exact truth CSV
/// (time_s,lat_deg,lon_deg,yaw_enu_rad,v_mps,yaw_rate_rps); the carrier-phase
/// flags are taken from `gnss` (nearest sample in time), all true if empty.
[[nodiscard]] std::vector<ReferenceSample> reference_from_truth_csv(
    const std::filesystem::path& path, const std::vector<TrajectorySample>& gnss);

struct TrajectoryEvalOptions {
  double min_speed_mps = 0.5;         ///< paper: standstill (v ≤ 0.5 m/s) excluded
  bool require_carrier_phase = true;  ///< paper: only carrier-phase reference
  /// Rows with these statuses are evaluated; "initializing" rows (before the
  /// first confident match) are excluded by default and counted separately.
  std::vector<std::string> statuses{"tracking", "degraded", "lost"};
};

/// Errors of one evaluated sample.
struct TrajectoryError {
  double time_s = 0.0;
  double long_m = 0.0;
  double lat_m = 0.0;
  double rot_rad = 0.0;  ///< |Δyaw|
  double speed_mps = 0.0;
  std::string status;
  /// Normalized estimation error squared of (long, lat, yaw) under the row's covariance
  /// (rotated into the reference frame; the CSV has no position-yaw cross terms); -1 when
  /// the covariance is not positive definite. χ²(3) if the covariance is consistent.
  double nees = -1.0;
  double sigma_lat_m = 0.0;  ///< the row's 1-σ across the reference heading
  double pl_lat_m = 0.0;     ///< the row's lateral protection level (0: none)
};

/// χ²(3) quantile 0.95: a consistent covariance has 95 % of NEES values below it.
inline constexpr double kChi2Dof3Q95 = 7.814727903251178;

struct TrajectoryMetrics {
  int rows = 0;               ///< rows in the trajectory
  int rows_in_reference = 0;  ///< rows inside the reference's time span
  int evaluated = 0;          ///< rows passing every filter
  int excluded_speed = 0;
  int excluded_not_carrier_phase = 0;
  int excluded_status = 0;
  /// Share of rows (in the reference span, moving) whose reference is
  /// carrier-phase fixed (paper Table IV "Reli. GNSS").
  double reliable_gt_share = 0.0;
  double long_rmse_m = 0.0, long_max_m = 0.0;
  double lat_rmse_m = 0.0, lat_max_m = 0.0;
  double rot_rmse_deg = 0.0, rot_max_deg = 0.0;
  /// Time of the first "tracking" row relative to the first row (-1: never).
  double time_to_tracking_s = -1.0;
  /// Share of rows per status.
  double share_tracking = 0.0, share_degraded = 0.0, share_lost = 0.0, share_initializing = 0.0;
  std::vector<TrajectoryError> errors;  ///< the evaluated samples
  // Uncertainty (issue 15: honest covariance and protection level).
  int nees_samples = 0;                ///< evaluated samples with a positive-definite covariance
  double nees_mean = 0.0;              ///< 3 when consistent
  double nees_within_q95_share = 0.0;  ///< share with NEES ≤ χ²₃(0.95); 0.95 when consistent
  int pl_samples = 0;                  ///< evaluated samples with a protection level
  double pl_bounded_share = 0.0;       ///< share with |lateral error| ≤ protection level
  double pl_mean_m = 0.0;
};

/// Evaluates rows against a time-ordered reference (linear interpolation
/// between reference samples; rows outside its span are skipped).
[[nodiscard]] TrajectoryMetrics evaluate_trajectory(const std::vector<TrajectoryRow>& rows,
                                                    const std::vector<ReferenceSample>& reference,
                                                    const TrajectoryEvalOptions& options = {});

}  // namespace polmap::eval
