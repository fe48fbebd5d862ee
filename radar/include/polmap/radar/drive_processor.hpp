#pragma once
/// @file drive_processor.hpp
/// Mapping-mode processing of one drive (paper §III-B, §III-C): recording -> poses from
/// the georeferenced GNSS/IMU trajectory -> per-frame static-reduced spectra into a
/// full-history covariance gridmap -> pCFAR points and ridge/Hough lines.
///
/// Frame: the drive's tiles::LocalFrame at header.origin (x east, y north). A
/// trajectory sample becomes T_frame_vehicle = (to_local(lat, lon), yaw_enu +
/// convergence(xy)); the pose at a sensor frame's trigger time is interpolated
/// linearly between the bracketing samples (yaw along the shorter arc) and
/// composed with the sensor's mount: T_frame_sensor = T_frame_vehicle·T_vehicle_sensor.
/// Sensor frames wait in a short queue until a trajectory sample at or after their
/// time arrives (records are time-ordered, trajectory ≥ 50 Hz, so the queue holds
/// a few frames). Frames are skipped (and counted) when no pose can be interpolated:
/// more than max_extrapolation_before_s before the first sample, across a trajectory gap longer
/// than max_interpolation_gap_s, more than max_extrapolation_s after the last sample, or from a
/// sensor the header does not declare.
#include <functional>
#include <optional>
#include <vector>

#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/line_extractor.hpp"
#include "polmap/radar/point_extractor.hpp"
#include "polmap/radar/reference_mount_calibration.hpp"
#include "polmap/radar/static_reduction.hpp"
#include "polmap/schema/recording.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::radar {

struct DriveProcessingConfig {
  /// Gridmap settings; window_s is ignored (mapping mode keeps the full history).
  GridmapConfig gridmap;
  PointExtractorConfig points;
  LineExtractorConfig lines;
  bool extract_points = true;
  bool extract_lines = true;
  /// Longest trajectory gap a pose is interpolated across (GNSS outages are
  /// bridged by the IMU in the logged solution; a longer gap means no solution).
  double max_interpolation_gap_s = 0.5;
  /// Frames after the last trajectory sample are posed by constant-velocity
  /// extrapolation up to this long.
  double max_extrapolation_s = 0.1;
  /// Frames up to this long before the first trajectory sample are posed by
  /// extrapolating backwards: the calibrated time offset (mount_calibration) moves a
  /// drive's first frame up to a few milliseconds before the trajectory's start.
  double max_extrapolation_before_s = 0.005;
  /// Frames taken while the vehicle is slower than this (|v| from the trajectory) are
  /// not mapped. At standstill the static Doppler is 0 for every beam, so crossing
  /// traffic (radial velocity ≈ 0) and traffic whose radial velocity aliases onto 0
  /// (±2·v_ua, ±10 m/s) pass the static reduction, and the same viewpoint would
  /// dominate N. 0.5 m/s: the standstill threshold of the paper's evaluation.
  double min_speed_mps = 0.5;
  /// Recompute each frame's spectrum from its data cube (when the frame has one)
  /// by static reduction with the trajectory's (v, ω), instead of using the logged
  /// spectrum; frames without a cube use the logged spectrum.
  bool use_cube = false;
  StaticReductionConfig static_reduction;
  /// Mount yaws and time offsets calibrated against the trajectory
  /// (reference_mount_calibration.hpp): frames are held (not mapped) until the calibration
  /// converged or they span max_calibration_hold_s of drive time, then every frame is mapped
  /// with the calibrated mounts and stamps (frozen for the rest of the drive, so the whole
  /// gridmap shares one calibration). 60 s of frames are ~16 MB of recording.
  ReferenceMountCalibrationConfig mount_calibration;
  double max_calibration_hold_s = 60.0;
  /// The vehicle's motion for the calibration: central differences of the trajectory's
  /// positions and headings over ±motion_difference_s (velocity with side slip; the
  /// acceleration from two such velocities).
  double motion_difference_s = 0.2;
};

