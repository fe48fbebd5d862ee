#include "polmap/localization_client/localizer.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <set>
#include <unordered_map>

#include "polmap/schema/errors.hpp"
#include "polmap/util/cpu_time.hpp"

namespace polmap::loc {

std::string_view to_string(LocalizationOutput::Status s) {
  switch (s) {
    case LocalizationOutput::Status::Initializing:
      return "initializing";
    case LocalizationOutput::Status::Tracking:
      return "tracking";
    case LocalizationOutput::Status::Degraded:
      return "degraded";
    case LocalizationOutput::Status::Lost:
      return "lost";
  }
  return "unknown";
}

StageCpuTimes& StageCpuTimes::operator+=(const StageCpuTimes& o) {
  egomotion_s += o.egomotion_s;
  gridmap_s += o.gridmap_s;
  points_s += o.points_s;
  lines_s += o.lines_s;
  clustering_s += o.clustering_s;
  tiles_s += o.tiles_s;
  matching_s += o.matching_s;
  smoothing_s += o.smoothing_s;
  graph_s += o.graph_s;
  total_s += o.total_s;
  return *this;
}

namespace {

using Status = LocalizationOutput::Status;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

Eigen::Matrix3d diag3(double sxy, double syaw) {
  return Eigen::Vector3d(sxy * sxy, sxy * sxy, syaw * syaw).asDiagonal();
}

double position_sigma_m(const Eigen::Matrix3d& cov) {
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov.topLeftCorner<2, 2>());
  return std::sqrt(std::max(0.0, es.eigenvalues().maxCoeff()));
}

/// Map landmarks of one tile converted into the client's map frame.
struct ConvertedTile {
  std::uint64_t map_version = 0;
  std::size_t num_points = 0;
  std::size_t num_lines = 0;
  std::vector<PointLandmark> points;
  std::vector<LineLandmark> lines;
};

}  // namespace

struct Localizer::Impl {
  Impl(LocalizerConfig c, std::vector<SensorMount> m, TileSource& t)
      : cfg(std::move(c)),
        mounts(std::move(m)),
        tiles(t),
        ego(mounts, cfg.egomotion),
        odo(cfg.odometry),
        gridmap(cfg.gridmap),
        local_map(cfg.local_map),
        point_smoother(cfg.smoothing),
        line_smoother(cfg.smoothing),
        graph(cfg.graph),
        init_streak(cfg.initialization),
        reloc(cfg.initialization, RelocalizationConfig{cfg.relocalization_extra_matches,
                                                       cfg.relocalization_agreement_xy_m,
                                                       cfg.relocalization_agreement_yaw_rad}) {
    POLMAP_EXPECT(!mounts.empty());
    POLMAP_EXPECT(cfg.gridmap.window_s > 0.0);
    POLMAP_EXPECT(cfg.tracking_max_heading_span_rad >= 0.0 && cfg.tracking_min_window_s >= 0.0);
    POLMAP_EXPECT(cfg.extract_every_n_cycles >= 1);
    POLMAP_EXPECT(cfg.reported_covariance_scale > 0.0 && cfg.reported_sigma_floor_xy_m >= 0.0 &&
                  cfg.reported_sigma_floor_yaw_rad >= 0.0 && cfg.protection_level_k > 0.0);
    // Extraction runs at the frame of the sensor that triggers last in a cycle,
    // so the gridmap holds the complete cycle.
    const auto last = std::max_element(
        mounts.begin(), mounts.end(),
        [](const auto& a, const auto& b) { return a.trigger_offset_s < b.trigger_offset_s; });
    last_sensor_id = last->sensor_id;
    for (const auto& mt : mounts) mount_by_id[mt.sensor_id] = mt;
    double x_sum = 0.0;
    for (const auto& mt : mounts) x_sum += mt.T_vehicle_sensor.x_m;
    sensor_lever_m = std::max(1.0, std::abs(x_sum) / static_cast<double>(mounts.size()));
    // Without online calibration the stored mounts are taken as exact (as before it existed).
    common_yaw_uncertainty_rad =
        cfg.online_mount_calibration ? cfg.mount_common_yaw_tolerance_rad : 0.0;
    if (cfg.online_mount_calibration) {
      radar::MountCalibrationConfig calibration = cfg.mount_calibration;
      calibration.side_slip_gradient_rad_per_mps2 = cfg.egomotion.side_slip_gradient_rad_per_mps2;
      calibrator.emplace(mounts, calibration);
    }
  }

