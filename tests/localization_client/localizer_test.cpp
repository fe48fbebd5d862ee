// The Localizer end to end on synthetic sensor frames (a minimal frame
// synthesizer below: odd-bounce poles along a curved road, Doppler detections
// for ego-motion, sparse static-reduced spectra for the gridmap): it converges
// from a GNSS-grade initial pose (3 m, 3°), tracks, degrades over a stretch
// without landmarks, reports Lost and recovers; a TileSource that is not
// ready yet only delays initialization.
#include "polmap/localization_client/localizer.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <numbers>
#include <optional>
#include <random>

#include "polmap/tiles/local_frame.hpp"

namespace polmap::loc {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

struct TruthState {
  double t = 0, x = 0, y = 0, yaw = 0, v = 0, w = 0;
};

/// A drive along a gently curving road with poles on both sides.
class SyntheticDrive {
 public:
  /// Poles in [gap_from_m, gap_to_m) along the route exist in the world but
  /// not in the map (a stretch the map does not cover).
  /// With stop_from_s < stop_to_s the vehicle brakes at 5 m/s² to stand still
  /// from stop_from_s to stop_to_s, then accelerates at 2.5 m/s² back to 10 m/s.
  SyntheticDrive(std::uint64_t seed, double duration_s, double gap_from_m, double gap_to_m,
                 double stop_from_s = -1.0, double stop_to_s = -1.0)
      : frame_(GeoPoint{48.40, 9.98, 500.0}), rng_(seed), mounts_(default_front_mounts()) {
    // Truth at 1 ms steps, kept at 10 ms.
    TruthState s;
    s.v = 10.0;
    double dist = 0.0;
    for (int k = 0; s.t <= duration_s + 0.2; ++k) {
      if (stop_from_s < stop_to_s) {
        const double brake_start_s = stop_from_s - 2.0;
        if (s.t >= brake_start_s && s.t < stop_to_s) {
          s.v = std::max(0.0, 10.0 - 5.0 * (s.t - brake_start_s));
        } else if (s.t >= stop_to_s) {
          s.v = std::min(10.0, 2.5 * (s.t - stop_to_s));
        }
      }
      // Curvature follows the road (a car turns only while moving).
      s.w = s.v / 10.0 * 0.04 * std::sin(2.0 * std::numbers::pi * dist / 250.0);
      if (k % 10 == 0) states_.push_back(s);
      const Pose2 next = Pose2{s.x, s.y, s.yaw} * integrate_motion(s.v, s.w, 0.001);
      s.x = next.x_m;
      s.y = next.y_m;
      s.yaw = next.yaw_rad;
      s.t += 0.001;
      dist += s.v * 0.001;
    }
    // Poles every ~6 m, alternating sides, 5-11 m off the centre line.
    std::uniform_real_distribution<double> off(5.0, 11.0), jitter(-3.0, 3.0);
    double d = 0.0;
    int side = 1;
    for (std::size_t i = 0; i + 1 < states_.size(); ++i) {
      const double step = states_[i].v * 0.01;
      d += step;
      if (std::fmod(d, 6.0) < step) {
        side = -side;
        const Pose2 P{states_[i].x, states_[i].y, states_[i].yaw};
        poles_.push_back(P * Eigen::Vector2d(jitter(rng_), side * off(rng_)));
        pole_route_m_.push_back(d);
        mapped_.push_back(d < gap_from_m || d >= gap_to_m);
        map_error_m_.emplace_back(0.0, 0.0);
      }
    }
  }

  /// Frames in [from_s, to_s) carry no detections (ego-motion outage).
  void set_detection_outage(double from_s, double to_s) {
    outage_from_s_ = from_s;
    outage_to_s_ = to_s;
  }
  /// Poles in [from_m, to_m) along the route are in the map even inside the gap, the
  /// first of them displaced by first_error_m (an imprecise map landmark).
  void map_island(double from_m, double to_m, const Eigen::Vector2d& first_error_m) {
    bool first = true;
    for (std::size_t i = 0; i < poles_.size(); ++i) {
      if (pole_route_m_[i] < from_m || pole_route_m_[i] >= to_m) continue;
      mapped_[i] = true;
      if (first) map_error_m_[i] = first_error_m;
      first = false;
    }
  }
  [[nodiscard]] const tiles::LocalFrame& frame() const { return frame_; }
  [[nodiscard]] const std::vector<SensorMount>& mounts() const { return mounts_; }
  [[nodiscard]] const std::vector<Eigen::Vector2d>& poles() const { return poles_; }

