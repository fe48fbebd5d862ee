#pragma once
/// @file localizer.hpp
/// Radar-only map-based localization (paper §III, docs/architecture.md), the facade
/// of the client library. Per sensor frame:
///
///   ego-motion (radar::EgoMotionEstimator) -> integrated odometry
///   (radar::Odometry, defines the odometry frame) -> sliding-window covariance
///   gridmap in the odometry frame -> every `extract_every_n_cycles` radar
///   cycles (at the last-triggered sensor's frame): pCFAR point candidates
///   and, every 10th extraction or when fewer than 5 points matched, ridge/
///   Hough line candidates -> local-map clustering -> map
///   landmarks from tiles around the predicted pose (non-blocking
///   TileSource) -> matching -> temporal smoothing -> sliding-window graph
///   -> pose + covariance.
///
/// Frames. The client's map frame is tiles::LocalFrame at the position of the
/// first initial pose (set_initial_pose); tile-frame landmark positions are
/// converted into it through geodetic coordinates. Outputs carry both
/// T_map_vehicle and the WGS84 GeoPose.
///
/// Status.
///  - Initializing: no confident match yet. Matching searches the wide gate
///    of the initial pose (σ given to set_initial_pose, grown with the
///    distance driven); tracking starts when consecutive clearly unambiguous
///    matches agreed with each other over enough driving (initialization.hpp). The output meanwhile
///    is the initial pose moved by odometry.
///  - Tracking: landmark observations entered the graph within degraded_after_s.
///  - Degraded: none for longer (landmark-poor road, map gap, outside the
///    map): the graph integrates odometry from a pose prior, the covariance grows.
///  - Lost: the position σ exceeded lost_sigma_m or no landmark was associated
///    for lost_after_s. The graph and smoothing are reset and initialization
///    restarts around the current estimate with a gate widened to at least the
///    initial σ; the status stays Lost until a confident match.
/// While tracking, a periodic wide-gate relocalization check re-anchors when a
/// clearly better match disagrees with the estimate (LocalizerConfig). An
/// ego-motion outage widens the uncertainty by its length and restarts the
/// graph window (no odometry factor across the bridged arc).
///
/// Ground truth is never read. Not thread-safe (one instance per vehicle).
#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <numbers>
#include <optional>
#include <string_view>
#include <vector>

#include "polmap/localization_client/graph.hpp"
#include "polmap/localization_client/initialization.hpp"
#include "polmap/localization_client/local_map.hpp"
#include "polmap/localization_client/matcher.hpp"
#include "polmap/localization_client/smoothing.hpp"
#include "polmap/localization_client/tile_source.hpp"
#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/egomotion.hpp"
#include "polmap/radar/line_extractor.hpp"
#include "polmap/radar/mount_calibration.hpp"
#include "polmap/radar/odometry.hpp"
#include "polmap/radar/point_extractor.hpp"
#include "polmap/schema/geo.hpp"
#include "polmap/schema/pose2.hpp"
#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::loc {

/// cfg with chunk_tiles set (for the defaults below).
template <typename ExtractorConfig>
ExtractorConfig with_chunk_tiles(ExtractorConfig cfg, int chunk_tiles) {
  cfg.chunk_tiles = chunk_tiles;
  return cfg;
}

inline radar::LineExtractorConfig without_spread_rejection(radar::LineExtractorConfig cfg) {
  cfg.spread_min_decay_db_per_m = 0.0;
  return cfg;
}