  LocalizerConfig cfg;
  std::vector<SensorMount> mounts;
  TileSource& tiles;
  radar::EgoMotionEstimator ego;
  std::optional<radar::MountCalibrator> calibrator;
  /// Lateral acceleration at the last graph pose (odometry), for the slip-aware factor.
  double last_lateral_accel_mps2 = 0.0;
  /// What may be left of the common mount yaw (LocalizerConfig::mount_common_yaw_tolerance_rad)
  /// and the sensors' mean distance ahead of the rear axle it acts through.
  double common_yaw_uncertainty_rad = 0.0;
  double sensor_lever_m = 1.0;
  /// Time offset (true − stamp) per sensor from the calibration, for the gridmap's poses.
  std::map<std::uint8_t, double> time_offset_s;
  radar::Odometry odo;
  radar::CovarianceGridmap gridmap;
  LocalMap local_map;
  AssociationSmoother point_smoother;
  AssociationSmoother line_smoother;
  SlidingWindowGraph graph;
  MapIndex map;
  std::optional<tiles::LocalFrame> frame;
  std::map<std::uint8_t, SensorMount> mount_by_id;
  std::uint8_t last_sensor_id = 0;

  // Initial pose (map frame) until anchored to the odometry.
  std::optional<Pose2> pending_initial;
  Eigen::Matrix3d initial_cov = Eigen::Matrix3d::Identity();

  // Estimate: T_map_odom with the covariance of the vehicle pose at the anchor.
  bool anchored = false;
  Pose2 T_map_odom;
  Eigen::Matrix3d anchor_cov = Eigen::Matrix3d::Identity();
  double anchor_distance_m = 0.0;
  Status status = Status::Initializing;
  bool searching = true;  ///< Initializing or Lost: wide-gate matching, no graph

  InitializationStreak init_streak;
  RelocalizationConfirmation reloc;
  /// A relocalization check due at the next frame (see process()).
  struct PendingRelocalization {
    std::size_t tracking_point_matches = 0;
    MatcherConfig matcher;
  };
  std::optional<PendingRelocalization> pending_reloc;

  // Graph bookkeeping.
  std::optional<SlidingWindowGraph::PoseKey> last_key;
  double last_key_time_s = 0.0;
  /// Standstill hold (LocalizerConfig::standstill_*): the graph runs on its own
  /// clock, real time minus the time held, so a stop does not age the window.
  double standstill_total_s = 0.0;
  double last_track_time_s = 0.0;
  [[nodiscard]] double graph_time_s(double time_s) const { return time_s - standstill_total_s; }
  double last_assoc_time_s = -std::numeric_limits<double>::infinity();
  double tracking_since_s = 0.0;
  std::uint64_t extractions = 0;
  std::uint64_t last_lines_extraction = 0;
  int last_point_matches = 0;

  // Tiles.
  std::map<tiles::TileKey, ConvertedTile> converted;
  std::vector<tiles::TileKey> index_keys;  ///< tiles the MapIndex was built from
  std::map<tiles::TileKey, std::uint64_t> index_versions;
  std::uint64_t map_version = 0;
  double last_v_mps = 0.0;
  double last_motion_time_s = std::numeric_limits<double>::infinity();
  bool odometry_gap = false;  ///< an ego-motion outage since the last graph pose

  // ---------------------------------------------------------------- prediction

  /// Covariance of the predicted vehicle pose: the anchor's, grown with the
  /// distance driven since (odometry noise per metre, and the anchor's yaw
  /// uncertainty acting through the lever arm).
  /// Converged mount calibration: the ego-motion's corrections, and the gridmap's mounts
  /// (nominal yaw + offset) and measurement times.
  void apply_calibration(const radar::MountCalibrationResult& c) {
    radar::apply_mount_calibration(ego, c);
    // What may be left of the common yaw: 3σ once it is in every sensor's yaw; while it is
    // not (too small to apply early, or not significant) the estimate itself plus 3σ; the
    // tolerance until the calibration has seen enough driving.
    const bool in_all =
        c.common_yaw_applies_early ||
        (c.common_yaw_applied && c.status == radar::MountCalibrationResult::Status::Converged);
    const double left = (in_all ? 0.0 : std::abs(c.common_yaw_rad)) + 3.0 * c.common_yaw_sigma_rad;
    common_yaw_uncertainty_rad =
        c.observed_s >= cfg.mount_calibration.common_yaw_early_min_observed_s
            ? std::min(cfg.mount_common_yaw_tolerance_rad, left)
            : cfg.mount_common_yaw_tolerance_rad;
    for (const auto& s : c.sensors) {
      const auto nominal = std::find_if(mounts.begin(), mounts.end(), [&](const SensorMount& x) {
        return x.sensor_id == s.sensor_id;
      });
      if (nominal == mounts.end()) continue;
      SensorMount corrected = *nominal;
      if (s.yaw_status == radar::MountCalibrationResult::Status::Converged) {
        corrected.T_vehicle_sensor.yaw_rad += s.yaw_offset_rad;
      } else if (c.common_yaw_applies_early) {
        corrected.T_vehicle_sensor.yaw_rad += c.common_yaw_rad;
      }
      mount_by_id[s.sensor_id] = corrected;
      time_offset_s[s.sensor_id] =
          s.time_status == radar::MountCalibrationResult::Status::Converged ? s.time_offset_s : 0.0;
    }
  }