  [[nodiscard]] TruthState truth(double t) const {
    const std::size_t i = std::min(states_.size() - 1, static_cast<std::size_t>(t / 0.01));
    TruthState s = states_[i];
    const Pose2 p = Pose2{s.x, s.y, s.yaw} * integrate_motion(s.v, s.w, t - s.t);
    s.x = p.x_m;
    s.y = p.y_m;
    s.yaw = p.yaw_rad;
    s.t = t;
    return s;
  }

  /// Frame of mount m in cycle c (trigger t = 0.1 c + offset).
  [[nodiscard]] SensorFrame render(std::uint32_t cycle, const SensorMount& m) {
    SensorFrame f;
    f.cycle_index = cycle;
    f.sensor_id = m.sensor_id;
    f.time_s = 0.1 * cycle + m.trigger_offset_s;
    const TruthState s = truth(f.time_s);
    const Pose2 T_world_sensor = Pose2{s.x, s.y, s.yaw} * m.T_vehicle_sensor;
    const Pose2 T_sensor_world = T_world_sensor.inverse();
    PolSpectrum& sp = f.spectrum;
    sp.range_bin_m = 0.075;
    sp.num_range_bins = 1067;
    for (int j = 0; j < 81; ++j)
      sp.azimuth_bins_rad.push_back(static_cast<float>((-60.0 + 1.5 * j) * kDeg));
    sp.noise_sigma = 1.0F;
    std::map<std::pair<int, int>, std::complex<float>> cells;  // (beam, range bin) -> LR amplitude
    std::normal_distribution<double> n01(0.0, 1.0);
    // Sensor velocity in the vehicle frame (zero side slip), for Doppler.
    const Eigen::Vector2d v_s(s.v - s.w * m.T_vehicle_sensor.y_m, s.w * m.T_vehicle_sensor.x_m);
    for (const auto& p : poles_) {
      const Eigen::Vector2d q = T_sensor_world * p;
      const double r = q.norm(), az = std::atan2(q.y(), q.x());
      if (r < 1.0 || r > 78.0 || std::abs(az) > 59.0 * kDeg) continue;
      // Detection (for ego-motion): radial velocity of a static target, aliased.
      const Eigen::Vector2d u_vehicle =
          m.T_vehicle_sensor.rotation() * Eigen::Vector2d(std::cos(az), std::sin(az));
      double vr = -v_s.dot(u_vehicle) + 0.03 * n01(rng_);
      vr = vr - 10.0 * std::floor((vr + 5.0) / 10.0);
      if (f.time_s >= outage_from_s_ && f.time_s < outage_to_s_) continue;
      f.detections.push_back({static_cast<float>(r + 0.02 * n01(rng_)),
                              static_cast<float>(az + 0.3 * kDeg * n01(rng_)),
                              static_cast<float>(vr), 25.0F});
      // Spectrum: a 3 x 3 point-spread around the nearest (beam, range bin).
      const int i0 = static_cast<int>(std::lround(r / sp.range_bin_m));
      const int j0 = static_cast<int>(std::lround((az / kDeg + 60.0) / 1.5));
      const double amp = 40.0 * std::pow(30.0 / std::max(r, 10.0), 2);  // ~r^-2 amplitude
      const double phase = std::uniform_real_distribution<double>(0, 2 * std::numbers::pi)(rng_);
      for (int dj = -1; dj <= 1; ++dj) {
        for (int di = -1; di <= 1; ++di) {
          const int j = j0 + dj, i = i0 + di;
          if (j < 0 || j > 80 || i < 0 || i >= 1067) continue;
          const double w = (dj == 0 ? 1.0 : 0.4) * (di == 0 ? 1.0 : 0.5);
          cells[{j, i}] += std::polar(static_cast<float>(amp * w), static_cast<float>(phase));
        }
      }
    }
    for (const auto& [ji, a] : cells) {
      SpectrumCell c;
      c.azimuth_bin = static_cast<std::uint16_t>(ji.first);
      c.range_bin = static_cast<std::uint16_t>(ji.second);
      // Odd bounce: LR = RL = j * amplitude, LL = RR = 0 (radar/polarimetry.hpp).
      c.s = {cfloat{}, a * cfloat(0, 1), a * cfloat(0, 1), cfloat{}};
      sp.cells.push_back(c);
    }
    return f;
  }

