#pragma once
/// @file study.hpp
/// The leave-one-out localization study of paper §IV-B..IV-F on simulated
/// drives (`polmap study`).
///
/// For every seed S and polarimetric level L:
///  1. world = sim::load_world(world, length_m, S); N drives of its route are
///     simulated (sim::DriveSimulator, streamed straight into processing, no
///     recording on disk) and processed with level L (radar::process_drive:
///     mapping mode, poses from the drive's own GNSS/IMU trajectory, as in the
///     paper);
///  2. each processed drive is written as a drive package, validated and
///     ingested into a real SqliteMapStore at OUT/seed_S/L/map.sqlite;
///  3. for each drive k: a map version is built from all drives except k
///     (mapping::MapBuilder, excluded_drive_ids = {k}, not made current; paper
///     §IV-B "a separate map ... that includes all drives except its own"),
///     drive k is simulated again (deterministic: same frames) and localized
///     against that version by loc::Localizer with the same level, its tiles read
///     straight from the store (StoreTileSource) or, with `http`, through a real
///     mapping::Server on loopback and loc::TileFetcher (pinned to the version);
///  4. the localizer's poses are compared with the simulator's exact trajectory.
///
/// Initial pose. The localizer gets one coarse pose: the drive's first GNSS
/// sample, displaced by a deliberate error of initial_error_m in a seeded random
/// direction and initial_error_yaw_deg with a seeded random sign (default 3 m /
/// 3°), with σ = that error. After that the localizer reads no ground truth and no
/// GNSS: only radar frames and map tiles.
///
/// Errors (paper §IV-C/D, eval::evaluate_trajectory of trajectory_eval.hpp): at
/// every localizer output with a pose, in the frame of the exact pose
/// interpolated at the output time: (ε_long, ε_lat) = R_gt⁻¹ (t̂ − t_gt),
/// ε_rot = arccos(½ tr(R_gt⁻¹ R̂)). Samples are excluded when the true speed is
/// ≤ 0.5 m/s or the drive's GNSS solution at that time is not carrier-phase
/// fixed (the paper's protocol, kept although the simulator's truth is exact,
/// so figures are comparable), and while the localizer is still Initializing
/// (the initialization from the 3 m / 3° start is reported separately as time
/// to converge). RMSE and max are over the included samples; "Reli. GNSS" is the
/// share of moving outputs whose GNSS is carrier-phase fixed.
///
/// Outputs in OUT: study.json (everything), table.txt (the tables printed),
/// ccdf_lat.svg, ccdf_long.svg, ccdf_rot.svg (complementary CDFs per level,
/// paper Figs. 12/13), and per drive OUT/seed_S/L/loc_drive_k.csv (the
/// localization trajectory, schema/trajectory_csv.md) and errors_drive_k.csv
/// (errors of every output after convergence, with the included flag).
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/localization_client/localizer.hpp"
#include "polmap/localization_client/tile_fetcher.hpp"
#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/line_extractor.hpp"
#include "polmap/radar/point_extractor.hpp"
#include "polmap/schema/polarimetry.hpp"
#include "polmap/sim/config.hpp"

namespace polmap::sim {
class World;
}
namespace polmap::mapping {
class MapStore;
}