  /// What is reported of a covariance (LocalizerConfig: scale and floors).
  [[nodiscard]] Eigen::Matrix3d reported_cov(const Eigen::Matrix3d& c) const {
    Eigen::Matrix3d r = cfg.reported_covariance_scale * c;
    r(0, 0) += cfg.reported_sigma_floor_xy_m * cfg.reported_sigma_floor_xy_m;
    r(1, 1) += cfg.reported_sigma_floor_xy_m * cfg.reported_sigma_floor_xy_m;
    r(2, 2) += cfg.reported_sigma_floor_yaw_rad * cfg.reported_sigma_floor_yaw_rad;
    return r;
  }

  [[nodiscard]] Eigen::Matrix3d predicted_cov() const {
    const double d = std::max(0.0, odo.distance_m() - anchor_distance_m);
    Eigen::Matrix3d c = anchor_cov;
    const double s2 = std::pow(cfg.prediction_sigma_per_m * d, 2) + anchor_cov(2, 2) * d * d;
    c(0, 0) += s2;
    c(1, 1) += s2;
    c(2, 2) += std::pow(cfg.prediction_sigma_yaw_per_m * d, 2);
    return c;
  }

  /// Whether T_map_vehicle lies beyond max_unobserved_move_chi2 of the prediction.
  [[nodiscard]] bool moved_beyond_prediction(const Pose2& T_map_vehicle,
                                             const Pose2& predicted) const {
    const Eigen::Vector3d e(T_map_vehicle.x_m - predicted.x_m, T_map_vehicle.y_m - predicted.y_m,
                            wrap_angle_rad(T_map_vehicle.yaw_rad - predicted.yaw_rad));
    const Eigen::Matrix3d P = predicted_cov();
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(P);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return false;
    return e.dot(ldlt.solve(e)) > cfg.max_unobserved_move_chi2;
  }

  void anchor(const Pose2& T_map_vehicle, const Pose2& T_odom_vehicle, const Eigen::Matrix3d& cov) {
    T_map_odom = T_map_vehicle * T_odom_vehicle.inverse();
    anchor_cov = cov;
    anchor_distance_m = odo.distance_m();
    anchored = true;
  }

  // ---------------------------------------------------------------- map

  ConvertedTile convert(const tiles::LocalizationTile& t) const {
    const tiles::LocalFrame tf(tiles::tile_center(t.key));
    auto to_map = [&](const Eigen::Vector2d& p) { return frame->to_local(tf.to_geo(p)); };
    ConvertedTile c;
    c.map_version = t.map_version;
    c.num_points = t.points.size();
    c.num_lines = t.lines.size();
    c.points = t.points;
    for (auto& p : c.points) p.position_m = to_map(p.position_m);
    c.lines = t.lines;
    for (auto& l : c.lines) {
      for (auto& v : l.polyline_m) v = to_map(v);
    }
    return c;
  }

  /// Loads the tiles around the predicted pose (non-blocking) and rebuilds the
  /// MapIndex when the set of tiles or their content changed.
  void update_map(const Pose2& T_map_vehicle_pred) {
    const GeoPoint here = frame->to_geo(T_map_vehicle_pred.translation());
    const std::vector<tiles::TileKey> keys = tiles_around(here, cfg.map_radius_m);
    // Prefetch ahead along the heading (at least one tile radius ahead).
    const double ahead_m = std::max(cfg.map_radius_m, last_v_mps * cfg.prefetch_lookahead_s);
    const GeoPoint ahead = frame->to_geo(T_map_vehicle_pred * Eigen::Vector2d(ahead_m, 0.0));
    const auto ahead_keys = tiles_around(ahead, cfg.map_radius_m);
    tiles.prefetch(ahead_keys);

    bool changed = keys != index_keys;
    for (const auto& k : keys) {
      const auto t = tiles.tile(k);
      if (!t) continue;  // not available yet: try again at the next extraction
      const auto it = converted.find(k);
      if (it == converted.end() || it->second.map_version != t->map_version ||
          it->second.num_points != t->points.size() || it->second.num_lines != t->lines.size()) {
        converted[k] = convert(*t);
      }
      const auto vit = index_versions.find(k);
      if (vit == index_versions.end() || vit->second != converted[k].map_version) changed = true;
      map_version = std::max(map_version, t->map_version);
    }
    if (!changed) return;
    // Rebuild from the available tiles; landmarks crossing tile borders are
    // stored in every tile they touch (same id): keep one copy.
    std::vector<PointLandmark> points;
    std::vector<LineLandmark> lines;
    std::set<std::int64_t> seen_points, seen_lines;
    index_versions.clear();
    for (const auto& k : keys) {
      const auto it = converted.find(k);
      if (it == converted.end()) continue;
      index_versions[k] = it->second.map_version;
      for (const auto& p : it->second.points) {
        if (seen_points.insert(p.id).second) points.push_back(p);
      }
      for (const auto& l : it->second.lines) {
        if (seen_lines.insert(l.id).second) lines.push_back(l);
      }
    }
    index_keys = keys;
    map = MapIndex(std::move(points), std::move(lines));
    // Forget converted tiles far behind (keep a generous working set).
    if (converted.size() > 64) {
      for (auto it = converted.begin(); it != converted.end();) {
        it = std::find(keys.begin(), keys.end(), it->first) == keys.end() &&
                     std::find(ahead_keys.begin(), ahead_keys.end(), it->first) == ahead_keys.end()
                 ? converted.erase(it)
                 : std::next(it);
      }
    }
  }