  /// Map tiles of the poles (ids = index), as the server would send them.
  void fill_tiles(InMemoryTileSource& src) const {
    std::map<tiles::TileKey, tiles::LocalizationTile> out;
    for (std::size_t i = 0; i < poles_.size(); ++i) {
      if (!mapped_[i]) continue;
      const GeoPoint g = frame_.to_geo(poles_[i] + map_error_m_[i]);
      const auto key = tiles::tile_at(g.lat_deg, g.lon_deg, tiles::kLocalizationZoom);
      auto& t = out[key];
      t.key = key;
      t.map_version = 1;
      PointLandmark p;
      p.id = static_cast<std::int64_t>(i);
      p.position_m = tiles::LocalFrame(tiles::tile_center(key)).to_local(g);
      t.points.push_back(p);
    }
    for (auto& [k, t] : out) src.put(t);
  }

 private:
  tiles::LocalFrame frame_;
  std::mt19937 rng_;
  std::vector<SensorMount> mounts_;
  std::vector<TruthState> states_;
  std::vector<Eigen::Vector2d> poles_;
  std::vector<double> pole_route_m_;
  std::vector<bool> mapped_;
  std::vector<Eigen::Vector2d> map_error_m_;
  double outage_from_s_ = 1e9, outage_to_s_ = 1e9;
};

struct RunResult {
  std::vector<std::pair<double, LocalizationOutput>> outputs;  ///< extraction frames
  double first_tracking_s = -1.0;
  double max_pos_error_tracking_m = 0.0;
  double rms_pos_error_tracking_m = 0.0;
  double max_yaw_error_tracking_rad = 0.0;
  bool saw_lost = false;
  bool tracking_after_lost = false;
};

/// Runs the localizer over the drive; errors are evaluated on extraction
/// frames in Tracking after `settle_s` seconds of tracking.
RunResult run(SyntheticDrive& drive, Localizer& loc, double duration_s, double settle_s = 3.0) {
  RunResult r;
  double se = 0.0;
  int n = 0;
  for (std::uint32_t c = 0; 0.1 * c < duration_s; ++c) {
    for (const auto& m : drive.mounts()) {
      const SensorFrame f = drive.render(c, m);
      const LocalizationOutput out = loc.process(f);
      if (!out.extracted) continue;
      r.outputs.emplace_back(f.time_s, out);
      if (std::getenv("POLMAP_TEST_VERBOSE") != nullptr) {
        const TruthState s = drive.truth(f.time_s);
        const Eigen::Vector2d est = drive.frame().to_local(out.pose.position);
        std::printf(
            "t=%6.2f v=%.2f/%.2f %-12s motion=%d cand=%3d clusters=%3d map=%3d match=%s/%d pts=%2d "
            "err=%.3f extract=%.0fms proc=%.0fms\n",
            f.time_s, out.speed_mps, s.v, std::string(to_string(out.status)).c_str(),
            static_cast<int>(out.motion_status), out.candidates, out.local_point_clusters,
            out.map_points,
            out.match_status ? std::string(to_string(*out.match_status)).c_str() : "-",
            out.match_point_associations, out.matched_points,
            (est - Eigen::Vector2d(s.x, s.y)).norm(), 1e3 * out.extraction_time_s,
            1e3 * out.processing_time_s);
      }
      if (out.status == LocalizationOutput::Status::Lost) r.saw_lost = true;
      if (out.status != LocalizationOutput::Status::Tracking) continue;
      if (r.saw_lost) r.tracking_after_lost = true;
      if (r.first_tracking_s < 0) r.first_tracking_s = f.time_s;
      if (f.time_s < r.first_tracking_s + settle_s) continue;
      const TruthState s = drive.truth(f.time_s);
      const Eigen::Vector2d est = drive.frame().to_local(out.pose.position);
      const double e = (est - Eigen::Vector2d(s.x, s.y)).norm();
      const double yaw = out.pose.yaw_enu_rad + drive.frame().convergence_rad(est);
      r.max_pos_error_tracking_m = std::max(r.max_pos_error_tracking_m, e);
      r.max_yaw_error_tracking_rad =
          std::max(r.max_yaw_error_tracking_rad, std::abs(wrap_angle_rad(yaw - s.yaw)));
      se += e * e;
      ++n;
    }
  }
  r.rms_pos_error_tracking_m = n ? std::sqrt(se / n) : -1.0;
  return r;
}

/// Test configuration: the defaults, with the gridmap range and the extraction
/// cadence pinned (50 m, every 3rd cycle) so these tests keep their figures when
/// the defaults are tuned (the pCFAR cost grows with the observed area).
LocalizerConfig fast_config() {
  LocalizerConfig cfg;
  cfg.gridmap.max_range_m = 50.0;
  cfg.extract_every_n_cycles = 3;
  return cfg;
}

GeoPose perturbed_start(const SyntheticDrive& drive, double err_m, double err_deg, double dir_rad) {
  const TruthState s = drive.truth(0.0);
  const Eigen::Vector2d p =
      Eigen::Vector2d(s.x, s.y) + err_m * Eigen::Vector2d(std::cos(dir_rad), std::sin(dir_rad));
  GeoPose g;
  g.position = drive.frame().to_geo(p);
  g.yaw_enu_rad = s.yaw + err_deg * kDeg - drive.frame().convergence_rad(p);
  return g;
}

/// A localizer with cfg and the map `tiles`, started at `start` (3 m / 3 deg initial
/// uncertainty), run over the first duration_s of the drive.
RunResult localize(SyntheticDrive& drive, const LocalizerConfig& cfg, TileSource& tiles,
                   const GeoPose& start, double duration_s) {
  Localizer loc(cfg, drive.mounts(), tiles);
  loc.set_initial_pose(start, 3.0, 3.0 * kDeg);
  return run(drive, loc, duration_s);
}

/// localize() with the drive's whole map available from the start.
RunResult localize(SyntheticDrive& drive, const LocalizerConfig& cfg, const GeoPose& start,
                   double duration_s) {
  InMemoryTileSource tiles;
  drive.fill_tiles(tiles);
  return localize(drive, cfg, tiles, start, duration_s);
}

TEST(Localizer, ConvergesFromCoarseInitialPoseAndTracks) {
  SyntheticDrive drive(1, 12.0, 1e9, 1e9);
  const RunResult r = localize(drive, fast_config(), perturbed_start(drive, 3.0, 3.0, 2.0), 12.0);
  ASSERT_GT(r.first_tracking_s, 0.0) << "never reached Tracking";
  EXPECT_LT(r.first_tracking_s, 10.0);
  EXPECT_LT(r.rms_pos_error_tracking_m, 0.15);
  EXPECT_LT(r.max_pos_error_tracking_m, 0.4);
  EXPECT_LT(r.max_yaw_error_tracking_rad, 0.6 * kDeg);
  // The periodic wide-gate relocalization check must not fire while tracking well.
  for (const auto& [t, out] : r.outputs) EXPECT_FALSE(out.relocalized) << "at " << t;
  const auto& last = r.outputs.back().second;
  EXPECT_EQ(last.status, LocalizationOutput::Status::Tracking);
  EXPECT_GT(last.matched_points, 3);
  EXPECT_GT(last.map_points, 10);
  // The reported covariance is a real one: small while tracking, positive definite.
  EXPECT_LT(std::sqrt(last.covariance(0, 0)), 0.5);
  EXPECT_GT(last.covariance.determinant(), 0.0);
}

TEST(Localizer, DegradesInAMapGapThenLosesAndRecovers) {
  // 6..16 s: 100 m whose poles are not in the map.
  SyntheticDrive drive(2, 26.0, 60.0, 160.0);
  LocalizerConfig cfg = fast_config();
  cfg.lost_after_s = 4.0;
  const RunResult r = localize(drive, cfg, perturbed_start(drive, 2.0, -2.0, -1.0), 26.0);
  ASSERT_GT(r.first_tracking_s, 0.0);
  bool saw_degraded = false;
  for (const auto& [t, out] : r.outputs) {
    saw_degraded = saw_degraded || out.status == LocalizationOutput::Status::Degraded;
  }
  EXPECT_TRUE(saw_degraded);
  EXPECT_TRUE(r.saw_lost);
  EXPECT_TRUE(r.tracking_after_lost);
  const auto& [t_last, last] = r.outputs.back();
  EXPECT_EQ(last.status, LocalizationOutput::Status::Tracking);
  const TruthState s = drive.truth(t_last);
  EXPECT_LT((drive.frame().to_local(last.pose.position) - Eigen::Vector2d(s.x, s.y)).norm(), 0.4);
}

TEST(Localizer, DegradedStretchFollowsTheOdometryWithoutJumps) {
  // The map ends at 60 m except for an island of a few poles at 140-155 m, one of them
  // 0.3 m off in the map: the localizer degrades, matches the island for a moment and
  // goes on without landmarks. While degraded the estimate may only move with the
  // odometry: when the last pose prior left the graph window, the few island points
  // seen from one pose used to decide the pose alone and the estimate jumped.
  SyntheticDrive drive(7, 32.0, 60.0, 1e9);
  drive.map_island(140.0, 155.0, {0.0, 0.3});
  const RunResult r = localize(drive, fast_config(), perturbed_start(drive, 1.0, 1.0, 0.3), 32.0);
  ASSERT_GT(r.first_tracking_s, 0.0);
  ASSERT_LT(r.first_tracking_s, 5.0);
  EXPECT_FALSE(r.saw_lost);
  bool saw_degraded = false;
  std::optional<Eigen::Vector2d> prev_error;
  double max_step_m = 0.0, max_error_m = 0.0;
  for (const auto& [t, out] : r.outputs) {
    if (t < r.first_tracking_s + 3.0) continue;
    saw_degraded = saw_degraded || out.status == LocalizationOutput::Status::Degraded;
    const TruthState s = drive.truth(t);
    const Eigen::Vector2d e = drive.frame().to_local(out.pose.position) - Eigen::Vector2d(s.x, s.y);
    if (prev_error) max_step_m = std::max(max_step_m, (e - *prev_error).norm());
    prev_error = e;
    max_error_m = std::max(max_error_m, e.norm());
  }
  EXPECT_TRUE(saw_degraded);
  EXPECT_LT(max_step_m, 0.1);  // extractions 0.3 s apart
  EXPECT_LT(max_error_m, 1.0);
}

TEST(Localizer, SurvivesAnEgoMotionOutage) {
  // 2 s without detections at 10 m/s on a curving road: the odometry bridges
  // the outage with one arc; the localizer widens its uncertainty, restarts the
  // graph window and is back on track without a full re-initialization.
  SyntheticDrive drive(5, 16.0, 1e9, 1e9);
  drive.set_detection_outage(7.0, 9.0);
  const RunResult r = localize(drive, fast_config(), perturbed_start(drive, 1.0, 1.0, 0.3), 16.0);
  ASSERT_GT(r.first_tracking_s, 0.0);
  ASSERT_LT(r.first_tracking_s, 7.0);
  EXPECT_FALSE(r.saw_lost);
  double max_err_after = 0.0;
  for (const auto& [t, out] : r.outputs) {
    if (t < 12.0) continue;  // 3 s to re-converge after the outage
    EXPECT_EQ(out.status, LocalizationOutput::Status::Tracking) << "at " << t;
    const TruthState s = drive.truth(t);
    max_err_after =
        std::max(max_err_after,
                 (drive.frame().to_local(out.pose.position) - Eigen::Vector2d(s.x, s.y)).norm());
  }
  EXPECT_LT(max_err_after, 0.3);
}

TEST(Localizer, HoldsThePoseThroughAStandstill) {
  // Stop from 8 s to 20 s: a standing car does not move, so the estimate is
  // held (no drift, no Degraded for lack of new associations) and tracking
  // continues when it drives off.
  SyntheticDrive drive(6, 30.0, 1e9, 1e9, 8.0, 20.0);
  const RunResult r = localize(drive, fast_config(), perturbed_start(drive, 2.0, 2.0, 1.0), 30.0);
  ASSERT_GT(r.first_tracking_s, 0.0);
  ASSERT_LT(r.first_tracking_s, 6.0);
  EXPECT_FALSE(r.saw_lost);
  std::optional<Eigen::Vector2d> stop_position;
  std::optional<double> stop_yaw;
  double max_move_m = 0.0, max_turn_rad = 0.0;
  for (const auto& [t, out] : r.outputs) {
    if (t < r.first_tracking_s) continue;
    EXPECT_EQ(out.status, LocalizationOutput::Status::Tracking) << "at " << t;
    const Eigen::Vector2d est = drive.frame().to_local(out.pose.position);
    const TruthState s = drive.truth(t);
    if (t > 8.5 && t < 19.5) {
      if (!stop_position) {
        stop_position = est;
        stop_yaw = out.pose.yaw_enu_rad;
      }
      max_move_m = std::max(max_move_m, (est - *stop_position).norm());
      max_turn_rad =
          std::max(max_turn_rad, std::abs(wrap_angle_rad(out.pose.yaw_enu_rad - *stop_yaw)));
    }
    // Up to 27 s: near the end of the synthetic road the sensors look past its
    // last poles.
    if (t > 8.0 && t < 27.0) {
      EXPECT_LT((est - Eigen::Vector2d(s.x, s.y)).norm(), 0.3) << "at " << t;
      const double yaw = out.pose.yaw_enu_rad + drive.frame().convergence_rad(est);
      EXPECT_LT(std::abs(wrap_angle_rad(yaw - s.yaw)), 0.6 * kDeg) << "at " << t;
    }
  }
  ASSERT_TRUE(stop_position.has_value());
  EXPECT_LT(max_move_m, 0.02);
  EXPECT_LT(max_turn_rad, 0.1 * kDeg);
  EXPECT_GT(r.outputs.back().first, 27.5);
  EXPECT_GT(r.outputs.back().second.matched_points, 3);
}

/// Tiles become available only after a while (a fetcher still downloading).
class SlowTileSource final : public TileSource {
 public:
  SlowTileSource(TileSource& inner, int refuse_calls) : inner_(inner), refuse_(refuse_calls) {}
  std::optional<tiles::LocalizationTile> tile(const tiles::TileKey& key) override {
    ++calls_;
    if (calls_ <= refuse_) return std::nullopt;
    return inner_.tile(key);
  }
  void prefetch(std::span<const tiles::TileKey> keys) override { prefetched_ += keys.size(); }
  int calls_ = 0;
  std::size_t prefetched_ = 0;