/// All parameters of the pipeline; defaults are the paper's where it gives
/// them (Weishaupt et al. 2024, §IV-B), otherwise documented choices.
struct LocalizerConfig {
  radar::EgoMotionConfig egomotion;
  radar::OdometryConfig odometry;
  /// Online calibration of the mounts (radar/mount_calibration.hpp): each sensor's mount
  /// yaw and time offset relative to the others, estimated from the Doppler residuals while
  /// driving; once converged, the ego-motion and the sliding-window gridmap use them.
  /// Radar alone observes relative yaws and time offsets; a yaw common to all mounts looks
  /// like side slip. The localizer also estimates the common yaw from straight driving
  /// (where the slip model predicts no slip): on the realistic simulator preset it took the
  /// urban study from one diverged drive of three (lateral RMSE 1.20 m) to none (0.145 m).
  /// It is applied only when it stands out of its noise (MountCalibrationConfig::
  /// common_yaw_min_sigmas): applied always, it cost the ideal preset's urban 800 m drives
  /// 0.065 -> 0.075 m lateral RMSE pooled (polmap study --no-calibrate-common-yaw compares).
  bool online_mount_calibration = true;
  /// Side slip the radar odometry does not model (it assumes no lateral velocity at the
  /// rear axle): in a curve the rear axle drifts out at β ≈ gradient · a_y. The odometry
  /// factor between two graph poses gets σ_across = gradient · |a_y| · distance and
  /// σ_yaw = gradient · |Δa_y| (a_y = v · ω from the odometry) on top of the graph's
  /// sigmas, so landmarks, not the odometry, decide the pose in curves. 0.5°/(m/s²): a
  /// conservative passenger-car value (typical rear-axle slip gradients 0.2–0.4°/(m/s²)).
  double odometry_slip_gradient_rad_per_mps2 = 0.5 * 3.14159265358979323846 / 180.0;
  /// The yaw common to all mounts that the calibration has not yet removed reads as a
  /// yaw-rate bias of v·δψ̄/x (x: the sensors' mean distance ahead of the rear axle), so the
  /// odometry factor gets σ_yaw += distance · u / x, with u this tolerance until the
  /// calibration has a common-yaw estimate, then 3 of its σ (once converged ~0.015°, which
  /// adds 0.0004 rad per 5 m factor). 0.3°: the σ of corner-radar mounts after end-of-line
  /// alignment (tools/sim/README.md "Realism"). Not applied without online_mount_calibration
  /// (the stored mounts are then taken as exact).
  double mount_common_yaw_tolerance_rad = 0.3 * 3.14159265358979323846 / 180.0;
  radar::MountCalibrationConfig mount_calibration = [] {
    radar::MountCalibrationConfig c;
    c.estimate_common_yaw = true;
    return c;
  }();
  /// Sliding-window gridmap (window_s > 0 = localization mode). 2 s: ~20 m of
  /// driving at 10 m/s and 60 sensor frames per cell, long enough for stable
  /// pCFAR statistics, short enough that odometry drift stays below a cell.
  /// Range bins up to 50 m only: with ~3° beams a return at 50 m is smeared over
  /// 2.6 m across the beam (4 m at 80 m), so farther candidates are imprecise to
  /// match and constrain the pose little, while the window's area, hence the cost
  /// of the gridmap and of every extraction, grows with the range squared. On
  /// `polmap study` (2026-12-02, bench/baselines/b1f2c99) 50 m kept urban and rural
  /// accuracy within 5 % of the full 80 m at b95f220, and industrial and the
  /// OpenDRIVE world more accurate; 40 m lost up to 2× lateral accuracy on single
  /// urban drives, and the full range cost ~1.6× the CPU of 55 m (urban, seed 1).
  radar::GridmapConfig gridmap{0.1, PolLevel::Full, 2.0, 50.0};
  /// Extraction over the whole window in one chunk (32 tiles = 205 m): a 2 s window
  /// to 50 m fits, and no chunk halos are processed twice. Mapping keeps 8-tile chunks
  /// (bounded memory on long drives).
  radar::PointExtractorConfig points = with_chunk_tiles(radar::PointExtractorConfig{}, 32);
  /// Without the mapping's rejection of point-target azimuth smears: a line candidate the
  /// map does not have is simply not matched, and the rejection cost the client lines it
  /// matches (polmap study --world urban --length-m 600 --drives 3, 2026-12-04: lat / rot
  /// RMSE 0.061 m / 0.18 deg with it, 0.056 m / 0.14 deg without).
  radar::LineExtractorConfig lines =
      without_spread_rejection(with_chunk_tiles(radar::LineExtractorConfig{}, 32));
  LocalMapConfig local_map;
  MatcherConfig matcher;
  SmoothingConfig smoothing;
  GraphConfig graph;
  /// Candidates are extracted every this many radar cycles (at the frame of
  /// the last-triggered sensor). 4 cycles = 2.5 Hz: the 2 s gridmap changes
  /// little within 0.4 s, extraction dominates the per-frame cost, and on
  /// bench_localizer (urban, rural, industrial; oracle map, seed 2) 4 was as
  /// accurate as 3 (2026-12-02), as 3 had been as 2.
  int extract_every_n_cycles = 4;
  /// Lines every this many extractions, or whenever fewer than
  /// lines_below_point_matches points matched (paper §IV-B: 10th frame / < 5).
  int lines_every_n_extractions = 10;
  int lines_below_point_matches = 5;
  /// The few-points trigger fires at most every this many extractions: where points
  /// are few it fires every time, and line extraction (image filters over the whole
  /// window) then dominates the client's CPU. 2: lines at 1.25 Hz there.
  int lines_min_interval_extractions = 2;
  /// Map landmarks within this radius of the predicted position are matched
  /// (radar range 80 m + margin for the gate).
  double map_radius_m = 120.0;
  /// Tiles around the position predicted this far ahead are prefetched.
  double prefetch_lookahead_s = 20.0;
  /// Below this many distinct point landmarks in the graph window (lines
  /// count half) the last pose gets a prior (paper: PriorFactorPose2 when
  /// under-constrained).
  double min_landmarks_without_pose_prior = 3.0;
  /// A solution that moves the newest pose further from the prediction than this squared
  /// Mahalanobis distance (under the predicted covariance; 7.81 = χ²₃ at 95 %; at 99.9 %
  /// an HD-map world still lost a drive to a 0.86 m, 1.3° move at 3.4 σ) while
  /// fewer than min_landmarks_without_pose_prior landmarks were observed in the newest
  /// pose_prior_recent_s is solved again with a prior from the prediction on that pose.
  /// A few landmarks seen from older poses fix the newest ones poorly: three points seen
  /// 5 s earlier turned an HD-map world's window by 14° and 9 m once the last pose prior
  /// had left the window. 0 disables the check.
  double max_unobserved_move_chi2 = 7.81;
  double pose_prior_recent_s = 2.0;  ///< "observed lately" for max_unobserved_move_chi2
  /// Standstill hold: while the odometry has moved less than these since the
  /// last graph pose, the graph is not extended and the estimate is held. A
  /// standing car does not move; re-solving the same view every extraction
  /// only lets a few biased bearings rotate the window (up to 1.5 deg over a
  /// 20 s stop at a traffic light in `polmap study --world urban`). Standstill
  /// time neither degrades the status nor ages the graph window.
  double standstill_translation_m = 0.05;
  double standstill_yaw_rad = 0.002;
  /// Gate floor added to the predicted covariance while tracking: the graph's
  /// covariance can be optimistic, matching must still find its landmarks.
  double tracking_gate_floor_xy_m = 0.5;
  double tracking_gate_floor_yaw_rad = 0.02;
  /// Tracking matches the local map as seen since the odometry heading last differed
  /// from the current one by more than this (LocalMap::recent), but at least
  /// tracking_min_window_s back. The local map lives in the odometry frame, and in a
  /// curve the odometry's yaw-rate error (side slip beyond the slip model) bends it: the
  /// rigid match then pivots about the landmarks far behind the vehicle and turns the
  /// estimate away from the road. 0 disables the limit (the whole window is matched).
  /// 5° (README "Table IV under both presets", 10 seeds, 2026-12-06): under the realistic
  /// preset the lateral RMSE fell from 0.334 to 0.133 m (urban) and 3.35 to 0.165 m
  /// (rural), the largest lateral error from 5.5 to 1.6 m and 27.7 to 2.3 m; the ideal
  /// preset lost 0.00-0.01 m lateral and 0.01-0.03° rotation RMSE.
  double tracking_max_heading_span_rad = 5.0 * std::numbers::pi / 180.0;
  double tracking_min_window_s = 2.0;
  /// Initialization (initialization.hpp): a match counts when it is unambiguous with at
  /// least min_point_matches (6) associations and beats its best distinct alternative
  /// by min_margin (3 cost units); tracking starts when consecutive counting matches
  /// agreed (within 1 m / 1° at the current odometry pose) at least confirmations (2)
  /// times AND the streak spans min_travel_m (20 m) of driving. Agreement of matches
  /// 0.2 s apart says little (the local map barely changed); agreement over 20 m of new
  /// landmarks rejects a wrong fit to a periodic post row. Matches that do not count
  /// but agree continue the streak. The margin: the matcher's own ambiguity_margin (1)
  /// is for tracking, where the gate is tight; along a guardrail the candidates one post
  /// spacing apart differ by 1-3 units, and without the margin the alias won the
  /// initialization on 2 of 30 rural drives of the realistic preset (3.7 and 6.3 m
  /// along the road); ending the streak at every weak match let the gate grow until
  /// an alias 6 m off won (`polmap study --world rural --seeds 1,7 --realism realistic`).
  InitializationConfig initialization;
  /// Covariance of the first graph pose after a confident initialization.
  double init_pose_sigma_xy_m = 0.5;
  double init_pose_sigma_yaw_rad = 0.02;
  /// Relocalization check while tracking: every this many extractions the
  /// local map is also matched in the wide initial gate (at the frame after the
  /// extraction: the check costs about as much as an extraction, and no single
  /// frame should carry both). If that finds a match that would count in
  /// initialization (counts_for_initialization) with at least
  /// relocalization_extra_matches more associations than the tracking match, away from
  /// the current estimate (> max(1 m, 3σ) or > max(1.5°, 3σ)), twice in a row and
  /// agreeing (within relocalization_agreement_*), the localizer re-anchors there (a
  /// wrong initialization or a divergence that the graph's own covariance cannot reveal;
  /// initialization.hpp, RelocalizationConfirmation). 0 disables the check. Without the
  /// margin, a degraded stretch (2 tracking associations) re-anchored an urban drive 11 m
  /// sideways on two checks of 6 associations and margins of 1.2 and 1.5. Tried: the
  /// confirming check at the next extraction within 2.5 m / 2°. It re-anchored rural
  /// seed 6 drive 3 (realistic; lat RMSE 18.3 -> 1.2 m), but two checks 0.4 s apart
  /// agree on a guardrail alias as easily as on the truth, and two other rural drives
  /// were re-anchored 4.6 and 6.3 m along the road (10 seeds: 4/30 lost against 2/30).
  int relocalization_every_n_extractions = 10;
  double relocalization_agreement_xy_m = 1.0;
  double relocalization_agreement_yaw_rad = 0.0175;
  int relocalization_extra_matches = 3;
  /// The check's search (the matcher's pair and voting generators in the wide gate)
  /// uses fewer anchor clusters and yaw hypotheses than the initial search: it only has
  /// to notice a clearly better pose, and acts after two agreeing checks. 8 anchors
  /// (28 pairs instead of 91) and 41 yaw steps (0.6° in the 3σ gate of 3°) cost about a
  /// third of the full search (bench_localizer, industrial).
  int relocalization_max_anchor_clusters = 8;
  int relocalization_max_yaw_hypotheses = 41;
  /// Status thresholds (see file comment).
  double degraded_after_s = 2.0;
  double lost_after_s = 30.0;
  double lost_sigma_m = 3.0;
  /// Prediction noise between graph solutions, per metre driven (dead
  /// reckoning from radar odometry: ~1 % of distance, ~0.1°/m).
  double prediction_sigma_per_m = 0.01;
  double prediction_sigma_yaw_per_m = 0.002;
  /// Reported uncertainty (LocalizationOutput::covariance, protection_level_lat_m). The
  /// graph's covariance treats map landmarks as exact and candidates as independent, so it
  /// is optimistic; what is reported is
  ///   reported_covariance_scale · C + diag(floor_xy², floor_xy², floor_yaw²),
  /// calibrated on studies so that the NEES of the pose is consistent (polmap study's
  /// uncertainty table). Gates and priors inside the localizer keep the graph's own C.
  /// Defaults from `bench/calibrate_uncertainty.py --folds 2` over the four realistic-preset
  /// 10-seed studies of README "Table IV with parked cars that move" (2026-12-07): scale 2,
  /// floor 0.05 m / 0.3°, k 5.77 (the larger of the two folds' fits). Held out, NEES is
  /// within χ²₃(0.95) on 95.6 % (seeds 6-10) and 98.3 % (1-5) of the samples; over all
  /// 151,949 realistic samples 97.0 %, the protection level bounds 99.95 %, mean PL 1.04 m.
  /// (2026-12-06: scale 1, floor 0.05 m / 0°, k 8.04: NEES 91.6 % held out.)
  double reported_covariance_scale = 2.0;
  double reported_sigma_floor_xy_m = 0.05;
  double reported_sigma_floor_yaw_rad = 0.005236;
  /// Lateral protection level = protection_level_k · the reported lateral σ. A Gaussian's
  /// two-sided 99.9 % quantile is 3.29; the errors' tails are heavier (the excursions of
  /// up to 2.5 m in curves under the realistic preset), so the default is set from studies
  /// so that the level bounds the lateral error on ≥ 99.9 % of samples.
  double protection_level_k = 5.77;
};