  // ---------------------------------------------------------------- states

  void reset_tracking() {
    pending_reloc.reset();
    graph.clear();
    point_smoother.clear();
    line_smoother.clear();
    last_key.reset();
    init_streak.reset();
  }

  void go_lost() {
    status = Status::Lost;
    searching = true;
    reset_tracking();
    // Widen the gate to at least the initial uncertainty.
    for (int i = 0; i < 3; ++i) anchor_cov(i, i) = std::max(anchor_cov(i, i), initial_cov(i, i));
  }

  /// Starts tracking at a confidently matched pose: fresh graph with a prior.
  void start_tracking(const Pose2& T_map_vehicle, const Pose2& T_odom_vehicle, double time_s) {
    const Eigen::Matrix3d cov = diag3(cfg.init_pose_sigma_xy_m, cfg.init_pose_sigma_yaw_rad);
    anchor(T_map_vehicle, T_odom_vehicle, cov);
    searching = false;
    status = Status::Tracking;
    tracking_since_s = time_s;
    graph.clear();
    last_key.reset();
    last_track_time_s = time_s;
    const auto key = graph.add_pose(graph_time_s(time_s), T_map_vehicle, std::nullopt);
    graph.add_pose_prior(key, T_map_vehicle, cov);
    last_key = key;
    last_key_time_s = time_s;
    last_assoc_time_s = time_s;
    reloc.reset();
  }

  /// Whether two transforms agree at the current vehicle pose.
  /// Initialization / recovery: wide-gate matching until confident.
  void search(const MatchResult& match, double time_s, const Pose2& T_odom_vehicle) {
    const auto step = init_streak.add(match, T_odom_vehicle, odo.distance_m());
    if (step == InitializationStreak::Step::Ended || step == InitializationStreak::Step::Started) {
      point_smoother.clear();
    }
    if (step == InitializationStreak::Step::Ended) return;
    std::vector<std::pair<std::uint64_t, std::int64_t>> votes;
    for (const auto& m : match.points) votes.emplace_back(m.cluster_id, m.landmark_id);
    point_smoother.add_votes(votes);
    if (const auto T = init_streak.ready(odo.distance_m())) {
      start_tracking(*T * T_odom_vehicle, T_odom_vehicle, time_s);
    }
  }

  /// Relocalization check (LocalizerConfig): returns true if it re-anchored.
  bool relocalization_check(std::size_t tracking_point_matches, const MatcherConfig& mcfg,
                            double time_s, const Pose2& T_odom_vehicle) {
    MatchPrior wide;
    wide.T_map_odom = T_map_odom;
    wide.T_odom_vehicle = T_odom_vehicle;
    const Eigen::Matrix3d pred = predicted_cov();
    wide.covariance = pred;
    for (int i = 0; i < 3; ++i) wide.covariance(i, i) = std::max(pred(i, i), initial_cov(i, i));
    MatcherConfig wide_cfg = mcfg;
    wide_cfg.max_anchor_clusters =
        std::min(wide_cfg.max_anchor_clusters, cfg.relocalization_max_anchor_clusters);
    wide_cfg.max_yaw_hypotheses =
        std::min(wide_cfg.max_yaw_hypotheses, cfg.relocalization_max_yaw_hypotheses);
    const MatchResult r =
        match_local_map(local_map.point_clusters(), local_map.line_clusters(), map, wide, wide_cfg);
    const Pose2 now = T_map_odom * T_odom_vehicle;
    const Pose2 alt = r.T_map_odom * T_odom_vehicle;
    const double dxy = (alt.translation() - now.translation()).norm();
    const double dyaw = std::abs(wrap_angle_rad(alt.yaw_rad - now.yaw_rad));
    const bool distinct = dxy > std::max(1.0, 3.0 * position_sigma_m(pred)) ||
                          dyaw > std::max(0.026, 3.0 * std::sqrt(pred(2, 2)));
    if (!reloc.add(r, tracking_point_matches, distinct, T_odom_vehicle)) return false;
    reset_tracking();
    start_tracking(alt, T_odom_vehicle, time_s);
    return true;
  }