 private:
  TileSource& inner_;
  int refuse_;
};

TEST(Localizer, TilesNotReadyOnlyDelayInitialization) {
  SyntheticDrive drive(3, 10.0, 1e9, 1e9);
  InMemoryTileSource tiles;
  drive.fill_tiles(tiles);
  SlowTileSource slow(tiles, 20);  // the first ~2 s of extractions without map
  const RunResult r =
      localize(drive, fast_config(), slow, perturbed_start(drive, 1.0, 1.0, 0.5), 10.0);
  EXPECT_GT(slow.prefetched_, 0U);
  ASSERT_GT(r.first_tracking_s, 0.0);
  for (const auto& [t, out] : r.outputs) {
    if (t < 1.0) {
      EXPECT_EQ(out.map_points, 0);
      EXPECT_NE(out.status, LocalizationOutput::Status::Tracking);
    }
  }
  EXPECT_EQ(r.outputs.back().second.status, LocalizationOutput::Status::Tracking);
}

TEST(Localizer, NoPoseWithoutInitialPose) {
  SyntheticDrive drive(4, 2.0, 1e9, 1e9);
  InMemoryTileSource tiles;
  Localizer loc(LocalizerConfig{}, drive.mounts(), tiles);
  for (std::uint32_t c = 0; c < 10; ++c) {
    for (const auto& m : drive.mounts()) {
      const auto out = loc.process(drive.render(c, m));
      EXPECT_FALSE(out.has_pose);
      EXPECT_EQ(out.status, LocalizationOutput::Status::Initializing);
    }
  }
}

}  // namespace
}  // namespace polmap::loc