/// CPU time (thread CPU clock) of each stage of process() calls, seconds. Per call in
/// LocalizationOutput; sums of many calls give a per-stage budget.
struct StageCpuTimes {
  double egomotion_s = 0.0;   ///< ego-motion estimate and odometry
  double gridmap_s = 0.0;     ///< sliding-window gridmap update (add and expire)
  double points_s = 0.0;      ///< pCFAR point candidates
  double lines_s = 0.0;       ///< line candidates
  double clustering_s = 0.0;  ///< local-map clustering of the candidates
  double tiles_s = 0.0;       ///< map tiles around the pose (conversion, landmark index)
  double matching_s = 0.0;    ///< local map to map landmarks (and the relocalization check)
  double smoothing_s = 0.0;   ///< association smoothing and graph bookkeeping
  double graph_s = 0.0;       ///< graph solve and covariance
  double total_s = 0.0;       ///< the whole call
  StageCpuTimes& operator+=(const StageCpuTimes& o);
};

/// Output of one process() call.
struct LocalizationOutput {
  enum class Status { Initializing, Tracking, Degraded, Lost };
  double time_s = 0.0;
  Status status = Status::Initializing;
  /// False until both an initial pose and odometry exist, and during an
  /// ego-motion outage longer than the odometry's hold time (0.5 s); else the
  /// pose fields below are valid (in Initializing they are the odometry-moved
  /// initial pose with its wide covariance).
  bool has_pose = false;
  Pose2 T_map_vehicle;  ///< client map frame (see file comment)
  GeoPose pose;         ///< WGS84, ENU yaw
  /// (x_m, y_m, yaw_rad), map frame: the reported covariance (see LocalizerConfig).
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  /// Lateral protection level (m): bounds the error across the heading with the integrity
  /// the config's protection_level_k was calibrated for (0 without a pose).
  double protection_level_lat_m = 0.0;
  bool extracted = false;      ///< candidates were extracted at this frame
  bool graph_updated = false;  ///< the graph was solved at this frame
  bool relocalized = false;    ///< the relocalization check re-anchored at this frame
  /// The graph's solution moved the newest pose beyond the prediction with few recent
  /// landmarks and was re-solved with the prediction's prior (max_unobserved_move_chi2).
  bool held_unobserved_move = false;
  int matched_points = 0;  ///< point observations entered into the graph at this frame
  int matched_lines = 0;
  double graph_update_time_s = 0.0;  ///< Ceres solve + covariance (wall time), if updated
  double processing_time_s = 0.0;    ///< whole process() call (wall time)
  double extraction_time_s = 0.0;    ///< candidate extraction (wall time), if extracted
  double matching_time_s = 0.0;      ///< local map + tiles + matching (wall time)
  StageCpuTimes cpu;                 ///< CPU time of this call by stage
  int candidates = 0;                ///< point candidates extracted at this frame
  int line_candidates = 0;           ///< line candidates extracted at this frame
  int local_point_clusters = 0;
  int map_points = 0;  ///< map point landmarks loaded around the vehicle
  std::optional<MatchResult::Status> match_status;  ///< when matching ran at this frame
  int match_point_associations = 0;                 ///< point associations of that matching result
  int match_line_associations = 0;                  ///< line associations of that matching result
  int map_lines = 0;  ///< map line landmarks loaded around the vehicle
  /// Ego-motion of this frame (radar::MotionEstimate::Status::Ok when valid).
  radar::MotionEstimate::Status motion_status = radar::MotionEstimate::Status::TooFewDetections;
  double speed_mps = 0.0;         ///< latest accepted ego-motion speed
  std::uint64_t map_version = 0;  ///< newest map version among the loaded tiles
};