  /// Observed position (odometry frame) of a cluster at the latest
  /// extraction: of its latest observations the one closest to where the
  /// prediction puts the associated landmark (a far point target can split
  /// into two candidates ~0.5 m apart; averaging them would bias the bearing).
  [[nodiscard]] Eigen::Vector2d latest_observation(const PointCluster& c,
                                                   const Eigen::Vector2d& predicted_odom) const {
    const auto latest = local_map.latest_extraction_index();
    std::optional<Eigen::Vector2d> best;
    for (std::size_t i : c.members) {
      const auto& o = local_map.point_observations()[i];
      if (o.extraction_index != latest) continue;
      if (!best || (o.position_odom_m - predicted_odom).norm() < (*best - predicted_odom).norm()) {
        best = o.position_odom_m;
      }
    }
    return best.value_or(c.centroid_odom_m);
  }

  /// Start of the part of the local map that tracking matches
  /// (LocalizerConfig::tracking_max_heading_span_rad): the earliest time, stepping back
  /// from time_s in 0.1 s steps, before which the odometry heading differs from the
  /// current one by more than the span; never later than time_s - tracking_min_window_s.
  [[nodiscard]] double tracking_window_start_s(double time_s, const Pose2& T_odom_vehicle) const {
    const double window_s = cfg.local_map.window_s;
    if (cfg.tracking_max_heading_span_rad <= 0.0) return time_s - window_s;
    constexpr double step_s = 0.1;
    double since_s = time_s;
    for (double back_s = step_s; back_s <= window_s + 1e-9; back_s += step_s) {
      const auto T = odo.try_T_odom_vehicle(time_s - back_s);
      if (!T) break;
      const double dyaw =
          std::remainder(T_odom_vehicle.yaw_rad - T->yaw_rad, 2.0 * std::numbers::pi);
      if (std::abs(dyaw) > cfg.tracking_max_heading_span_rad) break;
      since_s = time_s - back_s;
    }
    return std::min(since_s, time_s - cfg.tracking_min_window_s);
  }

