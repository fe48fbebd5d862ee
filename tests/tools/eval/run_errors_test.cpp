// attach_run_errors: a report's errors are exactly those `polmap eval` computes for the same
// samples (same filters), at the samples' own times, in the reference's frame.
#include "polmap/eval/run_errors.hpp"

#include <gtest/gtest.h>

#include "polmap/tiles/local_frame.hpp"

namespace polmap::eval {
namespace {

TEST(RunErrors, AttachesTheEvaluationsErrorsToTheSamplesItEvaluated) {
  const tiles::LocalFrame f(GeoPoint{48.4, 9.99, 0.0});
  // Reference: east at 10 m/s for 10 s, 50 Hz; carrier phase lost between 4 and 5 s.
  std::vector<ReferenceSample> ref;
  for (int i = 0; i <= 500; ++i) {
    ReferenceSample r;
    r.time_s = 0.02 * i;
    const GeoPoint p = f.to_geo(Eigen::Vector2d(10.0 * r.time_s, 0.0));
    r.lat_deg = p.lat_deg;
    r.lon_deg = p.lon_deg;
    r.yaw_enu_rad = 0.0;
    r.speed_mps = 10.0;
    r.carrier_phase = !(r.time_s >= 4.0 && r.time_s < 5.0);
    ref.push_back(r);
  }
  // The run: 0.1 m north of the reference (left of an eastward heading), 1 m ahead.
  LocalizationRun run;
  for (int i = 0; i < 45; ++i) {
    LocalizationRunSample s;
    s.t_s = 0.1 + 0.2 * i;
    const GeoPoint p = f.to_geo(Eigen::Vector2d(10.0 * s.t_s + 1.0, 0.1));
    s.lat_deg = p.lat_deg;
    s.lon_deg = p.lon_deg;
    s.yaw_enu_deg = 0.5;
    s.status = i < 3 ? RunStatus::Initializing : RunStatus::Tracking;
    s.error = RunSampleError{9, 9, 9};  // stale errors are replaced or cleared
    run.samples.push_back(s);
  }
  const TrajectoryMetrics m = attach_run_errors(run, ref, RunReference::SimulatorTruth);
  EXPECT_EQ(run.reference, RunReference::SimulatorTruth);
  int with_error = 0;
  for (const auto& s : run.samples) {
    const bool expected = s.status != RunStatus::Initializing && !(s.t_s >= 4.0 && s.t_s < 5.0);
    ASSERT_EQ(s.error.has_value(), expected) << s.t_s;
    if (!s.error) continue;
    ++with_error;
    EXPECT_NEAR(s.error->long_m, 1.0, 1e-3);
    EXPECT_NEAR(s.error->lat_m, 0.1, 1e-3);
    EXPECT_NEAR(s.error->rot_deg, 0.5, 1e-4);  // meridian convergence over 1 m
  }
  EXPECT_EQ(with_error, m.evaluated);
  EXPECT_GT(with_error, 30);
  EXPECT_NEAR(m.lat_rmse_m, 0.1, 1e-3);
}

}  // namespace
}  // namespace polmap::eval
