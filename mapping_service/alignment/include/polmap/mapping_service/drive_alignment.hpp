#pragma once
/// @file drive_alignment.hpp
/// Aligning drives whose trajectories come from consumer-grade GNSS (metre-level, slowly
/// drifting errors) to each other before consensus: a multi-drive pose graph over smooth
/// per-drive corrections of the trajectory, with GNSS priors (the reported accuracy, so
/// survey-grade drives anchor the map absolutely), smoothness between neighbouring nodes
/// (the vehicle's own odometry is locally accurate) and inter-drive landmark associations
/// (point candidates of different drives that are one landmark). Solved with Ceres from a
/// coarse start found by displacement voting, with association gates shrinking from metres
/// to decimetres. Pure computation in one local metric frame (the build frame).
#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <span>
#include <string_view>
#include <vector>

namespace polmap::mapping {

/// One trajectory sample of a drive as the alignment uses it (build frame).
struct AlignmentSample {
  double time_s = 0.0;
  Eigen::Vector2d position_m = Eigen::Vector2d::Zero();
  /// Reported 1-sigma horizontal position accuracy (max of east and north), metres.
  double std_m = 0.0;
  /// Reported 1-sigma heading accuracy, radians.
  double std_yaw_rad = 0.0;
  /// The navigation solution's heading in the build frame (x axis = 0, counter-clockwise),
  /// the wheel speed and the yaw rate: the vehicle's odometry, relative motion that is
  /// accurate over tens of metres where the GNSS position error is not. NaN: unknown (no
  /// heading or speed: no odometry factors for the drive; no yaw rate: the step's heading
  /// comes from the reported heading, whose slow error then bends the map).
  double yaw_rad = std::numeric_limits<double>::quiet_NaN();
  double speed_mps = std::numeric_limits<double>::quiet_NaN();
  double yaw_rate_rps = std::numeric_limits<double>::quiet_NaN();
};

/// A drive as the alignment sees it: its trajectory (time order) and point candidates.
struct AlignmentDrive {
  std::int64_t drive = 0;
  std::vector<AlignmentSample> trajectory;
  std::vector<Eigen::Vector2d> points_m;
};

/// Parameters with documented defaults (README.md, "Maps from consumer-grade GNSS", has
/// what they were measured with).
struct DriveAlignmentConfig {
  /// Drives whose median reported accuracy is at most this are survey-grade: their
  /// corrections are held to their (centimetre) priors and they anchor the map.
  double survey_grade_std_m = 0.1;
  /// Drives whose median reported accuracy is below this are not aligned at all when no
  /// drive exceeds it (align_drives reports NotNeeded): RTK fleets keep today's maps.
  double consumer_grade_std_m = 0.3;
  /// Spacing of the correction nodes along a drive (arc length).
  double node_spacing_m = 10.0;
  /// Change of the correction between neighbouring nodes (1 sigma per node step) for
  /// drives without odometry: the consumer error's bias drifts ~0.2 m per 25 m (sigma
  /// 1.5 m, tau 300 s at 10 m/s) and canyon multipath changes faster, so the graph lets the
  /// landmarks decide.
  double smoothness_sigma_m = 0.3;
  double smoothness_yaw_sigma_rad = 0.002;
  /// Odometry factors between neighbouring nodes (drives whose samples carry heading and
  /// speed): the corrected displacement from node k to k+1 must equal the wheel speed
  /// integrated along the corrected heading, and the corrected heading must change as the
  /// gyro says (yaw rate known) or the heading correction slowly (not). Canyon multipath
  /// repeats at the same place in every drive, so only the vehicle's own motion can tell it
  /// from the road's shape (without odometry the map inherits it: simulated urban route,
  /// 200 m windows 0.16 m RMS).
  bool use_odometry = true;
  /// A step is not odometry (it gets the smoothness prior instead) when samples of a moving
  /// vehicle in it are further apart than odometry_max_gap_s (packages keep one at least
  /// every 2 s, the store every 5 s), or when its integrated length and the GNSS
  /// displacement differ by more than mismatch_m + mismatch_share x length: integrating
  /// speed across a gap that hides an acceleration is off by metres (drives stored before
  /// 2026-12-05, whose trajectories were simplified without keeping the odometry: 5 % of
  /// the urban 10 m steps off by > 2.7 m), while the consumer GNSS error changes by
  /// centimetres over a step. (A fixed 0.5 s gap rule also dropped a third of the good
  /// steps: compact packages keep samples up to 2 s apart on straight roads.)
  double odometry_max_gap_s = 2.5;
  double odometry_max_length_mismatch_m = 0.5;
  double odometry_max_length_mismatch_share = 0.05;
  /// Tyre slip in the integration (0 turns a term off). A car's rear axle moves at the
  /// side-slip angle beta = -gradient x a_y to its heading (a_y = speed x yaw rate; ISO 8855
  /// signs, the rear drifts out of the turn), and its wheels turn faster than it moves when
  /// they drive and slower when they brake: v = v_wheel / (1 + a_x / (g x slip stiffness)).
  /// Both repeat at the same curve and the same stop in every drive, so associations cannot
  /// see them and the map would inherit them (an urban 90-degree turn at 3 m/s^2 moves the
  /// next leg ~0.4 m sideways without the side slip). Defaults: the linear single-track
  /// model of a mid-size passenger car (Rajamani, Vehicle Dynamics and Control, 2nd ed.,
  /// ch. 2-3: 0.23 deg per m/s^2 at the rear axle) and dry asphalt (mu-slip slope ~30,
  /// Gustafsson 1997); a fleet backend would keep them per vehicle model.
  double odometry_side_slip_gradient_rad_per_mps2 = 0.0;
  double odometry_slip_stiffness = 0.0;
  /// Displacement noise per step: sigma_m + sigma_per_m x step length (wheel-speed noise
  /// and slip; the scale error is a parameter of its own below).
  double odometry_sigma_m = 0.02;
  double odometry_sigma_per_m = 0.002;
  /// Change of the heading correction per step: sigma_rad + sigma_per_m x step length (the
  /// simulator's consumer heading error, 0.3 deg with tau 60 s, changes ~0.001 rad per
  /// 10 m at 10 m/s).
  double odometry_yaw_sigma_rad = 0.0005;
  double odometry_yaw_sigma_per_m = 0.0001;
  /// With the yaw rate: the integrated gyro's heading-change noise per step,
  /// sigma_rad + sigma_per_m x step length (white rate noise; its bias is estimated).
  double gyro_sigma_rad = 0.0003;
  double gyro_sigma_per_m = 0.00002;
  /// Per drive: wheel-odometry scale error (1 sigma, relative) and yaw-rate bias (rad/s,
  /// an automotive MEMS gyro after the car's standstill calibration: ~0.1 deg/s), estimated.
  double odometry_scale_sigma = 0.003;
  double gyro_bias_sigma_rps = 0.002;
  /// The wheel-scale errors and yaw-rate biases are held at their prior (0) in association
  /// rounds whose gate exceeds this and estimated in the finer ones. Coarse rounds associate
  /// neighbouring objects wrongly, and those associations pull every drive's scale the same
  /// way: on the simulated urban route (10 consumer drives, 600 m) the 2 m round took the
  /// fleet to -1.9 % with exact wheel speeds and the finer rounds kept the shrunk geometry
  /// at -0.36 % (window share 0.93; 0.96 with this at 0.3). README "Maps from
  /// consumer-grade GNSS" has the measurements.
  double odometry_parameters_gate_m = 0.3;
  /// The mean wheel-scale error of the consumer-grade drives is 0 within this (one factor
  /// over all of them, estimated in the same rounds; 0: no such factor). Cars' scale errors
  /// are independent, but associations tie the drives together and cannot see a stretch or
  /// shrink they share, and each drive's own prior lets all of them move together: without
  /// it, on the simulated urban route with exact wheel speeds, the fleet's scale went to
  /// -0.23 % (10 drives, 600 m) and -0.37 % (19 drives, 2 km), and the map followed (200 m
  /// window RMS 0.141 m, 0.103 m with it; realistic preset 0.150 -> 0.103 m). README "Maps
  /// from consumer-grade GNSS" has the measurements.
  double fleet_scale_sigma = 0.0005;
  /// Length over which the GNSS error of one drive is correlated: the reported sigma is
  /// applied once per this length, not once per node (the priors are not independent).
  double gnss_correlation_length_m = 300.0;
  /// A point candidate takes the correction at this arc length ahead of (positive) the
  /// trajectory point nearest to it: where the drive mostly observed it. Its position in
  /// the drive's gridmap carries the trajectory error of the frames that saw it, and
  /// forward-looking radars see an object mostly before the car passes it; with a place-
  /// dependent error (canyon multipath, ~0.04 m per m) the error at the nearest point is
  /// the wrong one. Measured on the simulated urban route (front and corner radars, 10
  /// consumer drives; README "Maps from consumer-grade GNSS"): share of real landmarks
  /// within 0.3 m after their window's fit 0.68 at 0 m, 0.81 at -5, 0.93 at -10, 0.91 at
  /// -15, 0.78 at -20; the alignment residual is lowest there too. Depends on the sensor
  /// layout: a fleet backend would keep it per vehicle model.
  double candidate_lead_m = -10.0;
  /// Weight of a candidate-landmark association (1 sigma; the pCFAR centroid noise). A
  /// weaker weight was measured on 2026-12-07 (README "Maps from consumer-grade GNSS"): at
  /// 0.5 m the common wheel-scale error that 0.08 m gives unanchored fleets (-0.4 % over
  /// 600 m, -0.7 % over 2 km, with exact wheel speeds: the map shrinks and bends) vanishes
  /// and their maps match truth better, but localization against the maps got worse where
  /// it counts: 2 RTK + 18 consumer drives on 2 km 0.063 / 0.077 m -> 0.191 / 0.199 m
  /// (long / lat RMSE). The scale pull came from the coarse association rounds and a
  /// common stretch no association sees (odometry_parameters_gate_m, fleet_scale_sigma).
  double candidate_sigma_m = 0.08;
  /// Coarse start: displacements to other drives' candidates within this radius are voted
  /// into an image of vote_cell_m cells per window of +-vote_window_nodes nodes.
  double vote_radius_m = 6.0;
  double vote_cell_m = 0.2;
  int vote_window_nodes = 3;
  int vote_rounds = 2;
  /// Association gates of the refinement rounds (metres, coarse to fine).
  std::vector<double> gates_m = {2.0, 1.0, 0.5, 0.3};
  /// A cluster (one landmark) needs candidates of at least this many drives.
  int min_cluster_drives = 3;
  /// Ceres iterations per round.
  int max_iterations = 50;
};

/// The correction of one drive: nodes along its trajectory with (dx, dy, dyaw), linearly
/// interpolated by arc length, each the correction of the vehicle's pose there (position,
/// heading). A trajectory point takes the correction at its own arc length; a candidate the
/// correction where it was seen from (candidate_lead_m past its nearest trajectory point),
/// turned about that trajectory point as the pose error turned it.
struct DriveCorrection {
  std::int64_t drive = 0;
  bool survey_grade = false;
  /// Arc length of each node along the trajectory and the trajectory position there.
  std::vector<double> node_s_m;
  std::vector<Eigen::Vector2d> node_position_m;
  /// (dx_m, dy_m, dyaw_rad) per node.
  std::vector<Eigen::Vector3d> node_correction;
  /// The drive's trajectory resampled every ~1 m (position, arc length) for lookups.
  std::vector<Eigen::Vector2d> path_m;
  std::vector<double> path_s_m;
  /// The drive's odometry as the alignment used it: node steps constrained by odometry,
  /// steps that failed the gap or length test (they got the smoothness prior instead), and
  /// the estimated wheel-speed scale error (relative) and yaw-rate bias.
  int odometry_steps = 0;
  int odometry_steps_rejected = 0;
  double odometry_scale_error = 0.0;
  double gyro_bias_rps = 0.0;