struct DriveProcessingStats {
  std::size_t trajectory_samples = 0;
  std::size_t sensor_frames = 0;        ///< sensor frames read
  std::size_t frames_mapped = 0;        ///< added to the gridmap
  std::size_t frames_from_cube = 0;     ///< of which re-reduced from a data cube
  std::size_t frames_without_pose = 0;  ///< skipped: no pose (see file comment)
  std::size_t frames_unknown_sensor = 0;
  std::size_t frames_without_spectrum = 0;      ///< fewer than 2 beams and no usable cube
  std::size_t frames_standstill = 0;            ///< skipped: slower than min_speed_mps
  std::size_t frames_held_for_calibration = 0;  ///< mapped only once the calibration froze
  double start_time_s = 0.0;                    ///< first trajectory sample
  double end_time_s = 0.0;                      ///< last trajectory sample
  double distance_m = 0.0;                      ///< path length of the trajectory (drive frame)
  double gridmap_seconds = 0.0;                 ///< wall time spent in gridmap updates
  double points_seconds = 0.0;                  ///< wall time of point extraction
  double lines_seconds = 0.0;                   ///< wall time of line extraction
  double total_seconds = 0.0;                   ///< wall time of process_drive
};

struct DriveProcessingResult {
  RecordingHeader header;
  tiles::LocalFrame frame;  ///< origin = header.origin
  CovarianceGridmap gridmap;
  std::vector<PointCandidate> points;  ///< metres in `frame`
  std::vector<LineCandidate> lines;    ///< metres in `frame`
  std::vector<TrajectorySample> trajectory;
  DriveProcessingStats stats;
  /// The calibration the frames were mapped with (nullopt when disabled).
  std::optional<ReferenceMountCalibration> mount_calibration;
};

/// Poses of a georeferenced trajectory in a local frame, interpolated at any time.
class TrajectoryInterpolator {
 public:
  explicit TrajectoryInterpolator(tiles::LocalFrame frame, double max_gap_s = 0.5,
                                  double max_extrapolation_s = 0.1,
                                  double max_extrapolation_before_s = 0.005);
  /// Appends a sample; samples must come in increasing time (others are ignored,
  /// returns false).
  bool add(const TrajectorySample& s);
  /// T_frame_vehicle at time t, or nullopt (more than max_extrapolation_before_s before
  /// the first sample, across a gap, beyond the extrapolation limit).
  [[nodiscard]] std::optional<Pose2> T_frame_vehicle(double time_s) const;
  /// Interpolated speed and yaw rate at time t (same validity as the pose).
  [[nodiscard]] std::optional<std::pair<double, double>> motion(double time_s) const;
  /// Time of the last sample (−inf before any).
  [[nodiscard]] double last_time_s() const;
  /// Drops samples older than time_s (keeps the one bracketing it).
  void forget_before(double time_s);
  [[nodiscard]] const tiles::LocalFrame& frame() const { return frame_; }

 private:
  struct Sample {
    double t;
    Pose2 T;
    double v;
    double w;
  };
  /// Index i with s[i].t ≤ t < s[i+1].t, or nullopt.
  [[nodiscard]] std::optional<std::size_t> bracket(double t) const;
  tiles::LocalFrame frame_;
  double max_gap_s_;
  double max_extrapolation_s_;
  double max_extrapolation_before_s_;
  std::vector<Sample> samples_;
  std::size_t first_ = 0;  ///< samples before this index are forgotten
};

/// Processes a whole drive in mapping mode. progress(time_s) is called after each
/// mapped sensor frame. Throws what the source throws (FormatError for corrupt files).
DriveProcessingResult process_drive(RecordSource& source, const DriveProcessingConfig& cfg = {},
                                    const std::function<void(double time_s)>& progress = {});

}  // namespace polmap::radar