  /// Tracking: smoothing + graph update. Returns the solution if solved.
  std::optional<GraphSolution> track(const MatchResult& match, double time_s,
                                     const Pose2& T_odom_vehicle, bool use_lines,
                                     LocalizationOutput& out, util::CpuLap& lap) {
    // Votes from matches whose transform is trustworthy (the gate is tight
    // while tracking; an ambiguous or empty result casts no votes).
    if (match.status == MatchResult::Status::Ok ||
        match.status == MatchResult::Status::TooFewMatches) {
      std::vector<std::pair<std::uint64_t, std::int64_t>> votes;
      for (const auto& m : match.points) votes.emplace_back(m.cluster_id, m.landmark_id);
      point_smoother.add_votes(votes);
      votes.clear();
      for (const auto& m : match.lines) votes.emplace_back(m.cluster_id, m.landmark_id);
      line_smoother.add_votes(votes);
    }
    std::vector<std::uint64_t> alive;
    for (const auto& c : local_map.point_clusters()) alive.push_back(c.id);
    point_smoother.retain_clusters(alive);
    alive.clear();
    for (const auto& c : local_map.line_clusters()) alive.push_back(c.id);
    line_smoother.retain_clusters(alive);

    const Pose2 guess = T_map_odom * T_odom_vehicle;
    std::optional<Pose2> delta;
    if (last_key && !odometry_gap) {
      const auto prev = odo.try_T_odom_vehicle(last_key_time_s);
      if (prev) delta = prev->inverse() * T_odom_vehicle;
    }
    const double since_last_track_s = std::max(0.0, time_s - last_track_time_s);
    last_track_time_s = time_s;
    if (delta && delta->translation().norm() < cfg.standstill_translation_m &&
        std::abs(delta->yaw_rad) < cfg.standstill_yaw_rad) {
      // Standing: hold the estimate (config comment); the stop neither ages
      // the window nor counts as time without associations.
      standstill_total_s += since_last_track_s;
      last_assoc_time_s += since_last_track_s;
      out.cpu.smoothing_s += lap.lap();
      return std::nullopt;
    }
    if (!delta) graph.clear();  // odometry cannot link: restart the window
    odometry_gap = false;
    Eigen::Vector3d slip_sigma = Eigen::Vector3d::Zero();
    if (delta && last_key) {
      const double dt = std::max(time_s - last_key_time_s, 1e-3);
      const double dist_m = delta->translation().norm();
      const double a_y = (dist_m / dt) * (delta->yaw_rad / dt);  // v · ω
      const double k = cfg.odometry_slip_gradient_rad_per_mps2;
      slip_sigma = {0.0, k * std::abs(a_y) * dist_m,
                    std::hypot(k * std::abs(a_y - last_lateral_accel_mps2),
                               dist_m * common_yaw_uncertainty_rad / sensor_lever_m)};
      last_lateral_accel_mps2 = a_y;
    }
    const auto key = graph.add_pose(graph_time_s(time_s), guess, delta, slip_sigma);
    last_key = key;
    last_key_time_s = time_s;

    std::unordered_map<std::uint64_t, const PointCluster*> cluster_by_id;
    for (const auto& c : local_map.point_clusters()) cluster_by_id[c.id] = &c;
    const Pose2 T_vehicle_odom = T_odom_vehicle.inverse();
    const Pose2 T_vehicle_map = guess.inverse();
    const double assoc_gate_m = 1.0 + 3.0 * position_sigma_m(predicted_cov());
    int n_points = 0;
    for (const auto& a : point_smoother.smoothed()) {
      const auto it = cluster_by_id.find(a.cluster_id);
      if (it == cluster_by_id.end() || !it->second->observed_latest) continue;
      const PointLandmark* lm = map.find_point(a.landmark_id);
      if (lm == nullptr) continue;
      const Eigen::Vector2d predicted_odom = T_map_odom.inverse() * lm->position_m;
      const Eigen::Vector2d obs_vehicle =
          T_vehicle_odom * latest_observation(*it->second, predicted_odom);
      // A smoothed association far from where the prediction puts the
      // landmark would only be rejected by the robust loss; skip it.
      if ((T_vehicle_map * lm->position_m - obs_vehicle).norm() > assoc_gate_m) continue;
      graph.add_point_observation(key, lm->id, lm->position_m, obs_vehicle);
      ++n_points;
    }
    int n_lines = 0;
    if (use_lines) {
      const auto smoothed_lines = line_smoother.smoothed();
      std::unordered_map<std::uint64_t, std::int64_t> line_assoc;
      for (const auto& a : smoothed_lines) line_assoc[a.cluster_id] = a.landmark_id;
      std::unordered_map<std::uint64_t, const LineCluster*> line_by_id;
      for (const auto& c : local_map.line_clusters()) line_by_id[c.id] = &c;
      for (const auto& m : match.lines) {
        const auto la = line_assoc.find(m.cluster_id);
        if (la == line_assoc.end() || la->second != m.landmark_id) continue;
        const auto lc = line_by_id.find(m.cluster_id);
        if (lc == line_by_id.end() || !lc->second->observed_latest) continue;
        const LineLandmark* lm = map.find_line(m.landmark_id);
        if (lm == nullptr || m.edge_index + 1 >= static_cast<int>(lm->polyline_m.size())) continue;
        // The latest observations of the cluster, merged, in the vehicle frame.
        std::vector<Segment2> segs;
        for (std::size_t i : lc->second->members) {
          const auto& o = local_map.line_observations()[i];
          if (o.extraction_index == local_map.latest_extraction_index()) {
            segs.push_back(
                {T_vehicle_odom * o.segment_odom_m.a_m, T_vehicle_odom * o.segment_odom_m.b_m});
          }
        }
        if (segs.empty()) continue;
        const Segment2 map_seg{lm->polyline_m[m.edge_index], lm->polyline_m[m.edge_index + 1]};
        graph.add_line_observation(key, lm->id, merge_segments(segs), map_seg);
        ++n_lines;
      }
    }
    out.matched_points = n_points;
    out.matched_lines = n_lines;
    last_point_matches = n_points;
    if (n_points > 0 || n_lines > 0) last_assoc_time_s = time_s;

    graph.truncate_before(graph_time_s(time_s) - cfg.graph.window_s);
    const double constraint =
        graph.num_point_landmarks() + 0.5 * std::min(graph.num_line_observations(), 6);
    // Degraded (no association for degraded_after_s): the window's landmarks are old, and
    // the prior that held them must not drop out with the truncated poses.
    const bool stale = time_s - last_assoc_time_s > cfg.degraded_after_s;
    const auto prior_at_prediction = [&] {
      graph.clear_pose_priors();
      graph.add_pose_prior(key, guess, predicted_cov());
    };
    if (constraint < cfg.min_landmarks_without_pose_prior || stale) prior_at_prediction();
    out.cpu.smoothing_s += lap.lap();
    GraphSolution sol = graph.solve();
    double solve_time_s = sol.solve_time_s;
    const double recent_s = graph_time_s(time_s) - cfg.pose_prior_recent_s;
    if (sol.status == GraphSolution::Status::Ok && cfg.max_unobserved_move_chi2 > 0.0 &&
        graph.num_point_landmarks_since(recent_s) +
                0.5 * std::min(graph.num_line_observations_since(recent_s), 6) <
            cfg.min_landmarks_without_pose_prior &&
        moved_beyond_prediction(sol.T_map_vehicle, guess)) {
      // Too few landmarks were seen lately to move the newest pose that far
      // (LocalizerConfig::max_unobserved_move_chi2): keep it near the prediction, with the
      // prediction's uncertainty.
      prior_at_prediction();
      sol = graph.solve();
      solve_time_s += sol.solve_time_s;
      out.held_unobserved_move = true;
    }
    out.cpu.graph_s += lap.lap();
    out.graph_updated = true;
    out.graph_update_time_s = solve_time_s;
    if (sol.status != GraphSolution::Status::Ok) return std::nullopt;
    anchor(sol.T_map_vehicle, T_odom_vehicle,
           sol.covariance_valid ? sol.covariance : predicted_cov());
    return sol;
  }

  // ---------------------------------------------------------------- per frame