  /// Candidates take the correction this far ahead of their nearest trajectory point
  /// (DriveAlignmentConfig::candidate_lead_m).
  double candidate_lead_m = 0.0;

  /// p corrected (p in the build frame as the drive reported it). Identity without nodes.
  /// A candidate takes the correction candidate_lead_m ahead, a trajectory point its own.
  [[nodiscard]] Eigen::Vector2d apply(const Eigen::Vector2d& p_m, bool candidate = true) const;
  /// Interpolated (dx, dy, dyaw) at arc length s.
  [[nodiscard]] Eigen::Vector3d at(double s_m) const;
  /// Arc length of the trajectory point nearest to p (brute force over path_m: the caller
  /// corrects a few thousand points per drive).
  [[nodiscard]] double nearest_s_m(const Eigen::Vector2d& p_m) const;
};

/// Outcome of align_drives.
struct DriveAlignmentResult {
  enum class Status {
    Aligned,    ///< consumer-grade drives were aligned
    NotNeeded,  ///< every drive is better than consumer_grade_std_m: nothing changed
    NoOverlap,  ///< consumer-grade drives but no landmark shared by enough drives
  };
  Status status = Status::NotNeeded;
  std::vector<DriveCorrection> corrections;  ///< one per input drive, same order
  int survey_grade_drives = 0;
  int consumer_grade_drives = 0;
  int clusters = 0;                ///< landmarks associated in the final round
  int associations = 0;            ///< candidate-landmark residuals in the final round
  double residual_rms_m = 0.0;     ///< RMS candidate-landmark distance after the final round
  double mean_correction_m = 0.0;  ///< mean |(dx, dy)| over the consumer-grade nodes
  int odometry_drives = 0;         ///< consumer-grade drives constrained by odometry
  /// Over those drives: steps that failed the odometry gap or length test, and the mean and
  /// RMS of the estimated wheel-scale errors. Cars' scale errors are independent, so a mean
  /// far from fleet_scale_sigma says something pulls the map's length against the factor
  /// that holds it (2026-12-07, simulated urban route, seed 1, 19 drives on 2 km: -0.30 %
  /// with it, true 0). The same factor for the yaw-rate biases (whose mean is +0.007 deg/s
  /// there, true 0) was measured at 1e-4 and 3e-5 rad/s and changed neither window RMS nor
  /// bend.
  int odometry_steps_rejected = 0;
  double scale_error_mean = 0.0;
  double scale_error_rms = 0.0;
  /// Mean and RMS of those drives' estimated yaw-rate biases (rad/s).
  double gyro_bias_mean_rps = 0.0;
  double gyro_bias_rms_rps = 0.0;
  double seconds = 0.0;
};
std::string_view to_string(DriveAlignmentResult::Status s);

/// Aligns the drives (see the file comment). Drives without trajectory keep the identity.
DriveAlignmentResult align_drives(std::span<const AlignmentDrive> drives,
                                  const DriveAlignmentConfig& cfg = {});

}  // namespace polmap::mapping