[[nodiscard]] std::string_view to_string(LocalizationOutput::Status s);

/// The localization pipeline (see file comment).
class Localizer {
 public:
  /// mounts: every sensor whose frames will be passed to process().
  Localizer(LocalizerConfig cfg, std::vector<SensorMount> mounts, TileSource& tiles);
  ~Localizer();
  Localizer(const Localizer&) = delete;
  Localizer& operator=(const Localizer&) = delete;

  /// Coarse initial pose (e.g. GNSS) with its 1-σ uncertainty. Must be called
  /// before the first frame can produce a pose; calling it again later
  /// restarts initialization around the new pose (the map frame stays).
  void set_initial_pose(GeoPose coarse, double sigma_xy_m, double sigma_yaw_rad);

  /// Processes one sensor frame (time order, any sensor). Never blocks on I/O.
  LocalizationOutput process(const SensorFrame& frame);

  [[nodiscard]] const LocalizerConfig& config() const;
  /// The client's map frame (valid after set_initial_pose).
  [[nodiscard]] const std::optional<tiles::LocalFrame>& map_frame() const;
  /// Read-only views for diagnostics and tests.
  [[nodiscard]] const LocalMap& local_map() const;
  [[nodiscard]] const MapIndex& map_index() const;
  /// The online mount calibration so far (nullopt when LocalizerConfig turns it off).
  [[nodiscard]] std::optional<radar::MountCalibrationResult> mount_calibration() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace polmap::loc
