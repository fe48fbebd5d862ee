// Mapping-mode drive processing: poses come from the georeferenced trajectory
// (LocalFrame at the header origin, ENU yaw plus meridian convergence),
// interpolated at each sensor frame time and composed with the mount; a static
// pole seen by a moving sensor ends up as one odd-bounce point at its position.
#include "polmap/radar/drive_processor.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

namespace polmap::radar {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

/// A drive along a straight line in the drive frame, heading 30° north of east,
/// 100 Hz trajectory, one sensor (front-left mount) at 10 Hz, one pole.
class SyntheticDrive final : public RecordSource {
 public:
  SyntheticDrive() : frame_(origin()) {
    header_.drive_id = "synthetic";
    header_.origin = origin();
    header_.sensors = {SensorMount{1, "front_left", {3.5, 0.75, 40.0 * kDeg}, 0.033, {}}};
    const double t_end = 6.0;
    // A sensor frame before the first trajectory sample (cannot be posed).
    events_.push_back({-0.05, false});
    for (int k = 0; k <= static_cast<int>(t_end * 100); ++k) events_.push_back({k * 0.01, true});
    for (int k = 0; k < static_cast<int>(t_end * 10); ++k)
      events_.push_back({k * 0.1 + 0.033, false});
    std::stable_sort(events_.begin(), events_.end(),
                     [](const Event& a, const Event& b) { return a.t < b.t; });
  }
  static GeoPoint origin() { return {52.0, 13.0, 0.0}; }
  /// Exact vehicle pose in the drive frame.
  static Pose2 pose(double t) {
    const double h = 30.0 * kDeg, v = 8.0;
    return {200.0 + v * t * std::cos(h), -150.0 + v * t * std::sin(h), h};
  }
  static Eigen::Vector2d pole() { return pose(3.0) * Eigen::Vector2d(8.0, 6.0); }

  const RecordingHeader& header() const override { return header_; }
  std::optional<RecordingRecord> next() override {
    if (i_ >= events_.size()) return std::nullopt;
    const Event e = events_[i_++];
    if (e.trajectory) {
      const Pose2 p = pose(e.t);
      const GeoPoint g = frame_.to_geo(p.translation());
      TrajectorySample s;
      s.time_s = e.t;
      s.lat_deg = g.lat_deg;
      s.lon_deg = g.lon_deg;
      s.yaw_enu_rad = p.yaw_rad - frame_.convergence_rad(p.translation());
      s.speed_mps = 8.0;
      return s;
    }
    SensorFrame f;
    f.sensor_id = 1;
    f.time_s = e.t;
    f.spectrum = spectrum(pose(e.t) * header_.sensors[0].T_vehicle_sensor);
    return f;
  }

