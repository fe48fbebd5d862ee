// Detection list density: noise-referenced CFAR-like peaks, extended objects detected along
// their extent, ground-clutter detections at short range, the density knobs, and the mean
// number of detections per frame of short urban / rural drives (README "Detection list").
#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "polmap/sim/spectrum.hpp"
#include "sim_test_util.hpp"

namespace polmap::sim {
namespace {

using test::kDeg;
using test::wrap5;

/// A wall (facade parameters of the world builder) across the road at x = x_m, y in [-h, h].
std::shared_ptr<World> wall_world(double x_m, double half_m) {
  auto w = test::empty_world(400);
  WorldObject o;
  o.cls = ObjectClass::Wall;
  o.geometry_m = {{x_m, -half_m}, {x_m, half_m}};
  o.rcs_dbsm = -10.0 + 10.0 * std::log10(3.0);
  LineScatterer l;
  l.model = ExtendedModel::Surface;
  l.rcs_per_m_dbsm = static_cast<float>(o.rcs_dbsm);
  l.grazing_exponent = 1.0F;
  l.specular_gain_db = 20.0F;
  l.specular_width_rad = static_cast<float>(1.5 * kDeg);
  l.opaque = true;
  l.object = w->add_object(o);
  w->add_line_pieces(o.geometry_m, l);
  w->build_index();
  return w;
}

struct WallStats {
  double mean_on_wall = 0;  ///< detections within 0.3 m of the wall per frame
  double min_y = 1e9, max_y = -1e9;
  double max_dv = 0;  ///< largest |v_r - static prediction| of on-wall detections
  int beams = 0;      ///< distinct 1.5-degree azimuth bins holding on-wall detections
};

WallStats wall_stats(const SimConfig& cfg, int frames) {
  const double wall_x = 3.7 + 20.0;  // 20 m in front of the front sensor (mount x = 3.7 m)
  auto w = wall_world(wall_x, 10.0);
  FrameRenderer rend(w, cfg);
  const SensorMount& m = cfg.sensors.front();
  WallStats st;
  std::set<int> beams;
  int on = 0;
  for (int k = 0; k < frames; ++k) {
    const ExactState s = test::state_at(0.01 * k, 0.0, 0.0, 10.0);
    const SensorFrame f = rend.render(m, s, nullptr, k, false, 1000 + k);
    const Pose2 T_ws = Pose2{s.x_m, s.y_m, s.yaw_rad} * m.T_vehicle_sensor;
    for (const Detection& d : f.detections) {
      const Eigen::Vector2d p_s(d.range_m * std::cos(d.azimuth_rad),
                                d.range_m * std::sin(d.azimuth_rad));
      const Eigen::Vector2d p = T_ws * p_s;
      if (std::abs(p.x() - wall_x) > 0.3 || std::abs(p.y()) > 10.3) continue;
      ++on;
      st.min_y = std::min(st.min_y, p.y());
      st.max_y = std::max(st.max_y, p.y());
      // Static target seen from a sensor moving at 10 m/s along its boresight: v_r = -10 cos(az).
      st.max_dv = std::max(st.max_dv,
                           std::abs(wrap5(d.radial_velocity_mps + 10.0 * std::cos(d.azimuth_rad))));
      beams.insert(static_cast<int>(std::lround(d.azimuth_rad / (1.5 * kDeg))));
    }
  }
  st.mean_on_wall = double(on) / frames;
  st.beams = static_cast<int>(beams.size());
  return st;
}

TEST(Detection, WallAt20mGivesManyDetectionsAlongItsExtentWithStaticDoppler) {
  SimConfig cfg = test::quiet_config();
  const WallStats st = wall_stats(cfg, 6);
  std::printf(
      "wall at 20 m (+-10 m): %.1f detections/frame on the wall, y %.1f..%.1f m, %d beams, "
      "max |dv| %.3f m/s\n",
      st.mean_on_wall, st.min_y, st.max_y, st.beams, st.max_dv);
  // The wall spans +-26.6 deg = 36 beams; peaks in about every other beam near the normal and
  // every beam (several range bins apart) off it.
  EXPECT_GE(st.mean_on_wall, 18.0);
  EXPECT_LT(st.min_y, -7.0);
  EXPECT_GT(st.max_y, 7.0);
  EXPECT_GE(st.beams, 25);
  // sigma_vr 0.05 m/s + azimuth error (0.5 deg + uniform cell jitter) x 10 m/s x sin(az).
  EXPECT_LT(st.max_dv, 0.35);
}

TEST(Detection, ThresholdAndSuppressionKnobsControlDensity) {
  SimConfig cfg = test::quiet_config();
  const double base = wall_stats(cfg, 4).mean_on_wall;
  SimConfig low = cfg;
  low.radar.detection_threshold_db = 8.0;
  SimConfig high = cfg;
  high.radar.detection_threshold_db = 18.0;
  SimConfig wide = cfg;
  wide.radar.detection_suppress_range_bins = 4;
  wide.radar.detection_suppress_beams = 2;
  const double nl = wall_stats(low, 4).mean_on_wall, nh = wall_stats(high, 4).mean_on_wall,
               nw = wall_stats(wide, 4).mean_on_wall;
  std::printf("wall detections/frame: 8 dB %.1f, 12 dB %.1f, 18 dB %.1f, wide suppression %.1f\n",
              nl, base, nh, nw);
  EXPECT_GT(nl, base);
  EXPECT_LT(nh, base);
  EXPECT_LT(nw, base);
}

TEST(Detection, GroundClutterGivesStaticDetectionsAtShortRangeAtAllAzimuths) {
  auto w = test::empty_world(400);
  w->build_index();
  SimConfig cfg;
  cfg.radar.false_alarms_per_frame = 0.0;
  FrameRenderer rend(w, cfg);
  const SensorMount& m = cfg.sensors.front();
  const double v = 8.0;
  int n = 0, near = 0, left = 0, right = 0;
  double max_dv = 0;
  const int frames = 5;
  for (int k = 0; k < frames; ++k) {
    const SensorFrame f =
        rend.render(m, test::state_at(0.5 * k, 0, 0, v), nullptr, k, false, 77 + k);
    for (const Detection& d : f.detections) {
      ++n;
      if (d.range_m < 12.0) ++near;
      if (d.azimuth_rad > 30 * kDeg) ++left;
      if (d.azimuth_rad < -30 * kDeg) ++right;
      max_dv =
          std::max(max_dv, std::abs(wrap5(d.radial_velocity_mps + v * std::cos(d.azimuth_rad))));
    }
  }
  std::printf("empty world, ground only: %.1f detections/frame, %.0f %% below 12 m\n",
              double(n) / frames, 100.0 * near / std::max(n, 1));
  EXPECT_GT(n / frames, 120);
  EXPECT_LT(n / frames, 350);
  EXPECT_GT(near, 0.8 * n);
  EXPECT_GT(left, n / 8);
  EXPECT_GT(right, n / 8);
  EXPECT_LT(max_dv, 0.3);

  // Switched off, or with the old clutter-referenced threshold, the ground gives nothing.
  SimConfig off = cfg;
  off.radar.ground_detections = false;
  FrameRenderer rend_off(w, off);
  const SensorFrame f = rend_off.render(m, test::state_at(0, 0, 0, v), nullptr, 0, false, 77);
  EXPECT_LT(f.detections.size(), 5U);
}

double mean_detections_per_frame(const char* world_name, double speed_hint_s, int seed) {
  SimConfig cfg;
  cfg.duration_s = speed_hint_s;
  auto world = load_world(world_name, 400.0, seed, cfg);
  DriveSimulator sim(world, cfg, 0);
  std::size_t dets = 0, frames = 0, moving_frames = 0, moving_dets = 0, min_moving = 100000;
  double v = 0;
  while (auto rec = sim.next()) {
    if (const auto* s = std::get_if<TrajectorySample>(&*rec)) {
      v = s->speed_mps;
      continue;
    }
    const auto& f = std::get<SensorFrame>(*rec);
    ++frames;
    dets += f.detections.size();
    EXPECT_LE(f.detections.size(), 800U);
    if (v > 5.0) {
      ++moving_frames;
      moving_dets += f.detections.size();
      min_moving = std::min(min_moving, f.detections.size());
    }
  }
  std::printf(
      "%s 400 m seed %d, first %.0f s: %.0f detections/frame (%.0f while > 5 m/s, min %zu)\n",
      world_name, seed, speed_hint_s, double(dets) / frames,
      double(moving_dets) / std::max<std::size_t>(moving_frames, 1), min_moving);
  EXPECT_GT(moving_frames, 0U);
  return double(moving_dets) / std::max<std::size_t>(moving_frames, 1);
}

TEST(Detection, MeanDetectionsPerFrameOfShortDrivesAreInTheDocumentedRange) {
  // README "Detection list": urban 250-600 per frame, rural >= 100 at typical speeds.
  const double urban = mean_detections_per_frame("urban", 20.0, 1);
  EXPECT_GE(urban, 250.0);
  EXPECT_LE(urban, 600.0);
  const double rural = mean_detections_per_frame("rural", 20.0, 2);
  EXPECT_GE(rural, 100.0);
  EXPECT_LE(rural, 600.0);
}

}  // namespace
}  // namespace polmap::sim