  LocalizationOutput process(const SensorFrame& f) {
    const auto t0 = Clock::now();
    util::CpuLap lap;
    const double cpu0 = util::thread_cpu_s();
    LocalizationOutput out;
    out.time_s = f.time_s;
    const auto mit = mount_by_id.find(f.sensor_id);
    POLMAP_EXPECT(mit != mount_by_id.end());

    const radar::MotionEstimate m = ego.process(f);
    if (calibrator) {
      calibrator->add_frame(f);
      if (calibrator->add_estimate(m) && cfg.mount_calibration.calibrate_mounts) {
        apply_calibration(calibrator->result());
      }
    }
    out.motion_status = m.status;
    if (m.status == radar::MotionEstimate::Status::Ok) {
      // An outage of the ego-motion longer than the odometry's hold time is
      // bridged by one arc, which can be far off: widen the uncertainty by
      // the outage (1 m/s, 0.02 rad/s; the lost check then decides whether
      // to search again) and do not link graph poses across it.
      const double gap_s = m.time_s - last_motion_time_s;
      if (anchored && gap_s > cfg.odometry.max_hold_s) {
        anchor_cov(0, 0) += gap_s * gap_s;
        anchor_cov(1, 1) += gap_s * gap_s;
        anchor_cov(2, 2) += std::pow(0.02 * gap_s, 2);
        odometry_gap = true;
      }
      last_motion_time_s = m.time_s;
      last_v_mps = m.v_mps;
    }
    odo.add(m);
    out.cpu.egomotion_s = lap.lap();
    if (odo.empty()) {
      out.status = status;
      out.processing_time_s = seconds_since(t0);
      out.cpu.total_s = util::thread_cpu_s() - cpu0;
      return out;
    }
    if (pending_initial) {
      // Anchor the coarse initial pose at the current odometry pose.
      anchor(*pending_initial, odo.T_odom_vehicle(odo.latest_time_s()), initial_cov);
      pending_initial.reset();
      searching = true;
      if (status != Status::Lost) status = Status::Initializing;
      reset_tracking();
    }
    const std::optional<Pose2> T_odom_vehicle = odo.try_T_odom_vehicle(f.time_s);
    if (T_odom_vehicle && f.spectrum.azimuth_bins_rad.size() >= 2) {
      // The calibrated measurement time (stamp + offset) places the frame.
      const auto dt = time_offset_s.find(f.sensor_id);
      std::optional<Pose2> T_at = T_odom_vehicle;
      if (dt != time_offset_s.end() && dt->second != 0.0) {
        if (auto t = odo.try_T_odom_vehicle(f.time_s + dt->second)) T_at = t;
      }
      gridmap.add(f.spectrum, *T_at * mit->second.T_vehicle_sensor, f.time_s);
    }
    out.cpu.gridmap_s = lap.lap();

    const bool extract =
        anchored && T_odom_vehicle && f.sensor_id == last_sensor_id &&
        f.cycle_index % static_cast<std::uint32_t>(cfg.extract_every_n_cycles) == 0;
    if (pending_reloc && !extract) {
      const PendingRelocalization p = *pending_reloc;
      pending_reloc.reset();
      if (!searching && anchored && T_odom_vehicle &&
          relocalization_check(p.tracking_point_matches, p.matcher, f.time_s, *T_odom_vehicle)) {
        out.relocalized = true;
      }
      out.cpu.matching_s += lap.lap();
    }
    if (extract) {
      out.extracted = true;
      ++extractions;
      const auto t_extract = Clock::now();
      const std::vector<PointCandidate> points = radar::extract_points(gridmap, cfg.points);
      out.cpu.points_s = lap.lap();
      const bool use_lines =
          extractions % cfg.lines_every_n_extractions == 0 ||
          (last_point_matches < cfg.lines_below_point_matches &&
           extractions >= last_lines_extraction + cfg.lines_min_interval_extractions);
      if (use_lines) last_lines_extraction = extractions;
      std::vector<LineCandidate> lines;
      if (use_lines) lines = radar::extract_lines(gridmap, cfg.lines);
      out.cpu.lines_s = lap.lap();
      out.extraction_time_s = seconds_since(t_extract);
      out.candidates = static_cast<int>(points.size());
      out.line_candidates = static_cast<int>(lines.size());
      const auto t_match = Clock::now();
      local_map.add(f.time_s, *T_odom_vehicle, points, lines);
      out.cpu.clustering_s = lap.lap();

      const Pose2 pred = T_map_odom * *T_odom_vehicle;
      update_map(pred);
      out.cpu.tiles_s = lap.lap();
      MatchPrior prior;
      prior.T_map_odom = T_map_odom;
      prior.T_odom_vehicle = *T_odom_vehicle;
      prior.covariance = predicted_cov();
      if (!searching) {
        prior.covariance += diag3(cfg.tracking_gate_floor_xy_m, cfg.tracking_gate_floor_yaw_rad);
      }
      MatcherConfig mcfg = cfg.matcher;
      mcfg.use_lines = mcfg.use_lines && use_lines;
      const MatchResult match = [&] {
        const double since_s = searching ? -std::numeric_limits<double>::infinity()
                                         : tracking_window_start_s(f.time_s, *T_odom_vehicle);
        if (since_s <= f.time_s - cfg.local_map.window_s) {
          return match_local_map(local_map.point_clusters(), local_map.line_clusters(), map, prior,
                                 mcfg);
        }
        const LocalMap::View view = local_map.recent(since_s);
        return match_local_map(view.points, view.lines, map, prior, mcfg);
      }();
      out.match_status = match.status;
      out.match_point_associations = static_cast<int>(match.points.size());
      out.match_line_associations = static_cast<int>(match.lines.size());
      out.matching_time_s = seconds_since(t_match);
      out.cpu.matching_s = lap.lap();
      if (searching) {
        search(match, f.time_s, *T_odom_vehicle);
        out.cpu.smoothing_s += lap.lap();
      } else {
        track(match, f.time_s, *T_odom_vehicle, use_lines, out, lap);
        // The relocalization check (a wide-gate match, as expensive as an extraction)
        // runs at the next frame, so that no frame carries both.
        if (cfg.relocalization_every_n_extractions > 0 &&
            extractions % cfg.relocalization_every_n_extractions == 0) {
          pending_reloc = PendingRelocalization{match.points.size(), mcfg};
        }
        status = f.time_s - last_assoc_time_s <= cfg.degraded_after_s ? Status::Tracking
                                                                      : Status::Degraded;
        if (position_sigma_m(predicted_cov()) > cfg.lost_sigma_m ||
            f.time_s - last_assoc_time_s > cfg.lost_after_s) {
          go_lost();
        }
      }
    }

    out.status = status;
    out.speed_mps = last_v_mps;
    out.local_point_clusters = static_cast<int>(local_map.point_clusters().size());
    out.map_points = static_cast<int>(map.points().size());
    out.map_lines = static_cast<int>(map.lines().size());
    out.map_version = map_version;
    if (anchored && T_odom_vehicle) {
      out.has_pose = true;
      out.T_map_vehicle = T_map_odom * *T_odom_vehicle;
      out.covariance = reported_cov(predicted_cov());
      const double yaw = out.T_map_vehicle.yaw_rad;
      const Eigen::Vector2d across(-std::sin(yaw), std::cos(yaw));
      out.protection_level_lat_m =
          cfg.protection_level_k *
          std::sqrt(std::max(0.0, across.dot(out.covariance.topLeftCorner<2, 2>() * across)));
      const Eigen::Vector2d xy = out.T_map_vehicle.translation();
      out.pose.position = frame->to_geo(xy);
      out.pose.yaw_enu_rad = wrap_angle_rad(out.T_map_vehicle.yaw_rad - frame->convergence_rad(xy));
    }
    out.processing_time_s = seconds_since(t0);
    out.cpu.smoothing_s += lap.lap();  // status and output bookkeeping
    out.cpu.total_s = util::thread_cpu_s() - cpu0;
    return out;
  }
};