 private:
  struct Event {
    double t;
    bool trajectory;
  };
  static PolSpectrum spectrum(const Pose2& T_frame_sensor) {
    PolSpectrum s;
    s.range_bin_m = 0.075;
    s.num_range_bins = 400;  // 30 m
    s.noise_sigma = 1.0F;
    for (int k = 0; k < 81; ++k)
      s.azimuth_bins_rad.push_back(static_cast<float>((-60.0 + 1.5 * k) * kDeg));
    const Eigen::Vector2d v = T_frame_sensor.inverse() * pole();
    const double fr = v.norm() / s.range_bin_m;
    const double fa = (std::atan2(v.y(), v.x()) / kDeg + 60.0) / 1.5;
    if (fr > 395 || fa < 1 || fa > 79) return s;
    for (int k = static_cast<int>(fa) - 2; k <= static_cast<int>(fa) + 3; ++k) {
      for (int i = static_cast<int>(fr) - 2; i <= static_cast<int>(fr) + 3; ++i) {
        if (k < 0 || k > 80) continue;
        const double g =
            30.0 * std::exp(-0.5 * ((i - fr) * (i - fr) / 0.4 + (k - fa) * (k - fa) / 0.5));
        if (g < 3.0) continue;
        SpectrumCell c;
        c.azimuth_bin = static_cast<std::uint16_t>(k);
        c.range_bin = static_cast<std::uint16_t>(i);
        c.s[1] = c.s[2] = cfloat(0.0F, static_cast<float>(g));
        s.cells.push_back(c);
      }
    }
    return s;
  }
  RecordingHeader header_;
  tiles::LocalFrame frame_;
  std::vector<Event> events_;
  std::size_t i_ = 0;
};

TEST(DriveProcessor, StaticPoleBecomesOneOddPointAtItsPosition) {
  SyntheticDrive drive;
  int progress_calls = 0;
  const DriveProcessingResult r = process_drive(drive, {}, [&](double) { ++progress_calls; });
  EXPECT_EQ(r.stats.sensor_frames, 61U);
  EXPECT_EQ(r.stats.frames_without_pose, 1U);
  EXPECT_EQ(r.stats.frames_mapped, 60U);
  EXPECT_EQ(progress_calls, 60);
  EXPECT_EQ(r.stats.trajectory_samples, 601U);
  EXPECT_NEAR(r.stats.distance_m, 48.0, 1e-3);
  EXPECT_EQ(r.trajectory.size(), 601U);
  EXPECT_EQ(r.header.drive_id, "synthetic");
  EXPECT_NEAR(r.frame.origin().lat_deg, 52.0, 1e-12);
  ASSERT_EQ(r.points.size(), 1U);
  EXPECT_LT((r.points[0].position_m - SyntheticDrive::pole()).norm(), 0.1)
      << r.points[0].position_m.transpose() << " vs " << SyntheticDrive::pole().transpose();
  EXPECT_EQ(r.points[0].scattering, ScatteringClass::Odd);
  EXPECT_TRUE(r.lines.empty());
}

TEST(DriveProcessor, TrajectoryInterpolatorUsesConvergenceAndRespectsGaps) {
  const tiles::LocalFrame frame({60.0, 10.0, 0.0});
  TrajectoryInterpolator traj(frame, 0.5, 0.1);
  // 20 km east of the origin (lat 60°) the meridian convergence is ~5 mrad.
  const Eigen::Vector2d xy(20000.0, 0.0);
  const GeoPoint g = frame.to_geo(xy);
  const double conv = frame.convergence_rad(xy);
  ASSERT_GT(std::abs(conv), 4e-3);
  for (int k = 0; k < 3; ++k) {
    TrajectorySample s;
    s.time_s = k * 0.4 + (k == 2 ? 1.0 : 0.0);  // samples at 0, 0.4, 1.8: a 1.4 s gap
    s.lat_deg = g.lat_deg;
    s.lon_deg = g.lon_deg;
    s.yaw_enu_rad = 0.0;
    EXPECT_TRUE(traj.add(s));
  }
  TrajectorySample old;
  old.time_s = 0.2;
  EXPECT_FALSE(traj.add(old));  // not increasing
  const auto p = traj.T_frame_vehicle(0.2);
  ASSERT_TRUE(p.has_value());
  EXPECT_NEAR(p->yaw_rad, conv, 1e-12);
  EXPECT_NEAR(p->x_m, 20000.0, 1e-6);
  EXPECT_FALSE(traj.T_frame_vehicle(1.0).has_value());   // inside the gap
  EXPECT_FALSE(traj.T_frame_vehicle(-0.1).has_value());  // before the first sample
  // A few milliseconds before it (a calibrated time offset): the first sample's motion
  // extrapolated backwards.
  const auto p_before = traj.T_frame_vehicle(-0.004);
  const auto p_first = traj.T_frame_vehicle(0.0);
  ASSERT_TRUE(p_before.has_value() && p_first.has_value());
  const auto vw_first = traj.motion(0.0);
  ASSERT_TRUE(vw_first.has_value());
  const Pose2 expected = *p_first * integrate_motion(vw_first->first, vw_first->second, -0.004);
  EXPECT_NEAR(p_before->x_m, expected.x_m, 1e-9);
  EXPECT_NEAR(p_before->y_m, expected.y_m, 1e-9);
  EXPECT_NEAR(p_before->yaw_rad, expected.yaw_rad, 1e-12);
  EXPECT_FALSE(traj.T_frame_vehicle(-0.006).has_value());
  EXPECT_TRUE(traj.T_frame_vehicle(1.85).has_value());  // short extrapolation
  EXPECT_FALSE(traj.T_frame_vehicle(2.0).has_value());
}

}  // namespace
}  // namespace polmap::radar