namespace polmap::eval {

struct StudyConfig {
  /// urban | industrial | rural | FILE.osm | FILE.xodr (sim::load_world).
  std::string world = "urban";
  /// Route length (procedural worlds; HD maps: upper bound). 600 m keeps the
  /// default study (3 drives, full polarimetry) at a few minutes on 2 cores.
  double length_m = 600.0;
  /// Passes over the route; each is left out once. At least 3: the consensus
  /// needs N_p = 2 drives besides the left-out one.
  int drives = 3;
  /// One world + drive set per seed (world layout, traffic, noise).
  std::vector<std::uint64_t> seeds{1};
  /// Polarimetric levels; mapping and localization use the same level.
  std::vector<PolLevel> levels{PolLevel::Full};
  /// Study directory (created). Stores, packages, figures and CSVs go here.
  std::filesystem::path out_dir;
  /// Drive package format the mapping drives are uploaded in (2: compact, what vehicles
  /// send; 1: lossless Float32 + GeoPackage).
  std::uint32_t package_format = 2;
  /// Format 2 packages without the gridmap (simulate_and_package; the study's maps need
  /// landmarks only, the fleet gridmap does not).
  bool landmarks_only = false;
  /// Tiles through a real Server on loopback + TileFetcher instead of the store.
  bool http = false;
  /// Deliberate error of the initial pose (see file comment).
  double initial_error_m = 3.0;
  double initial_error_yaw_deg = 3.0;
  /// Evaluation protocol (paper §IV-D).
  double min_speed_mps = 0.5;
  bool require_carrier_phase = true;
  /// A drive counts as diverged when, after converging, a translational error
  /// above this occurs (wrong lane or worse), or it never converges.
  double divergence_threshold_m = 1.5;
  /// Simulator settings (seed is overwritten per study seed).
  sim::SimConfig sim;
  /// Mapping-mode processing (the level is overwritten per study level).
  radar::GridmapConfig mapping_gridmap;
  radar::PointExtractorConfig points;
  radar::LineExtractorConfig lines;
  /// Localizer settings (gridmap level overwritten per study level).
  loc::LocalizerConfig localizer;
  /// Keep the package directories (they are copied into the store anyway).
  bool keep_packages = false;
  /// Write OUT/seed_S/L/loc_drive_k.csv.
  bool write_trajectories = true;
  /// Also run diagnose_drive for every left-out drive (doubles the run time).
  bool diagnose = false;
  /// With sim.gnss.grade = Consumer: the first rtk_drives drives are survey-grade (map
  /// anchors). Consumer studies evaluate in the map's own frame (StudyDriveResult::map_*).
  int rtk_drives = 0;
  /// Leave out and localize only the last held_out_drives drives (0: every drive), each
  /// against the map of all others: a large fleet's map costs one build per left-out drive.
  int held_out_drives = 0;
};

/// RMSE and maximum of the included samples.
struct ErrorSummary {
  std::int64_t samples = 0;
  double long_rmse_m = 0.0, long_max_m = 0.0;
  double lat_rmse_m = 0.0, lat_max_m = 0.0;
  double rot_rmse_deg = 0.0, rot_max_deg = 0.0;
  // Uncertainty: NEES of (long, lat, yaw) and the lateral protection level.
  std::int64_t nees_samples = 0;
  double nees_mean = 0.0;              ///< 3 for a consistent covariance
  double nees_within_q95_share = 0.0;  ///< 0.95 for a consistent covariance
  std::int64_t pl_samples = 0;
  double pl_bounded_share = 0.0;  ///< |lateral error| ≤ protection level; target ≥ 0.999
  double pl_mean_m = 0.0;
};

/// Stage diagnosis of one drive against a map (`polmap study --diagnose`):
/// separates the error sources of the chain by replaying the localizer's
/// front end with ground truth where the localizer has estimates.
///  - ego-motion: radar::EgoMotionEstimator + Odometry with the localizer's
///    config; over every window of window_s (the graph window, starts every
///    1 s) the odometry's relative motion is compared with the true one
///    (position error in the vehicle frame at the window start, heading error):
///    what dead reckoning alone would do where no landmark helps;
///  - candidates vs map: a sliding-window gridmap like the localizer's, but
///    posed with the EXACT trajectory (no odometry error), extracted at the
///    localizer's rate; every point candidate is compared with the nearest map
///    point landmark (world frame): share within assoc_radius_m, and the mean
///    and RMS offset of those pairs in the vehicle frame (a mean offset is a
///    bias the graph cannot remove); line candidates likewise by the
///    perpendicular distance of their midpoint to the nearest map line;
///  - observability: per extraction the number of true point pairs; the share
///    of extractions with fewer than 3 (where localization must coast).
/// Matching and graph errors are what remains: localization error where
/// candidates agree with the map and odometry is good.
struct DiagnosisConfig {
  double window_s = 8.0;
  double assoc_radius_m = 0.3;
};
struct DriveDiagnosis {
  // ego-motion / odometry
  std::int64_t egomotion_ok = 0, egomotion_frames = 0;
  double odo_window_pos_rms_m = 0.0, odo_window_pos_max_m = 0.0;
  double odo_window_lat_rms_m = 0.0;
  double odo_window_yaw_rms_deg = 0.0, odo_window_yaw_max_deg = 0.0;
  // candidates vs map (truth-posed sliding window)
  std::int64_t extractions = 0;
  double candidates_per_extraction = 0.0;
  double matched_share = 0.0;  ///< candidates with a map point within assoc_radius_m
  double pairs_per_extraction = 0.0;
  double sparse_extraction_share = 0.0;  ///< extractions with < 3 pairs
  double offset_long_mean_m = 0.0,
         offset_lat_mean_m = 0.0;  ///< candidate − landmark, vehicle frame
  double offset_rms_m = 0.0;
  double line_candidates_per_extraction = 0.0;
  double line_matched_share = 0.0;  ///< midpoint within 0.3 m of a map line
  double line_offset_rms_m = 0.0;
  std::int64_t map_points = 0, map_lines = 0;
};
/// One left-out drive.
struct StudyDriveResult {
  std::uint64_t seed = 0;
  PolLevel level = PolLevel::Full;
  int drive = 0;
  std::string drive_id;
  // --- drive
  double duration_s = 0.0;
  double distance_m = 0.0;
  double reliable_gnss_share = 0.0;  ///< GNSS samples with carrier-phase fix
  // --- mapping
  std::int64_t point_candidates = 0;  ///< of this drive (mapping mode)
  std::int64_t line_candidates = 0;
  std::int64_t map_version = 0;  ///< leave-one-out version
  std::int64_t map_point_landmarks = 0;
  std::int64_t map_line_landmarks = 0;
  double map_build_s = 0.0;
  /// The leave-one-out map's point landmarks against truth (eval/map_geometry.hpp): absolute
  /// offset, RMS after one rigid fit and after a rigid fit per 200 m window. With consumer-
  /// grade GNSS the localization errors are measured in the map's frame (truth moved by the
  /// rigid fit), as a map without survey-grade drives has no better absolute reference.
  double map_offset_m = 0.0;
  double map_rigid_rms_m = 0.0;
  double map_window_rms_m = 0.0;
  /// Matched share of the map's landmarks per 200 m window (pooled, and the worst window):
  /// low where a section of the map broke apart.
  double map_window_share = 0.0;
  double map_worst_window_share = 0.0;
  /// The largest shift of a window's own fit against the whole map's (MapGeometry).
  double map_max_window_shift_m = 0.0;
  bool errors_in_map_frame = false;
  // --- localization
  ErrorSummary errors;
  /// Consumer-grade studies: the errors once more in the map's local frame (truth moved by
  /// the rigid fit of the map's landmarks within the 200 m square around the vehicle,
  /// eval::local_rigid_fit), the frame the relative-geometry target judges a map
  /// in: a map that bends between its sections is a metre off in its global frame there
  /// but consistent where the car is. samples = 0 when not measured.
  ErrorSummary errors_local_frame;
  bool converged = false;        ///< reached Tracking at some point
  double converge_time_s = 0.0;  ///< from the first frame to the first Tracking
  bool diverged = false;         ///< see StudyConfig::divergence_threshold_m
  int lost_events = 0;           ///< transitions into Lost after converging
  double tracking_share = 0.0;   ///< of outputs after converging
  double degraded_share = 0.0;
  double lost_share = 0.0;
  double mean_matched_points = 0.0;  ///< per graph update
  // --- speed and data
  std::int64_t frames = 0;
  double localizer_cpu_s = 0.0;       ///< thread CPU time inside Localizer::process
  double localizer_wall_s = 0.0;      ///< wall time inside Localizer::process (machine load!)
  double realtime_factor = 0.0;       ///< drive time / localizer CPU time
  double realtime_factor_wall = 0.0;  ///< drive time / localizer wall time
  /// Per process() call, thread CPU time.
  double frame_mean_ms = 0.0, frame_p95_ms = 0.0, frame_p99_ms = 0.0, frame_max_ms = 0.0;
  /// CPU time by stage summed over the drive (stage_budget.hpp), and that of helper
  /// threads (the tile fetcher's worker with --http), included in localizer_cpu_s.
  loc::StageCpuTimes stage_cpu;
  double helper_threads_cpu_s = 0.0;
  /// Per extraction (every extract_every_n_cycles cycles), wall time as the
  /// localizer reports it: candidate extraction, and local map + tiles + matching.
  double extraction_mean_ms = 0.0, matching_mean_ms = 0.0;
  std::int64_t graph_updates = 0;
  double graph_update_mean_ms = 0.0, graph_update_p95_ms = 0.0, graph_update_max_ms = 0.0;
  std::uint64_t tile_bytes = 0;  ///< encoded tile bytes fetched (distinct tiles)
  double tile_bytes_per_km = 0.0;
  double simulate_process_s = 0.0;  ///< wall time of simulation + mapping-mode processing
  /// Online mount calibration at the end of the drive against the simulator's true mounts
  /// (offsets true − nominal; relative = minus the mean over the sensors).
  struct Calibration {
    double common_yaw_deg = 0.0;              ///< estimated common yaw (reported always)
    double common_yaw_sigma_deg = 0.0;        ///< its 1-σ
    double common_yaw_true_deg = 0.0;         ///< mean true yaw offset
    bool common_yaw_applied = false;          ///< the localizer applied it (significant, enabled)
    double relative_yaw_max_error_deg = 0.0;  ///< max over sensors |estimated − true|
    double relative_time_max_error_ms = 0.0;  ///< same for the relative time offsets
    double converged_after_s = -1.0;          ///< first Converged, drive time; −1 never
  };
  std::optional<Calibration> calibration;
  /// Stage diagnosis (StudyConfig::diagnose).
  std::optional<DriveDiagnosis> diagnosis;
  // --- per included sample (for CCDFs)
  std::vector<double> sample_time_s;
  std::vector<double> abs_long_m, abs_lat_m, rot_deg;
  std::vector<double> nees;      ///< per included sample, -1 where not available
  std::vector<double> pl_lat_m;  ///< per included sample, 0 where not reported
};

/// Pooled over all drives and seeds of one level.
struct StudyLevelSummary {
  PolLevel level = PolLevel::Full;
  ErrorSummary errors;
  ErrorSummary errors_local_frame;  ///< pooled StudyDriveResult::errors_local_frame
  int drives = 0;
  int converged = 0;
  int diverged = 0;
  double duration_s = 0.0;
  double reliable_gnss_share = 0.0;  ///< duration-weighted
  double realtime_factor = 0.0;      ///< total duration / total localizer CPU time
  double graph_update_mean_ms = 0.0;
  double tile_bytes_per_km = 0.0;
};

struct StudyResult {
  std::string world;
  /// The simulator's error sources: "ideal", "realistic" or the realistic sources kept on.
  std::string realism;
  double length_m = 0.0;
  int drives = 0;
  std::vector<std::uint64_t> seeds;
  bool http = false;
  std::vector<StudyDriveResult> results;  ///< seed-major, then level, then drive
  std::vector<StudyLevelSummary> levels;  ///< in the order of StudyConfig::levels
  std::vector<std::filesystem::path> figures;
  double wall_s = 0.0;
};

/// Progress of run_study (for a terminal line).
struct StudyProgress {
  std::string stage;  ///< "simulate+process", "ingest", "build", "localize", "figures"
  std::uint64_t seed = 0;
  PolLevel level = PolLevel::Full;
  int drive = -1;
  double fraction = 0.0;  ///< of the whole study, [0, 1]
};

// ------------------------------------------------------------------ building blocks
// (used by run_study and by the end-to-end tests)

/// A drive simulated, processed in mapping mode and written as a package directory.
struct StudyPackage {
  std::string drive_id;
  std::filesystem::path dir;
  std::int64_t point_candidates = 0;
  std::int64_t line_candidates = 0;
  double seconds = 0.0;  ///< wall time of simulation + processing + writing
};

/// Simulates drive `drive` of `world` (streamed, no recording), processes it
/// with `level` (cfg.mapping_gridmap / points / lines) and writes the package
/// into package_dir (replaced if present). progress gets the simulated fraction.
StudyPackage simulate_and_package(const std::shared_ptr<const sim::World>& world,
                                  const sim::SimConfig& sim_cfg, int drive, PolLevel level,
                                  const StudyConfig& cfg, const std::filesystem::path& package_dir,
                                  const std::function<void(double fraction)>& progress = {});

struct LocalizeOptions {
  /// HTTP mode: after the initial pose, wait (≤ 20 s, start-up only) until the
  /// tiles around it are in memory.
  loc::TileFetcher* fetcher = nullptr;
  /// Localization trajectory CSV (schema/trajectory_csv.md; empty: none).
  std::filesystem::path csv_path;
  /// Per-output errors CSV: time_s,status,speed_mps,e_long_m,e_lat_m,e_rot_deg,included
  /// (every output after convergence; included = counted in the paper's figures).
  std::optional<std::filesystem::path> errors_csv_path;
  std::function<void(double fraction)> progress;
  /// Called before every sensor frame with its time (tests: stop a server mid-drive).
  std::function<void(double time_s)> before_frame;
  /// Evaluate in the map's frame: truth positions p become R^T (p - t) and yaws lose the
  /// fit's yaw, for a map whose truth ~ R map + t (world frame, metres).
  std::optional<std::pair<Eigen::Matrix2d, Eigen::Vector2d>> truth_to_map;
  /// When set, the errors are evaluated once more (StudyDriveResult::errors_local_frame)
  /// with each truth pose moved by the transform this returns for its position (world
  /// frame); nullopt there: truth_to_map's (or none).
  std::function<std::optional<std::pair<Eigen::Matrix2d, Eigen::Vector2d>>(
      const Eigen::Vector2d& truth_position_m)>
      truth_to_local_map;
};

/// Simulates drive `drive` again (the same frames as for mapping) and localizes
/// it with a Localizer of `level` against `tiles`, starting from the perturbed
/// first GNSS sample; evaluates against the exact trajectory (file comment).
/// Fills everything of StudyDriveResult except the mapping and tile figures.
StudyDriveResult localize_simulated_drive(const std::shared_ptr<const sim::World>& world,
                                          const sim::SimConfig& sim_cfg, int drive, PolLevel level,
                                          const StudyConfig& cfg, loc::TileSource& tiles,
                                          const LocalizeOptions& opt = {});

/// Runs the diagnosis of drive `drive` against map version `version` of `store`
/// (landmarks read from the store). csv_path: per-extraction rows (may be empty).
DriveDiagnosis diagnose_drive(const std::shared_ptr<const sim::World>& world,
                              const sim::SimConfig& sim_cfg, int drive, PolLevel level,
                              const StudyConfig& cfg, const mapping::MapStore& store,
                              std::int64_t version, const DiagnosisConfig& dcfg = {},
                              const std::filesystem::path& csv_path = {});
nlohmann::json to_json(const DriveDiagnosis& d);

/// Runs the study (see file comment). Throws ValidationError for a bad config
/// (fewer than 3 drives, no seeds/levels, empty out_dir), IoError for the
/// study directory, and whatever a stage throws.
StudyResult run_study(const StudyConfig& cfg,
                      const std::function<void(const StudyProgress&)>& progress = {});

/// Pooled summary of a set of drive results (empty -> zero samples).
ErrorSummary summarize_errors(const std::vector<const StudyDriveResult*>& drives);
/// Pools per-drive summaries: RMSEs weighted by samples, maxima, NEES and PL shares.
ErrorSummary pool_error_summaries(const std::vector<ErrorSummary>& parts);

/// Paper Table IV for one level: a row per (seed, drive) and a total row.
std::string format_accuracy_table(const StudyResult& r, PolLevel level);
/// The per-level comparison (§IV-F): one row per level, pooled.
std::string format_level_table(const StudyResult& r);
/// Speed and data figures per level.
std::string format_speed_table(const StudyResult& r);
/// NEES and protection-level figures per level (issue 15's honest uncertainty).
std::string format_uncertainty_table(const StudyResult& r);
/// Per left-out drive: its map's geometry against truth (absolute offset, rigid-fit and
/// 200 m window RMS) and whether its errors are in the map's frame.
std::string format_map_geometry_table(const StudyResult& r);
/// Stage diagnosis per drive (drives without diagnosis are skipped).
/// Online mount calibration per drive against the simulator's truth (empty without one).
std::string format_calibration_table(const StudyResult& r);
std::string format_diagnosis_table(const StudyResult& r);

/// Writes OUT/ccdf_lat.svg, ccdf_long.svg, ccdf_rot.svg (one series per level,
/// log-scale y; diverged drives left out and counted in the series label) and
/// returns their paths.
std::vector<std::filesystem::path> write_ccdf_figures(const StudyResult& r,
                                                      const std::filesystem::path& dir);

nlohmann::json to_json(const ErrorSummary& s);
/// Everything except the per-sample vectors.
nlohmann::json to_json(const StudyResult& r);

}  // namespace polmap::eval