Localizer::Localizer(LocalizerConfig cfg, std::vector<SensorMount> mounts, TileSource& tiles)
    : impl_(std::make_unique<Impl>(std::move(cfg), std::move(mounts), tiles)) {}

Localizer::~Localizer() = default;

void Localizer::set_initial_pose(GeoPose coarse, double sigma_xy_m, double sigma_yaw_rad) {
  POLMAP_EXPECT(sigma_xy_m > 0.0 && sigma_yaw_rad > 0.0);
  auto& I = *impl_;
  if (!I.frame) I.frame.emplace(coarse.position);
  const Eigen::Vector2d xy = I.frame->to_local(coarse.position);
  const Pose2 T{xy.x(), xy.y(), wrap_angle_rad(coarse.yaw_enu_rad + I.frame->convergence_rad(xy))};
  I.initial_cov = diag3(sigma_xy_m, sigma_yaw_rad);
  if (I.odo.empty()) {
    I.pending_initial = T;
  } else {
    I.anchor(T, I.odo.T_odom_vehicle(I.odo.latest_time_s()), I.initial_cov);
    I.searching = true;
    I.status = Status::Initializing;
    I.reset_tracking();
  }
}

LocalizationOutput Localizer::process(const SensorFrame& frame) { return impl_->process(frame); }

const LocalizerConfig& Localizer::config() const { return impl_->cfg; }
const std::optional<tiles::LocalFrame>& Localizer::map_frame() const { return impl_->frame; }
const LocalMap& Localizer::local_map() const { return impl_->local_map; }
const MapIndex& Localizer::map_index() const { return impl_->map; }

std::optional<radar::MountCalibrationResult> Localizer::mount_calibration() const {
  if (!impl_->calibrator) return std::nullopt;
  return impl_->calibrator->result();
}

}  // namespace polmap::loc
